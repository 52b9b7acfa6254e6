"""Model workbench: the chain, the fit, the residual views, the size estimate."""
import inspect
import math
import re
import time

import numpy as np
import pytest
from scipy.signal import lfilter

from valvediag import simulate_loop
from valvediag.models.closedloop import process_matrices
from valvediag.synth.cases import alternating_steps
from valvediag.workbench import (
    EFFECTS,
    LoopModel,
    WorkbenchDataError,
    check_effects,
    estimate_valve_size,
    forward_select,
    prepare_loop,
    suggest_effects,
)
from valvediag.workbench.data import growing_swing
from valvediag.workbench.diagnosis import event_average, valve_breakaways
from valvediag.workbench.fit import Problem, Theta, zoh_matrices
from valvediag.workbench.sensor import pv_grid, quantised_mean


def _sim(**kw):
    base = dict(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, duration=2 * 3600, sp_step=1.0,
                valve="backlash", valve_params={"DB": 3.0}, noise_std=0.0, seed=1)
    base.update(kw)
    return simulate_loop(**base)


@pytest.fixture(scope="module")
def clean_backlash():
    """Noise-free loop: backlash, dead time and lag, integrating plant."""
    sim = _sim(dead_time=7.0, lag=12.0)
    return sim, prepare_loop(sim.pv, sim.op, 1.0)


# -- the chain ------------------------------------------------------------------------------
@pytest.mark.parametrize("process", ["integrating", "self-regulating"])
@pytest.mark.parametrize("lag", [0.0, 4.0, 30.0])
def test_zoh_matrices_match_process_matrices(process, lag):
    h, tau = 1.5, 25.0
    t = 1.0 if process == "integrating" else tau
    _, _, pg, gg, _ = process_matrices(process, [1.0], [t], [lag], [0.0], [h])
    ref = (pg[0, 0, 0], pg[0, 0, 1], pg[0, 1, 0], pg[0, 1, 1], gg[0, 0], gg[0, 1])
    mine = zoh_matrices(process, lag, t, h)
    used = (2, 3, 5) if lag == 0 else range(6)   # without a lag the z state is unused
    for i in used:
        assert mine[i] == pytest.approx(ref[i], abs=1e-12)


def test_chain_reproduces_the_simulator(clean_backlash):
    """Driven by the measured OP with the true parameters, the chain gives the
    simulated valve position exactly, and the PV to rounding without a lag
    (exact ZOH, fractional dead time). With a lag, the lag state keeps a
    trace of the unknown initial valve position at the burn-in (1e-4)."""
    sim, data = clean_backlash
    fit = LoopModel(("deadband", "dead_time", "lag")).evaluate(data, Theta(DB=3.0, delay=7.0, lag=12.0))
    b = data.burn_in
    np.testing.assert_allclose(fit.valve[b:], sim.mv[b:], atol=1e-12)
    assert fit.params["gain"] == pytest.approx(1 / 60, rel=1e-3)
    assert fit.train_rmse < 1e-4 and fit.heldout_rmse < 1e-4
    assert fit.fit_pct > 99.9
    sim2 = _sim(dead_time=6.5)
    data2 = prepare_loop(sim2.pv, sim2.op, 1.0)
    fit2 = LoopModel(("deadband", "dead_time")).evaluate(data2, Theta(DB=3.0, delay=6.5))
    assert fit2.params["gain"] == pytest.approx(1 / 60, rel=1e-9)
    assert fit2.train_rmse < 1e-9 and fit2.heldout_rmse < 1e-9


def test_signals_are_kept(clean_backlash):
    _, data = clean_backlash
    fit = LoopModel(("deadband", "dead_time", "lag")).evaluate(data, Theta(DB=3.0, delay=7.0, lag=12.0))
    for name in ("op", "valve", "delayed", "lagged", "load", "plant_input", "pv", "pv_model", "residual"):
        assert getattr(fit, name).shape == (data.n,)
    b = data.burn_in
    np.testing.assert_allclose(fit.delayed[b:], fit.valve[b - 7:-7])
    np.testing.assert_allclose(fit.plant_input, fit.lagged - fit.load)
    with pytest.raises(Exception):
        fit.fit_pct = 0.0          # frozen


