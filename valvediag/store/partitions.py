"""
Parquet partitions of a scan: each loop's window, exported from the store.

DuckDB lets one process hold the store, and a second process cannot even open
it read-only. Workers of a distributed scan (Dask processes, other machines)
therefore never open the DuckDB file: after the ingest, the flow process
exports every loop's samples over its window to Parquet
(:func:`export_partitions`), the workers read their loop from there
(:func:`load_partition_frames`) and return results, and one task writes the
results to the store.

Layout, under the run's partition directory (:func:`partition_dir`)::

    <db stem>.partitions/<run id>/job=<k>/data_0.parquet     one directory per loop

with the columns ``role, ts, value, status`` (``ts`` UTC, microseconds). Row
``k`` is the loop's position in the job list. The frames read back are those
:func:`valvediag.scan.load_loop_frames` reads from the store, row for row
(set point and mode include their last sample before the window).

The export runs one DuckDB ``COPY`` per group of loops (:data:`GROUP_LOOPS`
loops, their tags only), so its memory is bounded by a group, not the plant.
"""
from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import polars as pl

if TYPE_CHECKING:  # pragma: no cover
    from ..scan.types import LoopJob
    from .database import Store

__all__ = ["export_partitions", "fetch_loop_windows", "load_partition_frames", "partition_dir", "partition_root",
           "remove_partitions", "GROUP_LOOPS", "PARTITION_SCHEMA"]

#: Loops exported by one ``COPY`` statement.
GROUP_LOOPS = 50
#: Columns of a partition file (``role`` is ``pv``, ``op``, ``sp``, ``mv`` or ``mode``).
PARTITION_SCHEMA: dict[str, pl.DataType] = {
    "role": pl.String(), "ts": pl.Datetime("us", "UTC"), "value": pl.Float64(),
    "status": pl.String()}
_FRAME_SCHEMA = {"ts": pl.Datetime("us", "UTC"), "value": pl.Float64, "status": pl.String}
_HELD_ROLES = ("sp", "mode")
_JOBS_SCHEMA = {"job": pl.Int64, "role": pl.String, "tag": pl.String,
                "w_start": pl.Datetime("us", "UTC"), "w_end": pl.Datetime("us", "UTC"),
                "held": pl.Boolean}

#: Parquet export of :func:`_windows`' query (``sql/loop_windows.sql``), per job.
_COPY_OPTIONS = "(FORMAT parquet, PARTITION_BY (job), OVERWRITE_OR_IGNORE, COMPRESSION zstd)"


def _jobs_frame(jobs: Sequence[LoopJob], first: int = 0) -> pl.DataFrame:
    """One row per (job, role): the tag and window; ``job`` counts from ``first``."""
    rows = [{"job": first + k, "role": role, "tag": tag, "w_start": job.start, "w_end": job.end,
             "held": role in _HELD_ROLES}
            for k, job in enumerate(jobs) for role, tag in job.spec.tags.items()]
    return pl.DataFrame(rows, schema=_JOBS_SCHEMA)


def _windows(store: Store, frame: pl.DataFrame, copy_to: Path | None = None
             ) -> pl.DataFrame | None:
    """The window samples of the jobs of ``frame`` (``sql/loop_windows.sql``), or, with
    ``copy_to``, written there as Parquet partitioned by job (None returned)."""
    from .database import load_sql

    sql = load_sql("loop_windows")
    if copy_to is not None:
        path = str(copy_to).replace("'", "''")
        sql = f"COPY ({sql}) TO '{path}' {_COPY_OPTIONS}"
    held = sorted(set(frame.filter("held")["tag"])) or [""]
    params = {"tags": sorted(set(frame["tag"])), "held_tags": held,
              "t0": frame["w_start"].min(), "t1": frame["w_end"].max(),
              "t_held": frame["w_start"].max()}
    store.con.register("export_jobs", frame)
    try:
        rel = store.con.sql(sql, params=params)
        return None if copy_to is not None else rel.pl()
    finally:
        store.con.unregister("export_jobs")


def fetch_loop_windows(store: Store, jobs: Sequence[LoopJob]) -> list[dict[str, pl.DataFrame]]:
    """Several loops' samples over their windows, read in one query.

    Parameters
    ----------
    store : valvediag.store.Store
        The store (any mode; only reads).
    jobs : sequence of LoopJob
        The loops and windows.

    Returns
    -------
    list of dict of str to polars.DataFrame
        Per job, role -> ``ts, value, status`` by time, row for row what
        :func:`valvediag.scan.load_loop_frames` reads (set point and mode
        with their last sample before the window; an empty frame for a role
        without samples).

    Notes
    -----
    The ``samples`` table is sorted by tag within each ingested slice, not
    across files, so the row groups that may hold a tag are many (84 of
    1,225 for one tag of the 149 M-sample plant benchmark) and reading a
    loop tag by tag scans them again for every tag: 0.19 s per loop-day.
    One query for a group of loops scans each row group once. Memory holds
    the group's samples a few times over while DuckDB's result becomes
    polars frames (see :func:`valvediag.scan.analyse_stored_loops`).
    """
    out = [{} for _ in jobs]
    frame = _jobs_frame(jobs)
    data = (_windows(store, frame) if frame.height
            else pl.DataFrame(schema={"job": pl.Int64, **PARTITION_SCHEMA}))
    # split first, then sort each (job, role) by time: a third of the cost of one sort
    groups = data.partition_by("job", "role", as_dict=True, include_key=False)
    for k, job in enumerate(jobs):
        for role in job.spec.tags:
            g = groups.pop((k, role), None)
            out[k][role] = (g.sort("ts").cast(_FRAME_SCHEMA) if g is not None
                            else pl.DataFrame(schema=_FRAME_SCHEMA))
    return out


