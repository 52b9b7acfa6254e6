"""Set-point steps read as bump tests of a level's valve."""
import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest

from valvediag.analysis.bumps import (BUMP_Z, MIN_BUMPS_AGAINST, MIN_SIDE, SCREEN_SHIFT_MAX,
                                     SCREEN_STEPS, setpoint_bumps, setpoint_process_screen)
from valvediag.analysis.classify import classify_loop
from valvediag.analysis.quality import white_noise_std
from valvediag.models.closedloop import simulate_loop
from valvediag.analysis.signature import loop_sense
from valvediag.synth.cases import alternating_steps, benchmark_rng, draw_loop


def p_only_level(seed, valve, valve_params=None, sense=1.0, h=5.0, n=17_280, tau=300.0,
                 size=(2.0, 4.0), noise=0.05):
    """A day of a proportional-only level under a wandering load, with set-point steps."""
    rng = np.random.default_rng(seed)
    sp = alternating_steps(rng, n, every_s=(1500.0, 3000.0), size=size, sample_time=h)
    t = np.arange(n) * h
    knots = np.arange(0.0, n * h + 901.0, 900.0)
    load = np.interp(t, knots, np.cumsum(rng.normal(0.0, 0.8, knots.size)))
    r = simulate_loop(kc=1.5 * sense, ti=1e12, sample_time=h, n_samples=n, process="integrating",
                      process_gain=sense, tau=tau, valve=valve, valve_params=valve_params,
                      sp=50.0, load=50.0 * sense, load_profile=load * sense, sp_profile=sp,
                      noise_std=noise, seed=seed)
    return r.pv, r.op, r.sp, h


def level_bending(seed, against, h=10.0, n=8640, rate=2e-4, alternate=True):
    """Hand-built: a level whose slope turns smoothly at each set-point step, the
    kick's way or against it (``against``: which steps, by their order), and a
    proportional controller's OP computed from it. Steps that alternate in
    sign every 25-50 minutes make a level that bends against each one
    zig-zag at a period of about 75 minutes, as regular as a cycle
    (Thornhill's regularity 5-46); ``alternate=False`` gives each step a
    random sign, and the level wanders."""
    rng = np.random.default_rng(seed)
    sp = 50.0 + alternating_steps(rng, n, every_s=(1500.0, 3000.0), size=(2.5, 3.5),
                                  sample_time=h)
    if not alternate:
        moves = np.diff(sp, prepend=sp[0])
        sign = np.random.default_rng(seed + 100).choice((-1.0, 1.0), n)
        sp = 50.0 + np.cumsum(np.abs(moves) * sign)
    t = np.arange(n) * h
    slope = np.zeros(n)
    for i, k in enumerate(np.flatnonzero(np.diff(sp)) + 1):
        way = np.sign(sp[k] - sp[k - 1]) * (-1.0 if against(i) else 1.0)
        slope += way * rate * 0.5 * (1.0 + np.tanh((t - t[k] - 150.0) / 60.0))
    pv = 50.0 + np.cumsum(slope) * h + rng.normal(0.0, 0.02, n)
    op = 40.0 + 1.5 * (sp - pv) + rng.normal(0.0, 0.03, n)
    return pv, op, sp, h


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_level_whose_valve_follows_answers_every_setpoint_kick(seed, sense):
    pv, op, sp, h = p_only_level(seed, "linear", sense=sense)
    b = setpoint_bumps(pv, op, sp, h)
    assert b.sense == sense
    assert b.steps >= 30
    assert b.against == 0 and not b.found
    assert b.answered == b.steps and np.all(b.z >= BUMP_Z)


@pytest.mark.parametrize("valve, params", [("linear", None), ("kano", {"S": 4.0, "J": 2.0})])
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_setpoint_steps_smaller_than_the_pvs_noise_are_read(seed, valve, params):
    """An entered set point stands still between the operator's moves, so each
    of its moves is a step, however small against the PV's noise: steps of
    1.2-2.2 % under 0.8 % of noise (three standard deviations 2.4 %) kick the
    OP by 1.8-3.3 %. Each is read, and a valve that follows its OP is not read
    against any of them."""
    pv, op, sp, h = p_only_level(seed, valve, params, size=(1.2, 2.2), noise=0.8)
    d = np.abs(np.diff(sp))
    moves = np.flatnonzero(d) + 1
    assert moves.size >= 30 and d.max() < 3.0 * white_noise_std(pv)
    b = setpoint_bumps(pv, op, sp, h)
    # all but a step within MIN_SIDE samples of the record's end
    assert b.steps == np.count_nonzero(moves <= sp.size - MIN_SIDE)
    if valve == "linear":
        assert b.against == 0 and not b.found


