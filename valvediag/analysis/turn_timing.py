"""
A level's rounded turn against the controller's reversal: a dead band or a slip behind a lag.

In an integrating loop's limit cycle the level runs in straight ramps while
the valve stands, and turns where the valve moves. The Backlash Index
(Farenzena & Trierweiler, 2012) reads the turn's shape: sharp where a
sticky valve jumps, rounded where a loose valve follows the OP across the
top of its travel. A first-order lag between the valve and the measured
level (a positioner, a sensor, a mixing volume) rounds a sticky valve's
turn as well, and the two shapes are then too alike to tell apart
(:func:`~valvediag.analysis.bi.lagged_turns`).

*When* the level turns, against the OP, tells them apart. A PI controller
reverses its output where the PV's slope, which it sees at once, reaches
``e / Ti``; the valve's state does not enter. A loose valve moves only
while the OP moves on beyond its band, so all of its travel, and all of
the level's change of slope, comes *before* the OP's reversal; after it
the valve rests in its band and the level runs straight (a lag leaves only
its tail). A sticky valve stands until it slips; the slip turns the level,
the controller sees the turn and reverses at once, and the rest of the
level's change of slope, spread by the lag, comes *after* the OP's
reversal.

:func:`turn_timing` measures, at each reversal of the OP, how far the level
lies from the straight ramp before it and from the straight ramp after it:
the level's departure from the ramp after is the part of the turn still to
come. Its share of the two is close to 0 for a dead band, and a good part
of the turn for a slip behind a lag, where the controller reverses before
the turn is done. The reading is one-sided: where the integral action is
strong against the ramps (``e / Ti`` at the turn close to the new ramp's
slope) the controller reverses only once a slip's turn is done, too.

References
----------
.. [1] Farenzena, M., Trierweiler, J. O. (2012). Valve backlash and stiction
   detection in integrating processes. IFAC ADCHEM 8, Singapore.
.. [2] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter
from scipy.stats import trim_mean

from .quality import stored_points, white_noise_std
from .trend import pv_op_trend

__all__ = ["TurnTiming", "turn_timing", "SLIP_SHARE", "POOLED_SHARE", "POOLED_Z", "MIN_TURNS",
           "OP_RESOLUTION"]

#: Median share of a turn after the OP's reversal at and above which the
#: level turns behind the valve's slip (the loose level valves of the
#: realistic benchmark's study seeds 10-16 read at most 0.17).
SLIP_SHARE = 0.2
#: The same share pooled over the turns, from the level's signed distances
#: from the two ramps (their trimmed means), at and above which the level
#: turns behind the valve's slip: measurement noise inflates each turn's
#: share of two distances read unsigned, and cancels in their means (the
#: loose level valves of the realistic benchmark's development seeds 1 and 2
#: and study seeds 10-26 read at most 0.041, a lag of 50 s's tail).
POOLED_SHARE = 0.08
#: Standard errors above zero by which the mean distance from the ramp after
#: must stand for the pooled share to name anything.
POOLED_Z = 3.0
#: Turns that must be read before the share names anything.
MIN_TURNS = 3
#: Fewest samples per period: coarser records do not place a turn.
MIN_SPP = 20.0
#: The ramps are read from this share of the way to the neighbouring
#: reversal to this one ...
RAMP_FROM, RAMP_TO = 0.2, 0.5
#: Fewest samples on a ramp.
MIN_RAMP = 5
#: Widest span between the OP's stored points around a reversal read, as a
#: share of the period (a compressed OP's extreme lies anywhere between two
#: stored points).
OP_RESOLUTION = 0.02
#: Least share of a compressed OP's stored moves that the PI law fitted to
#: them must explain (R^2) for the law to place the OP's reversals. A
#: reversal needs only the law's slow turn, not every stored move, so this
#: asks less than the workbench's fits
#: (:data:`~valvediag.workbench.data.REBUILD_R2`, 0.8). The realistic
#: benchmark's compressed level cycles (development seeds 1 and 2, study
#: seeds 10-26, 93 records) spread over 0.07-0.99; between 0.5 and 0.8 the
#: law placed reversals at which loose valves read medians of at most 0.08
#: and pooled shares of at most 0.076, and sticky ones behind a lag turned
#: after them (shares 0.19-0.55).
LAW_R2 = 0.5


@dataclass(frozen=True)
class TurnTiming:
    """A level's turns against its OP's reversals.

    Attributes
    ----------
    kind : str
        ``'stiction'`` when the turns come after the OP's reversals (a slip
        behind a lag), else ``''``: a turn done by the OP's reversal is a
        dead band's or a slip's that the controller answered late (see
        :func:`turn_timing`, Notes).
    reason : str
        One sentence.
    turns : int
        Turns read.
    share : float
        Median share of a turn that comes after the OP's reversal (0: all
        before; NaN when fewer than :data:`MIN_TURNS` turns were read).
    shares : numpy.ndarray
        That share at each turn read.
    at : numpy.ndarray
        Sample of the OP's reversal at each turn read.
    by_law : int
        Turns read whose reversal the compressed OP did not place and the
        controller's law did (see :func:`turn_timing`, Notes).
    pooled : float
        Share of the turns after the OP's reversals, pooled: the trimmed
        mean of the level's signed distance from the ramp after over the
        sum of the two trimmed means (NaN when fewer than
        :data:`MIN_TURNS` turns).
    pooled_z : float
        Mean distance from the ramp after over its standard error.
    """

    kind: str
    reason: str
    turns: int = 0
    share: float = math.nan
    shares: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    at: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    by_law: int = 0
    pooled: float = math.nan
    pooled_z: float = math.nan
    pv: np.ndarray | None = field(default=None, repr=False)
    op: np.ndarray | None = field(default=None, repr=False)
    sample_time: float = 1.0

    def as_dict(self) -> dict:
        """The figures as plain types."""
        return {"kind": self.kind, "turns": self.turns,
                "share_after_op_reversal": (round(self.share, 3) if math.isfinite(self.share)
                                            else None),
                "reversals_by_law": self.by_law,
                "pooled_share": round(self.pooled, 3) if math.isfinite(self.pooled) else None,
                "pooled_z": round(self.pooled_z, 1) if math.isfinite(self.pooled_z) else None}

    def plot(self, ax=None):
        """PV and OP, with a line at each OP reversal read, red where the level turned after it.

        Returns
        -------
        matplotlib.axes.Axes
        """
        ax, t = pv_op_trend(ax, self.pv, self.op, self.sample_time, self.reason)
        if t is None:
            return ax
        late = self.shares >= SLIP_SHARE
        for sel, color, label in ((late, "C3", "OP reversal; the level turns after it"),
                                  (~late, "C2", "OP reversal; the level has turned")):
            for k, j in enumerate(self.at[sel]):
                ax.axvline(t[j], color=color, lw=0.6, alpha=0.6, label=label if k == 0 else None)
        ax.legend(loc="upper left", fontsize=7)
        title = (f"{self.turns} turns: median share after the OP's reversal {self.share:.2f}"
                 if self.turns else "no turn read against the OP's reversals")
        if math.isfinite(self.pooled):
            title += f"; pooled {self.pooled:.2f} ({self.pooled_z:.1f} SE)"
        ax.set_title(title)
        return ax


def _windows(cs: np.ndarray, cty: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Mean, slope per sample and centre of ``x`` over each window ``[a, b)``, from prefix sums."""
    L = (b - a).astype(float)
    sy = cs[b] - cs[a]
    sty = cty[b] - cty[a]
    tm = 0.5 * (a + b - 1)
    mean = sy / L
    stt = L * (L * L - 1.0) / 12.0
    slope = (sty - tm * sy) / stt
    return mean, slope, tm