def test_kernel_score_equals_direct_residual(clean_backlash):
    """The batch kernel's inner-product SSE equals the residual of the full
    evaluation, with load columns (bias, drift) in the model."""
    _, data = clean_backlash
    noisy = prepare_loop(data.pv + 0.01 * np.random.default_rng(0).standard_normal(data.n),
                         data.op, 1.0)
    prob = Problem(noisy, ("deadband", "dead_time", "lag", "bias", "drift"))
    th = Theta(DB=2.5, delay=5.5, lag=9.0)
    sc = prob.score([th, th.replace(DB=3.0)])
    ev = prob.evaluate(th)
    e = ev["residual"]
    assert sc[0, 0] == pytest.approx(np.nansum(e[prob.sample_set == 0] ** 2), rel=1e-7)
    assert sc[0, 1] == pytest.approx(np.nansum(e[prob.sample_set == 1] ** 2), rel=1e-7)
    assert sc[0, 2] == pytest.approx(ev["gain"], rel=1e-7)


def test_kernel_scores_only_the_stored_pv_samples(clean_backlash):
    """With ``pv_points='stored'`` the kernel's SSE is the residual's over the
    samples a historian stored, and a record whose every sample is stored
    scores as before."""
    from valvediag.synth.plant import swinging_door

    _, data = clean_backlash
    pv = data.pv + 0.01 * np.random.default_rng(0).standard_normal(data.n)
    t = np.arange(data.n, dtype=float)
    keep = np.flatnonzero(swinging_door(pv, 0.04, t=t))
    stored = prepare_loop(np.interp(t, keep, pv[keep]), data.op, 1.0, pv_points="stored")
    scored = stored.sample_set >= 0
    assert 0 < scored.sum() < 0.5 * (stored.seg_set >= 0).sum() * stored.horizon
    assert set(np.flatnonzero(scored)) <= set(keep)
    effects = ("deadband", "dead_time", "lag", "bias", "drift")
    th = Theta(DB=2.5, delay=5.5, lag=9.0)
    prob = Problem(stored, effects)
    sc = prob.score([th, th.replace(DB=3.0)])
    e = prob.evaluate(th)["residual"]
    assert np.isnan(e[~scored]).all()
    assert sc[0, 0] == pytest.approx(np.nansum(e[prob.sample_set == 0] ** 2), rel=1e-7)
    assert sc[0, 1] == pytest.approx(np.nansum(e[prob.sample_set == 1] ** 2), rel=1e-7)
    every = Problem(prepare_loop(pv, data.op, 1.0), effects).score([th])
    same = Problem(prepare_loop(pv, data.op, 1.0, pv_points="stored"), effects).score([th])
    np.testing.assert_allclose(same, every, rtol=1e-9)
    with pytest.raises(WorkbenchDataError, match="pv_points"):
        prepare_loop(pv, data.op, 1.0, pv_points="some")


def test_reinit_at_the_measured_pv(clean_backlash):
    """Segments re-initialised at the measured PV: the kernel still equals
    the direct residual, the truth still fits exactly on clean data, and with
    PV noise the error is about sqrt(2) times that of the fitted start."""
    sim, data = clean_backlash
    m = LoopModel(("deadband", "dead_time", "lag", "bias"))
    th = Theta(DB=3.0, delay=7.0, lag=12.0)
    clean = prepare_loop(sim.pv, sim.op, 1.0, reinit="measured")
    assert m.evaluate(clean, th).heldout_rmse < 1e-4
    pv = sim.pv + 0.01 * np.random.default_rng(5).standard_normal(sim.pv.size)
    meas = prepare_loop(pv, sim.op, 1.0, reinit="measured")
    prob = Problem(meas, m.effects)
    sc = prob.score([th.replace(DB=2.5)])
    ev = prob.evaluate(th.replace(DB=2.5))
    assert sc[0, 0] == pytest.approx(np.nansum(ev["residual"][prob.sample_set == 0] ** 2), rel=1e-7)
    r_meas = m.evaluate(meas, th).heldout_rmse
    r_fit = m.evaluate(prepare_loop(pv, sim.op, 1.0), th).heldout_rmse
    assert r_fit == pytest.approx(0.01, rel=0.1)
    assert r_meas == pytest.approx(np.sqrt(2) * 0.01, rel=0.15)
    with pytest.raises(WorkbenchDataError):
        prepare_loop(pv, sim.op, 1.0, reinit="zero")


@pytest.mark.parametrize("process, reinit", [("integrating", "fit"),
                                              ("self-regulating", "fit"),
                                              ("self-regulating", "measured")])
