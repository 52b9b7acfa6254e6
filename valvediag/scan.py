"""
The plant scan: every loop of the registry, from historian data to ranked verdicts.

This module is the scan as plain library code. The nightly Prefect flow
(``pipelines/``) and the ``valvediag scan`` command call the same functions;
nothing here imports Prefect. The steps, each a function a flow can make a
task of::

    jobs = plan_loops(store, loops, config)            # window and problems per loop
    frames = load_loop_frames(db_path, job)            # one loop's samples (read only)
    result = analyse_loop(job, frames, config)         # pure numerics, no store
    results = rank_results(results)                    # rank 1 = most severe fault
    persist_results(store, run_id, results)            # DuckDB: verdicts, episodes
    write_outputs(results, out_dir, run_id=..., run_info=...)   # json, csv, html

:func:`run_scan` does all of it in one process, ingest included.

Per loop, over the scan window (default: the latest 24 h of the loop's data):

1. **Alignment.** PV, OP and SP go on a uniform grid
   (:func:`valvediag.align.align_loop`): the grid step is the PV's median
   sample spacing and the grid is in phase with the PV's samples (so they are
   taken as they are, not interpolated, which would round the peaks);
   compressed analog values are interpolated linearly; a
   bad-state row or an interval much longer than the tag's own usual spacing
   (:func:`valvediag.align.tag_max_gap`) splits the data into segments. The
   quality screen (:func:`valvediag.quality.quality_metrics`) runs on the same
   grid.
2. **Episodes.** Every segment of at least :data:`MIN_SEGMENT_SAMPLES` valid
   points and :data:`MIN_SEGMENT_S` seconds is classified with :func:`valvediag.classify.classify_loop`. A
   segment whose oscillation is established (see :data:`EPISODE_VERDICTS`)
   is then screened in blocks of :data:`BLOCK_PERIODS` periods: a block is
   *active* when its half range is at least :data:`ACTIVE_AMPLITUDE` of the
   segment's amplitude and its autocorrelation one period on is above
   :data:`ACTIVE_ACF`. When the active blocks cover at least
   :data:`SPLIT_COVERAGE` of the segment, the segment is one episode;
   otherwise each run of active blocks lasting ``min_cycles`` periods or more
   is classified on its own and becomes an episode. Each episode keeps its
   time span, period, amplitude, regularity, verdict, BI and confidence.
3. **Integrating screen.** ``process_type`` from ``loops.csv`` is used when it
   is ``integrating`` or ``self-regulating``; for ``unknown`` the classifier's
   data test decides, and its result (``process_screen``) and ramp ratio are
   in the evidence.
4. **Loop verdict.** Episodes vote with weight ``duration x confidence``. The
   verdict with the largest weight wins; its confidence is the weighted mean
   confidence of the episodes that voted for it, times the share of the total
   weight they hold (so conflicting episodes lower it). Episodes that could
   only say ``insufficient-data`` vote only when no other episode exists. The
   loop's BI, period, amplitude and regularity are those of the winning
   episode with the largest weight. A loop without episodes takes the verdict
   of its longest segment (``no-oscillation``, ``insufficient-data``, ...),
   but ``no-oscillation`` needs usable data over at least
   ``config.min_coverage`` of the window: below that it is
   ``insufficient-data``. Compressed PV data lower the confidence
   (:data:`COMPRESSION_PENALTY`) and the reason says so.
5. **Severity and rank.** See :func:`severity`. Loops whose verdict calls for
   action (:data:`ACTION_VERDICTS`) are ranked 1, 2, ... by decreasing
   severity; all other loops have no rank, so every fault ranks above every
   healthy loop.
6. **Every loop gets a verdict.** A loop without a PV or OP tag in
   ``loops.csv``, whose tags have no samples in the window, or whose samples
   are all bad states is ``insufficient-data`` with the reason.

References
----------
.. [1] Farenzena, M., Trierweiler, J. O. (2012). Valve backlash and stiction
   detection in integrating processes. ADCHEM 2012, Singapore, 320-325.
.. [2] Thornhill, N. F., Huang, B., Zhang, H. (2003). Detection of multiple
   oscillations in control loops. J. Process Control 13, 91-100.
"""
from __future__ import annotations

import dataclasses
import datetime as dt
import logging
import math
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .align import AlignedLoop, align_loop, median_spacing, to_epoch_us
from .classify import LoopDiagnosis, classify_loop
from .quality import DataQuality, quality_metrics
from .registry import LoopSpec

if TYPE_CHECKING:  # pragma: no cover
    import polars as pl

    from .ingest import IngestReport
    from .store import Store

__all__ = [
    "ScanConfig", "LoopJob", "Episode", "LoopTrend", "LoopDetail", "LoopResult", "ScanSummary",
    "plan_loops", "load_loop_frames", "analyse_loop", "analyse_stored_loops", "rank_results",
    "persist_results",
    "run_scan", "severity", "valve_fault_size", "ACTION_VERDICTS", "VALVE_FAULTS", "EPISODE_VERDICTS",
]

#: Verdicts that call for action: they get a rank and a work order.
ACTION_VERDICTS = ("stiction", "backlash", "linear-oscillation", "undecided")
#: Verdicts that are valve faults.
VALVE_FAULTS = ("stiction", "backlash")
#: Verdicts that establish an oscillation (an episode).
EPISODE_VERDICTS = ("not-integrating", "linear-oscillation", "stiction", "backlash", "undecided")
_ORDER = ("stiction", "backlash", "undecided", "linear-oscillation", "not-integrating",
          "no-oscillation", "insufficient-data")

#: Shortest segment classified: at least this many grid points and seconds.
#: Over a few dozen samples noise can pass for a short regular oscillation.
MIN_SEGMENT_SAMPLES = 64
MIN_SEGMENT_S = 600.0
#: Block length of the activity screen inside a segment [periods].
BLOCK_PERIODS = 4.0
#: A block is active when its half range reaches this share of the segment amplitude ...
ACTIVE_AMPLITUDE = 0.4
#: ... and its autocorrelation at one period lag exceeds this.
ACTIVE_ACF = 0.3
#: A segment whose active blocks cover at least this share is one episode.
SPLIT_COVERAGE = 0.75
#: Confidence factor for a compressed PV, and for one with fewer than
#: :data:`MIN_RAW_PER_CYCLE` raw samples per period.
COMPRESSION_PENALTY = (0.9, 0.7)
MIN_RAW_PER_CYCLE = 10.0
#: Severity: amplitude scale [% of span] and the largest criticality weight.
AMPLITUDE_SCALE_PCT = 5.0
MAX_CRITICALITY = 10.0
#: Loops read from the store in one query by :func:`analyse_stored_loops` [-].
READ_LOOPS = 10
#: Buckets of the PV sparkline kept for every loop (min and max of each) [-].
SPARK_BUCKETS = 48
#: Buckets of the PV/OP/SP trend kept for a loop needing action (two points each) [-].
TREND_BUCKETS = 720

