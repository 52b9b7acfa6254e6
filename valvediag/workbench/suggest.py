"""
Which effect is missing: evidence in the residual, then the proof by refit.

For every effect not yet in the model, :func:`suggest_effects` measures the
residual signature that its absence leaves (:data:`EFFECTS`) *and* adds
the effect, refits, and scores the refit on the held-out blocks. Candidates
are ranked by held-out error (the evidence breaks near-ties and explains).
An effect is *accepted* only when both the held-out RMSE and the BIC fall.

:func:`forward_select` repeats this greedily from a starting model and
returns the error ladder.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..plain import finite_or_none
from .data import LoopData, periodogram_band
from .diagnosis import Z99, Diagnosis, event_average, residual_ccf
from .effects import EFFECTS, check_effects
from .model import LoopModel, ModelFit, fit_model
from .sensor import quantised_mean

__all__ = ["Evidence", "Suggestion", "Suggestions", "PairComparison", "LadderStep",
           "ErrorLadder", "effect_evidence", "suggest_effects", "compare_heldout",
           "forward_select", "diagnose"]

#: Smallest relative fall of the held-out RMSE for an effect to be accepted.
MIN_GAIN = 0.01
#: Effects with the same parameter count whose residual signatures are alike:
#: when both are accepted the record must show which one it holds.
RIVALS = (("lag", "dead_time"),)
#: The held-out errors of two rivals differ for real when their paired
#: difference over the held-out segments is at least this many standard
#: errors from zero [-] (about 95 % two-sided), and the held-out RMSEs differ
#: by at least :data:`MIN_GAIN` (a difference too small to accept an effect
#: for is too small to choose between two).
RIVAL_T = 2.0
#: An accepted effect's evidence: its held-out gain lies :data:`RIVAL_T`
#: standard errors beyond the noise of the held-out segments, or its BIC
#: falls by at least this much (very strong evidence on Kass and Raftery's
#: scale of twice the log Bayes factor) [-].
STRONG_BIC = 10.0


@dataclass(frozen=True)
class Evidence:
    """The residual signature of a missing effect.

    Attributes
    ----------
    signature : str
        What the effect's absence leaves in the residual.
    statistic : float
        Strength of that signature in units of its standard error, computed
        across events or segments (reversals, segments) since samples
        within a segment are correlated; for correlations, the peak over
        the 99 % band times 2.58. Descriptive: where it is a maximum over
        positions or lags it is larger than a test statistic would be.
    summary : str
        One sentence on what was measured.
    """

    signature: str
    statistic: float
    summary: str

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {"signature": self.signature, "statistic": finite_or_none(self.statistic),
                "summary": self.summary}


def _segment_slopes(fit: ModelFit):
    """Least-squares slope of the residual in every scored segment [PV/s]
    and the segment mid-times [s]."""
    d = fit.data
    e = fit.residual
    sl, tm = [], []
    for a, b, st in zip(d.seg_start, d.seg_end, d.seg_set):
        if st < 0:
            continue
        y = e[a:b]
        t = d.t[a:b]
        ok = np.isfinite(y)
        if ok.sum() < 3:
            continue
        tc = t[ok] - t[ok].mean()
        den = float(tc @ tc)
        if den <= 0:
            continue
        sl.append(float(tc @ (y[ok] - y[ok].mean())) / den)
        tm.append(float(t[ok].mean()))
    return np.array(sl), np.array(tm)


def effect_evidence(effect: str, fit: ModelFit, diag: Diagnosis | None = None) -> Evidence:
    """Residual evidence that ``effect`` is missing from ``fit``.

    Parameters
    ----------
    effect : str
        An effect name.
    fit : ModelFit
        The current model.
    diag : Diagnosis, optional
        Its residual analysis (computed if not given).

    Returns
    -------
    Evidence
    """
    d = fit.data
    h = d.sample_time
    e = fit.residual
    sig = EFFECTS[effect].signature
    if diag is None:
        diag = fit.diagnose()
    w = int(max(5, min(d.horizon, 0.25 * d.period / h if np.isfinite(d.period) else d.horizon)))
    if effect == "deadband":
        _, m, se, c = event_average(e, d.reversals, -d.reversal_sign, w // 4, w)
        z = np.abs(m) / np.where(se > 0, se, np.inf)
        k = int(np.nanargmax(z)) if np.isfinite(z).any() else 0
        stat = float(np.nanmax(z)) if np.isfinite(z).any() else 0.0
        return Evidence(sig, stat, f"signed residual over {c} OP reversals peaks at "
                                   f"{_g(m[k])} PV {(k - w // 4) * h:.0f} s after the reversal "
                                   f"({stat:.1f} standard errors)")
    if effect == "stiction":
        # A missing slip jump J: after each OP reversal the true valve stays
        # put until the OP has travelled S, then jumps J further than the
        # model's valve in the direction of travel. The residual's rate,
        # signed with the travel, therefore steps (by g J on an integrator)
        # at an OP travel S after the reversals. Per reversal: the rate
        # binned by travel; at each bin edge b the step of the rate beyond
        # its local trend; the statistic is the mean over reversals in units
        # of its standard error, at the b where it is largest.
        trav, rate, ev_id = _travel_rate(fit)
        if trav.size < 50:
            return Evidence(sig, 0.0, "too few samples after OP reversals")
        nb = 20
        edges = np.linspace(0.0, d.band_max, nb + 1)
        b_of = np.digitize(trav, edges) - 1
        ok = (b_of >= 0) & (b_of < nb)
        ne = int(ev_id.max()) + 1
        key = ev_id[ok] * nb + b_of[ok]
        cnt = np.bincount(key, minlength=ne * nb).reshape(ne, nb)
        sm = np.bincount(key, weights=rate[ok], minlength=ne * nb).reshape(ne, nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            m = sm / cnt
        best = (0.0, 0.0, 0.0, 0)
        for b in range(2, nb - 1):
            blk = m[:, b - 2:b + 2]
            use = np.isfinite(blk).all(axis=1)
            if use.sum() < 5:
                continue
            blk = blk[use]
            # the step at b beyond the local trend: a dead time or lag error
            # changes the rate smoothly with travel, a missing jump abruptly
            step = blk[:, 2] - blk[:, 1]
            trend = 0.5 * ((blk[:, 1] - blk[:, 0]) + (blk[:, 3] - blk[:, 2]))
            diff = step - trend
            sd = diff.std(ddof=1)
            z = abs(diff.mean()) / (sd / math.sqrt(diff.size)) if sd > 0 else 0.0
            if z > best[0]:
                best = (z, step.mean(), edges[b], int(diff.size))
        z, jump, at, nev = best
        return Evidence(sig, float(z), f"over {nev} reversals the residual's rate, signed with the "
                                       f"travel, steps by {_g(jump)} PV/s at an OP travel of "
                                       f"{at:.3g} ({z:.1f} standard errors)")
    if effect == "dead_time":
        pos = diag.ccf_lags > 0
        r = np.abs(diag.ccf[pos]) / diag.ccf_band[pos] * Z99
        if not r.size:
            return Evidence(sig, 0.0, "no positive lags")
        k = int(np.argmax(r))
        return Evidence(sig, float(r[k]),
                        f"residual-OP cross-correlation peaks at lag {diag.ccf_lags[pos][k]:.0f} s "
                        f"({diag.ccf[pos][k]:+.2f}, {r[k] / Z99:.1f} times the 99 % band)")
    if effect == "lag":
        du = np.r_[0.0, np.diff(fit.op)]
        L = int(max(5, min(d.horizon, 0.25 * d.period / h if np.isfinite(d.period) else 20)))
        lags, c, band = residual_ccf(fit, L, signal=du)
        pos = lags >= 0
        r = np.abs(c[pos]) / band[pos] * Z99
        k = int(np.argmax(r))
        return Evidence(sig, float(r[k]),
                        f"residual vs OP rate cross-correlation {c[pos][k]:+.2f} at lag "
                        f"{lags[pos][k] * h:.0f} s ({r[k] / Z99:.1f} times the 99 % band)")
    if effect == "drift":
        sl, tm = _segment_slopes(fit)
        if sl.size < 3:
            return Evidence(sig, 0.0, "too few segments")
        b, stat = _slope_z(tm, sl)
        # slow wander: lag-1 correlation of the segment rate errors
        r1 = float(np.corrcoef(sl[:-1], sl[1:])[0, 1]) if sl.size > 3 and sl.std() > 0 else 0.0
        return Evidence(sig, float(max(stat, r1 * math.sqrt(sl.size))),
                        f"rate error changes by {_g(b * 3600)} PV/s per hour ({stat:.1f} "
                        f"standard errors); neighbouring segments correlate {r1:+.2f}")
    if effect == "saturation":
        # per segment (samples within one are correlated): mean squared
        # residual of segments that spend a fifth of their time near an OP
        # extreme against the others
        lo, hi = np.percentile(d.op, [0.5, 99.5])
        span = hi - lo
        near = (d.op <= lo + 0.03 * span) | (d.op >= hi - 0.03 * span)
        a2, b2 = [], []
        for a, b, st in zip(d.seg_start, d.seg_end, d.seg_set):
            if st < 0 or not np.isfinite(e[a:b]).any():      # (no scored sample)
                continue
            ms = float(np.nanmean(e[a:b] ** 2))
            (a2 if near[a:b].mean() >= 0.2 else b2).append(ms)
        a2, b2 = np.array(a2), np.array(b2)
        if a2.size < 2 or b2.size < 2:
            return Evidence(sig, 0.0, "the OP hardly dwells near its extremes")
        ratio = math.sqrt(a2.mean() / b2.mean()) if b2.mean() > 0 else math.inf
        den = math.sqrt(a2.var(ddof=1) / a2.size + b2.var(ddof=1) / b2.size)
        stat = (a2.mean() - b2.mean()) / den if den > 0 else 0.0
        return Evidence(sig, float(max(stat, 0.0)),
                        f"residual RMS in the {a2.size} segments near the OP extremes is "
                        f"{ratio:.2f} times that of the other {b2.size}")
    if effect == "characteristic":
        # per segment, the residual's rate (integrating plant) or its mean
        # (self-regulating) against the mean squared distance of the valve
        # from its median: a linear characteristic fitted to a curved one
        # is right at the median and wrong, with one sign, on both sides
        x = fit.valve
        q = (x - np.nanmedian(x)) ** 2
        integ = fit.model.process_type == "integrating"
        ys, qs = [], []
        for a, b, st in zip(d.seg_start, d.seg_end, d.seg_set):
            y = e[a:b]
            ok = np.isfinite(y)
            if st < 0 or ok.sum() < 3:
                continue
            if integ:
                tc = d.t[a:b][ok] - d.t[a:b][ok].mean()
                den = float(tc @ tc)
                if den <= 0:
                    continue
                ys.append(float(tc @ (y[ok] - y[ok].mean())) / den)
            else:
                ys.append(float(y[ok].mean()))
            qs.append(float(q[a:b][ok].mean()))
        ys, qs = np.array(ys), np.array(qs)
        if ys.size < 4 or not qs.std() > 0:
            return Evidence(sig, 0.0, "too few segments, or the valve hardly moves")
        _, stat = _slope_z(qs, ys)
        what = "rate" if integ else "mean"
        return Evidence(sig, float(stat), f"the residual's {what} per segment follows the squared "
                                          f"distance of the valve from its median ({stat:.1f} "
                                          "standard errors)")
    if effect == "oscillating_load":
        # the residual's periodogram (unscored samples as zeros): its highest
        # peak against the median ordinate, which for white noise is
        # exponential (a peak of 20 times the median is rare among a few
        # thousand ordinates)
        f, pw = periodogram_band(np.nan_to_num(e), h)
        if f.size < 8:
            return Evidence(sig, 0.0, "record too short for a periodogram")
        i = int(np.argmax(pw))
        ratio = float(pw[i] / np.median(pw))
        return Evidence(sig, ratio, f"the residual's periodogram peaks at a period of "
                                    f"{1.0 / f[i]:.0f} s, {ratio:.0f} times its median")
    if effect == "quantisation":
        # per segment, the residual regressed on the error a hard staircase
        # would add to the model's PV (its reading less the PV); the slopes'
        # mean in standard errors
        grid = d.pv_grid
        if not grid.found:
            return Evidence(sig, 0.0, grid.describe())
        y = fit.pv_model
        c = quantised_mean(y, grid.step, grid.offset, 0.0) - y
        sl = []
        for a, b, st in zip(d.seg_start, d.seg_end, d.seg_set):
            ok = np.isfinite(e[a:b]) & np.isfinite(c[a:b])
            cc = c[a:b][ok]
            if st < 0 or ok.sum() < 3 or not cc @ cc > 0:
                continue
            sl.append(float(cc @ e[a:b][ok]) / float(cc @ cc))
        sl = np.array(sl)
        if sl.size < 3 or not sl.std() > 0:
            return Evidence(sig, 0.0, grid.describe() + "; too few segments")
        z = float(sl.mean() / (sl.std(ddof=1) / math.sqrt(sl.size)))
        return Evidence(sig, max(z, 0.0), f"{grid.describe()}; the residual follows the "
                                          f"staircase's error by {sl.mean():.2f} of it "
                                          f"({z:.1f} standard errors over {sl.size} segments)")
    raise ValueError(f"unknown effect {effect!r}")


def _slope_z(x, y) -> tuple[float, float]:
    """Least-squares slope of ``y`` on ``x`` and its size in standard errors."""
    xc = x - x.mean()
    b = float(xc @ (y - y.mean()) / (xc @ xc))
    res = y - y.mean() - b * xc
    se = math.sqrt(float(res @ res) / max(y.size - 2, 1) / float(xc @ xc))
    return b, (abs(b) / se if se > 0 else 0.0)


def _travel_rate(fit: ModelFit):
    """OP travel since the last reversal and the residual's rate [PV/s],
    both signed with the direction of travel, and the reversal's index, for
    the scored samples."""
    d = fit.data
    h = d.sample_time
    e = fit.residual
    de = np.r_[np.nan, np.diff(e)] / h
    de[d.seg_start] = np.nan
    rev = d.reversals
    if rev.size < 2:
        return np.array([]), np.array([])
    # direction after each reversal: away from the extreme
    k = np.searchsorted(rev, np.arange(d.n), side="right") - 1
    has = k >= 0
    kk = np.maximum(k, 0)
    sgn = -d.reversal_sign[kk].astype(float)
    trav = sgn * (d.op - d.op[rev[kk]])
    rate = sgn * de
    ok = has & np.isfinite(rate) & (d.sample_set >= 0)
    return trav[ok], rate[ok], kk[ok]


def _g(x):
    return f"{x:+.3g}" if np.isfinite(x) else "nan"


@dataclass(frozen=True, eq=False)
class Suggestion:
    """One candidate effect, refitted and scored.

    Attributes
    ----------
    effect : str
    params : dict
        Parameters of the refitted model (the new effect's included).
    fit_pct, heldout_rmse, bic : float
        Scores of the refitted model.
    evidence : Evidence
        The residual signature in the current model.
    accepted : bool
        Held-out RMSE fell by at least :data:`MIN_GAIN` and BIC fell (see
        :func:`suggest_effects`).
    gain : float
        Relative fall of the held-out RMSE, ``1 - new/base``.
    fit : ModelFit
    """

    effect: str
    params: dict
    fit_pct: float
    heldout_rmse: float
    bic: float
    evidence: Evidence
    accepted: bool
    gain: float
    fit: ModelFit = field(repr=False)

    def to_dict(self) -> dict:
        """JSON-ready form (NaN as None)."""
        ev = self.evidence.to_dict()
        ev["accepted"] = bool(self.accepted)
        ev["heldout_gain_pct"] = finite_or_none(100 * self.gain)
        return {"effect": self.effect, "params": {k: finite_or_none(v) for k, v in self.params.items()},
                "fit_pct": finite_or_none(self.fit_pct), "heldout_rmse": finite_or_none(self.heldout_rmse),
                "bic": finite_or_none(self.bic), "evidence": ev}


@dataclass(frozen=True)
class PairComparison:
    """Whether a record tells two rival effects apart.

    Attributes
    ----------
    effects : tuple of str
        The two effects, the one with the lower held-out error first.
    t : float
        Mean paired difference of their squared errors over the held-out
        segments, in standard errors of that mean (>= 0) [-].
    segments : int
        Held-out segments compared.
    error_diff_pct : float
        How much lower the first one's held-out RMSE is [%].
    distinguishable : bool
        ``t >= RIVAL_T`` and the held-out RMSEs differ by at least
        :data:`MIN_GAIN`.
    summary : str
        One sentence: which is better and by what figure, or why the record
        cannot tell.
    """

    effects: tuple[str, str]
    t: float
    segments: int
    error_diff_pct: float
    distinguishable: bool
    summary: str

    def to_dict(self) -> dict:
        """JSON-ready form (NaN as None)."""
        return {"effects": list(self.effects), "t": finite_or_none(self.t),
                "segments": int(self.segments),
                "error_diff_pct": finite_or_none(self.error_diff_pct),
                "distinguishable": bool(self.distinguishable), "summary": self.summary}


#: What tells each pair of rivals apart, for the summary of a tie.
_RIVAL_SHAPES = {("dead_time", "lag"): "a lag rounds the response to a step, a dead time delays "
                                        "it unchanged; a record with set-point steps or sharp OP "
                                        "moves (slips) tells them apart"}


def compare_heldout(a: ModelFit, b: ModelFit, names=("a", "b")) -> PairComparison:
    """Compare two fits of one record on its held-out segments.

    Parameters
    ----------
    a, b : ModelFit
        Fits of the same :class:`LoopData`.
    names : tuple of str
        Labels of ``a`` and ``b`` (the effects they add).

    Returns
    -------
    PairComparison

    Notes
    -----
    Each held-out segment is re-initialised, so its squared error is one
    nearly independent observation of the fit (samples within a segment are
    not); the paired t statistic of the segment differences says whether
    the held-out RMSEs differ beyond the noise of that sample of segments.
    Two models with the same number of parameters need no further margin
    (the held-out error does not reward parameters). The differences are
    heavy-tailed where a few events (set-point steps, slips) carry all the
    information, so a difference driven by two or three segments may not
    reach :data:`RIVAL_T`: the record then has too few such events to tell.
    """
    d = a.data
    held = np.flatnonzero(d.seg_set == 1)
    ea = np.nan_to_num(a.residual) ** 2
    eb = np.nan_to_num(b.residual) ** 2
    ca, cb = np.r_[0.0, np.cumsum(ea)], np.r_[0.0, np.cumsum(eb)]
    sa = ca[d.seg_end[held]] - ca[d.seg_start[held]]
    sb = cb[d.seg_end[held]] - cb[d.seg_start[held]]
    a_first = sa.sum() <= sb.sum()
    first, second = (names[0], names[1]) if a_first else (names[1], names[0])
    x = (sb - sa) if a_first else (sa - sb)       # > 0 where the first one is better
    m = int(x.size)
    sd = float(x.std(ddof=1)) if m > 1 else 0.0
    t = float(x.mean() / (sd / math.sqrt(m))) if sd > 0 else (math.inf if x.mean() > 0 else 0.0)
    lo, hi = sorted((sa.sum(), sb.sum()))
    diff = 100.0 * (1.0 - math.sqrt(lo / hi)) if hi > 0 else 0.0
    ok = bool(t >= RIVAL_T and diff >= 100.0 * MIN_GAIN)
    if ok:
        summary = (f"{first} fits better than {second}: held-out RMSE {diff:.1f} % lower, "
                   f"{t:.1f} standard errors over {m} held-out segments")
    else:
        why = _RIVAL_SHAPES.get(tuple(sorted((first, second))), "")
        summary = (f"{first} and {second} are indistinguishable on this record: held-out RMSE "
                   f"{diff:.1f} % apart, {t:.1f} standard errors over {m} held-out segments "
                   f"(need {100 * MIN_GAIN:g} % and {RIVAL_T:g})" + (f"; {why}" if why else ""))
    return PairComparison(effects=(first, second), t=t, segments=m, error_diff_pct=diff,
                          distinguishable=ok, summary=summary)


@dataclass(frozen=True, eq=False)
class Suggestions:
    """Candidate effects for one model, best first.

    Attributes
    ----------
    base : ModelFit
    diagnosis : Diagnosis
        Where the base model fails.
    items : tuple of Suggestion
        Best first.
    rivals : tuple of PairComparison
        For each pair of :data:`RIVALS` both accepted: whether the record
        tells them apart. Where it does not, the order of the two in
        :attr:`items` is not evidence.
    """

    base: ModelFit = field(repr=False)
    diagnosis: Diagnosis = field(repr=False)
    items: tuple[Suggestion, ...]
    rivals: tuple[PairComparison, ...] = ()

    @property
    def best(self) -> Suggestion | None:
        """The first accepted suggestion, or None."""
        for s in self.items:
            if s.accepted:
                return s
        return None

    def to_dict(self) -> dict:
        """``{"base": {...}, "suggestions": [...]}`` (NaN as None)."""
        return {"base": self.base.to_dict(), "suggestions": [s.to_dict() for s in self.items],
                "rivals": [r.to_dict() for r in self.rivals]}

    def table(self) -> str:
        """A plain-text table."""
        b = self.base
        rows = [f"{'model':34s} {'fit %':>7s} {'held-out RMSE':>14s} {'BIC':>11s}  evidence",
                f"{b.model.name:34s} {b.fit_pct:7.1f} {b.heldout_rmse:14.4g} {b.bic:11.1f}  (base)"]
        for s in self.items:
            mark = "accepted" if s.accepted else "rejected"
            rows.append(f"{'+ ' + s.effect:34s} {s.fit_pct:7.1f} {s.heldout_rmse:14.4g} "
                        f"{s.bic:11.1f}  {mark}; {s.evidence.summary}")
        rows += [f"{'':34s} {r.summary}" for r in self.rivals]
        return "\n".join(rows)

    def plot(self, ax=None):
        """Held-out RMSE of each candidate against the base model.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional

        Returns
        -------
        matplotlib.axes.Axes
        """
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots(figsize=(6, 0.4 * len(self.items) + 1.2))
        names = [f"+ {s.effect}" for s in self.items][::-1]
        vals = [s.heldout_rmse for s in self.items][::-1]
        cols = ["C2" if s.accepted else "0.6" for s in self.items][::-1]
        ax.barh(names, vals, color=cols)
        ax.axvline(self.base.heldout_rmse, color="C3", lw=1, ls="--",
                   label=f"base: {self.base.model.name}")
        ax.set_xlabel("held-out RMSE [PV] (green: accepted)")
        ax.legend(loc="lower right", fontsize=8)
        return ax


def _is_null(effect: str, fit: ModelFit, base: ModelFit) -> bool:
    """True when the fitted effect does nothing (its parameters at the
    value that removes it), so that it cannot be accepted."""
    p = fit.params
    h = fit.data.sample_time
    if effect == "dead_time":
        return p["dead_time"] < 0.25 * h
    if effect == "lag":
        return p["lag"] < 0.05 * h
    if effect == "saturation":
        return not (math.isfinite(p["sat_low"]) or math.isfinite(p["sat_high"]))
    if effect == "characteristic":
        # its gain changes by under 5 % over the OP's range
        lo, hi = np.percentile(fit.data.op, [1, 99])
        return abs(p["curvature"]) * (hi - lo) < 0.05
    if effect == "oscillating_load":
        return not fit.derived.get("load_amplitude", 0.0) > 0.0
    if effect == "quantisation":
        # no grid, or a staircase dithered away by the noise ahead of it
        return not p["quant_noise"] < p["quant_step"]
    if effect == "deadband":
        return p["DB"] < 1e-6 * fit.data.band_max
    if effect == "stiction":
        if "deadband" in base.effects:
            return p["J"] < 0.01 * p["S"]
        return p["S"] < 1e-6 * fit.data.band_max
    return False


def suggest_effects(base: ModelFit, candidates=None) -> Suggestions:
    """Rank the effects missing from a fitted model.

    Parameters
    ----------
    base : ModelFit
    candidates : iterable of str, optional
        Effects to try; default every effect not in the model.

    Returns
    -------
    Suggestions

    Notes
    -----
    Each candidate is added, the whole model refitted (warm-started from
    ``base``) and scored on the held-out blocks. Ranking: held-out RMSE,
    where two candidates are within 0.5 % of each other the stronger
    residual evidence first. An effect is accepted when the held-out RMSE
    falls by at least :data:`MIN_GAIN` and the BIC falls too (the BIC counts
    the grid-searched parameters), both against the base fit and against
    the base model evaluated at the refit's other parameters (the refit
    searches those again, and a better optimum of the base is no merit of
    the effect; for a stiction fit that replaces a dead band, the dead band
    is also read as ``S`` and as ``S - J``); where the BIC falls by less
    than :data:`STRONG_BIC`, the held-out gain must also stand
    :data:`RIVAL_T` standard errors out of the noise of the held-out
    segments (:func:`compare_heldout`: on a PV read on a grid of five
    levels a drift gained 5 % held-out, 1.3 standard errors, with a BIC
    1.7 lower; a real drift's BIC falls by thousands), and when the fitted
    effect is not void (a dead time under a quarter sample, a lag under 5 % of a
    sample, no stop, no jump on top of a dead band, no grid or a quantiser
    dithered away by its noise).

    References
    ----------
    .. [1] Kass, R. E., Raftery, A. E. (1995), Bayes factors, Journal of the
       American Statistical Association 90(430), 773-795.
    """
    data = base.data
    diag = base.diagnose()
    cands = base.model.candidates() if candidates is None else \
        tuple(e for e in check_effects(candidates) if e in base.model.candidates())
    items = []
    for eff in cands:
        if eff in base.effects:
            continue
        ev = effect_evidence(eff, base, diag)
        f = base.model.add(eff).fit(data, start=base)
        gain = 1.0 - f.heldout_rmse / base.heldout_rmse if base.heldout_rmse > 0 else 0.0
        # a fair comparison: the refit also re-searched the base's own
        # parameters; if the base model at those parameters (the effect
        # removed) is better than the base fit, the gain is the search's,
        # not the effect's
        ref = base
        thetas = [f.theta] if f.theta != base.theta else []
        if eff == "stiction" and "deadband" in base.effects:
            # the refit's valve read as a dead band: a Kano valve with a small
            # jump moves like a dead band of width S - J and rests like one of S
            th = f.theta
            thetas += [th.replace(DB=th.S), th.replace(DB=max(th.S - th.J, 0.0))]
        for t in thetas:
            r = base.model.evaluate(data, t)
            if r.train_rmse < ref.train_rmse:
                ref = r
        ref_gain = 1.0 - f.heldout_rmse / ref.heldout_rmse if ref.heldout_rmse > 0 else 0.0
        acc = bool(gain >= MIN_GAIN and ref_gain >= MIN_GAIN and f.bic < ref.bic
                   and not _is_null(eff, f, base))
        if acc and ref.bic - f.bic < STRONG_BIC:
            # a gain the BIC hardly backs must stand out of the held-out noise
            c = compare_heldout(f, ref, ("effect", "base"))
            acc = c.effects[0] == "effect" and c.t >= RIVAL_T
        items.append(Suggestion(effect=eff, params=dict(f.params), fit_pct=f.fit_pct,
                                heldout_rmse=f.heldout_rmse, bic=f.bic, evidence=ev,
                                accepted=acc, gain=gain, fit=f))
    ref = base.heldout_rmse if base.heldout_rmse > 0 else 1.0
    items.sort(key=lambda s: (not s.accepted, round(s.heldout_rmse / ref / 0.005),
                              -np.nan_to_num(s.evidence.statistic)))
    acc = {s.effect: s for s in items if s.accepted}
    rivals = tuple(compare_heldout(acc[a].fit, acc[b].fit, (a, b)) for a, b in RIVALS
                   if a in acc and b in acc)
    for r in rivals:
        # a real difference between rivals orders them, whatever the near-tie
        # rule above (held-out errors within 0.5 %, then the evidence) said
        i, j = (next(k for k, s in enumerate(items) if s.effect == e) for e in r.effects)
        if r.distinguishable and i > j:
            items[i], items[j] = items[j], items[i]
    return Suggestions(base=base, diagnosis=diag, items=tuple(items), rivals=rivals)


@dataclass(frozen=True, eq=False)
class LadderStep:
    """One rung of the error ladder.

    Attributes
    ----------
    added : str or None
        The effect added at this step (None for the start).
    fit : ModelFit
    suggestions : Suggestions or None
        The candidates tried from this step (None for the last step when
        the search was not run from it).
    alternatives : tuple of str
        Rival effects that the record could not tell from ``added`` when it
        was chosen (both accepted, :attr:`PairComparison.distinguishable`
        false): ``added`` is one of them, and its name is not evidence.
    """

    added: str | None
    fit: ModelFit = field(repr=False)
    suggestions: Suggestions | None = field(repr=False, default=None)
    alternatives: tuple[str, ...] = ()

    @property
    def effects(self) -> tuple[str, ...]:
        """Effects of the model at this step."""
        return self.fit.effects


@dataclass(frozen=True, eq=False)
class ErrorLadder:
    """Greedy forward selection: the model, step by step, and its errors.

    Attributes
    ----------
    steps : tuple of LadderStep
        From the starting model to the final one.
    """

    steps: tuple[LadderStep, ...]

    @property
    def first(self) -> ModelFit:
        """The starting model's fit."""
        return self.steps[0].fit

    @property
    def final(self) -> ModelFit:
        """The selected model's fit."""
        return self.steps[-1].fit

    def rows(self) -> list[dict]:
        """One dict per step: model, effects, added, alternatives, params,
        fit_pct, heldout_rmse, bic, n_params."""
        out = []
        for s in self.steps:
            f = s.fit
            out.append({"model": f.model.name, "effects": list(f.effects), "added": s.added,
                        "alternatives": list(s.alternatives),
                        "params": dict(f.params), "fit_pct": f.fit_pct,
                        "heldout_rmse": f.heldout_rmse, "bic": f.bic, "n_params": f.n_params})
        return out

    def table(self) -> str:
        """A plain-text table."""
        lines = [f"{'step':4s} {'model':40s} {'k':>3s} {'fit %':>7s} {'held-out RMSE':>14s} "
                 f"{'BIC':>11s}  parameters"]
        for i, r in enumerate(self.rows()):
            ps = ", ".join(f"{k}={v:.4g}" for k, v in r["params"].items())
            if r["alternatives"]:
                ps += (f"  ({r['added']} or {' or '.join(r['alternatives'])}: this record "
                       "cannot tell them apart)")
            lines.append(f"{i:<4d} {r['model']:40s} {r['n_params']:3d} {r['fit_pct']:7.1f} "
                         f"{r['heldout_rmse']:14.4g} {r['bic']:11.1f}  {ps}")
        return "\n".join(lines)

    def plot(self, ax=None):
        """Held-out RMSE and fit % per step.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional

        Returns
        -------
        matplotlib.axes.Axes
        """
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots(figsize=(6, 3))
        rows = self.rows()
        x = np.arange(len(rows))
        labels = [r["model"] if r["added"] is None else f"+ {r['added']}" for r in rows]
        ax.plot(x, [r["heldout_rmse"] for r in rows], "o-", color="C3", label="held-out RMSE")
        ax.set_xticks(x)
        ax.set_xticklabels(labels, rotation=20, ha="right", fontsize=8)
        ax.set_ylabel("held-out RMSE [PV]")
        ax.set_ylim(bottom=0)
        ax2 = ax.twinx()
        ax2.plot(x, [r["fit_pct"] for r in rows], "s--", color="C0", label="fit %")
        ax2.set_ylabel("fit [%]")
        lines = ax.get_lines() + ax2.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], loc="center right", fontsize=8)
        ax.set_title("error ladder", fontsize=9)
        return ax


