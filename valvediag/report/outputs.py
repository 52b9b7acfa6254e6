"""
The scan's output files: ``verdicts.json``, ``work_orders.csv``,
``work_orders.json`` and ``report.html``.

:func:`write_outputs` writes them all from ranked
:class:`valvediag.scan.LoopResult` objects:

``verdicts.json``
    ``{"run_id": ..., "loops": [...]}`` with one entry per loop, in rank order,
    holding ``loop, verdict, rank, severity, confidence, process_type, bi,
    period_s, amplitude, reason`` and, for convenience, ``unit,
    amplitude_pct_span, regularity, window_start, window_end, size`` (the
    valve fault's size from the loop model, see
    :func:`valvediag.scan.valve_fault_size`; ``null`` for other verdicts). NaN is
    written as ``null``; numbers are rounded to 6 significant digits.
``work_orders.csv``
    One row per loop that needs action (:data:`valvediag.verdicts.ACTION_VERDICTS`),
    in rank order, with the columns :data:`WORK_ORDER_COLUMNS`: ``loop, unit,
    fault, confidence, severity, recommended_action, report_link, status,
    first_reported, rank, description, reason, size_estimate`` (e.g. ``dead band
    3.1 % OP (model fit 95 %, confidence 0.93)``). ``report_link`` is
    ``report.html#loop-<id>`` (:func:`loop_anchor`). ``status`` is ``new``
    for a problem first found in this run and ``repeat`` for one reported by
    an earlier run and still open (see :mod:`valvediag.report.history`);
    ``first_reported`` is the start of the run that first reported it (ISO
    8601, UTC). A loop appears once, however many runs reported it.
``work_orders.json``
    The same rows as ``{"run_id", "generated", "report", "work_orders": [...]}``
    with ``first_run_id`` and ``open_runs`` (runs that found the open problem)
    added; NaN as ``null``.
``report.html``
    The self-contained morning report (:func:`valvediag.report.render_report`).

With a store (``write_outputs(..., store=db)``) the history across runs comes
from its earlier complete runs; without one every problem is ``new``.
"""
from __future__ import annotations

import contextlib
import csv
import datetime as dt
import json
import math
import shutil
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from valvediag.report.explain import ACTIONS, size_text
from valvediag.report.history import PlantHistory, plant_history, read_history
from valvediag.report.html import REPORTS_DIR, loop_anchor, render_report

from ..plain import spreadsheet_safe, to_plain
from ..scan.types import LoopResult
from ..verdicts import ACTION_VERDICTS

__all__ = ["write_outputs", "write_verdicts_json", "write_work_orders", "write_work_orders_json",
           "write_report_html", "work_orders", "render_report", "loop_anchor",
           "RECOMMENDED_ACTIONS", "WORK_ORDER_COLUMNS", "VERDICT_KEYS", "REPORTS_DIR"]

#: Staging directories of :func:`write_outputs` (inside the output directory)
#: and the age past which one is a killed scan's leftover [s].
STAGING_PREFIX = ".valvediag-staging-"
STAGING_STALE_S = 6 * 3600.0
#: What to do about each verdict that needs action.
RECOMMENDED_ACTIONS = ACTIONS
#: Columns of ``work_orders.csv``, in order.
WORK_ORDER_COLUMNS = ("loop", "unit", "fault", "confidence", "severity", "recommended_action",
                      "report_link", "status", "first_reported", "rank", "description", "reason", "size_estimate")
#: Keys of every ``verdicts.json`` loop entry, in order.
VERDICT_KEYS = ("loop", "verdict", "rank", "severity", "confidence", "process_type", "bi",
                "period_s", "amplitude", "reason", "unit", "amplitude_pct_span", "regularity",
                "window_start", "window_end", "size")
_UTC = dt.timezone.utc


def _sig(x, digits: int = 6):
    """Round a finite float to ``digits`` significant digits; other values pass."""
    if isinstance(x, float) and math.isfinite(x) and x != 0:
        return round(x, digits - 1 - int(math.floor(math.log10(abs(x)))))
    return x


