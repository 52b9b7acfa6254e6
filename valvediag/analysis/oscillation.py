"""
Oscillation analysis: period, amplitude, regularity and cycle segmentation.

A record is split into half-cycles by crossings of a hysteresis band around
its baseline; the extreme of each half-cycle is an *apex* (a peak or a
valley). The period is the median spacing of like crossings, the regularity
follows Thornhill et al. (2003).

The compiled functions here are shared by the Backlash Index
(:mod:`valvediag.analysis.bi`), the one-loop classifier and the batch kernels that
reproduce Farenzena & Trierweiler (2012).

References
----------
.. [1] Thornhill, N. F., Huang, B., Zhang, H. (2003). Detection of multiple
   oscillations in control loops. Journal of Process Control 13, 91-100.
.. [2] Hägglund, T. (1995). A control-loop performance monitor. Control
   Engineering Practice 3, 1543-1551.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.fft import irfft, next_fast_len, rfft

from .quality import stored_points, white_noise_std
from .signature import SENSE_SKEW, controller_lag

__all__ = ["Oscillation", "detect_oscillation", "acf_period", "acf_regularity",
           "regular_oscillation", "PhaseWander", "phase_wander", "pooled_phase_wander"]

#: Hysteresis band as a fraction of the half peak-to-peak range.
BAND_FRACTION = 0.2
#: A regular oscillation's mean cycle holds at least this share of the record's variance.
PERIODIC_FRACTION_MIN = 0.4
#: The ACF at its period is strong above this ...
ACF_STRONG = 0.3
#: The ACF's zero crossings are read across a band of this half width about
#: zero (:func:`acf_regularity`) [-, of the ACF at lag 0].
ACF_CROSSING_BAND = 0.05
#: Fewest upward crossings, in one run of like cycles, from which a phase's wander is read.
MIN_CROSSINGS = 40
#: At or below this wander (the crossing times' scatter about a steady clock
#: over the periods' variance: 1/2 for a clock read through jitter, about
#: n/15 for a phase that random-walks over n cycles) the oscillation keeps
#: time like a clock.
CLOCK_WANDER = 0.75
#: ... or at most this share of a random walk's ``n / 15`` over ``n``
#: crossings: a clock read through a slowly varying error (the sample grid
#: beating against the period) scatters more than 1/2, but does not grow.
CLOCK_SHARE = 0.1
#: Over fewer crossings than :data:`MIN_CROSSINGS`, periods are steady where
#: they vary at most this many times as much as the PV's white noise alone
#: makes a steady clock's periods read (:func:`phase_wander`): about 1 for a
#: clock, 2 and more for a limit cycle whose phase the noise moves.
CLOCK_JITTER = 1.5
#: ... read over at least this many crossings (four periods),
MIN_JITTER_CROSSINGS = 5
#: ... and beside the noise's reading, a clock's tick placed anywhere within
#: this share of a sample [samples]: a load moves at the control system's
#: scan, and the historian stamps each sample at its poll, whatever the noise.
#: Half a sample: a controller that runs at twice its record's rate, as the
#: realistic benchmark's do; a whole sample's spread read two sticky flow
#: cycles of its study seeds 17-26 at 1.32 and 1.37.
TICK_WIDTH = 0.5
#: ... where the smoothed PV takes at least this many samples to cross its
#: hysteresis band [samples]: a crossing read between two samples either side
#: of a jump places it by the noise alone, whatever the jump's own timing.
CROSSING_SAMPLES = 2.0
#: Least standard deviation of the periods [samples]: steadier periods
#: carry no noise to read.
MIN_JITTER = 0.01
#: Least timing noise at a crossing [samples] (the PV's white noise over its
#: slope there) for the wander to be read: a noise-free limit cycle keeps time
#: too, since nothing moves its phase.
MIN_TIMING_NOISE = 0.02
#: A tag that keeps fewer than this share of its samples was stored by
#: exception: its noise is gone.
STORED_SHARE = 0.7
#: Least correlation of the OP's answer to the PV's noise (second
#: differences, moves beyond the noise left out) that shows the noise enters
#: the loop: a controller that answers its measurement reads 0.3-1 on the
#: realistic benchmark's raw records; a smooth swing that both tags share
#: correlates by about 0.05 at every lag.
NOISE_ANSWER = 0.2
#: ... and then band crossings this much faster than that period are noise's,
NOISE_CROSSINGS = 1.0 / 3.0
#: and the band is widened to this many standard deviations of the white noise,
BAND_NOISE = 4.0
#: where the cycles then found span at most this share of the record,
PART_TIME = 0.75
#: or where their period is the ACF's to within this share of it and they
#: swing by at least this many standard deviations of the white noise
#: (their median half peak-to-peak).
ACF_AGREES = 0.1
SWING_NOISE = 10.0


@numba.njit(cache=True, nogil=True)
def linear_detrend(x):
    """``x`` minus its least-squares straight line (compiled; shared by the BI kernels)."""
    n = x.size
    tm = 0.5 * (n - 1)
    xm = x.mean()
    num = 0.0
    den = 0.0
    for i in range(n):
        num += (i - tm) * (x[i] - xm)
        den += (i - tm) * (i - tm)
    slope = num / den if den > 0 else 0.0
    y = np.empty(n)
    for i in range(n):
        y[i] = x[i] - xm - slope * (i - tm)
    return y


@numba.njit(cache=True, nogil=True)
def _baseline(x, L):
    """Centred moving average over ``L`` samples, extrapolated linearly at the
    ends (a moving average over exactly one period removes the oscillation and
    keeps the drift)."""
    n = x.size
    b = np.empty(n)
    if L < 2 or L >= n:
        m = x.mean()
        for i in range(n):
            b[i] = m
        return b
    c = np.empty(n + 1)
    c[0] = 0.0
    for i in range(n):
        c[i + 1] = c[i] + x[i]
    lo = L // 2
    hi = n - (L - lo)
    for i in range(lo, hi + 1):
        b[i] = (c[i - lo + L] - c[i - lo]) / L
    # linear extrapolation from the first / last quarter period of full windows
    k = max(1, L // 4)
    k = min(k, max(1, (hi - lo) // 2))
    s0 = (b[lo + k] - b[lo]) / k if hi - lo >= k else 0.0
    s1 = (b[hi] - b[hi - k]) / k if hi - lo >= k else 0.0
    for i in range(lo):
        b[i] = b[lo] - s0 * (lo - i)
    for i in range(hi + 1, n):
        b[i] = b[hi] + s1 * (i - hi)
    return b


@numba.njit(cache=True, nogil=True)
def _half_range(y):
    """Half of the 3-97 % quantile range: a noise-robust amplitude.

    Long records are strided to at most ~1024 values, and the two order
    statistics are found by selection rather than sorting (this runs once per
    record in the grid kernels)."""
    stride = max(1, y.size // 1024)
    ys = y[::stride].copy()
    m = ys.size
    k1 = int(0.03 * (m - 1))
    k2 = int(0.97 * (m - 1))
    lo = np.partition(ys, k1)[k1]
    hi = np.partition(ys, k2)[k2]
    return 0.5 * (hi - lo)


@numba.njit(cache=True, nogil=True)
def hysteresis_runs(y, band):
    """Start index and sign of each run beyond the hysteresis band."""
    n = y.size
    starts = np.empty(n, dtype=np.int64)
    signs = np.empty(n, dtype=np.int64)
    m = 0
    state = 0
    for i in range(n):
        if y[i] > band and state != 1:
            state = 1
            starts[m] = i
            signs[m] = 1
            m += 1
        elif y[i] < -band and state != -1:
            state = -1
            starts[m] = i
            signs[m] = -1
            m += 1
    return starts[:m], signs[:m]


@numba.njit(cache=True, nogil=True)
def run_apices(y, starts, signs):
    """Index of the extreme of every complete run (between two run starts).

    A run is complete when the signal entered it from the opposite side of the
    band; the first run may have started before the record, so its extreme is
    kept only if it is not at the record's first sample."""
    m = starts.size
    idx = np.empty(max(m - 1, 0), dtype=np.int64)
    sg = np.empty(max(m - 1, 0), dtype=np.int64)
    k = 0
    for j in range(m - 1):
        a = starts[j]
        b = starts[j + 1]
        s = signs[j]
        best = a
        for i in range(a, b):
            if s * y[i] > s * y[best]:
                best = i
        if j == 0 and best == 0:
            continue
        idx[k] = best
        sg[k] = s
        k += 1
    return idx[:k], sg[:k]


