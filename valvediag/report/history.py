"""
History across nights: which loops are new, which are repeats, which are resolved.

A loop's problem is **open** from the first run that found it needing action
until a run finds it healthy. :func:`plant_history` compares this run's
results with the verdicts of the earlier complete runs in the store:

* a loop needing action is a **repeat** when an earlier run found the same
  kind of problem and no run since found the loop healthy; its
  ``first_reported`` is the start of the earliest run of that unbroken
  stretch. Otherwise it is **new**. Valve faults (``stiction``,
  ``backlash``, ``undecided``) are one kind, whichever of them a night
  reported, because the valve is the same; a ``linear-oscillation`` (tuning
  or a disturbance) is another;
* a run that could not judge the loop (``insufficient-data``) or did not
  scan it neither closes nor extends the stretch: a historian outage does not
  close a work order;
* a loop is **resolved** when the previous complete run found it needing
  action and this run finds it healthy (``no-oscillation`` or
  ``not-integrating``), and **no longer assessable** when this run has
  ``insufficient-data`` for it.
"""
from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from ..plain import one_line
from ..verdicts import HEALTHY_VERDICTS, VALVE_NONLINEARITY

__all__ = ["HistoryPoint", "LoopHistory", "PlantHistory", "plant_history", "fault_kind"]

_UTC = dt.timezone.utc


def fault_kind(verdict: str) -> str | None:
    """``'valve'``, ``'oscillation'`` or None: the kind of work a verdict calls for.

    Parameters
    ----------
    verdict : str
        A loop verdict.
    """
    if verdict in VALVE_NONLINEARITY:
        return "valve"
    if verdict == "linear-oscillation":
        return "oscillation"
    return None


@dataclass(frozen=True)
class HistoryPoint:
    """One loop's verdict in one run.

    Attributes
    ----------
    run_id : str
    started_at : datetime or None
        Start of the run (UTC).
    verdict : str
    bi : float
        Backlash Index [-]; NaN when not measured.
    confidence : float
        [0-1]; NaN when unknown.
    current : bool
        True for the run being reported.
    """

    run_id: str
    started_at: dt.datetime | None
    verdict: str
    bi: float = math.nan
    confidence: float = math.nan
    current: bool = False


@dataclass(frozen=True)
class LoopHistory:
    """A loop's verdicts across runs and the status of its problem.

    Attributes
    ----------
    loop : str
    points : tuple of HistoryPoint
        Oldest first; the current run last.
    status : str
        ``'new'`` or ``'repeat'`` for a loop needing action, else ``''``.
    first_reported : datetime or None
        Start of the first run of the open stretch (this run's start for a
        new problem); None for a loop needing no action.
    first_run_id : str or None
        That run.
    open_runs : int
        Runs of the open stretch that found the problem (this one included).
    """

    loop: str
    points: tuple[HistoryPoint, ...] = ()
    status: str = ""
    first_reported: dt.datetime | None = None
    first_run_id: str | None = None
    open_runs: int = 0


@dataclass(frozen=True)
class PlantHistory:
    """This run compared with the earlier ones.

    Attributes
    ----------
    run_id : str
    started_at : datetime
        Start of this run (UTC).
    previous_run : dict or None
        ``run_id`` and ``started_at`` of the latest earlier complete run.
    loops : mapping of str to LoopHistory
        Every loop of this run.
    resolved : tuple of (str, str)
        (loop, verdict in the previous run): needed action then, healthy now.
    unassessable : tuple of (str, str)
        (loop, verdict in the previous run): needed action then, no usable
        data now.
    runs_compared : int
        Earlier complete runs read.
    error : str
        Why the history could not be read (the report says so); empty when
        it was.
    """

    run_id: str
    started_at: dt.datetime
    previous_run: dict | None = None
    loops: Mapping[str, LoopHistory] = field(default_factory=dict)
    resolved: tuple[tuple[str, str], ...] = ()
    unassessable: tuple[tuple[str, str], ...] = ()
    runs_compared: int = 0
    error: str = ""

    def of(self, loop: str) -> LoopHistory:
        """The history of ``loop`` (an empty one when unknown).

        Parameters
        ----------
        loop : str
        """
        return self.loops.get(loop) or LoopHistory(loop=loop)

    def with_status(self, status: str) -> list[str]:
        """Loops whose problem has this status (``'new'`` or ``'repeat'``).

        Parameters
        ----------
        status : str
        """
        return [k for k, h in self.loops.items() if h.status == status]


def _float_or_nan(x) -> float:
    return float(x) if x is not None and isinstance(x, (int, float)) and math.isfinite(x) \
        else math.nan


