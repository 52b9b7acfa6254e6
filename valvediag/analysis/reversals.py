"""
A loose valve read at the OP's reversals: the flow runs on with its load while the valve rests.

A self-regulating loop (a flow, a pressure) whose valve follows its OP
answers every move of the OP within the process's dead time and lag. When
the load drifts, the controller's output drifts with it and the PV stays
near its set point; where the load turns, the OP turns too. A valve with a
dead band (backlash, a loose linkage, a worn positioner) holds its position
after the OP reverses until the OP has crossed the band: for that while the
loop is open, the PV runs on with the load, away from its set point, and the
OP, driven by the growing error, moves on *without the PV answering it*.
Once the band is taken up the valve follows and the PV comes back, now
answering the OP. Behind slow integral action that take-up is a slow return,
not a jump, and a reader of jumps
(:func:`~valvediag.analysis.signature.stick_slip_events`) sees nothing.

:func:`reversal_rests` reads every leg of the OP between two reversals. It
finds the PV's excursion against the OP's correction and fits, before the
PV turned back and after, the PV as a line plus a gain times the OP. A rest
is an excursion during which the PV did not answer the OP (the gain is
within two standard errors of zero, and well below the gain after) and after
which it did. The OP's travel during a rest is the dead band.

A load's step moves the PV first and the OP answers it: the PV's excursion
then grows *with* the OP's travel (the controller's proportional action
follows the error it sees), and the fitted gain is large and negative, no
rest. A linear valve under a drifting load answers the OP at once and
leaves no excursion beyond the noise.

References
----------
.. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston (the
   valve at rest while the OP moves).
.. [2] Hägglund, T. (2007). Automatic on-line estimation of backlash in
   control loops. Journal of Process Control 17, 489-499 (a dead band
   read from the loop's behaviour at the OP's reversals).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.stats import median_abs_deviation

from .quality import drawn_counts, drawn_within, resolved_noise_std, white_noise_std
from .signature import loop_sense
from .trend import pv_op_trend

__all__ = ["Excursions", "ReversalRests", "reversal_rests", "pooled_reversal_rests",
           "EXCURSION_Z", "MIN_RESTS", "MIN_REST_SHARE", "SMOOTH_S"]

#: Window of the moving average that reads the OP's reversals and the PV's
#: excursions through their noise [s] (3 to 31 samples).
SMOOTH_S = 30.0
#: The PV's excursion against the OP's correction, in standard errors of the
#: smoothed PV, that makes a leg read.
EXCURSION_Z = 6.0
#: Rests that make a fault ...
MIN_RESTS = 3
#: ... and the share of the excursions they must make.
MIN_REST_SHARE = 1.0 / 3.0
#: Or: at least this many rests, making this share of the excursions ...
MIN_RESTS_FIXED, MIN_REST_SHARE_FIXED = 5, 0.15
#: ... whose durations spread by at least this much (robust standard
#: deviation of their logarithm: about 20 %) ...
DURATION_SPREAD = 0.2
#: ... while their OP travels spread by at most this share of it: the valve
#: took up a band of fixed width, whatever the OP's speed.
TRAVEL_SPREAD_SHARE = 0.5
#: Or: at least this many excursions in all ...
MIN_TURNS_FIXED = 8
#: ... whose OP travels from the reversal to the PV's turn spread by at most
#: this much (robust standard deviation of their logarithm: about 20 %) and
#: by at most ``TRAVEL_SPREAD_SHARE`` of their durations' spread (at least
#: ``DURATION_SPREAD``), while the OP's whole legs spread by at least this
#: many times their travels' spread (and at least ``DURATION_SPREAD``): the
#: PV turned after a fixed travel of an OP that moved at any speed and as
#: far as it liked, which no process delay and no periodic load does.
TURN_TRAVEL_SPREAD, LEG_SPREAD_RATIO = 0.2, 2.0
#: Most legs of the OP read (the first ones of the record).
MAX_LEGS = 2000
#: Fewest samples in a fitted stretch.
MIN_FIT = 6


@dataclass(frozen=True)
class Excursions:
    """The excursions of a PV after its OP's reversals, one entry each.

    Attributes
    ----------
    legs : int
        Legs of the OP read (set point steady), excursions or not.
    start, turn : numpy.ndarray
        Sample of the OP's reversal and of the PV's turn.
    travel : numpy.ndarray
        The OP's travel from the reversal to the PV's turn [OP unit].
    leg : numpy.ndarray
        The OP's travel over the whole leg [OP unit].
    gain_rest, gain_follow : numpy.ndarray
        The PV's fitted gain on the OP before and after its turn, in the
        loop's sense [PV unit / OP unit].
    rest : numpy.ndarray of bool
        The valve rested: the PV did not answer the OP before its turn and
        did after it.
    """

    legs: int = 0
    start: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    turn: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    travel: np.ndarray = field(default_factory=lambda: np.zeros(0))
    leg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gain_rest: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gain_follow: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rest: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @staticmethod
    def joined(parts) -> "Excursions":
        """The excursions of several stretches as one table (``start`` and
        ``turn`` index each stretch's own samples)."""
        parts = list(parts)
        cat = {name: np.concatenate([getattr(p, name) for p in parts] or [np.zeros(0)])
               for name in ("start", "turn", "travel", "leg", "gain_rest", "gain_follow",
                            "rest")}
        return Excursions(legs=sum(p.legs for p in parts),
                          start=cat["start"].astype(int), turn=cat["turn"].astype(int),
                          travel=cat["travel"], leg=cat["leg"], gain_rest=cat["gain_rest"],
                          gain_follow=cat["gain_follow"], rest=cat["rest"].astype(bool))


@dataclass(frozen=True)
class ReversalRests:
    """A self-regulating loop's PV at its OP's reversals.

    Attributes
    ----------
    found : bool
        At least :data:`MIN_RESTS` rests, making :data:`MIN_REST_SHARE` of
        the excursions, or :data:`MIN_RESTS_FIXED` making
        :data:`MIN_REST_SHARE_FIXED` of them at a fixed OP travel, or
        :data:`MIN_TURNS_FIXED` excursions whose PV turned at a fixed OP
        travel (see :func:`reversal_rests`): a valve with a dead band.
    reason : str
        One sentence.
    legs : int
        Legs of the OP read (from one reversal to the next, set point
        steady).
    excursions : int
        Legs in which the PV moved against the OP's correction by
        :data:`EXCURSION_Z` standard errors and came at least halfway back
        before the OP turned again.
    rests : int
        Excursions during which the PV did not answer the OP, and after
        which it did.
    dead_band : float
        Median OP travel from the reversal to the PV's turn, over the rests
        (over all excursions where only their turns name the band) [OP
        unit]: the dead band, plus what the OP moves within the process's
        dead time and lag.
    sense : float
        +1 when the PV rises with the OP, -1 when it falls, 0 when the
        record cannot tell (then nothing is found).
    travel_spread, duration_spread : float
        Robust standard deviation of the logarithm of the rests' OP travels
        and of their durations [-]; NaN for fewer than
        :data:`MIN_RESTS_FIXED` rests.
    turn_travel_spread, turn_duration_spread, leg_spread : float
        The same over all excursions, and of the OP's travel over their
        whole legs [-]; NaN for fewer than :data:`MIN_TURNS_FIXED`
        excursions.
    turn_gain_rest, turn_gain_follow : float
        Median over all excursions of the PV's gain on the OP before and
        after its turn, in the loop's sense [PV unit / OP unit]; NaN as
        above.
    by_turns : bool
        Found by the excursions' turns at a fixed OP travel alone (too few
        rests).
    start, turn : numpy.ndarray
        Sample of the OP's reversal and of the PV's turn, for each rest
        (for each excursion where ``by_turns``).
    travel : numpy.ndarray
        The OP's travel during each rest (excursion) [OP unit].
    gain_rest, gain_follow : numpy.ndarray
        The PV's fitted gain on the OP during and after each rest
        (excursion), in the loop's sense [PV unit / OP unit].
    read : Excursions or None
        Every excursion read, rest or not: what the verdict was judged on,
        and what a record cut by gaps pools over its stretches
        (:func:`pooled_reversal_rests`).
    """

    found: bool
    reason: str
    legs: int = 0
    excursions: int = 0
    rests: int = 0
    dead_band: float = math.nan
    sense: float = 0.0
    travel_spread: float = math.nan
    duration_spread: float = math.nan
    turn_travel_spread: float = math.nan
    turn_duration_spread: float = math.nan
    leg_spread: float = math.nan
    turn_gain_rest: float = math.nan
    turn_gain_follow: float = math.nan
    by_turns: bool = False
    start: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    turn: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    travel: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    gain_rest: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    gain_follow: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    read: Excursions | None = field(default=None, repr=False)
    pv: np.ndarray | None = field(default=None, repr=False)
    op: np.ndarray | None = field(default=None, repr=False)
    sample_time: float = 1.0

    @property
    def confidence(self) -> float:
        """Confidence in a dead band found, 0.5-0.9: it grows with the rests
        (the excursions, where their turns alone named it) up to ten."""
        count = self.excursions if self.by_turns else self.rests
        return 0.5 + 0.4 * min(1.0, count / 10.0)

    def as_dict(self) -> dict:
        """The figures as plain types."""
        return {"found": self.found, "legs": self.legs, "excursions": self.excursions,
                "rests": self.rests, "by_turns": self.by_turns,
                "dead_band": round(self.dead_band, 3) if math.isfinite(self.dead_band) else None,
                "sense": self.sense,
                **{k: round(v, 3) if math.isfinite(v) else None
                   for k, v in (("travel_spread", self.travel_spread),
                                ("duration_spread", self.duration_spread),
                                ("turn_travel_spread", self.turn_travel_spread),
                                ("turn_duration_spread", self.turn_duration_spread),
                                ("leg_spread", self.leg_spread),
                                ("turn_gain_rest", self.turn_gain_rest),
                                ("turn_gain_follow", self.turn_gain_follow))}}

    def plot(self, ax=None):
        """PV and OP, with each rest shaded from the OP's reversal to the PV's turn.

        Returns
        -------
        matplotlib.axes.Axes
        """
        ax, t = pv_op_trend(ax, self.pv, self.op, self.sample_time, self.reason)
        if t is None:
            return ax
        what = ("from the OP's reversal to the PV's turn" if self.by_turns else
                "valve at rest: the OP moved, the PV ran on")
        for k, (a, j) in enumerate(zip(self.start, self.turn)):
            ax.axvspan(t[a], t[j], color="C3", alpha=0.15, lw=0, label=what if k == 0 else None)
        ax.legend(loc="upper left", fontsize=7)
        if self.by_turns:
            title = (f"the PV turned at a fixed OP travel at {self.excursions} excursions after "
                     f"the OP's reversals (dead band about {self.dead_band:.2g})")
        elif self.rests:
            title = (f"{self.rests} rests at {self.excursions} excursions of the PV after the "
                     f"OP's reversals (dead band about {self.dead_band:.2g})")
        else:
            title = "no rest of the valve at the OP's reversals"
        ax.set_title(title)
        return ax


def _gain(pv: np.ndarray, op: np.ndarray, lo: int, hi: int, noise: float):
    """The coefficient of ``op`` in ``pv ~ 1 + t + op`` over ``[lo, hi)``, and its std. error."""
    t = np.arange(hi - lo, dtype=float)
    A = np.c_[np.ones_like(t), t, op[lo:hi] - op[lo]]
    AtA = A.T @ A
    if np.linalg.cond(AtA) > 1e12:
        return math.nan, math.nan
    inv = np.linalg.inv(AtA)
    return float(inv[2] @ (A.T @ pv[lo:hi])), noise * math.sqrt(max(float(inv[2, 2]), 0.0))


def reversal_rests(pv, op, sample_time: float, *, sp=None, sense: float | None = None,
                   drawn=None) -> ReversalRests:
    """Find a dead band in a self-regulating loop by the valve's rests at the OP's reversals.

    Parameters
    ----------
    pv, op : array_like, shape (n,)
        One gap-free stretch of a self-regulating loop in automatic [PV unit,
        OP unit].
    sample_time : float
        [s]
    sp : array_like, shape (n,), optional
        Set point [PV unit]: legs in which it moved are not read.
    sense : float, optional
        +1 when the PV rises with the OP, -1 when it falls; read from the
        record (:func:`~valvediag.analysis.signature.loop_sense`) when not
        given.
    drawn : array_like of bool, shape (n,), optional
        True where the PV was drawn across a gap rather than measured: a leg
        that holds such a sample is not read (the PV's excursion and its
        answer to the OP are not on record there).

    Returns
    -------
    ReversalRests

    Raises
    ------
    ValueError
        Unequal lengths or a non-positive sample time.

    Notes
    -----
    PV and OP are smoothed over :data:`SMOOTH_S` (3 to 31 samples). The
    OP's reversals are its extremes confirmed by a move of six standard
    errors of its smoothed noise. In each leg from one reversal ``a`` to the
    next, the PV's excursion against the OP's correction (the way the OP
    moves, through the loop's sense, is the way the controller wants the PV
    to go) peaks at ``j``; it is read when it stands :data:`EXCURSION_Z`
    standard errors above the noise and the PV comes at least halfway back
    before the next reversal. Over ``[a, j]`` and over ``[j, k]``, where ``k``
    is where the OP has moved as far again (or the next reversal), the PV
    is fitted as ``c0 + c1 t + g OP`` (the load drifting linearly). A rest
    has ``|g_rest|`` within two standard errors, ``g_follow`` above three,
    and ``|g_rest|`` plus two standard errors at most half ``g_follow``.
    :data:`MIN_RESTS` rests that make :data:`MIN_REST_SHARE` of the
    excursions name the dead band.

    Fewer rests name it too (:data:`MIN_RESTS_FIXED`, making
    :data:`MIN_REST_SHARE_FIXED` of the excursions) where they show what
    tells a dead band from a process's delay: a dead band is taken up after a
    fixed travel of the OP, whatever its speed, so where the OP came back at
    different speeds the rests' durations spread and their travels do not;
    a dead time or a lag delays the PV's turn by a fixed time, so the travel
    grows with the OP's speed. The durations must spread by
    :data:`DURATION_SPREAD` (robust standard deviation of their logarithm)
    and the travels by at most :data:`TRAVEL_SPREAD_SHARE` of that. A loose
    valve under a wandering load leaves many excursions that are no rest
    (the load turns the PV on its own between the OP's reversals), and where
    the take-up turns the PV within the stretch read as the rest, the valve's
    first motion shows in its gain: its rests may make only a fifth of the
    excursions (18 of the 152 loose flow valves counted below are found by
    this reading alone). A periodic load turns at the same OP travel and
    after the same time at every cycle, and its rests' durations do not
    spread.

    The excursions' turns name it without rests too: where a wandering load
    moves the PV during the rest, the fitted gain is no longer nought, but
    the PV still turns back once the OP has crossed the band. Over
    :data:`MIN_TURNS_FIXED` excursions or more, the OP's travel from the
    reversal to the PV's turn must spread by at most
    :data:`TURN_TRAVEL_SPREAD` and by at most :data:`TRAVEL_SPREAD_SHARE` of
    the durations' spread (at least :data:`DURATION_SPREAD`), and the OP's
    whole legs by at least :data:`LEG_SPREAD_RATIO` times the travels'
    spread; and on the median excursion the PV must answer the OP as at a
    rest (the median gain before the turn within half the median gain
    after it, which is positive). A healthy loop's PV turns a process response after the reversal,
    at a travel that grows with the OP's speed, and a periodic load at the
    end of legs that are all alike. On the benchmark's study seeds 10-16 (8
    loops per class, those with five excursions or more), the healthy
    flows' travels spread by 23-99 %, the loose valves' mostly by 1-12 %;
    the periodic loads whose travels spread little had legs that spread by
    about 1 %, where the flagged loose valves' legs spread by 2.5-26 times
    their travels. A pump that starts and stops by the same step moves the
    PV first, and the OP answers by a fixed travel too; there the PV moves
    with the OP's travel before its turn (a median gain before the turn of
    -1.5 times the gain after, where eight loose valves looked at read
    -0.10 to 0.12).

    It assumes a self-regulating process whose PV answers the valve within a
    few smoothing windows, and a load that drifts smoothly over a rest. It
    fails where:

    * the process is integrating: a level runs on after the OP turns until
      the valve's flow crosses the load's, whatever the valve; the scan does
      not read it on loops the registry calls integrating (read anyway, none
      of the 280 level loops of the realistic benchmark's study seeds, sticky,
      loose or healthy, showed a fault);
    * the dead band is crossed within the process's dead time and lag, or
      within the smoothing window (a band smaller than the OP's move in
      :data:`SMOOTH_S`): no rest shows;
    * the load drifts so slowly that the error of a rest stays within the
      noise, or turns within the rest;
    * the valve sticks and slips: it rests too, and a slip that brings the
      PV back without the OP moving can pass for a take-up; the valve
      events (:func:`~valvediag.analysis.signature.stick_slip_events`),
      which read slips, come first;
    * a set point that steps within a leg (the leg is not read); a
      cascade's, which wanders by less than three noise standard deviations
      of the PV over the smoothing window, is read through;
    * a record cut by gaps into stretches shorter than the OP's legs: no leg
      spans a gap, so a stretch holds only the legs that fit in it. The
      excursions of a record's stretches are judged together by
      :func:`pooled_reversal_rests` (five minutes missing every hour on the
      realistic benchmark's study seeds 10-16, 4 loops a class: 14 of 28
      loose flows without a cycle read ``backlash``, where 10 did read
      stretch by stretch, and 22 without the gaps); where the scan joins
      stretches by drawing the PV across a gap (``drawn``), the legs that
      hold a drawn sample are not read either;
    * the OP is stored by a swinging door wider than its noise: its noise
      is then read at its stored resolution
      (:func:`~valvediag.analysis.quality.resolved_noise_std`), and a rest
      is told only where the OP's creep through it leaves about twice the
      door's deviation (on the realistic benchmark's loose flows without a
      cycle, study seeds 10-13, 4 loops each, the scan read 8 of 16
      ``backlash`` with the OP stored by a door of 0.1 %, where it read 6
      before, and 13 with the OP as drawn).

    A load that steps at an OP's reversal moves the PV first and the OP
    with it (a negative gain), and a loop that answers its OP leaves no rest
    (on the realistic benchmark's development and study seeds 1, 2 and
    10-26, 8 loops per class: none of the 1,824 loops of its twelve other
    classes, healthy, disturbed, sticky or dead, flows and levels, read a
    fault, and 114 of 152 loose flow valves without a cycle did: 83 by the
    share of rests alone, 101 with the rests at a fixed travel, 13 more by
    the turns alone).

    References
    ----------
    See the module docstring.
    """
    h = float(sample_time)
    pv = np.asarray(pv, dtype=float).ravel()
    op = np.asarray(op, dtype=float).ravel()
    if pv.size != op.size or (sp is not None and np.size(sp) != pv.size):
        raise ValueError(f"pv, op and sp must have one length, got {pv.size}, {op.size}"
                         + (f" and {np.size(sp)}" if sp is not None else "") + " samples")
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"sample_time must be a positive number of seconds, got {sample_time!r}")
    base = dict(pv=pv, op=op, sample_time=h)
    m = int(np.clip(round(SMOOTH_S / h), 3, 31))
    if pv.size < 8 * m or not (np.all(np.isfinite(pv)) and np.all(np.isfinite(op))):
        return ReversalRests(found=False, reason=f"only {pv.size} samples, or gaps", **base)
    pv_noise, op_noise = white_noise_std(pv), resolved_noise_std(op)
    if not (pv_noise > 0 and op_noise > 0):
        return ReversalRests(found=False, reason="the PV or the OP has no measurable noise",
                             **base)
    if sense is None:
        sense = loop_sense(pv, op)
    base["sense"] = float(sense)
    if sense == 0:
        return ReversalRests(found=False, reason="the sense in which the OP moves the PV "
                             "cannot be read", **base)
    # the workbench's compiled kernel, imported here: reading a loop's
    # verdict needs no more of the workbench than this
    from ..workbench.kernels import turning_points

    pvs = uniform_filter1d(pv, m, mode="nearest")
    ops = uniform_filter1d(op, m, mode="nearest")
    se_s = pv_noise / math.sqrt(m)
    turns, _, _ = turning_points(ops, 6.0 * op_noise / math.sqrt(m))
    turns = turns[(turns >= m) & (turns < pv.size - m)]
    sp = None if sp is None else np.asarray(sp, dtype=float).ravel()
    drawn_at = drawn_counts(drawn, pv.size)
    legs = 0
    # every excursion: reversal, turn, travel, the leg's travel, gains, a rest?
    turned = []
    for a, b in zip(turns[:MAX_LEGS], turns[1:MAX_LEGS + 1]):
        # a set point that steps in the leg kicks the OP and the PV with it; a
        # cascade's, the outer loop's output, wanders by less than the noise
        # over the smoothing window and moves the PV only through the valve
        if b - a < 2 * MIN_FIT or (sp is not None and not np.all(
                np.abs(sp[a + m:b] - sp[a:b - m]) <= 3.0 * pv_noise)):
            continue
        if drawn_at is not None and drawn_within(drawn_at, a, b + 1):
            continue          # the PV drawn across a gap in the leg: not on record
        legs += 1
        d = 1.0 if ops[b] > ops[a] else -1.0
        dev = -d * sense * (pvs[a:b] - pvs[a])
        j = int(np.argmax(dev))
        if dev[j] < EXCURSION_Z * se_s or dev[j] - dev[-1] < 0.5 * dev[j]:
            continue
        # the stretch after the turn: until the OP has moved as far again
        travel = abs(ops[a + j] - ops[a])
        far = np.flatnonzero(np.abs(ops[a + j:b + 1] - ops[a + j]) >= travel)
        k = a + j + (int(far[0]) if far.size else b - a - j)
        if j + 1 < MIN_FIT or k - (a + j) + 1 < MIN_FIT:
            continue
        # the PV on the (smoothed) OP: the OP's own noise is the PV's, turned
        # round by the proportional action, and would bias the gain
        g_r, se_r = _gain(pv, ops, a, a + j + 1, pv_noise)
        g_f, se_f = _gain(pv, ops, a + j, k + 1, pv_noise)
        g_r, g_f = sense * g_r, sense * g_f
        rest = abs(g_r) <= 2.0 * se_r and g_f >= 3.0 * se_f and abs(g_r) + 2.0 * se_r <= 0.5 * g_f
        turned.append((a, a + j, travel, abs(ops[b] - ops[a]), g_r, g_f, rest))
    cols = list(zip(*turned)) if turned else [()] * 7
    read = Excursions(legs=legs, start=np.asarray(cols[0], int), turn=np.asarray(cols[1], int),
                      travel=np.asarray(cols[2], float), leg=np.asarray(cols[3], float),
                      gain_rest=np.asarray(cols[4], float),
                      gain_follow=np.asarray(cols[5], float), rest=np.asarray(cols[6], bool))
    return _judged(read, base)


