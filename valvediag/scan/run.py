"""
A whole plant scan, from the historian exports to the report: one sequence of
steps, whichever entry point runs it.

:func:`execute_scan` takes the store's scan lock and runs the steps of a
:class:`ScanSteps` in order: read the registry, ingest (after marking the runs
of dead scans aborted), plan and start the run, analyse, rank, persist (and
find the faults new since the previous complete run), write the outputs,
publish, and finish the run, or mark it failed with a one-line note. The
steps are plain functions of this module. :func:`run_scan` executes them in
this process; the nightly Prefect flow (``valvediag.pipelines.nightly``)
executes the same sequence with each step wrapped as a Prefect task and the
analysis spread over worker processes or Dask.
"""
from __future__ import annotations

import datetime as dt
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..io.exports import expand_paths
from ..io.registry import LoopSpec, read_loops_csv
from ..plain import one_line
from ..report.outputs import write_outputs
from ..store.database import Store
from ..store.ingest import IngestReport, ingest_exports
from ..store.lock import ScanLock, owner_id
from ..store.partitions import partition_dir, remove_partitions
from .loop import analyse_stored_loops
from .plan import plan_loops
from .plant import persist_results, rank_results
from .types import LoopJob, LoopResult, ScanConfig, ScanSummary

__all__ = ["ScanSteps", "execute_scan", "run_scan", "ingest_step", "plan_run", "persist_run",
           "finish_run", "fail_run", "discard_partitions", "run_info", "run_status",
           "check_writable", "NothingStoredError"]

_UTC = dt.timezone.utc
#: Bytes written and removed by :func:`check_writable`: a full disk shows
#: before the work, not after it.
WRITE_PROBE_BYTES = 1 << 20
#: Longest note kept with a run [characters].
NOTE_MAX = 500


class NothingStoredError(RuntimeError):
    """No export of the run reached the store (each failed or was quarantined)."""


def check_writable(directory, what: str) -> None:
    """Check that ``directory`` exists (it is created) and takes a file of
    :data:`WRITE_PROBE_BYTES`, before a scan does any work.

    Parameters
    ----------
    directory : str or path-like
    what : str
        What the directory holds, for the message (``'the store'``).

    Raises
    ------
    OSError
        One line naming the directory and the cause (not a directory, no
        permission, read-only file system, disk full).

    Notes
    -----
    A disk with less than the probe free fails here; one that fills up later
    still fails the step that writes, and the run is then ``failed``.
    """
    path = Path(directory)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path, prefix=".valvediag-probe-") as fh:
            fh.write(b"\0" * WRITE_PROBE_BYTES)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        raise type(exc)(f"{path}: cannot write {what} here: "
                        f"{exc.strerror or one_line(exc)}") from None


def run_status(ingest: IngestReport) -> tuple[str, str | None]:
    """How a run whose steps all succeeded ends, given its ingest.

    Parameters
    ----------
    ingest : IngestReport

    Returns
    -------
    status : {'complete', 'partial'}
        ``partial`` when some export's samples did not all reach the store
        (:attr:`~valvediag.store.ingest.IngestReport.incomplete`: unreadable,
        every row or more than a tenth quarantined, or rows quarantined for
        want of a setting).
    note : str or None
        The exports concerned, one line (at most :data:`NOTE_MAX` characters).
    """
    missing = ingest.incomplete
    if not missing:
        return "complete", None
    note = f"{len(missing)} export(s) not fully stored: " + "; ".join(missing)
    return "partial", note if len(note) <= NOTE_MAX else note[:NOTE_MAX - 1] + "\u2026"


