"""
Where a fitted loop model fails: residual analysis in the manner of
MATLAB's ``resid`` (Ljung 1999), plus views specific to valves.

* the residual over time, with its worst segments located and labelled
  (after an OP reversal, after a valve breakaway, at an OP limit, during a
  set-point change, during a drift);
* the residual autocorrelation with its 99 % band;
* the residual-OP cross-correlation with its 99 % band;
* the residual averaged over OP reversals, signed with the direction of
  travel (a dead band leaves a pulse there, a slip jump a step).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .data import shade_heldout

__all__ = ["Diagnosis", "WorstSegment", "diagnose_fit", "residual_acf", "residual_ccf",
           "event_average", "valve_breakaways"]

#: Two-sided 99 % point of the standard normal distribution.
Z99 = 2.5758293035489004


@dataclass(frozen=True)
class WorstSegment:
    """One badly predicted segment.

    Attributes
    ----------
    start, end : float
        Time span [s].
    rms : float
        RMS residual in the segment [PV unit].
    ratio : float
        ``rms`` over the RMS residual of all scored segments.
    labels : tuple of str
        What happens there: ``'after OP reversal'``, ``'after valve
        breakaway'``, ``'at OP limit'``, ``'during set-point change'``,
        ``'during drift'`` (the OP averaged over a period moves by more than
        a quarter of a typical swing nearby), or ``'no pattern'``.
    heldout : bool
        True for a held-out segment.
    """

    start: float
    end: float
    rms: float
    ratio: float
    labels: tuple[str, ...]
    heldout: bool


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Residual analysis of one fitted model.

    Attributes
    ----------
    model_name : str
    t, residual : numpy.ndarray
        Time [s] and residual ``pv - pv_model`` [PV unit] (NaN where not
        scored).
    sample_set : numpy.ndarray of int
        0 training, 1 held-out, -1 not scored.
    rms : float
        RMS residual over all scored samples [PV unit].
    worst : tuple of WorstSegment
        Worst segments, worst first.
    acf_lags, acf : numpy.ndarray
        Residual autocorrelation against lag [s].
    acf_band : float
        Its 99 % band for a white residual, ``2.58 / sqrt(N)``.
    ccf_lags, ccf, ccf_band : numpy.ndarray
        Residual-OP cross-correlation against lag [s] (positive: the OP
        leads) and its 99 % band per lag (Bartlett's formula with both
        autocorrelations).
    rev_lags, rev_mean, rev_se : numpy.ndarray
        Residual averaged over the OP reversals, signed with the direction
        of travel after the reversal, against time from the reversal [s],
        and its standard error [PV unit].
    rev_count : int
        Reversals averaged.
    """

    model_name: str
    t: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    sample_set: np.ndarray = field(repr=False)
    rms: float
    worst: tuple[WorstSegment, ...]
    acf_lags: np.ndarray = field(repr=False)
    acf: np.ndarray = field(repr=False)
    acf_band: float
    ccf_lags: np.ndarray = field(repr=False)
    ccf: np.ndarray = field(repr=False)
    ccf_band: np.ndarray = field(repr=False)
    rev_lags: np.ndarray = field(repr=False)
    rev_mean: np.ndarray = field(repr=False)
    rev_se: np.ndarray = field(repr=False)
    rev_count: int

    VIEWS = ("residual", "acf", "ccf", "reversals")

    @property
    def acf_outside(self) -> float:
        """Fraction of ACF lags (beyond 0) outside the 99 % band."""
        a = self.acf[1:]
        return float(np.mean(np.abs(a) > self.acf_band)) if a.size else 0.0

    @property
    def ccf_outside(self) -> float:
        """Fraction of CCF lags outside the 99 % band."""
        return float(np.mean(np.abs(self.ccf) > self.ccf_band)) if self.ccf.size else 0.0

    def summary(self) -> str:
        """The findings in a few lines."""
        lines = [f"residual RMS {self.rms:.4g}; ACF outside the 99 % band at "
                 f"{100 * self.acf_outside:.0f} % of lags, residual-OP CCF at "
                 f"{100 * self.ccf_outside:.0f} %"]
        for w in self.worst[:3]:
            lines.append(f"  {w.start:.0f}-{w.end:.0f} s: RMS {w.rms:.3g} ({w.ratio:.1f}x), "
                         f"{', '.join(w.labels)}")
        return "\n".join(lines)

    def plot(self, view: str = "residual", ax=None, *, fit=None):
        """Draw one view.

        Parameters
        ----------
        view : {'residual', 'acf', 'ccf', 'reversals'}
            Residual over time with the worst segments marked; residual
            autocorrelation; residual-OP cross-correlation; residual
            averaged over OP reversals.
        ax : matplotlib.axes.Axes, optional
        fit : ModelFit, optional
            For the residual view: shades the held-out blocks.

        Returns
        -------
        matplotlib.axes.Axes
        """
        if view not in self.VIEWS:
            raise ValueError(f"view must be one of {self.VIEWS}, not {view!r}")
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots(figsize=(9, 3) if view == "residual" else (5, 3))
        if view == "residual":
            if fit is not None:
                shade_heldout(ax, fit.data)
            ax.plot(self.t, self.residual, color="C3", lw=0.7)
            ax.axhline(0, color="k", lw=0.5)
            for i, w in enumerate(self.worst):
                ax.axvspan(w.start, w.end, color="C1", alpha=0.25, lw=0)
                ax.annotate(f"{i + 1}", (0.5 * (w.start + w.end), 1.0), xycoords=("data", "axes fraction"),
                            ha="center", va="bottom", fontsize=7)
            ax.set_xlabel("time [s]")
            ax.set_ylabel("residual [PV]")
            ax.set_title(f"residual of {self.model_name} (worst segments numbered)", fontsize=9)
        elif view == "acf":
            ax.vlines(self.acf_lags, 0, self.acf, color="C0", lw=1)
            ax.axhspan(-self.acf_band, self.acf_band, color="C0", alpha=0.15, lw=0)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_xlabel("lag [s]")
            ax.set_ylabel("autocorrelation")
            ax.set_title("residual ACF (99 % band)", fontsize=9)
        elif view == "ccf":
            ax.vlines(self.ccf_lags, 0, self.ccf, color="C0", lw=1)
            ax.fill_between(self.ccf_lags, -self.ccf_band, self.ccf_band, color="C0", alpha=0.15,
                            lw=0)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_xlabel("lag [s] (positive: OP leads)")
            ax.set_ylabel("cross-correlation")
            ax.set_title("residual-OP cross-correlation (99 % band)", fontsize=9)
        else:
            ax.plot(self.rev_lags, self.rev_mean, color="C0", lw=1)
            ax.fill_between(self.rev_lags, self.rev_mean - Z99 * self.rev_se,
                            self.rev_mean + Z99 * self.rev_se, color="C0", alpha=0.2, lw=0)
            ax.axhline(0, color="k", lw=0.5)
            ax.axvline(0, color="k", lw=0.5, ls=":")
            ax.set_xlabel("time from OP reversal [s]")
            ax.set_ylabel("signed residual [PV]")
            ax.set_title(f"residual over {self.rev_count} OP reversals (99 % band)", fontsize=9)
        return ax


