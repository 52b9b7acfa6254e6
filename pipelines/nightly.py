"""
The nightly plant scan as a Prefect flow: ``nightly-scan``.

The flow only orchestrates; every step is a :mod:`valvediag` function::

    (scan lock)     valvediag.store.lock.ScanLock: one scan per store, held by the flow process
    read-registry   valvediag.io.registry.read_loops_csv
    ingest          Store.abort_stale_runs, valvediag.store.ingest.ingest_exports
                    (+ Store.replace_loops)                                   retries 2
    plan            valvediag.scan.plan_loops (+ Store.start_run: status 'running')
    analyse-loops   valvediag.scan.analyse_stored_loops: one mapped task per batch of
                    loops (:func:`loop_batches`), each reading its loops from the store
                    read-only, on a pool of worker processes (Prefect's
                    ProcessPoolTaskRunner, ``processes``, default one per core; threads
                    of the flow process for a handful of loops), or, with ``workers``
                    or ``dask_address``:
    export-partitions  valvediag.store.partitions.export_partitions: each loop's window to Parquet
    analyse-partitions valvediag.store.partitions.load_partition_frames + analyse_loop, one task
                    per batch of loops on Dask (prefect-dask's DaskTaskRunner)
    rank            valvediag.scan.rank_results
    persist         valvediag.scan.persist_results: the only task that writes results
    write-outputs   valvediag.report.outputs.write_outputs: verdicts.json, work_orders.csv, report.html
    artifacts       a table of the ranked loops and a markdown summary linking the report
    finish-run      Store.finish_run: 'complete' only here; 'failed' if any step after plan fails

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

Loops are analysed in batches of up to :data:`BATCH_LOOPS` per task: a
Prefect task run costs 0.1-0.5 s on a worker process (its states go to the
API), about as much as the numerics of one loop-day at 1 s, so one task per
loop would spend half the workers' time on bookkeeping. Batches are small
enough that every worker gets several (the last batch to finish bounds the
stage).

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
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from prefect import flow, get_run_logger, task
from prefect.artifacts import create_markdown_artifact, create_table_artifact
from prefect.cache_policies import NO_CACHE
from prefect.task_runners import ProcessPoolTaskRunner, ThreadPoolTaskRunner
from prefect.utilities.annotations import quote, unmapped

from valvediag.io.exports import expand_paths
from valvediag.io.registry import LoopSpec, read_loops_csv
from valvediag.report.outputs import write_outputs
from valvediag.scan.loop import analyse_loop, analyse_stored_loops
from valvediag.scan.plan import plan_loops
from valvediag.scan.plant import persist_results, rank_results
from valvediag.scan.types import LoopJob, LoopResult, ScanConfig
from valvediag.store.database import VERDICTS, Store, StoreLockedError
from valvediag.store.ingest import ingest_exports
from valvediag.store.lock import ScanLock, owner_id
from valvediag.store.partitions import (
    export_partitions,
    load_partition_frames,
    partition_dir,
    remove_partitions,
)

__all__ = ["nightly_scan", "progress_to", "loop_batches", "FLOW_NAME", "TABLE_ARTIFACT_KEY",
           "REPORT_ARTIFACT_KEY", "TABLE_ARTIFACT_MAX_ROWS"]

FLOW_NAME = "nightly-scan"
TABLE_ARTIFACT_KEY = "valvediag-ranked-loops"
REPORT_ARTIFACT_KEY = "valvediag-report"
#: Threads of the flow process (analysis of fewer than :data:`MIN_LOOPS_FOR_PROCESSES`
#: loops, or ``processes=0``). Prefect's default pool starts a thread per
#: submitted task, so a plant of 1,000 loops held ~1,000 loops in memory at once
#: (9.7 GB measured); Python code holds the GIL, so more threads only cost memory.
ANALYSIS_THREADS = 2 * (os.cpu_count() or 1)
#: Worker processes analysing loops without Dask (default: one per core).
ANALYSIS_PROCESSES = os.cpu_count() or 1
#: Fewer loops than this are analysed on threads of the flow process: starting
#: worker processes (importing numpy, polars, numba kernels) costs seconds.
MIN_LOOPS_FOR_PROCESSES = 16
#: Most loops in one analysis task (see the module notes).
BATCH_LOOPS = 20
#: Batches per worker at least, so that the workers finish close together.
BATCHES_PER_WORKER = 4
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
           partitions: str | None = None) -> dict:
    """Ingest the exports into the store and replace its loop registry.

    Runs left ``running`` by a scan that died are marked ``aborted`` first
    (the flow holds the scan lock, so their scans are gone) and their
    partitions are deleted.

    Returns
    -------
    dict
        ``files, rows_inserted, rows_skipped_duplicate, rows_quarantined,
        errors`` (one line per file that failed or pattern that matched nothing).

    Raises
    ------
    FileNotFoundError
        No export file matches at all.
    """
    logger = get_run_logger()
    files, _ = expand_paths(exports)    # ingest_exports reports the patterns matching nothing
    if not files:
        raise FileNotFoundError(f"no export file matches {', '.join(exports)}")
    _report("ingest", 0, len(files))
    with Store(db) as store:
        _abort_stale(store, db, partitions, logger)
        report = ingest_exports(store, exports, timezone=timezone,
                                progress=lambda done, total, _path: _report("ingest", done, total))
        store.replace_loops(loops)
    logger.info("ingested %d files: %d rows new, %d duplicates skipped, %d quarantined",
                report.files, report.rows_inserted, report.rows_skipped_duplicate,
                report.rows_quarantined)
    for e in report.errors:
        logger.warning("%s", e)
    return {"files": report.files, "rows_inserted": report.rows_inserted,
            "rows_skipped_duplicate": report.rows_skipped_duplicate,
            "rows_quarantined": report.rows_quarantined, "errors": list(report.errors)}


def _abort_stale(store: Store, db: str, partitions: str | None, logger) -> None:
    for run in store.abort_stale_runs():
        logger.warning("run %s of %s was left running by a scan that died (%s); marked aborted",
                       run["run_id"], db, run["owner"] or "owner unknown")
        remove_partitions(partition_dir(db, run["run_id"], partitions))


@task(name="plan", cache_policy=NO_CACHE)
def plan(db: str, loops: list[LoopSpec], config: ScanConfig, exports: list[str]
         ) -> tuple[str, list[LoopJob]]:
    """Plan every loop's window and register the run (status ``running``).

    Returns
    -------
    run_id : str
    jobs : list of LoopJob
    """
    with Store(db) as store:
        jobs = plan_loops(store, loops, config)
        run_id = store.start_run(window_start=min((j.start for j in jobs), default=None),
                                 window_end=max((j.end for j in jobs), default=None),
                                 exports=exports, params=config.to_json(), owner=owner_id())
    get_run_logger().info("run %s: %d loops to analyse", run_id, len(jobs))
    return run_id, jobs


def loop_batches(n_loops: int, workers: int, batch_loops: int = BATCH_LOOPS
                 ) -> list[range]:
    """Split ``n_loops`` loops into consecutive batches for ``workers`` workers.

    Parameters
    ----------
    n_loops : int
        Loops to analyse.
    workers : int
        Workers (processes or Dask workers) sharing them.
    batch_loops : int, default BATCH_LOOPS
        Most loops per batch.

    Returns
    -------
    list of range
        Index ranges into the job list, in order, covering it once; at least
        :data:`BATCHES_PER_WORKER` batches per worker when there are loops
        enough, none longer than ``batch_loops``.
    """
    if n_loops <= 0:
        return []
    per = max(1, min(int(batch_loops), n_loops // (max(int(workers), 1) * BATCHES_PER_WORKER)))
    return [range(a, min(a + per, n_loops)) for a in range(0, n_loops, per)]


def _batched(jobs: list[LoopJob], batches: list[range]) -> dict[str, list]:
    """Mapped task arguments: each batch's jobs and its label (the task run's name)."""
    groups = [jobs[b.start:b.stop] for b in batches]
    labels = [g[0].spec.loop if len(g) == 1 else
              f"{g[0].spec.loop}..{g[-1].spec.loop} ({len(g)} loops)" for g in groups]
    return {"jobs": groups, "label": labels}


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


def _dask_runner(workers: int | None, dask_address: str | None):
    """A DaskTaskRunner: the cluster at ``dask_address``, else a LocalCluster of
    ``workers`` single-threaded worker processes."""
    from prefect_dask import DaskTaskRunner

    if dask_address:
        return DaskTaskRunner(address=dask_address)
    return DaskTaskRunner(cluster_class="distributed.LocalCluster",
                          cluster_kwargs={"n_workers": int(workers), "threads_per_worker": 1,
                                          "processes": True, "dashboard_address": ":0"})


def _dask_workers(runner, default: int) -> int:
    """Workers of the runner's cluster (for batch sizes), else ``default``."""
    try:
        return max(len(runner.client.scheduler_info()["workers"]), 1)
    except Exception:   # noqa: BLE001 - only sizes the batches
        return default


