"""
The scan's output files: ``verdicts.json``, ``work_orders.csv`` and ``report.html``.

:func:`write_outputs` writes all three from ranked
:class:`valvediag.scan.LoopResult` objects:

``verdicts.json``
    ``{"run_id": ..., "loops": [...]}`` with one entry per loop, in rank order,
    holding ``loop, verdict, rank, severity, confidence, process_type, bi,
    period_s, amplitude, reason`` and, for convenience, ``unit,
    amplitude_pct_span, regularity, window_start, window_end``. NaN is
    written as ``null``; numbers are rounded to 6 significant digits.
``work_orders.csv``
    One row per loop that needs action (:data:`valvediag.scan.ACTION_VERDICTS`),
    in rank order: ``loop, unit, fault, confidence, severity,
    recommended_action, report_link, rank, description, reason``, where
    ``report_link`` is ``report.html#loop-<id>`` (:func:`loop_anchor`).
``report.html``
    A self-contained page (inline CSS, no scripts, no external files): the
    run, the problems met, the ranked loops needing action, the other loops,
    and one section per loop with its evidence, data quality and episodes.
    Every name and text from the data is HTML-escaped (jinja2 autoescape).

The template is ``reports/scan_basic.html.j2`` next to the package; set
``VALVEDIAG_REPORTS_DIR`` to use another directory.
"""
from __future__ import annotations

import csv
import datetime as dt
import hashlib
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from .scan import ACTION_VERDICTS, LoopResult, _clean

__all__ = ["write_outputs", "write_verdicts_json", "write_work_orders", "write_report_html",
           "render_report", "loop_anchor", "RECOMMENDED_ACTIONS", "WORK_ORDER_COLUMNS",
           "VERDICT_KEYS", "REPORTS_DIR"]

REPORTS_DIR = Path(os.environ.get("VALVEDIAG_REPORTS_DIR",
                                  Path(__file__).resolve().parent.parent / "reports"))
TEMPLATE = "scan_basic.html.j2"

#: What to do about each verdict that needs action.
RECOMMENDED_ACTIONS = {
    "stiction": "valve maintenance (packing, stem, actuator) or a positioner check",
    "backlash": "dead-band compensation (Hägglund 2007) or mechanical repair of the "
                "linkage or positioner",
    "linear-oscillation": "review the controller tuning or trace the external disturbance; "
                          "not a valve fault",
    "undecided": "inspect: a valve nonlinearity whose kind (stiction or backlash) is not "
                 "clear; check the trend and collect more data",
}
#: Columns of ``work_orders.csv``, in order.
WORK_ORDER_COLUMNS = ("loop", "unit", "fault", "confidence", "severity", "recommended_action",
                      "report_link", "rank", "description", "reason")
#: Keys of every ``verdicts.json`` loop entry, in order.
VERDICT_KEYS = ("loop", "verdict", "rank", "severity", "confidence", "process_type", "bi",
                "period_s", "amplitude", "reason", "unit", "amplitude_pct_span", "regularity",
                "window_start", "window_end")

_SAFE_ID = re.compile(r"[A-Za-z0-9_.\-]+")


def loop_anchor(loop: str) -> str:
    """The HTML id of a loop's section in ``report.html``: ``loop-<id>``.

    Parameters
    ----------
    loop : str
        Loop name.

    Returns
    -------
    str
        ``"loop-" + loop`` when the name uses only letters, digits, ``_``,
        ``.`` and ``-``; otherwise the name with every other character
        replaced by ``-`` plus the first 8 hex digits of its SHA-1, so ids
        stay unique and need no escaping in a URL.
    """
    if _SAFE_ID.fullmatch(loop):
        return f"loop-{loop}"
    slug = re.sub(r"[^A-Za-z0-9_.\-]", "-", loop)
    return f"loop-{slug}-{hashlib.sha1(loop.encode()).hexdigest()[:8]}"


def _sig(x, digits: int = 6):
    """Round a finite float to ``digits`` significant digits; other values pass."""
    if isinstance(x, float) and math.isfinite(x) and x != 0:
        return round(x, digits - 1 - int(math.floor(math.log10(abs(x)))))
    return x