def _open_stretch(points: Sequence[HistoryPoint], kind: str) -> list[HistoryPoint]:
    """The earlier points (newest first) that belong to the open stretch of ``kind``."""
    stretch = []
    for p in reversed(points):
        k = fault_kind(p.verdict)
        if k == kind:
            stretch.append(p)
        elif p.verdict == "insufficient-data":
            continue
        else:
            break
    return stretch


def plant_history(results: Sequence, *, run_id: str, started_at: dt.datetime | None = None,
                  earlier=None, error: str = "") -> PlantHistory:
    """Compare this run's results with the earlier runs.

    Parameters
    ----------
    results : sequence of valvediag.scan.LoopResult
        This run's results.
    run_id : str
        This run.
    started_at : datetime, optional
        Start of this run (default: now, UTC).
    earlier : polars.DataFrame, optional
        Earlier verdicts as :meth:`valvediag.store.Store.history_before`
        returns them; None (no store) makes every loop needing action new.
    error : str
        Why ``earlier`` is missing, shown in the report.

    Returns
    -------
    PlantHistory
    """
    started_at = (started_at or dt.datetime.now(_UTC)).astimezone(_UTC)
    by_loop: dict[str, list[HistoryPoint]] = {}
    runs: dict[str, dt.datetime | None] = {}
    if earlier is not None and earlier.height:
        for row in earlier.iter_rows(named=True):
            t = row["started_at"]
            runs[row["run_id"]] = t
            by_loop.setdefault(row["loop"], []).append(HistoryPoint(
                run_id=row["run_id"], started_at=t, verdict=row["verdict"],
                bi=_float_or_nan(row["bi"]), confidence=_float_or_nan(row["confidence"])))
    previous = None
    if runs:
        pid = max(runs, key=lambda k: (runs[k] or dt.datetime.min.replace(tzinfo=_UTC), k))
        previous = {"run_id": pid, "started_at": runs[pid]}
    loops: dict[str, LoopHistory] = {}
    resolved, unassessable = [], []
    for r in results:
        past = by_loop.get(r.loop, [])
        now = HistoryPoint(run_id=run_id, started_at=started_at, verdict=r.verdict,
                           bi=_float_or_nan(r.bi), confidence=_float_or_nan(r.confidence), current=True)
        points = tuple(past) + (now,)
        kind = fault_kind(r.verdict)
        if kind is None:
            loops[r.loop] = LoopHistory(loop=r.loop, points=points)
            last = next((p for p in reversed(past) if previous and p.run_id == previous["run_id"]),
                        None)
            if last is not None and fault_kind(last.verdict) is not None:
                (resolved if r.verdict in HEALTHY_VERDICTS else unassessable).append(
                    (r.loop, last.verdict))
            continue
        stretch = _open_stretch(past, kind)
        first = stretch[-1] if stretch else now
        loops[r.loop] = LoopHistory(loop=r.loop, points=points,
                                    status="repeat" if stretch else "new",
                                    first_reported=first.started_at, first_run_id=first.run_id,
                                    open_runs=len(stretch) + 1)
    return PlantHistory(run_id=run_id, started_at=started_at, previous_run=previous,
                        loops=loops, resolved=tuple(sorted(resolved)),
                        unassessable=tuple(sorted(unassessable)), runs_compared=len(runs),
                        error=error)


def read_history(store, results: Sequence, *, run_id: str, started_at: dt.datetime | None = None,
                 max_runs: int = 60) -> PlantHistory:
    """:func:`plant_history` with the earlier verdicts read from a store.

    Parameters
    ----------
    store : str, path-like or valvediag.store.Store
        The DuckDB store (a path is opened read-only for the call).
    results : sequence of valvediag.scan.LoopResult
        This run's results.
    run_id : str
        This run; its start time is read from the store when it is there.
    started_at : datetime, optional
        Start of this run when the store does not know it (default now).
    max_runs : int
        Earlier complete runs compared [-].

    Returns
    -------
    PlantHistory
        With ``error`` set (and no history) when the store cannot be read,
        for example while another process holds it: the report is written
        all the same.
    """
    import os

    import duckdb

    from ..store.database import Store, StoreLockedError

    def compare(st: Store) -> PlantHistory:
        known = st.query("run_started", run_id=run_id)["started_at"].to_list()
        start = known[0] if known and known[0] is not None else started_at
        return plant_history(results, run_id=run_id, started_at=start,
                             earlier=st.history_before(run_id, max_runs=max_runs))

    try:
        if isinstance(store, Store):
            return compare(store)
        try:
            st = Store(store, read_only=True)
        except duckdb.ConnectionException:   # this process holds it read-write
            st = Store(store)
        with st:
            return compare(st)
    except (StoreLockedError, duckdb.Error, OSError) as exc:
        why = one_line(exc)
        name = os.fspath(store.path if isinstance(store, Store) else store)
        return plant_history(results, run_id=run_id, started_at=started_at,
                             error=f"the history in {name} could not be read: {why}")
