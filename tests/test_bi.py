"""Backlash Index: analytic shapes, simulations, invariance, thresholds, bad input."""
import numpy as np
import pytest

from valvediag import backlash_index, simulate_loop
from valvediag.analysis.bi import NREF, THRESHOLDS, bi_verdict


def triangle(t, P):
    return 2 * np.abs(((t / P) % 1) - 0.5)


def hyperbolic_wave(t, P, w):
    """Triangle-like wave whose apices are exactly the robust method's model:
    -(sqrt(tau^2 + w^2) - w), slopes +-1 (w << P)."""
    ph = (t + P / 4) % P - P / 4                      # apex of the peak at 0, valley at P/2
    near_peak = ph < P / 4
    tau = np.where(near_peak, ph, ph - P / 2)
    # both branches round corners on the asymptotes -|tau| and -P/2 + |tau|,
    # which meet at the middle points (continuous up to w^2/P)
    r = np.sqrt(tau ** 2 + w ** 2)
    return np.where(near_peak, -r, r - P / 2)


@pytest.mark.parametrize("method", ["paper", "robust"])
def test_triangle_is_stiction_with_bi_one(method):
    h, P = 0.5, 100.0
    t = np.arange(4000) * h
    r = backlash_index(triangle(t, P), h, method=method)
    assert r.bi == pytest.approx(1.0, abs=0.02)
    assert r.verdict == "stiction"
    assert r.period == pytest.approx(P, rel=0.01)
    assert r.amplitude == pytest.approx(0.5, rel=0.02)


def test_paper_bi_of_a_sine_matches_closed_form():
    h, P = 0.5, 100.0
    t = np.arange(4000) * h
    r = backlash_index(np.sin(2 * np.pi * t / P), h, method="paper")
    # small-angle frame: BI = middle slope / mean slope from a peak to its neighbours
    expected = (2 * np.pi / P) / ((1 - np.cos(2 * np.pi * h / P)) / h)
    assert r.bi == pytest.approx(expected, rel=0.01)
    assert r.verdict == "backlash"


def test_robust_recovers_the_rounding_of_its_own_model():
    h, P, w = 1.0, 400.0, 8.0                       # rounding w/P = 0.02
    t = np.arange(8000) * h
    r = backlash_index(hyperbolic_wave(t, P, w), h)
    assert r.rounding == pytest.approx(w / P, rel=0.3)   # grid of widths ~30 % apart
    # the BI is the chord angle ratio at the reference resolution delta = P/NREF
    # on the fitted curve: 1 / (sqrt(1 + rho^2) - rho), rho = w / delta
    rho = r.rounding * NREF
    assert r.bi == pytest.approx(1 / (np.sqrt(1 + rho ** 2) - rho), rel=0.05)
    assert r.verdict == "backlash"