def forward_select(data: LoopData, start=(), *, process_type: str = "integrating",
                   max_steps: int | None = None, start_fit: ModelFit | None = None) -> ErrorLadder:
    """Greedy forward selection of effects from a starting model.

    Parameters
    ----------
    data : LoopData
    start : str or tuple of str
        Starting effects.
    process_type : {'integrating', 'self-regulating'}
    max_steps : int, optional
        Most effects added.
    start_fit : ModelFit, optional
        An already fitted starting model (skips its fit).

    Returns
    -------
    ErrorLadder
        Stops when no candidate is accepted.

    Notes
    -----
    Where the best candidate has an accepted rival that the record cannot
    tell from it (:func:`compare_heldout`), the step names the rival among
    its :attr:`LadderStep.alternatives`: the choice between the two is not
    evidence. The next step tries the rival again on top of the chosen one
    and adds it only where it explains what the chosen one left.
    """
    fit = start_fit if start_fit is not None else LoopModel(start, process_type).fit(data)
    steps = []
    added, alts = None, ()
    while True:
        sug = suggest_effects(fit)
        steps.append(LadderStep(added=added, fit=fit, suggestions=sug, alternatives=alts))
        best = sug.best
        if best is None or (max_steps is not None and len(steps) - 1 >= max_steps):
            break
        fit, added = best.fit, best.effect
        alts = tuple(e for r in sug.rivals if not r.distinguishable and added in r.effects
                     for e in r.effects if e != added)
    return ErrorLadder(steps=tuple(steps))


def diagnose(pv, op, sample_time, effects=(), *, process_type: str = "integrating", sp=None,
             **options) -> Suggestions:
    """Fit a starting model and rank the effects missing from it.

    Parameters
    ----------
    pv, op, sample_time, effects, process_type, sp, **options : see fit_model
        As :func:`valvediag.workbench.fit_model`: the record, the starting
        model (default: the plant alone) and its options.

    Returns
    -------
    Suggestions
    """
    return suggest_effects(fit_model(pv, op, sample_time, effects, process_type=process_type,
                                     sp=sp, **options))
