"""
Where the nightly flow's analysis runs: threads, worker processes or Dask, and
what those workers need (their thread settings, the Prefect API to report to).

The flow (:mod:`valvediag.pipelines.nightly`) hands its analysis task and the
batches of loops to :func:`map_on_threads`, :func:`map_on_processes` or
:func:`map_on_dask`; each waits for the batches, reporting loops done, and
returns the results in job order.
"""
from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence

from prefect.task_runners import ProcessPoolTaskRunner

__all__ = ["loop_batches", "batch_arguments", "map_on_threads", "map_on_processes",
           "map_on_dask", "dask_runner", "temporary_api", "WORKER_THREAD_ENV",
           "ANALYSIS_THREADS", "ANALYSIS_PROCESSES", "MIN_LOOPS_FOR_PROCESSES", "BATCH_LOOPS",
           "BATCHES_PER_WORKER"]

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
#: Most loops in one analysis task (see :mod:`valvediag.pipelines.nightly`).
BATCH_LOOPS = 20
#: Batches per worker at least, so that the workers finish close together.
BATCHES_PER_WORKER = 4
#: Environment of worker processes: one thread each for numba's parallel kernels and
#: the BLAS/OpenMP pools, so that N workers on N cores do not start N x N threads.
WORKER_THREAD_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                     "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

Progress = Callable[[int, int], object]


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


def batch_arguments(jobs: Sequence, batches: Sequence[range]) -> dict[str, list]:
    """Mapped task arguments: each batch's jobs and its label (the task run's name).

    Parameters
    ----------
    jobs : sequence of valvediag.scan.LoopJob
    batches : sequence of range
        From :func:`loop_batches`.

    Returns
    -------
    dict
        ``jobs`` (one list per batch) and ``label`` (``LIC101`` or
        ``LIC101..LIC120 (20 loops)``).
    """
    groups = [list(jobs[b.start:b.stop]) for b in batches]
    labels = [g[0].spec.loop if len(g) == 1 else
              f"{g[0].spec.loop}..{g[-1].spec.loop} ({len(g)} loops)" for g in groups]
    return {"jobs": groups, "label": labels}


def _collect(futures, batches: Sequence[range], total: int, progress: Progress | None) -> list:
    """Wait for the batch futures, reporting loops done; results in job order."""
    if progress is not None:
        progress(0, total)
    pending, done = list(zip(futures, batches)), 0
    while pending:
        still = [(f, b) for f, b in pending if not f.wrapped_future.done()]
        if len(still) < len(pending):
            done += sum(len(b) for f, b in pending if f.wrapped_future.done())
            if progress is not None:
                progress(done, total)
        else:
            time.sleep(0.05)
        pending = still
    return [r for f in futures for r in f.result()]


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
    from prefect.settings import (
        PREFECT_API_URL,
        get_current_settings,
        temporary_settings,
    )

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


def map_on_threads(task, params: dict, batches: Sequence[range], total: int,
                   progress: Progress | None = None) -> list:
    """Run ``task`` over the batches on the flow's own thread pool.

    Parameters
    ----------
    task : prefect.Task
    params : dict
        Mapped arguments (lists, one item per batch) and ``unmapped`` ones.
    batches : sequence of range
    total : int
        Loops in all.
    progress : callable(done, total), optional

    Returns
    -------
    list
        The batches' results, concatenated in order.
    """
    return _collect(list(task.map(**params)), batches, total, progress)


def map_on_processes(task, params: dict, batches: Sequence[range], total: int, workers: int,
                     progress: Progress | None = None) -> list:
    """Run ``task`` over the batches on ``workers`` worker processes of this machine.

    Parameters
    ----------
    task : prefect.Task
    params : dict
    batches : sequence of range
    total : int
    workers : int
        Processes (Prefect's ``ProcessPoolTaskRunner``), each with one numba
        and BLAS thread (:data:`WORKER_THREAD_ENV`).
    progress : callable(done, total), optional

    Returns
    -------
    list
    """
    with _worker_env(), _api_for_processes(), ProcessPoolTaskRunner(max_workers=workers) as r:
        return _collect(r.map(task, params), batches, total, progress)


