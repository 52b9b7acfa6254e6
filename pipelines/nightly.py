"""
The nightly plant scan as a Prefect flow: ``nightly-scan``.

The flow runs the scan's one sequence of steps
(:func:`valvediag.scan.run.execute_scan`) with each step wrapped as a task::

    (scan lock)     taken by execute_scan for the whole run
    read-registry   valvediag.io.registry.read_loops_csv
    ingest          valvediag.scan.run.ingest_step: runs of dead scans marked
                    aborted, exports ingested, registry stored          retries 2
    plan            valvediag.scan.run.plan_run (run registered 'running')
    analyse-loops   valvediag.scan.loop.analyse_stored_loops: one mapped task per batch of
                    loops, each reading its loops from the store read-only, on worker
                    processes (one per core; threads of the flow process for a handful
                    of loops), or, with ``workers`` or ``dask_address``:
    export-partitions  valvediag.store.partitions.export_partitions
    analyse-partitions each batch's Parquet partitions analysed on Dask
    rank            valvediag.scan.plant.rank_results
    persist         valvediag.scan.run.persist_run: the only task that writes results
    write-outputs   valvediag.report.outputs.write_outputs
    artifacts       a table of the ranked loops and a markdown summary linking the report
                    (valvediag.report.artifacts)
    finish-run      valvediag.scan.run.finish_run: 'complete' only here; a failure after
                    the plan marks the run 'failed' with a one-line note

Where the analysis runs (threads, processes, Dask) is :mod:`valvediag.pipelines.runners`.
The deployment ``nightly-scan/nightly`` (``prefect.yaml``, ``make serve``) and
the ``valvediag scan`` command run this same flow; the command runs it
in-process and shows progress through :func:`progress_to`.

Notes
-----
DuckDB lets one process hold the store for writing. Every task opens the
store, works and closes it; only ``ingest``, ``plan``, ``persist`` and
``finish-run`` write, one at a time, in the flow's process. Without Dask the
mapped analyses run in worker processes, each batch reading its loops with
its own read-only connection while no process writes. With Dask the workers
never open the DuckDB file: they read the Parquet partitions that
``export-partitions`` wrote (on a real cluster, ``partitions`` must be a
directory every worker can read) and return their results to the flow.

Loops are analysed in batches of up to
:data:`~valvediag.pipelines.runners.BATCH_LOOPS` per task: a Prefect task run
costs 0.1-0.5 s on a worker process (its states go to the API), about as much
as the numerics of one loop-day at 1 s, so one task per loop would spend half
the workers' time on bookkeeping.

Faults: the flow holds the store's scan lock for the whole run, so a second
scan on the same store waits ``wait_s`` seconds and then fails with a
one-line :class:`~valvediag.store.lock.ScanLockedError`. A scan whose process
died (SIGKILL, crash) releases the lock with its process; the next scan
marks its run ``aborted`` and deletes its partitions. An ingest interrupted
midway is completed by the next one (files are recorded only once fully
written, and samples are never duplicated). A Dask worker that dies during
a loop is replaced by its nanny and Dask runs the loop again on a live
worker (up to ``distributed.scheduler.allowed-failures`` times).
"""
from __future__ import annotations

import contextlib
import datetime as dt
import os
from collections.abc import Callable, Iterator
from pathlib import Path

from prefect import flow, get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact
from prefect.cache_policies import NO_CACHE
from prefect.task_runners import ThreadPoolTaskRunner
from prefect.utilities.annotations import quote, unmapped
from valvediag.pipelines import runners

from valvediag.io.exports import expand_paths
from valvediag.io.registry import LoopSpec, read_loops_csv
from valvediag.report.artifacts import ranked_table, run_summary_markdown
from valvediag.report.outputs import write_outputs
from valvediag.scan.loop import analyse_loop, analyse_stored_loops
from valvediag.scan.plant import rank_results
from valvediag.scan.run import (
    ScanSteps,
    discard_partitions,
    execute_scan,
    fail_run,
    finish_run,
    ingest_step,
    persist_run,
    plan_run,
)
from valvediag.scan.types import LoopJob, LoopResult, ScanConfig
from valvediag.store.database import Store, StoreLockedError
from valvediag.store.partitions import (
    export_partitions,
    load_partition_frames,
    partition_dir,
)
from valvediag.verdicts import count_verdicts