# ------------------------------------------------------------------------------ steps
def ingest_step(db, exports: Sequence[str], loops: Sequence[LoopSpec], timezone: str | None,
                partitions: str | None = None,
                progress: Callable[[int, int], object] | None = None
                ) -> tuple[IngestReport, list[dict]]:
    """Mark the runs of dead scans aborted, ingest the exports and store the registry.

    Parameters
    ----------
    db : str or path-like
        The store (created when missing).
    exports : sequence of str
        Export files, directories or globs.
    loops : sequence of LoopSpec
        The registry; it replaces the stored one.
    timezone : str or None
        IANA zone of naive time stamps.
    partitions : str, optional
        Where Dask partitions live (:func:`valvediag.store.partitions.partition_dir`);
        those of aborted runs are deleted.
    progress : callable(done, total), optional
        Files ingested so far.

    Returns
    -------
    report : IngestReport
    aborted : list of dict
        The runs marked aborted (``run_id``, ``owner``).

    Raises
    ------
    FileNotFoundError
        An export path that does not exist or a pattern that matches no file
        (every one is named): the scan stops before it stores anything.

    Notes
    -----
    Runs left ``running`` belong to scans that died: the caller holds the
    scan lock, so no other scan of the store is alive.
    """
    files, missing = expand_paths(exports)
    if missing or not files:
        # an unmounted share or a mistyped path must not look like a quiet night
        raise FileNotFoundError("; ".join(missing) if missing else
                                f"no export file matches {', '.join(exports)}")
    if progress is not None:
        progress(0, len(files))
    with Store(db) as store:
        aborted = store.abort_stale_runs()
        for run in aborted:
            remove_partitions(partition_dir(db, run["run_id"], partitions))
        report = ingest_exports(store, exports, timezone=timezone,
                                progress=None if progress is None else
                                lambda done, total, _path: progress(done, total))
        store.replace_loops(loops)
    return report, aborted


def plan_run(db, loops: Sequence[LoopSpec], config: ScanConfig, exports: Sequence[str]
             ) -> tuple[str, list[LoopJob]]:
    """Plan every loop's window and register the run (status ``running``).

    Parameters
    ----------
    db : str or path-like
        The store.
    loops : sequence of LoopSpec
        The registry.
    config : ScanConfig
        The scan's parameters.
    exports : sequence of str
        What the run read (kept with the run).

    Returns
    -------
    run_id : str
    jobs : list of LoopJob
        In registry order.
    """
    with Store(db) as store:
        jobs = plan_loops(store, loops, config)
        run_id = store.start_run(window_start=min((j.start for j in jobs), default=None),
                                 window_end=max((j.end for j in jobs), default=None),
                                 exports=list(exports), params=config.to_json(),
                                 owner=owner_id())
    return run_id, jobs


def persist_run(db, run_id: str, ranked: Sequence[LoopResult]) -> list[str]:
    """Store the run's verdicts and episodes; return the loops that are new faults.

    Parameters
    ----------
    db : str or path-like
    run_id : str
    ranked : sequence of LoopResult

    Returns
    -------
    list of str
        Loops whose verdict is a fault (:data:`valvediag.verdicts.FAULT_VERDICTS`)
        that was not one in the latest complete run before this one.
    """
    with Store(db) as store:
        persist_results(store, run_id, ranked)
        return store.new_faults(run_id)["loop"].to_list()


def finish_run(db, run_id: str, status: str = "complete", note: str | None = None) -> None:
    """Mark the run ``complete`` (every step succeeded) or ``partial`` (and some
    export was not stored, see :func:`run_status`).

    Parameters
    ----------
    db : str or path-like
    run_id : str
    status : {'complete', 'partial'}
    note : str, optional
        What is missing from a partial run.
    """
    with Store(db) as store:
        store.finish_run(run_id, status, note=note)


def fail_run(db, run_id: str, exc: BaseException) -> None:
    """Mark the run ``failed`` with a one-line note of what went wrong.

    Parameters
    ----------
    db : str or path-like
    run_id : str
    exc : BaseException
        The failure.
    """
    note = one_line(exc)[:NOTE_MAX]
    with Store(db) as store:
        store.finish_run(run_id, "failed", note=note)


def discard_partitions(db, run_id: str, partitions: str | None) -> None:
    """Delete the run's Dask partitions, if it wrote any.

    Parameters
    ----------
    db : str or path-like
    run_id : str
    partitions : str or None
        Their root (default beside the store).
    """
    remove_partitions(partition_dir(db, run_id, partitions))