@numba.njit(cache=True, nogil=True)
def _cycle_durations(starts, signs):
    """Full-cycle durations between like band crossings [samples]."""
    m = starts.size
    out = np.empty(max(m - 2, 0))
    k = 0
    for j in range(m - 2):
        if signs[j + 2] == signs[j]:
            out[k] = starts[j + 2] - starts[j]
            k += 1
    return out[:k]


@numba.njit(cache=True, nogil=True)
def segment_cycles(x, period_hint, remove_drift, band_floor=0.0):
    """Split a record into half-cycles.

    Parameters
    ----------
    x : float64 array
        Uniformly sampled signal (no NaN).
    period_hint : float
        Period [samples] if known (> 1), else 0.
    remove_drift : bool
        Subtract a one-period moving average (True) or only the mean (False,
        the literal reading of the paper).
    band_floor : float
        Least hysteresis half-width [PV unit].

    Returns
    -------
    y : array
        Signal minus baseline.
    apex_idx, apex_sign : int arrays
        Apex indices and +1 (peak) / -1 (valley).
    period : float
        Median full-cycle duration [samples]; NaN if fewer than 2 cycles.
    durations : array
        All full-cycle durations [samples].
    band : float
        Hysteresis half-width used [PV unit].
    """
    n = x.size
    if remove_drift:
        y = linear_detrend(x)
    else:
        y = x - x.mean()
    P = period_hint
    if remove_drift:
        if P <= 1.0:
            band = BAND_FRACTION * _half_range(y)
            st, sg = hysteresis_runs(y, band)
            d = _cycle_durations(st, sg)
            if d.size > 0:
                P = np.median(d)
        if P > 1.0 and P < n:
            y = x - _baseline(x, int(round(P)))
    band = max(BAND_FRACTION * _half_range(y), band_floor)
    st, sg = hysteresis_runs(y, band)
    d = _cycle_durations(st, sg)
    period = np.median(d) if d.size > 0 else np.nan
    ai, asg = run_apices(y, st, sg)
    return y, ai, asg, period, d, band


def acf_period(x, max_lag=None):
    """Dominant period of a record from its autocorrelation function.

    Parameters
    ----------
    x : array_like
        Uniformly sampled signal.
    max_lag : int, optional
        Longest lag searched [samples]; default half the record.

    Returns
    -------
    period : float
        Lag of the first ACF maximum after its first zero crossing [samples],
        refined by a parabola; NaN if the ACF never crosses zero, or only
        falls after it (no maximum within ``max_lag``).
    acf_at_period : float
        The ACF value there (close to 1 for a clean periodic signal).
    """
    y = np.asarray(x, dtype=float)
    y = y - y.mean()
    n = y.size
    if n < 8 or not np.any(y):
        return np.nan, 0.0
    m = next_fast_len(2 * n, real=True)   # awkward lengths make the FFT 10-30x slower
    f = rfft(y, m)
    ac = irfft(f * np.conj(f), m)[:n]
    ac /= ac[0]
    max_lag = n // 2 if max_lag is None else min(int(max_lag), n - 2)
    neg = np.flatnonzero(ac[:max_lag] < 0)
    if neg.size == 0:
        return np.nan, 0.0
    z = neg[0]
    if z + 1 >= max_lag:
        return np.nan, 0.0
    k = z + int(np.argmax(ac[z:max_lag]))
    if k == z:
        # the ACF only falls after its zero crossing: no maximum, no period
        return np.nan, 0.0
    d = 0.0
    if 0 < k < n - 1:
        # refine only a maximum: where the search range holds none (an ACF
        # that falls straight through zero, as a drifting record's does) the
        # parabola through the edge is flat or convex and its vertex lies
        # anywhere, at negative lags too
        a, b, c = ac[k - 1], ac[k], ac[k + 1]
        den = a - 2 * b + c
        if den < 0 and b >= a and b >= c:
            d = 0.5 * (a - c) / den
    return float(k + d), float(ac[k])


