"""
The plant scan, in the order it runs.

* :mod:`~valvediag.scan.types`: the scan's parameters and results
  (:class:`ScanConfig`, :class:`LoopJob`, :class:`LoopResult`, ...).
* :mod:`~valvediag.scan.plan`: every loop's window (:func:`plan_loops`).
* :mod:`~valvediag.scan.loop`: one loop, from its samples to its verdict
  (:func:`analyse_loop`).
* :mod:`~valvediag.scan.plant`: ranking and storing the loops' verdicts.
* :mod:`~valvediag.scan.run`: a whole scan, begun and concluded by the same
  steps whichever entry point runs it (:func:`~valvediag.scan.run.run_scan`).

The run module sits above the report (it writes the outputs), so it is not
imported here: ``from valvediag.scan.run import run_scan``.
"""
from .loop import analyse_loop, analyse_stored_loops, load_loop_frames, valve_fault_size
from .plan import plan_loops
from .plant import persist_results, rank_results, severity
from .types import (
           Episode,
           LoopDetail,
           LoopJob,
           LoopResult,
           LoopTrend,
           ScanConfig,
           ScanSummary,
)

__all__ = ["ScanConfig", "LoopJob", "Episode", "LoopTrend", "LoopDetail", "LoopResult",
           "ScanSummary", "plan_loops", "analyse_loop", "analyse_stored_loops", "load_loop_frames",
           "valve_fault_size", "rank_results", "persist_results", "severity"]