def _collect(futures, batches: list[range], total: int) -> list[LoopResult]:
    """Wait for the batch futures, reporting loops done; results in job order."""
    _report("analyse", 0, total)
    pending, done = list(zip(futures, batches)), 0
    while pending:
        still = [(f, b) for f, b in pending if not f.wrapped_future.done()]
        if len(still) < len(pending):
            done += sum(len(b) for f, b in pending if f.wrapped_future.done())
            _report("analyse", done, total)
        else:
            time.sleep(0.05)
        pending = still
    return [r for f in futures for r in f.result()]


#: Environment of worker processes: one thread each for numba's parallel kernels and
#: the BLAS/OpenMP pools, so that N workers on N cores do not start N x N threads.
WORKER_THREAD_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                     "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@contextlib.contextmanager
def _worker_env() -> Iterator[None]:
    """:data:`WORKER_THREAD_ENV` in ``os.environ`` while worker processes start (they
    inherit it; a variable the user set is kept)."""
    added = {k: v for k, v in WORKER_THREAD_ENV.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


@contextlib.contextmanager
def _api_for_processes() -> Iterator[None]:
    """Let worker processes report to the API this flow reports to.

    Without ``PREFECT_API_URL`` Prefect serves the flow from a temporary
    server it started in a subprocess; a worker process would try to start
    its own (and time out). Its address is handed to the workers here.
    """
    from prefect.settings import PREFECT_API_URL, get_current_settings, temporary_settings

    if get_current_settings().api.url:
        yield
        return
    from prefect.server.api.server import SubprocessASGIServer

    server = SubprocessASGIServer()      # the temporary server of this process
    if not server.running:
        yield
        return
    with temporary_settings(updates={PREFECT_API_URL: server.api_url}):
        yield


def _analyse_here(db: str, jobs: list[LoopJob], config: ScanConfig,
                  processes: int | None) -> list[LoopResult]:
    """Batches of loops on worker processes of this machine, or threads for a few loops."""
    n = ANALYSIS_PROCESSES if processes is None else int(processes)
    if n >= 1 and len(jobs) >= MIN_LOOPS_FOR_PROCESSES:
        batches = loop_batches(len(jobs), n)
        params = {"db": unmapped(db), "config": unmapped(config), **_batched(jobs, batches)}
        with _worker_env(), _api_for_processes(), ProcessPoolTaskRunner(max_workers=n) as runner:
            return _collect(runner.map(analyse, params), batches, len(jobs))
    batches = loop_batches(len(jobs), ANALYSIS_THREADS, batch_loops=1)
    params = {"db": unmapped(db), "config": unmapped(config), **_batched(jobs, batches)}
    return _collect(list(analyse.map(**params)), batches, len(jobs))


def _analyse_on_dask(db: str, run_id: str, jobs: list[LoopJob], config: ScanConfig,
                     workers: int | None, dask_address: str | None,
                     partitions: str | None) -> list[LoopResult]:
    """Export the partitions, then run ``analyse-partitions`` tasks (batches of loops) on Dask."""
    paths = export(db, run_id, jobs, partitions)
    with _worker_env(), _dask_runner(workers, dask_address) as runner:
        batches = loop_batches(len(jobs), _dask_workers(runner, int(workers or 1)))
        params = {"paths": [paths[b.start:b.stop] for b in batches],
                  "config": unmapped(config), **_batched(jobs, batches)}
        return _collect(runner.map(analyse_partitions, params), batches, len(jobs))


@task(name="rank", cache_policy=NO_CACHE)
def rank(results: list[LoopResult]) -> list[LoopResult]:
    """Rank the loops (see :func:`valvediag.scan.rank_results`) and log counts per verdict."""
    ranked = rank_results(results)
    counts = _counts(ranked)
    get_run_logger().info("verdicts: %s", ", ".join(f"{v} {n}" for v, n in counts.items()) or
                          "no loops")
    return ranked


@task(name="persist", retries=2, retry_delay_seconds=10, retry_condition_fn=_transient,
      cache_policy=NO_CACHE)
def persist(db: str, run_id: str, ranked: list[LoopResult]) -> list[str]:
    """Write verdicts and episodes (one transaction); return the loops newly faulty.

    A loop is new when its verdict is a fault (:data:`valvediag.verdicts.FAULT_VERDICTS`)
    and it was not one in the latest complete run before this one.
    """
    with Store(db) as store:
        persist_results(store, run_id, ranked)
        new = store.new_faults(run_id)["loop"].to_list()
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
              new_faults: list[str]) -> None:
    """A table artifact of the ranked loops and a markdown artifact linking the report."""
    rows = [{"rank": r.rank, "loop": r.loop, "verdict": r.verdict,
             "confidence": r.confidence, "severity": round(r.severity, 4),
             "bi": _num(r.bi), "period_s": _num(r.period_s),
             "amplitude_pct_span": _num(r.amplitude_pct_span), "reason": r.reason}
            for r in ranked[:TABLE_ARTIFACT_MAX_ROWS]]
    shown = ("" if len(ranked) <= TABLE_ARTIFACT_MAX_ROWS
             else f" (first {TABLE_ARTIFACT_MAX_ROWS} of {len(ranked)}; the report has all)")
    create_table_artifact(key=TABLE_ARTIFACT_KEY, table=rows,
                          description=f"valvediag run {run_id}: loops by rank{shown}")
    counts = _counts(ranked)
    act = [r for r in ranked if r.rank is not None]
    lines = [f"# valvediag nightly scan {run_id}", "",
             f"**{len(act)} of {len(ranked)} loops need action.** "
             f"[Open the report](file://{paths['report']})", "",
             "| verdict | loops |", "|---|---|",
             *(f"| {v} | {n} |" for v, n in counts.items()), ""]
    if new_faults:
        lines += [f"New since the last complete run: {', '.join(new_faults)}", ""]
    if act:
        lines += ["| rank | loop | verdict | confidence |", "|---|---|---|---|",
                  *(f"| {r.rank} | {r.loop} | {r.verdict} | {r.confidence:.2f} |"
                    for r in act[:20]), ""]
    lines += [f"- report: `{paths['report']}`", f"- work orders: `{paths['work_orders']}`",
              f"- verdicts: `{paths['verdicts']}`"]
    create_markdown_artifact(key=REPORT_ARTIFACT_KEY, markdown="\n".join(lines),
                             description=f"valvediag report of run {run_id}")


