"""A set point read back from the controller's kicks (valvediag.analysis.setpoint)."""
import numpy as np
import pytest

from valvediag.analysis import classify_loop
from valvediag.analysis.setpoint import infer_setpoint
from valvediag.models import simulate_loop
from valvediag.synth.cases import alternating_steps
from valvediag.synth.plant import exception_deadband


def _loop(process, kc, ti, seed, n=6000, noise=0.05, tau=20.0):
    """A linear valve's loop under operator set-point steps, recorded at its scan."""
    rng = np.random.default_rng(seed)
    steps = alternating_steps(rng, n, every_s=(600.0, 1200.0), size=(1.0, 3.0))
    sim = simulate_loop(kc=kc, ti=ti, sample_time=1.0, n_samples=n, process=process, tau=tau,
                        sp=50.0, load=50.0 if process == "integrating" else 0.0,
                        sp_profile=steps, noise_std=noise, seed=seed)
    return sim.pv, sim.op, sim.sp


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("process,kc,ti", [("self-regulating", 0.5, 15.0),
                                           ("integrating", 1.5, 1e12),
                                           ("integrating", 2.0, 300.0)])
def test_the_set_points_steps_are_read_where_and_as_large_as_they_were(process, kc, ti, seed):
    pv, op, sp = _loop(process, kc, ti, seed)
    true = np.flatnonzero(np.diff(sp) != 0) + 1
    assert true.size >= 4
    got = infer_setpoint(pv, op)
    assert got.sp is not None, got.reason
    np.testing.assert_array_equal(got.steps, true)
    # each move within 5 % of the step (the kick less the noise's share)
    np.testing.assert_allclose(np.diff(got.sp)[true - 1], np.diff(sp)[true - 1], rtol=0.05)
    # the controller's gain, OP per PV move, opposes the PV
    assert got.gain == pytest.approx(-kc, rel=0.05)


@pytest.mark.parametrize("seed", [3, 4])
def test_a_set_point_that_wanders_without_a_step_is_not_read_as_standing(seed):
    """A cascade's inner loop: its set point, the outer loop's output,
    wanders by a few percent over tens of minutes, each sample's move far
    below a kick. No level stood; the fit's residual keeps the wander in its
    slow part, and nothing is read (the same loop under a set point that
    stood reads its level)."""
    rng = np.random.default_rng(seed)
    n = 7200
    t = np.arange(n, dtype=float)
    wander = 2.0 * np.sin(2 * np.pi * t / 1500.0) + 1.5 * np.sin(2 * np.pi * t / 4100.0 + 1.0)
    load = np.cumsum(rng.normal(0, 0.02, n))
    kw = dict(kc=0.5, ti=15.0, sample_time=1.0, n_samples=n, process="self-regulating",
              tau=20.0, sp=47.3, noise_std=0.05, seed=seed, load_profile=load)
    wandered = simulate_loop(sp_profile=wander, **kw)
    got = infer_setpoint(wandered.pv, wandered.op)
    assert got.sp is None and "wandered" in got.reason, got.reason
    stood = simulate_loop(**kw)
    assert infer_setpoint(stood.pv, stood.op).sp is not None


@pytest.mark.parametrize("seed", [3, 4])
@pytest.mark.parametrize("process,kc,ti", [("self-regulating", 0.5, 15.0),
                                           ("integrating", 2.0, 300.0),
                                           ("self-regulating", 0.5, 1e12),
                                           ("integrating", 1.5, 1e12)])