@pytest.mark.parametrize("seed", [0, 1])
def test_a_setpoint_step_averaged_over_a_sample_is_one_step(seed):
    """An export of 15 s means: a step that falls within a mean moves the set
    point at two samples running, and is read as one step."""
    pv, op, sp, h = p_only_level(seed, "linear", size=(1.2, 2.2), noise=0.8)
    pv, op, sp = (x.reshape(-1, 3).mean(axis=1) for x in (pv, op, sp))
    split = np.flatnonzero(np.diff(np.flatnonzero(np.diff(sp))) == 1)
    assert split.size >= 10
    b = setpoint_bumps(pv, op, sp, 3 * h)
    steps = np.flatnonzero(np.diff(p_only_level(seed, "linear", size=(1.2, 2.2))[2]))
    assert b.steps == np.count_nonzero(steps < 3 * (sp.size - MIN_SIDE))
    assert b.against == 0 and not b.found


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_sticky_level_valve_holds_through_the_kicks(seed):
    pv, op, sp, h = p_only_level(seed, "kano", {"S": 4.0, "J": 2.0})
    b = setpoint_bumps(pv, op, sp, h)
    assert b.found
    # the valve held through most kicks, and the level went its own way
    assert b.against >= b.steps / 2
    assert "moved against the OP" in b.reason


@pytest.mark.parametrize("seed", [0, 2])
def test_a_tight_level_kept_at_one_sample_a_minute_is_not_read_against_its_kicks(seed):
    """A level that answers its kick in about 40 s, kept at every 60 s: the
    level answers its valve within a sample, and the controller's answer to
    the noise reads the loop's sense the wrong way round (where the minute's
    samples fall against the steps decides it: seed 1's reads it right).
    The OP's kicks give the sense, and every step answers the kick, as at
    5 s. Read in the wrong sense, the record's OP shows the kick at one
    sample and has moved past it at the next, and the integral of the OP
    reads against the level (36-37 of 37 steps): such steps, whose kick has
    faded two samples on, are not counted either. A sticky valve kept so
    still holds its kick and is found."""
    pv, op, sp, h = p_only_level(seed, "linear", tau=60.0)
    assert setpoint_bumps(pv, op, sp, h).answered >= 30
    pv, op, sp, h = pv[::12], op[::12], sp[::12], 12 * h
    assert loop_sense(pv, op) == -1.0                          # the misreading
    b = setpoint_bumps(pv, op, sp, h)
    assert (b.sense, b.sense_source) == (1.0, "the set-point kicks")
    assert b.answered >= 30 and b.against == 0 and not b.found
    b = setpoint_bumps(pv, op, sp, h, sense=-1.0)
    assert np.sum(b.z <= -BUMP_Z) >= MIN_BUMPS_AGAINST       # the hazard of that sense
    assert b.against < MIN_BUMPS_AGAINST and not b.found
    assert np.all(b.held[b.z <= -BUMP_Z] < 0.5)
    pv, op, sp, h = p_only_level(seed, "kano", {"S": 4.0, "J": 2.0}, tau=60.0)
    assert setpoint_bumps(pv[::12], op[::12], sp[::12], 12 * h).found


def fast_level(seed, valve="linear", valve_params=None, kc=2.0, ti=25.0, h=1.0, n=14_400):
    """Four hours of a small, fast level (integrating time 20 s) at 1 s, its set
    point stepped every few minutes, its load wandering within a minute or two."""
    rng = np.random.default_rng(seed)
    sp = alternating_steps(rng, n, every_s=(150.0, 300.0), size=(2.0, 4.0), sample_time=h)
    t = np.arange(n) * h
    knots = np.arange(0.0, n * h + 91.0, 90.0)
    load = np.interp(t, knots, np.cumsum(rng.normal(0.0, 1.0, knots.size)))
    r = simulate_loop(kc=kc, ti=ti, sample_time=h, n_samples=n, process="integrating",
                      tau=20.0, valve=valve, valve_params=valve_params, sp=50.0, load=50.0,
                      load_profile=load, sp_profile=sp, noise_std=0.05, seed=seed)
    return r.pv, r.op, r.sp, h


