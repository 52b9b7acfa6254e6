"""
Valve travel: the recorded valve position read against the controller output.

Many valves report their position (a positioner's travel feedback, the
``mv`` tag of ``loops.csv``). Where they do, the valve need not be read back
through the process (:mod:`~valvediag.analysis.signature`): the record shows
directly whether the valve follows the controller output (OP), holds in a
dead band after each reversal and then follows (a loose valve), or holds and
then jumps (a sticky one). No process model, load or lag stands between the
two signals, so this reading settles what the PV alone cannot: a square or
triangular load on a flow loop, which turns a linear loop's PV into a
sticky valve's square wave, leaves the valve position following the OP.

:func:`valve_travel` answers two questions, each with its own evidence:

* **Does the valve follow the OP?** The position is fitted by the OP
  (gain and offset, a delay of 0 or 1 sample) and by Kano's valve model [1]_
  over a grid of stick band ``S`` and slip jump ``J`` (``J = 0`` is a dead
  band of width ``S``), with and without an actuator that ignores the OP's
  noise. A valve nonlinearity must remove part of the linear fit's error
  (``ratio``) and the linear fit must leave more than the position's own
  noise (``linear_over_noise``).
* **Does it jump?** A slip moves the position in one sample by far more
  than the OP moved, towards the OP it had fallen behind. Such moves are
  counted and set against the count the position's noise alone would make;
  a loose valve makes none (after its dead band it moves with the OP). This
  is Kano et al.'s stick detection [1]_ read on the recorded position: the
  OP moved and the valve did not, then the valve caught up at once. Slips
  too small against the position's noise to count one by one show pooled:
  a valve that slips fits the whole record better than any dead band.

References
----------
.. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import find_peaks
from scipy.stats import norm, poisson

from ..models.valves import apply_valve
from .quality import (longest_run, most_active_window, resolved_noise_std, stored_points,
                      white_noise_std)
from .signature import NOISE_REVERSAL, held_delay

__all__ = ["ValveTravel", "valve_travel", "TRAVEL_LIMITS"]

#: Decision limits of :func:`valve_travel`.
TRAVEL_LIMITS = {
    # a valve model must leave at most this share of the linear fit's RMS error ...
    "ratio": 0.9,
    # ... and the linear fit must leave more than this multiple of the position's noise
    "linear_over_noise": 1.15,
    # a position no valve model explains better follows the OP when the linear fit
    # leaves at most this multiple of its noise
    "follows_over_noise": 1.5,
    # a jump exceeds this many standard deviations of the position's sample-to-sample noise ...
    "jump_z": 4.5,
    # ... and three times the move the OP made over the same sample
    "jump_over_op": 3.0,
    # the jumps towards the OP must be at least this many and this improbable under noise
    # alone (a Poisson count with half the noise's expected jumps) ...
    "jumps_min": 2,
    "jump_p": 1e-3,
    # jumps towards the OP as probable as this under noise alone are noise: no slip ...
    "noise_p": 0.05,
    # ... unless one exceeds this many noise standard deviations (a slip, even alone)
    "strong_z": 8.0,
    # ... and this share of them must close the gap between the OP and the valve
    "toward_share": 0.75,
    # the OP's 1-99 % range must exceed this many of its noise bands for the fit
    "op_bands": 4.0,
    # slips too small to count one by one name a sticky valve where a valve with
    # a slip jump removes at least this share of the best dead band's RMS error
    # steadily over the record (the t statistic of its lower squared error over
    # 24 blocks; a limit cycle's slips) ...
    "slip_fit": 0.02,
    "slip_t": 3.0,
    # ... or this share, however few stretches carry it (a few slips in a day)
    "slip_fit_alone": 0.1,
    # an OP range [OP unit] over which a position that stands still is a dead valve
    "dead_op_range": 10.0,
    # a signal that keeps fewer of its samples than this was drawn back between stored
    # points, and a jump must exceed twice what that can hide (see valve_travel)
    "stored_min": 0.5,
}
#: Most samples read (the window in which the OP travels furthest).
MAX_SAMPLES = 20_000
#: Jumps are read sample by sample and on the means of this many samples either
#: side: a slip smaller than one sample's noise stands out of four samples' mean
#: (on wider means a loose valve's brief move at the OP's turn reads as a step).
JUMP_MEANS = 4
_JS = (0.0, 0.25, 0.5, 0.75, 1.0)
_S_POINTS = 20


@dataclass(frozen=True)
class ValveTravel:
    """The recorded valve position against the OP, and what it shows.

    Attributes
    ----------
    verdict : str
        ``'stiction'`` (the valve lags the OP and catches up in jumps),
        ``'backlash'`` (it lags the OP and then follows it without a jump),
        ``'undecided'`` (it lags the OP, with a few jumps more than noise
        makes but too few to name a sticky valve), ``'linear'`` (it follows
        the OP), ``'no-response'`` (the OP travels and the position stands
        still) or ``'unknown'`` (too little OP travel, position movement or
        data to tell, or a position no valve model explains).
    reason : str
        One sentence with the figures.
    ratio : float
        RMS error of the best valve model over that of the linear fit [-].
    linear_over_noise : float
        RMS error of the linear fit over the position's white noise [-].
    S, J : float
        Stick band and slip jump of the best valve model [OP unit]; ``J`` is
        biased low where the record straddles the slips (see Notes).
    jump : float
        Median size of the jumps towards the OP, in OP units (through the
        valve's gain) [OP unit].
    jumps, jumps_expected : int, float
        Jumps counted, and the count the position's noise alone would give.
    toward : int
        Of the jumps, those that closed the gap between the OP and the valve.
    gain : float
        Valve position per unit OP, from the two signals' ranges [-].
    noise : float
        White noise of the position [position unit].
    samples : int
        Samples read.
    slip_fit : float
        Share of the RMS error of the best valve without a slip jump (a dead
        band) that the best valve with one removes [-]; negative where a
        jump fits worse, NaN where no valve model was fitted.
    slip_t : float
        t statistic of that lower squared error over 24 consecutive blocks
        of the fitted window [-]: high where the slips lower it steadily (a
        limit cycle), low where a few stretches carry it.
    step : int
        Samples either side over whose means the jumps were read (1, or
        :data:`JUMP_MEANS` where that reading stood further from noise).
    """

    verdict: str
    reason: str
    ratio: float = math.nan
    linear_over_noise: float = math.nan
    S: float = math.nan
    J: float = math.nan
    jump: float = math.nan
    jumps: int = 0
    jumps_expected: float = math.nan
    toward: int = 0
    gain: float = math.nan
    noise: float = math.nan
    samples: int = 0
    slip_fit: float = math.nan
    slip_t: float = math.nan
    step: int = 1
    mv: np.ndarray | None = field(default=None, repr=False)
    op: np.ndarray | None = field(default=None, repr=False)
    jump_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)

    @property
    def fault(self) -> bool:
        """True when the position shows a valve nonlinearity (sticky, loose or unnamed)."""
        return self.verdict in ("stiction", "backlash", "undecided")

    def excerpt(self, samples: int = 1500) -> "ValveTravel":
        """A copy holding only the stretch in which the OP travels furthest.

        Parameters
        ----------
        samples : int
            Length of the stretch kept [samples].

        Returns
        -------
        ValveTravel
            The same figures; ``mv``, ``op`` and ``jump_index`` cut to the
            stretch (copies, so the excerpt does not keep the whole record
            alive). A report draws it.
        """
        if self.mv is None or self.op is None:
            return self
        lo = most_active_window(self.op, samples)
        hi = lo + samples
        k = self.jump_index
        return replace(self, mv=np.array(self.mv[lo:hi]), op=np.array(self.op[lo:hi]),
                       jump_index=np.array(k[(k >= lo) & (k < hi - 1)] - lo))

    def as_dict(self) -> dict:
        """The figures as plain types (NaN as None)."""
        out = {"verdict": self.verdict}
        for k in ("ratio", "linear_over_noise", "S", "J", "jump", "jumps_expected", "gain",
                  "noise", "slip_fit", "slip_t"):
            v = float(getattr(self, k))
            out[k] = round(v, 4) if math.isfinite(v) else None
        out.update(jumps=int(self.jumps), toward=int(self.toward), samples=int(self.samples),
                   step=int(self.step))
        return out

    def plot(self, ax=None):
        """Valve position against OP, the jumps marked.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(5, 4))
        if self.mv is None or self.op is None:
            ax.text(0.5, 0.5, self.reason, ha="center", va="center", wrap=True,
                    transform=ax.transAxes)
            return ax
        ax.plot(self.op, self.mv, lw=0.5, color="C0")
        k = self.jump_index
        if k.size:
            for i in k:
                ax.plot(self.op[i:i + 2], self.mv[i:i + 2], color="C3", lw=1.5)
        ax.set_xlabel("OP")
        ax.set_ylabel("valve position")
        ax.set_title(f"valve position: {self.verdict}")
        return ax