@task(name="finish-run", retries=2, retry_delay_seconds=5, retry_condition_fn=_transient,
      cache_policy=NO_CACHE)
def finish(db: str, run_id: str, status: str) -> None:
    """Mark the run ``complete`` or ``failed`` in the store."""
    with Store(db) as store:
        store.finish_run(run_id, status)
    get_run_logger().info("run %s %s", run_id, status)


# ------------------------------------------------------------------------------- flow
def _counts(results: Sequence[LoopResult]) -> dict[str, int]:
    counts = {v: 0 for v in VERDICTS}
    for r in results:
        counts[r.verdict] = counts.get(r.verdict, 0) + 1
    return {v: n for v, n in counts.items() if n}


def _num(x, digits: int = 4):
    return None if x is None or x != x or x in (float("inf"), float("-inf")) else round(x, digits)


@flow(name=FLOW_NAME, log_prints=False,
      task_runner=ThreadPoolTaskRunner(max_workers=ANALYSIS_THREADS))
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
        ProcessPoolTaskRunner); default :data:`ANALYSIS_PROCESSES` (one per
        core). 0 analyses on threads of the flow process (no parallel
        numerics: Python holds the GIL). Fewer than
        :data:`MIN_LOOPS_FOR_PROCESSES` loops always run on threads.

    Returns
    -------
    dict
        ``run_id``, ``loops``, ``counts`` (per verdict), ``new_faults``,
        ``outputs`` (absolute paths), ``ingest`` (counts and errors) and
        ``registry_problems``.

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
    distributed = bool(dask_address) or bool(workers)
    if workers is not None and int(workers) < 0:
        raise ValueError(f"workers must be >= 0, not {workers}")
    if processes is not None and int(processes) < 0:
        raise ValueError(f"processes must be >= 0, not {processes}")
    logger.info("exports %s; loops %s; store %s; out %s; analysis on %s", ", ".join(exports),
                loops_csv, db, out, dask_address or (
                    f"{workers} Dask workers" if workers else
                    "threads" if processes == 0 else
                    f"{ANALYSIS_PROCESSES if processes is None else processes} processes"))
    files, _ = expand_paths(exports)    # before the store or its lock is created
    if not files:
        raise FileNotFoundError(f"no export file matches {', '.join(exports)}")
    Path(db).parent.mkdir(parents=True, exist_ok=True)
    with ScanLock(db, timeout=wait_s):
        return _scan(logger, config, exports, loops_csv, db, out, distributed, workers,
                     dask_address, partitions, processes)