def _corr_at(a, b, lags):
    """Normalised cross-correlation ``sum a_k b_{k-lag} / (N sa sb)`` (NaN-free)."""
    n = a.size
    sa = math.sqrt(np.dot(a, a) / n)
    sb = math.sqrt(np.dot(b, b) / n)
    out = np.zeros(lags.size)
    if sa == 0 or sb == 0:
        return out
    for i, L in enumerate(lags):
        if L >= 0:
            out[i] = np.dot(a[L:], b[: n - L]) / (n * sa * sb)
        else:
            out[i] = np.dot(a[: n + L], b[-L:]) / (n * sa * sb)
    return out


def _scored(fit):
    """Residual and OP over the scored samples, each segment's mean removed."""
    ss = fit.sample_set
    use = ss >= 0
    e = np.where(use, np.nan_to_num(fit.residual), 0.0)
    u = fit.op.copy()
    sid = fit.data.seg_id
    s = sid[use]
    nseg = fit.data.seg_start.size
    cnt = np.bincount(s, minlength=nseg)
    cnt = np.where(cnt > 0, cnt, 1)
    um = np.bincount(s, weights=u[use], minlength=nseg) / cnt
    em = np.bincount(s, weights=e[use], minlength=nseg) / cnt
    u = np.where(use, u - um[np.maximum(sid, 0)], 0.0)
    e = np.where(use, e - em[np.maximum(sid, 0)], 0.0)
    return e, u, use


def residual_acf(fit, max_lag: int):
    """Residual autocorrelation over the scored samples.

    Parameters
    ----------
    fit : ModelFit
    max_lag : int
        [samples]

    Returns
    -------
    lags : numpy.ndarray of int
    acf : numpy.ndarray
    band : float
        99 % band ``2.58/sqrt(N)`` for a white residual.
    """
    e, _, use = _scored(fit)
    lags = np.arange(0, max_lag + 1)
    acf = _corr_at(e, e, lags) * e.size / max(int(use.sum()), 1)
    acf /= acf[0] if acf[0] else 1.0
    return lags, acf, Z99 / math.sqrt(max(int(use.sum()), 1))