__all__ = ["nightly_scan", "progress_to", "FLOW_NAME", "TABLE_ARTIFACT_KEY",
           "REPORT_ARTIFACT_KEY", "TABLE_ARTIFACT_MAX_ROWS"]

FLOW_NAME = "nightly-scan"
TABLE_ARTIFACT_KEY = "valvediag-ranked-loops"
REPORT_ARTIFACT_KEY = "valvediag-report"
#: Rows of the ranked-loops table artifact; the report has every loop.
TABLE_ARTIFACT_MAX_ROWS = 1000

# --------------------------------------------------------------------------- progress
_progress: Callable[[str, int, int], object] | None = None


@contextlib.contextmanager
def progress_to(callback: Callable[[str, int, int], object] | None) -> Iterator[None]:
    """Report progress of flows run in this process to ``callback(stage, done, total)``.

    Parameters
    ----------
    callback : callable or None
        Called with ``stage`` ``"ingest"`` (files) or ``"analyse"`` (loops),
        from the flow's own thread. None reports nothing.
    """
    global _progress
    previous, _progress = _progress, callback
    try:
        yield
    finally:
        _progress = previous


def _report(stage: str, done: int, total: int) -> None:
    if _progress is not None:
        _progress(stage, done, total)


# ------------------------------------------------------------------------------ tasks
def _transient(task, task_run, state) -> bool:
    """Retry condition: only errors that may pass (the store locked by another process,
    I/O errors other than a missing file), not bad input or a bug."""
    exc = state.data
    return isinstance(exc, (StoreLockedError, OSError)) and not isinstance(exc, FileNotFoundError)


@task(name="read-registry", cache_policy=NO_CACHE)
def read_registry(loops_csv: str) -> tuple[list[LoopSpec], list[str]]:
    """Read ``loops.csv`` and log each problem of it (see :func:`read_loops_csv`)."""
    loops, problems = read_loops_csv(loops_csv)
    logger = get_run_logger()
    logger.info("loops.csv %s: %d loops, %d problems", loops_csv, len(loops), len(problems))
    for p in problems:
        logger.warning("%s", p)
    return loops, problems


@task(name="ingest", retries=2, retry_delay_seconds=10, retry_condition_fn=_transient,
      cache_policy=NO_CACHE)
def ingest(db: str, exports: list[str], loops: list[LoopSpec], timezone: str | None,
           partitions: str | None = None, progress=None):
    """Ingest the exports (see :func:`valvediag.scan.run.ingest_step`) and log what happened."""
    logger = get_run_logger()
    report, aborted = ingest_step(db, exports, loops, timezone, partitions, progress)
    for run in aborted:
        logger.warning("run %s of %s was left running by a scan that died (%s); marked aborted",
                       run["run_id"], db, run["owner"] or "owner unknown")
    logger.info("ingested %d files: %d rows new, %d duplicates skipped, %d quarantined",
                report.files, report.rows_inserted, report.rows_skipped_duplicate,
                report.rows_quarantined)
    for e in report.errors:
        logger.warning("%s", e)
    return report, aborted


@task(name="plan", cache_policy=NO_CACHE)
def plan(db: str, loops: list[LoopSpec], config: ScanConfig, exports: list[str]
         ) -> tuple[str, list[LoopJob]]:
    """Plan every loop's window and register the run (see :func:`valvediag.scan.run.plan_run`)."""
    run_id, jobs = plan_run(db, loops, config, exports)
    get_run_logger().info("run %s: %d loops to analyse", run_id, len(jobs))
    return run_id, jobs


