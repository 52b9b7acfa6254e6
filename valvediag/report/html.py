"""
The morning report: one self-contained HTML file per run.

:func:`render_report` fills ``reports/report.html.j2`` (and its partials in
``reports/partials/``) with the run summary, the ranked table of every loop
and one section per loop; ``reports/report.css`` and ``reports/report.js``
are inlined. The page loads nothing from anywhere: figures are inline SVG,
there are no fonts, images or scripts by URL, so it opens offline and as an
e-mail attachment. The few lines of script only sort and filter the table;
without them the page reads the same, ranked.

Every text from the data (loop and tag names, descriptions, reasons, file
names) goes through jinja2's autoescape; the SVGs are generated from numbers
and fixed words, with the few data texts in them XML-escaped.
"""
from __future__ import annotations

import datetime as dt
import hashlib
import importlib.resources
import math
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from markupsafe import Markup

from ..verdicts import ACTION_VERDICTS, RANK_ORDER, rank_position
from .explain import (
    ACTIONS,
    SHORT_ACTIONS,
    VERDICT_LABELS,
    confidence_word,
    duration_text,
    explain,
    quality_label,
    regularity_text,
    size_text,
)
from .history import PlantHistory, plant_history
from .svg import history_svg, sparkline_svg

__all__ = ["render_report", "loop_anchor", "REPORTS_DIR", "TEMPLATE"]

#: The templates, CSS and script: ``reports/`` of the repository, shipped as
#: ``valvediag.templates``.
REPORTS_DIR = importlib.resources.files("valvediag.templates")
TEMPLATE = "report.html.j2"
_SAFE_ID = re.compile(r"[A-Za-z0-9_.\-]+")
_UTC = dt.timezone.utc


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


def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def _fmt(x, spec=".3g", unit=""):
    return f"{x:{spec}}{unit}" if _finite(x) else "–"


def _time(t, fmt="%Y-%m-%d %H:%M UTC"):
    if t is None:
        return "–"
    if isinstance(t, str):
        t = dt.datetime.fromisoformat(t)
    if t.tzinfo is None:
        t = t.replace(tzinfo=_UTC)
    return t.astimezone(_UTC).strftime(fmt)


def _sort_num(x) -> str:
    """A sort key attribute: the number to 4 significant digits, or empty (sorted last)."""
    return f"{float(x):.4g}" if _finite(x) else ""


def _row(r, hist, anchor: str) -> dict:
    label, detail, score = quality_label(r.quality)
    spark = r.detail.sparkline if r.detail is not None else None
    return {
        "loop": r.loop, "anchor": anchor, "unit": r.unit or "", "description": r.description,
        "verdict": r.verdict, "verdict_label": VERDICT_LABELS.get(r.verdict, r.verdict),
        "vclass": "v-" + r.verdict, "rank": "" if r.rank is None else r.rank,
        "rank_key": _sort_num(r.rank), "order_key": rank_position(r.verdict),
        "confidence": _fmt(r.confidence, ".2f"), "confidence_key": _sort_num(r.confidence),
        "bi": _fmt(r.bi, ".2f"), "bi_key": _sort_num(r.bi),
        "period": duration_text(r.period_s), "period_key": _sort_num(r.period_s),
        "amp_pct": _fmt(r.amplitude_pct_span, ".2g", " %"),
        "amp_key": _sort_num(r.amplitude_pct_span),
        "regularity": _fmt(r.regularity, ".2g") if not (_finite(r.regularity) and
                                                         r.regularity > 99) else "> 99",
        "regularity_key": _sort_num(r.regularity),
        "severity": _fmt(r.severity, ".2g") if r.severity else "–",
        "severity_key": _sort_num(r.severity),
        "quality": label, "quality_detail": detail, "quality_key": _sort_num(score),
        "status": hist.status, "first": _time(hist.first_reported, "%Y-%m-%d")
        if hist.first_reported else "",
        "first_key": hist.first_reported.isoformat() if hist.first_reported else "",
        "action": SHORT_ACTIONS.get(r.verdict, ""), "action_full": ACTIONS.get(r.verdict, ""),
        "spark": sparkline_svg(spark),
        "reason": r.reason,
    }