def write_verdicts_json(results: Sequence[LoopResult], path, *, run_id: str,
                        run_info: Mapping | None = None) -> Path:
    """Write ``verdicts.json``.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results, written in this order.
    path : str or path-like
        Output file.
    run_id : str
        The run.
    run_info : mapping, optional
        From a scan: its ``status`` and ``status_note``, and ``ingest_files``
        (per export read this time: rows read, stored, already stored,
        quarantined and the quarantine's reasons), written as ``status``,
        ``status_note`` and ``ingest``.

    Returns
    -------
    pathlib.Path
    """
    loops = []
    for r in results:      # only the keys written: to_json() would clean the evidence too
        d = to_plain({k: getattr(r, k, None) for k in VERDICT_KEYS})
        loops.append({k: _sig(d.get(k)) for k in VERDICT_KEYS})
    doc = {"run_id": run_id}
    info = run_info or {}
    if "status" in info:
        doc.update(status=info["status"], status_note=info.get("status_note") or "")
    if "ingest_files" in info:
        doc["ingest"] = info["ingest_files"]
    doc["loops"] = loops
    path = Path(path)
    path.write_text(json.dumps(to_plain(doc), indent=1, allow_nan=False, ensure_ascii=False)
                    + "\n", encoding="utf-8")
    return path


def _iso(t: dt.datetime | None) -> str:
    return t.astimezone(_UTC).isoformat(timespec="seconds") if t is not None else ""


def work_orders(results: Sequence[LoopResult], history: PlantHistory | None = None, *,
                report_name: str = "report.html", run_id: str = "") -> list[dict]:
    """The work-order rows: one per loop needing action, in rank order.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    history : valvediag.report.history.PlantHistory, optional
        Status (new/repeat) and first report of every loop; default: every
        problem new, first reported by ``run_id`` now.
    report_name : str
        File the ``report_link`` points to.
    run_id : str
        This run (used without ``history``).

    Returns
    -------
    list of dict
        Keys :data:`WORK_ORDER_COLUMNS` plus ``first_run_id`` and
        ``open_runs``; ``confidence`` and ``severity`` as floats.
    """
    if history is None:
        history = plant_history(results, run_id=run_id)
    rows = [r for r in results if r.verdict in ACTION_VERDICTS]
    rows.sort(key=lambda r: (r.rank is None, r.rank or 0, r.loop))
    out = []
    for r in rows:
        h = history.of(r.loop)
        out.append({"loop": r.loop, "unit": r.unit or "", "fault": r.verdict,
                    "confidence": r.confidence, "severity": r.severity,
                    "recommended_action": RECOMMENDED_ACTIONS[r.verdict],
                    "report_link": f"{report_name}#{loop_anchor(r.loop)}",
                    "status": h.status or "new", "first_reported": _iso(h.first_reported),
                    "rank": r.rank, "description": r.description, "reason": r.reason,
                    "size_estimate": size_text(r.size),
                    "first_run_id": h.first_run_id or run_id, "open_runs": h.open_runs or 1})
    return out


def write_work_orders(results: Sequence[LoopResult], path, *, report_name: str = "report.html",
                      history: PlantHistory | None = None, run_id: str = "") -> Path:
    """Write ``work_orders.csv``: one row per loop needing action, in rank order.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    path : str or path-like
        Output file (UTF-8, header row :data:`WORK_ORDER_COLUMNS`).
    report_name : str
        File the ``report_link`` column points to.
    history : valvediag.report.history.PlantHistory, optional
        See :func:`work_orders`.
    run_id : str
        This run.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(WORK_ORDER_COLUMNS)
        for o in work_orders(results, history, report_name=report_name, run_id=run_id):
            # text from loops.csv and the data is escaped: a spreadsheet must
            # not run a description such as =HYPERLINK(...) as a formula
            w.writerow([spreadsheet_safe(o["loop"]), spreadsheet_safe(o["unit"]), o["fault"],
                        f"{o['confidence']:.2f}", f"{o['severity']:.4g}",
                        o["recommended_action"], spreadsheet_safe(o["report_link"]),
                        o["status"], o["first_reported"], "" if o["rank"] is None else o["rank"],
                        spreadsheet_safe(o["description"]), spreadsheet_safe(o["reason"]),
                        o["size_estimate"]])
    return path


def write_work_orders_json(results: Sequence[LoopResult], path, *, run_id: str,
                           report_name: str = "report.html",
                           history: PlantHistory | None = None) -> Path:
    """Write ``work_orders.json`` (the rows of :func:`work_orders`).

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    path : str or path-like
        Output file (UTF-8).
    run_id : str
        This run.
    report_name : str
        File the ``report_link`` points to.
    history : valvediag.report.history.PlantHistory, optional
        See :func:`work_orders`.

    Returns
    -------
    pathlib.Path
    """
    rows = [{k: (_sig(v) if isinstance(v, float) else v) for k, v in o.items()}
            for o in work_orders(results, history, report_name=report_name, run_id=run_id)]
    doc = {"run_id": run_id,
           "generated": _iso(history.started_at) if history is not None else "",
           "report": report_name, "work_orders": to_plain(rows)}
    path = Path(path)
    path.write_text(json.dumps(doc, indent=1, allow_nan=False, ensure_ascii=False) + "\n",
                    encoding="utf-8")
    return path


def write_report_html(results: Sequence[LoopResult], path, *, run_id: str,
                      run_info: Mapping | None = None, history: PlantHistory | None = None,
                      workers: int | None = None) -> Path:
    """Write ``report.html`` (see :func:`valvediag.report.render_report`).

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results.
    path : str or path-like
        Output file (UTF-8).
    run_id : str
        The run.
    run_info : mapping, optional
        See :func:`valvediag.report.render_report`.
    history : valvediag.report.history.PlantHistory, optional
        This run compared with the earlier ones.
    workers : int, optional
        Processes drawing the figures.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    text = render_report(results, run_id=run_id, run_info=run_info, history=history,
                         workers=workers)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path