@task(name="analyse-loops", retries=1, retry_delay_seconds=2, retry_condition_fn=_transient,
      cache_policy=NO_CACHE, task_run_name="analyse-{label}")
def analyse(db: str, jobs: list[LoopJob], config: ScanConfig, label: str = "") -> list[LoopResult]:
    """A batch of loops: read them from the store (read-only) and diagnose each."""
    return analyse_stored_loops(db, jobs, config)


@task(name="export-partitions", retries=1, retry_delay_seconds=5,
      retry_condition_fn=_transient, cache_policy=NO_CACHE)
def export(db: str, run_id: str, jobs: list[LoopJob], partitions: str | None) -> list[str]:
    """Export every loop's window to Parquet for the Dask workers; one path per job."""
    out = partition_dir(db, run_id, partitions)
    with Store(db, read_only=True) as store:
        paths = export_partitions(store, jobs, out)
    get_run_logger().info("exported %d loops to %s", len(jobs), out)
    return paths


@task(name="analyse-partitions", retries=1, retry_delay_seconds=2, cache_policy=NO_CACHE,
      task_run_name="analyse-{label}")
def analyse_partitions(paths: list[str], jobs: list[LoopJob], config: ScanConfig,
                       label: str = "") -> list[LoopResult]:
    """A batch of loops on a Dask worker: read each one's Parquet partition and diagnose it."""
    return [analyse_loop(job, load_partition_frames(path, job), config)
            for path, job in zip(paths, jobs)]


@task(name="rank", cache_policy=NO_CACHE)
def rank(results: list[LoopResult]) -> list[LoopResult]:
    """Rank the loops (see :func:`valvediag.scan.plant.rank_results`) and log counts."""
    ranked = rank_results(results)
    counts = {v: n for v, n in count_verdicts(r.verdict for r in ranked).items() if n}
    get_run_logger().info("verdicts: %s", ", ".join(f"{v} {n}" for v, n in counts.items()) or
                          "no loops")
    return ranked


@task(name="persist", retries=2, retry_delay_seconds=10, retry_condition_fn=_transient,
      cache_policy=NO_CACHE)
def persist(db: str, run_id: str, ranked: list[LoopResult]) -> list[str]:
    """Store verdicts and episodes; return the new faults (:func:`valvediag.scan.run.persist_run`)."""
    new = persist_run(db, run_id, ranked)
    get_run_logger().info("stored %d verdicts of run %s; new faults: %s", len(ranked), run_id,
                          ", ".join(new) or "none")
    return new


@task(name="write-outputs", retries=1, retry_condition_fn=_transient, cache_policy=NO_CACHE)
def outputs(ranked: list[LoopResult], out: str, run_id: str, run_info: dict) -> dict[str, str]:
    """Write ``verdicts.json``, ``work_orders.csv`` and ``report.html`` into ``out``."""
    paths = {k: str(Path(p).resolve()) for k, p in
             write_outputs(ranked, out, run_id=run_id, run_info=run_info).items()}
    get_run_logger().info("report %s", paths["report"])
    return paths


@task(name="artifacts", cache_policy=NO_CACHE)
def artifacts(ranked: list[LoopResult], paths: dict[str, str], run_id: str,
              new_faults: list[str], status: str = "complete",
              problems: list[str] | None = None) -> None:
    """A table artifact of the ranked loops and a markdown artifact linking the report
    (with the run's status and the problems of its input)."""
    rows, caption = ranked_table(ranked, TABLE_ARTIFACT_MAX_ROWS)
    create_table_artifact(key=TABLE_ARTIFACT_KEY, table=rows,
                          description=f"valvediag run {run_id}: {caption}")
    create_markdown_artifact(key=REPORT_ARTIFACT_KEY,
                             markdown=run_summary_markdown(ranked, paths, run_id, new_faults,
                                                           status=status,
                                                           problems=problems or ()),
                             description=f"valvediag report of run {run_id} ({status})")