def _facts(r) -> list[tuple[str, str]]:
    unit = f" {r.unit}" if r.unit else ""
    ev = r.evidence or {}
    facts = [("Verdict", f"{r.verdict} ({VERDICT_LABELS.get(r.verdict, '')})"),
             ("Confidence", f"{_fmt(r.confidence, '.2f')} ({confidence_word(r.confidence)})"),
             ("Backlash Index", _fmt(r.bi, ".2f")),
             ("Fault size (model fit)", size_text(getattr(r, "size", None)) or "–"),
             ("Period", f"{duration_text(r.period_s)} ({_fmt(r.period_s, '.4g', ' s')})"),
             ("Amplitude", f"±{_fmt(r.amplitude, '.3g', unit)} "
                           f"({_fmt(r.amplitude_pct_span, '.2g', ' % of span')})"),
             ("Regularity", regularity_text(r.regularity)),
             ("Severity", _fmt(r.severity, ".3g")),
             ("Process type", f"{r.process_type} (from {ev.get('process_type_source', '–')})"),
             ("Cycles analysed", _fmt(ev.get("cycles"), ".0f")),
             ("Share of window oscillating", _fmt(ev.get("time_share"), ".0%")),
             ("Window", f"{_time(r.window_start)} to {_time(r.window_end)}")]
    return facts


def _quality_rows(q: dict) -> list[tuple[str, str]]:
    rows = []
    for key, label, spec in (("valid_pct", "usable grid points [%]", ".1f"),
                             ("bad_pct", "bad-state rows [%]", ".2g"),
                             ("gap_count", "gaps", "d"),
                             ("median_spacing_s", "median PV spacing [s]", ".3g"),
                             ("compressed", "PV compressed", ""),
                             ("saturation_pct", "OP saturated [%]", ".2g"),
                             ("op_held_pct", "OP held constant [%]", ".2g"),
                             ("manual_pct", "manual mode [%]", ".2g")):
        v = (q or {}).get(key)
        if v is None:
            continue
        rows.append((label, ("yes" if v else "no") if spec == "" else _fmt(v, spec)))
    return rows


def _history_view(hist, thresholds) -> dict:
    points = [{"verdict": p.verdict, "bi": p.bi, "current": p.current,
               "label": f"{_time(p.started_at)}: {p.verdict}"
                        + (f", BI {p.bi:.2f}" if _finite(p.bi) else "")
                        + (" (this run)" if p.current else "")}
              for p in hist.points]
    rows = [{"when": _time(p.started_at), "run": p.run_id, "verdict": p.verdict,
             "vclass": "v-" + p.verdict, "bi": _fmt(p.bi, ".2f"),
             "confidence": _fmt(p.confidence, ".2f"), "current": p.current}
            for p in reversed(hist.points[-8:])]
    return {"svg": history_svg(points, thresholds=thresholds), "rows": rows,
            "more": max(0, len(hist.points) - 8)}


def _episodes(r) -> list[dict]:
    unit = f" {r.unit}" if r.unit else ""
    return [{"start": _time(e.start, "%Y-%m-%d %H:%M"), "end": _time(e.end, "%H:%M"),
             "duration": duration_text(e.duration_s), "period": duration_text(e.period_s),
             "amplitude": _fmt(e.amplitude, ".3g", unit), "regularity": _fmt(e.regularity, ".3g"),
             "verdict": e.verdict, "vclass": "v-" + e.verdict, "bi": _fmt(e.bi, ".2f"),
             "confidence": _fmt(e.confidence, ".2f")} for e in r.episodes]


def _read(name: str) -> str:
    return (REPORTS_DIR / name).read_text(encoding="utf-8")