@pytest.mark.parametrize("seed", [0, 1, 5])
def test_a_fast_level_is_read_over_its_own_time_not_ten_minutes(seed, monkeypatch):
    """A level that halves its error within seconds of a step, read over all the
    minutes between its steps, has its OP's integral answer the load: steps read
    against the OP (the hazard, asserted with the window in seconds alone). Read
    over ten half-times, none does; a sticky valve on the same level is found."""
    import valvediag.analysis.bumps as bumps

    pv, op, sp, h = fast_level(seed)
    b = setpoint_bumps(pv, op, sp, h)
    assert b.steps >= 60 and b.against == 0 and b.answered >= b.steps - 1
    pv_s, op_s, sp_s, _ = fast_level(seed, "kano", {"S": 4.0, "J": 2.0}, kc=1.5, ti=1e12)
    assert setpoint_bumps(pv_s, op_s, sp_s, h).found
    monkeypatch.setattr(bumps, "RESPONSE_WINDOWS", 1e9)
    assert setpoint_bumps(pv, op, sp, h).against >= MIN_BUMPS_AGAINST


def test_one_step_against_the_kick_is_not_a_fault():
    for n_against, found in ((1, False), (MIN_BUMPS_AGAINST, True)):
        pv, op, sp, h = level_bending(0, against=lambda i: i < n_against)
        b = setpoint_bumps(pv, op, sp, h)
        assert b.against == n_against
        assert b.found is found
        assert b.answered >= b.steps / 2


def test_classify_reads_the_steps_only_on_a_level():
    # steps of random sign: the level does not zig-zag as a cycle would
    pv, op, sp, h = level_bending(1, against=lambda i: True, alternate=False)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    # no slip of the level's slope (its turns are smooth): sticky or loose
    assert d.verdict == "undecided"
    assert d.evidence["setpoint_bumps"]["found"]
    assert "set-point steps as bump tests" in d.reason
    # a flow answers a kick in its PV, not its slope: the steps are not read
    d = classify_loop(pv, op, sp, sample_time=h, process_type="self-regulating")
    assert "setpoint_bumps" not in d.evidence
    # the level that bends the kick's way is no valve fault
    pv, op, sp, h = level_bending(1, against=lambda i: False, alternate=False)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict == "no-oscillation"
    assert not d.evidence["setpoint_bumps"]["found"]


def test_a_record_without_steps_reads_nothing_and_plots():
    pv, op, sp, h = p_only_level(0, "linear", n=2000)
    flat = np.full(pv.size, 50.0)
    b = setpoint_bumps(pv, op, flat, h)
    assert not b.found and b.steps == 0
    assert "no set-point step" in b.reason
    import matplotlib.pyplot as plt

    b = setpoint_bumps(*p_only_level(0, "kano", {"S": 4.0, "J": 2.0}))
    ax = b.plot()
    assert ax.get_title().startswith(f"{b.against} of {b.steps}")
    plt.close("all")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_slip_steps_the_slope_by_more_than_a_following_valve(seed):
    from valvediag.analysis.bumps import SLIP_OVER_FOLLOWING, kinks_over_following
    from valvediag.analysis.signature import stick_slip_events

    ratios = {}
    for valve, params in (("linear", None), ("kano", {"S": 4.0, "J": 2.0})):
        pv, op, sp, h = p_only_level(seed, valve, params)
        kinks = stick_slip_events(pv, op, h, process="integrating", sp=sp)
        ratios[valve] = kinks_over_following(kinks, setpoint_bumps(pv, op, sp, h))
    # the linear valve's kinks (too few to be a fault) are what its OP made
    # them: about its gain times the OP's change across them (0.7-2.1 here)
    assert ratios["linear"] < SLIP_OVER_FOLLOWING / 2.0
    # a slip is the valve's jump, far beyond what the OP did across it
    assert ratios["kano"] > 10 * SLIP_OVER_FOLLOWING


def test_op_across_a_kink_is_the_mean_after_less_the_mean_before():
    from valvediag.analysis.signature import pooled_stick_slip_events, stick_slip_events

    pv, op, sp, h = p_only_level(2, "kano", {"S": 4.0, "J": 2.0})
    kinks = stick_slip_events(pv, op, h, process="integrating", sp=sp)
    w = kinks.step
    assert kinks.index.size >= 3 and kinks.op_across.size == kinks.index.size
    expected = [op[k:k + w].mean() - op[k - w:k].mean() for k in kinks.index]
    np.testing.assert_allclose(kinks.op_across, expected, rtol=1e-9, atol=1e-9)
    # pooled stretches keep each stretch's, in turn
    half = pv.size // 2
    parts = [stick_slip_events(pv[a:b], op[a:b], h, process="integrating", sp=sp[a:b])
             for a, b in ((0, half), (half, pv.size))]
    pooled = pooled_stick_slip_events(parts, record_s=pv.size * h)
    np.testing.assert_array_equal(pooled.op_across,
                                  np.concatenate([r.op_across for r in parts]))