_SECOND = dt.timedelta(seconds=1)
_UTC = dt.timezone.utc


# ----------------------------------------------------------------- contracts

_log = logging.getLogger(__name__)

def _aware(value: dt.datetime | None, what: str) -> dt.datetime | None:
    if value is None:
        return None
    if not isinstance(value, dt.datetime):
        raise TypeError(f"{what} must be a datetime, not {type(value).__name__}")
    if value.tzinfo is None or value.utcoffset() is None:
        raise ValueError(f"{what} {value.isoformat()} has no time zone; give an aware datetime")
    return value.astimezone(_UTC)


def _clean(obj):
    """Plain JSON values: NaN/inf -> None, numpy -> Python, datetimes -> ISO 8601."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = obj.to_json() if hasattr(obj, "to_json") else dataclasses.asdict(obj)
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, np.generic):
        return _clean(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (dt.datetime, dt.date)):
        return obj.isoformat()
    if isinstance(obj, Path):
        return os.fspath(obj)
    return obj


@dataclass(frozen=True)
class ScanConfig:
    """Parameters of a plant scan.

    Attributes
    ----------
    window_hours : float, default 24.0
        Length of the analysis window [h].
    end : datetime, optional
        End of the window (timezone-aware) for every loop. Default: each
        loop's latest sample (its PV's, else its OP's).
    method : {'robust', 'paper'}
        Backlash Index estimator (see :func:`valvediag.bi.backlash_index`).
    min_cycles : float, default 3.0
        Fewest complete cycles for a verdict on the valve [-].
    timezone : str, optional
        IANA zone of naive time stamps in the exports (ingest only).
    max_gap_s : float, optional
        Longest interval bridged by interpolation, for every tag [s]. Default:
        per tag from its own spacing (:func:`valvediag.align.tag_max_gap`).
    min_coverage : float, default 0.1
        Share of the window that must hold usable data before a loop without
        any oscillation is called ``no-oscillation`` rather than
        ``insufficient-data`` [-].
    size_estimate : bool, default True
        Fit the workbench's loop model to every ``stiction`` or ``backlash``
        loop and put the fault's size on it (dead band, or Kano S and J, in
        OP units; :func:`valvediag.workbench.estimate_valve_size`). About a
        second per faulty loop for a day at 1 s.

    Raises
    ------
    ValueError
        A non-positive window, ``min_cycles`` or ``max_gap_s``, an unknown
        method, a naive ``end`` or ``min_coverage`` outside [0, 1].
    """

    window_hours: float = 24.0
    end: dt.datetime | None = None
    method: str = "robust"
    min_cycles: float = 3.0
    timezone: str | None = None
    max_gap_s: float | None = None
    min_coverage: float = 0.1
    size_estimate: bool = True

    def __post_init__(self):
        if not (isinstance(self.window_hours, (int, float)) and math.isfinite(self.window_hours)
                and self.window_hours > 0):
            raise ValueError(f"window_hours must be a positive number, not {self.window_hours!r}")
        if self.method not in ("robust", "paper"):
            raise ValueError(f"method must be 'robust' or 'paper', not {self.method!r}")
        if not (math.isfinite(self.min_cycles) and self.min_cycles > 0):
            raise ValueError(f"min_cycles must be positive, not {self.min_cycles!r}")
        if self.max_gap_s is not None and not (math.isfinite(self.max_gap_s)
                                               and self.max_gap_s > 0):
            raise ValueError(f"max_gap_s must be positive seconds or None, not {self.max_gap_s!r}")
        if not 0.0 <= self.min_coverage <= 1.0:
            raise ValueError(f"min_coverage must lie in [0, 1], not {self.min_coverage!r}")
        object.__setattr__(self, "end", _aware(self.end, "end"))

    @property
    def window(self) -> dt.timedelta:
        """The window length."""
        return dt.timedelta(hours=self.window_hours)

    def to_json(self) -> dict:
        """The parameters as plain JSON values."""
        return _clean(dataclasses.asdict(self))


@dataclass(frozen=True)
class LoopJob:
    """One loop to analyse, over one window.

    Attributes
    ----------
    spec : LoopSpec
        The loop's registry row.
    start, end : datetime
        Window ``[start, end)`` in UTC.
    problems : tuple of str
        What limits the analysis, known before reading the data: the registry
        row's issues and tags with no sample at all in the store.
    """

    spec: LoopSpec
    start: dt.datetime
    end: dt.datetime
    problems: tuple[str, ...] = ()


@dataclass(frozen=True)
class Episode:
    """A stretch of one loop's window with one oscillation and one verdict.

    Attributes
    ----------
    start, end : datetime
        Time span (UTC).
    period_s : float
        Oscillation period [s].
    amplitude : float
        Half peak-to-peak amplitude [PV unit].
    regularity : float
        Thornhill regularity [-] (> 1: regular).
    verdict : str
        The classifier's verdict on this stretch.
    bi : float
        Backlash Index [-], NaN when not measured.
    confidence : float
        [0-1]
    """

    start: dt.datetime
    end: dt.datetime
    period_s: float
    amplitude: float
    regularity: float
    verdict: str
    bi: float
    confidence: float

    @property
    def duration_s(self) -> float:
        """Length [s]."""
        return (self.end - self.start).total_seconds()

    def to_json(self) -> dict:
        """Plain JSON values (NaN -> None, times as ISO 8601)."""
        return _clean({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})


def _bucket_extremes(y: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Per bucket of ``k`` points: (first extreme, second extreme) in time order; NaN if empty."""
    nb = -(-y.size // k)
    pad = np.full(nb * k, np.nan)
    pad[:y.size] = y
    blocks = pad.reshape(nb, k)
    empty = np.isnan(blocks).all(axis=1)
    lo_i = np.argmin(np.where(np.isnan(blocks), np.inf, blocks), axis=1)
    hi_i = np.argmax(np.where(np.isnan(blocks), -np.inf, blocks), axis=1)
    rows = np.arange(nb)
    lo, hi = blocks[rows, lo_i], blocks[rows, hi_i]
    first = np.where(lo_i <= hi_i, lo, hi)
    second = np.where(lo_i <= hi_i, hi, lo)
    first[empty] = np.nan
    second[empty] = np.nan
    return first, second


def _reduce(y: np.ndarray | None, buckets: int) -> np.ndarray | None:
    """``y`` reduced to two points (its extremes, in time order) per bucket, as float32."""
    if y is None:
        return None
    y = np.asarray(y, dtype=float)
    k = max(1, -(-y.size // buckets))
    if k == 1:
        return y.astype(np.float32)
    a, b = _bucket_extremes(y, k)
    return np.column_stack([a, b]).ravel().astype(np.float32)


@dataclass(frozen=True)
class LoopTrend:
    """A loop's PV, OP and SP over the analysis window, reduced for plotting.

    Every bucket of ``step`` grid points keeps two points: the extremes of the
    bucket in the order they occur, so a trace drawn through them looks like
    the full-resolution one (the oscillation's band stays visible). NaN marks
    invalid data (gaps, bad states), which breaks the drawn line.

    Attributes
    ----------
    start : datetime
        Time of ``t = 0`` (UTC): the grid's first point.
    t : numpy.ndarray
        Time of every point since ``start`` [s].
    pv : numpy.ndarray
        Process variable [PV unit].
    op : numpy.ndarray or None
        Controller output [%].
    sp : numpy.ndarray or None
        Set point [PV unit].
    sample_time : float
        Spacing of the analysis grid [s].
    step : int
        Grid points per bucket (1: not reduced).
    """

    start: dt.datetime
    t: np.ndarray = field(repr=False)
    pv: np.ndarray = field(repr=False)
    op: np.ndarray | None = field(default=None, repr=False)
    sp: np.ndarray | None = field(default=None, repr=False)
    sample_time: float = 1.0
    step: int = 1

    @classmethod
    def from_aligned(cls, aligned: AlignedLoop, buckets: int = TREND_BUCKETS) -> LoopTrend:
        """Reduce an aligned loop to at most ``2 * buckets`` points per signal.

        Parameters
        ----------
        aligned : valvediag.align.AlignedLoop
            The loop on its grid (invalid points NaN).
        buckets : int
            Number of buckets [-].

        Returns
        -------
        LoopTrend
        """
        h = aligned.sample_time
        k = max(1, -(-aligned.n // buckets))
        pv = np.where(aligned.role_valid.get("pv", np.isfinite(aligned.pv)), aligned.pv, np.nan)
        if k == 1:
            t = np.arange(aligned.n) * h
        else:
            nb = -(-aligned.n // k)
            t = (np.arange(nb)[:, None] * k + np.array([0.25, 0.75]) * k).ravel() * h
        return cls(start=aligned.start, t=t.astype(np.float64), pv=_reduce(pv, buckets),
                   op=_reduce(aligned.op, buckets), sp=_reduce(aligned.sp, buckets),
                   sample_time=h, step=k)

    def times(self) -> np.ndarray:
        """The points' times as ``datetime64[ms]`` (UTC, naive)."""
        t0 = np.datetime64(self.start.astimezone(_UTC).replace(tzinfo=None), "ms")
        return t0 + np.round(self.t * 1e3).astype("timedelta64[ms]")

    def plot(self, ax=None, *, episodes: Sequence[Episode] = (), highlight: int | None = None,
             op_ax=None):
        """PV and SP against time, episodes shaded; OP below or on a twin axis.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Axes of the PV and SP.
        episodes : sequence of Episode
            Oscillating stretches to shade.
        highlight : int, optional
            Index into ``episodes`` of the one shaded darker (the one behind
            the verdict).
        op_ax : matplotlib.axes.Axes, optional
            Axes of the OP (e.g. a panel below sharing the time axis);
            default a twin of ``ax`` with its own scale on the right.

        Returns
        -------
        matplotlib.axes.Axes
            The PV axes.
        """
        import matplotlib.dates as mdates
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(10, 3))
        x = self.times()
        axes = [ax] if op_ax is None else [ax, op_ax]
        for j, e in enumerate(episodes):
            a = np.datetime64(e.start.astimezone(_UTC).replace(tzinfo=None), "ms")
            b = np.datetime64(e.end.astimezone(_UTC).replace(tzinfo=None), "ms")
            for k, each in enumerate(axes):
                each.axvspan(a, b, color="#f8c471" if j == highlight else "#fdf2e0", lw=0,
                             zorder=0, label="oscillating" if k == 0 and j == 0 else None)
        ax.plot(x, self.pv, color="#1f5fa8", lw=0.7, label="PV", zorder=3)
        if self.sp is not None and np.isfinite(self.sp).any():
            ax.plot(x, self.sp, color="black", lw=0.9, ls="--", label="SP", zorder=4)
        ax.set_ylabel("PV")
        if self.op is not None:
            if op_ax is None:
                op_ax = ax.twinx()
            op_ax.plot(x, self.op, color="#d35400", lw=0.6, label="OP")
            op_ax.set_ylabel("OP [%]")
        loc = mdates.AutoDateLocator(minticks=3, maxticks=7)
        ax.xaxis.set_major_locator(loc)
        ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc, show_offset=False))
        if x.size:
            ax.set_xlim(x[0], x[-1])
        ax.legend(loc="upper left", fontsize=6.5, ncol=3, framealpha=0.8)
        return ax


@dataclass(frozen=True)
class LoopDetail:
    """What a report draws for one loop; kept on the result object only.

    Neither :meth:`LoopResult.to_json` nor the store see it: it holds arrays.

    Attributes
    ----------
    sparkline : numpy.ndarray or None
        PV over the window, two points (the extremes in time order) per
        bucket of :data:`SPARK_BUCKETS`; NaN where no valid data [PV unit].
    trend : LoopTrend or None
        PV, OP and SP over the window, for loops needing action.
    diagnosis : valvediag.classify.LoopDiagnosis or None
        The classification of the episode behind the verdict (with its
        oscillation, Backlash Index and cycle shape), for loops needing action.
    diagnosis_start, diagnosis_end : datetime or None
        Time span of the data of ``diagnosis`` (UTC).
    """

    sparkline: np.ndarray | None = field(default=None, repr=False)
    trend: LoopTrend | None = field(default=None, repr=False)
    diagnosis: LoopDiagnosis | None = field(default=None, repr=False)
    diagnosis_start: dt.datetime | None = None
    diagnosis_end: dt.datetime | None = None


@dataclass(frozen=True)
class LoopResult:
    """The scan's verdict on one loop.

    Attributes
    ----------
    loop : str
        Loop name.
    unit : str or None
        PV engineering unit.
    verdict : str
        One of :data:`valvediag.classify.VERDICTS`.
    confidence : float
        [0-1]
    severity : float
        See :func:`severity`; 0 for loops that do not oscillate [-].
    rank : int or None
        1 = most severe loop needing action; None for loops needing none.
        Set by :func:`rank_results`.
    process_type : str
        ``integrating``, ``self-regulating`` or ``unknown``: from the registry
        when it says, else from the data test.
    bi : float
        Backlash Index [-]; NaN when not measured.
    period_s : float
        Oscillation period [s]; NaN when none.
    amplitude : float
        Half peak-to-peak amplitude [PV unit]; NaN when none.
    amplitude_pct_span : float
        ``amplitude`` in % of the span [%].
    regularity : float
        Thornhill regularity [-].
    reason : str
        One or two sentences explaining the verdict.
    evidence : dict
        The figures behind the verdict (JSON-serialisable).
    quality : dict
        Data-quality figures (:class:`valvediag.quality.DataQuality`), with
        ``issues`` listing the findings.
    episodes : tuple of Episode
        Oscillating stretches, by time.
    window_start, window_end : datetime
        The analysis window (UTC).
    description : str
        From the registry.
    criticality : float
        Ranking weight from the registry [-].
    size : dict or None
        Size of a valve fault (``stiction``/``backlash`` only): ``DB`` or
        ``S`` and ``J`` [OP unit], with ``fit_pct``, ``confidence`` and
        ``reason`` (see :func:`valvediag.workbench.estimate_valve_size`).
    detail : LoopDetail or None
        Plot data for the report (sparkline for every analysed loop; trend
        and diagnosis for loops needing action). Not part of :meth:`to_json`,
        of equality or of the store.
    """

    loop: str
    unit: str | None
    verdict: str
    confidence: float
    severity: float
    rank: int | None
    process_type: str
    bi: float
    period_s: float
    amplitude: float
    amplitude_pct_span: float
    regularity: float
    reason: str
    evidence: dict
    quality: dict
    episodes: tuple[Episode, ...]
    window_start: dt.datetime
    window_end: dt.datetime
    description: str = ""
    criticality: float = 1.0
    size: dict | None = None
    detail: LoopDetail | None = field(default=None, repr=False, compare=False)

    @property
    def needs_action(self) -> bool:
        """True for the verdicts that get a work order (:data:`ACTION_VERDICTS`)."""
        return self.verdict in ACTION_VERDICTS

    def to_json(self) -> dict:
        """Every field but ``detail`` as plain JSON values (NaN -> None, times as ISO 8601)."""
        return _clean({f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                       if f.name != "detail"})


@dataclass(frozen=True)
class ScanSummary:
    """What :func:`run_scan` did.

    Attributes
    ----------
    run_id : str
        The run in the store.
    results : tuple of LoopResult
        Ranked (as :func:`rank_results` orders them).
    outputs : dict of str to Path
        ``verdicts``, ``work_orders``, ``report``.
    ingest : IngestReport
        The ingest of the exports.
    registry_problems : tuple of str
        One line per problem found in ``loops.csv``.
    new_faults : tuple of str
        Loops that turned faulty since the previous complete run
        (:meth:`valvediag.store.Store.new_since_last_run`).
    ingest_s, analysis_s : float
        Wall time of the ingest and of the analysis [s].
    """

    run_id: str
    results: tuple[LoopResult, ...]
    outputs: dict
    ingest: IngestReport
    registry_problems: tuple[str, ...] = ()
    new_faults: tuple[str, ...] = ()
    ingest_s: float = 0.0
    analysis_s: float = 0.0

    @property
    def counts(self) -> dict[str, int]:
        """Loops per verdict."""
        out: dict[str, int] = {}
        for r in self.results:
            out[r.verdict] = out.get(r.verdict, 0) + 1
        return out

    @property
    def errors(self) -> tuple[str, ...]:
        """One line per export file that could not be read."""
        return tuple(self.ingest.errors)


# ------------------------------------------------------------------ planning

def plan_loops(store: Store, loops: Sequence[LoopSpec], config: ScanConfig = ScanConfig()
               ) -> list[LoopJob]:
    """Decide every loop's window and note what is missing, before reading data.

    Parameters
    ----------
    store : valvediag.store.Store
        The store holding the samples.
    loops : sequence of LoopSpec
        The registry (every loop gets a job, even one without tags).
    config : ScanConfig
        ``window_hours`` and ``end`` are used.

    Returns
    -------
    list of LoopJob
        In registry order.

    Notes
    -----
    Without ``config.end`` a loop's window ends at the first whole second
    after its latest PV sample (bad or good), else its latest OP sample, else
    the latest sample of the whole store (a loop with no data at all); the
    window ``[start, end)`` thus holds that sample. One query reads the latest
    time stamp of every tag.
    """
    latest = store.latest_timestamps()
    last = dict(zip(latest["tag"].to_list(), latest["last_ts"].to_list()))
    plant_end = max(last.values()) if last else dt.datetime.now(_UTC)
    jobs = []
    for spec in loops:
        problems = list(spec.issues)
        for role, tag in spec.tags.items():
            if tag not in last:
                problems.append(f"{role.upper()} tag {tag} not found in the exports")
        if config.end is not None:
            end = config.end
        else:
            latest_ts = (last.get(spec.pv_tag) or last.get(spec.op_tag) or plant_end)
            end = latest_ts.astimezone(_UTC).replace(microsecond=0) + _SECOND
        end = end.astimezone(_UTC)
        jobs.append(LoopJob(spec=spec, start=end - config.window, end=end,
                            problems=tuple(problems)))
    return jobs


def load_loop_frames(db_path, job: LoopJob) -> dict[str, pl.DataFrame]:
    """Read one loop's samples over its window.

    Parameters
    ----------
    db_path : str, path-like or valvediag.store.Store
        The DuckDB file (opened read-only for the call), or an open store.
    job : LoopJob
        The loop and window.

    Returns
    -------
    dict of str to polars.DataFrame
        Role -> ``ts, value, status`` (see
        :meth:`valvediag.store.Store.fetch_loop`); set point and mode include
        their last sample before the window.

    Notes
    -----
    DuckDB lets one process write a file and refuses every other process,
    even read-only. Call this from worker processes only while no process
    holds the file for writing, or from threads of the writing process: when
    this process already has the file open read-write, the call shares that
    database instead of failing.
    """
    from .store import Store

    if isinstance(db_path, Store):
        return db_path.fetch_loop(job.spec, job.start, job.end)
    import duckdb

    try:
        store = Store(db_path, read_only=True)
    except duckdb.ConnectionException:  # this process holds it read-write
        store = Store(db_path)
    with store:
        return store.fetch_loop(job.spec, job.start, job.end)


def analyse_stored_loops(db_path, jobs: Sequence[LoopJob], config: ScanConfig = ScanConfig()
                         ) -> list[LoopResult]:
    """Read and diagnose several loops with one connection to the store.

    Parameters
    ----------
    db_path : str or path-like
        The DuckDB file, opened once for all ``jobs`` (read-only, or shared
        with this process's writer as in :func:`load_loop_frames`).
    jobs : sequence of LoopJob
        The loops and windows.
    config : ScanConfig
        As for :func:`analyse_loop`.

    Returns
    -------
    list of LoopResult
        In the order of ``jobs``; unranked.

    Notes
    -----
    The loops are read :data:`READ_LOOPS` at a time, each group in one
    query (:func:`valvediag.partition.fetch_loop_windows`, the frames
    :func:`load_loop_frames` reads): reading them tag by tag scanned the
    same row groups once per tag (0.19 s per loop-day at 1 s on a store of
    149 M samples). While a group is read and converted its samples are in
    memory a few times over: a worker peaked at 1.07 GB reading 20
    loop-days at 1 s at once, 0.84 GB reading 10 and 0.71 GB reading 5.
    """
    import duckdb

    from .partition import fetch_loop_windows
    from .store import Store

    if not jobs:
        return []
    try:
        store = Store(db_path, read_only=True)
    except duckdb.ConnectionException:  # this process holds it read-write
        store = Store(db_path)
    results = []
    with store:
        for k0 in range(0, len(jobs), READ_LOOPS):
            chunk = jobs[k0:k0 + READ_LOOPS]
            frames = fetch_loop_windows(store, chunk)
            for k, job in enumerate(chunk):
                results.append(analyse_loop(job, frames[k], config))
                frames[k] = None      # free each loop's samples once analysed
    return results


# ------------------------------------------------------------------ analysis

def severity(amplitude_pct_span: float, regularity: float, time_share: float,
             criticality: float) -> tuple[float, dict]:
    """Severity of an oscillating loop: how much it matters to fix it.

    ``severity = f_amp * f_reg * f_time * f_crit`` with

    * ``f_amp = 1 - exp(-a / 5)``, ``a`` the amplitude in % of span: 0.18 at
      1 %, 0.63 at 5 %, 0.86 at 10 % (bounded by 1);
    * ``f_reg = r / (1 + r)``, ``r`` Thornhill's regularity: 0.5 at the
      regularity limit r = 1, 0.9 at r = 9 (bounded by 1);
    * ``f_time``: share of the window spent in oscillating episodes [0-1];
    * ``f_crit = min(criticality, 10)``: the registry's weight (default 1).

    Parameters
    ----------
    amplitude_pct_span : float
        Half peak-to-peak amplitude [% of span].
    regularity : float
        Thornhill regularity [-].
    time_share : float
        Share of the window oscillating [-].
    criticality : float
        Registry weight [-], >= 0.

    Returns
    -------
    severity : float
        In [0, 10]; 0 when any factor is missing (NaN).
    factors : dict
        ``f_amp, f_reg, f_time, f_crit``.

    Notes
    -----
    The factors multiply, so a loop must be large, regular, persistent and
    critical to rank first. The amplitude is relative to the span from
    ``loops.csv``; without one, to the PV's robust range in the window, which
    makes the amplitude factor large (the range is then mostly the
    oscillation itself); the evidence says which span was used.
    """
    def num(x):
        return float(x) if x is not None and math.isfinite(float(x)) else math.nan

    a, r, s, c = num(amplitude_pct_span), num(regularity), num(time_share), num(criticality)
    f = {"f_amp": 1.0 - math.exp(-max(a, 0.0) / AMPLITUDE_SCALE_PCT) if a == a else math.nan,
         "f_reg": max(r, 0.0) / (1.0 + max(r, 0.0)) if r == r else math.nan,
         "f_time": min(max(s, 0.0), 1.0) if s == s else math.nan,
         "f_crit": min(max(c, 0.0), MAX_CRITICALITY) if c == c else 1.0}
    value = f["f_amp"] * f["f_reg"] * f["f_time"] * f["f_crit"]
    return (round(value, 6) if math.isfinite(value) else 0.0), f


def _utc(aligned: AlignedLoop, k: int) -> dt.datetime:
    return aligned.start + dt.timedelta(seconds=float(k) * aligned.sample_time)


def _block_activity(y: np.ndarray, h: float, period: float, amplitude: float
                    ) -> list[tuple[int, int]]:
    """Runs of active blocks of ``BLOCK_PERIODS`` periods, as (start, stop) indices into ``y``.

    Each block has its least-squares line removed; it is active when half its
    2-98 % range is at least ``ACTIVE_AMPLITUDE * amplitude`` and its
    autocorrelation one period on exceeds ``ACTIVE_ACF``. The last block
    takes the remainder. The blocks of equal length are screened together
    as the rows of one matrix (a closed-form line fit instead of
    ``np.polyfit`` per block: the same line to rounding).
    """
    n = y.size
    L = int(round(BLOCK_PERIODS * period / h))
    lag = int(round(period / h))
    if L < 8 or n < 2 * L or not (amplitude > 0):
        return [(0, n)]
    nb = n // L
    edges = [k * L for k in range(nb)] + [n]
    y = np.asarray(y, dtype=float)
    active = np.concatenate([_active_blocks(y[:(nb - 1) * L].reshape(nb - 1, L), lag, amplitude),
                             _active_blocks(y[(nb - 1) * L:][None, :], lag, amplitude)]).tolist()
    runs, start = [], None
    for k, on in enumerate(active + [False]):
        if on and start is None:
            start = k
        elif not on and start is not None:
            runs.append((edges[start], edges[k]))
            start = None
    return runs


def _active_blocks(Y: np.ndarray, lag: int, amplitude: float) -> np.ndarray:
    """Activity of each row of ``Y`` (blocks of equal length), see :func:`_block_activity`."""
    m = Y.shape[1]
    t = np.arange(m, dtype=float)
    tc = t - t.mean()
    ym = Y.mean(axis=1, keepdims=True)
    slope = ((Y - ym) @ tc / (tc @ tc))[:, None]
    seg = Y - (ym + slope * tc)
    lo, hi = np.percentile(seg, [2, 98], axis=1)
    big = 0.5 * (hi - lo) >= ACTIVE_AMPLITUDE * amplitude
    x0, x1 = seg[:, :-lag], seg[:, lag:]
    den = np.sqrt(np.einsum("ij,ij->i", x0, x0) * np.einsum("ij,ij->i", x1, x1))
    num = np.einsum("ij,ij->i", x0, x1)
    acf = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    return big & (acf > ACTIVE_ACF)


def _classify(aligned, a, b, process_type, config) -> LoopDiagnosis:
    sp = aligned.sp[a:b] if aligned.sp is not None else None
    return classify_loop(aligned.pv[a:b], aligned.op[a:b], sp, sample_time=aligned.sample_time,
                         process_type=process_type, method=config.method,
                         min_cycles=config.min_cycles)


def _is_episode(d: LoopDiagnosis, min_cycles: float) -> bool:
    if d.verdict in EPISODE_VERDICTS:
        return True
    # an oscillation that is there but cannot be diagnosed (BI failed, too few
    # samples per period) is still an episode
    osc = d.oscillation
    return (d.verdict == "insufficient-data" and osc is not None and osc.is_regular
            and d.cycles >= min_cycles)


def _segment_episodes(aligned, a, b, process_type, config
                      ) -> tuple[LoopDiagnosis, list[tuple[int, int, LoopDiagnosis]]]:
    """Classify one segment; return its diagnosis and its episodes (start, stop, diagnosis)."""
    d = _classify(aligned, a, b, process_type, config)
    if not _is_episode(d, config.min_cycles):
        return d, []
    h = aligned.sample_time
    runs = _block_activity(aligned.pv[a:b], h, d.period, d.amplitude)
    covered = sum(rb - ra for ra, rb in runs)
    if covered >= SPLIT_COVERAGE * (b - a):
        return d, [(a, b, d)]
    out = []
    for ra, rb in runs:
        if (rb - ra) * h < config.min_cycles * d.period:
            continue
        sub = _classify(aligned, a + ra, a + rb, process_type, config)
        if _is_episode(sub, config.min_cycles):
            out.append((a + ra, a + rb, sub))
    return d, (out or [(a, b, d)])


def _no_data_quality(frames: Mapping[str, pl.DataFrame] | None) -> dict:
    rows = {role: f.height for role, f in (frames or {}).items()}
    return {"rows": rows, "issues": []}


def _status_summary(frame: pl.DataFrame) -> str:
    vc = frame["status"].drop_nulls().value_counts(sort=True)
    names = [str(x) for x in vc[vc.columns[0]].to_list()[:3]]
    return ", ".join(names) if names else "no status text"


def _base(job: LoopJob) -> dict:
    s = job.spec
    return dict(loop=s.loop, unit=s.unit, rank=None, window_start=job.start,
                window_end=job.end, description=s.description or "",
                criticality=float(s.criticality))


def valve_fault_size(aligned: AlignedLoop, a: int, b: int, fault: str,
                     process_type: str = "integrating", *, period: float = math.nan) -> dict:
    """Size of a loop's valve fault from the loop model fitted to one episode.

    Parameters
    ----------
    aligned : valvediag.align.AlignedLoop
        The loop on its grid.
    a, b : int
        Grid points ``[a, b)`` of the episode behind the verdict; the part
        :func:`valvediag.workbench.size_window` chooses is fitted.
    fault : {'stiction', 'backlash'}
        The verdict.
    process_type : str
        ``'self-regulating'`` fits a first-order plant; anything else an
        integrating one.
    period : float, optional
        The episode's oscillation period [s].

    Returns
    -------
    dict
        :func:`valvediag.workbench.estimate_valve_size`'s result, floats to
        four significant digits. A fit that fails gives NaN sizes, confidence
        0 and the reason; it never raises.

    Notes
    -----
    The sizes are in the OP's unit (usually % of the valve's travel) and
    describe the valve as the controller sees it: the dead band or stick
    band that, put in front of the fitted plant, reproduces the PV best on
    held-out stretches. A low ``confidence`` means the model explains the PV
    poorly or the fault barely improves it over a linear valve.
    """
    from .workbench import estimate_valve_size, size_window

    h = aligned.sample_time
    off, k = size_window(b - a, h, period)
    a += off
    ptype = "self-regulating" if process_type == "self-regulating" else "integrating"
    sp = aligned.sp[a:b:k] if aligned.sp is not None else None
    try:
        out = estimate_valve_size(aligned.pv[a:b:k], aligned.op[a:b:k], k * h, fault,
                                  ptype, sp=sp)
    except Exception as exc:  # noqa: BLE001 - a size is extra evidence, never a failed loop
        keys = ("S", "J") if fault == "stiction" else ("DB",)
        out = {k: math.nan for k in keys}
        out.update(confidence=0.0, reason=f"the model fit failed: {type(exc).__name__}: {exc}")
    return {k: (float(f"{v:.4g}") if isinstance(v, float) and math.isfinite(v) else v)
            for k, v in out.items()}


def _sparkline(aligned: AlignedLoop) -> np.ndarray | None:
    """The PV's sparkline (see :attr:`LoopDetail.sparkline`), or None without valid PV."""
    valid = aligned.role_valid.get("pv", np.isfinite(aligned.pv))
    if aligned.n == 0 or not valid.any():
        return None
    pv = np.where(valid, aligned.pv, np.nan)
    return _reduce(pv, SPARK_BUCKETS)


def _own(d: LoopDiagnosis | None) -> LoopDiagnosis | None:
    """``d`` with its data copied, so that it does not keep the whole aligned grid alive.

    The Backlash Index is measured on the diagnosed PV itself, so its record
    shares the one copy (a third of a result's memory: 2 MB per loop-day at
    1 s, held by the flow for every loop needing action).
    """
    if d is None:
        return None
    own = lambda a: None if a is None else np.array(a)
    pv = own(d.pv)
    bres = d.backlash
    if bres is not None:
        same = (bres.pv is not None and pv is not None and bres.pv.shape == pv.shape
                and np.array_equal(bres.pv, pv, equal_nan=True))
        bres = dataclasses.replace(bres, pv=pv if same else own(bres.pv))
    return dataclasses.replace(d, pv=pv, op=own(d.op), backlash=bres)


def _detail(aligned: AlignedLoop, verdict: str, rep: LoopDiagnosis | None = None,
            span: tuple[int, int] | None = None) -> LoopDetail:
    """Report data of one loop: the sparkline always; trend and diagnosis when it needs action."""
    if verdict not in ACTION_VERDICTS or rep is None:
        return LoopDetail(sparkline=_sparkline(aligned))
    a, b = span if span is not None else (0, aligned.n)
    return LoopDetail(sparkline=_sparkline(aligned), trend=LoopTrend.from_aligned(aligned),
                      diagnosis=_own(rep), diagnosis_start=_utc(aligned, a),
                      diagnosis_end=_utc(aligned, b))


def _insufficient(job: LoopJob, reason: str, *, frames=None, quality: dict | None = None,
                  evidence: dict | None = None, confidence: float = 0.95,
                  detail: LoopDetail | None = None) -> LoopResult:
    spec = job.spec
    ev = {"problems": list(job.problems)}
    ev.update(evidence or {})
    nan = math.nan
    return LoopResult(**_base(job), verdict="insufficient-data", confidence=confidence,
                      severity=0.0, process_type=spec.process_type, bi=nan, period_s=nan,
                      amplitude=nan, amplitude_pct_span=nan, regularity=nan, reason=reason,
                      evidence=_clean(ev), quality=quality if quality is not None
                      else _no_data_quality(frames), episodes=(), detail=detail)


def _check_frames(job: LoopJob, frames: Mapping[str, pl.DataFrame]) -> str | None:
    """Reason the loop cannot be analysed at all, or None."""
    spec = job.spec
    if not spec.pv_tag:
        return "no PV tag in loops.csv"
    if not spec.op_tag:
        return "no OP tag in loops.csv"
    window = f"{job.start:%Y-%m-%d %H:%M} to {job.end:%Y-%m-%d %H:%M} UTC"
    for role, tag in (("pv", spec.pv_tag), ("op", spec.op_tag)):
        f = frames.get(role)
        if f is None or f.height == 0:
            absent = any(p == f"{role.upper()} tag {tag} not found in the exports"
                         for p in job.problems)
            return (f"{role.upper()} tag {tag} not found in the exports" if absent
                    else f"{role.upper()} tag {tag} has no samples from {window}")
        if f["value"].null_count() == f.height:
            return (f"all {f.height} {role.upper()} samples of {tag} in the window are bad "
                    f"states ({_status_summary(f)})")
    return None


def _grid_step(pv: pl.DataFrame) -> float | None:
    """The PV's median sample spacing [s], as align_loop's default, or None."""
    h = median_spacing(to_epoch_us(pv["ts"].drop_nulls()))
    return h if math.isfinite(h) and h > 0 else None


def _grid_start(pv: pl.DataFrame, start: dt.datetime, h: float | None = None) -> dt.datetime:
    """The first instant at or after ``start`` in phase with the PV's first sample.

    A grid in phase with the samples takes them as they are; a grid offset by
    a fraction of the spacing would interpolate every point, which low-passes
    the PV and rounds its peaks (biasing the Backlash Index towards backlash).
    ``h`` is :func:`_grid_step`'s result when the caller has it already.
    """
    if h is None:
        h = _grid_step(pv)
    if h is None:
        return start
    step = max(int(round(h * 1e6)), 1)
    first = int(to_epoch_us(pv["ts"].drop_nulls()).min())
    s_us = (start - dt.datetime(1970, 1, 1, tzinfo=_UTC)) // dt.timedelta(microseconds=1)
    t0 = first - ((first - s_us) // step) * step
    return dt.datetime(1970, 1, 1, tzinfo=_UTC) + dt.timedelta(microseconds=int(t0))


def _span(spec: LoopSpec, aligned: AlignedLoop) -> tuple[float, str]:
    if spec.span is not None and math.isfinite(spec.span) and spec.span > 0:
        return float(spec.span), "loops.csv"
    pv = aligned.pv[aligned.valid]
    if pv.size >= 2:
        lo, hi = np.percentile(pv, [0.5, 99.5])
        if hi > lo:
            return float(hi - lo), "data (robust PV range in the window)"
    return math.nan, "unknown"


def _quality_note(q: DataQuality, period: float) -> tuple[float, str]:
    """(confidence factor, reason suffix) for a compressed PV."""
    if not q.compressed:
        return 1.0, ""
    spc = q.samples_per_cycle(period) if math.isfinite(period) else math.nan
    if math.isfinite(spc) and spc < MIN_RAW_PER_CYCLE:
        return COMPRESSION_PENALTY[1], (f"; the PV is compressed to {spc:.0f} stored samples "
                                        f"per period, so its waveform may be distorted")
    return COMPRESSION_PENALTY[0], "; the PV is compressed, which may distort the waveform"


def analyse_loop(job: LoopJob, frames: Mapping[str, pl.DataFrame],
                 config: ScanConfig = ScanConfig()) -> LoopResult:
    """Diagnose one loop over its window: pure numerics, no store.

    Parameters
    ----------
    job : LoopJob
        The loop and its window (from :func:`plan_loops`).
    frames : mapping of str to polars.DataFrame
        The loop's samples by role (from :func:`load_loop_frames`).
    config : ScanConfig
        ``method``, ``min_cycles``, ``max_gap_s`` and ``min_coverage`` are
        used.

    Returns
    -------
    LoopResult
        Unranked (``rank`` None); :func:`rank_results` ranks a plant.

    Notes
    -----
    The steps are described in the module docstring: alignment and quality,
    episodes, integrating screen, verdict per episode and per loop, severity.
    A loop without a PV or OP tag, without samples in the window or with only
    bad-state samples is ``insufficient-data`` and the reason names the tag.
    The classifier analyses one gap-free segment at a time, so a day split by
    gaps is analysed in pieces; an oscillation that occupies less than about
    a third of a segment may be missed by the segment's classification (the
    block screen only splits segments found oscillating). An unexpected error
    in the analysis gives the loop ``insufficient-data`` with the error as its
    reason (and logs the traceback) rather than stopping the scan.
    """
    try:
        return _analyse_loop(job, frames, config)
    except Exception as exc:   # one loop's failure must not stop the plant's scan
        _log.exception("analysis of loop %s failed", job.spec.loop)
        return _insufficient(job, f"analysis failed ({type(exc).__name__}: {exc}); "
                                  "please report this with the loop's data", frames=frames)


def _analyse_loop(job: LoopJob, frames: Mapping[str, pl.DataFrame],
                  config: ScanConfig) -> LoopResult:
    spec = job.spec
    why = _check_frames(job, frames)
    if why is not None:
        return _insufficient(job, why, frames=frames)
    roles = {r: f for r, f in frames.items() if r in ("pv", "op", "sp", "mv", "mode")}
    step = _grid_step(roles["pv"])
    aligned = align_loop(roles, sample_time=step,
                         start=_grid_start(roles["pv"], job.start, step), end=job.end,
                         max_gap=config.max_gap_s)
    q = quality_metrics(aligned, roles, span=spec.span)
    qd = _clean(q.as_dict())
    window_s = (job.end - job.start).total_seconds()
    h = aligned.sample_time
    min_len = max(MIN_SEGMENT_SAMPLES, int(math.ceil(MIN_SEGMENT_S / h)))
    segs = [(a, b) for a, b in aligned.segments if b - a >= min_len]
    usable_s = sum(b - a for a, b in segs) * h
    ev: dict = {"problems": list(job.problems), "sample_time_s": h, "segments": len(segs),
                "usable_s": usable_s, "coverage": usable_s / window_s if window_s else 0.0}
    if not segs:
        issues = "; ".join(q.issues) or "no overlap of valid PV and OP samples"
        longest = max((b - a for a, b in aligned.segments), default=0) * h
        return _insufficient(job, f"no stretch of usable PV and OP data lasting "
                             f"{min_len * h / 60:.3g} min ({min_len} samples) in the window; the "
                             f"longest lasts {longest / 60:.3g} min ({issues})",
                             quality=qd, evidence=ev, detail=_detail(aligned, "insufficient-data"))

    seg_diag: list[tuple[int, int, LoopDiagnosis]] = []
    episodes: list[tuple[int, int, LoopDiagnosis]] = []
    for a, b in segs:
        d, eps = _segment_episodes(aligned, a, b, spec.process_type, config)
        seg_diag.append((a, b, d))
        episodes.extend(eps)

    span, span_source = _span(spec, aligned)
    ev.update(span=span, span_source=span_source)
    diagnostic = [e for e in episodes if e[2].verdict != "insufficient-data"]
    voters = diagnostic or episodes
    if voters:
        weights: dict[str, float] = {}
        for a, b, d in voters:
            weights[d.verdict] = weights.get(d.verdict, 0.0) + (b - a) * h * max(d.confidence, 0.05)
        total = sum(weights.values())
        verdict = max(weights, key=lambda v: (weights[v], -_ORDER.index(v)))
        mine = [(a, b, d) for a, b, d in voters if d.verdict == verdict]
        dur = sum((b - a) for a, b, _ in mine)
        conf_mean = sum((b - a) * d.confidence for a, b, d in mine) / dur
        agreement = weights[verdict] / total
        ra, rb, rep = max(mine, key=lambda e: (e[1] - e[0]) * e[2].confidence)
        confidence = conf_mean * agreement
        reason = rep.reason
        if agreement < 0.999:
            others = ", ".join(f"{v} {100 * w / total:.0f}%" for v, w in
                               sorted(weights.items(), key=lambda kv: -kv[1]) if v != verdict)
            reason += f" (episodes disagree: {verdict} {100 * agreement:.0f}%, {others})"
        ev.update(episode_votes={v: round(w / total, 4) for v, w in weights.items()},
                  agreement=round(agreement, 4))
    else:
        ra, rb, rep = max(seg_diag, key=lambda e: e[1] - e[0])
        verdict, confidence, reason = rep.verdict, rep.confidence, rep.reason
        if verdict == "no-oscillation" and ev["coverage"] < config.min_coverage:
            verdict = "insufficient-data"
            reason = (f"only {usable_s / 3600:.2g} h of usable data in the {window_s / 3600:.3g} h "
                      f"window (need {100 * config.min_coverage:.0f}% of it to rule out an "
                      f"oscillation)")
            confidence = 0.9
        if len(segs) > 1:
            ev["segment_verdicts"] = sorted({d.verdict for _, _, d in seg_diag})

    osc_s = sum((b - a) for a, b, _ in episodes) * h
    amp = rep.amplitude if verdict != "no-oscillation" else math.nan
    amp_pct = 100.0 * amp / span if math.isfinite(amp) and span and math.isfinite(span) else math.nan
    if verdict in EPISODE_VERDICTS:
        factor, note = _quality_note(q, rep.period)
        confidence *= factor
        reason += note
        sev, factors = severity(amp_pct, rep.regularity, osc_s / window_s, spec.criticality)
    else:
        sev, factors = 0.0, {}
    if spec.process_type != "unknown":
        ptype, source = spec.process_type, "loops.csv"
    else:
        screen = rep.process_screen if rep.process_screen in ("integrating", "self-regulating") \
            else "unknown"
        ptype, source = screen, "data test" if screen != "unknown" else "unknown"
    ev.update({k: v for k, v in rep.evidence.items() if k not in ev})
    ev.update(process_type_source=source, process_screen=rep.process_screen,
              oscillating_s=osc_s, time_share=osc_s / window_s if window_s else 0.0,
              severity_factors=factors, episodes=len(episodes))
    size = None
    if config.size_estimate and verdict in VALVE_FAULTS:
        size = valve_fault_size(aligned, ra, rb, verdict, ptype, period=rep.period)
        ev["size"] = size
    eps = tuple(Episode(start=_utc(aligned, a), end=_utc(aligned, b), period_s=d.period,
                        amplitude=d.amplitude, regularity=d.regularity, verdict=d.verdict,
                        bi=d.bi, confidence=d.confidence) for a, b, d in sorted(episodes,
                                                                               key=lambda e: e[0]))
    return LoopResult(**_base(job), verdict=verdict,
                      confidence=round(float(np.clip(confidence, 0.0, 1.0)), 3), severity=sev,
                      process_type=ptype,
                      bi=rep.bi if verdict in EPISODE_VERDICTS else math.nan,
                      period_s=rep.period if verdict != "no-oscillation" else math.nan,
                      amplitude=amp, amplitude_pct_span=amp_pct,
                      regularity=rep.regularity, reason=reason, evidence=_clean(ev),
                      quality=qd, episodes=eps, size=size,
                      detail=_detail(aligned, verdict, rep, (ra, rb)))


# ------------------------------------------------------------- plant level

def _order_key(r: LoopResult):
    return (_ORDER.index(r.verdict) if r.verdict in _ORDER else len(_ORDER), r.loop)


def rank_results(results: Iterable[LoopResult]) -> list[LoopResult]:
    """Rank a plant's results: rank 1 is the most severe loop that needs action.

    Parameters
    ----------
    results : iterable of LoopResult
        One per loop (from :func:`analyse_loop`); their ``severity`` is used.

    Returns
    -------
    list of LoopResult
        Copies with ``rank`` set: loops with a verdict in
        :data:`ACTION_VERDICTS` get 1, 2, ... by decreasing severity (ties:
        higher confidence, then loop name), in that order; the others follow
        without a rank, by verdict and name. Every loop needing action thus
        ranks above every loop that does not.
    """
    results = list(results)
    act = sorted((r for r in results if r.needs_action),
                 key=lambda r: (-r.severity, -r.confidence, r.loop))
    rest = sorted((r for r in results if not r.needs_action), key=_order_key)
    return ([dataclasses.replace(r, rank=k) for k, r in enumerate(act, 1)]
            + [dataclasses.replace(r, rank=None) for r in rest])


def _nan_none(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def persist_results(store: Store, run_id: str, results: Sequence[LoopResult]) -> None:
    """Write a run's verdicts and episodes to the store (one transaction).

    Parameters
    ----------
    store : valvediag.store.Store
        Writable store.
    run_id : str
        A run with status ``running`` (:meth:`Store.start_run`). Writing again
        replaces the run's earlier results, so a retried task is idempotent.
    results : sequence of LoopResult
        Ranked results.
    """
    verdicts, episodes = [], []
    for r in results:
        verdicts.append({"loop": r.loop, "verdict": r.verdict, "confidence": r.confidence,
                         "rank": r.rank, "severity": r.severity, "process_type": r.process_type,
                         "bi": _nan_none(r.bi), "period_s": _nan_none(r.period_s),
                         "amplitude": _nan_none(r.amplitude),
                         "regularity": _nan_none(r.regularity), "reason": r.reason,
                         "evidence": r.evidence, "quality": r.quality})
        for e in r.episodes:
            episodes.append({"loop": r.loop, "start_ts": e.start, "end_ts": e.end,
                             "period_s": _nan_none(e.period_s),
                             "amplitude": _nan_none(e.amplitude),
                             "regularity": _nan_none(e.regularity), "verdict": e.verdict,
                             "bi": _nan_none(e.bi), "confidence": e.confidence})
    store.write_results(run_id, episodes=episodes, verdicts=verdicts)


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
    valvediag.registry.RegistryError
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
    from .ingest import ingest_exports
    from .outputs import write_outputs
    from .registry import read_loops_csv
    from .store import Store

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