def _started(run_info: Mapping) -> dt.datetime | None:
    t = run_info.get("generated")
    if isinstance(t, str):
        t = dt.datetime.fromisoformat(t)
    if isinstance(t, dt.datetime):
        return t if t.tzinfo is not None else t.replace(tzinfo=_UTC)
    return None


def write_outputs(results: Sequence[LoopResult], out_dir, *, run_id: str,
                  run_info: Mapping | None = None, store=None, history_runs: int = 60,
                  workers: int | None = None) -> dict[str, Path]:
    """Write ``verdicts.json``, ``work_orders.csv``, ``work_orders.json`` and ``report.html``.

    Parameters
    ----------
    results : sequence of LoopResult
        Ranked results (:func:`valvediag.scan.rank_results`).
    out_dir : str or path-like
        Directory, created when missing; existing files of these names are
        replaced, as a set: the four are written into a staging directory
        inside ``out_dir`` and moved in once all are complete, so a failure
        (a full disk, an error in a figure) leaves the previous run's files
        as they were.
    run_id : str
        The run.
    run_info : mapping, optional
        Header of the report (see :func:`valvediag.report.render_report`).
    store : str, path-like or valvediag.store.Store, optional
        The store holding the earlier runs: new/repeat status of every work
        order, what was resolved since the last run, each loop's history.
        Default: ``run_info["db"]`` when given (the scan and the nightly flow
        put it there). A path is opened read-only for the call. When it
        cannot be read the outputs are written without history and the
        report says why.
    history_runs : int
        Earlier complete runs compared [-].
    workers : int, optional
        Processes drawing the report's figures (default: automatic).

    Returns
    -------
    dict of str to pathlib.Path
        ``verdicts``, ``work_orders``, ``work_orders_json`` and ``report``.
    """
    info = dict(run_info or {})
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if store is None:
        store = info.get("db")
    if store is not None:
        history = read_history(store, results, run_id=run_id, started_at=_started(info),
                               max_runs=history_runs)
    else:
        history = plant_history(results, run_id=run_id, started_at=_started(info))
    _remove_stale_staging(out)
    staging = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=out))
    try:
        written = {
            "verdicts": write_verdicts_json(results, staging / "verdicts.json", run_id=run_id,
                                            run_info=info),
            "work_orders": write_work_orders(results, staging / "work_orders.csv",
                                             history=history, run_id=run_id),
            "work_orders_json": write_work_orders_json(results, staging / "work_orders.json",
                                                       run_id=run_id, history=history),
            "report": write_report_html(results, staging / "report.html", run_id=run_id,
                                        run_info=info, history=history, workers=workers),
        }
        # every file is complete before the first is swapped in: a failure above
        # leaves the previous run's outputs as they were, as a set
        for key, path in written.items():
            written[key] = path.replace(out / path.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return written


def _remove_stale_staging(out: Path, age_s: float = STAGING_STALE_S) -> None:
    """Delete staging directories that a killed scan left in ``out``."""
    now = time.time()
    for d in out.glob(STAGING_PREFIX + "*"):
        with contextlib.suppress(OSError):
            if d.is_dir() and now - d.stat().st_mtime > age_s:
                shutil.rmtree(d, ignore_errors=True)
