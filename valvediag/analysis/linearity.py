"""
Is an oscillation caused by a valve nonlinearity at all?

A linear loop (an aggressive tuning, or a linear loop driven by a sinusoidal
disturbance) oscillates sinusoidally: the PV and the OP hold one harmonic.
A sticky or loose valve makes the valve position a square or trapezoidal wave,
so the PV of an integrating process (the integral of the valve position) is a
triangle or a trapezoid-rounded triangle with odd harmonics.

Two measures are computed on the *mean cycle*: every cycle, from valley to
valley, is resampled to a fixed number of phase points and the cycles are
averaged, which removes noise (by the square root of the number of cycles)
and tolerates period jitter.

``pv_distortion``
    Total harmonic distortion of the mean PV cycle (harmonics 2-7 over the
    fundamental), with the noise floor estimated from the cycle-to-cycle
    scatter subtracted. A triangle wave has 0.121, a sine 0. It is read on
    two mean cycles, one cut from valley to valley and one from peak to
    peak, and their harmonic powers are pooled: a cut aligns one apex and
    smears the other by the cycles' jitter, and one cut alone would read a
    PV and its mirror image (a reverse-acting loop) apart.
``valve_linearity``
    For an integrating process the valve position is proportional to the PV
    slope. ``valve_linearity`` is the best squared correlation between that
    implied valve position and the OP shifted by any lag: close to 1 when the
    valve follows the controller linearly, lower when it sticks or lags in a
    dead band.

References
----------
.. [1] Choudhury, M. A. A. S., Shah, S. L., Thornhill, N. F. (2004). Diagnosis
   of poor control-loop performance using higher-order statistics.
   Automatica 40, 1719-1728. (Nonlinearity from harmonics.)
.. [2] Thornhill, N. F., Huang, B., Zhang, H. (2003). Detection of multiple
   oscillations in control loops. J. Process Control 13, 91-100.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .oscillation import resample_cycles, turned_cycles
from .quality import white_noise_std

__all__ = ["CycleShape", "mean_cycles", "cycle_shape", "rest_share", "REST_NEAR",
           "REST_STILL", "REST_NBINS", "away_share", "AWAY_STEPS", "move_onset", "ONSET_SHARE",
           "ONSET_STEPS"]

NBINS = 64
N_HARMONICS = 7
#: A phase point of the mean cycle is at the set point where the mean control
#: error lies within this share of its half swing of zero ...
REST_NEAR = 0.1
#: ... and the OP is still where its move to the next point is at most this
#: share of its mean move between points.
REST_STILL = 0.1
#: Phase points of the mean cycle read by :func:`rest_share`.
REST_NBINS = 128
#: Steps per oscillation period over which :func:`away_share` reads the
#: control error's moves.
AWAY_STEPS = 40
#: Share of an oscillation period over which :func:`move_onset` compares the
#: PV's speed before and after its fastest point (long enough that a lag of a
#: twentieth of the period, a sensor's or a mixing volume's, rounds only the
#: start of a slip's window) ...
ONSET_SHARE = 1.0 / 6.0
#: ... read over steps of this many to a period (the PV smoothed as long).
ONSET_STEPS = 40


def mean_cycles(signals, apex_idx, apex_sign, nbins: int = NBINS):
    """Resample every valley-to-valley cycle to ``nbins`` phase points.

    Parameters
    ----------
    signals : sequence of array_like
        Signals sampled like the PV (e.g. PV and OP).
    apex_idx, apex_sign : array_like
        Apices of the PV (from :func:`valvediag.analysis.oscillation.segment_cycles`).
    nbins : int
        Phase points per cycle.

    Returns
    -------
    list of numpy.ndarray, shape (n_cycles, nbins)
        One matrix per signal; empty when fewer than two cycles.
    """
    return resample_cycles(signals, apex_idx, apex_sign, nbins)


@dataclass(frozen=True)
class CycleShape:
    """Shape evidence of an oscillation.

    Attributes
    ----------
    pv_distortion : float
        Noise-corrected harmonic distortion of the mean PV cycle [-].
    valve_linearity : float
        Best squared correlation of the implied valve position (PV slope)
        with the lagged OP [-], NaN without OP.
    op_lag : float
        The lag of that best match [fraction of a period].
    cycles : int
        Cycles averaged.
    pv_cycle, op_cycle : numpy.ndarray
        Mean cycles (PV minus its mean; OP minus its mean).
    """

    pv_distortion: float
    valve_linearity: float
    op_lag: float
    cycles: int
    pv_cycle: np.ndarray
    op_cycle: np.ndarray

    def plot(self, ax=None):
        """Phase plot of the mean cycle: OP against implied valve position."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(4, 4))
        n = self.pv_cycle.size
        slope = np.gradient(np.r_[self.pv_cycle, self.pv_cycle[:1]])[:n] * n
        ax.plot(np.r_[self.op_cycle, self.op_cycle[:1]], np.r_[slope, slope[:1]], color="C0")
        ax.set_xlabel("OP (mean cycle)")
        ax.set_ylabel("PV slope ~ valve position")
        ax.set_title(f"valve linearity {self.valve_linearity:.2f}, "
                     f"PV distortion {self.pv_distortion:.3f}", fontsize=9)
        return ax