def run_info(db, loops_csv, exports: Sequence[str], jobs: Sequence[LoopJob],
             config: ScanConfig, registry_problems: Sequence[str], ingest: IngestReport,
             new_faults: Sequence[str]) -> dict:
    """The header of the report: what the run read, its window and its parameters.

    Parameters
    ----------
    db, loops_csv : str or path-like
    exports : sequence of str
    jobs : sequence of LoopJob
    config : ScanConfig
    registry_problems : sequence of str
    ingest : IngestReport
    new_faults : sequence of str

    Returns
    -------
    dict
        See :func:`valvediag.report.render_report`.
    """
    return {"db": os.fspath(db), "loops_csv": os.fspath(loops_csv), "exports": list(exports),
            "window_start": min((j.start for j in jobs), default=None),
            "window_end": max((j.end for j in jobs), default=None),
            "config": config.to_json(), "registry_problems": list(registry_problems),
            "ingest_errors": list(ingest.incomplete), "new_faults": list(new_faults),
            "ingest_quarantine": [f.summary() for f in ingest.quarantined_files],
            "ingest_files": [f.as_dict() for f in ingest.per_file if not f.unchanged],
            "generated": dt.datetime.now(_UTC)}


class ScanSteps:
    """The steps of a scan, run directly in this process.

    :func:`execute_scan` calls each attribute in turn; the nightly flow
    passes a subclass whose attributes are the same functions wrapped as
    Prefect tasks, with its own ``analyse`` (worker processes or Dask) and
    ``publish`` (Prefect artifacts). Every step takes and returns plain
    values, so the two runs differ only in where each step executes.
    """

    read_registry = staticmethod(read_loops_csv)
    ingest = staticmethod(ingest_step)
    plan = staticmethod(plan_run)
    rank = staticmethod(rank_results)
    persist = staticmethod(persist_run)
    finish = staticmethod(finish_run)
    fail = staticmethod(fail_run)

    def __init__(self, progress: Callable[[str, int, int], object] | None = None):
        self.progress = progress

    def report(self, stage: str) -> Callable[[int, int], object] | None:
        """The progress callback of one stage (``'ingest'``, ``'analyse'``), or None."""
        if self.progress is None:
            return None
        return lambda done, total: self.progress(stage, done, total)

    def analyse(self, db, run_id: str, jobs: Sequence[LoopJob], config: ScanConfig
                ) -> list[LoopResult]:
        """Analyse the loops (here: in this process,
        :func:`~valvediag.scan.loop.analyse_stored_loops`)."""
        progress = self.report("analyse")
        if progress is not None:
            progress(0, len(jobs))
        return analyse_stored_loops(db, jobs, config, progress)

    def outputs(self, ranked: Sequence[LoopResult], out, run_id: str, info: dict) -> dict:
        """Write the outputs (:func:`valvediag.report.outputs.write_outputs`)."""
        return write_outputs(ranked, out, run_id=run_id, run_info=info)

    def publish(self, ranked: Sequence[LoopResult], paths: dict, run_id: str,
                new_faults: Sequence[str], info: dict) -> None:
        """Announce the run beyond its output files (here: nothing). ``info`` is
        :func:`run_info`'s, with the run's ``status``."""

    def cleanup(self, db, run_id: str) -> None:
        """Remove what the run left behind (here: nothing)."""