def test_a_set_point_that_stood_is_read_where_the_integral_action_holds_the_pv(
        process, kc, ti, seed):
    """No kick: the set point stood. With integral action the OP drifts by
    its gain times the PV's distance from the set point, which says where it
    stood (the PV's mean is off it by the wander's share); a proportional-only
    controller does not say, and nothing is read."""
    rng = np.random.default_rng(seed)
    n = 4000
    sim = simulate_loop(kc=kc, ti=ti, sample_time=1.0, n_samples=n, process=process, tau=20.0,
                        sp=47.3, noise_std=0.05, seed=seed,
                        load=50.0 if process == "integrating" else 0.0,
                        load_profile=np.cumsum(rng.normal(0, 0.02, n)))
    got = infer_setpoint(sim.pv, sim.op)
    assert got.steps.size == 0 and "stood" in got.reason
    if ti > 1e6:
        assert got.sp is None
    else:
        assert got.sp is not None and np.ptp(got.sp) == 0
        # within a tenth of the PV's noise
        assert got.sp[0] == pytest.approx(47.3, abs=0.005)
        # a direct-acting controller (the PV read upside down) as well
        mirrored = infer_setpoint(100.0 - sim.pv, sim.op)
        assert mirrored.sp is not None and mirrored.sp[0] == pytest.approx(52.7, abs=0.005)


def test_an_op_stored_by_exception_is_not_read_as_kicks():
    pv, op, _ = _loop("self-regulating", 0.5, 15.0, 4)
    t = np.arange(op.size, dtype=float)
    keep = np.flatnonzero(exception_deadband(op, 0.3))
    got = infer_setpoint(pv, np.interp(t, keep, op[keep]))
    assert got.sp is None
    assert "exception" in got.reason


@pytest.mark.parametrize("seed", [5, 6, 7, 8])
def test_a_level_without_its_set_point_reads_its_steps_back(seed):
    """A healthy P-only level stepped by its operator, exported without the
    set point: its steps are read back, and its valve is not called faulty."""
    pv, op, sp = _loop("integrating", 1.5, 1e12, seed, n=14400, noise=0.03, tau=200.0)
    d = classify_loop(pv, op, None, sample_time=1.0, process_type="integrating")
    read = d.evidence["setpoint_inferred"]
    assert read["read"] and read["steps"] == np.count_nonzero(np.diff(sp))
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


@pytest.mark.parametrize("klass,index", [("level-healthy", 3), ("level-healthy", 4),
                                         ("flow-healthy", 9)])
def test_healthy_valves_exported_without_their_set_point_are_not_called_sticky(klass, index):
    """Realistic benchmark draws (development seed 1) exported without their
    set point: read without the steps, their answers to them read as slips
    (``stiction``); read back from the OP's kicks, they are not."""
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop(klass, benchmark_rng(klass, 1, index))
    d = classify_loop(loop.pv, loop.op, None, sample_time=loop.sample_time,
                      process_type=loop.process_type)
    assert d.evidence["setpoint_inferred"]["read"]
    assert d.verdict == "no-oscillation", d.reason


def test_a_pumped_level_exported_without_its_set_point_rests_where_its_integral_holds_it():
    """Realistic benchmark draw (study seed 11, a level of no registered type
    under a pump's square load): exported without its set point, the set
    point that stood is read where the integral action holds the PV, and the
    loop's rests at it with the OP still name the load, as with the set point
    exported (without it, the valve signature read `stiction`)."""
    from valvediag.synth.cases import benchmark_rng, draw_loop

    klass = "level-linear-slow-load"
    loop = draw_loop(klass, benchmark_rng(klass, 11, 2))
    assert np.ptp(loop.sp) == 0
    d = classify_loop(loop.pv, loop.op, None, sample_time=loop.sample_time,
                      process_type="unknown")
    read = d.evidence["setpoint_inferred"]
    assert read["read"] and read["steps"] == 0
    assert d.verdict == "linear-oscillation" and "rests at its set point" in d.reason, d.reason