@pytest.mark.parametrize("seed,index", [(1, 4), (16, 5), (14, 6)])
def test_a_healthy_level_whose_kinks_its_op_made_is_not_called_sticky(seed, index):
    """Healthy levels of the realistic benchmark's generator (PI control, set-point
    steps, a wandering load with pump steps) whose kinks the reader takes for
    slips: the OP's change across each, through the valve's gain read at the
    set-point steps, makes most of the slope step the kink shows (the median
    over the kinks reads 0.9-1.5 on these three). A fourth, study seed 24
    loop 2 (4.1), no longer reads a fault from its kinks alone (3 of 9 are
    valve events, where 3 of 3 were): a kink after a stretch over which the
    level held still while the OP crept says nothing of the valve."""
    from valvediag.analysis.bumps import SLIP_OVER_FOLLOWING
    from valvediag.analysis.signature import stick_slip_events
    from valvediag.synth.cases import benchmark_rng, draw_loop

    rng = benchmark_rng("level-healthy", seed, index)
    loop = draw_loop("level-healthy", rng)
    kinks = stick_slip_events(loop.pv, loop.op, loop.sample_time, process="integrating",
                              sp=loop.sp)
    assert kinks.found and kinks.kind == "stiction"      # what the kinks alone say
    d = classify_loop(loop.pv, loop.op, loop.sp, sample_time=loop.sample_time,
                      process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason
    assert d.evidence["kinks_followed"]["ratio"] < SLIP_OVER_FOLLOWING
    assert d.evidence["setpoint_bumps"]["answered"] >= 3


def test_a_fault_found_by_setpoint_steps_is_not_sized():
    from valvediag.scan.loop import signature_size

    pv, op, sp, h = level_bending(1, against=lambda i: True, alternate=False)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    size = signature_size(d.evidence, "stiction")
    assert np.isnan(size["S"]) and size["confidence"] == 0.0
    assert "set-point steps" in size["reason"]


def test_a_cascade_set_point_that_moves_at_every_sample_has_no_step_to_read():
    pv, op, sp, h = p_only_level(0, "linear")
    rng = np.random.default_rng(5)
    moving = sp + np.cumsum(rng.normal(0.0, 1.0, sp.size))       # a master's output
    b = setpoint_bumps(pv, op, moving, h)
    assert b.steps == 0 and not b.found
    assert "steady samples either side" in b.reason


def test_bad_input_is_named():
    pv, op, sp, h = p_only_level(0, "linear", n=2000)
    with pytest.raises(ValueError, match="one length"):
        setpoint_bumps(pv, op[:-1], sp, h)
    with pytest.raises(ValueError, match="sample_time"):
        setpoint_bumps(pv, op, sp, 0.0)
    assert "only 10 samples" in setpoint_bumps(pv[:10], op[:10], sp[:10], h).reason


def pi_flow(seed, h=2.0, n=21_600, kc=0.5, gain=1.0):
    """A day of a PI flow loop under a wandering load, with set-point steps."""
    rng = np.random.default_rng(seed)
    sp = alternating_steps(rng, n, every_s=(1500.0, 3000.0), size=(2.0, 4.0), sample_time=h)
    t = np.arange(n) * h
    knots = np.arange(0.0, n * h + 901.0, 900.0)
    load = np.interp(t, knots, np.cumsum(rng.normal(0.0, 0.3, knots.size)))
    r = simulate_loop(kc=kc, ti=20.0, sample_time=h, n_samples=n, process="self-regulating",
                      process_gain=gain, tau=10.0, valve="linear", sp=50.0, load=0.0,
                      load_profile=load, sp_profile=sp, noise_std=0.3, seed=seed)
    return r.pv, r.op, r.sp, h


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_op_comes_back_after_a_levels_setpoint_steps(seed, sense):
    pv, op, sp, h = p_only_level(seed, "linear", sense=sense)
    s = setpoint_process_screen(pv, op, sp, h)
    assert s.steps >= 30
    assert s.process == "integrating", s.reason
    assert abs(s.shift_over_kick) + 2 * s.standard_error < SCREEN_SHIFT_MAX


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_sticky_levels_op_settles_anywhere_in_its_band_and_reads_no_flow(seed):
    # the OP rests wherever in the stick band the valve caught: the shifts
    # scatter, which may leave the process unnamed, never a flow's
    pv, op, sp, h = p_only_level(seed, "kano", {"S": 4.0, "J": 2.0})
    s = setpoint_process_screen(pv, op, sp, h)
    assert s.steps >= 30
    assert s.process != "self-regulating", s.reason


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("kc,gain", [(0.5, 1.0), (1.0, 0.5), (-0.3, -2.0)])
def test_the_op_settles_away_after_a_flows_setpoint_steps(seed, kc, gain):
    pv, op, sp, h = pi_flow(seed, kc=kc, gain=gain)
    s = setpoint_process_screen(pv, op, sp, h)
    assert s.process == "self-regulating", s.reason
    # the lasting shift over the kick is the loop gain's reciprocal, 1 / (K Kc)
    assert s.shift_over_kick == pytest.approx(1.0 / (kc * gain), rel=0.25)


def test_too_few_setpoint_steps_name_no_process():
    pv, op, sp, h = p_only_level(0, "linear")
    k = np.flatnonzero(np.diff(sp))[SCREEN_STEPS - 1] + 1
    s = setpoint_process_screen(pv[:k], op[:k], sp[:k], h)
    assert s.steps == SCREEN_STEPS - 1
    assert s.process == "unknown" and "need" in s.reason
    with pytest.raises(ValueError, match="one length"):
        setpoint_process_screen(pv, op[:-1], sp, h)


def test_a_sticky_level_of_unknown_type_has_its_kinks_read_after_the_screen():
    pv, op, sp, h = p_only_level(2, "kano", {"S": 4.0, "J": 2.0})
    d = classify_loop(pv, op, sp, sample_time=h, process_type="unknown")
    assert d.evidence["setpoint_screen"]["process"] == "integrating"
    assert d.verdict in ("stiction", "undecided"), d.reason
    assert "data test: the OP after the set-point steps" in d.reason
    assert d.process_screen == "integrating"        # the result names the type the data read
    # a healthy flow of unknown type is read as self-regulating, and keeps its valve
    pv, op, sp, h = pi_flow(0)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="unknown")
    assert d.evidence["setpoint_screen"]["process"] == "self-regulating"
    assert d.verdict == "no-oscillation", d.reason
    assert d.process_screen == "self-regulating"