def residual_ccf(fit, max_lag: int, signal=None):
    """Residual cross-correlation with the OP (or another input signal).

    Parameters
    ----------
    fit : ModelFit
    max_lag : int
        [samples]
    signal : array_like, optional
        Input to correlate with; default the OP.

    Returns
    -------
    lags : numpy.ndarray of int
        Positive: the input leads the residual.
    ccf : numpy.ndarray
    band : numpy.ndarray
        99 % band per lag under independence: ``2.58 sqrt(sum_k
        r_e(k) r_u(k) / N)`` (Bartlett), which widens for autocorrelated
        signals (Ljung 1999, sec. 16.6).
    """
    e, u, use = _scored(fit)
    if signal is not None:
        u = np.where(use, np.asarray(signal, float), 0.0)
        sid = fit.data.seg_id
        s = sid[use]
        nseg = fit.data.seg_start.size
        cnt = np.maximum(np.bincount(s, minlength=nseg), 1)
        um = np.bincount(s, weights=u[use], minlength=nseg) / cnt
        u = np.where(use, u - um[np.maximum(sid, 0)], 0.0)
    N = max(int(use.sum()), 1)
    lags = np.arange(-max_lag, max_lag + 1)
    ccf = _corr_at(e, u, lags) * e.size / N
    kk = np.arange(0, max_lag + 1)
    re = _corr_at(e, e, kk)
    ru = _corr_at(u, u, kk)
    if re[0]:
        re = re / re[0]
    if ru[0]:
        ru = ru / ru[0]
    var = (1.0 + 2.0 * np.sum(re[1:] * ru[1:])) / N
    band = np.full(lags.size, Z99 * math.sqrt(max(var, 1.0 / N)))
    return lags, ccf, band


def event_average(x, events, signs, before: int, after: int):
    """Average of ``sign * x`` over windows around events.

    Parameters
    ----------
    x : array_like
        Signal (NaN where missing).
    events : array_like of int
        Event indices [sample].
    signs : array_like
        Sign per event (e.g. the direction of travel).
    before, after : int
        Window [samples].

    Returns
    -------
    lags : numpy.ndarray of int
    mean, se : numpy.ndarray
        NaN-aware mean and standard error per lag.
    count : int
        Events with any data in their window.
    """
    x = np.asarray(x, dtype=float)
    lags = np.arange(-before, after + 1)
    ev = np.asarray(events, dtype=np.int64)
    sg = np.asarray(signs, dtype=float)
    ok = (ev - before >= 0) & (ev + after < x.size)
    ev, sg = ev[ok], sg[ok]
    if ev.size == 0:
        nan = np.full(lags.size, np.nan)
        return lags, nan, nan, 0
    M = x[ev[:, None] + lags[None, :]] * sg[:, None]
    good = np.isfinite(M).any(axis=1)
    M = M[good]
    if M.shape[0] == 0:
        nan = np.full(lags.size, np.nan)
        return lags, nan, nan, 0
    cnt = np.isfinite(M).sum(axis=0)
    # (a lag at which no event has a scored sample, as on a PV scored only
    # at its stored points, is NaN: not a warning)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(M, axis=0) if M.shape[0] else np.full(lags.size, np.nan)
        sd = np.nanstd(M, axis=0, ddof=1) if M.shape[0] > 1 else np.full(lags.size, np.nan)
        se = sd / np.sqrt(np.maximum(cnt, 1))
    return lags, mean, se, int(M.shape[0])


def valve_breakaways(valve, min_rest: int = 2):
    """Samples where a modelled valve starts to move after resting.

    Parameters
    ----------
    valve : array_like
        Valve position [OP unit].
    min_rest : int
        Samples at rest before the move [samples].

    Returns
    -------
    idx : numpy.ndarray of int
    direction : numpy.ndarray
        +1 opening, -1 closing.
    """
    x = np.asarray(valve, dtype=float)
    dx = np.diff(x)
    moving = dx != 0
    start = np.flatnonzero(moving[1:] & ~moving[:-1]) + 1
    if min_rest > 1 and start.size:
        rest = np.r_[0, np.cumsum(~moving)]
        ok = start >= min_rest
        start = start[ok]
        ok2 = (rest[start] - rest[start - min_rest]) == min_rest
        start = start[ok2]
    return start + 1, np.sign(dx[start])