def partition_root(db_path: str | os.PathLike) -> Path:
    """Directory holding every run's partitions of a store: ``<db>.partitions`` beside it.

    Parameters
    ----------
    db_path : str or path-like
        The DuckDB file.
    """
    db = Path(os.fspath(db_path)).resolve()
    return db.with_name(db.name + ".partitions")


def partition_dir(db_path: str | os.PathLike, run_id: str,
                  root: str | os.PathLike | None = None) -> Path:
    """The partition directory of one run.

    Parameters
    ----------
    db_path : str or path-like
        The DuckDB file.
    run_id : str
        The run.
    root : str or path-like, optional
        Parent of the run directories; default :func:`partition_root`. A
        distributed scan needs a directory every worker can read (a shared
        file system).
    """
    base = Path(root).resolve() if root is not None else partition_root(db_path)
    return base / run_id


def _job_path(out_dir: Path, k: int) -> str:
    return str(out_dir / f"job={k}")


def export_partitions(store: Store, jobs: Sequence[LoopJob], out_dir: str | os.PathLike, *,
                      group_loops: int = GROUP_LOOPS,
                      progress: Callable[[int, int], object] | None = None) -> list[str]:
    """Export each loop's samples over its window to Parquet, one directory per loop.

    Parameters
    ----------
    store : valvediag.store.Store
        The store (any mode; the export only reads).
    jobs : sequence of LoopJob
        The loops and windows (:func:`valvediag.scan.plan_loops`).
    out_dir : str or path-like
        The run's partition directory (:func:`partition_dir`); created, and
        emptied first if it exists (a retried export starts afresh).
    group_loops : int, default GROUP_LOOPS
        Loops per ``COPY`` statement: bounds the export's memory.
    progress : callable(done, total), optional
        Called after each group with loops exported so far.

    Returns
    -------
    list of str
        One partition path per job, in job order, for
        :func:`load_partition_frames`. A loop without tags or samples gets a
        path that does not exist; it reads as no samples.
    """
    out = Path(out_dir)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    paths = [_job_path(out, k) for k in range(len(jobs))]
    group_loops = max(int(group_loops), 1)
    for g0 in range(0, len(jobs), group_loops):
        frame = _jobs_frame(jobs[g0:g0 + group_loops], first=g0)
        if frame.height:
            tmp = out / f".group-{g0}"
            _windows(store, frame, copy_to=tmp)
            if tmp.exists():   # DuckDB writes nothing for a group without samples
                for part in tmp.iterdir():
                    part.rename(out / part.name)
                tmp.rmdir()
        if progress is not None:
            progress(min(g0 + group_loops, len(jobs)), len(jobs))
    return paths


def load_partition_frames(path: str | os.PathLike, job: LoopJob) -> dict[str, pl.DataFrame]:
    """Read one loop's samples from its partition (see :func:`export_partitions`).

    Parameters
    ----------
    path : str or path-like
        The loop's partition directory (or a Parquet file).
    job : LoopJob
        The loop; every role it has a tag for gets a frame.

    Returns
    -------
    dict of str to polars.DataFrame
        Role -> ``ts, value, status`` by time, as
        :func:`valvediag.scan.load_loop_frames` returns them (an empty frame
        for a role without samples).
    """
    p = Path(os.fspath(path))
    files = sorted(p.glob("*.parquet")) if p.is_dir() else ([p] if p.is_file() else [])
    if files:
        data = pl.read_parquet(files).select(list(PARTITION_SCHEMA)).cast(PARTITION_SCHEMA)
    else:
        data = pl.DataFrame(schema=PARTITION_SCHEMA)
    out = {}
    for role in job.spec.tags:
        out[role] = data.filter(pl.col("role") == role).drop("role").sort("ts").cast(
            _FRAME_SCHEMA)
    return out


def remove_partitions(path: str | os.PathLike) -> None:
    """Delete a run's partition directory (nothing when it is gone).

    Parameters
    ----------
    path : str or path-like
        The directory (:func:`partition_dir`).
    """
    shutil.rmtree(os.fspath(path), ignore_errors=True)