def _judged(read: Excursions, base: dict) -> ReversalRests:
    """The verdict on a table of excursions (one stretch's, or several pooled)."""
    legs, excursions = read.legs, int(read.rest.size)
    if not legs:
        return ReversalRests(found=False, reason="no reversal of the OP beyond its noise with "
                             "the set point steady", read=read, **base)
    e_start, e_turn, e_trav, e_leg, e_gr, e_gf, is_rest = (
        read.start, read.turn, read.travel, read.leg, read.gain_rest, read.gain_follow,
        read.rest)
    a_, j_, trav, g_r, g_f = (v[is_rest] for v in (e_start, e_turn, e_trav, e_gr, e_gf))
    rests = int(is_rest.sum())
    band = float(np.median(trav)) if rests else math.nan
    s_trav = s_dur = math.nan
    if rests >= MIN_RESTS_FIXED:
        s_trav = float(median_abs_deviation(np.log(trav), scale="normal"))
        s_dur = float(median_abs_deviation(np.log(j_ - a_), scale="normal"))
    many = rests >= MIN_RESTS and rests >= MIN_REST_SHARE * excursions
    fixed = (rests >= MIN_RESTS_FIXED and rests >= MIN_REST_SHARE_FIXED * excursions
             and s_dur >= DURATION_SPREAD and s_trav <= TRAVEL_SPREAD_SHARE * s_dur)
    t_trav = t_dur = s_leg = g_rest = g_follow = math.nan
    turn_band = math.nan
    answers = False
    if excursions >= MIN_TURNS_FIXED:
        dur = (e_turn - e_start).astype(float)
        ok = (e_trav > 0) & (e_leg > 0)
        if ok.sum() >= MIN_TURNS_FIXED:
            t_trav, t_dur, s_leg = (float(median_abs_deviation(np.log(v[ok]), scale="normal"))
                                    for v in (e_trav, dur, e_leg))
            turn_band = float(np.median(e_trav[ok]))
            # on the median, the PV answered the OP after its turn and not
            # before, as at a rest: a load's step of a fixed size moves the
            # PV first and the OP answers it by a fixed travel too, but there
            # the excursion grows with the OP's travel (a negative gain)
            g_rest, g_follow = float(np.median(e_gr[ok])), float(np.median(e_gf[ok]))
            answers = g_follow > 0 and abs(g_rest) <= 0.5 * g_follow
    turns_fixed = (answers and t_trav <= TURN_TRAVEL_SPREAD and t_dur >= DURATION_SPREAD
                   and t_trav <= TRAVEL_SPREAD_SHARE * t_dur
                   and s_leg >= max(DURATION_SPREAD, LEG_SPREAD_RATIO * t_trav))
    found = many or fixed or turns_fixed
    if many or fixed:
        reason = (f"at {rests} of {excursions} excursions of the PV after the OP's reversals "
                  f"the PV ran on with its load while the OP moved about {band:.2g} back, "
                  "answering it not at all, then followed the OP: a valve that rests in a "
                  f"dead band of about {band:.2g} at every reversal")
        if not many:
            reason += (f" (the OP's travel during the rests spread by {100 * s_trav:.0f} %, "
                       f"their durations by {100 * s_dur:.0f} %: a band of fixed width taken "
                       "up at any speed, not a process delay)")
    elif found:
        band = turn_band
        a_, j_, trav, g_r, g_f = e_start, e_turn, e_trav, e_gr, e_gf
        reason = (f"at {excursions} excursions of the PV after the OP's reversals the PV turned "
                  f"back once the OP had moved about {band:.2g} (spread {100 * t_trav:.0f} %), "
                  f"however long that took (durations spread {100 * t_dur:.0f} %) and however "
                  f"far the OP went on (its legs spread {100 * s_leg:.0f} %): a valve that takes "
                  f"up a dead band of about {band:.2g} at every reversal, where a process's "
                  "delay would turn the PV after a fixed time")
    else:
        reason = (f"{rests} rests of the valve at {excursions} excursions of the PV in "
                  f"{legs} legs of the OP (a fault needs {MIN_RESTS} and a third of the "
                  f"excursions, or {MIN_RESTS_FIXED} and {100 * MIN_REST_SHARE_FIXED:.0f} % "
                  f"at a fixed OP travel, or {MIN_TURNS_FIXED} excursions turning at a fixed "
                  "OP travel)")
    return ReversalRests(found=found, reason=reason, legs=legs, excursions=excursions,
                         rests=rests, dead_band=band, travel_spread=s_trav,
                         duration_spread=s_dur, turn_travel_spread=t_trav,
                         turn_duration_spread=t_dur, leg_spread=s_leg,
                         turn_gain_rest=g_rest, turn_gain_follow=g_follow,
                         by_turns=bool(found and not (many or fixed)),
                         start=a_.astype(int), turn=j_.astype(int),
                         travel=trav.astype(float), gain_rest=g_r.astype(float),
                         gain_follow=g_f.astype(float), read=read, **base)