def test_records_with_nothing_to_read_say_why():
    pv, op, _ = _loop("self-regulating", 0.5, 15.0, 0)
    assert "standing still" in infer_setpoint(pv, np.full(pv.size, 40.0)).reason
    assert "the PV keeps fewer" in infer_setpoint(np.full(pv.size, 40.0), op).reason
    assert "too few" in infer_setpoint(pv[:5], op[:5]).reason
    with pytest.raises(ValueError, match="pv has"):
        infer_setpoint(pv, op[:-1])
    # missing samples are skipped, and the steps still read
    pv, op = pv.copy(), op.copy()
    pv[100:110], op[500] = np.nan, np.nan
    got = infer_setpoint(pv, op)
    assert got.sp is not None and np.all(np.isfinite(got.sp))


def test_the_read_back_set_point_plots():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pv, op, _ = _loop("integrating", 1.5, 1e12, 1)
    got = infer_setpoint(pv, op)
    fig, ax = plt.subplots()
    assert got.plot(ax) is ax
    assert len(ax.lines) == 3 and "kicks" in ax.get_title()
    plt.close(fig)
    # a set point that stood, read where the integral action holds the PV
    pv, op, _ = _loop("self-regulating", 0.5, 15.0, 2, noise=0.05)
    stood = infer_setpoint(pv[:500], op[:500])
    assert stood.sp is not None and stood.steps.size == 0, stood.reason
    fig, ax = plt.subplots()
    stood.plot(ax)
    assert "stood" in ax.get_legend().get_texts()[1].get_text()
    plt.close(fig)


def test_an_op_clipped_at_its_limit_reads_no_kicks():
    """A level whose valve closes fully against a small inflow: the OP sits at
    0 % for part of each cycle, and near it the controller's moves are cut
    short between the samples recorded (realistic benchmark sawtooth, study
    seed 17, which read 3,212 kicks where its set point never moved)."""
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop("level-stiction-sawtooth",
                     benchmark_rng("level-stiction-sawtooth", 17, 2))
    assert np.ptp(loop.sp) == 0 and np.mean(loop.op == 0.0) > 0.01
    got = infer_setpoint(loop.pv, loop.op)
    assert got.steps.size == 0, got.reason


@pytest.mark.parametrize("seed", [1, 3, 5])
def test_a_dead_loop_whose_op_winds_up_to_its_limit_is_read_without_its_set_point(seed):
    """A PV that does not answer (a valve stuck shut) under a PI controller:
    the operator steps the set point to either side of it, and the OP winds
    from limit to limit, held at 0 or 100 % for half the record. The samples
    held at the limit are the limit's, not a historian's: the steps are read
    back from the OP's kicks where it moved, and the loop is found dead
    without its set point (before, the held samples read as a record stored
    by exception, and the loop as `no-oscillation`)."""
    rng = np.random.default_rng(seed)
    n, h, kc, ti = 7200, 2.0, 0.6, 20.0
    pv = 30.0 + rng.normal(0.0, 0.05, n)
    ends = np.cumsum(rng.integers(300, 900, 24))
    offset = rng.choice([-1.0, 1.0], ends.size) * rng.uniform(2.0, 5.0, ends.size)
    sp = 30.0 + offset[np.searchsorted(ends, np.arange(n), side="right")]
    e = sp - pv
    # a PI controller whose integral stops at the OP's limits (anti-windup)
    op, i_part = np.empty(n), 40.0
    for k in range(n):
        i_part += kc * e[k] * h / ti
        op[k] = min(100.0, max(0.0, i_part + kc * e[k]))
        i_part = op[k] - kc * e[k]
    assert np.mean((op == 0.0) | (op == 100.0)) > 0.4, "the test's OP is not held at its limits"
    got = infer_setpoint(pv, op)
    assert got.sp is not None, got.reason
    # the steps that fell while the OP moved between its limits, and no others
    true = np.flatnonzero(np.diff(sp)) + 1
    seen = {k for k in true if 0.0 < op[k - 1] < 100.0 and 0.0 < op[k] < 100.0}
    assert seen and seen <= set(got.steps.tolist()) <= set(true.tolist())
    d = classify_loop(pv, op, None, sample_time=h, process_type="self-regulating")
    assert d.verdict == "insufficient-data" and "does not answer" in d.reason, d.reason
