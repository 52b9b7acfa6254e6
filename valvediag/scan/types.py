"""
The plant scan's data types: its parameters, a loop's job, episodes, trends and results.
"""
from __future__ import annotations

import dataclasses
import datetime as dt
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..analysis.align import AlignedLoop
from ..analysis.classify import LoopDiagnosis
from ..io.registry import LoopSpec
from ..plain import aware_utc, to_plain
from ..verdicts import ACTION_VERDICTS, count_verdicts

if TYPE_CHECKING:  # pragma: no cover

    from ..store.ingest import IngestReport


__all__ = ["ScanConfig", "LoopJob", "Episode", "LoopTrend", "LoopDetail", "LoopResult", "ScanSummary",
           "SPARK_BUCKETS", "TREND_BUCKETS", "reduce_to_buckets"]


#: Buckets of the PV sparkline kept for every loop (min and max of each) [-].
SPARK_BUCKETS = 48
#: Buckets of the PV/OP/SP trend kept for a loop needing action (two points each) [-].
TREND_BUCKETS = 720

_UTC = dt.timezone.utc


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
        Backlash Index estimator (see :func:`valvediag.analysis.bi.backlash_index`).
    min_cycles : float, default 3.0
        Fewest complete cycles for a verdict on the valve [-].
    timezone : str, optional
        IANA zone of naive time stamps in the exports (ingest only).
    max_gap_s : float, optional
        Longest interval bridged by interpolation, for every tag [s]. Default:
        per tag from its own spacing (:func:`valvediag.analysis.align.tag_max_gap`).
    min_coverage : float, default 0.1
        Share of the window below which a verdict is a snapshot's: its reason
        names the hours it stands on, and a ``no-oscillation`` verdict's
        confidence falls in proportion (an export of a few hours around an
        event is analysed, not refused) [-].
    size_estimate : bool, default True
        Fit the workbench's loop model to every ``stiction`` or ``backlash``
        loop and put the fault's size on it (dead band, or Kano S and J, in
        OP units; :func:`valvediag.workbench.estimate_valve_size`). About a
        second per faulty loop for a day at 1 s. On a level whose Backlash
        Index reads backlash while its turns are those of a slip behind a
        short lag, also fit a sticky and a loose valve behind a lag and let
        them decide (:func:`valvediag.workbench.valve_kind`; a few seconds).

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
        object.__setattr__(self, "end", aware_utc(self.end, "end"))

    @property
    def window(self) -> dt.timedelta:
        """The window length."""
        return dt.timedelta(hours=self.window_hours)

    def to_json(self) -> dict:
        """The parameters as plain JSON values."""
        return to_plain(dataclasses.asdict(self))


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
        return to_plain({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})


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


def reduce_to_buckets(y: np.ndarray | None, buckets: int) -> np.ndarray | None:
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
        aligned : valvediag.analysis.align.AlignedLoop
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
        return cls(start=aligned.start, t=t.astype(np.float64), pv=reduce_to_buckets(pv, buckets),
                   op=reduce_to_buckets(aligned.op, buckets), sp=reduce_to_buckets(aligned.sp, buckets),
                   sample_time=h, step=k)

    def times(self) -> np.ndarray:
        """The points' times as ``datetime64[ms]`` (UTC, naive)."""
        t0 = np.datetime64(self.start.astimezone(_UTC).replace(tzinfo=None), "ms")
        return t0 + np.round(self.t * 1e3).astype("timedelta64[ms]")


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
    diagnosis : valvediag.analysis.classify.LoopDiagnosis or None
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
        One of :data:`valvediag.analysis.classify.VERDICTS`.
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
        Data-quality figures (:class:`valvediag.analysis.quality.DataQuality`), with
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
        return to_plain({f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                       if f.name != "detail"})


@dataclass(frozen=True)
class ScanSummary:
    """What a scan did (:func:`valvediag.scan.run.execute_scan`).

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
        (:meth:`valvediag.store.Store.new_faults`).
    ingest_s, analysis_s : float
        Wall time of the ingest and of the analysis [s].
    status : {'complete', 'partial'}
        How the run ended (:func:`valvediag.scan.run.run_status`).
    status_note : str
        What a partial run misses (the exports not stored); empty otherwise.
    """

    run_id: str
    results: tuple[LoopResult, ...]
    outputs: dict
    ingest: IngestReport
    registry_problems: tuple[str, ...] = ()
    new_faults: tuple[str, ...] = ()
    ingest_s: float = 0.0
    analysis_s: float = 0.0
    status: str = "complete"
    status_note: str = ""

    @property
    def errors(self) -> tuple[str, ...]:
        """One line per export file that could not be read."""
        return tuple(self.ingest.errors)

    def to_json(self) -> dict:
        """A plain summary (what the nightly flow returns).

        Returns
        -------
        dict
            ``run_id``, ``status``, ``status_note``, ``loops``, ``counts`` (every verdict, in
            :data:`valvediag.verdicts.VERDICTS` order), ``new_faults``,
            ``outputs`` (absolute paths), ``ingest`` (``files``,
            ``rows_inserted``, ``rows_skipped_duplicate``,
            ``rows_quarantined``, ``errors``, ``quarantined``: one line per
            file with rows quarantined, with the top reasons) and
            ``registry_problems``.
        """
        r = self.ingest
        return {"run_id": self.run_id, "status": self.status, "status_note": self.status_note,
                "loops": len(self.results),
                "counts": count_verdicts(x.verdict for x in self.results),
                "new_faults": list(self.new_faults),
                "outputs": {k: str(Path(p).resolve()) for k, p in self.outputs.items()},
                "ingest": {"files": r.files, "rows_inserted": r.rows_inserted,
                           "rows_skipped_duplicate": r.rows_skipped_duplicate,
                           "rows_quarantined": r.rows_quarantined, "errors": list(r.errors),
                           "quarantined": [f.summary() for f in r.quarantined_files]},
                "registry_problems": list(self.registry_problems)}