def cycle_shape(pv, op, apex_idx, apex_sign, nbins: int = NBINS) -> CycleShape:
    """Harmonic and valve-linearity evidence from the mean cycle.

    Parameters
    ----------
    pv : array_like
        PV (drift removed or not; the mean cycle removes a constant) [PV unit].
    op : array_like or None
        Controller output, same sampling [OP unit].
    apex_idx, apex_sign : array_like
        PV apices.
    nbins : int
        Phase points per cycle.

    Returns
    -------
    CycleShape

    Notes
    -----
    The implied valve position assumes an integrating process without
    significant lag; a lag of a fraction of the period smooths the PV and
    lowers ``pv_distortion``. A non-sinusoidal external disturbance (a square
    wave load) looks nonlinear here and cannot be told from a valve fault by
    PV and OP alone.

    The noise floor subtracted from the harmonic power is the variance of
    the mean of each harmonic's coefficient, read from its scatter over the
    cycles (``sum |F_k - F|^2 / (K (K - 1))`` over harmonics 2-7): the
    expected excess of the mean cycle's harmonic power over the true one.
    The scatter does not spread evenly over the phase bins, as a floor
    taken from the whole residual assumed: a ringing loop's cycles differ
    mostly in amplitude (the fundamental), a limit cycle's in where its
    sharp turns fall (the harmonics). On the realistic benchmark's ringing
    levels (study seeds 10 and 11) that floor was 1.2-4.4 times this one,
    on its sticky level and flow cycles 0.5-0.9 times.
    ``pv_distortion`` is the same for ``pv`` and ``-pv`` wherever both cuts
    hold two cycles; ``valve_linearity`` and the mean cycles returned come
    from the valley cut alone.
    """
    have_op = op is not None
    sig = [pv, op] if have_op else [pv]
    cyc = mean_cycles(sig, apex_idx, apex_sign, nbins)
    C = cyc[0]
    K = C.shape[0]
    if K < 2:
        nan = np.full(nbins, np.nan)
        return CycleShape(np.nan, np.nan, np.nan, K, nan, nan)
    mean = C.mean(axis=0)
    F = np.fft.rfft(mean - mean.mean()) / nbins
    H = min(N_HARMONICS, nbins // 2 - 1)
    # the harmonic powers of both cuts pooled (see turned_cycles)
    Cp = turned_cycles(pv, apex_idx, apex_sign, nbins)
    fund = harm = floor = 0.0
    for M in (C, Cp) if Cp.shape[0] >= 2 else (C,):
        k = M.shape[0]
        Fm = np.fft.rfft(M.mean(axis=0) - M.mean()) / nbins
        fund += np.abs(Fm[1]) ** 2
        harm += np.sum(np.abs(Fm[2:H + 1]) ** 2)
        # noise floor: the variance of the mean of each harmonic's
        # coefficient, from its scatter over the cycles (see Notes)
        Fc = np.fft.rfft(M - M.mean(axis=1, keepdims=True), axis=1) / nbins
        floor += float(np.sum(np.abs(Fc[:, 2:H + 1] - Fm[2:H + 1]) ** 2)) / (k * (k - 1))
    dist = float(np.sqrt(max(harm - floor, 0.0) / fund)) if fund > 0 else np.nan
    if not have_op:
        return CycleShape(dist, np.nan, np.nan, K, mean - mean.mean(), np.full(nbins, np.nan))
    opm = cyc[1].mean(axis=0)
    G = np.fft.rfft(opm - opm.mean()) / nbins
    n = np.arange(F.size)
    keep = (n >= 1) & (n <= H)
    Fv = np.where(keep, 1j * n * F, 0)       # implied valve position: d PV / d phase
    Gv = np.where(keep, G, 0)
    # correlation of Fv with Gv shifted by lag L (fraction of period):
    # sum_n Re(Fv_n conj(Gv_n) e^{+2 pi i n L}) over the one-sided spectrum
    lags = np.linspace(0.0, 1.0, 256, endpoint=False)
    cross = np.real((Fv * np.conj(Gv))[None, :] * np.exp(2j * np.pi * n[None, :] * lags[:, None])).sum(1)
    den = np.sqrt(np.sum(np.abs(Fv) ** 2) * np.sum(np.abs(Gv) ** 2))
    if den == 0:
        r2, lag = np.nan, np.nan
    else:
        r = cross / den
        k = int(np.argmax(r))
        r2, lag = float(max(r[k], 0.0) ** 2), float(lags[k])
    return CycleShape(dist, r2, lag, K, mean - mean.mean(), opm - opm.mean())


def rest_share(error, op, apex_idx, apex_sign, nbins: int = REST_NBINS) -> float:
    """Share of the mean cycle over which the loop rests at its set point with its OP still.

    Parameters
    ----------
    error : array_like, shape (n,)
        Control error, PV less set point [PV unit], sampled like the PV whose
        apices are given.
    op : array_like, shape (n,)
        Controller output [OP unit].
    apex_idx, apex_sign : array_like
        Apices of the PV (:func:`valvediag.analysis.oscillation.detect_oscillation`).
    nbins : int
        Phase points per cycle.

    Returns
    -------
    float
        Share of the mean cycle's phase points [0-1] where the mean error is
        within :data:`REST_NEAR` of its half swing of zero and the mean OP
        moves by at most :data:`REST_STILL` of its mean move; NaN where fewer
        than two cycles are cut.

    Notes
    -----
    A valve's limit cycle never rests at the set point. With the error at
    zero the controller stops; a valve that sticks, or rests in its dead
    band, then holds a position that passes the load's flow only by chance,
    and were it to, the loop would stay at rest and the cycle end. A loop
    whose every cycle rests at its set point with the OP still is settling
    after each move of its load (a pump that starts and stops, a batch
    step): the swing is the load's, whatever the valve. On the realistic
    benchmark's study seeds 10-16 (4 loops a class) the sticky and loose
    valves' cycles, level and flow, rest for at most 0.016 of the cycle, the
    ringing levels for at most 0.016; the square loads on fast flows for up
    to 0.68.

    It fails where the loop never settles between the load's moves (a slow
    loop, a fast load) and where the load ramps: the loop then holds a
    steady error off its set point while the OP follows the ramp, as a
    sticky flow valve's loop does while the OP creeps. A noisy mean cycle
    (few cycles) reads fewer rests, not more. A set point that wanders
    without a step is read through (the error is the PV less it).
    """
    E, U = resample_cycles([error, op], apex_idx, apex_sign, nbins)
    if E.shape[0] < 2:
        return float("nan")
    e, u = E.mean(axis=0), U.mean(axis=0)
    half = 0.5 * float(np.ptp(e))
    du = np.abs(np.diff(np.r_[u, u[:1]]))
    if not (half > 0 and du.mean() > 0):
        return float("nan")
    at_sp = np.abs(e) <= REST_NEAR * half
    still = du <= REST_STILL * du.mean()
    return float(np.mean(at_sp & still))


def away_share(error, sample_time: float, period: float, sp=None) -> float:
    """Share of a self-regulating loop's fast motion that leads away from its set point.

    Parameters
    ----------
    error : array_like, shape (n,)
        The PV about its set point [PV unit], one gap-free stretch: the
        control error, or the PV less its drift over a period (integral
        action holds a cycle's mean PV at the set point, and the drift-free
        record does not depend on a set point exported stale or offset).
    sample_time : float
        [s]
    period : float
        Oscillation period [s].
    sp : array_like, shape (n,), optional
        Set point [PV unit]: moves over which it steps are left out (a
        set-point step moves the error away from zero by itself).

    Returns
    -------
    float
        Over steps of ``period / AWAY_STEPS`` (at least a sample), the sum of
        the squared moves of the error that lead away from zero (the move and
        the error at its midpoint have the same sign) over the sum of all
        squared moves, the white noise's part taken out of both [0-1]; NaN
        where the period spans fewer than two samples or the noise makes 90 %
        or more of the motion.

    Notes
    -----
    A sticky valve's slip is the controller's correction arriving at once:
    the valve jumps the way the OP had crept, and a self-regulating PV
    answers it as a process does a step, fastest at first, towards the set
    point and across it, then more slowly as it settles on the other side.
    Squared, the moves weigh by their speed, so its fast motion leads
    towards the set point. A load that steps does the opposite: it pushes
    the PV away from a set point it had settled at, and the controller
    brings it back more slowly. A sinusoidal load moves the PV away and back
    alike (0.5). The white noise does too: its expected share of the squared
    moves (two noise variances a move, :func:`~valvediag.analysis.quality.white_noise_std`)
    is taken out of both sums, or a slow loop whose plateaus last long read
    its noise there as half its motion.

    On the realistic benchmark's development seeds 1-2 (12 loops a class)
    and study seeds 10-16 (4 a class), the sticky flow cycles (51 loops,
    time constants of 2-60 s) read 0.28-0.39 and the sticky temperature
    cycles (52, time constants of 60-600 s) 0.28-0.42 but for one at 0.50;
    healthy loops under loads at the cycle's period read 0.49-0.54 under
    sines (24), 0.44-0.64 under clipped sines (29), 0.36-0.85 under square
    waves (27, most 0.6 and more) and 0.19-0.52 under triangles (24).

    A sticky cycle biased to one side of its set point (the valve's balance
    close to one of its stick points) creeps slowly from a small error and
    slips far past the set point: most of the slip then leads away, and the
    share reads about 0.5 (the one at 0.50 above: four cycles in four
    hours, plateaus 0.4 above the set point, slips 4 below it). A square
    load that comes faster than the loop settles keeps it swinging in a
    near-triangle, and reads as low as a slip does.

    It cannot tell a triangular load from a sticky valve: a loop holds a
    steady error off its set point while its OP follows each ramp of the
    load, and the error crosses the set point where the load turns, as a
    sticky valve's square wave does (0.19-0.52 read); how the PV's swings
    start tells them apart where the process's lag is resolved
    (:func:`move_onset`). Where the process is
    so fast that a slip crosses the set point within one step, the step
    sees only the jump's two ends, and a move split evenly about the set
    point reads either way. Noise that is large against the swing leaves
    the share uncertain. An integrating process ramps away and back
    alike whatever its valve does; the share says nothing there.
    """
    e = np.asarray(error, dtype=float).ravel()
    h = float(sample_time)
    if not (np.isfinite(period) and period >= 2.0 * h) or e.size < 3:
        return float("nan")
    m = max(1, int(round(period / (AWAY_STEPS * h))))
    if e.size <= m:
        return float("nan")
    d = e[m:] - e[:-m]
    mid = 0.5 * (e[m:] + e[:-m])
    w = d * d
    kept = np.ones(d.size, bool)
    if sp is not None:
        s = np.asarray(sp, dtype=float).ravel()
        kept = s[m:] == s[:-m]
        w = np.where(kept, w, 0.0)
    # the white noise moves the error away and back alike: its share of the
    # squared moves (two variances a move) is taken out of both sums
    floor = 2.0 * white_noise_std(e) ** 2 * int(kept.sum())
    total = float(w.sum()) - floor
    if not total > 0.0 or not total > 0.1 * float(w.sum()):
        return float("nan")
    return float((w[np.sign(d) == np.sign(mid)].sum() - 0.5 * floor) / total)


def move_onset(error, sample_time: float, period: float, apex_idx, apex_sign,
               sp=None) -> float:
    """How gradually a self-regulating PV's swings start: its speed before its fastest point.

    Parameters
    ----------
    error : array_like, shape (n,)
        The PV about its set point or its cycle's centre [PV unit], one
        gap-free stretch.
    sample_time : float
        [s]
    period : float
        Oscillation period [s].
    apex_idx, apex_sign : array_like
        Apices of the PV (:func:`valvediag.analysis.oscillation.detect_oscillation`);
        each swing runs from one apex to the next of the other sign.
    sp : array_like, shape (n,), optional
        Set point [PV unit]: a swing over which it steps is left out (the
        step moves the PV by itself).

    Returns
    -------
    float
        The median over the swings of the PV's mean speed, the way it swings,
        over the :data:`ONSET_SHARE` of a period before its fastest point,
        over its mean speed over as long from that point on (speeds over
        steps of ``period / ONSET_STEPS``, at least a sample); about 0 where
        swings start at once, 1 where the PV gathers speed as gradually as it
        loses it. NaN for fewer than three swings read.

    Notes
    -----
    A sticky valve's slip is a step of the valve's position, and a process
    answers a step at once: the PV leaves its plateau at full speed (behind
    its dead time; a lag much shorter than the process's own rounds the
    start only over that lag) and then slows as it settles. Its speed before
    the fastest point is the plateau's, about nothing. A load that turns
    without a step (a triangle, a clipped or pure sine, an upstream level
    that fills and empties) moves the PV through the process's lag as well:
    the PV's speed changes as gradually as the load's, and is as high just
    before its fastest point as just after. The ratio reads that difference
    where the process's time constant is resolved at a sixth of the period;
    on a fast loop sampled coarsely (a flow at 10-20 samples a period, its
    time constant shorter than a sample) a load's turn starts the PV at once
    too, and the ratio reads low for both. A swing that the smoothed PV
    makes from a tenth to nine tenths of its way within two steps is a jump
    the step cannot resolve, and reads 0 (over 3,900 s cycles of a flow
    whose time constant is shorter than its 5 s samples, the smoothing's own
    symmetric ramp read 0.98). A square load steps the PV at once as a slip
    does (:func:`away_share` reads which way it pushes it).

    On the realistic benchmark's development seeds 1-2 (12 loops a class)
    and study seeds 10-16 (4 a class), as the classifier reads them (the
    cycles that reach this reading), the sticky temperature cycles (52)
    read 0.06-0.42 and the sticky flow cycles (52) 0.00-0.44; the disturbed
    temperature loops that reach it read 0.73-0.87 under triangles (6),
    0.88-1.85 under clipped sines (5) and 0.30-0.53 under square waves (3).
    Over a tenth of a period rather than a sixth, a sticky flow behind a lag
    of a twentieth of its period (one of the further study seeds 17-26) read
    0.93. Over more draws (development seeds 1-2 at 20 loops a class, study
    seeds 10-26 at 4), the sticky flow cycles (107) read 0.00-0.58, six of
    them above 0.44 (five with a compressed PV), and the sticky temperature
    cycles (106) 0.00-0.48. Six triangular loads on temperature loops whose
    PV was stored by exception read 0.52-0.82: the scan's limit
    (:data:`~valvediag.analysis.classify.ONSET_SMOOTH`, 0.7) leaves the two
    lowest to the valve signature, which reads them as sticky valves.

    It fails where a lag between valve and PV as long as a tenth of the
    period or more (a slow sensor, a mixing volume) rounds a slip's start,
    which then reads as a load's; and where noise large against the swing hides
    the plateau's stillness (the speeds are signed, so the noise adds no
    bias, only scatter, which the median over swings tempers). An
    integrating process turns a slip into a ramp that starts at once, and
    a loose valve's take-up into one that gathers speed; the ratio is not
    read there.
    """
    e = np.asarray(error, dtype=float).ravel()
    h = float(sample_time)
    ai = np.asarray(apex_idx, dtype=np.int64).ravel()
    sg = np.asarray(apex_sign, dtype=float).ravel()
    if not (np.isfinite(period) and period >= 2.0 * h) or ai.size < 4:
        return float("nan")
    m = max(1, int(round(period / (ONSET_STEPS * h))))
    d = max(1, int(round(ONSET_SHARE * period / h)))
    # the PV smoothed over a step, and its speed over a step [PV unit/step]
    cs = np.r_[0.0, np.cumsum(e)]
    y = (cs[m:] - cs[:-m]) / m                          # y[k]: mean of e[k:k+m]
    v = np.r_[y[m:] - y[:-m], np.zeros(m)]              # v[k]: y[k+m] - y[k]
    # each swing, from one apex to the next of the other sign, the way it goes
    turn = (sg[1:] != sg[:-1]) & (ai[1:] > ai[:-1] + 1)
    a0, a1 = ai[:-1][turn], ai[1:][turn]
    way = np.sign(e[a1] - e[a0])
    a1 = np.minimum(a1, v.size - m)
    keep = (way != 0) & (a1 > a0)
    if sp is not None:
        s = np.asarray(sp, dtype=float).ravel()
        steps = np.r_[0, np.cumsum(np.abs(np.diff(s)) > 0)]
        keep &= steps[np.minimum(a1 + 2 * m, s.size - 1)] == steps[a0]
    a0, a1, way = a0[keep], a1[keep], way[keep]
    if a0.size < 3:
        return float("nan")
    # the fastest point of each swing: the first sample of the swing at its
    # greatest speed the swing's way (sorted by swing, then by speed)
    lengths = a1 - a0
    seg = np.repeat(np.arange(a0.size), lengths)
    idx = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths) \
        + np.repeat(a0, lengths)
    speed = v[idx] * np.repeat(way, lengths)
    order = np.lexsort((-speed, seg))
    first = np.r_[0, np.flatnonzero(np.diff(seg[order])) + 1]
    top = idx[order][first]
    # a swing the smoothed PV makes from a tenth to nine tenths of its way
    # within two steps is a jump the step cannot resolve (a fast process
    # sampled coarsely): it starts at once, whatever the speeds around it say
    ends = np.r_[0, np.cumsum(lengths)]
    frac = (y[idx] - np.repeat(y[a0], lengths)) * np.repeat(way, lengths)
    frac /= np.repeat(np.maximum((y[a1 - 1] - y[a0]) * way, 1e-300), lengths)
    pos = np.arange(idx.size) - np.repeat(ends[:-1], lengths)
    never = np.iinfo(np.int64).max
    t10 = np.minimum.reduceat(np.where(frac >= 0.1, pos, never), ends[:-1])
    t90 = np.minimum.reduceat(np.where(frac >= 0.9, pos, never), ends[:-1])
    jump = (t90 < never) & (t90 - t10 <= 2 * m)
    ok = (top - d >= 0) & (top + d <= v.size)
    top, way, jump = top[ok], way[ok], jump[ok]
    if top.size < 3:
        return float("nan")
    cv = np.r_[0.0, np.cumsum(v)]
    before = (cv[top] - cv[top - d]) * way
    after = (cv[top + d] - cv[top]) * way
    good = (after > 0) | jump
    if int(good.sum()) < 3:
        return float("nan")
    ratio = np.where(jump, 0.0, before / np.where(after > 0, after, 1.0))
    return float(np.median(ratio[good]))