def pooled_reversal_rests(readings) -> ReversalRests:
    """Judge the rests of a record's stretches together, as one gap-free record's.

    Parameters
    ----------
    readings : sequence of ReversalRests
        :func:`reversal_rests` of each stretch of one loop's record, cut by
        gaps.

    Returns
    -------
    ReversalRests
        Judged on the excursions of the stretches read in the loop's sense
        (the sense most legs were read in), by the rules of
        :func:`reversal_rests`. ``start`` and ``turn`` index each stretch's
        own samples, and there is no ``pv`` or ``op`` to plot.

    Notes
    -----
    A loose valve rests at every reversal of its OP whatever the record's
    gaps; a stretch of an hour between two of them may hold one or two
    reversals with an excursion, too few for a fault alone. Each excursion
    is a leg between two of the OP's reversals inside one stretch, so the
    rests, their shares and their spreads are counted over the stretches as
    over a record without gaps, and no leg spans a gap. Stretches whose
    sense could not be read, or was read the other way, leave their legs
    out: the sense decides which way an excursion runs. It fails as
    :func:`reversal_rests` does.
    """
    readings = [r for r in readings if r.read is not None and r.sense != 0]
    by_sense: dict[float, int] = {}
    for r in readings:
        by_sense[r.sense] = by_sense.get(r.sense, 0) + r.read.legs
    if not by_sense:
        return ReversalRests(found=False, reason="no stretch whose sense could be read")
    sense = max(by_sense, key=lambda k: (by_sense[k], k))
    used = [r for r in readings if r.sense == sense]
    h = used[0].sample_time
    return _judged(Excursions.joined(r.read for r in used), dict(sense=sense, sample_time=h))
