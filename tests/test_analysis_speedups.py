"""The vectorised shortcuts of the per-loop analysis give the results of the
straightforward code they replace."""
from __future__ import annotations

import numba
import numpy as np
import pytest

from valvediag.analysis.align import median_spacing
from valvediag.analysis.bi import _fit_one
from valvediag.analysis.linearity import mean_cycles
from valvediag.analysis.oscillation import _periodic_fraction, resample_cycles


def _median_spacing_reference(ts_us):
    d = np.diff(np.unique(ts_us))
    return float(np.median(d)) / 1e6 if d.size else float("nan")


@pytest.mark.parametrize("case", ["sorted", "unsorted", "repeats", "one", "two-equal", "empty"])
def test_median_spacing_matches_the_sorted_unique_definition(case):
    rng = np.random.default_rng(3)
    ts = np.cumsum(rng.integers(1, 5, 500)) * 1_000_000
    if case == "unsorted":
        ts = rng.permutation(ts)
    elif case == "repeats":
        ts = np.sort(np.r_[ts, ts[::7], ts[::11]])
    elif case == "one":
        ts = ts[:1]
    elif case == "two-equal":
        ts = np.array([5_000_000, 5_000_000])
    elif case == "empty":
        ts = ts[:0]
    got, ref = median_spacing(ts), _median_spacing_reference(ts)
    assert (np.isnan(got) and np.isnan(ref)) or got == ref


def _interp_reference(signals, apex_idx, apex_sign, nbins):
    vl = apex_idx[apex_sign < 0]
    phase = np.linspace(0.0, 1.0, nbins, endpoint=False)
    out = [[] for _ in signals]
    for a, b in zip(vl[:-1], vl[1:]):
        if b - a < 3:
            continue
        tt = (np.arange(a, b + 1) - a) / (b - a)
        for k, s in enumerate(signals):
            out[k].append(np.interp(phase, tt, s[a:b + 1]))
    return [np.asarray(o) if len(o) else np.empty((0, nbins)) for o in out]


@pytest.mark.parametrize("nbins", [32, 64, 128])
def test_resampled_cycles_equal_numpy_interp_bit_for_bit(nbins):
    rng = np.random.default_rng(nbins)
    n = 20_000
    y = np.cumsum(rng.normal(size=n))
    u = rng.normal(size=n)
    # cycle lengths from 1 (skipped) to longer than nbins, and lengths that
    # divide nbins (phase points exactly on samples)
    lengths = rng.choice([1, 2, 3, 4, 5, 7, 8, 16, 31, 32, 33, 64, 100, 257, 1000], 60)
    vl = np.cumsum(np.r_[5, lengths])
    vl = vl[vl < n - 1]
    pk = (vl[:-1] + vl[1:]) // 2
    idx = np.r_[vl, pk]
    sgn = np.r_[-np.ones(vl.size, int), np.ones(pk.size, int)]
    order = np.argsort(idx, kind="stable")
    idx, sgn = idx[order], sgn[order]
    got = resample_cycles([y, u], idx, sgn, nbins)
    ref = _interp_reference([y, u], idx, sgn, nbins)
    for g, r in zip(got, ref):
        assert g.shape == r.shape and g.shape[0] > 10
        np.testing.assert_array_equal(g, r)
    np.testing.assert_array_equal(mean_cycles([y], idx, sgn, nbins)[0], ref[0])


def test_periodic_fraction_of_a_clean_and_of_a_noisy_oscillation():
    t = np.arange(6000.0)
    y = np.sin(2 * np.pi * t / 100)
    vl = np.arange(75, 6000, 100)
    idx = np.sort(np.r_[vl, vl[:-1] + 50])
    sgn = np.where(np.isin(idx, vl), -1, 1)
    assert _periodic_fraction(y, idx, sgn) == pytest.approx(1.0, abs=1e-9)
    noisy = y + np.random.default_rng(0).normal(0, 1.0, t.size)
    assert 0.2 < _periodic_fraction(noisy, idx, sgn) < 0.5
    assert _periodic_fraction(y, idx[:3], sgn[:3]) == 0.0


