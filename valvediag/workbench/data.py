"""
Measured loop data prepared for the workbench: segments, training and
held-out blocks, burn-in, OP reversals.

The PV prediction is a free simulation driven by the measured OP and
re-initialised at the start of every *segment* of ``horizon`` samples.
Segments are grouped into consecutive time blocks that alternate between
training (fit) and held-out (score). The record is never resampled.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import periodogram

from ..analysis.quality import despike, stored_points, white_noise_std
from .kernels import nudge_holds, turning_points
from .sensor import PVGrid, pv_grid

__all__ = ["LoopData", "WorkbenchDataError", "prepare_loop", "white_noise_std", "periodogram_band",
           "rebuild_compressed_op", "REBUILD_R2", "stored_points", "growing_swing"]

#: Fewest segments a record must give (training plus held-out).
MIN_SEGMENTS = 6
#: Fewest samples a record must have.
MIN_SAMPLES = 200
#: An OP reversal smaller than this many OP noise standard deviations is
#: noise, not a reversal of the valve's travel [-].
NOISE_REVERSAL = 6.0
#: Time blocks are rebalanced by the OP's reversals when one holds fewer than
#: this share of the mean reversals per block [-].
BURSTY_BLOCK = 0.5
#: Shifts of the rebalanced block edges tried, in blocks, until each set
#: holds a third of the reversals [-].
BLOCK_SHIFTS = (0.0, 0.25, 0.5, 0.75)
#: Fewest reversals of the OP a record must show: each one is where a valve's
#: band shows; with fewer, a band is not told from the process [-].
MIN_REVERSALS = 4
#: Fewest stored PV samples in the training and in the held-out blocks when
#: only stored samples are scored [-].
MIN_STORED = 50
#: A PV (or control error, with a set point) whose straight-line trend
#: explains at least this share of its variance, and whose last quarter lies
#: beyond its first quarter's range, diverges [-].
DIVERGING_R2 = 0.9
#: A swing (2-98 percentile range) that rises from each of :data:`GROWTH_WINDOWS`
#: equal windows to the next but once, to at least this multiple of the
#: second window's, is an unstable loop's growing oscillation (a swing
#: growing linearly from rest ends at four times the second window's) [-].
GROWTH_FACTOR = 3.0
GROWTH_WINDOWS = 8


class WorkbenchDataError(ValueError):
    """Data the workbench cannot model; the message is one line."""


def _cover_op_range(op, starts, sets, tol):
    """Move held-out segments whose OP leaves the training blocks' range to training.

    Parameters
    ----------
    op : numpy.ndarray, shape (n,)
        Controller output, missing samples held [OP unit].
    starts : numpy.ndarray of int
        First sample of each segment; each runs to the next one's start, the
        last to the end of the record.
    sets : numpy.ndarray of int
        Each segment's set (0 training, 1 held-out, -1 unused); changed in
        place.
    tol : float
        How far beyond the training OP's range a held-out segment may reach
        [OP unit].

    Returns
    -------
    int
        Segments moved.

    Notes
    -----
    A held-out segment whose OP goes where no training sample went asks the
    model to extrapolate: a stop, a curvature or a band that only such
    excursions show cannot be fitted, and whatever a candidate effect does
    there is chance, not evidence (in a simulated record whose valve reaches
    one stop only in held-out blocks, a dead time gained 2.5 % held-out,
    85 % of it in those segments). The estimation data must cover the range
    the validation data visit. Segments are moved one at a time, the
    farthest out first (each move widens the range), at most half of the
    held-out ones: a record whose held-out blocks lie mostly outside the
    training range keeps its split, and its held-out error says so.
    """
    lo = np.minimum.reduceat(op, starts)
    hi = np.maximum.reduceat(op, starts)
    held = sets == 1
    budget = int(held.sum()) // 2
    moved = 0
    while moved < budget and (sets == 0).any():
        tr = sets == 0
        out = np.where(sets == 1, np.maximum(lo[tr].min() - lo, hi - hi[tr].max()), -np.inf)
        j = int(np.argmax(out))
        if not out[j] > tol:
            break
        sets[j] = 0
        moved += 1
    return moved


def _nan_fill(x):
    """Hold the last finite value over NaNs (first finite value at the start)."""
    x = np.asarray(x, dtype=float).copy()
    ok = np.isfinite(x)
    if ok.all():
        return x
    idx = np.where(ok, np.arange(x.size), 0)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(ok))
    out = x[idx]
    out[:first] = x[first]
    return out


@dataclass(frozen=True, eq=False)
class LoopData:
    """One loop's record, split into re-initialised segments.

    Build it with :func:`prepare_loop`.

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        Time since the first sample [s].
    pv : numpy.ndarray
        Measured PV [PV unit]; NaN where missing.
    op : numpy.ndarray
        Controller output with missing values held [OP unit, e.g. %].
    sp : numpy.ndarray or None
        Set point [PV unit].
    sample_time : float
        [s]
    horizon : int
        Segment length [samples].
    period : float
        Dominant period of the OP [s]; NaN when none was found.
    burn_in : int
        First sample scored: the valve state is known from here on [sample].
    seg_start, seg_end : numpy.ndarray of int
        Segment bounds ``[start, end)`` [sample].
    seg_set : numpy.ndarray of int
        0 training, 1 held-out, -1 unused (missing data inside).
    band_max : float
        Largest valve band searched (dead band, stick band) [OP unit].
    op_delta : float
        Hysteresis used to find OP reversals [OP unit].
    reversals, reversal_sign : numpy.ndarray of int
        Index of each OP reversal (an extreme of the OP) and its sign
        (+1 maximum, -1 minimum).
    held_fraction : float
        Fraction of samples where the OP equals the previous sample: held or
        compressed data (false rests for the Kano model).
    op_noise : float
        Standard deviation of the OP's white noise (:func:`white_noise_std`)
        [OP unit]; 0 for a noise-free OP.
    name : str
        Label of the record (file name) for reports.
    reinit : {'fit', 'measured'}
        How each segment's prediction starts: from the best initial state
        (fitted per segment, robust to PV noise) or from the measured PV at
        the segment's first sample.
    pv_scored : numpy.ndarray of bool or None
        Per sample, whether the PV there is a measurement that the fit scores
        (``None``: every sample). ``False`` where a compressed PV is read back
        by interpolation between the historian's stored points.
    moved_to_training : int
        Held-out segments moved to training because their OP left the
        training blocks' range (:func:`prepare_loop`).
    """

    t: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    sp: np.ndarray | None
    sample_time: float
    horizon: int
    period: float
    burn_in: int
    seg_start: np.ndarray
    seg_end: np.ndarray
    seg_set: np.ndarray
    band_max: float
    op_delta: float
    reversals: np.ndarray
    reversal_sign: np.ndarray
    held_fraction: float
    op_noise: float = 0.0
    name: str = ""
    reinit: str = "fit"
    pv_scored: np.ndarray | None = field(default=None, repr=False)
    moved_to_training: int = 0
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def hold_run(self) -> int:
        """Longest run of repeated OP samples bridged by a rest tolerance: the
        95th percentile of the runs, 1 to 30 samples [samples]."""
        key = "hold_run"
        if key not in self._cache:
            same = np.r_[False, np.diff(self.op) == 0]
            edges = np.flatnonzero(np.diff(np.r_[0, same.astype(np.int8), 0]))
            runs = edges[1::2] - edges[::2]
            self._cache[key] = int(np.clip(np.percentile(runs, 95), 1, 30)) if runs.size else 1
        return self._cache[key]

    def op_nudged(self) -> np.ndarray:
        """The OP with held runs of up to :attr:`hold_run` samples creeping on
        in the direction of travel (not rests for the Kano valve).

        Returns
        -------
        numpy.ndarray
        """
        key = "op_nudged"
        if key not in self._cache:
            eps = 1e-9 * max(float(np.ptp(self.op)), 1.0)
            self._cache[key] = nudge_holds(self.op, self.hold_run, eps)
        return self._cache[key]

    @property
    def noise_band(self) -> float:
        """Noise band of a sticky valve's actuator: :data:`NOISE_REVERSAL`
        times :attr:`op_noise` [OP unit].

        Notes
        -----
        Kano's valve sticks at every reversal of its input, so a model driven
        by a noisy OP sticks at every noise reversal, needs its whole stick
        band to move again and misses the slips of the real valve; a fit then
        settles on a narrow band without a slip jump. A real actuator (a
        pneumatic diaphragm behind a positioner) does not reverse on
        controller noise, so the fitted valve takes a fall of the OP by no
        more than this band from its running extreme for noise
        (:func:`valvediag.models.valves.valve_step`). A white noise dips below the
        running maximum of a slow ramp by several standard deviations now and
        then; six keep a day of samples free of false reversals, while real
        reversals of a valve's travel (about its band) are much larger. A
        reversal smaller than the band, if real, is not modelled. Whether a
        valve reverses on noise is a property of its actuator: a stiction fit
        tries this band and none, and keeps the one that fits better
        (:meth:`valvediag.workbench.LoopModel.fit`).
        """
        return NOISE_REVERSAL * self.op_noise

    @property
    def pv_grid(self) -> PVGrid:
        """The grid the PV's readings lie on, from the scored readings
        (:func:`valvediag.workbench.sensor.pv_grid`; ``step`` 0 if none)."""
        if "pv_grid" not in self._cache:
            self._cache["pv_grid"] = pv_grid(self.pv, self.pv_scored)
        return self._cache["pv_grid"]

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    @property
    def sample_set(self) -> np.ndarray:
        """Per sample: 0 training, 1 held-out, -1 not scored."""
        key = "sample_set"
        if key not in self._cache:
            s = np.full(self.n, -1, np.int64)
            for a, b, c in zip(self.seg_start, self.seg_end, self.seg_set):
                s[a:b] = c
            if self.pv_scored is not None:
                off = ~np.asarray(self.pv_scored, dtype=bool)
                if self.reinit == "measured":
                    off[self.seg_start] = False      # each prediction starts there
                s[off] = -1
            self._cache[key] = s
        return self._cache[key]

    @property
    def seg_id(self) -> np.ndarray:
        """Per sample: index of its segment, -1 before the burn-in."""
        key = "seg_id"
        if key not in self._cache:
            s = np.full(self.n, -1, np.int64)
            for j, (a, b) in enumerate(zip(self.seg_start, self.seg_end)):
                s[a:b] = j
            self._cache[key] = s
        return self._cache[key]

    def plot(self, ax=None):
        """Plot PV and OP with the training (white) and held-out (grey) blocks.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional

        Returns
        -------
        matplotlib.axes.Axes
        """
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots(figsize=(9, 3))
        shade_heldout(ax, self)
        ax.plot(self.t, self.pv, color="C0", lw=0.8, label="PV")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("PV")
        ax2 = ax.twinx()
        ax2.plot(self.t, self.op, color="C1", lw=0.7, label="OP")
        ax2.set_ylabel("OP")
        return ax


def shade_heldout(ax, data: LoopData):
    """Grey spans over the held-out blocks."""
    ss = data.sample_set
    held = ss == 1
    if not held.any():
        return
    edges = np.flatnonzero(np.diff(np.r_[0, held.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(data.t[a], data.t[b - 1], color="0.9", lw=0, zorder=0)


#: A compressed OP is rebuilt from the controller's law when that law explains at
#: least this share of the variance of its stored moves [-]
#: (:func:`rebuild_compressed_op`'s second result).
REBUILD_R2 = 0.8


def rebuild_compressed_op(pv, op, sample_time: float, sp=None) -> tuple[np.ndarray, float]:
    """The controller output between the points a historian stored, from the
    controller's law.

    Parameters
    ----------
    pv, op : array_like, shape (n,)
        Uniformly sampled, gap-free; ``op`` read back by linear interpolation
        between its stored points [PV unit, OP unit].
    sample_time : float
        [s]
    sp : array_like, shape (n,), optional
        Set point [PV unit]; constant when not given.

    Returns
    -------
    op : numpy.ndarray
        The OP rebuilt between its stored points (equal to them at each); the
        input when it cannot be rebuilt.
    r2 : float
        Share of the variance of the stored OP's moves that the controller's
        law explains; NaN when the OP is not compressed or has gaps.

    Notes
    -----
    Exception reporting stores an OP sample only when it has moved more
    than a dead band since the last one, and a straight line between stored
    samples cuts each reversal: it turns too early and too low, so a valve
    model driven by it moves too early, a fitted dead time takes that up
    and the valve's band reads small. The OP is what a PI controller made
    of the control error ``e = SP - PV``, which is recorded: between stored
    samples ``i`` and ``j``, ``OP_j - OP_i = Kc (e_j - e_i) + Kc/Ti sum(e h)
    + c (t_j - t_i)``. ``Kc``, ``Kc/Ti`` and ``c`` (a set point that is not
    recorded) are found by least squares over all stored intervals; the OP
    is then integrated from each stored sample, and the small mismatch at
    the next is spread linearly over the interval, so the stored samples are
    kept exactly.

    It assumes a PI controller (no derivative action, no output filter, no
    change of mode or tuning) running at the record's sample time or
    faster. Where the PV is itself compressed, its own reconstruction
    errors pass into the rebuilt OP. The controller's share of the PV
    noise is smoothed away where the PV is compressed: read the OP's noise
    from its stored points (:func:`white_noise_std`), not from the rebuilt
    OP.
    """
    pv = np.asarray(pv, dtype=float)
    op = np.asarray(op, dtype=float)
    if not (np.isfinite(pv).all() and np.isfinite(op).all()) or op.size < 8:
        return op, math.nan
    k = stored_points(op)
    if k.size > 0.7 * op.size or k.size < 8:
        return op, math.nan
    e = (np.asarray(sp, dtype=float) - pv) if sp is not None else -pv
    if not np.isfinite(e).all():
        return op, math.nan
    h = float(sample_time)
    ce = np.r_[0.0, np.cumsum(e[1:])] * h           # integral of e up to each sample
    i, j = k[:-1], k[1:]
    X = np.column_stack([e[j] - e[i], ce[j] - ce[i], (j - i) * h])
    y = op[j] - op[i]
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    ss = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum((y - X @ coef) ** 2)) / ss if ss > 0 else math.nan
    t = np.arange(op.size)
    seg = np.clip(np.searchsorted(k, t, side="right") - 1, 0, k.size - 2)
    a, b = k[seg], k[seg + 1]
    law = lambda m: coef[0] * (e[m] - e[a]) + coef[1] * (ce[m] - ce[a]) + coef[2] * (m - a) * h
    frac = (t - a) / np.maximum(b - a, 1)
    rebuilt = op[a] + law(t) + frac * (op[b] - op[a] - law(b))
    rebuilt[k] = op[k]
    return rebuilt, r2


def periodogram_band(y, sample_time: float, detrend="constant"):
    """Periodogram of ``y`` between two cycles per record and four samples per
    cycle (the periods a record can show as a cycle).

    Parameters
    ----------
    y : numpy.ndarray
        Uniformly sampled signal, no NaN.
    sample_time : float
        [s]
    detrend : {'constant', 'linear'}
        Passed to :func:`scipy.signal.periodogram`.

    Returns
    -------
    f, p : numpy.ndarray
        Frequencies [Hz] and power spectral density [unit^2/Hz].
    """
    h, n = float(sample_time), y.size
    f, p = periodogram(y, fs=1.0 / h, detrend=detrend)
    ok = (f > 2.0 / (n * h)) & (f < 1.0 / (4.0 * h))
    return f[ok], p[ok]


def _refuse_diverging(y, ok, label: str):
    """Raise :class:`WorkbenchDataError` when ``y`` runs away over the record.

    A loop that is open, saturated or unstable drives its PV (or control
    error) off along a trend instead of about a set point; a model driven
    by the OP then fits the runaway, and its valve band is meaningless.
    Diverging: a straight-line trend explains at least
    :data:`DIVERGING_R2` of the variance, and the last quarter of the
    record lies wholly beyond the first quarter's range. A slow drift under
    an oscillation explains little of the variance and passes.
    """
    idx = np.flatnonzero(ok)
    if idx.size < 8:
        return
    v = y[idx]
    t = idx.astype(float)
    slope, icpt = np.polyfit(t, v, 1)
    var = float(np.var(v))
    r2 = 1.0 - float(np.var(v - (slope * t + icpt))) / var if var > 0 else 0.0
    q = idx.size // 4
    first, last = v[:q], v[-q:]
    beyond = last.min() > first.max() or last.max() < first.min()
    if r2 >= DIVERGING_R2 and beyond:
        raise WorkbenchDataError(
            f"the {label} diverges (from about {np.median(first):.4g} to {np.median(last):.4g}; a "
            f"straight trend explains {100 * r2:.0f} % of its variance): an open, saturated or "
            "unstable loop, whose runaway a valve model cannot size")


def growing_swing(y, ok=None) -> tuple[float, float] | None:
    """The swing of a record that grows window after window, or None.

    Parameters
    ----------
    y : array_like, shape (n,)
        PV or OP [unit of ``y``].
    ok : array_like of bool, shape (n,), optional
        Valid samples (default: the finite ones).

    Returns
    -------
    tuple of float or None
        (swing of the second window, swing of the last) [unit of ``y``] when
        the record grows; None otherwise.

    Notes
    -----
    An unstable loop oscillates with a growing amplitude (exponentially, or
    linearly behind a dead band) until something limits it. Growing: of
    :data:`GROWTH_WINDOWS` equal windows of the valid samples, the swing
    (2-98 percentile range) rises from each to the next but once, and the
    last one's is at least :data:`GROWTH_FACTOR` times the second one's (the
    first may be the quiet start before the first set-point step). A loop
    moved by set-point steps and loads swings irregularly and passes; a
    limit cycle that grows and then settles within the record passes too.
    """
    y = np.asarray(y, dtype=float)
    v = y[np.flatnonzero(np.isfinite(y) if ok is None else ok)]
    m = GROWTH_WINDOWS
    if v.size < 8 * m:
        return None
    swing = np.array([np.subtract(*np.percentile(x, [98, 2])) for x in np.array_split(v, m)])
    rises = int(np.sum(swing[1:] > swing[:-1]))
    if rises >= m - 2 and swing[-1] >= GROWTH_FACTOR * swing[1] > 0:
        return float(swing[1]), float(swing[-1])
    return None


def _refuse_growing(y, ok, label: str):
    """Raise :class:`WorkbenchDataError` when the swing of ``y`` grows window
    after window (:func:`growing_swing`): a model driven by the OP would fit
    the runaway of an unstable loop, which no steady plant makes."""
    g = growing_swing(y, ok)
    if g is not None:
        raise WorkbenchDataError(
            f"the {label}'s swing grows from window to window ({g[0]:.4g} to {g[1]:.4g} over "
            "the record): an unstable loop, whose runaway a valve model cannot size")


def prepare_loop(pv, op, sample_time, *, sp=None, horizon="auto", blocks: int = 9,
                 band_max=None, name: str = "", op_noise: float | None = None,
                 reinit: str = "fit", pv_points: str = "all") -> LoopData:
    """Prepare a loop record for the workbench.

    Parameters
    ----------
    pv : array_like, shape (n,)
        Process variable, uniformly sampled; NaN marks missing samples
        [PV unit].
    op : array_like, shape (n,)
        Controller output, same sampling [OP unit, e.g. %]. Not clipped.
    sample_time : float
        [s]
    sp : array_like, shape (n,), optional
        Set point [PV unit]; used to label set-point changes.
    horizon : int or 'auto'
        Segment length: the prediction is re-initialised every ``horizon``
        samples [samples]. ``'auto'``: a quarter of the OP period, at least
        30 and at most 600 samples (and at most 1/12 of the record).
    blocks : int
        Number of alternating training / held-out time blocks (odd: the first
        and last blocks train, so the held-out blocks are interior).
    band_max : float, optional
        Largest valve band searched [OP unit]; default 1.5 times the median
        OP swing between reversals (at most 1.1 times the OP's 1-99 % range).
    name : str
        Label of the record for reports.
    op_noise : float, optional
        The OP's white noise [OP unit]; default read from ``op``
        (:func:`white_noise_std`). Give it for an OP rebuilt between stored
        points (:func:`rebuild_compressed_op`), whose noise is smoothed.
    reinit : {'fit', 'measured'}
        Start of each segment's prediction: ``'fit'`` (default), the best
        initial state of the segment (one nuisance value per segment, also
        on held-out segments; the measurement noise of a single sample does
        not offset the whole segment), or ``'measured'``, the measured PV at
        the segment's first sample.
    pv_points : {'all', 'stored'}
        PV samples the fit scores: every one (default), or only those a
        historian stored (:func:`stored_points`), for a PV stored by exception
        or swinging-door compression and read back by straight lines between
        its stored points. Those lines are not measurements: they cut every
        turn of the PV short, and scored as data they pull the fitted valve's
        reversals early (a dead band sized 20-30 % small). The lines must be
        exact (as interpolated in floating point): a record exported with its
        values rounded to a few decimals has a kink at every sample, and then
        every sample is scored.

    Returns
    -------
    LoopData

    Raises
    ------
    WorkbenchDataError
        Arrays of different lengths, a record too short, an OP that never
        moves or reverses fewer than :data:`MIN_REVERSALS` times (too few
        events to tell a valve's band from the process), a PV that is all
        missing or never moves (frozen), a PV (or control error) that
        diverges (:func:`_refuse_diverging`), or a PV or OP that swings wider
        and wider (:func:`growing_swing`).

    Notes
    -----
    Isolated gross outliers of PV and OP (placeholders such as -9999 or
    9.9e37, one-sample spikes) are masked first
    (:func:`valvediag.analysis.quality.despike`), as the scan masks them.
    Missing OP samples are held (so the valve chain can run) and every
    segment that contains a missing PV or OP sample is left out of fit and
    score. The first samples, until the OP has reversed and then travelled
    ``band_max`` (or the 25th percentile OP swing if smaller), plus half a
    period, are not scored: there the valve state (and a lag fed by it)
    depends on the unknown initial position (a pitfall of fitting Kano's model). The data
    are never resampled. The alternating blocks are of equal time, unless one of them
    then holds under :data:`BURSTY_BLOCK` of the mean OP reversals per block (moves
    in bursts, as around set-point steps): then each holds an equal share of half
    the time and half the reversals, lest the fit train on some bursts only, or
    check on none. A held-out segment whose OP leaves the training blocks' range by
    more than the reversal hysteresis ``op_delta`` then moves to training
    (farthest out first, at most half the held-out segments): the held-out
    blocks check the model where it was fitted, and do not ask it to extrapolate
    to a stop or a stretch of the characteristic no training sample reached.
    """
    if reinit not in ("fit", "measured"):
        raise WorkbenchDataError(f"reinit must be 'fit' or 'measured', not {reinit!r}")
    if pv_points not in ("all", "stored"):
        raise WorkbenchDataError(f"pv_points must be 'all' or 'stored', not {pv_points!r}")
    h = float(sample_time)
    if not np.isfinite(h) or h <= 0:
        raise WorkbenchDataError(f"sample time must be a positive number of seconds, got {sample_time!r}")
    pv = np.asarray(pv, dtype=float).ravel()
    op_raw = np.asarray(op, dtype=float).ravel()
    if pv.size != op_raw.size:
        raise WorkbenchDataError(f"pv has {pv.size} samples but op has {op_raw.size}")
    n = pv.size
    if sp is not None:
        sp = np.asarray(sp, dtype=float).ravel()
        if sp.size != n:
            raise WorkbenchDataError(f"pv has {n} samples but sp has {sp.size}")
    if n < MIN_SAMPLES:
        raise WorkbenchDataError(f"record too short: {n} samples (need at least {MIN_SAMPLES})")
    # placeholders (-9999, 9.9e37) and one-sample spikes would dominate every
    # squared error: masked as the scan masks them
    pv, op_raw = despike(pv)[0], despike(op_raw)[0]
    okp, oko = np.isfinite(pv), np.isfinite(op_raw)
    if okp.sum() < MIN_SAMPLES or oko.sum() < MIN_SAMPLES:
        raise WorkbenchDataError(f"too few valid samples (pv {int(okp.sum())}, op {int(oko.sum())}; "
                                 f"need {MIN_SAMPLES})")
    op = _nan_fill(op_raw)
    lo1, hi99 = np.percentile(op[oko], [1, 99])
    rng = float(hi99 - lo1)
    if not rng > 0:
        raise WorkbenchDataError("the OP never moves: nothing to explain the PV with")
    dop = np.diff(op[oko])
    noise = white_noise_std(op_raw) if op_noise is None else float(op_noise)
    delta = max(0.05 * rng, 4.0 * noise)
    idx, sgn, conf = turning_points(op, delta)
    # the first extreme only fixes the direction: the start of the record
    rev, rsg = idx[1:], sgn[1:]
    if rev.size < 2:
        raise WorkbenchDataError(f"the OP does not oscillate ({rev.size} reversal(s) larger than "
                                 f"{delta:.3g}); the workbench needs a moving, reversing OP")
    if not np.ptp(pv[okp]) > 0:
        raise WorkbenchDataError(f"the PV never moves (every valid sample is {pv[okp][0]:.6g}): "
                                 "a frozen or stale measurement; there is nothing to model")
    if rev.size < MIN_REVERSALS:
        raise WorkbenchDataError(f"the OP reverses only {rev.size} times by more than {delta:.3g} "
                                 f"(need {MIN_REVERSALS}): too few reversals to tell a valve's "
                                 "band from the process; give a longer record")
    _refuse_diverging(pv if sp is None else sp - pv, okp if sp is None else okp & np.isfinite(sp),
                      "control error" if sp is not None else "PV")
    _refuse_growing(op, oko, "OP")
    _refuse_growing(pv, okp, "PV")
    held = float(np.mean(dop == 0.0)) if dop.size else 0.0
    # period: twice the median spacing of the reversals (robust to start-up
    # transients and irregular cycles, unlike the ACF)
    period = float(2.0 * np.median(np.diff(idx)) * h) if idx.size >= 3 else float("nan")
    swing = np.abs(np.diff(op[idx]))
    if band_max is None:
        # a valve band larger than the OP swings would never let the valve move
        band_max = min(1.1 * rng, 1.5 * float(np.median(swing)))
    band_max = float(band_max)
    # burn-in: OP has reversed and moved band_max since (valve state known)
    # (the first extreme only fixes the direction; the second is a reversal),
    # plus half a period: the longest dead time searched fills the delay line
    # and a lag forgets the unknown valve position of the start
    # (a valve that moves in most half-cycles has a band below the 25th
    # percentile OP swing: that is the hysteresis, if below band_max)
    _, _, bconf = turning_points(op, max(min(band_max, float(np.percentile(swing, 25))), delta))
    burn = int(bconf[1]) if bconf.size >= 2 else int(conf[1])
    P = period if np.isfinite(period) else 0.1 * n * h
    burn += int(max(5, min(round(0.5 * P / h), 600)))
    if horizon == "auto":
        H = int(round(0.25 * period / h)) if np.isfinite(period) else 30
        H = max(30, min(H, 600, (n - burn) // 12))
    else:
        H = int(horizon)
    if H < 2:
        raise WorkbenchDataError(f"horizon must be at least 2 samples, got {horizon!r}")
    nseg = (n - burn) // H
    if nseg < MIN_SEGMENTS:
        raise WorkbenchDataError(f"record too short: {n - burn} usable samples give {nseg} segments of "
                                 f"{H} samples (need {MIN_SEGMENTS})")
    starts = burn + H * np.arange(nseg)
    ends = starts + H
    ends[-1] = n           # the last segment takes the remainder
    blocks = int(blocks)
    if blocks < 3:
        raise WorkbenchDataError("blocks must be at least 3")
    if blocks % 2 == 0:
        blocks += 1
    while blocks > 3 and nseg < 2 * blocks:
        blocks -= 2
    block_of = np.minimum((np.arange(nseg) * blocks) // nseg, blocks - 1)
    # where the OP's moves come in bursts (set-point steps), time blocks can
    # leave every burst to one set, and a band or time constant that only those
    # moves show is then never trained on or never checked: the blocks then
    # take equal shares of time and of reversals together
    scored = rev[rev >= starts[0]]
    nrev = np.bincount(np.searchsorted(starts, scored, side="right") - 1, minlength=nseg)
    per_block = np.bincount(block_of, weights=nrev, minlength=blocks)
    if nrev.sum() > 0 and per_block.min() < BURSTY_BLOCK * per_block.mean():
        share = 0.5 / nseg + 0.5 * nrev / nrev.sum()
        mid = np.cumsum(share) - 0.5 * share
        # a few bursts, each about a block's share, can still fall all in one
        # set: the block edges are then shifted by a fraction of a block, to
        # the first shift that gives each set at least a third of the reversals
        best = None
        for shift in BLOCK_SHIFTS:
            cand = np.minimum((mid * blocks + shift).astype(np.int64), blocks)
            fewest = np.bincount(cand % 2, weights=nrev, minlength=2).min()
            if best is None or fewest > best[0]:
                best = (fewest, cand)
            if fewest >= nrev.sum() / 3.0:
                break
        block_of = best[1]
    sets = (block_of % 2).astype(np.int64)
    # segments with missing data are not used
    bad = ~(okp & oko)
    cbad = np.r_[0, np.cumsum(bad)]
    sets[(cbad[ends] - cbad[starts]) > 0] = -1
    moved = _cover_op_range(op, starts, sets, float(delta))
    if (sets == 0).sum() < 2 or (sets == 1).sum() < 1:
        raise WorkbenchDataError("too few complete segments for training and held-out scoring "
                                 "(missing data)")
    scored = None
    if pv_points == "stored":
        scored = np.zeros(n, dtype=bool)
        scored[stored_points(pv)] = True
    t = np.arange(n) * h
    data = LoopData(t=t, pv=pv, op=op, sp=sp, sample_time=h, horizon=H, period=period,
                    burn_in=burn, seg_start=starts.astype(np.int64), seg_end=ends.astype(np.int64),
                    seg_set=sets, band_max=band_max, op_delta=float(delta), reversals=rev,
                    reversal_sign=rsg, held_fraction=held, op_noise=float(noise), name=str(name),
                    reinit=reinit, pv_scored=scored, moved_to_training=moved)
    if scored is not None:
        per_set = np.bincount(data.sample_set[data.sample_set >= 0], minlength=2)
        if per_set.min() < MIN_STORED:
            raise WorkbenchDataError(f"too few stored PV samples to score ({per_set[0]} training, "
                                     f"{per_set[1]} held-out; need {MIN_STORED} of each)")
    return data