def dask_runner(workers: int | None, dask_address: str | None):
    """A DaskTaskRunner: the cluster at ``dask_address``, else a LocalCluster of
    ``workers`` single-threaded worker processes.

    Parameters
    ----------
    workers : int or None
    dask_address : str or None
        ``tcp://host:8786``.

    Returns
    -------
    prefect_dask.DaskTaskRunner
    """
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


def map_on_dask(task, jobs: Sequence, paths: Sequence[str], unmapped_params: dict,
                workers: int | None, dask_address: str | None,
                progress: Progress | None = None) -> list:
    """Run ``task`` over batches of loops on Dask (each job reads its Parquet partition).

    Parameters
    ----------
    task : prefect.Task
        Called with ``paths``, ``jobs``, ``label`` per batch plus ``unmapped_params``.
    jobs : sequence of valvediag.scan.LoopJob
    paths : sequence of str
        One partition per job.
    unmapped_params : dict
        Arguments shared by every batch (wrapped in ``prefect.unmapped``).
    workers : int or None
        Local cluster size (when no address).
    dask_address : str or None
    progress : callable(done, total), optional

    Returns
    -------
    list
    """
    with _worker_env(), dask_runner(workers, dask_address) as runner:
        batches = loop_batches(len(jobs), _dask_workers(runner, int(workers or 1)))
        params = {"paths": [list(paths[b.start:b.stop]) for b in batches],
                  **unmapped_params, **batch_arguments(jobs, batches)}
        return _collect(runner.map(task, params), batches, len(jobs), progress)


#: The watchdog of :func:`temporary_api`: argv ``parent-pid server-pid``. It
#: stops the server (SIGTERM, then SIGKILL) once its parent has died, however
#: it died; the parent terminates it when the server is stopped normally.
_SERVER_WATCHDOG = """
import os, signal, sys, time
parent, server = int(sys.argv[1]), int(sys.argv[2])
while os.getppid() == parent:
    time.sleep(0.5)
for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 0.0)):
    try:
        os.kill(server, sig)
    except ProcessLookupError:
        break
    time.sleep(wait)
"""


@contextlib.contextmanager
def temporary_api() -> Iterator[None]:
    """Without ``PREFECT_API_URL``, one temporary Prefect server for the scan.

    Prefect would otherwise start a temporary server of its own, and one in
    every Dask worker process (slow, and each on the same SQLite file), and a
    scan killed with SIGKILL would leave it running. The server is started
    once here, with a watchdog process that stops it if this process dies,
    and stopped, with the run's last log lines flushed, at the end.
    """
    from prefect.settings import PREFECT_API_URL, temporary_settings

    if os.environ.get("PREFECT_API_URL") or PREFECT_API_URL.value():
        yield                       # a server is configured (environment, profile, settings)
        return
    from prefect.server.api.server import SubprocessASGIServer

    # a port of its own: Prefect keeps one server object per port, and the one of
    # port None may be another caller's (stopping it here would stop theirs)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = SubprocessASGIServer(port=port)
    server.start(timeout=180)
    watchdog = subprocess.Popen([sys.executable, "-c", _SERVER_WATCHDOG, str(os.getpid()),
                                 str(server.server_process.pid)], start_new_session=True,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    os.environ["PREFECT_API_URL"] = server.api_url     # for the worker processes
    try:
        with temporary_settings(updates={PREFECT_API_URL: server.api_url}):
            yield
    finally:
        from prefect.logging.handlers import APILogHandler

        APILogHandler().flush()  # the run's last log lines, before the server goes
        os.environ.pop("PREFECT_API_URL", None)
        watchdog.terminate()
        watchdog.wait()
        server.stop()