@pytest.mark.parametrize("cycles", [30, 79, 80, 81, 200])
def test_a_long_record_reads_the_index_of_its_parts(cycles):
    # more apices than the pooled fit takes (MAX_APEX): it reads runs of
    # three neighbours spread over the record, and a middle slope between
    # each two. Spread one by one, neighbours were skipped: at 80 cycles no
    # middle slope was read (no index: a day of a level cycling every 18
    # minutes read insufficient-data), at 79-82 two to four of them. The
    # rounding is one of the fit's own widths, so that the index does not
    # jump between two neighbouring widths as the apices taken change
    from valvediag.analysis.bi import MAX_APEX, W_GRID

    h, P = 1.0, 400.0
    w = float(W_GRID[16]) * P
    t = np.arange(int(cycles * P)) * h
    x = hyperbolic_wave(t, P, w) + np.random.default_rng(1).normal(0.0, 0.002 * P, t.size)
    whole = backlash_index(x, h)
    part = backlash_index(x[:int(20 * P)], h)
    assert whole.verdict == part.verdict == "backlash"
    assert whole.bi == pytest.approx(part.bi, rel=0.02)
    # a middle slope is read between every two neighbours taken
    assert np.isfinite(whole.theta_middle).sum() >= min(2 * cycles - 3, 2 * (MAX_APEX // 3))


def hyperbolic_sawtooth(t, P, w, rise=0.15):
    """Sawtooth of unit amplitude, rising over ``rise`` of the period and falling
    over the rest, whose corners are the robust method's model: the slope turns
    as ``tau / sqrt(tau^2 + w^2)`` between the ramps' slopes."""
    R, F = rise * P, (1 - rise) * P
    m, b = 0.5 * (1 / R - 1 / F), 0.5 * (1 / R + 1 / F)
    ph = t % P
    near_peak = (ph >= R / 2) & (ph < R + F / 2)
    tau = np.where(near_peak, ph - R, np.where(ph < R / 2, ph, ph - P))
    g = tau / np.sqrt(tau ** 2 + w ** 2)
    slope = m - b * np.where(near_peak, g, -g)
    return np.cumsum(slope) * (t[1] - t[0])


@pytest.mark.parametrize("cycles", [81, 90, 120])
def test_a_long_sawtooth_reads_both_its_ramps(cycles):
    # a sawtooth's middle slopes differ between its fast and its slow ramp:
    # the neighbours taken from a long record read both, as many of each,
    # and the index is that of its first twenty cycles
    from valvediag.analysis.bi import W_GRID

    h, P = 1.0, 400.0
    t = np.arange(int(cycles * P)) * h
    x = hyperbolic_sawtooth(t, P, float(W_GRID[12]) * P)
    x = x + np.random.default_rng(2).normal(0.0, 0.002, t.size)
    whole = backlash_index(x, h)
    part = backlash_index(x[:int(20 * P)], h)
    assert whole.bi == pytest.approx(part.bi, rel=0.05)
    assert whole.verdict == part.verdict


@pytest.mark.parametrize("w_share,expected", [(0.005, "stiction"), (0.03, "backlash")])
def test_robust_bi_of_a_sawtooth_reads_its_rounding_not_its_unequal_ramps(w_share, expected):
    # a level under a net inflow cycles in a sawtooth (fast rise, slow fall);
    # its corners are as round as a triangle's with the same rounding width,
    # and so is its BI: the fast ramp must not shift the chord onto the slow
    # side and read the rounding several times over (a sticky valve's corner
    # behind a lag of 0.5 % of the period read BI 3-4 before)
    h, P = 1.0, 500.0
    t = np.arange(12000) * h
    r = backlash_index(hyperbolic_sawtooth(t, P, w_share * P), h)
    rho = r.rounding * NREF
    assert r.rounding == pytest.approx(w_share, rel=0.3)   # grid of widths ~30 % apart
    assert r.bi == pytest.approx(1 / (np.sqrt(1 + rho ** 2) - rho), rel=0.1)
    assert r.verdict == expected


@pytest.mark.parametrize("method", ["paper", "robust"])
def test_clean_simulations(method):
    kw = dict(kc=2.0, ti=20.0, tau=20.0, sample_time=0.1, duration=3000, sp_step=1.0)
    sticky = simulate_loop(valve="kano", valve_params={"S": 3.0, "J": 1.5}, **kw).pv[5000:]
    loose = simulate_loop(valve="backlash", valve_params={"DB": 3.0}, **kw).pv[5000:]
    assert backlash_index(sticky, 0.1, method=method).verdict == "stiction"
    assert backlash_index(loose, 0.1, method=method).verdict == "backlash"


@pytest.fixture(scope="module")
def noisy_backlash():
    sim = simulate_loop(kc=1.2, ti=30.0, tau=25.0, sample_time=1.0, duration=6000, sp_step=1.0,
                        valve="backlash", valve_params={"DB": 2.0})
    pv = sim.pv[1000:]
    return pv + np.random.default_rng(0).normal(0, 0.01 * np.ptp(pv), pv.size)


@pytest.mark.parametrize("method", ["paper", "robust"])
def test_invariant_to_scale_offset_and_time_unit(noisy_backlash, method):
    ref = backlash_index(noisy_backlash, 1.0, method=method)
    scaled = backlash_index(1000.0 * noisy_backlash + 537.0, 1.0, method=method)
    minutes = backlash_index(noisy_backlash, 1.0 / 60.0, method=method)
    assert scaled.bi == pytest.approx(ref.bi, rel=1e-6)
    assert minutes.bi == pytest.approx(ref.bi, rel=1e-6)
    assert scaled.verdict == minutes.verdict == ref.verdict
    assert minutes.period == pytest.approx(ref.period / 60.0, rel=1e-9)


def test_robust_survives_noise_where_the_paper_method_fails(noisy_backlash):
    assert backlash_index(noisy_backlash, 1.0, method="robust").verdict == "backlash"
    assert backlash_index(noisy_backlash, 1.0, method="paper").verdict != "backlash"


def test_robust_ignores_drift():
    t = np.arange(6000) * 1.0
    tri = triangle(t, 200.0)
    drifting = tri + 0.002 * t + 0.3 * np.sin(2 * np.pi * t / 6000)
    r = backlash_index(drifting, 1.0)
    assert r.verdict == "stiction" and r.bi == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("method,lo,hi", [("paper", 1.5, 3.0), ("robust", 2.2, 2.4)])
def test_thresholds(method, lo, hi):
    assert THRESHOLDS[method] == (lo, hi)
    assert bi_verdict(lo, method) == "stiction"
    assert bi_verdict(hi, method) == "backlash"
    assert bi_verdict(0.5 * (lo + hi), method) == "undecided"
    assert bi_verdict(np.inf, method) == "backlash"
    assert bi_verdict(np.nan, method) == "insufficient-data"
    assert bi_verdict(2.0, method, thresholds=(1.0, 1.9)) == "backlash"


def average_export(f, n, h, t0=0.37, sub=200):
    """``n`` samples of ``f`` as an average export records them: each the
    mean of ``f`` over the sample time ``h`` that ends at its time stamp."""
    tf = t0 + (np.arange(n * sub) + 0.5) / sub * h
    return f(tf).reshape(n, sub).mean(axis=1)


@pytest.mark.parametrize("w", [0.0, 0.3, 2.0])
@pytest.mark.parametrize("tau", [-3.2, -0.4, 0.0, 0.2, 1.7])
def test_the_averaged_corner_is_the_mean_of_the_corner_over_its_sample(w, tau):
    from valvediag.analysis.bi import _corner_basis

    u = tau + np.linspace(-0.5, 0.5, 200001)
    corner, tail = _corner_basis(tau, w, 1.0)
    # the trapezoid rule's error on a grid of 1/200000 sample is below 1e-6
    assert corner == pytest.approx(np.trapezoid(-(np.sqrt(u * u + w * w) - w), u), abs=1e-6)
    assert tail == pytest.approx(np.trapezoid(np.where(u > 0, u * u, 0.0), u), abs=1e-6)


def test_an_average_export_of_a_triangle_reads_stiction_when_its_averaging_is_given():
    # 12.4 samples a period: averaging over the sample rounds each sharp turn
    # over one sample, which read as sampled is a valve turning over 8 % of
    # the period
    h, P = 1.0, 12.4
    pv = average_export(lambda t: triangle(t, P), 400, h)
    assert backlash_index(pv, h).verdict == "backlash"
    r = backlash_index(pv, h, averaging_time=h)
    assert r.bi == pytest.approx(1.0, abs=0.02)
    assert r.verdict == "stiction" and r.averaging_time == h


@pytest.mark.parametrize("P,w_share", [(14.3, 0.03), (20.3, 0.02)])
def test_an_average_export_of_a_rounded_turn_reads_as_the_turn_sampled(P, w_share):
    h = 1.0
    wave = lambda t: hyperbolic_wave(t, P, w_share * P)
    sampled = backlash_index(wave(np.arange(600) * h + 0.37), h)
    averaged = backlash_index(average_export(wave, 600, h), h, averaging_time=h)
    assert averaged.verdict == sampled.verdict == "backlash"
    assert averaged.bi == pytest.approx(sampled.bi, rel=0.02)
    assert averaged.rounding == pytest.approx(w_share, rel=0.3)   # grid of widths ~30 % apart


def test_too_few_cycles_is_insufficient_data():
    t = np.arange(300) * 1.0
    r = backlash_index(triangle(t, 250.0), 1.0)
    assert r.verdict == "insufficient-data"
    assert "cycles" in r.reason and np.isnan(r.bi)


@pytest.mark.parametrize("pv,kw,match", [
    (np.r_[np.sin(np.arange(100.0)), np.nan, np.sin(np.arange(100.0))], {}, "non-finite values \\(first at sample 100\\)"),
    (np.full(200, 3.0), {}, "constant"),
    (np.arange(5.0), {}, "at least two cycles"),
    (np.ones((10, 10)), {}, "one-dimensional"),
])
def test_bad_input(pv, kw, match):
    with pytest.raises(ValueError, match=match):
        backlash_index(pv, 1.0, **kw)


@pytest.mark.parametrize("averaging_time", [-1.0, np.nan, np.inf])
def test_bad_averaging_time(averaging_time):
    with pytest.raises(ValueError, match="averaging_time"):
        backlash_index(np.sin(np.arange(200) / 5), 1.0, averaging_time=averaging_time)


def test_bad_time():
    pv = np.sin(np.arange(200) / 5)
    t = np.arange(200.0)
    t[50] = t[49] - 1
    with pytest.raises(ValueError, match="time does not increase at sample 50"):
        backlash_index(pv, time=t)
    t2 = np.cumsum(np.r_[1.0, np.random.default_rng(0).uniform(0.5, 1.5, 199)])
    with pytest.raises(ValueError, match="not uniformly sampled"):
        backlash_index(pv, time=t2)
    with pytest.raises(ValueError, match="positive"):
        backlash_index(pv, 0.0)
    with pytest.raises(ValueError, match="method"):
        backlash_index(pv, 1.0, method="magic")


def test_time_array_equals_sample_time():
    t = np.arange(4000) * 0.5
    a = backlash_index(triangle(t, 100.0), time=t + 1e6)
    b = backlash_index(triangle(t, 100.0), 0.5)
    assert a.bi == b.bi


def test_result_parts_and_plot():
    import matplotlib
    matplotlib.use("Agg")
    t = np.arange(4000) * 0.5
    r = backlash_index(triangle(t, 100.0), 0.5)
    assert r.peaks.size >= 18 and r.valleys.size >= 18
    assert r.middle.size == r.theta_middle.size
    assert r.theta_peak.size == r.peaks.size + r.valleys.size
    assert np.all(np.abs(r.bi_per_cycle[np.isfinite(r.bi_per_cycle)] - 1) < 0.05)
    ax = r.plot(zoom_cycles=3)
    assert "stiction" in ax.get_title()
    assert len(ax.get_lines()) > 5


def _lagged(x, h, tau):
    """``x`` through a first-order lag ``tau`` [s], started at its steady state."""
    from scipy.signal import lfilter

    a = np.exp(-h / tau)
    return lfilter([1 - a], [1, -a], x, zi=[a * x[0]])[0]


def test_lagged_turns_find_the_sharp_turn_behind_a_lag():
    from valvediag.analysis.bi import lagged_turns
    from valvediag.analysis.classify import sharp_behind_lag

    h, P, tau = 1.0, 500.0, 15.0                   # a lag of 3 % of the period
    t = np.arange(12000) * h
    r = backlash_index(_lagged(triangle(t, P), h, tau), h)
    assert r.verdict == "backlash"                  # what the lag does to the BI
    turns = lagged_turns(r)
    assert turns.lag == pytest.approx(tau, rel=0.3)   # lag grid ~30 % apart
    assert turns.bi <= 1.2 and turns.bi_without_lag > 2.4 and sharp_behind_lag(turns)
    ax = turns.plot()
    assert len(ax.lines) == 3


def test_lagged_turns_read_a_cycle_of_16_samples():
    """A sharp triangle of 160 s behind a 6.5 s lag, sampled every 10 s (16
    samples a period, 0.5 % noise): the index reads backlash, and the turns'
    windows of seven samples find the lag and the sharp turn behind it."""
    from valvediag.analysis.bi import lagged_turns
    from valvediag.analysis.classify import sharp_behind_lag

    hf, P, tau = 0.5, 160.0, 6.5
    x = _lagged(triangle(np.arange(43200) * hf, P), hf, tau)[::20]
    x = x + np.random.default_rng(0).normal(0, 0.005 * np.ptp(x), x.size)
    r = backlash_index(x, 10.0)
    assert r.verdict == "backlash" and r.bi > 4
    turns = lagged_turns(r)
    assert turns is not None and turns.lag == pytest.approx(tau, rel=0.3)
    assert turns.bi <= 1.5 and sharp_behind_lag(turns)


def test_a_turn_within_a_sample_is_sharp_behind_its_lag():
    """A turn fitted at 0.016 periods (Backlash Index 1.68, above the
    paper's 1.5) is 0.4 of a sample of a cycle of 234 s sampled every 10 s:
    the record cannot show it from a slip. Sampled every second, it is
    four samples long and not sharp; a lag beyond 5 % of the period is no
    short lag either way."""
    from valvediag.analysis.bi import LaggedTurns, turn_bi
    from valvediag.analysis.classify import LAG_SHARP_BI, sharp_behind_lag

    def turns(h, lag=6.9):
        return LaggedTurns(duration=0.016, lag=lag, duration_without_lag=0.04,
                           bi=turn_bi(0.016), bi_without_lag=turn_bi(0.04), sse=1.0,
                           sse_without_lag=2.0, apices=20, period=234.0, sample_time=h)

    assert turn_bi(0.016) > LAG_SHARP_BI
    assert sharp_behind_lag(turns(10.0)) and not sharp_behind_lag(turns(1.0))
    assert not sharp_behind_lag(turns(10.0, lag=0.06 * 234.0))
    assert not sharp_behind_lag(None)


@pytest.mark.parametrize("kc,ti", [(2.0, 300.0), (1.5, 250.0), (1.5, 150.0)])
def test_a_lag_behind_a_sticky_valve_puts_a_doubt_on_the_backlash_index(kc, ti):
    from valvediag import classify_loop

    # a level loop with a 10 s lag between a sticky valve and the PV (2 % of
    # the period), 1 % noise: the BI reads backlash, and the turns fitted
    # behind a lag are sharp
    sim = simulate_loop(sample_time=0.5, n_samples=43200, sp=50.0, process="integrating",
                        tau=200.0, kc=kc, ti=ti, load=50.0, lag=10.0, valve="kano",
                        valve_params={"S": 3.0, "J": 2.4}, sp_step=1.0, sp_step_time=60.0)
    pv, op = sim.pv[7200::2], sim.op[7200::2]
    pv = pv + np.random.default_rng(0).normal(0, 0.01 * np.ptp(pv), pv.size)
    d = classify_loop(pv, op, sample_time=1.0, process_type="integrating")
    lt = d.evidence["lagged_turns"]
    assert lt["lag_s"] == pytest.approx(10.0, rel=0.35) and lt["bi"] <= 1.5
    if ti >= 250.0:
        # the level turns after the OP's reversal (a slip behind the lag):
        # the turns' timing names the slip (at Kc 1.5, Ti 250 s the median
        # turn's share is 0.17, under the slip's 0.2; pooled over the turns
        # it is 0.17 at 16 standard errors)
        assert d.verdict == "stiction" and d.evidence["turn_timing"]["kind"] == "stiction"
    else:
        # stronger integral action against the ramps: the controller reverses
        # late, the timing reads nothing, and the verdict says that the turns
        # may be a lag's, at a lower confidence
        assert d.evidence["turn_timing"]["kind"] == ""
        assert d.verdict == "backlash" and "may stick instead" in d.reason, d.reason