def write_verdicts_json(results: Sequence[LoopResult], path, *, run_id: str) -> Path:
    """Write ``verdicts.json``.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results, written in this order.
    path : str or path-like
        Output file.
    run_id : str
        The run.

    Returns
    -------
    pathlib.Path
    """
    loops = []
    for r in results:
        d = r.to_json()
        loops.append({k: _sig(d.get(k)) for k in VERDICT_KEYS})
    path = Path(path)
    path.write_text(json.dumps({"run_id": run_id, "loops": _clean(loops)}, indent=1,
                               allow_nan=False, ensure_ascii=False) + "\n", encoding="utf-8")
    return path


def write_work_orders(results: Sequence[LoopResult], path, *, report_name: str = "report.html"
                      ) -> Path:
    """Write ``work_orders.csv``: one row per loop needing action, in rank order.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    path : str or path-like
        Output file (UTF-8, header row).
    report_name : str
        File the ``report_link`` column points to.

    Returns
    -------
    pathlib.Path
    """
    rows = [r for r in results if r.verdict in ACTION_VERDICTS]
    rows.sort(key=lambda r: (r.rank is None, r.rank or 0, r.loop))
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(WORK_ORDER_COLUMNS)
        for r in rows:
            w.writerow([r.loop, r.unit or "", r.verdict, f"{r.confidence:.2f}",
                        f"{r.severity:.4g}", RECOMMENDED_ACTIONS[r.verdict],
                        f"{report_name}#{loop_anchor(r.loop)}",
                        "" if r.rank is None else r.rank, r.description, r.reason])
    return path


def _fmt(x, spec=".3g", unit=""):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:{spec}}{unit}"