def acf_regularity(x, max_crossings: int = 12, band: float = ACF_CROSSING_BAND,
                   period: float | None = None):
    """Regularity of an oscillation from the zero crossings of its ACF.

    Parameters
    ----------
    x : array_like
        Uniformly sampled signal without drift.
    max_crossings : int
        Zero crossings of the ACF used (Thornhill et al. use about ten).
    band : float
        A crossing counts where the ACF passes from beyond ``+band`` to
        beyond ``-band`` or back [-, of the ACF at lag 0]. The larger of
        that reading and the one at every zero crossing (Thornhill et
        al.'s) is returned; ``band=0`` reads theirs alone.
    period : float, optional
        The ACF's period [samples] (:func:`acf_period`): where given, the
        crossings end where the ACF stays inside the band for longer.

    Returns
    -------
    regularity : float
        ``mean(T) / (3 std(T))`` of the periods ``T`` between every other
        zero crossing of the autocorrelation function; above 1 means regular
        (Thornhill et al. 2003). Inf when all periods are equal, 0 when fewer
        than three crossings exist.

    Notes
    -----
    The ACF averages over the whole record, so an oscillation whose amplitude
    wanders (a disturbance exciting a lightly damped loop) still shows regular
    crossings, where crossings of the signal itself would be missed in the
    low-amplitude cycles.

    The ACF of a waveform that rests between its swings (a level that
    settles at its set point after each step of a pump's load) lingers about
    zero for a share of each period, and its noise crosses zero there
    several times. Read at every zero crossing, every other crossing is then
    not half a period on, and such a cycle read as irregular (Thornhill's
    regularity 0.1-0.9 on the realistic benchmark's slow loads, whose mean
    cycle holds 0.9 of their variance). Across the band the lingering counts
    once, timed at the ACF's last zero crossing before it leaves the band, so
    a sine reads as it does without the band. Across a band the crossings of
    an ACF that decays run out within a few periods (a load whose period
    wanders by a fifth reads 0.3 at a band of 0.1 and 2.4 at 0.05, and the
    ACF of a noise-driven resonance that halves every half period leaves a
    band of 0.05 only a few times): where it has decayed into the band
    and stays there for longer than a period, the band's crossings end (its
    noise at far lags is no crossing of the oscillation's), and the
    regularity is the larger of the two readings, at every zero crossing
    and across the band. Neither reads a regularity into noise, whose ACF
    crosses zero at random or not at all.

    References
    ----------
    .. [1] Thornhill, N. F., Huang, B. and Zhang, H. (2003). Detection of
       multiple oscillations in control loops. Journal of Process Control
       13(1), 91-100.
    """
    y = np.asarray(x, dtype=float)
    y = y - y.mean()
    n = y.size
    if n < 8 or not np.any(y):
        return 0.0
    m = next_fast_len(2 * n, real=True)
    f = rfft(y, m)
    ac = irfft(f * np.conj(f), m)[: n // 2]
    ac /= ac[0]
    sgn = np.signbit(ac)
    zc = np.flatnonzero(sgn[1:] != sgn[:-1])
    # the side of the band the ACF was last beyond, carried through the band
    state = np.where(ac > band, 1, np.where(ac < -band, -1, 0))
    last = np.where(state != 0, np.arange(ac.size), 0)
    np.maximum.accumulate(last, out=last)
    side = state[last]
    leave = np.flatnonzero((side[1:] != side[:-1]) & (side[:-1] != 0)) + 1
    # an ACF that decays into the band stays there: its noise may leave the
    # band again far later, which is no crossing of the oscillation's. Read up
    # to the first stay inside the band longer than a period
    if period is not None and np.isfinite(period) and period > 0:
        stay = np.flatnonzero(np.diff(leave) > period)
        if stay.size:
            leave = leave[:stay[0] + 1]
    # each crossing timed at the ACF's last zero crossing before it left the band
    at = np.searchsorted(zc, leave) - 1
    best = 0.0
    for idx in (zc[:max_crossings], zc[at[at >= 0]][:max_crossings]):
        if idx.size < 3:
            continue
        z = idx + ac[idx] / (ac[idx] - ac[idx + 1])      # sub-sample crossing lags
        T = z[2:] - z[:-2]
        sd = np.std(T)
        best = max(best, float(np.inf if sd == 0 else np.mean(T) / (3 * sd)))
    return best


@dataclass(frozen=True)
class Oscillation:
    """Summary of the oscillation in one record.

    Attributes
    ----------
    period : float
        Median cycle duration [s]; NaN when fewer than two cycles were seen.
    amplitude : float
        Median half peak-to-peak amplitude [PV unit].
    cycles : float
        Number of complete cycles (half the number of apices minus one).
    regularity : float
        Thornhill's regularity ``mean(T) / (3 std(T))`` of the periods
        between zero crossings of the autocorrelation function; above 1 means
        a regular oscillation.
    acf_at_period : float
        Autocorrelation at one period lag (1 for a clean periodic signal).
    periodic_fraction : float
        Share of the detrended variance explained by the mean cycle shape.
    apex_idx, apex_sign : numpy.ndarray
        Apex sample indices and +1 (peak) / -1 (valley).
    baseline_removed : numpy.ndarray
        The record minus its drift [PV unit].
    sample_time : float
        [s]
    acf_period : float
        Lag of the autocorrelation function's first maximum after its first
        zero crossing [s]; NaN where it has none.
    """

    period: float
    amplitude: float
    cycles: float
    regularity: float
    acf_at_period: float
    periodic_fraction: float
    apex_idx: np.ndarray
    apex_sign: np.ndarray
    baseline_removed: np.ndarray
    sample_time: float
    acf_period: float = float("nan")

    @property
    def samples_per_period(self) -> float:
        return self.period / self.sample_time

    @property
    def amplitude_variation(self) -> float:
        """Coefficient of variation of the half-cycle swings [-]; NaN under three cycles.

        Each swing is the difference of two successive apices, each the mean
        of the drift-free record over a twentieth of the period about it (so
        that the noise which made a sample the extreme does not count). A
        valve's limit cycle keeps its amplitude (the nonlinearity sets it:
        a few percent here); a linear loop ringing under a random load has
        the wandering envelope of narrow-band noise (about 0.5).
        """
        ai = np.asarray(self.apex_idx)
        if ai.size < 7 or not (np.isfinite(self.period) and self.period > 0):
            return float("nan")
        x = self.baseline_removed
        q = max(1, int(self.period / self.sample_time / 40))
        cs = np.r_[0.0, np.cumsum(x)]
        lo, hi = np.maximum(ai - q, 0), np.minimum(ai + q + 1, x.size)
        v = (cs[hi] - cs[lo]) / (hi - lo)
        swing = np.abs(np.diff(v))
        m = float(swing.mean())
        return float(swing.std() / m) if m > 0 else float("nan")

    @property
    def is_regular(self) -> bool:
        """Regular oscillation: Thornhill regularity > 1, strong ACF and shape
        (:func:`regular_oscillation`)."""
        return regular_oscillation(self.cycles, self.regularity, self.acf_at_period,
                                   self.periodic_fraction)

    def plot(self, ax=None):
        """Plot the detrended record with its apices marked."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(9, 3))
        t = np.arange(self.baseline_removed.size) * self.sample_time
        ax.plot(t, self.baseline_removed, lw=0.8, color="C0")
        pk = self.apex_idx[self.apex_sign > 0]
        vl = self.apex_idx[self.apex_sign < 0]
        ax.plot(t[pk], self.baseline_removed[pk], "v", color="C3", ms=4, label="peaks")
        ax.plot(t[vl], self.baseline_removed[vl], "^", color="C2", ms=4, label="valleys")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("PV minus drift")
        ax.set_title(f"period {self.period:.4g} s, regularity {self.regularity:.2f}, "
                     f"{self.cycles:.1f} cycles")
        ax.legend(fontsize=8, loc="upper right")
        return ax


def resample_cycles(signals, apex_idx, apex_sign, nbins: int):
    """Resample every valley-to-valley cycle to ``nbins`` phase points.

    Parameters
    ----------
    signals : sequence of array_like
        Signals sampled like the record whose apices are given [any unit].
    apex_idx, apex_sign : array_like
        Apex sample indices and +1 (peak) / -1 (valley).
    nbins : int
        Phase points per cycle, at phases ``k / nbins``, ``k = 0 .. nbins-1``.

    Returns
    -------
    list of numpy.ndarray, shape (n_cycles, nbins)
        One matrix per signal; a cycle shorter than 3 samples is skipped.

    Notes
    -----
    Row ``i`` equals ``np.interp(phase, (j - a) / (b - a), s[a:b + 1])`` for
    cycle ``[a, b]``, bit for bit: the same bracketing sample, slope and
    formula as NumPy's ``interp``, in one compiled pass instead of one call
    per cycle. The signals must be finite on the cycles (no NaN fallback).
    """
    apex_idx = np.asarray(apex_idx)
    vl = apex_idx[np.asarray(apex_sign) < 0].astype(np.int64)
    a, b = vl[:-1], vl[1:]
    keep = b - a >= 3
    a, m = a[keep], (b - a)[keep]
    if a.size == 0:
        return [np.empty((0, nbins)) for _ in signals]
    phase = np.linspace(0.0, 1.0, nbins, endpoint=False)
    return [_resample_kernel(np.ascontiguousarray(s, dtype=float), a, m, phase)
            for s in signals]


@numba.njit(cache=True, nogil=True)
def _resample_kernel(s, a, m, phase):
    """``out[i, q] = np.interp(phase[q], (j - a_i) / m_i, s[a_i : a_i + m_i + 1])``."""
    out = np.empty((a.size, phase.size))
    for i in range(a.size):
        k = a[i]
        mi = m[i]
        mf = float(mi)
        for q in range(phase.size):
            x = phase[q]
            # the bracketing sample as NumPy's binary search finds it:
            # j/m <= x < (j+1)/m
            j = min(int(x * mf), mi - 1)
            if j / mf > x:
                j -= 1
            elif (j + 1) / mf <= x:
                j += 1
            xj = j / mf
            fj = s[k + j]
            if xj == x:
                out[i, q] = fj
            else:
                slope = (s[k + j + 1] - fj) / ((j + 1) / mf - xj)
                out[i, q] = slope * (x - xj) + fj
    return out


def turned_cycles(y, apex_idx, apex_sign, nbins: int) -> np.ndarray:
    """The cycles of ``y`` cut from peak to peak and turned over, each
    resampled to ``nbins`` phase points.

    Parameters
    ----------
    y : array_like
        Record [any unit].
    apex_idx, apex_sign : array_like
        Its apices: sample indices and +1 (peak) / -1 (valley).
    nbins : int
        Phase points per cycle.

    Returns
    -------
    numpy.ndarray, shape (n_cycles, nbins)
        :func:`resample_cycles` of ``-y`` (its valleys are ``y``'s peaks):
        like the valley-to-valley cycles, each runs from a low apex through
        a high one and back.

    Notes
    -----
    A cut aligns the apex it starts and ends at: that apex stays sharp in
    the mean cycle, and the other is smeared by the cycles' jitter. A figure
    read from the valley-to-valley cut alone reads a record and its mirror
    image (a reverse-acting loop's, whose PV falls as its OP rises) apart;
    read from both cuts, it does not.
    """
    return resample_cycles([-np.asarray(y, dtype=float)], apex_idx, -np.asarray(apex_sign),
                           nbins)[0]


def _periodic_fraction(y, apex_idx, apex_sign, nbins=32):
    """Variance share of the mean cycle (each cycle resampled to ``nbins``
    phase points), the cycles cut from valley to valley and from peak to peak
    pooled (:func:`turned_cycles`)."""
    tot = res = 0.0
    for C in (resample_cycles([y], apex_idx, apex_sign, nbins)[0],
              turned_cycles(y, apex_idx, apex_sign, nbins)):
        if C.shape[0] >= 2:
            tot += C.var() * C.size
            res += ((C - C.mean(axis=0)) ** 2).sum()
    return float(max(0.0, 1.0 - res / tot)) if tot > 0 else 0.0



def regular_oscillation(cycles, regularity, acf_at_period, periodic_fraction) -> bool:
    """Is an oscillation so described regular?

    Parameters
    ----------
    cycles : float
        Cycles in the record [-].
    regularity : float
        Thornhill's regularity [-].
    acf_at_period : float
        Autocorrelation at one period [-].
    periodic_fraction : float
        Share of the record's variance that the mean cycle holds [-].

    Returns
    -------
    bool
        At least two cycles, regularity above 1, the autocorrelation above
        :data:`ACF_STRONG` and the mean cycle's share above
        :data:`PERIODIC_FRACTION_MIN`; False where a figure is missing or NaN
        (a verdict's evidence kept in a store may lack them). An infinite
        regularity (every crossing interval alike) is regular.
    """
    vals = (cycles, regularity, acf_at_period, periodic_fraction)
    if any(v is None or np.isnan(v) for v in vals):
        return False
    return bool(cycles >= 2 and regularity > 1.0 and acf_at_period > ACF_STRONG
                and periodic_fraction > PERIODIC_FRACTION_MIN)


@dataclass(frozen=True)
class PhaseWander:
    """Whether an oscillation keeps time like a clock or wanders as a limit cycle does.

    Attributes
    ----------
    keeps_clock : bool
        The crossing times scatter about a steady clock without drifting
        from it (:func:`phase_wander`): a periodic disturbance from outside
        the loop, not the loop's own limit cycle.
    reason : str
        One sentence.
    crossings : int
        Upward crossings read, in the longest run of like cycles.
    wander : float
        Variance of the crossing times about the best steady clock over the
        variance of the periods [-]: 1/2 for a clock read through jitter, about
        ``crossings / 15`` for a phase that random-walks; NaN where not read.
    jitter : float
        Standard deviation of the periods [s].
    timing_noise : float
        The PV's white noise over its median slope at the crossings [s].
    jitter_ratio : float
        Over fewer crossings than :data:`MIN_CROSSINGS`, the standard
        deviation of the periods over that of a steady clock's periods read
        through the PV's white noise and the time grid
        (:data:`TICK_WIDTH`) [-]: about 1 for a clock; NaN where not read.
    times : numpy.ndarray
        Crossing times [s from the record's start].
    readable : bool
        The noise moves a limit cycle's phase here (enough timing noise and
        jitter, and the OP answers the PV's noise): the crossings read, too
        few alone, may be pooled with other stretches'
        (:func:`pooled_phase_wander`).
    cycle : numpy.ndarray
        Cycle number of each crossing time; empty where they follow one
        another (a stretch without gaps).
    """

    keeps_clock: bool
    reason: str
    crossings: int = 0
    wander: float = float("nan")
    jitter: float = float("nan")
    timing_noise: float = float("nan")
    jitter_ratio: float = float("nan")
    times: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    readable: bool = False
    cycle: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    @property
    def steady_periods(self) -> bool:
        """Over fewer crossings than a wander is read from, the periods vary
        at most :data:`CLOCK_JITTER` times as much as a steady clock's read
        through the PV's noise and the time grid (``jitter_ratio``)."""
        return bool(np.isfinite(self.jitter_ratio) and self.jitter_ratio <= CLOCK_JITTER)

    def as_dict(self) -> dict:
        """The figures as plain types."""
        def r(v, d):
            return round(float(v), d) if np.isfinite(v) else None
        return {"keeps_clock": self.keeps_clock, "crossings": self.crossings,
                "wander": r(self.wander, 3), "jitter_s": r(self.jitter, 4),
                "timing_noise_s": r(self.timing_noise, 4),
                "jitter_ratio": r(self.jitter_ratio, 3)}

    def departures(self) -> np.ndarray:
        """Each crossing's time less the best steady clock's (least squares) [s].

        Empty where fewer than three crossings were read.
        """
        t = np.asarray(self.times, dtype=float)
        if t.size < 3:
            return np.zeros(0)
        k = self._cycles()
        return t - np.polyval(np.polyfit(k, t, 1), k)

    def _cycles(self) -> np.ndarray:
        return np.asarray(self.cycle, dtype=float) if np.size(self.cycle) else \
            np.arange(np.size(self.times), dtype=float)

    def plot(self, ax=None):
        """The crossings' departure from the best steady clock against the cycle count.

        A clock's departures scatter in a band; a limit cycle's wander off
        as a random walk.

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(9, 3))
        dev = self.departures()
        if dev.size:
            ax.plot(self._cycles(), dev, ".-", lw=0.6, ms=3, color="C0")
            ax.axhline(0.0, color="0.5", lw=0.6)
        ax.set_xlabel("cycle")
        ax.set_ylabel("crossing minus steady clock [s]")
        ax.set_title(self.reason, fontsize=8)
        return ax


def phase_wander(pv, osc: Oscillation, op=None) -> PhaseWander:
    """Read whether an oscillation keeps time like a clock: a disturbance from outside the loop.

    Parameters
    ----------
    pv : array_like, shape (n,)
        The record as :func:`detect_oscillation` read it (its white noise is
        read from it) [PV unit].
    osc : Oscillation
        Its oscillation (:func:`detect_oscillation`).
    op : array_like, shape (n,), optional
        The controller's output over the same samples [OP unit]. Where given,
        the wander is read only where the OP answers the PV's noise (a
        correlation of at least :data:`NOISE_ANSWER`, moves beyond the
        noise's left out:
        :func:`~valvediag.analysis.signature.controller_lag`): noise that
        never enters the loop moves no limit cycle's phase. Where the PV was
        stored by exception (it keeps fewer than :data:`STORED_SHARE` of its
        samples) its noise is gone and the answer cannot be read; a plant's
        controller answers its measurement, and the wander is read.

    Returns
    -------
    PhaseWander

    Notes
    -----
    A valve's limit cycle is the loop's own, self-sustained oscillation: no
    clock holds its phase, so the noise that the controller answers jitters
    each slip or turn and shifts all later cycles with it, and its phase
    wanders as a random walk (phase diffusion, [1]_). A load that a clock
    drives from outside the loop (a timer, a machine's cycle, a batch step)
    keeps its phase: each cycle is read a little early or late, but the
    error does not carry over. With
    ``t_k`` the upward crossings of the drift-free record (smoothed over a
    twelfth of the period; the crossing between samples interpolated), the
    ratio of the variance of ``t_k`` about the best straight line in ``k``
    to the variance of the periods ``t_{k+1} - t_k`` is 1/2 for a clock read
    through jitter and grows as ``n / 15`` over ``n`` cycles of a random walk
    (a variance-ratio test, [2]_). The oscillation keeps time where it is at
    most :data:`CLOCK_WANDER`, or at most :data:`CLOCK_SHARE` of ``n / 15``
    (an error that varies slowly but does not grow), over
    :data:`MIN_CROSSINGS` crossings or more, read in the longest run of
    periods within 40 % of their median.

    Forty crossings keep a pure random walk from reading 0.75 or less but
    about once in 240 records (once in 7 at 20 crossings), and a clock
    read through white jitter from reading more about once in 170
    (simulated, 20,000 records each). On the realistic benchmark's study seeds
    10-16 (8 loops a class) the wander was read on 94 of the 112 healthy
    valves under periodic loads: 0.35-1.47, 3 above 0.75 (two of them, over
    2,000 crossings, under 0.01 of ``n / 15``); and on 145 sticky and loose
    valves' cycles and ringing loops: 1.12 and up, and at least 0.18 of
    ``n / 15``.

    The reading assumes that the noise moves a limit cycle's phase, each
    cycle, by about as much as it jitters the crossings, as it does where
    the same noise that the controller answers makes the slip or turn come
    early or late: a limit cycle whose phase hardly moves against its
    crossings' jitter reads as a clock over a few tens of cycles.

    :func:`~valvediag.analysis.classify.classify_loop` reads a swing that
    keeps a clock's time as a load from outside the loop
    (``linear-oscillation``). That stands on the noise going round the loop,
    as it does on a plant. A simulation that adds the noise to a limit
    cycle's record afterwards keeps perfect time and reads as a load: the
    synthetic plant did so until its faulty loops took their noise into the
    loop, and on 1,000 of its loop-days 110 of its 146 loose valves and 13
    sticky ones then read as loads.

    It says nothing where the oscillation wanders: a load from another
    loop's limit cycle wanders too. A loop entrained by a periodic load
    keeps its clock whatever its valve does. A noise-free record keeps time
    whatever makes it swing, since nothing moves its phase: the reading needs
    the PV's white noise over its slope at the crossings to be at least
    :data:`MIN_TIMING_NOISE` of a sample, the periods to vary by at least
    :data:`MIN_JITTER` of a sample, and, where the OP is given, the OP
    to answer that noise (a simulation with noise added to the PV afterwards
    has a limit cycle that keeps time).

    Fewer crossings than :data:`MIN_CROSSINGS` (a short snapshot, or a slow
    swing over a day) hold too few cycles for a random walk to show, and the
    wander is not read. Their periods are read instead against the noise
    and the time grid (``jitter_ratio``, ``steady_periods``): smoothed over ``w``
    samples, the PV's white noise ``sigma`` reads each crossing of a steady
    clock within ``sigma / (sqrt(w) s)`` samples, ``s`` the smoothed slope
    there. Beside the noise, a clock's tick falls anywhere within
    :data:`TICK_WIDTH` of a sample (a uniform spread of ``TICK_WIDTH /
    sqrt(12)``): a load moves at the control system's scan, and a historian
    stamps each sample at its poll, whatever the noise; a square load at 2 s
    whose moves fell on its simulation's steps of 1 s (study seed 11, #2)
    read 2.10 by the noise alone, 0.97 with the spread. The periods, each
    between two such readings, vary by ``sqrt(2)`` times their combined
    spread. A limit cycle's periods vary more: the same
    noise, through the controller's proportional action, moves the OP's
    approach to each slip or turn, by a time that the smoothing does not
    shorten. The ratio of the two is read over :data:`MIN_JITTER_CROSSINGS`
    crossings or more, on the same terms as the wander, and not on a PV
    stored by exception, whose noise is gone. Nor where the PV crosses its
    hysteresis band in fewer than :data:`CROSSING_SAMPLES` samples (a fast
    loop's jump, or a coarse export of it): the samples either side of the
    jump then place the crossing by the noise alone, and a slip's timing
    within the sample does not show. Kept at one sample in 30 s (study seeds
    10-16, 4 a class), seven sticky flow and temperature cycles read 0.28-1.39
    there, crossing their band in 0.4-1.5 samples. Noise that is not white (a
    transmitter's damping) reads a steady clock as more than 1; so does a
    load whose own timing varies. A record whose noise, and the OP's answer
    to it, were added after its simulation (the paper's experiment as
    :func:`valvediag.paper.scenarios.record` draws it) keeps a clock's time
    whatever its valve does: 8 of 12 sticky and 12 of 12 loose valves' cycles
    drawn from the paper's ranges, at 20 samples a period, read 0.3-1 by the
    noise alone.
    :func:`~valvediag.analysis.classify.classify_loop` reads steady periods
    as a load's on self-regulating loops, where the valve signature cannot
    tell a periodic load from a sticky valve. On the realistic benchmark's
    development seeds 1-2 (20 loops a class) and study seeds 10-26 (4 a
    class), the sticky and loose valves' limit cycles on self-regulating
    loops read 1.81 and up (68 read) but for one sticky flow at 1.21 that
    the valve signature read as linear too, on levels 1.34 and up (126);
    the healthy flows and temperatures under periodic loads 0.28 and up,
    44 of the 49 read at most 1.5; the 15 loads that the valve methods had
    called faulty (slow loads on levels of no known type, read as
    self-regulating, among them) read 0.39-1.37.

    References
    ----------
    .. [1] Pikovsky, A., Rosenblum, M., Kurths, J. (2001). Synchronization: a
       universal concept in nonlinear sciences. Cambridge University Press,
       ch. 9 (phase diffusion of a noisy self-sustained oscillator).
    .. [2] Lo, A. W., MacKinlay, A. C. (1988). Stock market prices do not follow
       random walks: evidence from a simple specification test. Review of
       Financial Studies 1, 41-66.
    """
    h = float(osc.sample_time)
    x = np.asarray(pv, dtype=float)
    y = np.asarray(osc.baseline_removed, dtype=float)
    P = osc.period / h if np.isfinite(osc.period) else np.nan
    if not (np.isfinite(P) and P >= 6 and y.size >= 3 * P):
        return PhaseWander(False, "no period to read the phase's wander at")
    w = max(1, int(P / 12))
    ys = np.convolve(y, np.ones(w) / w, mode="same") if w > 1 else y
    band = BAND_FRACTION * _half_range(ys)
    st, sg = hysteresis_runs(ys, band)
    enter = st[1:][(sg[1:] > 0) & (sg[:-1] < 0)]                  # runs above from below
    prev = st[:-1][(sg[1:] > 0) & (sg[:-1] < 0)]
    up = np.flatnonzero((ys[:-1] < 0) & (ys[1:] >= 0)) + 1       # first sample at or above 0
    k = np.zeros(0, np.int64)
    if up.size:
        j = np.searchsorted(up, enter, side="right") - 1
        k = up[j[(j >= 0) & (up[np.maximum(j, 0)] > prev)]]
    few = (f"{k.size} upward crossings, fewer than {MIN_CROSSINGS}: too few to read the "
           "phase's wander")
    if k.size < 3:
        return PhaseWander(False, few, crossings=int(k.size))
    a, b = ys[k - 1], ys[k]
    t = (k - 1) + a / (a - b)                                     # [samples]
    slope = float(np.median(b - a))
    d = np.diff(t)
    like = np.abs(d / np.median(d) - 1.0) <= 0.4
    if not like.any():
        return PhaseWander(False, few if k.size < MIN_CROSSINGS else
                           "no two periods alike: no clock to read", crossings=int(k.size))
    # the longest run of like periods: a missed or extra crossing is no wander
    edges = np.flatnonzero(np.diff(np.r_[0, like.astype(np.int8), 0]))
    s0, s1 = edges[::2], edges[1::2]
    i = int(np.argmax(s1 - s0))
    t = t[s0[i]:s1[i] + 1]
    n = int(t.size)
    noise = white_noise_std(x)
    q = noise / slope if slope > 0 else np.inf
    d = np.diff(t)
    common = dict(crossings=n, jitter=float(np.std(d)) * h if d.size else np.nan,
                  timing_noise=q * h, times=t * h)
    unread = None
    by_exception = stored_points(x).size < STORED_SHARE * np.count_nonzero(np.isfinite(x))
    if not (np.isfinite(q) and q >= MIN_TIMING_NOISE) or not np.std(d) >= MIN_JITTER:
        unread = "too little noise to move the phase of a limit cycle: its wander is not read"
    elif op is not None and not by_exception:
        lag, r = controller_lag(x, op, noise_only=True)
        if lag is None or abs(r[lag + SENSE_SKEW]) < NOISE_ANSWER:
            unread = ("the OP does not answer the PV's noise, which then moves no limit "
                      "cycle's phase: its wander is not read")
    if n < MIN_CROSSINGS:
        if k.size < MIN_CROSSINGS:
            common["crossings"] = int(k.size)
        if (unread is None and not by_exception and n >= MIN_JITTER_CROSSINGS
                and 2.0 * band >= CROSSING_SAMPLES * slope):
            # the smoothing over w samples leaves sqrt(w) less of the noise at
            # each crossing, beside which the tick falls anywhere within
            # TICK_WIDTH of a sample; a steady clock's periods differ by two
            # crossings'
            read = q * q / w + TICK_WIDTH ** 2 / 12.0
            common["jitter_ratio"] = float(np.std(d) / np.sqrt(2.0 * read))
        return PhaseWander(False, few if k.size < MIN_CROSSINGS else
                           f"{n} upward crossings in a run of like cycles, fewer than "
                           f"{MIN_CROSSINGS}", readable=unread is None, **common)
    if unread is not None:
        return PhaseWander(False, unread, **common)
    wander, keeps = _clock_reading(t, np.arange(n, dtype=float), d)
    if keeps:
        why = (f"the oscillation keeps time like a clock over {n} cycles (its crossings "
               f"scatter {wander:.2f} times the periods' variance about a steady clock, where "
               f"a limit cycle's phase would wander about {n / 15:.0f} times)")
    else:
        why = (f"the oscillation's phase wanders ({wander:.2f} times the periods' variance "
               f"over {n} cycles), as a limit cycle's does")
    return PhaseWander(keeps, why, wander=wander, readable=True, **common)


def _clock_reading(t: np.ndarray, k: np.ndarray, d: np.ndarray) -> tuple[float, bool]:
    """(wander, keeps time) of crossing times ``t`` at cycle numbers ``k``,
    against the periods ``d`` read between consecutive crossings."""
    resid = t - np.polyval(np.polyfit(k, t, 1), k)
    wander = float(np.var(resid) / np.var(d))
    span = float(k[-1] - k[0] + 1)
    return wander, bool(wander <= CLOCK_WANDER or wander <= CLOCK_SHARE * span / 15.0)


def pooled_phase_wander(readings, starts_s) -> PhaseWander:
    """Read whether an oscillation keeps a clock's time over the stretches of a record cut by gaps.

    Parameters
    ----------
    readings : sequence of PhaseWander
        :func:`phase_wander` of each stretch.
    starts_s : sequence of float
        Each stretch's first sample, in seconds from a common origin [s].

    Returns
    -------
    PhaseWander
        Over the stretches whose phase can be read (``readable``), their
        crossing times on the common clock, numbered by cycle across the
        gaps (``cycle``); ``keeps_clock`` as :func:`phase_wander` decides it,
        over :data:`MIN_CROSSINGS` crossings or more in all.

    Notes
    -----
    A clock outside the loop holds its phase through a gap in the record; a
    limit cycle's phase wanders on through it, unseen. Each gap is counted
    as the whole number of median periods nearest to it, and the crossings
    of all the stretches are fitted with one steady clock; the wander is
    read as over a gap-free record, and the random walk's expected wander
    grows with the cycles spanned, gaps included. A stretch whose periods'
    median differs from the pooled one by more than 40 % is left out (another
    oscillation). A gap over which a limit cycle's phase drifts by more than
    half a period is counted a cycle off, which hides part of that drift:
    over a gap of ``m`` cycles the drift is about ``sqrt(m)`` times the
    periods' jitter, half a period only where the jitter is large, and then
    the crossings within each stretch wander too.
    """
    use = sorted(((float(s), r) for r, s in zip(readings, starts_s)
                  if r.readable and np.size(r.times) >= 3), key=lambda e: e[0])
    if len(use) < 2:
        return PhaseWander(False, "fewer than two stretches whose phase can be read")
    med = [float(np.median(np.diff(r.times))) for _, r in use]
    period = float(np.median(np.concatenate([np.diff(r.times) for _, r in use])))
    use = [e for e, m in zip(use, med) if abs(m / period - 1.0) <= 0.4]
    if len(use) < 2:
        return PhaseWander(False, "the stretches do not cycle at one period")
    times, cycles, periods = [], [], []
    k0, last = 0, None
    for s, r in use:
        t = s + np.asarray(r.times, dtype=float)
        if last is not None:
            k0 += max(1, int(round((t[0] - last) / period)))
        times.append(t)
        cycles.append(k0 + np.arange(t.size))
        periods.append(np.diff(t))
        k0, last = int(cycles[-1][-1]), float(t[-1])
    t, k, d = np.concatenate(times), np.concatenate(cycles).astype(float), np.concatenate(periods)
    common = dict(crossings=int(t.size), jitter=float(np.std(d)), times=t, cycle=k,
                  timing_noise=float(np.median([r.timing_noise for _, r in use])), readable=True)
    if t.size < MIN_CROSSINGS:
        return PhaseWander(False, f"{t.size} upward crossings over {len(use)} stretches, fewer "
                           f"than {MIN_CROSSINGS}", **common)
    wander, keeps = _clock_reading(t, k, d)
    span = int(k[-1] - k[0] + 1)
    if keeps:
        why = (f"over {len(use)} stretches of a record cut by gaps, the oscillation keeps time "
               f"like a clock over {span} cycles ({t.size} crossings read; they scatter "
               f"{wander:.2f} times the periods' variance about one steady clock, where a limit "
               f"cycle's phase would wander about {span / 15:.0f} times)")
    else:
        why = (f"over {len(use)} stretches, the oscillation's phase wanders ({wander:.2f} times "
               f"the periods' variance over {span} cycles), as a limit cycle's does")
    return PhaseWander(keeps, why, wander=wander, **common)


def detect_oscillation(pv, sample_time: float, *, remove_drift: bool = True) -> Oscillation:
    """Find the dominant oscillation of a uniformly sampled record.

    Parameters
    ----------
    pv : array_like
        Signal, no NaN [PV unit].
    sample_time : float
        [s]
    remove_drift : bool
        Remove a slow baseline (a one-period moving average) first.

    Returns
    -------
    Oscillation

    Notes
    -----
    The period from the ACF seeds the moving-average baseline; the cycle
    durations then come from hysteresis crossings (band 20 % of the half
    range), which tolerates noise up to several percent of the amplitude.
    Where an oscillation fills only part of a long, noisy record, that band
    is narrow against the noise of the quiet part, whose crossings would
    make the period a few samples; when the crossings come three times
    faster than a strong ACF's period, the band is widened to four standard
    deviations of the white noise, and that reading is kept where the cycles
    it finds span at most three quarters of the record, or where their
    period is the ACF's to within a tenth and they swing by ten noise
    deviations or more: a loop that rests at its set point between the
    steps of a slow load crosses the band with its noise while it rests,
    all through the record, and the wider band finds the load's period (on
    ten healthy levels under pumped and square loads of the realistic
    benchmark's study seeds that needed it, the swing read 14-34 deviations,
    and 9 on one). An oscillation smaller than that is not
    segmented there, and a swing within a few noise deviations all through
    the record (the plant benchmark's healthy loops under loads of 3-6 h
    swing by 4-10) is left as it was read.
    Several simultaneous oscillations of different periods are not separated
    (see Thornhill et al. 2003 for that).
    """
    x = np.ascontiguousarray(pv, dtype=float)
    hint, acf_peak = acf_period(linear_detrend(x))
    y, ai, asg, per, dur, _ = segment_cycles(x, hint if np.isfinite(hint) else 0.0, remove_drift)
    if (np.isfinite(hint) and acf_peak > ACF_STRONG and per < NOISE_CROSSINGS * hint
            and 3 * hint <= x.size):
        # the record is periodic at the ACF's lag (three cycles of it fit), yet
        # its band crossings come far faster: noise may cross a band set by a
        # cycle that fills only part of the record, or the rests of a loop that
        # settles between a slow load's steps. Cross beyond the noise, and keep
        # that reading where the cycles it finds fill only a part, or keep the
        # ACF's period with a swing well clear of the noise (a swing of a few
        # noise deviations all through the record stays unsegmented)
        noise = white_noise_std(x)
        seg = segment_cycles(x, hint, remove_drift, BAND_NOISE * noise)
        ai2 = seg[1]
        swing = (float(np.median(np.abs(np.diff(seg[0][ai2])))) / 2 if ai2.size >= 2
                 else 0.0)
        if ai2.size >= 2 and (ai2[-1] - ai2[0] <= PART_TIME * x.size
                              or (abs(seg[3] / hint - 1.0) <= ACF_AGREES
                                  and swing >= SWING_NOISE * noise)):
            y, ai, asg, per, dur, _ = seg
    reg = acf_regularity(y, period=hint)
    amps = np.abs(np.diff(y[ai])) / 2 if ai.size >= 2 else np.array([np.nan])
    return Oscillation(period=float(per) * sample_time, amplitude=float(np.median(amps)),
                       cycles=max(0.0, (ai.size - 1) / 2), regularity=reg,
                       acf_at_period=acf_peak, periodic_fraction=_periodic_fraction(y, ai, asg),
                       apex_idx=ai, apex_sign=asg, baseline_removed=y,
                       sample_time=float(sample_time), acf_period=float(hint) * sample_time)
