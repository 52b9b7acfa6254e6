"""
A set point the historian did not export, read back from the controller's kicks.

Many readers of a loop need to know where its set point moved: a set-point
step moves every valve, sticky or not, and the PV's answer to it (a flow's
jump, a level's kink) is no valve event. Some exports hold only the PV and
the OP. A controller whose proportional action acts on the control error
(the standard and parallel PI forms) answers the PV's every move at once with
``-Kc`` times it, and a set-point step with ``+Kc`` times the step, in the
sample the step falls in, before the process has answered: a *kick*. So the
OP's sample-to-sample moves less the controller's answer to the PV's moves
are the set point's moves times ``Kc``, and where they stand out of the
residual's noise they are its steps.

:func:`infer_setpoint` reads the controller's gain as the least-squares slope
of the OP's moves on the PV's (the PV's noise, which the controller answers
and the process has not, dominates both), marks the samples whose residual
stands out of its neighbours' by :data:`KICK_Z` robust standard deviations
as kicks, and steps a set point there by the residual over the gain.
Where no kick stands out, the set point stood; the integral action, which
moves the OP by its gain times the PV's distance from the set point, says
where.

References
----------
.. [1] Åström, K. J., Hägglund, T. (2006). Advanced PID Control. ISA,
   Research Triangle Park (set-point weighting and the proportional kick).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import median_filter

from .bumps import ENTERED_SHARE
from .quality import stored_points

__all__ = ["InferredSetPoint", "infer_setpoint", "KICK_Z", "GAIN_Z"]

#: A sample's OP move, less the controller's answer to the PV's move, is a
#: set-point kick beyond this many robust standard deviations of the rest.
KICK_Z = 6.0
#: The controller's answer to the PV's moves must be read to this many
#: standard errors for its kicks to be read at all.
GAIN_Z = 5.0
#: A floor on the residual's spread, as a share of the OP moves' robust
#: standard deviation: a proportional-only controller recorded at its own
#: scan answers the PV exactly, and rounding alone must not read as kicks.
SPREAD_FLOOR = 0.05
#: Samples of the running median the kicks stand out of.
LOCAL = 11
#: Samples over which the residual's spread is also read nearby.
SPREAD_LOCAL = 61
#: Least spread of the integral action's share of the OP's moves, over the
#: OP's spread, for the level at which it holds the PV to be read (a
#: proportional-only controller has none to read).
INTEGRAL_SHARE = 0.01
#: Samples over which the fit's residual is averaged to see a set point
#: that wandered without a step ...
WANDER_BLOCK = 32
#: ... and the largest share of its variance those means may hold for the
#: set point to be read as having stood (white noise leaves 1/32 there; on
#: the realistic benchmark's study seeds 10-13, 0.01-0.08 on records whose
#: set point stood, 0.78-0.99 on cascades' inner loops).
WANDER_SHARE = 0.25
#: Least share of their samples the OP and the PV must keep to be read
#: sample by sample: an OP stored by exception moves only now and then, a
#: compressed PV's recorded moves are not those the controller answered.
OP_KEPT = 0.7


def _slow_share(r: np.ndarray, m: int) -> float:
    """Share of the variance of ``r`` (NaN where not read) that lies in its
    means over blocks of ``m`` samples; NaN with fewer than 4 blocks read in
    a quarter or more. White noise leaves about ``1 / m`` there, a drift
    nearly all."""
    nb = r.size // m
    if nb < 4:
        return math.nan
    blocks = r[:nb * m].reshape(nb, m)
    count = np.isfinite(blocks).sum(axis=1)
    full = count >= m // 4
    if full.sum() < 4:
        return math.nan
    means = np.nansum(blocks[full], axis=1) / count[full]
    spread = float(np.nanvar(r))
    return float(np.var(means)) / spread if spread > 0 else math.nan


def _robust_std(x: np.ndarray) -> float:
    """1.4826 times the median absolute deviation from the median."""
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else math.nan


@dataclass(frozen=True)
class InferredSetPoint:
    """A set point read back from the OP's kicks.

    Attributes
    ----------
    sp : numpy.ndarray or None
        The set point at every sample [PV unit], or None where none could be
        read (no controller answer to the PV, kicks at too many samples, or
        no kick and no integral action to read). Where it stepped, its level
        is the PV's median distance from its steps: where integral action
        holds the PV at its set point it is the set point's, elsewhere
        (proportional-only control stands off it) only its moves are right.
        Where it stood, its level is the one at which the integral action
        holds the PV (the OP's drift against the PV's level).
    steps : numpy.ndarray
        Samples at which it moved (the kick's sample).
    gain : float
        The controller's OP move per PV move read from the record (``-Kc``
        for a controller that opposes the PV) [OP unit per PV unit].
    gain_z : float
        The gain over its standard error.
    reason : str
        One sentence.
    pv, op : numpy.ndarray
        The record read, for :meth:`plot`.
    """

    sp: np.ndarray | None = field(repr=False)
    steps: np.ndarray = field(repr=False)
    gain: float
    gain_z: float
    reason: str
    pv: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    op: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def as_dict(self) -> dict:
        """The figures as plain types."""
        return {"read": self.sp is not None, "steps": int(self.steps.size),
                "gain": round(self.gain, 4), "gain_z": round(self.gain_z, 1),
                "reason": self.reason}

    def plot(self, ax=None):
        """The PV with the set point read back, and the kicks marked.

        Returns
        -------
        matplotlib.axes.Axes
        """
        if ax is None:
            import matplotlib.pyplot as plt
            _, ax = plt.subplots()
        k = np.arange(self.pv.size)
        ax.plot(k, self.pv, lw=0.6, label="PV")
        if self.sp is not None:
            ax.plot(k, self.sp, lw=1.2,
                    label="set point read from the OP's kicks" if self.steps.size else
                    "set point that stood, where the integral action holds the PV")
            ax.plot(self.steps, self.sp[self.steps], "v", ms=5)
        ax.set_xlabel("sample")
        ax.set_ylabel("PV unit")
        ax.set_title(f"{self.steps.size} kicks; controller gain {self.gain:.3g} "
                     f"({self.gain_z:.0f} SE)", fontsize=9)
        ax.legend(fontsize=7)
        return ax


def infer_setpoint(pv, op) -> InferredSetPoint:
    """Read a loop's set-point steps from the kicks of its controller's OP.

    Parameters
    ----------
    pv, op : array_like, shape (n,)
        One stretch of a loop in automatic, uniformly sampled [PV unit, OP
        unit]; NaN marks missing samples.

    Returns
    -------
    InferredSetPoint

    Notes
    -----
    The controller's gain is the slope of the OP's moves on the PV's,
    beside the PV's level (the integral action on the error while the set
    point stands) and a constant, fitted twice by least squares (the second
    time without the first's kicks and with the error read against the set
    point they make). A kick is a residual that stands out of its
    neighbours' running median (:data:`LOCAL` samples) by more than
    :data:`KICK_Z` robust standard deviations, of the whole record's and of
    its own :data:`SPREAD_LOCAL` samples' (floored at :data:`SPREAD_FLOOR`
    of the OP moves') plus half the integral action on the PV's move in the
    sample (the integral over a sample in which the PV jumped is read
    between its ends, and may be off by that much); a run of them is one step, at its
    first sample, of its largest residual over the gain. Where no kick stands
    out, the set point stood, at the level where the fitted integral action
    stops moving the OP, if that action is read to :data:`GAIN_Z` standard
    errors and carries :data:`INTEGRAL_SHARE` of the OP's spread, and the
    fit's residual holds at most :data:`WANDER_SHARE` of its variance in its
    :data:`WANDER_BLOCK`-sample means (a set point that wanders without a
    step, as a cascade's inner loop's does, leaves its moves there, each
    below a kick). Nothing is read where
    the OP or the PV keeps fewer than :data:`OP_KEPT` of its samples (a
    record stored by exception or compressed, whose moves are not those the
    controller answered; the OP's samples held at a limit it is clipped at
    are the limit's, and the share is read over the rest: a dead loop's OP
    winds from limit to limit and rests there), the gain is not
    read to :data:`GAIN_Z` standard errors, or steps fall at more than
    :data:`~valvediag.analysis.bumps.ENTERED_SHARE` of the samples (an
    operator enters a set point now and then; an OP stored by exception
    moves only now and then, and is no controller's answer sample by
    sample).

    It fails where the controller does not kick: proportional action on the
    PV alone (I-PD), set-point weighting near zero, a set-point ramp or
    filter. Derivative action is not modelled: on the error, it kicks the
    OP further for a sample or a few, which reads a step in its place but
    too large; on the PV, its answer to a sharp change of the PV's move (a
    slip) may read as a kick and mask that slip. A regressor for it was
    tried and dropped: on a fast PI flow sampled every 10 s it read three
    kicks that were none. Those steps move the OP through the integral only, and the
    PV's answer is then smooth, so little is lost. An operator's manual
    moves of the OP read as kicks too; like a set-point step, they move
    every valve and say nothing of it. A step smaller than the residual's
    noise (a compressed PV's, whose recorded moves are not the ones the
    controller answered) is not read; where none is read, the level said to
    have stood is a mean of the levels the set point held. A set point with
    integral action holds the PV there on average; without it (proportional
    only) the level returned is off by the offset, and only the moves are
    right.

    References
    ----------
    .. [1] Åström, K. J., Hägglund, T. (2006). Advanced PID Control. ISA.
    """
    y = np.asarray(pv, dtype=float).ravel()
    u = np.asarray(op, dtype=float).ravel()
    if y.size != u.size:
        raise ValueError(f"pv has {y.size} samples but op has {u.size}")
    empty = np.zeros(0, dtype=int)

    def none(reason, gain=math.nan, z=math.nan):
        return InferredSetPoint(sp=None, steps=empty, gain=gain, gain_z=z, reason=reason,
                                pv=y, op=u)

    # an OP held at a limit (clipped: its extreme, held at more than one
    # sample) answers nothing; those samples are the limit's, not a
    # historian's, and the share kept is read over the others
    finite = u[np.isfinite(u)]
    limits = [end for end in ((finite.min(), finite.max()) if finite.size else ())
              if np.count_nonzero(finite == end) > 1]
    held = np.isin(u, limits)
    for name, x, off in (("OP", u, ~held), ("PV", y, np.ones(y.size, bool))):
        kept = np.count_nonzero(off[stored_points(x)])
        if kept < OP_KEPT * np.count_nonzero(off) or not off.any():
            return none(f"the {name} keeps fewer than {100 * OP_KEPT:.0f} % of its samples "
                        "(stored by exception or compressed, or standing still): the moves "
                        "recorded are not the ones the controller answered, sample by sample")
    dy, du = np.diff(y), np.diff(u)
    # near a limit (within the kicks' own threshold of its moves) a move may
    # have been cut short between the samples recorded; nor does an OP that
    # stands still answer
    near_limit = KICK_Z * _robust_std(du[np.isfinite(du)])
    at = np.zeros(u.size, bool)
    for end in limits:
        at |= np.abs(u - end) <= near_limit
    still = (du == 0) | at[:-1] | at[1:]
    ok = np.isfinite(dy) & np.isfinite(du) & ~still
    if ok.sum() < 8:
        return none("too few samples to read the controller's answer to the PV")
    floor = SPREAD_FLOOR * _robust_std(du[ok])
    # the OP's move: the answer to the PV's move, the integral action on the
    # error (the PV's level against the set point read so far) and the set
    # point's kicks, which stand out of their neighbours' residuals (the
    # integral action's answer to a step lasts; the kick is one sample's)
    kicks = np.zeros(dy.size, bool)
    path = np.zeros(y.size)               # the set point's moves read so far
    for _ in range(2):
        # the error over the sample, as the integral sums it (trapezoid)
        level = 0.5 * (y[:-1] + y[1:]) - path[1:]
        centre = float(np.nanmedian(level))
        level = level - centre
        X = np.column_stack([dy, level, np.ones(dy.size)])
        use = ok & ~kicks & np.isfinite(level)
        if use.sum() < 8 or not float(dy[use] @ dy[use]) > 0:
            return none("the PV does not move: no controller answer to read")
        coef, *_ = np.linalg.lstsq(X[use], du[use], rcond=None)
        res = du - X @ coef
        dof = max(int(use.sum()) - 3, 1)
        cov = np.linalg.pinv(X[use].T @ X[use]) * float(res[use] @ res[use]) / dof
        gain = float(coef[0])
        se = math.sqrt(max(float(cov[0, 0]), 0.0))
        z = abs(gain) / se if se > 0 else (math.inf if gain != 0 else 0.0)
        spike = res - median_filter(np.where(np.isfinite(res), res, 0.0), size=LOCAL,
                                    mode="nearest")
        spread = max(_robust_std(spike[use]), floor)
        # read against the residual's own spread nearby too: a stretch the
        # model does not fit (a loop in manual for the rest of the day, whose
        # OP answers nothing) must not set the scale for the rest
        size_abs = np.abs(np.where(np.isfinite(spike), spike, 0.0))
        near = 1.4826 * median_filter(size_abs, size=SPREAD_LOCAL, mode="nearest")
        # the integral action over a sample in which the PV moved is read
        # between its ends; where the PV jumped (a load's step or a slip on a
        # fast loop) it may be off by half the move's share
        within = 0.5 * abs(float(coef[1])) * np.abs(np.where(ok, dy, 0.0))
        kicks = ok & np.isfinite(spike) & (
            np.abs(spike) > KICK_Z * np.maximum(near, spread) + within)
        # a run of kicks is one step, at its first sample, of its largest
        # spike: the samples after a step carry the integral action's answer
        # to the error the PV has not yet closed
        first = kicks & ~np.r_[False, kicks[:-1]]
        size = np.zeros(dy.size)
        if kicks.any():
            k = np.flatnonzero(kicks)
            run = np.cumsum(first)[k]                              # ascending, as k
            by_run = k[np.lexsort((-np.abs(spike[k]), run))]      # largest first in each run
            size[first] = spike[by_run[np.r_[True, np.diff(run) != 0]]]
        path = np.zeros(y.size)
        if gain != 0:
            path[1:] = np.cumsum(-size / gain)
    if not z >= GAIN_Z:
        return none(f"the OP does not answer the PV's moves clearly ({z:.1f} standard errors): "
                    "no controller gain to read its kicks by", gain, z)
    if first.sum() > ENTERED_SHARE * ok.sum():
        return none(f"the OP jumps at {first.sum()} of {ok.sum()} samples, more than an "
                    "operator's set-point moves: not read as kicks", gain, z)
    if not first.any():
        # a set point that wanders without a step (a cascade's inner loop
        # follows its outer loop's output) is no level: its moves, each below
        # a kick, leave the fit's residual slow
        slow = _slow_share(np.where(use, res, np.nan), WANDER_BLOCK)
        if slow > WANDER_SHARE:
            return none(f"no kick of the OP beyond its answer to the PV, but "
                        f"{100 * slow:.0f} % of the answer's residual lies in its "
                        f"{WANDER_BLOCK}-sample means: the set point wandered without a step "
                        "(a cascade's inner loop?)", gain, z)
        # the integral action moves the OP by its gain times the PV's
        # distance from the set point, the same way as the proportional
        # action answers the PV's moves: where it is read clearly and carries
        # a share of the OP's moves, the OP's drift against the PV's level
        # says where the set point stood
        ki, ki_se = float(coef[1]), math.sqrt(max(float(cov[1, 1]), 0.0))
        carried = np.cumsum(ki * np.where(np.isfinite(level), level, 0.0))
        if (ki * gain > 0 and abs(ki) >= GAIN_Z * ki_se
                and np.std(carried) >= INTEGRAL_SHARE * float(np.nanstd(u))):
            stood = centre - float(coef[2]) / ki
            return InferredSetPoint(
                sp=np.full(y.size, stood), steps=empty, gain=gain, gain_z=z,
                reason=(f"no kick of the OP beyond its answer to the PV: the set point stood, "
                        f"at {stood:.4g}, where the integral action holds the PV (read to "
                        f"{abs(ki) / ki_se:.0f} standard errors)"), pv=y, op=u)
        return none("no kick of the OP beyond its answer to the PV: the set point stood",
                    gain, z)
    steps = np.flatnonzero(first) + 1                    # the sample the kick lands on
    offset = float(np.nanmedian(y - path))
    return InferredSetPoint(sp=offset + path, steps=steps, gain=gain, gain_z=z,
                            reason=f"{steps.size} set-point moves read from the OP's kicks "
                                   f"(controller gain {-gain:.3g}, read to {z:.0f} standard "
                                   "errors)", pv=y, op=u)