def _scan(logger, config, exports, loops_csv, db, out, distributed, workers, dask_address,
          partitions, processes) -> dict:
    """The flow's steps, run while holding the store's scan lock."""
    specs, problems = read_registry(loops_csv)
    ingested = ingest(db, exports, specs, config.timezone, partitions)
    run_id, jobs = plan(db, specs, config, exports)
    try:
        if distributed:
            results = _analyse_on_dask(db, run_id, jobs, config, workers, dask_address,
                                       partitions)
        else:
            results = _analyse_here(db, jobs, config, processes)
        # quote(): Prefect would otherwise walk every object of every result
        # (about 1 s per task for 1,000 loops) looking for futures
        ranked = rank(quote(results))
        new_faults = persist(db, run_id, quote(ranked))
        run_info = {"db": db, "loops_csv": loops_csv, "exports": exports,
                    "window_start": min((j.start for j in jobs), default=None),
                    "window_end": max((j.end for j in jobs), default=None),
                    "config": config.to_json(), "registry_problems": problems,
                    "ingest_errors": ingested["errors"], "new_faults": new_faults,
                    "generated": dt.datetime.now(dt.timezone.utc)}
        paths = outputs(quote(ranked), out, run_id, run_info)
        artifacts(quote(ranked), paths, run_id, new_faults)
        finish(db, run_id, "complete")
    except BaseException as exc:
        logger.error("run %s failed; marking it failed in %s", run_id, db)
        with Store(db) as store:
            store.finish_run(run_id, "failed", note=" ".join(str(exc).split())[:500] or
                             type(exc).__name__)
        raise
    finally:
        if distributed:
            remove_partitions(partition_dir(db, run_id, partitions))
    return {"run_id": run_id, "loops": len(ranked), "counts": _counts(ranked),
            "new_faults": new_faults, "outputs": paths, "ingest": ingested,
            "registry_problems": problems}