@task(name="finish-run", retries=2, retry_delay_seconds=5, retry_condition_fn=_transient,
      cache_policy=NO_CACHE)
def finish(db: str, run_id: str, status: str = "complete", note: str | None = None) -> None:
    """Mark the run ``complete`` or ``partial`` in the store."""
    finish_run(db, run_id, status, note)
    if status == "complete":
        get_run_logger().info("run %s complete", run_id)
    else:
        get_run_logger().warning("run %s %s: %s", run_id, status, note)


class FlowSteps(ScanSteps):
    """The scan's steps as this flow's tasks, the analysis on processes or Dask.

    Large arguments go through ``quote()``: Prefect would otherwise walk every
    object of every result (about 1 s per task for 1,000 loops) looking for
    futures.
    """

    read_registry = staticmethod(read_registry)
    plan = staticmethod(plan)
    rank = staticmethod(lambda results: rank(quote(results)))
    persist = staticmethod(lambda db, run_id, ranked: persist(db, run_id, quote(ranked)))
    finish = staticmethod(finish)

    def __init__(self, processes: int | None, workers: int | None, dask_address: str | None,
                 partitions: str | None):
        super().__init__(_report)
        self.processes, self.workers = processes, workers
        self.dask_address, self.partitions = dask_address, partitions
        self.distributed = bool(dask_address) or bool(workers)

    def ingest(self, db, exports, loops, timezone, partitions, progress):
        return ingest(db, exports, loops, timezone, partitions, quote(progress))

    def analyse(self, db, run_id, jobs, config):
        progress = self.report("analyse")
        if self.distributed:
            paths = export(db, run_id, jobs, self.partitions)
            return runners.map_on_dask(analyse_partitions, jobs, paths,
                                       {"config": unmapped(config)}, self.workers,
                                       self.dask_address, progress)
        n = runners.ANALYSIS_PROCESSES if self.processes is None else int(self.processes)
        if n >= 1 and len(jobs) >= runners.MIN_LOOPS_FOR_PROCESSES:
            batches = runners.loop_batches(len(jobs), n)
            params = {"db": unmapped(db), "config": unmapped(config),
                      **runners.batch_arguments(jobs, batches)}
            return runners.map_on_processes(analyse, params, batches, len(jobs), n, progress)
        batches = runners.loop_batches(len(jobs), runners.ANALYSIS_THREADS, batch_loops=1)
        params = {"db": unmapped(db), "config": unmapped(config),
                  **runners.batch_arguments(jobs, batches)}
        return runners.map_on_threads(analyse, params, batches, len(jobs), progress)

    def outputs(self, ranked, out, run_id, info):
        return outputs(quote(ranked), out, run_id, info)

    def publish(self, ranked, paths, run_id, new_faults, info):
        artifacts(quote(ranked), paths, run_id, new_faults, info.get("status", "complete"),
                  list(info.get("ingest_errors", ())) + [
                      f"rows quarantined: {q}" for q in info.get("ingest_quarantine", ())])

    def fail(self, db, run_id, exc):
        get_run_logger().error("run %s failed; marking it failed in %s", run_id, db)
        fail_run(db, run_id, exc)

    def cleanup(self, db, run_id):
        if self.distributed:
            discard_partitions(db, run_id, self.partitions)


# ------------------------------------------------------------------------------- flow
@flow(name=FLOW_NAME, log_prints=False,
      task_runner=ThreadPoolTaskRunner(max_workers=runners.ANALYSIS_THREADS))