def test_a_registry_that_names_the_wrong_process_is_doubted():
    # a flow registered as a level, and a level registered as a flow: the
    # verdict says what the OP after the set-point steps read
    pv, op, sp, h = pi_flow(1)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert "registry names the process integrating" in d.reason
    assert "settles away" in d.evidence["registry_doubt"]
    pv, op, sp, h = p_only_level(1, "linear")
    d = classify_loop(pv, op, sp, sample_time=h, process_type="self-regulating")
    assert "check the registry" in d.reason and "comes back" in d.evidence["registry_doubt"]
    # a registry that is right raises no doubt
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert "registry_doubt" not in d.evidence and "check the registry" not in d.reason


def test_the_setpoint_kicks_give_the_sense_where_the_noise_answer_misreads_it():
    """A healthy level of the realistic benchmark kept at one sample in 30 s:
    the level answers its valve within a sample, so the controller's answer to
    the PV's noise reads the loop's sense the wrong way round and every step
    went against the OP (``undecided`` before). The OP's kicks at the steps
    read the sense right, upside down too (a reverse-acting loop)."""
    loop = draw_loop("level-healthy", benchmark_rng("level-healthy", 10, 2))
    k = int(round(30.0 / loop.sample_time))
    pv, op, sp, h = loop.pv[::k], loop.op[::k], loop.sp[::k], k * loop.sample_time
    assert loop_sense(pv, op) == -1.0          # the misreading this guards against
    b = setpoint_bumps(pv, op, sp, h)
    assert (b.sense, b.sense_source) == (1.0, "the set-point kicks")
    assert b.steps >= MIN_BUMPS_AGAINST and b.against == 0 and not b.found
    assert setpoint_bumps(100.0 - pv, op, 100.0 - sp, h).sense == -1.0