def test_free_response_removed_per_segment(clean_backlash, process, reinit):
    """Each segment's free response (a constant for an integrator, a**j for a
    first-order plant) leaves the columns as the segment's least-squares
    projection, or from its first value when re-initialised at the measured
    PV; samples not scored stay zero."""
    sim, _ = clean_backlash
    data = prepare_loop(sim.pv, sim.op, 1.0, reinit=reinit)
    prob = Problem(data, ("deadband",), process)
    qa = prob.qa(Theta(tau=40.0))
    X = np.random.default_rng(3).standard_normal((data.n, 3)) + np.arange(data.n)[:, None] / 50
    out = prob.project(X, qa)
    scored = prob.sample_set >= 0
    assert np.all(out[~scored] == 0.0)
    for a, b in zip(data.seg_start, data.seg_end):
        k = a + np.flatnonzero(scored[a:b])
        if k.size < 2:
            continue
        w = qa ** (k - a)
        if reinit == "measured":
            expect = X[k] - w[:, None] * X[k[0]]
        else:
            coef = w @ X[k] / (w @ w)
            expect = X[k] - w[:, None] * coef
        np.testing.assert_allclose(out[k], expect, rtol=1e-9, atol=1e-9)
    # a single signal gives the same as its column
    np.testing.assert_allclose(prob.project(X[:, 1], qa), out[:, 1], rtol=0, atol=0)


@pytest.mark.parametrize("process", ["integrating", "self-regulating"])
def test_load_columns_through_the_plant_per_set(clean_backlash, process):
    """The load columns the scores use are the load signals through the plant
    (unit gain, held per sample), each segment's free response removed, and
    split by sample set."""
    sim, _ = clean_backlash
    data = prepare_loop(sim.pv, sim.op, 1.0)
    prob = Problem(data, ("deadband", "drift", "oscillating_load"), process)
    th = Theta(tau=40.0, load_period=300.0)
    B = prob.basis(th)
    h = data.sample_time
    if process == "integrating":
        resp = lfilter([0.0, h], [1.0, -1.0], B, axis=0)
    else:
        a = math.exp(-h / th.tau)
        resp = lfilter([0.0, 1.0 - a], [1.0, -a], B, axis=0)
    W = prob.project(resp, prob.qa(th))
    WT = prob.setup(th)["WT"]
    for s in (0, 1):
        expect = np.where((prob.sample_set == s)[:, None], W, 0.0)
        np.testing.assert_allclose(WT[s].T, expect, rtol=1e-9, atol=1e-9 * np.abs(W).max())


def test_correct_model_on_clean_data_fits_close_to_100(clean_backlash):
    _, data = clean_backlash
    fit = LoopModel(("deadband", "dead_time", "lag")).fit(data)
    assert fit.fit_pct > 99.5
    assert fit.params["DB"] == pytest.approx(3.0, rel=0.01)
    assert fit.params["dead_time"] == pytest.approx(7.0, abs=0.5)
    assert fit.params["lag"] == pytest.approx(12.0, rel=0.03)


def test_wrong_model_on_clean_data_fits_worse(clean_backlash):
    _, data = clean_backlash
    assert LoopModel(("deadband",)).fit(data).fit_pct < 95


def test_stiction_kano_recovered_and_bias_jointly():
    """Kano valve with a load offset: S, J and the offset from one fit (the
    (S-J)/2 offset and the bias are fitted jointly)."""
    sim = _sim(valve="kano", valve_params={"S": 3.0, "J": 1.0}, load=2.0, noise_std=0.002)
    fit = LoopModel(("stiction", "bias")).fit(prepare_loop(sim.pv, sim.op, 1.0))
    assert fit.params["S"] == pytest.approx(3.0, rel=0.03)
    assert fit.params["J"] == pytest.approx(1.0, rel=0.05)
    assert fit.derived["load_offset"] == pytest.approx(2.0, rel=0.02)
    assert fit.derived["valve_model"] == "kano"


@pytest.mark.parametrize("offset, scale", [(0.0, 1.0), (50.0, 3.0)], ids=["plain", "shifted"])
def test_self_regulating_plant(offset, scale):
    """Also with PV and OP at an operating point (offset 50, scaled by 3):
    the same fit in the new units."""
    rng = np.random.default_rng(3)
    sim = _sim(process="self-regulating", process_gain=1.5, tau=30.0, kc=1.3, ti=20.0,
               valve="kano", valve_params={"S": 3.0, "J": 1.0}, duration=3 * 3600)
    pv = sim.pv + 0.01 * rng.standard_normal(sim.pv.size)
    data = prepare_loop(offset + scale * pv, offset + scale * sim.op, 1.0)
    fit = LoopModel(("stiction",), "self-regulating").fit(data)
    assert fit.params["gain"] == pytest.approx(1.5, rel=0.05)
    assert fit.params["tau"] == pytest.approx(30.0, rel=0.1)
    assert fit.params["S"] == pytest.approx(3.0 * scale, rel=0.05)
    assert fit.fit_pct_train > 90
    if scale == 1.0:
        assert fit.fit_pct > 90
    # Not asserted for the scaled record: one slip of its held-out part clears
    # the fitted valve's threshold by 0.0002 % of travel, so whether the model
    # slips there turns on the fourth significant digit of the fitted S
    # (3.000096 against 9.000581 / 3 on one machine), which moves with the
    # processor's rounding; a missed slip holds the model's valve for 70
    # samples (held-out fit 70 %).