def _op_trend(op, width):
    """Moving average of the OP over ``width`` samples (one period)."""
    w = int(max(1, width))
    c = np.r_[0.0, np.cumsum(op)]
    n = op.size
    lo = np.clip(np.arange(n) - w // 2, 0, n)
    hi = np.clip(np.arange(n) + w - w // 2, 0, n)
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


def _labels(fit, a, b, e_seg, rev, brk, op_lo, op_hi, sp, trend, swing):
    H = b - a
    lab = []
    if np.any((rev >= a - H // 2) & (rev < b)):
        lab.append("after OP reversal")
    if brk.size and np.any((brk >= a - H // 2) & (brk < b)) and "after OP reversal" not in lab:
        lab.append("after valve breakaway")
    u = fit.op[a:b]
    if np.mean((u <= op_lo) | (u >= op_hi)) >= 0.2:
        lab.append("at OP limit")
    if sp is not None:
        s = sp[max(a - H, 0):b]
        s = s[np.isfinite(s)]
        if s.size > 1 and np.ptp(s) > 0:
            lab.append("during set-point change")
    # the operating point moves: the OP averaged over a period shifts by a
    # quarter of a typical swing within the segment (or the two around it)
    lo_, hi_ = max(a - H, 0), min(b + H, trend.size) - 1
    if swing > 0 and abs(trend[hi_] - trend[lo_]) > 0.25 * swing:
        lab.append("during drift")
    return tuple(lab) or ("no pattern",)


def diagnose_fit(fit, *, n_worst: int = 5, max_lag=None) -> Diagnosis:
    """Residual analysis of a fitted model: where and how it fails.

    Parameters
    ----------
    fit : ModelFit
    n_worst : int
        Worst segments reported.
    max_lag : int, optional
        Largest lag of the correlation views [samples]; default the longest
        dead time searched.

    Returns
    -------
    Diagnosis

    Notes
    -----
    The residual of a re-initialised free simulation is correlated within a
    segment even for a correct model when the plant integrates an
    unmodelled disturbance, so bands are a guide, not a test. The CCF band
    accounts for the autocorrelation of both signals (Bartlett's formula);
    the ACF band assumes a white residual, as in MATLAB's ``resid``.

    References
    ----------
    .. [1] Ljung, L. (1999). System Identification: Theory for the User,
       2nd ed., Prentice Hall, sec. 16.6 (model validation, residual
       analysis).
    """
    from .fit import max_delay

    d = fit.data
    h = d.sample_time
    L = int(max_lag) if max_lag is not None else int(max(10, max_delay(d)))
    e = fit.residual
    ss = fit.sample_set
    use = ss >= 0
    rms = float(np.sqrt(np.nanmean(e[use] ** 2)))
    lo, hi = np.percentile(d.op, [0.5, 99.5])
    span = hi - lo
    op_lo, op_hi = lo + 0.02 * span, hi - 0.02 * span
    brk, _ = valve_breakaways(fit.valve)
    per = d.period / h if np.isfinite(d.period) else 4 * d.horizon
    trend = _op_trend(d.op, per)
    sw = np.abs(np.diff(d.op[d.reversals])) if d.reversals.size > 1 else np.array([span])
    swing = float(np.median(sw))
    seg_rms = []
    for j, (a, b, st) in enumerate(zip(d.seg_start, d.seg_end, d.seg_set)):
        if st < 0 or not np.isfinite(e[a:b]).any():      # (no scored sample)
            continue
        seg_rms.append((float(np.sqrt(np.nanmean(e[a:b] ** 2))), j))
    seg_rms.sort(reverse=True)
    worst = []
    for r, j in seg_rms[:n_worst]:
        a, b = int(d.seg_start[j]), int(d.seg_end[j])
        worst.append(WorstSegment(start=float(d.t[a]), end=float(d.t[b - 1]), rms=r,
                                  ratio=r / rms if rms > 0 else math.nan,
                                  labels=_labels(fit, a, b, e[a:b], d.reversals, brk, op_lo,
                                                 op_hi, d.sp, trend, swing),
                                  heldout=bool(d.seg_set[j] == 1)))
    al, acf, aband = residual_acf(fit, min(L, d.horizon))
    cl, ccf, cband = residual_ccf(fit, L)
    w = int(min(max(d.horizon, 10), 0.5 * (d.period / h) if np.isfinite(d.period) else d.horizon))
    rl, rm, rse, rc = event_average(e, d.reversals, -d.reversal_sign, w // 4, w)
    return Diagnosis(model_name=fit.model.name, t=d.t, residual=e, sample_set=ss, rms=rms,
                     worst=tuple(worst), acf_lags=al * h, acf=acf, acf_band=aband,
                     ccf_lags=cl * h, ccf=ccf, ccf_band=cband, rev_lags=rl * h, rev_mean=rm,
                     rev_se=rse, rev_count=rc)