def _placed_reversals(x, u, h, m, w, delta, sp, idx, sign):
    """The OP's reversals ``idx`` (``sign`` +1 at a maximum), each where the
    record places it; which are placed, and which of those the law placed.

    A reversal is placed where the stored OP's points around it lie within
    :data:`OP_RESOLUTION` of the ``m`` samples of a period; the others move
    to the reversal of the same sign that the OP rebuilt from the
    controller's law makes within the stored points' span (``w`` samples
    either side), where the law explains the stored moves."""
    from ..workbench.data import rebuild_compressed_op
    from ..workbench.kernels import turning_points

    kept = stored_points(u)
    j = np.searchsorted(kept, idx, side="right")
    left, right = kept[np.maximum(j - 1, 0)], kept[np.minimum(j, kept.size - 1)]
    resolved = right - left <= max(2.0, OP_RESOLUTION * m)
    none = np.zeros(idx.size, bool)
    if resolved.all():
        return idx, resolved, none
    rebuilt, r2 = rebuild_compressed_op(x, u, h, sp=sp)
    if not (np.isfinite(r2) and r2 >= LAW_R2):
        return idx, resolved, none
    ridx, rsign, _ = turning_points(savgol_filter(rebuilt, w, 2), delta)
    if ridx.size == 0:
        return idx, resolved, none
    p = np.searchsorted(ridx, idx)
    near = np.clip(np.stack([p - 1, p]), 0, ridx.size - 1)          # (2, reversals)
    at, same = ridx[near], rsign[near] == sign
    inside = same & (at >= left - w) & (at <= right + w)
    best = np.argmin(np.where(inside, np.abs(at - idx), np.iinfo(np.int64).max), axis=0)
    cols = np.arange(idx.size)
    take = ~resolved & inside[best, cols]
    return np.where(take, at[best, cols], idx), resolved | take, take