def _fit_residuals(mv: np.ndarray, V: np.ndarray, burn: int) -> tuple[np.ndarray, np.ndarray]:
    """Residuals and gain of ``mv ~ a + b V[i]`` for every row ``i`` (samples from ``burn``)."""
    y = mv[burn:]
    X = V[:, burn:]
    xc = X - X.mean(axis=1, keepdims=True)
    yc = y - y.mean()
    b = (xc @ yc) / np.maximum(np.einsum("ij,ij->i", xc, xc), 1e-300)
    return yc[None, :] - b[:, None] * xc, b


def _fit_rms(mv: np.ndarray, V: np.ndarray, burn: int) -> tuple[np.ndarray, np.ndarray]:
    """RMS error and gain of ``mv ~ a + b V[i]`` for every row ``i`` (samples from ``burn``)."""
    r, b = _fit_residuals(mv, V, burn)
    return np.sqrt(np.einsum("ij,ij->i", r, r) / r.shape[1]), b


def _valve_of(family: tuple, op: np.ndarray, S: np.ndarray) -> np.ndarray:
    """The valve ``family`` (model, J/S, noise band) driven by ``op``: a row per band in ``S``."""
    model, js, nb = family
    S = np.atleast_1d(S)
    U = np.broadcast_to(op, (S.size, op.size))
    if model == "backlash":
        return apply_valve("backlash", U, DB=S)
    return apply_valve("kano", U, noise_band=nb, S=S, J=js * S)