def _fmt_time(t):
    if t is None:
        return "–"
    if isinstance(t, str):
        t = dt.datetime.fromisoformat(t)
    return t.astimezone(dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")


_EVIDENCE_KEYS = (("cycles", "cycles", ".3g"), ("samples_per_period", "samples per period", ".3g"),
                  ("theta_peak_mean", "mean angle at peaks [deg]", ".3g"),
                  ("theta_middle_mean", "mean angle at middles [deg]", ".3g"),
                  ("pv_distortion", "PV harmonic distortion", ".3g"),
                  ("ramp_ratio", "ramp ratio (integrating test)", ".3g"),
                  ("process_screen", "integrating screen", ""),
                  ("coverage", "usable share of window", ".0%"),
                  ("time_share", "share of window oscillating", ".0%"),
                  ("span", "span used", ".4g"), ("span_source", "span from", ""),
                  ("agreement", "episode agreement", ".0%"))


def _loop_view(r: LoopResult) -> dict:
    ev = r.evidence or {}
    evidence = []
    for key, label, spec in _EVIDENCE_KEYS:
        v = ev.get(key)
        if v is None:
            continue
        evidence.append((label, _fmt(v, spec) if spec else str(v)))
    q = r.quality or {}
    qrows = []
    for key, label, spec in (("valid_pct", "usable grid points", ".1f"),
                             ("bad_pct", "bad-state rows", ".1f"),
                             ("gap_count", "gaps", "d"),
                             ("median_spacing_s", "median PV spacing [s]", ".3g"),
                             ("compressed", "PV compressed", ""),
                             ("saturation_pct", "OP saturated [%]", ".1f"),
                             ("op_held_pct", "OP held constant [%]", ".1f")):
        v = q.get(key)
        if v is None:
            continue
        qrows.append((label, str(v) if not spec else _fmt(v, spec)))
    unit = f" {r.unit}" if r.unit else ""
    return {
        "loop": r.loop, "anchor": loop_anchor(r.loop), "unit": r.unit or "",
        "description": r.description, "verdict": r.verdict,
        "verdict_class": r.verdict.replace("-", "_"),
        "rank": "" if r.rank is None else r.rank, "confidence": _fmt(r.confidence, ".2f"),
        "severity": _fmt(r.severity, ".3g") if r.severity else "–",
        "process_type": r.process_type, "bi": _fmt(r.bi, ".2f"),
        "period": _fmt(r.period_s, ".4g", " s"),
        "amplitude": _fmt(r.amplitude, ".3g", unit),
        "amplitude_pct": _fmt(r.amplitude_pct_span, ".2f", " %"),
        "regularity": _fmt(r.regularity, ".2f"), "reason": r.reason,
        "action": RECOMMENDED_ACTIONS.get(r.verdict, ""),
        "window": f"{_fmt_time(r.window_start)} to {_fmt_time(r.window_end)}",
        "evidence": evidence, "quality": qrows, "issues": list(q.get("issues") or []),
        "problems": list(ev.get("problems") or []),
        "episodes": [{"start": _fmt_time(e.start), "end": _fmt_time(e.end),
                      "duration": _fmt(e.duration_s / 60, ".1f", " min"),
                      "period": _fmt(e.period_s, ".4g", " s"),
                      "amplitude": _fmt(e.amplitude, ".3g", unit),
                      "regularity": _fmt(e.regularity, ".2f"), "verdict": e.verdict,
                      "bi": _fmt(e.bi, ".2f"), "confidence": _fmt(e.confidence, ".2f")}
                     for e in r.episodes],
    }


def render_report(results: Sequence[LoopResult], *, run_id: str, run_info: Mapping | None = None
                  ) -> str:
    """The HTML text of ``report.html``.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    run_id : str
        The run.
    run_info : mapping, optional
        Shown in the header when present: ``window_start``, ``window_end``,
        ``generated`` (datetimes or ISO text), ``exports`` (list),
        ``loops_csv``, ``db``, ``config`` (dict), and lists of one-line
        ``registry_problems``, ``ingest_errors`` and ``new_faults`` (loop
        names).

    Returns
    -------
    str
    """
    import jinja2

    info = dict(run_info or {})
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(os.fspath(REPORTS_DIR)),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    views = [_loop_view(r) for r in results]
    counts: dict[str, int] = {}
    for r in results:
        counts[r.verdict] = counts.get(r.verdict, 0) + 1
    exports = info.get("exports") or []
    if isinstance(exports, (str, os.PathLike)):
        exports = [exports]
    config = info.get("config") or {}
    new = set(info.get("new_faults") or [])
    return env.get_template(TEMPLATE).render(
        run_id=run_id,
        generated=_fmt_time(info.get("generated")) if info.get("generated") else "–",
        window=(f"{_fmt_time(info.get('window_start'))} to {_fmt_time(info.get('window_end'))}"
                if info.get("window_start") else "–"),
        exports=[os.fspath(e) for e in exports],
        loops_csv=os.fspath(info.get("loops_csv", "")) if info.get("loops_csv") else "",
        config=[(k, "–" if v is None else str(v)) for k, v in config.items()],
        counts=sorted(counts.items(), key=lambda kv: -kv[1]),
        n_loops=len(results),
        action=[v for v in views if v["verdict"] in ACTION_VERDICTS],
        others=[v for v in views if v["verdict"] not in ACTION_VERDICTS],
        loops=views, new_faults=new,
        registry_problems=list(info.get("registry_problems") or []),
        ingest_errors=list(info.get("ingest_errors") or []),
    )


def write_report_html(results: Sequence[LoopResult], path, *, run_id: str,
                      run_info: Mapping | None = None) -> Path:
    """Write ``report.html`` (see :func:`render_report`).

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    path : str or path-like
        Output file (UTF-8).
    run_id : str
        The run.
    run_info : mapping, optional
        See :func:`render_report`.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    path.write_text(render_report(results, run_id=run_id, run_info=run_info), encoding="utf-8")
    return path


def write_outputs(results: Sequence[LoopResult], out_dir, *, run_id: str,
                  run_info: Mapping | None = None) -> dict[str, Path]:
    """Write ``verdicts.json``, ``work_orders.csv`` and ``report.html``.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results (:func:`valvediag.scan.rank_results`).
    out_dir : str or path-like
        Directory, created when missing; existing files of these names are
        replaced.
    run_id : str
        The run.
    run_info : mapping, optional
        Header of the report (see :func:`render_report`).

    Returns
    -------
    dict of str to pathlib.Path
        ``verdicts``, ``work_orders`` and ``report``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return {
        "verdicts": write_verdicts_json(results, out / "verdicts.json", run_id=run_id),
        "work_orders": write_work_orders(results, out / "work_orders.csv"),
        "report": write_report_html(results, out / "report.html", run_id=run_id,
                                    run_info=run_info),
    }