def render_report(results: Sequence, *, run_id: str, run_info: Mapping | None = None,
                  history: PlantHistory | None = None, workers: int | None = None) -> str:
    """The HTML text of ``report.html``.

    Parameters
    ----------
    results : sequence of valvediag.scan.LoopResult
        Ranked results (:func:`valvediag.scan.rank_results`). Loops needing
        action get their figures from ``result.detail`` (kept by the scan);
        a result without it gets its section without figures.
    run_id : str
        The run.
    run_info : mapping, optional
        Shown in the header when present: ``plant`` (name of the plant or
        area; default the folder of ``loops_csv``), ``window_start``,
        ``window_end``, ``generated`` (datetimes or ISO text), ``exports``
        (list), ``loops_csv``, ``db``, ``config`` (dict), lists of
        one-line ``registry_problems``, ``ingest_errors`` and
        ``ingest_quarantine`` (files with rows quarantined), and the run's
        ``status`` (``'partial'`` shows a banner) and ``status_note``.
    history : valvediag.report.history.PlantHistory, optional
        This run compared with the earlier ones (new, repeat, resolved);
        default: no history, every loop needing action is new.
    workers : int, optional
        Processes drawing the figures (see
        :func:`valvediag.report.figures.render_loop_figures`).

    Returns
    -------
    str
    """
    import jinja2

    from .figures import render_loop_figures

    info = dict(run_info or {})
    if history is None:
        history = plant_history(results, run_id=run_id, started_at=_as_time(info.get("generated")))
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(REPORTS_DIR)),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    anchors = {r.loop: loop_anchor(r.loop) for r in results}
    rows = [_row(r, history.of(r.loop), anchors[r.loop]) for r in results]
    detailed = [r for r in results if r.verdict in ACTION_VERDICTS]
    figures = render_loop_figures([(r, f"f{k}") for k, r in enumerate(detailed)],
                                  workers=workers)
    loops = []
    for r, svg in zip(detailed, figures):
        h = history.of(r.loop)
        th = tuple((r.evidence or {}).get("bi_thresholds") or (2.2, 2.4))[:2]
        loops.append({"loop": r.loop,
                      "anchor": anchors[r.loop], "description": r.description,
                      "verdict": r.verdict, "vclass": "v-" + r.verdict,
                      "verdict_label": VERDICT_LABELS.get(r.verdict, r.verdict),
                      "rank": "" if r.rank is None else r.rank, "status": h.status,
                      "first": _time(h.first_reported, "%Y-%m-%d") if h.first_reported else "",
                      "sentences": explain(r, h), "action": ACTIONS.get(r.verdict, ""),
                      "figure": Markup(svg) if svg else None, "facts": _facts(r),
                      "quality": _quality_rows(r.quality),
                      "issues": [str(i) for i in (r.quality or {}).get("issues") or []],
                      "problems": [str(p) for p in (r.evidence or {}).get("problems") or []],
                      "reason": r.reason, "history": _history_view(h, th),
                      "episodes": _episodes(r)})
    others = [{"loop": r.loop, "anchor": anchors[r.loop], "description": r.description,
               "verdict": r.verdict, "vclass": "v-" + r.verdict,
               "verdict_label": VERDICT_LABELS.get(r.verdict, r.verdict),
               "reason": r.reason,
               "issues": [str(i) for i in (r.quality or {}).get("issues") or []],
               "problems": [str(p) for p in (r.evidence or {}).get("problems") or []]}
              for r in results if r.verdict not in ACTION_VERDICTS]
    counts: dict[str, int] = {}
    for r in results:
        counts[r.verdict] = counts.get(r.verdict, 0) + 1
    exports = info.get("exports") or []
    if isinstance(exports, (str, os.PathLike)):
        exports = [exports]
    loops_csv = os.fspath(info["loops_csv"]) if info.get("loops_csv") else ""
    plant = info.get("plant") or (Path(loops_csv).resolve().parent.name if loops_csv else "")
    new = history.with_status("new")
    n_action = sum(1 for r in results if r.needs_action)
    prev = history.previous_run
    return env.get_template(TEMPLATE).render(
        css=Markup(_read("report.css")), js=Markup(_read("report.js")),
        run_id=run_id, plant=plant,
        generated=_time(info.get("generated")) if info.get("generated") else "–",
        window=(f"{_time(info.get('window_start'))} to {_time(info.get('window_end'))}"
                if info.get("window_start") else "–"),
        exports=[os.fspath(e) for e in exports], loops_csv=loops_csv,
        config=[(k, "–" if v is None else str(v)) for k, v in (info.get("config") or {}).items()],
        counts=[(v, counts[v], "v-" + v, VERDICT_LABELS.get(v, v))
                for v in RANK_ORDER if v in counts] +
               [(v, n, "v-" + v, v) for v, n in counts.items() if v not in RANK_ORDER],
        n_loops=len(results), n_action=n_action,
        new=[(x, anchors[x]) for x in new if x in anchors],
        repeat=[(x, anchors[x]) for x in history.with_status("repeat")],
        resolved=[(x, anchors.get(x), v) for x, v in history.resolved],
        unassessable=[(x, anchors.get(x), v) for x, v in history.unassessable],
        previous=({"run_id": prev["run_id"], "when": _time(prev["started_at"])}
                  if prev else None),
        history_error=history.error, runs_compared=history.runs_compared,
        rows=rows, loops=loops, others=others,
        verdicts=[(v, VERDICT_LABELS.get(v, v)) for v in RANK_ORDER if v in counts],
        registry_problems=[str(p) for p in info.get("registry_problems") or []],
        ingest_errors=[str(p) for p in info.get("ingest_errors") or []],
        ingest_quarantine=[str(p) for p in info.get("ingest_quarantine") or []],
        run_status=info.get("status") or "complete", status_note=info.get("status_note") or "",
    )


def _as_time(value) -> dt.datetime | None:
    if value is None:
        return None
    if isinstance(value, str):
        value = dt.datetime.fromisoformat(value)
    return value if value.tzinfo is not None else value.replace(tzinfo=_UTC)