def test_held_op_samples_get_a_rest_tolerance():
    """Every other OP sample held (compression): a held sample is not a rest
    for the Kano valve in 'auto' (plain Kano sees false rests and inflates J)."""
    sim = _sim(valve="kano", valve_params={"S": 3.0, "J": 1.0}, duration=3 * 3600, seed=3)
    pv = sim.pv + 0.01 * np.random.default_rng(3).standard_normal(sim.pv.size)
    op = sim.op.copy()
    op[1::2] = op[0:-1:2]
    data = prepare_loop(pv, op, 1.0)
    assert data.held_fraction > 0.4 and data.hold_run == 1
    auto = LoopModel(("stiction",)).fit(data)
    assert auto.derived["rest_tolerance"] == 1
    # S within 5 %; J is weakly determined in so regular a cycle (it trades
    # off against the gain): within 50 %, and nearer than plain Kano's
    assert auto.params["S"] == pytest.approx(3.0, rel=0.05)
    assert auto.params["J"] == pytest.approx(1.0, rel=0.5)
    plain = LoopModel(("stiction",), valve_model="kano").fit(data)
    assert "rest_tolerance" not in plain.derived
    assert abs(plain.params["J"] - 1.0) > abs(auto.params["J"] - 1.0)


# -- effects and data ---------------------------------------------------------------------------
def test_effect_names_and_units():
    assert check_effects("dead_time, deadband") == ("deadband", "dead_time")
    with pytest.raises(ValueError, match="unknown effect"):
        check_effects(("deadband", "friction"))
    # the operating point ('bias') is part of every model
    assert LoopModel(("deadband", "stiction")).effects == ("stiction", "bias")
    assert LoopModel(("deadband", "stiction")).name == "stiction"
    assert "bias" not in LoopModel(()).candidates()
    for e in EFFECTS.values():
        for p in e.params:
            assert p.unit and p.bounds and p.kind in ("searched", "linear", "read")
    assert "deadband" not in LoopModel(("stiction",)).candidates()


@pytest.mark.parametrize("pv,op,match", [
    (np.zeros(100), np.zeros(100), "too short"),
    (np.sin(np.arange(2000) / 30), np.full(2000, 40.0), "never moves"),
    (np.zeros(2000), np.linspace(0, 50, 2000), "does not oscillate"),
    (np.zeros(2000), np.zeros(1999), "samples"),
    (np.full(2000, 3.5), 40 + 5 * np.sin(np.arange(2000) / 30), "the PV never moves"),
    # three reversals in the record: too few to tell a band from the process
    (np.sin(np.arange(2000) / 30), 40 + 5 * np.sin(np.arange(2000) / 200), "reverses only 3 times"),
    # the PV runs away under an oscillating OP (an open or unstable loop)
    (np.arange(2000) / 10 + np.sin(np.arange(2000) / 30), 40 + 5 * np.sin(np.arange(2000) / 30),
     "the PV diverges"),
    # an unstable loop: PV and OP oscillate ever wider about their means
    (np.exp(np.arange(4000) / 1000) * np.sin(np.arange(4000) / 30),
     40 + 5 * np.exp(np.arange(4000) / 1000) * np.sin(np.arange(4000) / 30 + 1),
     "the OP's swing grows from window to window"),
])
def test_bad_data_one_line_errors(pv, op, match):
    with pytest.raises(WorkbenchDataError, match=match) as exc:
        prepare_loop(pv, op, 1.0)
    assert "\n" not in str(exc.value)


def test_growing_swing_reads_an_unstable_loop_and_passes_set_point_moves():
    """A swing that grows linearly (an unstable loop behind a dead band) or
    exponentially is read; a steady oscillation, a loop moved by set-point
    steps of random size, and a limit cycle that grows and settles are not."""
    t = np.arange(8000.0)
    wave = np.sin(t / 40)
    assert growing_swing(wave * (1 + t / 200)) is not None
    g = growing_swing(wave * np.exp(t / 2000))
    assert g is not None and g[1] / g[0] > 4
    assert growing_swing(wave) is None
    rng = np.random.default_rng(3)
    steps = np.repeat(rng.uniform(-3, 3, 16), 500)
    assert growing_swing(steps + 0.1 * rng.standard_normal(t.size)) is None
    assert growing_swing(wave * np.minimum(1 + t / 500, 6.0)) is None


