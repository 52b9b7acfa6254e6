"""
Set-point steps read as bump tests of a level's valve.

When an operator steps a level's set point, the controller's proportional
action kicks the OP at once. A valve that follows its OP changes the level's
inflow (or outflow) by the kick, and the level, which integrates the valve's
position, bends the kick's way: its slope steps by the process's gain times
the kick, and the loop's answer then curves it back. A sticky valve may hold
through the kick; the level then runs on as before, and whatever bends it in
the minutes around the step (the load, a slip made later when the OP has
crept further) owes nothing to the kick. Every set-point step is thus a free
bump test of the valve, where the record has them.

:func:`setpoint_bumps` fits, around every isolated set-point step, the level
as a straight line plus a gain times the integral of the OP's move, and
counts the steps at which the level moved *against* the OP by more than the
noise allows: no valve that follows its OP does that. The steps the level
answered give the valve's gain, and :func:`kinks_over_following` checks a
level's kinks (:func:`~valvediag.analysis.signature.stick_slip_events`)
against it: a slip steps the slope by far more than the OP's change across it
makes through that gain.

References
----------
.. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston.
.. [2] Åström, K. J., Hägglund, T. (2006). Advanced PID Control. ISA,
   Research Triangle Park (set-point steps and the proportional kick).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .quality import resolved_noise_std, white_noise_std
from .signature import loop_sense
from .trend import pv_op_trend

__all__ = ["SetPointBumps", "setpoint_bumps", "kinks_over_following", "SetPointScreen",
           "setpoint_process_screen", "BUMP_HALF_WINDOW_S", "BUMP_Z", "MIN_BUMPS_AGAINST",
           "SLIP_OVER_FOLLOWING", "SCREEN_STEPS", "SCREEN_SHIFT_MAX", "SCREEN_SIDE",
           "RESPONSE_WINDOWS", "step_half_time", "MIN_KICKS"]

#: Stretch read either side of a set-point step [s], cut short at the next
#: and the last step.
BUMP_HALF_WINDOW_S = 600.0
#: Standard errors by which the level's answer must go against the kick.
BUMP_Z = 6.0
#: Steps answered against the kick that make a fault.
MIN_BUMPS_AGAINST = 2
#: Share of the OP's kick (its largest move within a sample of the step)
#: still standing two samples on for a step to be read as going against it:
#: a loop that answers within a sample or two of the record (a closed-loop
#: time constant under about three samples) has moved the level before the
#: record sees the kick, and the OP's integral over samples that far apart
#: is not the valve's. A valve that held leaves the whole kick standing.
KICK_HELD = 0.5
#: Fewest samples either side of a step.
MIN_SIDE = 8
#: Largest share of samples at which a set point moves for it to be read as
#: entered, every move of it a step: an operator's set point moves a few
#: tens of times a day, a cascade's or a measured one at nearly every sample.
ENTERED_SHARE = 0.05
#: The stretch read either side of a step is at most this many times the
#: level's half-time after its steps (the median time for the control error
#: to fall to half its size after a step): the OP's integral over many of the
#: loop's time constants is mostly its answer to the load, and reads against
#: a healthy level (:func:`setpoint_bumps`).
RESPONSE_WINDOWS = 10.0
#: Most steps read (the first ones of the record).
MAX_STEPS = 500
#: Fewest clear kicks of the OP (beyond :data:`KICK_Z` noise standard
#: deviations) that give the loop's sense, :data:`KICK_SHARE` of them the
#: same way against their set-point moves.
MIN_KICKS = 2
#: Noise standard deviations of the OP by which a kick is clear.
KICK_Z = 3.0
#: Share of the clear kicks that must go one way to give the sense.
KICK_SHARE = 0.75
#: Fewest set-point steps for :func:`setpoint_process_screen` to name a process.
SCREEN_STEPS = 5
#: Upper bound (two standard errors above the estimate) of the OP's lasting
#: shift over its kick, per unit of set-point move, below which the process
#: integrates. A self-regulating loop reads ``1 / (K Kc)``, its loop gain's
#: reciprocal: below 0.3 only for a loop gain above about 3.
SCREEN_SHIFT_MAX = 0.3
#: Fewest samples either side of a step for the screen: a third of them is
#: averaged as the settled OP.
SCREEN_SIDE = 30


def _loop_record(pv, op, sp, sample_time):
    """PV, OP and set point as float arrays of one length, and the sample time [s]."""
    h = float(sample_time)
    pv = np.asarray(pv, dtype=float).ravel()
    op = np.asarray(op, dtype=float).ravel()
    sp = np.asarray(sp, dtype=float).ravel()
    if not (pv.size == op.size == sp.size):
        raise ValueError(f"pv, op and sp must have one length, got {pv.size}, {op.size} and "
                         f"{sp.size} samples")
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"sample_time must be a positive number of seconds, got {sample_time!r}")
    return pv, op, sp, h


def step_half_time(pv, sp, steps, after, noise: float) -> float:
    """A loop's half-time after its set-point steps: the median time its error takes to halve.

    Parameters
    ----------
    pv, sp : numpy.ndarray, shape (n,)
        One gap-free stretch [PV unit].
    steps, after : numpy.ndarray of int
        The first sample after each isolated step, and the next step's
        (:func:`_isolated_steps`).
    noise : float
        The PV's white-noise standard deviation [PV unit].

    Returns
    -------
    float
        [samples]; NaN where fewer than two steps move the set point by six
        noise standard deviations, or where at least half the errors had not
        halved by the next step.

    Notes
    -----
    The PV is averaged over three samples; the error just after a step is
    the new set point less the mean PV over the three samples before it. A
    loop that answers its steps halves the error in about 0.7 closed-loop
    time constants; a valve that holds after the kick leaves the error to
    the load, which may halve it sooner or never.
    """
    times = []
    smooth = np.convolve(pv, np.ones(3) / 3.0, mode="same")
    for k, q in zip(steps[:MAX_STEPS], after):
        if k < 3 or abs(sp[k] - sp[k - 1]) < 6.0 * noise:
            continue
        e0 = sp[k] - float(np.mean(pv[k - 3:k]))
        if not abs(e0) >= 6.0 * noise:
            continue
        left = (sp[k] - smooth[k:q]) / e0
        below = np.flatnonzero(left <= 0.5)
        times.append(float(below[0]) if below.size else math.inf)
    if len(times) < 2:
        return math.nan
    t = float(np.median(times))
    return t if math.isfinite(t) else math.nan


def _isolated_steps(sp: np.ndarray, noise: float, side: int):
    """The set point's steps: all of them, and the isolated ones with their neighbours.

    A step is a move of more than three noise standard deviations of the PV
    between two samples, or any move of a set point that is entered: one
    that stands still at all but :data:`ENTERED_SHARE` of its samples (the
    operator's moves, each a step however small against the PV's noise,
    kick the OP by the controller's gain times the move, read against the
    OP's noise, not the PV's). Two moves at samples running, and no third,
    are one step (a step averaged over a sample), at the first. It is
    isolated where ``side`` samples or more separate it from the steps
    either side (a cascade's set point, moving at every sample, has none).
    Returns ``(jumps, steps, before, after)``: the
    first sample after every step, the isolated ones, and for each of those
    the previous step's sample (-1 for none) and the next one's (the record's
    length for none)."""
    d = np.abs(np.diff(sp))
    moves = d > 0
    entered = d.size and np.count_nonzero(moves) <= ENTERED_SHARE * d.size
    jumps = np.flatnonzero(moves if entered else d > 3.0 * noise) + 1
    if jumps.size > 1:
        # a step averaged over a sample (an export of means) moves the set
        # point at two samples running: it is one step, at the first
        start = np.r_[True, np.diff(jumps) > 1]
        run = np.cumsum(start) - 1
        jumps = jumps[start | (np.bincount(run)[run] != 2)]
    prev = np.r_[-1, jumps[:-1]]
    nxt = np.r_[jumps[1:], sp.size]
    isolated = (jumps - prev - 1 >= side) & (nxt - jumps >= side)
    return jumps, jumps[isolated], prev[isolated], nxt[isolated]


@dataclass(frozen=True)
class SetPointBumps:
    """A level's answer to its set-point steps.

    Attributes
    ----------
    found : bool
        At least :data:`MIN_BUMPS_AGAINST` steps at which the level moved
        against the OP: a valve that did not follow its OP.
    reason : str
        One sentence.
    steps : int
        Set-point steps read (isolated, with :data:`MIN_SIDE` samples either
        side).
    answered : int
        Steps at which the level bent the OP's way, by more than
        :data:`BUMP_Z` standard errors.
    against : int
        Steps at which it bent against the OP, by more than :data:`BUMP_Z`
        standard errors, while the OP's kick stood (``held`` at least
        :data:`KICK_HELD`).
    sense : float
        +1 when the level rises with the OP, -1 when it falls, 0 when the
        record cannot tell (then nothing is found).
    sense_source : str
        What the sense was read from: ``'the set-point kicks'``, ``"the
        controller's answer to the noise"``, ``'the steps answered'`` or
        ``'given'``; empty where it was not read.
    index : numpy.ndarray
        Sample of each step read.
    gain : numpy.ndarray
        Fitted gain at each step, in the loop's sense [PV unit / (OP unit s)]:
        positive where the level answered the OP.
    z : numpy.ndarray
        ``gain`` over its standard error.
    kick : numpy.ndarray
        The OP's move at each step, three samples after against three before
        [OP unit].
    held : numpy.ndarray
        The share of the OP's kick still standing two samples after its
        peak [-]; NaN where the OP did not move.
    """

    found: bool
    reason: str
    steps: int = 0
    answered: int = 0
    against: int = 0
    sense: float = 0.0
    sense_source: str = ""
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    gain: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    z: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    kick: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    held: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    pv: np.ndarray | None = field(default=None, repr=False)
    op: np.ndarray | None = field(default=None, repr=False)
    sp: np.ndarray | None = field(default=None, repr=False)
    sample_time: float = 1.0

    def as_dict(self) -> dict:
        """The figures as plain types."""
        return {"found": self.found, "steps": self.steps, "answered": self.answered,
                "against": self.against, "sense": self.sense,
                "sense_source": self.sense_source,
                "z": [round(float(v), 1) for v in self.z]}

    def plot(self, ax=None):
        """PV, set point and OP, with each step marked by the way the level answered.

        Returns
        -------
        matplotlib.axes.Axes
        """
        ax, t = pv_op_trend(ax, self.pv, self.op, self.sample_time, self.reason)
        if t is None:
            return ax
        ax.plot(t, self.sp, lw=0.7, color="k", ls="--", label="SP")
        against = (self.z <= -BUMP_Z) & (self.held >= KICK_HELD)
        answered = self.z >= BUMP_Z
        for sel, mark, lab in ((answered, "^", "level answered the kick"),
                               (against, "v", "level moved against it")):
            k = self.index[sel]
            ax.plot(t[k], self.pv[k], mark, mfc="none", color="C3" if mark == "v" else "C2",
                    label=lab)
        ax.legend(loc="upper left", fontsize=7)
        ax.set_title(f"{self.against} of {self.steps} set-point steps answered against the OP")
        return ax


def _kicked_sense(sp: np.ndarray, idx: np.ndarray, kick: np.ndarray) -> float:
    """The loop's sense read from the OP's kicks at the set-point steps, or 0.

    ``kick``: at each step ``idx``, the OP's first move within a sample of
    it that stands :data:`KICK_Z` standard deviations of its
    sample-to-sample noise clear of its mean move over the three samples
    before (a ramping OP's trend left out), less that mean; 0 where none
    does. A controller in automatic kicks its OP the way that moves the PV
    towards the new set point: with the set point's move, where the PV rises
    with the OP. At least :data:`MIN_KICKS` kicks, :data:`KICK_SHARE` of
    them the same way, give the sense; fewer, or a mix (loads that stepped
    with the set point, a slip's answer within the sample), give 0."""
    if idx.size < MIN_KICKS:
        return 0.0
    dsp = sp[idx] - sp[idx - 1]
    way = np.sign(kick * dsp)[(kick != 0) & np.isfinite(dsp)]
    if way.size < MIN_KICKS or abs(way.sum()) < (2.0 * KICK_SHARE - 1.0) * way.size:
        return 0.0
    return float(np.sign(way.sum()))


def setpoint_bumps(pv, op, sp, sample_time: float, *, sense: float | None = None,
                   half_window_s: float = BUMP_HALF_WINDOW_S) -> SetPointBumps:
    """Read a level's set-point steps as bump tests of its valve.

    Parameters
    ----------
    pv, op, sp : array_like, shape (n,)
        One gap-free stretch of a level loop in automatic [PV unit, OP unit,
        PV unit]; NaN in ``sp`` leaves the steps near it unread.
    sample_time : float
        [s]
    sense : float, optional
        +1 when the level rises with the OP, -1 when it falls. By default
        read from the OP's kicks at the steps, else from the controller's
        answer to noise (:func:`~valvediag.analysis.signature.loop_sense`),
        else from the way most steps were answered (see Notes).
    half_window_s : float
        Stretch read either side of a step [s], cut at the neighbouring steps.

    Returns
    -------
    SetPointBumps

    Raises
    ------
    ValueError
        Unequal lengths or a non-positive sample time.

    Notes
    -----
    A step is a set-point move of more than three noise standard deviations
    of the PV between two samples, or any move of a set point that stands
    still at all but :data:`ENTERED_SHARE` of its samples (an entered one).
    Over the stretch around it (at most
    ``half_window_s`` either side, and at most :data:`RESPONSE_WINDOWS`
    times the level's half-time after its steps (:func:`step_half_time`),
    not reaching the neighbouring steps, at least :data:`MIN_SIDE` samples
    either side) the level is fitted by
    least squares (the first :data:`MAX_STEPS` such steps) as

    .. math:: y(t) = a + b\\,t + c \\int_{t_0}^{t} (u(s) - u_k)\\,ds

    where :math:`u_k` is the OP just before the step. The line is the level's
    run under the net load; the last term is what a valve that follows the
    OP adds (the level integrates the valve's position), kick and the
    controller's answer after it included. The gain :math:`c`, in the loop's
    sense, is positive where the valve followed; its standard error is read
    from the PV's white noise. A gain of the wrong sign beyond
    :data:`BUMP_Z` standard errors says the level bent against everything
    the OP did around the step: the valve did not follow. It counts only
    where :data:`KICK_HELD` of the OP's kick still stands two samples after
    its peak: a loop that answers within a sample or two of the record (a
    one-minute export of a tight level) has turned the level before the
    record's OP shows the kick, and the integral of an OP sampled that
    coarsely reads against the level. A valve that held leaves its
    controller's kick standing (a proportional controller's exactly; an
    integral action adds to it). On the realistic benchmark's study seeds
    10-16 (4 loops per class) kept at one sample a minute, or averaged over
    each minute, as a historian's export may be, three and two healthy
    levels read a sticky valve by their steps (up to 19 of 20 steps against
    the OP) before this check and none after; one sticky level kept at one
    sample a minute lost its finding. At the records' own sampling (study
    seeds 10-16 and development seeds 1-2, 85 loops with steps, 67 steps
    against the OP), no step and no verdict changed.

    The gain is read in the loop's sense, which the steps themselves give:
    a controller in automatic kicks its OP the way that brings the PV to its
    new set point, with the set point's move where the level rises with the
    OP. Where :data:`MIN_KICKS` kicks or more stand clear of the OP's noise
    and :data:`KICK_SHARE` of them go one way, that is the sense; else the
    controller's answer to the PV's noise
    (:func:`~valvediag.analysis.signature.loop_sense`) gives it. That
    answer fails on a record kept coarsely, where the level answers the
    valve within a sample: on the realistic benchmark's study seeds 10-16
    (4 loops a class) kept at one sample in 30 s, it read 3 of the 23
    healthy levels with two steps or more the wrong way round (every step
    then goes against the OP), and one of them read ``undecided`` by its
    steps. The kicks gave the sense of 72 of the 73 loops with two steps
    or more at their own sampling, 72 of 74 kept at one sample in 30 s and
    all 43 averaged over 30 s, each one right. A sticky level's loop that
    slips as the set point steps moves its OP back within the sample after
    the kick: the first clear move is read, not the largest.

    The half-time bound reads a fast level over its own time: one that
    halves its error within seconds of a step, read over the minutes
    between its steps, has the OP's integral answer the load more than the
    kick, and reads against it (the load turns within the stretch). The
    study seeds 10-12 replayed ten times faster (a tenth of the sample
    time) had four healthy levels read faulty that way (up to 11 of 18
    steps against) and none after it, with the same 52 of 60 sticky valves
    found; at the records' own pace one step's reading changed on the
    study seeds 10-16 and none on the development seeds 1-2 (their level
    classes, 364 loops), and no verdict.

    It assumes an integrating process (a level), a controller with
    proportional action on the error (a set-point step with set-point
    weighting zero kicks nothing and reads nothing) and a load that does not
    turn within the stretch by more than the kick moves the valve. It fails
    where a load's step coincides with a set-point step the other way (an
    operator moving the set point as a pump starts); two such steps are
    needed. A loose valve that holds inside its dead band after a kick that
    reverses the OP holds as a sticky one does: the test reads a valve that
    did not follow, and the kind of fault comes from other evidence. A self-
    regulating process answers a kick in its PV, not its slope, and is not
    read. A record compressed by the historian has too little noise read
    between its stored points for the standard errors to hold.

    References
    ----------
    See the module docstring.
    """
    pv, op, sp, h = _loop_record(pv, op, sp, sample_time)
    base = dict(pv=pv, op=op, sp=sp, sample_time=h)
    if pv.size < 2 * MIN_SIDE:
        return SetPointBumps(found=False, reason=f"only {pv.size} samples", **base)
    noise = white_noise_std(pv)
    if not noise > 0:
        return SetPointBumps(found=False, reason="the PV has no measurable noise", **base)
    jumps, steps, before, after = _isolated_steps(sp, noise, MIN_SIDE)
    half = max(MIN_SIDE, int(round(half_window_s / h)))
    t_half = step_half_time(pv, sp, steps, after, noise)
    if math.isfinite(t_half):
        half = max(MIN_SIDE, min(half, int(round(RESPONSE_WINDOWS * t_half))))
    idx, gain, se, kick, held, first_moves = [], [], [], [], [], []
    kick_clear = KICK_Z * math.sqrt(2.0) * resolved_noise_std(op)
    for k, p, q in zip(steps[:MAX_STEPS], before, after):
        lo, hi = max(0, k - half, p + 1), min(pv.size, k + half, q)
        if not np.all(np.isfinite(sp[lo:hi])):
            continue
        t = np.arange(lo - k, hi - k, dtype=float)
        moved = h * np.r_[0.0, np.cumsum(op[lo:hi - 1] - op[k - 1])]
        A = np.c_[np.ones_like(t), t, moved]
        AtA = A.T @ A
        if np.linalg.cond(AtA) > 1e12:
            continue
        inv = np.linalg.inv(AtA)
        c = float(inv[2] @ (A.T @ pv[lo:hi]))
        idx.append(int(k))
        gain.append(c)
        se.append(noise * math.sqrt(float(inv[2, 2])))
        kick.append(float(np.mean(op[k:k + 3]) - np.mean(op[k - 3:k])))
        # the kick two samples after its peak (within a sample of the step:
        # the OP may be stored a scan off the set point), against the peak
        op0 = float(np.mean(op[max(0, k - 4):k - 1])) if k >= 2 else float(op[0])
        at = k - 1 + int(np.argmax(np.abs(op[k - 1:k + 2] - op0)))
        peak = float(op[at] - op0)
        # the kick: the OP's first clear move within a sample of the step, less
        # its trend over the samples before (a ramping OP's moves left out);
        # the loop's answer to a slip or to the kick may move it back next
        moves = np.diff(op[k - 2:k + 2]) - (op[k - 2] - op[k - 5]) / 3.0
        clear = np.flatnonzero(np.abs(moves) > kick_clear)
        first_moves.append(float(moves[clear[0]]) if clear.size else 0.0)
        held.append(float(np.mean(op[at + 2:at + 4]) - op0) / peak
                    if peak != 0 and at + 2 < op.size else math.nan)
    idx, gain, se, kick, held = (np.asarray(idx, int), np.asarray(gain), np.asarray(se),
                                 np.asarray(kick), np.asarray(held))
    z = gain / se if idx.size else np.zeros(0)
    source = "given"
    if sense is None:
        sense, source = _kicked_sense(sp, idx, np.asarray(first_moves)), "the set-point kicks"
        if sense == 0:
            sense, source = loop_sense(pv, op), "the controller's answer to the noise"
        if sense == 0 and idx.size:
            strong = np.sign(z[np.abs(z) >= BUMP_Z])
            if strong.size and abs(strong.sum()) >= strong.size / 3.0:
                sense, source = float(np.sign(strong.sum())), "the steps answered"
    base.update(sense=float(sense), sense_source=source if sense else "", index=idx)
    if idx.size == 0:
        what = "no set-point step" if jumps.size == 0 else \
            f"no set-point step with {MIN_SIDE} steady samples either side"
        return SetPointBumps(found=False, reason=f"{what} to read the valve by", **base)
    if sense == 0:
        return SetPointBumps(found=False, steps=int(idx.size), gain=gain, z=z, kick=kick,
                             held=held,
                             reason="the sense in which the OP moves the level cannot be read",
                             **base)
    gain, z = gain * sense, z * sense
    answered = int(np.sum(z >= BUMP_Z))
    # where the kick has faded two samples on, the loop answered within the
    # record's sampling, and the OP's integral is not read: no step went against it
    against = int(np.sum((z <= -BUMP_Z) & (held >= KICK_HELD)))
    found = against >= MIN_BUMPS_AGAINST
    if found:
        reason = (f"at {against} of {idx.size} set-point steps the level moved against the "
                  f"OP (by more than {BUMP_Z:g} standard errors; {answered} answered its kick): "
                  "a valve that follows its OP bends a level the kick's way, this one held")
    else:
        reason = (f"{answered} of {idx.size} set-point steps answered the OP's kick, "
                  f"{against} went against it (a fault needs {MIN_BUMPS_AGAINST})")
    return SetPointBumps(found=found, reason=reason, steps=int(idx.size), answered=answered,
                         against=against, gain=gain, z=z, kick=kick, held=held, **base)


@dataclass(frozen=True)
class SetPointScreen:
    """The process type read from the OP's lasting shift after set-point steps.

    Attributes
    ----------
    process : {'integrating', 'self-regulating', 'unknown'}
    reason : str
        One sentence.
    steps : int
        Set-point steps read.
    shift_over_kick : float
        Least-squares OP shift (settled after the step against settled before)
        per unit set-point move, over the OP's kick per unit set-point move;
        NaN where nothing was read [-].
    standard_error : float
        Its standard error, from the scatter of the steps about the fit [-].
    dsp, shift, kick : numpy.ndarray
        Each step's set-point move [PV unit], the OP's lasting shift and its
        kick [OP unit].
    """

    process: str
    reason: str
    steps: int = 0
    shift_over_kick: float = math.nan
    standard_error: float = math.nan
    dsp: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    shift: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    kick: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def as_dict(self) -> dict:
        """The figures as plain types."""
        return {"process": self.process, "steps": self.steps,
                "shift_over_kick": round(self.shift_over_kick, 3),
                "standard_error": round(self.standard_error, 3)}

    def plot(self, ax=None):
        """The OP's lasting shift and its kick against each set-point move.

        Returns
        -------
        matplotlib.axes.Axes
        """
        if ax is None:
            import matplotlib.pyplot as plt
            _, ax = plt.subplots()
        ax.plot(self.dsp, self.kick, "o", mfc="none", label="kick (3 samples)")
        ax.plot(self.dsp, self.shift, "s", label="lasting shift")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel("set-point move [PV unit]")
        ax.set_ylabel("OP move [OP unit]")
        ax.set_title(f"{self.process}: shift/kick {self.shift_over_kick:.2f} "
                     f"± {self.standard_error:.2f} ({self.steps} steps)", fontsize=9)
        ax.legend(fontsize=7)
        return ax


def setpoint_process_screen(pv, op, sp, sample_time: float) -> SetPointScreen:
    """Read whether a loop's process integrates from its OP after set-point steps.

    Parameters
    ----------
    pv, op, sp : array_like, shape (n,)
        One gap-free stretch of a loop in automatic [PV unit, OP unit, PV
        unit].
    sample_time : float
        [s]

    Returns
    -------
    SetPointScreen
        ``'integrating'`` where the OP comes back after the steps,
        ``'self-regulating'`` where it settles away in proportion to them.

    Notes
    -----
    At steady state a self-regulating process (a flow, a pressure, a
    temperature) needs a new valve position for a new set point: the OP
    settles ``dSP / K`` away from where it was. An integrating one (a level)
    needs the valve that balances the load, whatever the set point: the OP
    comes back. The controller's proportional action kicks the OP by
    ``Kc dSP`` at once, in both. Over the isolated set-point steps (at least
    :data:`SCREEN_SIDE` samples from the neighbouring ones), the OP's
    lasting shift (the mean of the last third of the stretch after the
    step against that of the stretch before it) and its kick (three samples
    after against three before) are fitted against the set-point move
    through the origin; their ratio is ``1 / (K Kc)`` on a self-regulating
    loop and 0 on an integrating one. The process integrates where the ratio
    stands below :data:`SCREEN_SHIFT_MAX` by two standard errors, and
    regulates itself where it stands above it by two, over at least
    :data:`SCREEN_STEPS` steps.

    A load that moves between the steps scatters the shifts and widens the
    error: nothing is named then. It fails where the loop has not settled
    within two thirds of the stretch after a step (a slow level loop with
    frequent steps reads a flow's lasting shift), where the controller
    kicks nothing (set-point weighting zero, or a PV-derivative-only
    structure: nothing is read), on a self-regulating loop with a loop gain
    above about 3 (read as neither), on a sticky valve whose OP settles
    anywhere in its band (scatter), and on a flow whose OP runs into its
    limit after the steps (its shift is cut short: a level's reading). A
    cascade's inner loop, whose set point moves at every sample, and a set
    point ramped by the operator have no isolated step.

    References
    ----------
    .. [1] Åström, K. J., Hägglund, T. (2006). Advanced PID Control. ISA,
       Research Triangle Park (integrating processes; set-point response).
    """
    pv, op, sp, h = _loop_record(pv, op, sp, sample_time)
    noise = white_noise_std(pv) if pv.size >= 2 * SCREEN_SIDE else math.nan
    if not noise > 0:
        return SetPointScreen("unknown", "too short or noiseless a PV to find set-point steps")
    _, k, p, q = _isolated_steps(sp, noise, SCREEN_SIDE)
    # settled OP: the last third of the stretch before the step and after it
    c = np.r_[0.0, np.cumsum(op)]
    nb, na = (k - p - 1) // 3, (q - k) // 3
    before = (c[k] - c[k - nb]) / nb
    after = (c[q] - c[q - na]) / na
    kick = (c[k + 3] - c[k]) / 3.0 - (c[k] - c[k - 3]) / 3.0
    dsp, shift = sp[k] - sp[k - 1], after - before
    good = np.isfinite(dsp) & np.isfinite(shift) & np.isfinite(kick)
    dsp, shift, kick = dsp[good], shift[good], kick[good]
    base = dict(steps=int(dsp.size), dsp=dsp, shift=shift, kick=kick)
    if dsp.size < SCREEN_STEPS:
        return SetPointScreen("unknown", f"{dsp.size} isolated set-point steps (need "
                              f"{SCREEN_STEPS})", **base)
    s2 = float(dsp @ dsp)
    per_kick = float(dsp @ kick) / s2
    per_shift = float(dsp @ shift) / s2
    if not abs(per_kick) > 0:
        return SetPointScreen("unknown", "the set-point steps kick the OP by nothing", **base)
    res = shift - per_shift * dsp
    se = math.sqrt(float(res @ res) / (dsp.size - 1) / s2) / abs(per_kick)
    ratio = per_shift / per_kick
    base.update(shift_over_kick=ratio, standard_error=se)
    what = (f"after {dsp.size} set-point steps the OP's lasting shift is {ratio:.2f} "
            f"± {se:.2f} of its kick")
    if ratio + 2.0 * se < SCREEN_SHIFT_MAX:
        return SetPointScreen("integrating", f"{what}: it comes back, as on a level, whose "
                              "valve must balance the load whatever the set point", **base)
    if ratio - 2.0 * se > SCREEN_SHIFT_MAX:
        return SetPointScreen("self-regulating", f"{what}: it settles away, as a "
                              "self-regulating process needs a new valve position for a new "
                              "set point", **base)
    return SetPointScreen("unknown", f"{what}: neither a level's nor a flow's", **base)


#: A slip steps a level's slope by at least this multiple of what the OP's
#: change across it makes through the valve's gain read at the set-point
#: steps (a valve that follows its OP reads about 1).
SLIP_OVER_FOLLOWING = 5.0
#: Set-point steps answered that read the valve's gain.
MIN_ANSWERED = 3


def kinks_over_following(kinks, bumps: SetPointBumps) -> float:
    """How much more a level's kinks step its slope than a valve that followed the OP would.

    Parameters
    ----------
    kinks : valvediag.analysis.signature.StickSlipEvents
        A level's valve events (``process='integrating'``).
    bumps : SetPointBumps
        The same record's set-point steps.

    Returns
    -------
    float
        Median over the valve events of the slope step over the valve's gain
        times the OP's change across the kink
        (:attr:`~valvediag.analysis.signature.StickSlipEvents.op_across`: the
        OP's mean over the half-window after it less that over the one
        before); NaN where fewer than :data:`MIN_ANSWERED` steps answered
        the kick or there is no event.

    Notes
    -----
    The gain is the median, over the steps the level answered, of the fitted
    gain [PV unit / (OP unit s)]: what a unit of OP does to the level's
    slope. A level integrates its valve, so a valve that follows its OP
    changes the level's slope across a kink by the gain times the valve's
    own change across it, which is the OP's; its kinks read about 1. The
    healthy levels whose kinks the reader took for slips (a load's step, a
    quick OP move after one) read 0.7-4.1 on the realistic benchmark's
    development sets and study seeds 10-26. A slip changes the slope by the
    valve's jump, while the OP across it has only crept on (and turned
    back, once the level turned): sticky levels read 5.7-57 there (one,
    loop 1 of development seed 1, 1.5), and 4.0-118, four of them under
    5.7, where their steps also found the valve going against its kicks
    (see below). The OP's *travel before* the kink, which an earlier
    version divided by, holds a sticky valve's creep up to the slip: it
    read 1.4-2.6 on six of the study's sticky levels whose kinks made a
    fault, below a healthy one's 4.6.

    A sticky valve whose kicks always exceed its band answers every step,
    and its gain so read is a slipping valve's, larger than a following
    one's: the ratio then errs low. The scan
    (:func:`~valvediag.analysis.classify.classify_loop`) therefore lets the
    ratio clear no kinks where the same steps found a valve that went
    against its kicks (:attr:`SetPointBumps.found`). Where the set point
    never moves, nothing is read. A load that steps while the OP hardly
    moves across the kink reads as a slip, and a loop slower than the
    kink's window (its OP still making up for a load's step at the end of
    the window) reads above 1. Study seeds 10-16 cut by three gaps
    (``benchmarks/bench_realistic.py --gaps 3``): a stretch of one healthy
    level reads four kinks at 6.7 and the level ``stiction``, where the
    travel before cleared it (6 of 224 healthy valves read faulty, 130 of
    168 sticky valves found; 5 and 129 before).
    """
    answered = bumps.z >= BUMP_Z
    if int(answered.sum()) < MIN_ANSWERED or kinks.size.size == 0:
        return math.nan
    g = float(np.median(bumps.gain[answered]))
    moved = g * np.abs(kinks.op_across)
    ok = moved > 0
    if not ok.any():
        return math.nan
    return float(np.median(np.abs(kinks.size[ok]) / moved[ok]))
