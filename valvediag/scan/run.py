"""
A whole plant scan, from the historian exports to the report.
"""
from __future__ import annotations

import datetime as dt
import os
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover

    pass

from .loop import analyse_loop, load_loop_frames
from .plan import plan_loops
from .plant import persist_results, rank_results
from .types import _UTC, ScanConfig, ScanSummary


def run_scan(exports, loops_csv, db, out_dir, *, config: ScanConfig = ScanConfig(),
             progress: Callable[[int, int], object] | None = None) -> ScanSummary:
    """The whole nightly scan in one process, without Prefect.

    Parameters
    ----------
    exports : str, path-like or iterable of them
        Historian export files, directories or globs. Files ingested before
        (same content) are skipped; samples already stored are never
        duplicated.
    loops_csv : str or path-like
        The loop registry; it replaces the stored registry.
    db : str or path-like
        DuckDB store (created when missing); keeps the history of runs.
    out_dir : str or path-like
        Where ``verdicts.json``, ``work_orders.csv`` and ``report.html`` go.
    config : ScanConfig
        Scan parameters.
    progress : callable(done, total), optional
        Called after each loop analysed.

    Returns
    -------
    ScanSummary

    Raises
    ------
    valvediag.io.registry.RegistryError
        ``loops.csv`` cannot be read at all (one line naming the file).

    Notes
    -----
    An export that cannot be read (unknown columns, say) is reported in
    ``ScanSummary.errors`` with a one-line message naming the file; the
    other files are ingested and the scan goes on. Problems in single rows of
    ``loops.csv`` are in ``registry_problems`` and the loop's verdict says
    why it could not be analysed. The run is recorded ``complete`` in the
    store, or ``failed`` (and the exception re-raised) if the analysis fails.
    """
    from ..io.registry import read_loops_csv
    from ..report.outputs import write_outputs
    from ..store.database import Store
    from ..store.ingest import ingest_exports

    loops, problems = read_loops_csv(loops_csv)
    if isinstance(exports, (str, os.PathLike)):
        exports = [exports]
    exports = [os.fspath(e) for e in exports]
    with Store(db) as store:
        t0 = time.perf_counter()
        report = ingest_exports(store, exports, timezone=config.timezone)
        ingest_s = time.perf_counter() - t0
        store.replace_loops(loops)
        jobs = plan_loops(store, loops, config)
        w0 = min((j.start for j in jobs), default=None)
        w1 = max((j.end for j in jobs), default=None)
        run_id = store.start_run(window_start=w0, window_end=w1, exports=exports,
                                 params=config.to_json())
        t1 = time.perf_counter()
        try:
            results = []
            for i, job in enumerate(jobs, 1):
                results.append(analyse_loop(job, load_loop_frames(store, job), config))
                if progress is not None:
                    progress(i, len(jobs))
            results = rank_results(results)
            persist_results(store, run_id, results)
        except BaseException:
            store.finish_run(run_id, "failed")
            raise
        store.finish_run(run_id, "complete")
        analysis_s = time.perf_counter() - t1
        new = tuple(store.new_since_last_run()["loop"].to_list())
    run_info = {"db": os.fspath(db), "loops_csv": os.fspath(loops_csv), "exports": exports,
                "window_start": w0, "window_end": w1, "config": config.to_json(),
                "registry_problems": list(problems), "ingest_errors": list(report.errors),
                "new_faults": list(new), "generated": dt.datetime.now(_UTC)}
    outputs = write_outputs(results, out_dir, run_id=run_id, run_info=run_info)
    return ScanSummary(run_id=run_id, results=tuple(results), outputs=outputs, ingest=report,
                       registry_problems=tuple(problems), new_faults=new, ingest_s=ingest_s,
                       analysis_s=analysis_s)