@pytest.mark.parametrize("placeholder", [-9999.0, 9.9e37])
def test_a_placeholder_sample_does_not_wreck_the_fit(clean_backlash, placeholder):
    sim, data = clean_backlash
    pv = sim.pv.copy()
    pv[pv.size // 2] = placeholder
    model = LoopModel(("deadband", "dead_time", "lag"))
    clean, spiked = model.fit(data), model.fit(prepare_loop(pv, sim.op, 1.0))
    assert spiked.fit_pct > 90 and abs(spiked.params["DB"] - clean.params["DB"]) < 0.05


def test_missing_samples_are_left_out(clean_backlash):
    sim, _ = clean_backlash
    pv = sim.pv.copy()
    pv[3000:3010] = np.nan
    data = prepare_loop(pv, sim.op, 1.0)
    bad = (data.seg_start <= 3009) & (data.seg_end > 3000)
    assert np.all(data.seg_set[bad] == -1)
    fit = LoopModel(("deadband", "dead_time", "lag")).evaluate(data, Theta(DB=3.0, delay=7.0, lag=12.0))
    assert np.isnan(fit.pv_model[3000:3010]).all() and fit.heldout_rmse < 1e-4


def test_no_resampling_and_blocks_alternate(clean_backlash):
    sim, data = clean_backlash
    assert data.n == sim.pv.size and data.sample_time == 1.0
    used = data.seg_set[data.seg_set >= 0]
    assert used[0] == 0 and used[-1] == 0 and set(used) == {0, 1}
    assert data.burn_in > data.reversals[0]


# -- residual views ---------------------------------------------------------------------------
def test_diagnosis_views(clean_backlash):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim, _ = clean_backlash
    pv = sim.pv + 0.01 * np.random.default_rng(1).standard_normal(sim.pv.size)
    data = prepare_loop(pv, sim.op, 1.0)
    fit = LoopModel(("deadband",)).fit(data)
    dg = fit.diagnose()
    assert len(dg.worst) == 5 and dg.worst[0].rms >= dg.worst[-1].rms
    assert all(w.labels for w in dg.worst)
    assert dg.acf[0] == pytest.approx(1.0)
    assert dg.acf_band == pytest.approx(2.5758 / math.sqrt((fit.sample_set >= 0).sum()), rel=1e-3)
    assert dg.ccf.shape == dg.ccf_band.shape == dg.ccf_lags.shape
    # the missing dead time and lag leave the residual correlated with the OP
    assert dg.ccf_outside > 0.1
    assert dg.rev_count >= 10
    for view in dg.VIEWS:
        ax = dg.plot(view)
        assert ax.get_title()
        plt.close("all")
    fit.plot()
    fit.plot_chain()
    plt.close("all")


def test_event_average_and_breakaways():
    x = np.zeros(100)
    x[20:30] = 1.0
    x[60:70] = -1.0
    lags, m, se, c = event_average(x, [20, 60], [1, -1], 5, 5)
    assert c == 2 and np.allclose(m[5:], 1.0) and np.allclose(m[:5], 0.0)
    v = np.r_[np.zeros(10), np.arange(1, 6), np.full(10, 5.0), np.arange(4, 0, -1)]
    idx, d = valve_breakaways(v)
    assert list(idx) == [10, 25] and list(d) == [1, -1]


# -- size estimate for the scan ------------------------------------------------------------------
def test_estimate_valve_size_backlash_and_stiction():
    sim = _sim(dead_time=5.0, noise_std=0.01)
    t0 = time.perf_counter()
    out = estimate_valve_size(sim.pv, sim.op, 1.0, "backlash")
    assert time.perf_counter() - t0 < 10
    assert out["DB"] == pytest.approx(3.0, rel=0.05)
    assert out["fit_pct"] > 80 and 0.5 < out["confidence"] <= 1
    sim = _sim(valve="kano", valve_params={"S": 4.0, "J": 2.0}, noise_std=0.002)
    out = estimate_valve_size(sim.pv, sim.op, 1.0, "stiction")
    assert out["S"] == pytest.approx(4.0, rel=0.05) and out["J"] == pytest.approx(2.0, rel=0.1)
    assert out["valve_model"] == "kano"


def test_a_compressed_op_is_rebuilt_from_the_controller_law():
    from valvediag.synth.plant import exception_deadband
    from valvediag.workbench.data import rebuild_compressed_op, stored_points

    sim = _sim(noise_std=0.01)
    pv, op = sim.pv[600:], sim.op[600:]
    t = np.arange(op.size, dtype=float)
    kept = np.flatnonzero(exception_deadband(op, 0.15))     # the historian's exception
    stored = np.interp(t, kept, op[kept])                  # read back by interpolation
    rebuilt, r2 = rebuild_compressed_op(pv, stored, 1.0)
    assert r2 > 0.9
    np.testing.assert_array_equal(rebuilt[stored_points(stored)], stored[stored_points(stored)])
    err_line = np.sqrt(np.mean((stored - op) ** 2))
    err_rebuilt = np.sqrt(np.mean((rebuilt - op) ** 2))
    assert err_rebuilt < err_line / 3, (err_rebuilt, err_line)
    # every sample stored, or gaps: nothing to rebuild
    same, r2 = rebuild_compressed_op(pv, op, 1.0)
    assert same is not None and np.array_equal(same, op) and math.isnan(r2)
    gappy = stored.copy()
    gappy[100] = np.nan
    assert math.isnan(rebuild_compressed_op(pv, gappy, 1.0)[1])
    # the size fit rebuilds it and says so
    out = estimate_valve_size(pv, stored, 1.0, "backlash")
    assert "rebuilt between its stored points" in out["reason"]
    assert out["DB"] == pytest.approx(3.0, rel=0.15)


def test_a_dead_band_behind_a_compressed_pv_is_sized_on_its_stored_samples():
    """The straight lines between a compressed PV's stored points cut its
    turns short; scored as data they size a dead band small. Scored on its
    stored samples only, the size is the simulated one."""
    from valvediag.synth.plant import exception_deadband, swinging_door

    sim = _sim(duration=4 * 3600, noise_std=0.025)
    pv, op = sim.pv[600:], sim.op[600:]
    t = np.arange(pv.size, dtype=float)
    dev = 0.06 * 0.5 * np.ptp(pv)                        # 6 % of the amplitude
    exc = np.flatnonzero(exception_deadband(pv, dev / 2))
    keep = exc[swinging_door(pv[exc], dev, t=exc.astype(float))]
    read_back = np.interp(t, keep, pv[keep])
    out = estimate_valve_size(read_back, op, 1.0, "backlash")
    assert "stored samples" in out["reason"]
    assert out["DB"] == pytest.approx(3.0, rel=0.04)
    model = LoopModel(("deadband", "dead_time", "bias", "drift"))
    lines = model.fit(prepare_loop(read_back, op, 1.0))
    assert lines.params["DB"] < 0.95 * out["DB"]          # the bias the stored samples remove
    assert "stored samples" not in estimate_valve_size(pv, op, 1.0, "backlash")["reason"]


def test_suggestions_on_a_pv_scored_at_its_stored_points_read_every_segment():
    """Scored only at a compressed PV's stored points, some segments hold no
    scored sample: the evidence skips them (a NaN had entered the saturation
    evidence's means and the ranking of the worst segments, with warnings)."""
    import warnings

    from valvediag.synth.plant import swinging_door

    sim = _sim(duration=3 * 3600, noise_std=0.025)
    pv, op = sim.pv[600:], sim.op[600:]
    t = np.arange(pv.size, dtype=float)
    keep = np.flatnonzero(swinging_door(pv, 0.1 * 0.5 * np.ptp(pv), t=t))   # ~120 points
    data = prepare_loop(np.interp(t, keep, pv[keep]), op, 1.0, pv_points="stored")
    e = np.where(data.sample_set >= 0, 0.0, np.nan)
    empty = [j for j, (a, b) in enumerate(zip(data.seg_start, data.seg_end))
             if data.seg_set[j] >= 0 and not np.isfinite(e[a:b]).any()]
    assert empty                                       # the case the test is about
    base = LoopModel(("deadband",)).fit(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        sug = suggest_effects(base, ["saturation", "dead_time"])
    assert all(np.isfinite(s.evidence.statistic) for s in sug.items)


def test_too_few_stored_pv_samples_fall_back_to_every_sample():
    from valvediag.synth.plant import swinging_door

    sim = _sim(duration=2 * 3600)
    pv, op = sim.pv[600:], sim.op[600:]
    t = np.arange(pv.size, dtype=float)
    keep = np.flatnonzero(swinging_door(pv, 0.1 * np.ptp(pv), t=t))   # a few dozen points
    read_back = np.interp(t, keep, pv[keep])
    with pytest.raises(WorkbenchDataError, match="too few stored PV samples"):
        prepare_loop(read_back, op, 1.0, pv_points="stored")
    out = estimate_valve_size(read_back, op, 1.0, "backlash")
    assert np.isfinite(out["DB"]) and "stored samples" not in out["reason"]


def test_estimate_valve_size_bad_data_and_bad_fault():
    out = estimate_valve_size(np.zeros(500), np.full(500, 30.0), 1.0, "stiction")
    assert math.isnan(out["S"]) and out["confidence"] == 0.0 and "never moves" in out["reason"]
    with pytest.raises(ValueError):
        estimate_valve_size(np.zeros(500), np.zeros(500), 1.0, "leak")


# -- documentation (as test_docs.py does for the core modules) -------------------------------
def _public():
    import valvediag.workbench as wb

    for name in wb.__all__:
        obj = getattr(wb, name)
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj):
            for mname, m in vars(obj).items():
                if inspect.isfunction(m) and not mname.startswith("_"):
                    yield f"{name}.{mname}", m


@pytest.mark.parametrize("qual,func", list(_public()), ids=lambda x: x if isinstance(x, str) else "")
def test_workbench_documents_every_parameter(qual, func):
    doc = inspect.getdoc(func) or ""
    assert doc, f"{qual} has no docstring"
    params = [p for p in inspect.signature(func).parameters.values()
              if p.name not in ("self", "cls") and p.kind is not p.VAR_POSITIONAL]
    if not params:
        return
    assert "Parameters\n----------" in doc, f"{qual} has no Parameters section"
    section = doc.split("Parameters\n----------", 1)[1].split("\n\nReturns", 1)[0]
    documented = set()
    for line in section.splitlines():
        m = re.match(r"^(\*{0,2}[\w, *]+?)\s*:", line)
        if m and not line.startswith(" "):
            documented.update(n.strip().lstrip("*") for n in m.group(1).split(","))
    missing = [p.name for p in params if p.name not in documented]
    assert not missing, f"{qual}: undocumented parameters {missing}"


def _suggestions_plain_and_shifted(pv, op, sp, start=("deadband",)):
    """(scale, suggestions from ``start``) for the record as it is and with
    PV, OP and SP offset by 50 and scaled by 3."""
    for off, sc in ((0.0, 1.0), (50.0, 3.0)):
        data = prepare_loop(off + sc * pv, off + sc * op, 1.0, sp=off + sc * sp)
        yield sc, forward_select(data, start, max_steps=1).steps[0].suggestions


# -- the installed valve characteristic ----------------------------------------------------
def _characteristic_loop(curvature, seed=3, hours=3.0):
    """A dead-band valve with an installed characteristic, PI on an
    integrator, set-point steps every 25-50 min, 1 % PV noise."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600)
    sp = alternating_steps(rng, n)
    sim = simulate_loop(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, n_samples=n, sp_profile=sp,
                        noise_std=0.002, seed=seed, valve="backlash", valve_params={"DB": 3.0},
                        valve_curvature=curvature)
    pv = sim.pv + 0.01 * np.ptp(sim.pv[n // 10:]) * rng.standard_normal(n)
    return pv, sim.op, sp


@pytest.mark.parametrize("curvature", [0.1, -0.1])
def test_a_curved_valve_characteristic_is_found_and_sized_whatever_the_operating_point(curvature):
    """Equal-percentage (c > 0) and quick-opening (c < 0): ranked first and
    accepted behind a dead-band model, its curvature within 25 %, and the
    same with PV, OP and SP offset by 50 and scaled by 3 (the curvature, in
    1/OP unit, a third)."""
    pv, op, sp = _characteristic_loop(curvature)
    found = []
    for sc, sug in _suggestions_plain_and_shifted(pv, op, sp):
        top = sug.items[0]
        assert top.effect == "characteristic" and top.accepted, sug.table()
        assert top.params["curvature"] * sc == pytest.approx(curvature, rel=0.25)
        found.append((top.params["curvature"] * sc, top.gain))
    assert found[1] == pytest.approx(found[0], rel=1e-3)


def test_a_linear_valve_characteristic_is_not_accepted():
    pv, op, sp = _characteristic_loop(0.0)
    sug = forward_select(prepare_loop(pv, op, 1.0, sp=sp), ("deadband",),
                         max_steps=1).steps[0].suggestions
    assert not next(s for s in sug.items if s.effect == "characteristic").accepted
    assert not sug.best


# -- the PV read on a grid -----------------------------------------------------------------
def test_quantised_mean_is_the_expected_reading():
    """Against a Monte Carlo of the quantiser behind Gaussian noise; a hard
    staircase without noise; the input itself once the noise spans a step."""
    rng = np.random.default_rng(1)
    y = np.linspace(3.1, 7.9, 25)
    q, o = 0.5, 0.2
    for s in (0.05, 0.15, 0.3):
        n = s * rng.standard_normal((200_000, 1))
        mc = (o + q * np.round((y + n - o) / q)).mean(axis=0)
        # Monte Carlo standard error: at most 0.5 q / sqrt(200000) = 0.00056
        assert np.abs(quantised_mean(y, q, o, s) - mc).max() < 0.003
    assert np.array_equal(quantised_mean(y, q, o, 0.0), o + q * np.round((y - o) / q))
    assert np.array_equal(quantised_mean(y, q, o, q), y)


def test_pv_grid_reads_the_step_and_refuses_a_continuous_pv():
    rng = np.random.default_rng(2)
    x = 3.0 * np.sin(np.arange(5000) / 100.0) + 0.05 * rng.standard_normal(5000)
    g = pv_grid(0.2 + 0.5 * np.round((x - 0.2) / 0.5))
    assert g.found and g.step == pytest.approx(0.5, rel=1e-9)
    assert abs((g.offset - 0.2) / 0.5 - round((g.offset - 0.2) / 0.5)) < 1e-9
    assert not pv_grid(x).found                      # every reading distinct
    stale = np.round(x, 1)
    stale[::97] += 0.0123                            # readings off the grid
    assert not pv_grid(stale).found


def _quantised_loop(quantum, seed=5, hours=3.0):
    """A dead-band valve, PI on an integrator, set-point steps, the PV read
    on a grid of ``quantum`` noise standard deviations (1 % of the swing).
    Returns the record and the RMSE of a perfect model of the reading."""
    rng = np.random.default_rng(seed)
    n = int(hours * 3600)
    sp = alternating_steps(rng, n)
    sim = simulate_loop(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, n_samples=n, sp_profile=sp,
                        noise_std=0.002, seed=seed, valve="backlash", valve_params={"DB": 3.0})
    sigma = 0.01 * np.ptp(sim.pv[n // 10:])
    pv = sim.pv + sigma * rng.standard_normal(n)
    if quantum:
        step = quantum * sigma
        pv = step * np.round(pv / step)
        floor = np.sqrt(np.mean((pv - quantised_mean(sim.pv, step, 0.0, sigma))[n // 10:] ** 2))
    else:
        floor = sigma
    return pv, sim.op, sp, floor


def test_a_pv_read_on_a_grid_is_found_whatever_the_operating_point():
    """A grid of 15 noise deviations: the quantiser is ranked first and
    accepted behind a dead-band model, its step is the grid's, the error
    ends within 1.3 times that of a perfect model of the reading (a model
    of the process value alone leaves the staircase's error, q / sqrt(12):
    about 1.5 times it), and PV, OP and SP
    offset by 50 and scaled by 3 change neither the ranking nor the error
    ratio."""
    pv, op, sp, floor = _quantised_loop(15.0)
    found = []
    for sc, sug in _suggestions_plain_and_shifted(pv, op, sp):
        top = sug.items[0]
        assert top.effect == "quantisation" and top.accepted, sug.table()
        assert top.params["quant_step"] == pytest.approx(sc * pv_grid(pv).step, rel=1e-6)
        assert sug.base.heldout_rmse > 1.4 * sc * floor
        assert top.heldout_rmse < 1.3 * sc * floor, sug.table()
        found.append(top.heldout_rmse / sug.base.heldout_rmse)
    assert found[1] == pytest.approx(found[0], rel=1e-3)


def test_a_continuous_pv_gets_no_quantiser():
    pv, op, sp, _ = _quantised_loop(0.0)
    sug = forward_select(prepare_loop(pv, op, 1.0, sp=sp), ("deadband",),
                         max_steps=1).steps[0].suggestions
    q = next(s for s in sug.items if s.effect == "quantisation")
    assert not q.accepted and q.evidence.statistic == 0.0
    assert "not on a grid" in q.evidence.summary


@pytest.mark.parametrize("h, period, cycles", [
    (1.0, 300.0, 50.0),      # 150 samples per period at step 2: the budget cuts to the floor
    (3.0, 300.0, 60.0),      # 100 samples per period at step 1: 6,000 samples
    (10.0, 430.0, 100.0),    # 43 samples per period: 100 periods are 4,300 samples
    (1.0, 60.0, 100.0),      # 60 samples per period: 100 periods are 6,000 samples
])
def test_a_size_fit_reads_its_periods_within_a_sample_budget(h, period, cycles):
    from valvediag.workbench import size_window
    from valvediag.workbench.kind import KIND_MAX_CYCLES, kind_window

    n = int(86_400 / h)
    a, k = size_window(n, h, period)
    assert (n - a) * h / period == pytest.approx(cycles, abs=k * h / period)
    assert (n - 1 - a) % k == 0                   # the fitted record ends at the last sample
    # the kind check keeps its periods whatever their samples
    a, k = kind_window(n, h, period=period)
    assert (n - a) * h / period == pytest.approx(KIND_MAX_CYCLES, abs=k * h / period)