def nightly_scan(exports: str | list[str] = "data/exports", loops: str = "data/loops.csv",
                 db: str = "data/valvediag.duckdb", out: str = "out/nightly",
                 window_hours: float = 24.0, method: str = "robust", min_cycles: float = 3.0,
                 timezone: str | None = None, end: dt.datetime | None = None,
                 max_gap_s: float | None = None, workers: int | None = None,
                 dask_address: str | None = None, partitions: str | None = None,
                 wait_s: float = 0.0, processes: int | None = None) -> dict:
    """Scan every loop of the registry and write the maintenance report.

    Parameters
    ----------
    exports : str or list of str
        Historian export files, directories or globs. Files ingested before
        (same content) are skipped.
    loops : str
        The loop registry ``loops.csv``.
    db : str
        The DuckDB store (created when missing); keeps the history of runs.
    out : str
        Output directory for ``verdicts.json``, ``work_orders.csv`` and
        ``report.html``.
    window_hours : float
        Analysis window [h], ending at each loop's latest sample (or ``end``).
    method : {'robust', 'paper'}
        Backlash Index estimator.
    min_cycles : float
        Fewest oscillation cycles for a verdict on the valve [-].
    timezone : str, optional
        IANA zone of naive time stamps in the exports.
    end : datetime, optional
        Common end of every loop's window (with a UTC offset).
    max_gap_s : float, optional
        Longest gap bridged by interpolation [s]; default per tag.
    workers : int, optional
        Analyse on a local Dask cluster of this many single-threaded worker
        processes. Default (None or 0): worker processes of the flow
        (``processes``), without Dask.
    dask_address : str, optional
        Analyse on the Dask cluster whose scheduler is at this address
        (``tcp://host:8786``); overrides ``workers``. Its workers need
        valvediag installed and read access to ``partitions``.
    partitions : str, optional
        Directory for the Parquet partitions the Dask workers read (a run
        gets a subdirectory, deleted at its end). Default
        ``<db>.partitions`` beside the store.
    wait_s : float, default 0
        Longest wait for another scan of the same store to finish [s]; then
        the flow fails with a one-line error.
    processes : int, optional
        Worker processes analysing the loops without Dask (Prefect's
        ProcessPoolTaskRunner); default
        :data:`~valvediag.pipelines.runners.ANALYSIS_PROCESSES` (one per
        core). 0 analyses on threads of the flow process (no parallel
        numerics: Python holds the GIL). Fewer than
        :data:`~valvediag.pipelines.runners.MIN_LOOPS_FOR_PROCESSES` loops
        always run on threads.

    Returns
    -------
    dict
        :meth:`valvediag.scan.ScanSummary.to_json`: ``run_id``, ``loops``,
        ``counts`` (per verdict), ``new_faults``, ``outputs`` (absolute
        paths), ``ingest`` (counts and errors) and ``registry_problems``.

    Notes
    -----
    Relative paths are taken from the working directory: the repository
    checkout for a deployment run (its pull step goes there).
    """
    logger = get_run_logger()
    config = ScanConfig(window_hours=window_hours, end=end, method=method,
                        min_cycles=min_cycles, timezone=timezone, max_gap_s=max_gap_s)
    exports = [exports] if isinstance(exports, str) else list(exports)
    db, out, loops_csv = (os.path.abspath(p) for p in (db, out, loops))
    partitions = os.path.abspath(partitions) if partitions else None
    if workers is not None and int(workers) < 0:
        raise ValueError(f"workers must be >= 0, not {workers}")
    if processes is not None and int(processes) < 0:
        raise ValueError(f"processes must be >= 0, not {processes}")
    logger.info("exports %s; loops %s; store %s; out %s; analysis on %s", ", ".join(exports),
                loops_csv, db, out, dask_address or (
                    f"{workers} Dask workers" if workers else
                    "threads" if processes == 0 else
                    f"{runners.ANALYSIS_PROCESSES if processes is None else processes} "
                    "processes"))
    files, _ = expand_paths(exports)    # before the store or its lock is created
    if not files:
        raise FileNotFoundError(f"no export file matches {', '.join(exports)}")
    Path(db).parent.mkdir(parents=True, exist_ok=True)
    steps = FlowSteps(processes, workers, dask_address, partitions)
    summary = execute_scan(exports, loops_csv, db, out, config, steps=steps, wait_s=wait_s,
                           partitions=partitions)
    return summary.to_json()