def _block_t(x: np.ndarray, blocks: int = 24) -> float:
    """t statistic of the mean of ``x`` over consecutive blocks (NaN for fewer than 6 of
    at least 50 samples): a mean that a few stretches carry reads low."""
    B = min(blocks, x.size // 50)
    if B < 6:
        return math.nan
    means = x[:B * (x.size // B)].reshape(B, -1).mean(axis=1)
    sd = float(np.std(means, ddof=1))
    return float(np.mean(means)) / (sd / math.sqrt(B)) if sd > 0 else math.nan


def valve_travel(mv, op, sample_time: float, *, max_samples: int = MAX_SAMPLES) -> ValveTravel:
    """Read a valve's recorded position against its controller output.

    Parameters
    ----------
    mv : array_like, shape (n,)
        Recorded valve position [position unit, usually % of travel]; NaN
        where missing.
    op : array_like, shape (n,)
        Controller output, same samples [OP unit, usually %].
    sample_time : float
        [s]
    max_samples : int
        Longer records are read on the window of this many samples in which
        the OP travels furthest.

    Returns
    -------
    ValveTravel

    Raises
    ------
    ValueError
        Unequal lengths or a non-positive sample time.

    Notes
    -----
    Where the position and the OP are both finite, the longest such stretch
    is read. The fit is made on the window of ``max_samples`` in which the OP
    travels furthest: the linear fit allows a gain, an offset and a delay of
    one sample (a positioner answers within a sample or two); the valve
    models are Kano's with ``S`` on 20 points from the OP's noise band to
    90 % of its range, and at 95 and 100 % (a valve that slips at the top of
    the OP's swing, as a sawtooth's does), and ``J/S`` in 0, 1/4, ..., 1,
    each with and without an actuator that ignores OP noise within six noise
    standard deviations, and a dead band of the same widths that follows the
    OP's noise at its edge (Kano's valve with ``J = 0`` sticks at each of the
    noise's reversals); they need an OP that travels beyond four noise bands
    (otherwise only the linear fit is made). The first 5 % of the window is
    not scored (the valve's starting state is not known). The OP's noise is
    read by :func:`~valvediag.analysis.quality.resolved_noise_std`: an OP
    stored by a swinging door with its stored points 20 or more samples
    apart is read at its stored resolution, not at its turns.

    The jumps are counted over the whole stretch. A jump is a move of the
    position beyond :data:`TRAVEL_LIMITS`'s ``jump_z`` standard deviations
    of its sample-to-sample noise after the move the OP made over the same
    sample is taken off (through the valve's gain, the larger of the fitted
    one and the ratio of the two signals' 1-99 % ranges), and at least
    ``jump_over_op`` times the OP's move over that sample and the one before
    (a slip is vertical in the position-OP plot; a positioner that follows
    may answer the OP a sample late), and the position must have stood
    (within half the jump over the two samples before it) and must stay (at
    least half the jump away from where it started one and two samples
    later): a valve that slipped had stuck and stays; a spike of the
    reading comes back. The noise alone makes ``2 n Phi(-jump_z)`` of them in
    ``n`` samples, half of them towards the OP. A sticky valve needs
    ``jumps_min`` jumps towards the OP whose count is improbable under noise
    (Poisson tail below ``jump_p``), three quarters of all jumps; fewer than
    ``jumps_min`` jumps towards the OP, or a count that noise makes with
    probability ``noise_p`` or more, is no jump (a loose valve: one jump just
    beyond the noise is no pattern, the noise makes one now and then) unless
    a jump exceeds ``strong_z`` standard deviations; in between the kind is
    left ``'undecided'``.

    The jumps are read a second time on the means of :data:`JUMP_MEANS`
    samples either side of each sample boundary: the step between the two
    means, less the OP's through the gain, beyond ``jump_z`` standard
    deviations of that difference and beyond the OP's noise band through the
    gain (a loose valve that follows the OP's noisy edge moves in steps of
    that noise), at least ``jump_over_op`` times the step of the OP's means,
    the position standing over the two means before and staying over the two
    after; one jump per ``2 L`` samples, and the noise makes ``2 n / L
    Phi(-jump_z)`` of them. A slip of one or two noise standard deviations of
    a sample stands out of four samples' mean (on wider means a loose valve's
    brief move at the OP's turn, while the OP's mean stands, reads as a
    step). Of the two readings the one whose count the noise explains less
    is kept (the wider one's tail probability doubled, for two looks at one
    record).

    Slips too small to count one by one show pooled. The best valve with a
    slip jump (``J/S`` from 1/4) and the best without one (Kano's with
    ``J = 0``, the dead band) are each refined; the jump's share of the dead
    band's RMS error that it removes is ``slip_fit``. A dead band fits a
    loose valve's position at least as well as any jump (on the realistic
    benchmark's development seeds, 116 loose valves whose position was fitted
    gave ``slip_fit`` of at most 0.027, and 0.016 but for one); a sticky valve's
    stuck stretches each end in a jump the dead band cannot follow. A pooled
    slip names a sticky valve where it removes ``slip_fit_alone`` of the
    error however few stretches carry it (a few slips in a day), or
    ``slip_fit`` steadily over the record (``slip_t``, the t statistic of the
    lower squared error over 24 consecutive blocks: a limit cycle's slips,
    each small).

    The verdict: ``'linear'`` when the linear fit leaves at most
    ``linear_over_noise`` times the position's noise, or when no valve model
    does better (``ratio`` above its limit) and it leaves at most
    ``follows_over_noise`` times; otherwise ``'stiction'`` from the jumps or
    a pooled slip, and, where a valve model removes part of the linear fit's
    error, ``'backlash'`` or ``'undecided'``; ``'unknown'`` where nothing
    explains the position.

    A record drawn back by straight lines between stored points (fewer than
    ``stored_min`` of its samples stored) hides how the signal moved between
    them: the true signal stood or crept within the compression, whose
    deviation the steps between consecutive stored values bound (an
    exception dead band stores a value once the signal has left the last one
    by more than the band). A jump must then also exceed twice the 90th
    percentile of those steps (of the OP through the gain, and of the
    position): a step of the position that the OP's stored line hides is a
    valve following a move nobody stored, not a slip.

    It assumes the position is the valve's own (not a second controller's
    set point) and that the OP and the position are sampled together. It
    fails where:

    * the slip jump is smaller than about three noise standard deviations of
      the position (``jump_z`` of the difference of four samples' means),
      few slips are recorded and they do not show pooled: a sticky valve with a small
      ``J`` then reads as ``'backlash'`` (which it nearly is: below ``J/S``
      of about 0.2, the grid's first jump, 1/4, fits worse than none);
    * the OP swings barely further than the stick band (a level valve closed
      against a net inflow slips at the top of each of the OP's rises from
      its limit): where the model places a slip then turns on a few per cent
      of ``S``, and a small slip may not show pooled;
    * the record is sampled more slowly than the controller runs: a slip
      happens at the OP's turn, which the record straddles, so the fitted
      valve model misses slips and its ``J`` comes out low (the jump count,
      which needs no model, is unaffected);
    * a sticky valve slips only a few times in a long record (a valve that,
      once moving, follows a slowly creeping OP sticks again only where the
      OP reverses): two slips in a day are ``'undecided'``;
    * a positioner with a slow lag of its own makes the position lag the OP
      as a dead band does (``'backlash'``), and one that overshoots makes
      jumps;
    * the position transmitter is dead or frozen (``'no-response'``: the
      data cannot tell a valve stuck fast from a dead transmitter).

    References
    ----------
    See the module docstring.
    """
    h = float(sample_time)
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"sample_time must be a positive number of seconds, got {sample_time!r}")
    mv = np.asarray(mv, dtype=float).ravel()
    op = np.asarray(op, dtype=float).ravel()
    if mv.size != op.size:
        raise ValueError(f"mv has {mv.size} samples but op has {op.size}")
    a, b = longest_run(np.isfinite(mv) & np.isfinite(op))
    if b == a:
        return ValveTravel(verdict="unknown", reason="no valve position recorded")
    mv, op = mv[a:b], op[a:b]
    n = mv.size
    lim = TRAVEL_LIMITS
    if n < 64:
        return ValveTravel(verdict="unknown", reason=f"only {n} samples with a valve position",
                           samples=n)
    noise = white_noise_std(mv)
    mv_lo, mv_hi = np.percentile(mv, [1.0, 99.0])
    mv_range = float(mv_hi - mv_lo)
    lo, hi = np.percentile(op, [1.0, 99.0])
    op_range = float(hi - lo)
    # a position without measurable noise (a clean or quantised signal): a
    # thousandth of its range stands in, so ratios stay finite
    noise = max(noise, 1e-3 * mv_range, 1e-12)
    base = dict(noise=noise, samples=n, mv=mv, op=op)
    if mv_range <= 6.0 * noise:
        if op_range >= lim["dead_op_range"]:
            return ValveTravel(
                verdict="no-response",
                reason=f"the OP travels {op_range:.3g} and the valve position stands still "
                       f"(range {mv_range:.3g}, noise {noise:.3g}): a valve stuck fast, or a dead "
                       "position transmitter", **base)
        return ValveTravel(verdict="unknown",
                           reason=f"the valve position moves only within its noise (range "
                                  f"{mv_range:.3g}, noise {noise:.3g})", **base)
    # the fit, on the window in which the OP travels furthest
    start = most_active_window(op, max_samples)
    w_mv, w_op = mv[start:start + max_samples], op[start:start + max_samples]
    band = NOISE_REVERSAL * resolved_noise_std(w_op)
    lo, hi = np.percentile(w_op, [1.0, 99.0])
    w_range = float(hi - lo)
    w_lo, w_hi = np.percentile(w_mv, [1.0, 99.0])
    # the valve models need an OP that travels beyond its noise band; the
    # linear fit needs a position that moves beyond its noise
    fit = None
    if w_hi - w_lo > 6.0 * noise and w_range > 0:
        fit = _valve_fit(w_mv, w_op, band, w_range, noise,
                         valves=w_range > lim["op_bands"] * band)
    # the jumps, on the whole record; the valve's gain from the ranges is low by
    # the band over the OP's range, the fitted one is not: the larger is used,
    # so that a move with a large OP step is not read as a jump
    gain = mv_range / max(op_range, 1e-12)
    slip_fit, fit_slips = math.nan, False
    if fit is not None:
        fitted = fit.pop("gain")
        gain = math.copysign(max(gain, abs(fitted)), fitted) if math.isfinite(fitted) else gain
        rms_db, rms_slip = fit.pop("rms_deadband", math.nan), fit.pop("rms_slip", math.nan)
        slip_t = fit.pop("slip_t", math.nan)
        if rms_db > 0 and rms_slip > 0:
            # the slips pooled: a jump too small against the noise to count
            # one by one still lowers the error of every stuck stretch it ends
            slip_fit = 1.0 - rms_slip / rms_db
            fit_slips = slip_fit >= lim["slip_fit_alone"] or (slip_fit >= lim["slip_fit"]
                                                               and slip_t >= lim["slip_t"])
        fit["slip_fit"] = slip_fit
        fit["slip_t"] = slip_t
    else:
        corr = np.corrcoef(mv, op)[0, 1]
        gain = math.copysign(gain, corr if np.isfinite(corr) else 1.0)
    jumps = _jumps(mv, op, noise, gain)
    count = (f"{jumps['jumps']} jumps of the position beyond its noise and the OP's move "
             f"({jumps['jumps_expected']:.2g} expected from noise), {jumps['toward']} of them "
             f"towards the OP")
    if jumps["step"] > 1:
        count += f", read on the means of {jumps['step']} samples either side"
    p, strong = jumps.pop("p"), jumps.pop("strong")
    slips = bool(jumps["toward"] >= lim["jumps_min"] and p < lim["jump_p"]
                 and jumps["toward"] >= lim["toward_share"] * jumps["jumps"])
    slip_reason = (f"the valve position lags the OP and catches up in jumps ({count}; median jump "
                   f"{jumps['jump']:.3g} in OP units): a sticky valve")
    if fit is None:
        if slips:
            return ValveTravel(verdict="stiction", reason=slip_reason, **jumps, **base)
        return ValveTravel(verdict="unknown",
                           reason=f"over the {w_mv.size} samples in which the OP travels "
                                  f"furthest ({w_range:.3g}) the valve position stands within its "
                                  f"noise, and {count}", **jumps, **base)
    figures = (f"a valve model leaves {100 * fit['ratio']:.0f}% of the linear fit's RMS error, "
               f"which is {fit['linear_over_noise']:.2f} times the position's noise {noise:.3g}")
    if not math.isfinite(fit["S"]):
        figures = (f"the linear fit leaves {fit['linear_over_noise']:.2f} times the position's "
                   f"noise {noise:.3g}; the OP travels only {w_range:.3g}, too little beyond its "
                   f"noise band {band:.3g} to fit a valve model")
    lin_noise, nonlinear = fit["linear_over_noise"], fit["ratio"] <= lim["ratio"]
    if lin_noise <= lim["linear_over_noise"] or (not nonlinear and not slips
                                                  and lin_noise <= lim["follows_over_noise"]):
        return ValveTravel(verdict="linear",
                           reason=f"the valve position follows the OP ({figures})",
                           **fit, **jumps, **base)
    if slips:
        return ValveTravel(verdict="stiction", reason=f"{slip_reason} ({figures})",
                           **fit, **jumps, **base)
    if not nonlinear:
        return ValveTravel(verdict="unknown",
                           reason=f"the valve position departs from the OP in a way no valve "
                                  f"model explains (a positioner's lag, a position of another "
                                  f"loop's valve?): {figures}; {count}", **fit, **jumps, **base)
    if fit_slips:
        reason = (f"the valve position lags the OP, and a valve that slips fits it better than "
                  f"any dead band (it removes {100 * slip_fit:.0f}% of the best dead band's RMS "
                  f"error; S {fit['S']:.3g}, J {fit['J']:.3g}): slips too small to count one by "
                  f"one against the position's noise ({count}) show pooled: a sticky valve "
                  f"({figures})")
        return ValveTravel(verdict="stiction", reason=reason, **fit, **jumps, **base)
    if (jumps["toward"] < lim["jumps_min"] or p >= lim["noise_p"]) and not strong:
        # a single jump just beyond the noise is no pattern: noise makes one now and then
        reason = (f"the valve position lags the OP and follows it without a jump ({count}): a "
                  f"dead band of about {fit['S']:.3g} ({figures})")
        return ValveTravel(verdict="backlash", reason=reason, **fit, **jumps, **base)
    reason = (f"the valve position lags the OP, and {count}: more than noise makes, too few to "
              f"tell a sticky valve from a loose one ({figures})")
    return ValveTravel(verdict="undecided", reason=reason, **fit, **jumps, **base)


def _valve_fit(mv: np.ndarray, op: np.ndarray, band: float, op_range: float, noise: float, *,
               valves: bool = True) -> dict:
    """The linear fit and the best valve model of ``mv`` from ``op`` (see :func:`valve_travel`);
    the linear fit alone when ``valves`` is False (``ratio`` 1, ``S`` and ``J`` NaN).
    ``noise``: the position's white noise, against which the linear fit's error is read."""
    n = mv.size
    burn = max(2, n // 20)
    lin = [_fit_rms(mv, held_delay(op, d)[None, :], burn) for d in (0, 1)]
    r_lin, b_lin = min(lin, key=lambda rb: rb[0][0])
    rms_lin = float(r_lin[0])
    if not valves:
        return dict(ratio=1.0, linear_over_noise=rms_lin / noise, S=math.nan, J=math.nan,
                    gain=float(b_lin[0]))
    S_axis = np.r_[np.geomspace(max(band, op_range / 200.0), 0.9 * op_range, _S_POINTS),
                   0.95 * op_range, op_range]
    # families: Kano's valve at each J/S, with and without a noise band, and a
    # dead band that follows the OP's noise at its edge (Kano's valve with
    # J = 0 sticks at every reversal of the noise instead)
    families = [("kano", js, nb) for nb in (0.0, band) for js in _JS] + [("backlash", 0.0, 0.0)]

    def fit(family, S_values):
        # (RMS error, band, gain, residuals) of the best band and delay
        V = _valve_of(family, op, S_values)
        best = None
        for d in (0, 1):
            res, b = _fit_residuals(mv, held_delay(V, d), burn)
            r = np.sqrt(np.einsum("ij,ij->i", res, res) / res.shape[1])
            k = int(np.argmin(r))
            if best is None or r[k] < best[0]:
                best = (float(r[k]), float(S_values[k]), float(b[k]), res[k])
        return best

    grid = [(fit(f, S_axis), f) for f in families]
    # the best valve without a slip jump (a dead band: Kano's with J = 0 or
    # the backlash) and the best with one, each refined between its grid
    # neighbours: near the OP's swing the fit turns on a few per cent of the band
    refined = []
    for with_jump in (False, True):
        (r, S0, *_), f = min(((g, f) for g, f in grid if (f[1] > 0) == with_jump),
                             key=lambda gf: gf[0][0])
        i = int(np.argmin(np.abs(S_axis - S0)))
        fine = np.linspace(S_axis[max(0, i - 1)], S_axis[min(S_axis.size - 1, i + 1)], 25)
        r, S1, b, res = fit(f, fine)
        refined.append((r, S1, f[1] * S1, b, res))
    (rms_db, *_, res_db), (rms_slip, *_, res_slip) = refined
    rms_nl, S_best, J_best, gain, _ = min(refined, key=lambda x: x[0])
    return dict(ratio=rms_nl / rms_lin if rms_lin > 0 else 1.0,
                linear_over_noise=rms_lin / noise, S=S_best, J=J_best, gain=gain,
                rms_deadband=rms_db, rms_slip=rms_slip,
                slip_t=_block_t(res_db ** 2 - res_slip ** 2))


def _hidden(x: np.ndarray) -> float:
    """How far a compressed record may hide the signal's moves: 0 for a record
    that keeps most of its samples, else the 90th percentile of the steps
    between consecutive stored points."""
    kept = stored_points(x)
    if kept.size >= TRAVEL_LIMITS["stored_min"] * x.size:
        return 0.0
    return float(np.percentile(np.abs(np.diff(x[kept])), 90)) if kept.size > 1 else math.inf


def _jumps(mv: np.ndarray, op: np.ndarray, noise: float, gain: float) -> dict:
    """The position's own jumps towards the OP (see :func:`valve_travel`); ``gain`` is
    the position per unit OP, with its sign. Read sample by sample and on the means of
    :data:`JUMP_MEANS` samples either side; the reading the noise explains less wins."""
    one = _jumps_at(mv, op, noise, gain, 1)
    wide = _jumps_at(mv, op, noise, gain, JUMP_MEANS)
    # two readings of one record: the wider one's tail probability doubled
    wide["p"] = min(1.0, 2.0 * wide["p"])
    return wide if wide["p"] < one["p"] else one


def _jumps_at(mv: np.ndarray, op: np.ndarray, noise: float, gain: float, L: int) -> dict:
    """:func:`_jumps` read on the means of ``L`` samples either side of each step."""
    lim = TRAVEL_LIMITS
    n = mv.size
    gap = gain * (op - np.median(op)) - (mv - np.median(mv))
    if L == 1:
        dm, do = np.diff(mv), np.diff(op)
        # a slip is vertical in the position-OP plot: the OP moved little over
        # the sample and the one before it (a positioner that follows may answer
        # the OP's move a sample late)
        op_move = np.abs(do)
        op_move[1:] = np.maximum(op_move[1:], np.abs(do[:-1]))
        # and the valve stood before it and stays where it jumped to (a spike of
        # the reading comes back at once): one and two samples either side, the
        # position is within half the jump of where it was, and at least half the
        # jump away from where it started
        stays = np.ones(dm.size, bool)
        for j in (1, 2):
            after = np.full(dm.size, np.inf)
            after[:dm.size - j] = mv[1 + j:] - mv[:mv.size - 1 - j]       # mv[k+1+j] - mv[k]
            before = np.full(dm.size, np.inf)
            before[j:] = mv[j:-1] - mv[:mv.size - 1 - j]                 # mv[k] - mv[k-j]
            stays &= (np.abs(after) >= 0.5 * np.abs(dm)) & (np.abs(before) < 0.5 * np.abs(dm))
        floor = 0.0
    else:
        # the step between the means of L samples before and after each sample
        # boundary, and the same of the L samples beyond those: the valve stood
        # over the two windows before and stays over the two after
        (b2, b1, a1, a2), inside = _window_means(mv, L)
        (_, ob1, oa1, _), _ = _window_means(op, L)
        dm, do = a1 - b1, oa1 - ob1
        op_move = np.abs(do)
        stays = (inside & (np.abs(b1 - b2) < 0.5 * np.abs(dm))
                 & (np.abs(a2 - b1) >= 0.5 * np.abs(dm)))
        # a loose valve that follows the OP's noisy edge moves in steps of that
        # noise: a slip read on means must stand beyond the OP's noise band
        floor = abs(gain) * NOISE_REVERSAL * resolved_noise_std(op)
    # the position's own move: what it moved beyond following the OP (a valve
    # that follows moves by the OP's move, and a jump must stand out of that)
    own = dm - gain * do
    threshold = max(lim["jump_z"] * math.sqrt(2.0 / L) * noise,
                    2.0 * (abs(gain) * _hidden(op) + _hidden(mv)), floor)
    is_jump = ((np.abs(own) > threshold)
               & (np.abs(dm) >= lim["jump_over_op"] * abs(gain) * op_move) & stays)
    if L == 1:
        at = np.flatnonzero(is_jump)
    else:
        # one jump per slip: the largest of the steps it makes within 2 L samples
        at, _ = find_peaks(np.r_[0.0, np.where(is_jump, np.abs(own), 0.0), 0.0],
                           height=1e-300, distance=2 * L)
        at = at - 1
    toward = at[np.sign(own[at]) == np.sign(gap[at])]
    # (where a compressed record raised the threshold this overstates what the
    # noise makes, which only makes slips harder to claim)
    expected = 2.0 * (n - 1) / L * float(norm.sf(lim["jump_z"]))
    # under noise alone half the jumps would close the gap
    p = float(poisson.sf(toward.size - 1, 0.5 * expected)) if toward.size else 1.0
    jump = float(np.median(np.abs(dm[toward])) / abs(gain)) if toward.size else math.nan
    # a jump far beyond anything noise makes (no count of noise needed)
    strong = int(np.sum(np.abs(own[toward]) > lim["strong_z"] * math.sqrt(2.0 / L) * noise))
    return dict(jump=jump, jumps=int(at.size), jumps_expected=expected, toward=int(toward.size),
                gain=gain, jump_index=toward, p=p, strong=strong, step=L)


def _window_means(x: np.ndarray, L: int) -> tuple[tuple, np.ndarray]:
    """Means of the ``L`` samples ending ``L`` before, ending at, starting after and
    starting ``L + 1`` after each sample ``k < n - 1``, and where all four fit."""
    n = x.size
    c = np.r_[0.0, np.cumsum(x)]
    k = np.arange(n - 1)
    inside = (k >= 2 * L - 1) & (k + 2 * L <= n - 1)
    kk = np.clip(k, 2 * L - 1, max(2 * L - 1, n - 2 * L - 1))

    def mean(lo):
        return (c[np.clip(lo + L, 0, n)] - c[np.clip(lo, 0, n)]) / L

    return (mean(kk + 1 - 2 * L), mean(kk + 1 - L), mean(kk + 1), mean(kk + 1 + L)), inside