def turn_timing(pv, op, sample_time: float, period: float, *, sp=None) -> TurnTiming:
    """Read a level's turns against its OP's reversals: a dead band or a slip behind a lag.

    Parameters
    ----------
    pv, op : array_like, shape (n,)
        One gap-free oscillating stretch of an integrating loop in automatic
        under PI control [PV unit, OP unit].
    sample_time : float
        [s]
    period : float
        Oscillation period [s] (:func:`~valvediag.analysis.detect_oscillation`).
    sp : array_like, shape (n,), optional
        Set point [PV unit]; with a compressed OP, the controller's law is
        fitted to the control error ``SP - PV`` (constant set point when
        not given).

    Returns
    -------
    TurnTiming

    Raises
    ------
    ValueError
        Unequal lengths or a non-positive sample time.

    Notes
    -----
    The OP is smoothed by a quadratic Savitzky-Golay filter over a 25th of
    the period (5 samples at least); its reversals are its extremes
    confirmed by a move of 30 % of its 5-95 % range. At each reversal ``i``
    between reversals ``i0`` and ``i1``, the level's ramp before is the
    line fitted over ``[i0 + 0.2 (i - i0), i0 + 0.5 (i - i0))``, the ramp
    after over ``[i + 0.2 (i1 - i), i + 0.5 (i1 - i))``, and the level at the
    reversal its mean over a hundredth of the period either side. With
    ``e_b`` and ``e_a`` the level's distance from the two lines at ``i``, the
    share ``e_a / (e_a + e_b)`` is the part of the turn still to come. Only
    turns (ramps of opposite slope) whose distances stand three standard
    errors of the level's noise above zero are read, and only where the
    OP's stored points around the reversal lie within
    :data:`OP_RESOLUTION` of the period (an OP compressed by exception and
    read back by straight lines has its extreme anywhere between two stored
    points: on the synthetic plant's loose level valves, whose OPs are
    stored so, turns read 0.36-0.82 after the reversal without this guard).
    Such a reversal is placed instead where the controller made it: on the
    OP rebuilt between its stored points from the PI law fitted to the
    stored moves (:func:`~valvediag.workbench.data.rebuild_compressed_op`),
    where that law explains at least :data:`LAW_R2` of them, taking the
    rebuilt OP's reversal of the same sign within the stored points' span.
    The law sees the recorded level, which the valve does not enter, so the
    reversal it places is the controller's (the loose level valves of the
    realistic benchmark's study and development seeds with a compressed
    OP read at most 0.09 so, as without it); where the law does not hold
    (an OP held at a limit, derivative action, a change of tuning) the
    reversal is not read.

    A dead band reads at most its lag's tail, about ``2 (L / T_f)^2`` for a
    lag ``L`` and a valve that follows the OP for ``T_f``; a slip behind a
    lag reads the part of the lag's spread that comes after the PV's slope
    has reached ``e / Ti``, where the controller reverses. So a median at or
    above :data:`SLIP_SHARE` names a slip; a smaller one names nothing: a
    slip without a lag, or one whose turn the controller answers only once
    it is done (``e / Ti`` at the turn near the new ramp's slope: strong
    integral action, a long period), reads near 0 as well.

    Each turn's two distances are read unsigned for its share, and the
    level's noise adds to both: a noisy dead band's median share lies above
    its lag's tail, which is why the median must reach
    :data:`SLIP_SHARE`. Pooled, the distances are signed (a rounded turn
    lies inside the corner of its two ramps: positive on both) and averaged
    over the turns (:func:`scipy.stats.trim_mean`, a tenth cut at either
    end, against turns the reversals misplace), so the noise cancels, and a
    pooled share at or above :data:`POOLED_SHARE`, with the mean distance
    after the reversal :data:`POOLED_Z` standard errors above zero, names a
    slip too. The pooled share reads a dead band's lag tail as it is, and
    so a loose valve behind a longer lag reads as a slip sooner than by the
    median: on a PI level loop (``Kc`` 3, ``Ti`` 300 s, a time constant of
    200 s, a dead band of 3 %), a loose valve behind a first-order lag of
    24 s (2 % of its period) read 0.04 pooled, behind 48 s (5 %) 0.145, a
    slip, where the median reached :data:`SLIP_SHARE` only behind 96 s
    (13 %). The realistic benchmark's loose level valves lie behind lags of
    under 2 % of their periods.

    The reading holds for a PI controller that sees the level unfiltered:
    a filtered PV, or derivative action on it, moves the reversal. A valve
    that slips where the OP turns for another reason (a set-point move, a
    clamp at an OP limit) reads as a dead band. A turn whose slip lies
    within a sample or two of the reversal and has no lag (the index's own
    sharp turn) reads close to 0: the index is the evidence there. Coarse
    records (fewer than :data:`MIN_SPP` samples per period) are not read.
    """
    x = np.asarray(pv, dtype=float)
    u = np.asarray(op, dtype=float)
    h = float(sample_time)
    if x.shape != u.shape or x.ndim != 1:
        raise ValueError("pv and op must be one-dimensional and of equal length")
    if not h > 0:
        raise ValueError(f"sample_time must be positive, got {sample_time}")
    common = dict(pv=x, op=u, sample_time=h)
    m = period / h if np.isfinite(period) else math.nan
    if not m >= MIN_SPP:
        return TurnTiming("", f"{m:.3g} samples per period: too coarse to place a turn",
                          **common)
    w = max(5, int(m / 25) | 1)
    if x.size < 4 * w or not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        return TurnTiming("", "too short or not gap-free", **common)
    from ..workbench.kernels import turning_points

    us = savgol_filter(u, w, 2)
    lo, hi = np.percentile(us, [5, 95])
    idx, sign, _ = turning_points(us, 0.3 * (hi - lo)) if hi > lo else (np.zeros(0, int),) * 3
    if idx.size < 3:
        return TurnTiming("", "fewer than three reversals of the OP", **common)
    k = max(1, int(round(m / 100)))
    # the OP's reversal must be where the historian stored it: an OP read
    # back between stored points far apart places its extreme anywhere
    # between them; there the controller's law places it, where it holds
    i, resolved, by_law = _placed_reversals(x, u, h, m, w, 0.3 * (hi - lo), sp, idx, sign)
    i0, i, i1 = i[:-2], i[1:-1], i[2:]
    resolved, by_law = resolved[1:-1], by_law[1:-1]
    d0, d1 = i - i0, i1 - i
    ab, bb = i0 + (RAMP_FROM * d0).astype(int), i0 + (RAMP_TO * d0).astype(int)
    aa, ba = i + (RAMP_FROM * d1).astype(int), i + (RAMP_TO * d1).astype(int)
    ok = ((bb - ab >= MIN_RAMP) & (ba - aa >= MIN_RAMP) & (i - k >= 0) & (i + k + 1 <= x.size)
          & resolved)
    i, ab, bb, aa, ba, by_law = i[ok], ab[ok], bb[ok], aa[ok], ba[ok], by_law[ok]
    t = np.arange(x.size, dtype=float)
    cs = np.r_[0.0, np.cumsum(x)]
    cty = np.r_[0.0, np.cumsum(t * x)]
    mb, sb, tb = _windows(cs, cty, ab, bb)
    ma, sa, ta = _windows(cs, cty, aa, ba)
    level = (cs[i + k + 1] - cs[i - k]) / (2 * k + 1)
    # the level's distances from the two ramps at the reversal, signed so
    # that a turn rounded either way (it lies inside the corner the ramps
    # make) reads positive on both
    side = np.sign(sb)                     # +1 where the level turns at a maximum
    below_b = side * (mb + sb * (i - tb) - level)
    below_a = side * (ma + sa * (i - ta) - level)
    eb, ea = np.abs(below_b), np.abs(below_a)
    noise = white_noise_std(x)
    se = 3.0 * noise / math.sqrt(2 * k + 1) if np.isfinite(noise) else 0.0
    turns = np.sign(sa) * np.sign(sb) < 0
    read = turns & (ea + eb > se)
    shares = ea[read] / (ea[read] + eb[read])
    at = i[read]
    n = int(shares.size)
    common.update(by_law=int(by_law[read].sum()))
    pooled = pooled_z = math.nan
    if turns.sum() >= MIN_TURNS:
        after, before = below_a[turns], below_b[turns]
        mean_after, mean_before = float(trim_mean(after, 0.1)), float(trim_mean(before, 0.1))
        whole = mean_after + mean_before
        pooled = mean_after / whole if whole > 0 else math.nan
        sd = float(np.std(after, ddof=1))
        pooled_z = float(np.mean(after)) / (sd / math.sqrt(after.size)) if sd > 0 else math.nan
        common.update(pooled=pooled, pooled_z=pooled_z)
    late = math.isfinite(pooled) and pooled >= POOLED_SHARE and pooled_z >= POOLED_Z
    if n < MIN_TURNS and not late:
        return TurnTiming("", f"{n} turns read against the OP's reversals, fewer than "
                          f"{MIN_TURNS}", turns=n, shares=shares, at=at, **common)
    share = float(np.median(shares)) if n >= MIN_TURNS else math.nan
    if share >= SLIP_SHARE:
        kind, why = "stiction", (f"the level turns after the OP has reversed (a median "
                                 f"{100 * share:.0f}% of each turn comes after it, {n} turns): "
                                 "the valve slipped and a lag spread the turn")
    elif late:
        kind, why = "stiction", (f"the level turns after the OP has reversed (over "
                                 f"{int(turns.sum())} turns, {100 * pooled:.0f}% of the turn "
                                 f"comes after it, {pooled_z:.1f} standard errors above none): "
                                 "the valve slipped and a lag spread the turn")
    else:
        kind, why = "", (f"the level has mostly turned by the time the OP reverses (a median "
                         f"{100 * share:.0f}% of each turn comes after it, {n} turns): a "
                         "valve that moved with the OP, or a slip the controller answered late")
    if common["by_law"]:
        why += (f"; {common['by_law']} of the reversals placed by the PI law fitted to the "
                "compressed OP's stored moves")
    return TurnTiming(kind, why, turns=n, share=share, shares=shares, at=at, **common)
