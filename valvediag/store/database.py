"""
The DuckDB store: samples, quarantine, the loop registry and scan results.

Every SQL statement the store runs lives in ``sql/<name>.sql`` and is loaded
by name (:func:`load_sql`); this module only binds parameters and moves polars
frames in and out (``con.sql(q).pl()``, registered frames for bulk inserts).

Notes
-----
* DuckDB allows one process to hold a database file open for writing; a
  second process fails even read-only. Parallel workers must return frames and
  let one task write. Opening a locked file raises
  :class:`StoreLockedError` with a one-line message.
* The connection runs with ``TimeZone = 'UTC'``: every TIMESTAMPTZ comes back
  as ``Datetime(us, UTC)``.
* (tag, ts) of ``samples`` is unique. The ingest guarantees it with an
  anti-join in one transaction per file, not with a PRIMARY KEY, because
  DuckDB's ART index for it costs ~5x insert time and ~9x file size (measured
  on 3 M rows). :meth:`Store.duplicate_keys` checks the invariant.
* Each connection caps DuckDB's buffer pool (:data:`MEMORY_LIMIT`: 2 GB for
  the writer, 512 MB for a reader; ``VALVEDIAG_DUCKDB_MEMORY`` overrides);
  larger joins spill to a temporary directory beside the file.
* Time arguments must be timezone-aware :class:`datetime.datetime` objects;
  naive ones are refused rather than guessed.
* The queries are the ``.sql`` files of the repository's ``sql/`` folder,
  installed as the package ``valvediag.sql`` and read with
  :mod:`importlib.resources`.
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime as dt
import functools
import importlib.resources
import json
import math
import os
import threading
import uuid
from collections.abc import Iterable, Iterator, Mapping, Sequence

import duckdb
import polars as pl
import pyarrow  # noqa: F401 - imported once here, not first by DuckDB in several threads at once

from ..io.registry import LoopSpec
from ..plain import aware_utc, one_line, to_plain
from ..verdicts import FAULT_VERDICTS, VERDICTS

__all__ = ["Store", "StoreLockedError", "load_sql", "SQL_DIR", "EPISODE_COLUMNS", "VERDICT_COLUMNS",
           "RUN_END_STATUSES"]

#: The named queries: ``sql/`` of the repository, shipped as ``valvediag.sql``.
SQL_DIR = importlib.resources.files("valvediag.sql")


#: Columns a caller may give for episodes / verdicts (run_id is added by the store).
EPISODE_COLUMNS: dict[str, pl.DataType] = {
    "loop": pl.String(), "start_ts": pl.Datetime("us", "UTC"), "end_ts": pl.Datetime("us", "UTC"),
    "period_s": pl.Float64(), "amplitude": pl.Float64(), "regularity": pl.Float64(),
    "verdict": pl.String(), "bi": pl.Float64(), "confidence": pl.Float64(),
}
VERDICT_COLUMNS: dict[str, pl.DataType] = {
    "loop": pl.String(), "verdict": pl.String(), "confidence": pl.Float64(),
    "rank": pl.Int32(), "severity": pl.Float64(), "process_type": pl.String(),
    "bi": pl.Float64(), "period_s": pl.Float64(), "amplitude": pl.Float64(),
    "regularity": pl.Float64(), "reason": pl.String(), "evidence": pl.String(),
    "quality": pl.String(),
}
_JSON_COLUMNS = ("evidence", "quality")
_SAMPLE_FRAME_SCHEMA = {"ts": pl.Datetime("us", "UTC"), "value": pl.Float64, "status": pl.String}
_HELD_ROLES = ("sp", "mode")
#: How a run can end: ``complete`` (every step and every export), ``partial``
#: (every step, but some export could not be read or stored nothing),
#: ``failed`` (a step failed), ``aborted`` (the scan's process died).
RUN_END_STATUSES = ("complete", "partial", "failed", "aborted")

#: DuckDB's buffer-pool limit per connection: writer, reader. DuckDB's own
#: default (80 % of RAM per database instance) lets a long ingest and every
#: reader of the analysis cache gigabytes each. Environment variable
#: ``VALVEDIAG_DUCKDB_MEMORY`` (e.g. ``4GB``) sets both.
MEMORY_LIMIT = (os.environ.get("VALVEDIAG_DUCKDB_MEMORY", "2GB"),
                os.environ.get("VALVEDIAG_DUCKDB_MEMORY", "512MB"))


def _key_bounds(samples: pl.DataFrame) -> dict:
    """Time bounds and tag list of incoming samples, pushed into the scan of ``samples``."""
    return {"ts_min": samples["ts"].min(), "ts_max": samples["ts"].max(),
            "tags": samples["tag"].unique().sort().to_list()}


def _tag_bounds(samples: pl.DataFrame) -> pl.DataFrame:
    """``tag, ts_min, ts_max`` of incoming samples."""
    return samples.group_by("tag").agg(pl.col("ts").min().alias("ts_min"),
                                       pl.col("ts").max().alias("ts_max"))


def _sorted_by_key(samples: pl.DataFrame) -> bool:
    """True when ``samples`` is sorted by (tag, ts) (ties allowed)."""
    if samples.height < 2:
        return True
    tag, ts = pl.col("tag"), pl.col("ts")
    prev_tag, prev_ts = tag.shift(), ts.shift()
    ok = (tag > prev_tag) | ((tag == prev_tag) & (ts >= prev_ts))
    return bool(samples.select(ok.slice(1).all()).item())


_CONNECT_GUARD = threading.Lock()


class StoreLockedError(RuntimeError):
    """The database file is held by another process."""


@functools.cache
def load_sql(name: str) -> str:
    """Return the text of ``sql/<name>.sql``.

    Raises
    ------
    KeyError
        No such named query; the message lists the directory searched.
    """
    path = SQL_DIR / f"{name}.sql"
    if not path.is_file():
        raise KeyError(f"no named query {name!r} in {SQL_DIR}")
    return path.read_text()


def _to_json(obj) -> str | None:
    """JSON text of a value (:func:`valvediag.plain.to_plain`); text is taken as JSON already."""
    if obj is None or isinstance(obj, str):
        return obj
    return json.dumps(to_plain(obj), allow_nan=False)


def _result_frame(rows, columns: dict[str, pl.DataType], run_id: str, what: str
                  ) -> pl.DataFrame:
    """Normalise episodes/verdicts given as a frame or as mappings."""
    if rows is None:
        rows = []
    if isinstance(rows, pl.DataFrame):
        frame = rows
    else:
        records = [dict(r) for r in rows]
        for r in records:
            for c in _JSON_COLUMNS:
                if c in r:
                    r[c] = _to_json(r[c])
        frame = pl.DataFrame(records, schema_overrides={k: v for k, v in columns.items()
                                                        if any(k in r for r in records)},
                             strict=False, infer_schema_length=None
                             ) if records else pl.DataFrame(schema=columns)
    unknown = [c for c in frame.columns if c not in columns and c != "run_id"]
    if unknown:
        raise ValueError(f"{what}: unknown columns {unknown}; expected {list(columns)}")
    for c in _JSON_COLUMNS:
        if c in frame.columns and frame.schema[c] != pl.String:
            frame = frame.with_columns(pl.col(c).map_elements(_to_json, return_dtype=pl.String))
    frame = frame.with_columns([pl.lit(None, t).alias(c) for c, t in columns.items()
                                if c not in frame.columns])
    return frame.select(pl.lit(run_id).alias("run_id"),
                        *[pl.col(c).cast(t) for c, t in columns.items()])


class Store:
    """A valvediag DuckDB database.

    Parameters
    ----------
    path : str or path-like, default ":memory:"
        Database file; created with the schema when missing.
    read_only : bool, default False
        Open without write access (the schema must exist).

    Raises
    ------
    StoreLockedError
        Another process holds the file.

    Examples
    --------
    >>> with Store("plant.duckdb") as store:            # doctest: +SKIP
    ...     store.tags()
    """

    def __init__(self, path: str | os.PathLike = ":memory:", *, read_only: bool = False):
        self.path = os.fspath(path)
        try:
            # one connect at a time per process: threads that open the same file at
            # once share DuckDB's database instance, and one of them may query it
            # before the Python table functions (python_arrow_scan, which scans a
            # registered polars frame) are set up on it (seen as a CatalogException
            # in a scan's analysis threads)
            with _CONNECT_GUARD:
                self.con = duckdb.connect(self.path, read_only=read_only)
                self.con.execute("SET TimeZone = 'UTC'")
        except duckdb.IOException as exc:
            first = one_line(exc)
            if "lock" in first.lower():
                raise StoreLockedError(f"{self.path}: the store is open in another process "
                                       f"(DuckDB allows one writer): {first}") from None
            raise
        self.con.execute(f"SET memory_limit = '{MEMORY_LIMIT[1 if read_only else 0]}'")
        if not read_only:
            missing = self.con.execute(load_sql("samples_bounds_missing")).fetchall()
            fill_bounds = bool(missing[0][0])
            self.con.execute(load_sql("schema"))
            if fill_bounds:  # new store, or one made before sample_bounds existed
                with self.transaction():
                    self.con.execute(load_sql("samples_bounds_rebuild"))
            if not self.con.execute(load_sql("runs_current")).fetchall()[0][0]:
                with self.transaction():       # a store older than runs.owner/note or 'partial'
                    self.con.execute(load_sql("runs_migrate"))

    # -- plumbing ----------------------------------------------------------
    def close(self) -> None:
        """Close the connection."""
        self.con.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def query(self, name: str, **params) -> pl.DataFrame:
        """Run the named read query ``sql/<name>.sql`` and return a polars frame.

        Parameters
        ----------
        name : str
            File stem in ``sql/``, e.g. ``"new_faults_of_run"``.
        **params
            Values of the query's ``$name`` parameters (exactly those it uses).
        """
        return self.con.sql(load_sql(name), params=params or None).pl()

    def _run(self, name: str, **params) -> int | None:
        """Run a named statement; return its row count when it reports one."""
        res = self.con.execute(load_sql(name), params or None)
        try:
            row = res.fetchone()
        except duckdb.InvalidInputException:
            return None
        return None if row is None else row[0]

    @contextlib.contextmanager
    def transaction(self) -> Iterator[Store]:
        """Run the body in one transaction; roll back on any exception."""
        self.con.begin()
        try:
            yield self
        except BaseException:
            self.con.rollback()
            raise
        self.con.commit()

    @contextlib.contextmanager
    def _registered(self, name: str, frame: pl.DataFrame) -> Iterator[None]:
        self.con.register(name, frame)
        try:
            yield
        finally:
            self.con.unregister(name)

    def counts(self) -> dict[str, int]:
        """Row count of every table."""
        return self.query("table_counts").row(0, named=True)

    # -- ingest ------------------------------------------------------------
    def file_known(self, sha256: str) -> bool:
        """True when a file with this content hash was ingested before.

        Parameters
        ----------
        sha256 : str
            Hex digest of the file content.
        """
        return bool(self.query("ingested_file_known", sha256=sha256)["known"][0])

    def conflicting_samples(self, samples: pl.DataFrame, *, may_overlap: bool | None = None
                            ) -> pl.DataFrame:
        """Incoming samples whose (tag, ts) is stored with a different value or status.

        Parameters
        ----------
        samples : polars.DataFrame
            :data:`~valvediag.io.exports.SAMPLE_SCHEMA` rows.
        may_overlap : bool, optional
            The result of :meth:`may_overlap` for these samples, when the
            caller has it already (it is the costly part of the check);
            None computes it.

        Returns
        -------
        polars.DataFrame
            ``source_line, tag, stored_file, stored_line``.
        """
        empty = pl.DataFrame(schema={"source_line": pl.Int64, "tag": pl.String,
                                     "stored_file": pl.String, "stored_line": pl.Int64})
        if samples.is_empty():
            return empty
        if may_overlap is None:
            may_overlap = self.may_overlap(samples)
        if not may_overlap:
            return empty
        with self._registered("incoming_samples", samples):
            return self.query("samples_conflicting", **_key_bounds(samples))

    def may_overlap(self, samples: pl.DataFrame) -> bool:
        """Whether a stored sample of an incoming tag lies in that tag's incoming time range.

        Parameters
        ----------
        samples : polars.DataFrame
            Incoming rows with at least ``tag`` and ``ts``.

        Returns
        -------
        bool
            False when no incoming (tag, ts) can be stored yet; then the
            anti-join (a hash join whose cost grows with the whole table) is
            skipped. True is conservative (a key *may* be stored).

        Notes
        -----
        Within one transaction the answer holds until samples of these tags
        are inserted, so :func:`~valvediag.store.ingest.ingest_exports` computes it
        once per slice and passes it to :meth:`conflicting_samples` and
        :meth:`insert_new_samples`.
        """
        if samples.is_empty():
            return False
        bounds = _tag_bounds(samples)
        with self._registered("incoming_bounds", bounds):
            # the per-tag stored ranges first (a table of one row per tag): usually settles it
            if not self.con.execute(load_sql("samples_bounds_overlap")).fetchall()[0][0]:
                return False
            return bool(self.con.execute(load_sql("samples_may_overlap"),
                                         {"tags": bounds["tag"].to_list()}).fetchall()[0][0])

    def insert_new_samples(self, samples: pl.DataFrame, *, may_overlap: bool | None = None
                           ) -> int:
        """Insert samples whose (tag, ts) is not stored yet; return how many [rows].

        Parameters
        ----------
        samples : polars.DataFrame
            :data:`~valvediag.io.exports.SAMPLE_SCHEMA` rows, unique per (tag, ts).
        may_overlap : bool, optional
            See :meth:`conflicting_samples`; None computes it.

        Notes
        -----
        Rows are inserted sorted by (tag, ts), so the zone maps of the
        ``samples`` row groups prune the per-tag window reads. A frame that is
        sorted already (as every parsed export is) is inserted as it is: a
        sort inside DuckDB cost ~2.5x the insert itself (7.5 M rows: 6.4 s vs
        2.4 s CPU). The source file is bound as a parameter, not moved as a
        column of the same text on every row (a frame of several files is
        inserted file by file).
        """
        if samples.is_empty():
            return 0
        if may_overlap is None:
            may_overlap = self.may_overlap(samples)
        if not _sorted_by_key(samples):
            samples = samples.sort("tag", "ts", maintain_order=True)
        files = samples["source_file"]
        if files.null_count() == 0 and (files == files[0]).all():
            parts = [(files[0], samples)]
        else:  # several files (or nulls, which the NOT NULL column refuses)
            parts = [(None, samples)] if files.null_count() else [
                (p["source_file"][0], p)
                for p in samples.partition_by("source_file", maintain_order=True)]
        inserted = 0
        for source_file, part in parts:
            if source_file is not None:
                part = part.with_columns(source_file=pl.lit(None))  # Null type: no data
            name, params = ("samples_insert_new", _key_bounds(part)) if may_overlap else (
                "samples_insert_all", {})
            with self._registered("incoming_samples", part):
                inserted += int(self._run(name, source_file=source_file, **params) or 0)
        with self._registered("incoming_bounds", _tag_bounds(samples)):
            self._run("samples_bounds_update")  # keep sample_bounds a superset
        return inserted

    def insert_quarantine(self, rows: pl.DataFrame) -> int:
        """Add quarantine rows (``source_file, line, raw, reason``); return new rows."""
        if rows.is_empty():
            return 0
        with self._registered("incoming_quarantine", rows):
            return int(self._run("quarantine_insert") or 0)

    def record_ingested_file(self, path: str, sha256: str, *, rows: int, rows_inserted: int,
                             duplicates: int, quarantined: int) -> None:
        """Remember that a file was ingested.

        Parameters
        ----------
        path : str
            Absolute path.
        sha256 : str
            Hex digest of the content.
        rows, rows_inserted, duplicates, quarantined : int
            Samples parsed, newly stored, skipped as exact duplicates, and
            quarantine rows of the file [rows].
        """
        self._run("ingested_file_record", path=path, sha256=sha256, rows=rows,
                  rows_inserted=rows_inserted, duplicates=duplicates, quarantined=quarantined)

    def ingested_files(self) -> pl.DataFrame:
        """Every ingested file with its counts."""
        return self.query("ingested_files")

    def quarantine(self, source_file: str | None = None) -> pl.DataFrame:
        """Quarantined rows, by file and line.

        Parameters
        ----------
        source_file : str, optional
            Only this file (absolute path, as stored).
        """
        return self.query("quarantine_rows", source_file=source_file)

    def duplicate_keys(self) -> int:
        """Number of (tag, ts) keys stored more than once (the invariant says 0)."""
        return int(self.query("samples_duplicate_keys")["n"][0])

    # -- reading samples ---------------------------------------------------
    def tags(self) -> list[str]:
        """All tags with at least one sample, sorted."""
        return self.query("tags")["tag"].to_list()

    def latest_timestamps(self) -> pl.DataFrame:
        """Per tag: ``last_ts`` (any sample), ``last_good_ts`` and ``rows``."""
        return self.query("tag_latest")

    def fetch_tag(self, tag: str, start: dt.datetime | None = None,
                  end: dt.datetime | None = None, *, include_previous: bool = False
                  ) -> pl.DataFrame:
        """One tag's samples in ``[start, end)``.

        Parameters
        ----------
        tag : str
        start, end : datetime, optional
            Timezone-aware bounds; None is open.
        include_previous : bool, default False
            Also return the last sample before ``start`` (for held signals such
            as a set point that changed before the window).

        Returns
        -------
        polars.DataFrame
            ``ts: Datetime(us, UTC), value: Float64, status: str``, by time.
        """
        name = "tag_window_with_previous" if include_previous else "tag_window"
        frame = self.query(name, tag=tag, start=aware_utc(start, "start"), end=aware_utc(end, "end"))
        return frame.cast(_SAMPLE_FRAME_SCHEMA)

    def fetch_loop(self, loop: LoopSpec, start: dt.datetime | None = None,
                   end: dt.datetime | None = None) -> dict[str, pl.DataFrame]:
        """The samples of every tag of a loop, by role (``pv``, ``op``, ...).

        Parameters
        ----------
        loop : LoopSpec
            The loop; roles without a tag are left out.
        start, end : datetime, optional
            Timezone-aware window ``[start, end)``; None is open.

        Returns
        -------
        dict of str to polars.DataFrame
            Role -> ``ts, value, status`` as :meth:`fetch_tag`. Set point and
            mode include the last sample before ``start``. A tag with no data
            gives an empty frame; :meth:`missing_tags` names those.
        """
        return {role: self.fetch_tag(tag, start, end, include_previous=role in _HELD_ROLES)
                for role, tag in loop.tags.items()}

    def missing_tags(self, loop: LoopSpec, start: dt.datetime | None = None,
                     end: dt.datetime | None = None) -> dict[str, str]:
        """Roles whose tag has no sample at all (in ``[start, end)`` when given).

        Parameters
        ----------
        loop : LoopSpec
            The loop to check.
        start, end : datetime, optional
            Timezone-aware window; None is open.

        Returns
        -------
        dict
            role -> tag, e.g. ``{"op": "FIC101.OP"}``; empty when all have data.
        """
        tags = loop.tags
        if not tags:
            return {}
        present = set(self.query("tags_with_data", tags=sorted(set(tags.values())),
                                 start=aware_utc(start, "start"), end=aware_utc(end, "end"))["tag"])
        return {role: tag for role, tag in tags.items() if tag not in present}

    # -- registry ----------------------------------------------------------
    def replace_loops(self, loops: Iterable[LoopSpec]) -> int:
        """Replace the stored registry with ``loops``; return how many."""
        loops = list(loops)
        frame = pl.DataFrame(
            [{**dataclasses.asdict(l), "issues": list(l.issues)} for l in loops],
            schema={"loop": pl.String, "pv_tag": pl.String, "op_tag": pl.String,
                    "sp_tag": pl.String, "mv_tag": pl.String, "mode_tag": pl.String,
                    "process_type": pl.String, "unit": pl.String, "span": pl.Float64,
                    "criticality": pl.Float64, "description": pl.String,
                    "sampling": pl.String, "issues": pl.List(pl.String)},
        ).with_columns(pl.col("span").fill_nan(None))
        with self.transaction(), self._registered("incoming_loops", frame):
            self._run("loops_delete")
            self._run("loops_insert")
        return len(loops)

    def loops(self) -> list[LoopSpec]:
        """The stored registry, by loop name."""
        out = []
        for row in self.query("loops_all").iter_rows(named=True):
            row["issues"] = tuple(row["issues"] or ())
            row["span"] = math.nan if row["span"] is None else row["span"]
            row["description"] = row["description"] or ""
            row["sampling"] = row.get("sampling") or "point"
            out.append(LoopSpec(**row))
        return out

    # -- runs and results --------------------------------------------------
    def start_run(self, *, window_start: dt.datetime | None = None,
                  window_end: dt.datetime | None = None,
                  exports: str | Sequence[str] | None = None,
                  params: Mapping | None = None, run_id: str | None = None,
                  owner: str | None = None) -> str:
        """Register a scan with status ``running``; return its run id.

        Parameters
        ----------
        window_start, window_end : datetime, optional
            Timezone-aware analysis window of the scan.
        exports : str or sequence of str, optional
            The exports or globs the scan read (joined with ``;``).
        params : mapping, optional
            Scan parameters, stored as JSON (NaN -> null).
        run_id : str, optional
            Default ``<UTC time>-<8 hex>``, which sorts by time.
        owner : str, optional
            Who runs the scan, e.g. ``pid@host`` (:func:`valvediag.store.lock.owner_id`).
        """
        if run_id is None:
            now = dt.datetime.now(dt.timezone.utc)
            run_id = f"{now:%Y%m%dT%H%M%S}Z-{uuid.uuid4().hex[:8]}"
        if exports is not None and not isinstance(exports, str):
            exports = ";".join(os.fspath(e) for e in exports)
        self._run("run_start", run_id=run_id, window_start=aware_utc(window_start, "window_start"),
                  window_end=aware_utc(window_end, "window_end"), exports=exports,
                  params=_to_json(params or {}), owner=owner)
        return run_id

    def run(self, run_id: str) -> dict:
        """One run's row as a dict.

        Parameters
        ----------
        run_id : str
            The run.

        Raises
        ------
        KeyError
            No such run.
        """
        frame = self.query("run_get", run_id=run_id)
        if frame.is_empty():
            raise KeyError(f"no run {run_id!r} in {self.path}")
        return frame.row(0, named=True)

    def runs(self) -> pl.DataFrame:
        """All runs, oldest first."""
        return self.query("runs_all")

    def finish_run(self, run_id: str, status: str = "complete", note: str | None = None
                   ) -> None:
        """Mark a run ``complete``, ``partial``, ``failed`` or ``aborted`` and stamp
        ``finished_at``.

        Parameters
        ----------
        run_id : str
            The run (KeyError when unknown).
        status : {"complete", "partial", "failed", "aborted"}
            Only complete and partial runs (every step ran, but some export
            could not be read or stored nothing) count as history.
        note : str, optional
            Why it is partial, failed or was aborted (one line).
        """
        if status not in RUN_END_STATUSES:
            raise ValueError(f"run status must be one of {', '.join(RUN_END_STATUSES)}, "
                             f"not {status!r}")
        self.run(run_id)
        self._run("run_finish", run_id=run_id, status=status, note=note)

    def abort_stale_runs(self, note: str = "the scan's process died before the run finished"
                         ) -> list[dict]:
        """Mark every run still ``running`` as ``aborted``; return them.

        Call this only while holding the store's scan lock
        (:class:`valvediag.store.lock.ScanLock`): then no other scan is alive, so
        a run still ``running`` belongs to a scan whose process died (killed,
        crashed, power lost) and will never finish it.

        Parameters
        ----------
        note : str
            Stored in the runs' ``note``.

        Returns
        -------
        list of dict
            ``run_id`` and ``owner`` of each run aborted.
        """
        rows = self.con.execute(load_sql("runs_abort_stale"), {"note": note}).fetchall()
        return [{"run_id": r[0], "owner": r[1]} for r in rows]

    def write_results(self, run_id: str, episodes=None, verdicts=None) -> None:
        """Write a run's episodes and verdicts in one transaction.

        Parameters
        ----------
        run_id : str
            A run with status ``running``. Earlier results of the same run are
            replaced, so a retried task is idempotent.
        episodes, verdicts : polars.DataFrame or sequence of mappings, optional
            Columns from :data:`EPISODE_COLUMNS` / :data:`VERDICT_COLUMNS`
            (missing ones are NULL). ``evidence``/``quality`` may be dicts or
            dataclasses; they are stored as JSON (NaN -> null).

        Raises
        ------
        ValueError
            Unknown run, a run that is not running, unknown columns, or a
            verdict outside :data:`VERDICTS`.
        """
        status = self.run(run_id)["status"]
        if status != "running":
            raise ValueError(f"run {run_id!r} is {status}; its results can no longer change")
        ep = _result_frame(episodes, EPISODE_COLUMNS, run_id, "episodes")
        ve = _result_frame(verdicts, VERDICT_COLUMNS, run_id, "verdicts")
        bad = sorted(set(ve["verdict"].drop_nulls()) - set(VERDICTS))
        if bad or ve["verdict"].null_count():
            raise ValueError(f"verdicts: unknown verdict values {bad or [None]}; "
                             f"expected one of {', '.join(VERDICTS)}")
        dup = ve.filter(pl.col("loop").is_duplicated())["loop"].unique().to_list()
        if dup:
            raise ValueError(f"verdicts: more than one verdict for loops {sorted(dup)}")
        with self.transaction():
            self._run("episodes_delete_run", run_id=run_id)
            self._run("verdicts_delete_run", run_id=run_id)
            with self._registered("incoming_episodes", ep):
                self._run("episodes_insert")
            with self._registered("incoming_verdicts", ve):
                self._run("verdicts_insert")

    def verdicts(self, run_id: str | None = None) -> pl.DataFrame:
        """Verdicts of a run, by rank.

        Parameters
        ----------
        run_id : str, optional
            Default: the latest complete run.
        """
        return self.query("run_verdicts", run_id=run_id)

    def episodes(self, run_id: str) -> pl.DataFrame:
        """Episodes of a run, by loop and start.

        Parameters
        ----------
        run_id : str
            The run.
        """
        return self.query("run_episodes", run_id=run_id)

    def verdict_history(self, loop: str) -> pl.DataFrame:
        """A loop's verdicts over all complete runs, oldest first.

        Parameters
        ----------
        loop : str
            Loop name.
        """
        return self.query("verdict_history", loop=loop)

    def history_before(self, run_id: str, max_runs: int = 60) -> pl.DataFrame:
        """Every loop's verdicts in the latest complete runs before ``run_id``.

        Parameters
        ----------
        run_id : str
            The run to compare (it may still be running, or be unknown: then
            every complete run counts). Its own verdicts are not included.
        max_runs : int
            Most recent complete runs returned [-].

        Returns
        -------
        polars.DataFrame
            ``loop, run_id, started_at, window_end, verdict, confidence, bi,
            rank``, by loop and time (oldest first).
        """
        if max_runs < 1:
            raise ValueError(f"max_runs must be at least 1, not {max_runs!r}")
        return self.query("history_before_run", run_id=run_id, max_runs=int(max_runs))

    def new_faults(self, run_id: str) -> pl.DataFrame:
        """Loops that are faulty in run ``run_id`` and were not in the latest
        complete (or partial) run before it.

        A loop is listed when its verdict in ``run_id`` is one of
        :data:`valvediag.verdicts.FAULT_VERDICTS` and in the previous complete
        or partial run it was not (or the loop was absent, or there is no
        earlier such run). The run itself may still be running.
        """
        return self.query("new_faults_of_run", run_id=run_id, faults=list(FAULT_VERDICTS))

    def new_since_last_run(self) -> pl.DataFrame:
        """Loops that turned faulty in the latest complete (or partial) run (see
        :meth:`new_faults`)."""
        last = self.query("run_latest_complete")["run_id"].to_list()
        return self.new_faults(last[0] if last else "")