@numba.njit
def _fit_apices_one_model(y, ai, asg, qbs, qas, wgrid, reach, tail):
    """Fit the apex model around every apex for every rounding width, over
    ``qbs[a]`` samples before and ``qas[a]`` after the centre of apex ``a``.

    The sub-sample position of the corner is searched on a half-sample grid
    over ``+-reach`` samples, refined by successive halving to 1/64 sample.

    Returns rss (A, W) and params (A, W, 5) = (shift, y0, m, b, c), time in
    samples relative to the apex centre: the fit of one model at a time, as
    valvediag.analysis.bi had it before :func:`_fit_apices_both`."""
    nA = ai.size
    nW = wgrid.size
    rss = np.full((nA, nW), np.inf)
    par = np.full((nA, nW, 5), np.nan)
    A = np.empty((4, 4))
    r = np.empty(4)
    ngrid = int(round(4 * reach)) + 1
    for a in range(nA):
        k = ai[a]
        s = asg[a]
        qb = qbs[a]
        qa = qas[a]
        for wi in range(nW):
            w = wgrid[wi]
            best = np.inf
            bsh = 0.0
            for si in range(ngrid):
                sh = -reach + 0.5 * si
                v = _fit_one(y, k, s, qb, qa, sh, w, A, r, tail)
                if v < best:
                    best = v
                    bsh = sh
            step = 0.25
            for _ in range(5):
                centre = bsh
                for sh in (centre - step, centre + step):
                    v = _fit_one(y, k, s, qb, qa, sh, w, A, r, tail)
                    if v < best:
                        best = v
                        bsh = sh
                step *= 0.5
            v = _fit_one(y, k, s, qb, qa, bsh, w, A, r, tail)
            rss[a, wi] = v
            par[a, wi, 0] = bsh
            for i in range(4):
                par[a, wi, 1 + i] = r[i]
    return rss, par


def test_both_apex_fits_at_once_equal_the_two_separate_fits():
    from valvediag.analysis.bi import W_GRID, _fit_apices_both

    rng = np.random.default_rng(7)
    t = np.arange(3000.0)
    # a rounded triangle wave with noise, apices every 24 samples
    y = np.abs(((t / 48.0) % 1.0) - 0.5) * 4 - 1 + rng.normal(0, 0.05, t.size)
    ai = np.arange(36, 2950, 24, dtype=np.int64)
    asg = np.where((ai // 24) % 2 == 0, -1, 1).astype(np.int64)
    qbs = np.full(ai.size, 12, dtype=np.int64)
    qas = np.full(ai.size, 10, dtype=np.int64)
    qbs[::5] = 3      # some short windows
    wgrid = W_GRID * 48.0
    rss, par = _fit_apices_both(y, ai, asg, qbs, qas, wgrid, 3.5)
    for k, tail in enumerate((False, True)):
        r1, p1 = _fit_apices_one_model(y, ai, asg, qbs, qas, wgrid, 3.5, tail)
        np.testing.assert_array_equal(rss[k], r1)
        np.testing.assert_array_equal(par[k], p1)


def _block_activity_reference(y, h, period, amplitude):
    """The scan's block screen as it was written, one block at a time."""
    import math

    from valvediag.scan.loop import ACTIVE_ACF, ACTIVE_AMPLITUDE, BLOCK_PERIODS

    n = y.size
    L = int(round(BLOCK_PERIODS * period / h))
    lag = int(round(period / h))
    if L < 8 or n < 2 * L or not (amplitude > 0):
        return [(0, n)]
    nb = n // L
    edges = [k * L for k in range(nb)] + [n]
    active = []
    for a, b in zip(edges[:-1], edges[1:]):
        seg = y[a:b]
        t = np.arange(seg.size)
        seg = seg - np.polyval(np.polyfit(t, seg, 1), t)
        lo, hi = np.percentile(seg, [2, 98])
        big = 0.5 * (hi - lo) >= ACTIVE_AMPLITUDE * amplitude
        x0, x1 = seg[:-lag], seg[lag:]
        den = math.sqrt(float(np.dot(x0, x0) * np.dot(x1, x1)))
        acf = float(np.dot(x0, x1)) / den if den > 0 else 0.0
        active.append(big and acf > ACTIVE_ACF)
    runs, start = [], None
    for k, on in enumerate(active + [False]):
        if on and start is None:
            start = k
        elif not on and start is not None:
            runs.append((edges[start], edges[k]))
            start = None
    return runs


def test_block_screen_finds_the_runs_of_the_block_by_block_screen():
    from valvediag.scan.loop import _block_activity

    rng = np.random.default_rng(5)
    found = 0
    for _ in range(40):
        n = int(rng.integers(2_000, 20_000))
        P = float(rng.uniform(20, 300))
        t = np.arange(n)
        on = (rng.uniform(size=n // 700 + 1) > 0.4).repeat(700)[:n]
        y = (np.sin(2 * np.pi * t / P) * on * rng.uniform(0.3, 2)
             + rng.normal(0, rng.uniform(0.05, 0.8), n) + 500 + 0.01 * t)
        amp = float(rng.uniform(0.2, 1.5))
        runs = _block_activity(y, 1.0, P, amp)
        assert runs == _block_activity_reference(y, 1.0, P, amp)
        found += len(runs)
    assert found > 20
    assert _block_activity(np.zeros(5000), 1.0, 50.0, 1.0) == []