def execute_scan(exports, loops_csv, db, out_dir, config: ScanConfig = ScanConfig(), *,
                 steps: ScanSteps | None = None, wait_s: float = 0.0,
                 partitions: str | None = None) -> ScanSummary:
    """Run a whole scan: the one sequence every entry point uses.

    Parameters
    ----------
    exports : str, path-like or iterable of them
        Historian export files, directories or globs.
    loops_csv : str or path-like
        The loop registry.
    db : str or path-like
        The store (created when missing).
    out_dir : str or path-like
        Where the outputs go.
    config : ScanConfig
        The scan's parameters.
    steps : ScanSteps, optional
        How each step runs (default: directly, in this process).
    wait_s : float, default 0
        Longest wait for another scan of the same store to end [s]; then a
        one-line :class:`~valvediag.store.lock.ScanLockedError`.
    partitions : str, optional
        Root of the Dask partitions (deleted at the end of the run).

    Returns
    -------
    ScanSummary

    Notes
    -----
    The scan lock is taken here, once, for the whole run (a process that
    already holds it, such as ``valvediag scan`` around the flow, shares
    it). Before any work, the store's and the outputs' directories must take
    a file (:func:`check_writable`). The run is ``complete`` when every step
    after the plan succeeded and every export was stored, ``partial`` (with
    a note naming the exports) when some export failed or stored nothing
    although it had rows (:func:`run_status`); otherwise, including when no
    export reached the store (:class:`NothingStoredError`), it is ``failed``
    with a one-line note, and the exception propagates.
    """
    steps = steps or ScanSteps()
    if isinstance(exports, (str, os.PathLike)):
        exports = [exports]
    exports = [os.fspath(e) for e in exports]
    with ScanLock(db, timeout=wait_s):
        check_writable(Path(db).parent, "the store")
        check_writable(out_dir, "the outputs")
        loops, problems = steps.read_registry(loops_csv)
        t0 = time.perf_counter()
        ingest, _ = steps.ingest(db, exports, loops, config.timezone, partitions,
                                 steps.report("ingest"))
        ingest_s = time.perf_counter() - t0
        run_id, jobs = steps.plan(db, loops, config, exports)
        status, note = run_status(ingest)
        t1 = time.perf_counter()
        try:
            if not ingest.usable:
                raise NothingStoredError("no export reached the store: " + (
                    "; ".join(ingest.incomplete) or "the exports hold no samples"))
            ranked = steps.rank(steps.analyse(db, run_id, jobs, config))
            analysis_s = time.perf_counter() - t1
            new_faults = steps.persist(db, run_id, ranked)
            info = run_info(db, loops_csv, exports, jobs, config, problems, ingest, new_faults)
            info["status"], info["status_note"] = status, note
            paths = steps.outputs(ranked, out_dir, run_id, info)
            steps.publish(ranked, paths, run_id, new_faults, info)
            steps.finish(db, run_id, status, note)
        except BaseException as exc:
            steps.fail(db, run_id, exc)
            raise
        finally:
            steps.cleanup(db, run_id)
    return ScanSummary(run_id=run_id, results=tuple(ranked), outputs=paths, ingest=ingest,
                       registry_problems=tuple(problems), new_faults=tuple(new_faults),
                       ingest_s=ingest_s, analysis_s=analysis_s, status=status,
                       status_note=note or "")


def run_scan(exports, loops_csv, db, out_dir, *, config: ScanConfig = ScanConfig(),
             progress: Callable[[str, int, int], object] | None = None,
             wait_s: float = 0.0) -> ScanSummary:
    """The whole nightly scan in this process, without Prefect.

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
    progress : callable(stage, done, total), optional
        Called with ``'ingest'`` (files) and ``'analyse'`` (loops).
    wait_s : float, default 0
        Longest wait for another scan of the store [s].

    Returns
    -------
    ScanSummary

    Raises
    ------
    valvediag.io.registry.RegistryError
        ``loops.csv`` cannot be read at all (one line naming the file).
    valvediag.store.lock.ScanLockedError
        Another scan holds the store.

    Notes
    -----
    The same steps as the nightly flow (:func:`execute_scan`), run one after
    the other. An export that cannot be read (unknown columns, say) is
    reported in ``ScanSummary.errors`` with a one-line message naming the
    file; the other files are ingested and the scan goes on. Problems in
    single rows of ``loops.csv`` are in ``registry_problems`` and the loop's
    verdict says why it could not be analysed.
    """
    return execute_scan(exports, loops_csv, db, out_dir, config, steps=ScanSteps(progress),
                        wait_s=wait_s)
