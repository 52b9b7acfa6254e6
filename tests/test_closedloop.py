"""Closed-loop simulator: exact discretisation, dead time, steady state."""
import numpy as np
import pytest

from valvediag import simulate_loop
from valvediag.models.closedloop import process_matrices


def test_process_matrices_integrator_with_lag_match_analytic():
    K, tau, lag, h = 2.0, 30.0, 7.0, 0.5
    pf, gf, pg, gg, nd = process_matrices("integrating", [K], [tau], [lag], [0.0], [h])
    a = np.exp(-h / lag)
    # lag state z' = (v - z)/lag; y' = K z / tau, held input over h
    assert pg[0, 0, 0] == pytest.approx(a)
    assert gg[0, 0] == pytest.approx(1 - a)
    assert pg[0, 1, 0] == pytest.approx(K / tau * lag * (1 - a))
    assert gg[0, 1] == pytest.approx(K / tau * (h - lag * (1 - a)))
    assert nd[0] == 0 and np.allclose(pf[0], np.eye(2)) and np.allclose(gf[0], 0)


def test_process_matrices_first_order():
    K, T, h = 1.5, 12.0, 2.0
    _, _, pg, gg, _ = process_matrices("self-regulating", [K], [T], [0.0], [0.0], [h])
    a = np.exp(-h / T)
    assert pg[0, 1, 1] == pytest.approx(a)
    assert gg[0, 1] == pytest.approx(K * (1 - a))


def test_steady_state_without_excitation():
    sim = simulate_loop(kc=2, ti=30, tau=20, sample_time=1, duration=500, sp=42.0,
                        valve="kano", valve_params={"S": 3, "J": 1})
    assert np.all(sim.pv == 42.0)
    assert np.ptp(sim.op) == 0


def test_fractional_dead_time_is_exact():
    # integrating process, load step at t=0: the PV must not move before the
    # dead time, then ramp at -K*L/tau exactly (the controller has not acted yet)
    h, theta, K, tau, L = 1.0, 2.5, 1.0, 10.0, 1.0
    sim = simulate_loop(kc=1.0, ti=1e9, tau=tau, process_gain=K, dead_time=theta,
                        sample_time=h, n_samples=6, load_step=L, load_step_time=0.0)
    t = sim.t
    expected = -K * L / tau * np.clip(t - theta, 0, None)
    np.testing.assert_allclose(sim.pv[:4], expected[:4], atol=1e-12)
    assert sim.pv[2] == 0.0 and sim.pv[3] == pytest.approx(-0.05)


def test_scenarios_vectorised_equal_single_runs():
    kw = dict(ti=[20.0, 30.0, 40.0], tau=20, lag=[0.0, 5.0, 2.0], dead_time=[0.0, 3.3, 7.0],
              sample_time=0.5, duration=400, sp_step=1.0)
    many = simulate_loop(kc=[2.0, 1.5, 3.0], valve=["kano", "backlash", "linear"],
                         valve_params={"S": 3.0, "J": 1.5, "DB": 2.0}, **kw)
    for i, (valve, vp) in enumerate([("kano", {"S": 3.0, "J": 1.5}), ("backlash", {"DB": 2.0}),
                                     ("linear", {})]):
        one = simulate_loop(kc=[2.0, 1.5, 3.0][i], valve=valve, valve_params=vp,
                            **{k: (v[i] if isinstance(v, list) else v) for k, v in kw.items()})
        np.testing.assert_allclose(many.pv[i], one.pv, atol=1e-12)


def test_sticky_valve_makes_a_limit_cycle_and_a_linear_valve_settles():
    kw = dict(kc=2.0, ti=50.0, tau=50.0, sample_time=0.5, duration=3000, sp_step=1.0)
    sticky = simulate_loop(valve="kano", valve_params={"S": 3.0, "J": 1.5}, **kw)
    linear = simulate_loop(**kw)
    late = slice(3000, None)
    assert np.ptp(sticky.pv[late]) > 0.3
    assert np.ptp(linear.pv[late]) < 1e-3
    assert linear.pv[-1] == pytest.approx(1.0, abs=1e-3)


def test_output_limits_hold():
    sim = simulate_loop(kc=5.0, ti=20.0, tau=10.0, sample_time=0.5, duration=200,
                        sp_step=5.0, op_limits=(-1.0, 1.0))
    assert sim.op.max() <= 1.0 and sim.op.min() >= -1.0


def test_noise_is_seeded_and_reproducible():
    kw = dict(kc=1.0, ti=20.0, tau=10.0, sample_time=1.0, duration=100, noise_std=0.1,
              load_noise_std=0.05)
    a, b = simulate_loop(seed=3, **kw), simulate_loop(seed=3, **kw)
    c = simulate_loop(seed=4, **kw)
    np.testing.assert_array_equal(a.pv, b.pv)
    assert not np.array_equal(a.pv, c.pv)


def test_bad_arguments():
    with pytest.raises(ValueError, match="kc"):
        simulate_loop(kc=0.0, ti=1.0, sample_time=1.0, duration=10)
    with pytest.raises(ValueError, match="ti and sample_time"):
        simulate_loop(kc=1.0, ti=1.0, sample_time=-1.0, duration=10)
    with pytest.raises(TypeError, match="duration"):
        simulate_loop(kc=1.0, ti=1.0, sample_time=1.0)
    with pytest.raises(ValueError, match="process must be"):
        simulate_loop(kc=1.0, ti=1.0, sample_time=1.0, duration=10, process="stable")
    with pytest.raises(TypeError, match="valve_params"):
        simulate_loop(kc=1.0, ti=1.0, sample_time=1.0, duration=10, valve="kano")


def test_plot(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    sim = simulate_loop(kc=1.0, ti=20.0, tau=10.0, sample_time=1.0, duration=100, sp_step=1.0)
    ax = sim.plot()
    assert len(ax.get_lines()) == 2


def test_an_equal_percentage_valve_settles_where_its_characteristic_says():
    # self-regulating, K = 1, no load: the steady-state flow equals the PV, so
    # after a set-point step from 50 to 60 the valve sits at the inverse of its
    # characteristic, x0 + log1p(c (60 - x0)) / c, not at 60
    c = 0.05
    kw = dict(kc=0.5, ti=5.0, sample_time=0.5, duration=400.0, process="self-regulating",
              tau=5.0, sp=50.0, sp_step=10.0, sp_step_time=10.0)
    lin = simulate_loop(**kw)
    eq = simulate_loop(**kw, valve_curvature=c)
    assert lin.op[-1] == pytest.approx(60.0, abs=1e-6)
    assert eq.op[-1] == pytest.approx(50.0 + np.log1p(c * 10.0) / c, abs=1e-6)
    assert eq.pv[-1] == pytest.approx(60.0, abs=1e-6)
    np.testing.assert_array_equal(simulate_loop(**kw, valve_curvature=0.0).pv, lin.pv)
    with pytest.raises(ValueError, match="valve_curvature"):
        simulate_loop(**kw, valve_curvature=np.inf)
