"""Valve signature: hand-built valve traces (parallelogram, ellipse, slips) and disturbances."""
import dataclasses

import numpy as np
import pytest
from scipy.signal import lfilter

from valvediag import classify_loop, simulate_loop
from valvediag.analysis.signature import (MIN_SLIPS, SIGNATURE_LIMITS, horch_correlation,
                                          pooled_stick_slip_events, stick_slip_events,
                                          valve_signature)
from valvediag.models.valves import apply_valve

H = 1.0


def _triangle(n, period, amp=5.0):
    t = np.arange(n) * H
    return 50.0 + amp * 2 / np.pi * np.arcsin(np.sin(2 * np.pi * t / period))


def _noisy(op, noise=0.01):
    """The recorded OP: a real OP carries the PV's noise (the actuator does not follow it)."""
    return op + np.random.default_rng(7).normal(0, noise, op.size)


def _lag(x, tau):
    a = np.exp(-H / tau)
    return lfilter([1 - a], [1, -a], x - x[0]) + x[0]


def _flow(valve, op, noise=0.05, tau=5.0, seed=0):
    """A fast self-regulating process (a flow): PV = 2 x lagged valve position + noise."""
    rng = np.random.default_rng(seed)
    return 2.0 * _lag(valve, tau) + rng.normal(0, noise, op.size)


def _wandering_op(n=3000):
    """A triangular OP whose reversals wander (a slow sine beneath it): a
    valve's stick band then delays the PV by varying times, which no dead time
    or lag of a linear valve can copy."""
    t = np.arange(n) * H
    return _triangle(n, 300.0, amp=2.0) + 3.0 * np.sin(2 * np.pi * t / 1100.0)


def test_parallelogram_of_a_sticky_valve_is_stiction_with_its_size():
    op = _wandering_op()
    pv = _flow(apply_valve("kano", op, S=3.0, J=1.5), op)
    s = valve_signature(pv, _noisy(op), H, process="self-regulating")
    assert s.verdict == "stiction", s.reason
    assert s.S == pytest.approx(3.0, rel=0.3) and s.J == pytest.approx(1.5, rel=0.5)
    assert s.gain > 0.8 and s.r2_valve > 0.95 and s.stuck_share > 0.05


def test_dead_band_without_jump_is_identified_as_a_dead_band():
    op = _wandering_op()
    pv = _flow(apply_valve("backlash", op, DB=3.0), op)
    s = valve_signature(pv, _noisy(op), H, process="self-regulating")
    # the band and the absence of a jump are identified ...
    assert s.J == 0.0 and s.S == pytest.approx(3.0, rel=0.1)
    assert s.kind_gain < 0 and s.gain > 0.6
    # ... but a linear valve behind a lag already explains 96 % of this PV, and
    # the dead band adds under 3 %: not a fault that matters (the limit)
    assert s.verdict == "linear" and "adds only" in s.reason


def test_ellipse_of_a_linear_valve_behind_a_lag_is_linear():
    # a sine OP through a lag: PV against OP is an ellipse, not a valve fault
    t = np.arange(3000) * H
    op = 50 + 5 * np.sin(2 * np.pi * t / 200.0)
    pv = _flow(op, op, tau=20.0)
    s = valve_signature(pv, _noisy(op), H, process="self-regulating")
    assert s.verdict == "linear", s.reason
    assert s.r2_linear > 0.99 and s.gain < 0.4


def test_level_slope_of_a_sticky_valve_is_stiction_and_of_a_linear_valve_is_linear():
    # an integrating process (a level): the PV slope is flat while the valve
    # sticks at each reversal of the OP, then jumps by J; the OP swings little
    # more than the stick band, as in a limit cycle the valve causes
    op = _triangle(4000, 800.0, amp=3.0)
    valve = apply_valve("kano", op, S=2.0, J=1.5)
    rng = np.random.default_rng(1)
    pv = np.cumsum(0.05 * (valve - 50.0)) + rng.normal(0, 0.01, op.size)
    s = valve_signature(pv, _noisy(op), H, process="integrating")
    assert s.verdict == "stiction", s.reason
    assert s.S == pytest.approx(2.0, rel=0.3)
    lin = valve_signature(np.cumsum(0.05 * (op - 50.0)) + rng.normal(0, 0.01, op.size),
                          _noisy(op), H, process="integrating")
    assert lin.verdict == "linear", lin.reason


def test_op_that_moves_and_pv_that_does_not_is_no_response():
    op = _noisy(_triangle(3000, 600.0, amp=20.0))
    pv = 30.0 + np.random.default_rng(2).normal(0, 0.05, op.size)
    s = valve_signature(pv, op, H, process="self-regulating")
    assert s.verdict == "no-response" and "did not answer" in s.reason


def test_clipped_sine_load_on_a_level_loop_with_a_healthy_valve_is_not_a_valve_fault():
    # a non-sinusoidal external disturbance: the PV is distorted, the valve is linear
    n, h = 20000, 1.0
    t = np.arange(n) * h
    load = np.clip(1.6 * np.sin(2 * np.pi * t / 400.0), -1, 1) * 2.0
    sim = simulate_loop(process="integrating", valve="linear", sample_time=h, n_samples=n,
                        kc=2.0, ti=200.0, tau=100.0, load_profile=load, noise_std=0.002,
                        seed=3)
    pv, op = sim.pv[4000:], sim.op[4000:]
    d = classify_loop(pv, op, sample_time=h, process_type="integrating")
    assert d.verdict == "linear-oscillation", d.reason
    # the load keeps a clock's time, which the scan reads first; the valve's
    # own signature says the same
    assert d.evidence["phase_wander"]["keeps_clock"]
    sig = valve_signature(pv, op, h, process="integrating", period=d.period)
    assert sig.verdict == "linear", sig.reason


def test_horch_odd_for_square_against_triangle_even_for_anti_phase_sines():
    t = np.arange(4000) * H
    op = _triangle(4000, 400.0)
    square = np.sign(np.sin(2 * np.pi * (t - 100.0) / 400.0))
    assert horch_correlation(square, op, H, 400.0) < 0.3
    sine = np.sin(2 * np.pi * t / 400.0)
    assert horch_correlation(-sine, sine, H, 400.0) > 0.9


@pytest.mark.parametrize("kw, msg", [
    (dict(process="level"), "process must be"),
    (dict(process="integrating", sample_time=0.0), "sample_time"),
])
def test_bad_arguments_name_the_problem(kw, msg):
    args = dict(sample_time=1.0)
    args.update(kw)
    with pytest.raises(ValueError, match=msg):
        valve_signature(np.zeros(100), np.zeros(100), **args)


def test_short_or_still_records_are_unknown():
    assert valve_signature(np.arange(10.0), np.arange(10.0), 1.0,
                           process="integrating").verdict == "unknown"
    s = valve_signature(np.random.default_rng(0).normal(size=500), np.full(500, 40.0), 1.0,
                        process="self-regulating")
    assert s.verdict == "unknown" and "hardly moves" in s.reason


def test_plot_draws_the_signature():
    op = _triangle(2000, 300.0)
    s = valve_signature(_flow(apply_valve("kano", op, S=3.0, J=1.5), op), _noisy(op), H,
                        process="self-regulating")
    ax = s.plot()
    assert len(ax.lines) == 2 and ax.get_xlabel().startswith("OP")


def _slip_record(towards_sp=True, n_events=5, seed=3):
    """A flow loop at set point 50: between events the PV drifts 1.0 away from
    the set point over 300 s while the OP creeps 1 %; then the PV jumps, back
    towards the set point (a slip) or, for a load step, away from it."""
    rng = np.random.default_rng(seed)
    pv, op, out, start = [], [], 40.0, 50.0
    for i in range(n_events):
        side = 1.0 if i % 2 else -1.0
        if towards_sp:
            pv.append(np.linspace(start, 50.0 + side, 300))  # stuck: the error grows
            op.append(out - np.linspace(0, side, 300))     # the controller creeps
            pv.append(np.full(200, 50.0 - 0.3 * side))     # slip: back past the set point
            op.append(np.full(200, out - side))
            out -= side
            start = 50.0 - 0.3 * side
        else:
            pv.append(np.full(300, 50.0))                  # on set point, OP quiet
            op.append(np.full(300, out))
            pv.append(50.0 + side * 1.2 * np.exp(-np.arange(200) / 40.0))  # a load step
            op.append(out - side * 1.2 * (1 - np.exp(-np.arange(200) / 40.0)))
    pv = np.concatenate(pv) + rng.normal(0, 0.02, 500 * n_events)
    op = np.concatenate(op) + rng.normal(0, 0.01, 500 * n_events)
    return pv, op, np.full(pv.size, 50.0)


def test_slips_back_towards_the_set_point_are_stick_slip_events():
    pv, op, sp = _slip_record()
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.found and e.consistent >= 4, e.reason
    assert e.op_travel == pytest.approx(1.0, rel=0.3)
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="self-regulating")
    assert d.verdict == "stiction" and "stick-slip events" in d.reason


def _takeup_record(n_events=6, seed=5):
    """A flow loop at set point 50 with a loose valve: after each reversal the
    OP creeps 1 % through the dead band while the load pulls the PV 1.0 away;
    then the valve takes up and the PV comes back over 20 s as the OP moves on
    by another 1 %, with no jump."""
    rng = np.random.default_rng(seed)
    pv, op, out = [], [], 40.0
    for i in range(n_events):
        side = 1.0 if i % 2 else -1.0
        pv.append(np.linspace(50.0, 50.0 + side, 300))     # in the dead band
        op.append(out - np.linspace(0, side, 300))
        pv.append(np.linspace(50.0 + side, 50.0, 20))       # taken up: PV follows the OP
        op.append(out - side - np.linspace(0, side, 20))
        pv.append(np.full(180, 50.0))
        op.append(np.full(180, out - 2 * side))
        out -= 2 * side
    pv = np.concatenate(pv) + rng.normal(0, 0.02, 500 * n_events)
    op = np.concatenate(op) + rng.normal(0, 0.01, 500 * n_events)
    return pv, op, np.full(pv.size, 50.0)


def test_slips_are_told_from_dead_band_take_ups_by_the_op_during_the_jump():
    pv, op, sp = _slip_record()
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.kind == "stiction" and e.slips >= 4 and e.takeups == 0, e.reason
    pv, op, sp = _takeup_record()
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.found and e.kind == "backlash" and e.takeups >= 4 and e.slips == 0, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="self-regulating")
    assert d.verdict == "backlash" and "dead-band take-ups" in d.reason, d.reason


def test_two_slips_and_no_other_jump_make_a_snapshot_sticky():
    pv, op, sp = _slip_record(n_events=2)
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.found and e.kind == "stiction" and e.consistent == e.events == 2, e.reason
    pv, op, sp = _slip_record(n_events=1)
    assert not stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp).found
    # the same two slips in a whole day of otherwise quiet record are too few
    pv, op, sp = _slip_record(n_events=2)
    rng = np.random.default_rng(9)
    quiet = 86_400 - pv.size
    pv = np.r_[pv[0] + rng.normal(0, 0.02, quiet), pv]
    op = np.r_[op[0] + rng.normal(0, 0.01, quiet), op]
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=np.full(pv.size, 50.0))
    assert e.consistent == 2 and not e.found, e.reason


def test_a_snapshot_is_the_record_exported_not_a_stretch_cut_from_a_day():
    # two slips in a stretch of 1,000 s: a fault in a 2 h export, not in a
    # stretch of a day's record that gaps cut out
    pv, op, sp = _slip_record(n_events=2)
    for record_s, found in ((None, True), (2 * 3600.0, True), (86_400.0, False)):
        e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp, record_s=record_s)
        assert e.consistent == 2 and e.found is found, (record_s, e.reason)


def test_slips_of_a_record_cut_by_gaps_are_pooled_over_its_stretches():
    # three stretches of a day, each with one or two slips: none a fault
    # alone, all of them together are
    reads = []
    for n, seed in ((2, 3), (1, 4), (2, 5)):
        pv, op, sp = _slip_record(n_events=n, seed=seed)
        e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp, record_s=86_400.0)
        assert not e.found and e.consistent == n, e.reason
        reads.append(e)
    p = pooled_stick_slip_events(reads, record_s=86_400.0)
    assert p.found and p.kind == "stiction" and p.consistent == p.slips == 5, p.reason
    assert p.reason.startswith("over 3 stretches") and p.travel.size == 5
    assert p.op_travel == np.median(np.concatenate([r.travel for r in reads]))
    # load steps away from the set point add jumps that are no valve events
    pv, op, sp = _slip_record(towards_sp=False, n_events=4)
    load = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp, record_s=86_400.0)
    assert load.events >= 3 and load.consistent == 0, load.reason
    p = pooled_stick_slip_events(reads[:2] + [load], record_s=86_400.0)
    assert p.consistent == 3 and not p.found, p.reason
    # a slip and a take-up in two stretches of a snapshot do not agree on a kind
    pv, op, sp = _takeup_record(n_events=1)
    up = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp, record_s=7200.0)
    assert up.takeups == 1, up.reason
    assert not pooled_stick_slip_events([reads[1], up], record_s=7200.0).found
    assert pooled_stick_slip_events([reads[1], reads[1]], record_s=7200.0).found
    with pytest.raises(ValueError, match="different processes"):
        pooled_stick_slip_events([reads[0], dataclasses.replace(up, process="integrating")],
                                 record_s=7200.0)
    with pytest.raises(ValueError, match="no stretch"):
        pooled_stick_slip_events([], record_s=7200.0)


def _overshooting_slips(n_events=5, seed=11):
    """A flow loop at set point 50 behind slow integral action: between slips
    the PV stands 0.3 off the set point (the load keeps the error from
    growing) while the OP creeps 1 %; then the valve slips and the PV jumps
    2.0, far past the set point, and settles back to 0.3 on the other side."""
    rng = np.random.default_rng(seed)
    pv, op, out, at = [], [], 40.0, 50.3
    for i in range(n_events):
        side = 1.0 if i % 2 else -1.0          # the error's side: PV = 50 - 0.3 side
        pv.append(np.r_[np.linspace(at, 50.0 - 0.3 * side, 100), np.full(300, 50.0 - 0.3 * side)])
        op.append(out + side * np.r_[np.zeros(100), np.linspace(0, 1.0, 300)])
        out += side
        at = 50.0 + 1.7 * side                 # the slip: 2.0 towards and past the set point
    pv.append(np.r_[np.linspace(at, 50.0, 100), np.full(300, 50.0)])
    op.append(np.full(400, out))
    pv = np.concatenate(pv) + rng.normal(0, 0.02, 400 * (n_events + 1))
    op = np.concatenate(op) + rng.normal(0, 0.01, 400 * (n_events + 1))
    return pv, op, np.full(pv.size, 50.0)


def test_a_slip_behind_slow_integral_action_may_overshoot_the_set_point():
    # the error stands (it does not grow) and the slip closes it more than
    # six times over: still a stuck valve's slips (neither was one before
    # 2026-11-27)
    pv, op, sp = _overshooting_slips()
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.found and e.kind == "stiction" and e.consistent >= 4, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="self-regulating")
    assert d.verdict == "stiction", d.reason


def test_two_events_of_different_kinds_do_not_make_a_snapshot_faulty():
    # a slip, then a take-up: in a snapshot two events name a fault only
    # where they agree on its kind
    pv1, op1, _ = _slip_record(n_events=1)
    pv2, op2, _ = _takeup_record(n_events=1)
    pv = np.r_[pv1, pv2 - pv2[0] + pv1[-1]]
    op = np.r_[op1, op2 - op2[0] + op1[-1]]
    sp = np.full(pv.size, 50.0)
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.consistent == 2 and e.slips == 1 and e.takeups == 1, e.reason
    assert not e.found, e.reason


def test_load_steps_away_from_the_set_point_are_not_slips():
    pv, op, sp = _slip_record(towards_sp=False)
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert not e.found and e.consistent == 0, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="self-regulating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


def test_a_pv_that_ignores_set_point_moves_is_a_dead_response():
    n = 4000
    sp = 30.0 + 5.0 * (np.arange(n) // 1000 % 2)
    pv = 30.0 + np.random.default_rng(4).normal(0, 0.05, n)
    op = np.clip(20.0 + np.cumsum(sp - pv) * 0.01, 0, 100)
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="self-regulating")
    assert d.verdict == "insufficient-data" and "does not answer" in d.reason
    assert "check on site" in d.reason


def test_a_cycles_fastest_moves_are_slips_in_a_sticky_loop_and_take_ups_behind_a_dead_band():
    from valvediag import simulate_loop
    from valvediag.analysis.oscillation import detect_oscillation
    from valvediag.analysis.signature import cycle_transitions

    # closed loop, sticky flow valve: the PV jumps and the controller answers
    sim = simulate_loop(sample_time=0.5, n_samples=28800, sp=50.0, process="self-regulating",
                        tau=10.0, kc=0.8, ti=8.0, dead_time=2.0, valve="kano",
                        valve_params={"S": 3.0, "J": 0.6}, sp_step=1.0, sp_step_time=60.0)
    pv, op = sim.pv[3600::2], _noisy(sim.op[3600::2], 0.005)
    osc = detect_oscillation(pv, 1.0)
    slips, takeups = cycle_transitions(pv, op, 1.0, osc.period, osc.apex_idx, 0.03)
    assert slips >= 20 and takeups <= slips / 10, (slips, takeups)
    # a dead band driven by a triangular OP: the PV moves only as the OP moves on
    op = _triangle(6000, 300.0)
    pv = _flow(apply_valve("backlash", op, DB=2.0), op, noise=0.01)
    osc = detect_oscillation(pv, H)
    slips, takeups = cycle_transitions(pv, _noisy(op, 0.005), H, osc.period, osc.apex_idx,
                                       0.03)
    assert takeups >= 20 and slips <= takeups / 10, (slips, takeups)


def test_load_steps_between_slips_do_not_hide_them():
    """Four slips back towards the set point, each followed by a load step
    that throws the PV away from it (and a recovery as the OP moves): the
    load's jumps are not the valve's and do not count against it."""
    rng = np.random.default_rng(11)
    pv, op, out, start = [], [], 40.0, 50.0
    for i in range(4):
        side = 1.0 if i % 2 else -1.0
        pv.append(np.linspace(start, 50.0 + side, 300))       # stuck: the error grows
        op.append(out - np.linspace(0, side, 300))
        pv.append(np.full(200, 50.0 - 0.3 * side))            # slip
        op.append(np.full(200, out - side))
        out -= side
        # a load step away from the set point, then the loop recovers
        k = np.arange(300)
        pv.append(50.0 - 0.3 * side - side * 1.5 * np.exp(-k / 60.0) * (k > 0))
        op.append(out + side * 1.5 * (1 - np.exp(-k / 60.0)) * (k > 0))
        out += side * 1.5
        start = pv[-1][-1]
    pv = np.concatenate(pv) + rng.normal(0, 0.02, 3200)
    op = np.concatenate(op) + rng.normal(0, 0.01, 3200)
    sp = np.full(pv.size, 50.0)
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.found and e.kind == "stiction" and e.consistent >= 3, e.reason
    assert e.events == e.consistent, e.reason


def _level_staircase(seed=3, stick=True, sense=1.0, n=6000, wander=False, tau=200.0,
                     noise=0.02, every=600.0):
    """A level under proportional control whose inflow valve sticks: the
    outflow wanders (40 +- 2 % over 25 minutes), the OP (40 + 2 x the error,
    plus the measurement's noise) creeps as the level drifts, and the valve
    holds until the OP is 1 % away, then jumps to it (a Kano valve with
    ``J = S``). Between slips the level runs straight; each slip steps its
    slope: the valve position the slope implies is a staircase under a
    smooth OP. With ``stick=False`` the valve follows the OP (the same loop,
    healthy). With ``wander=True`` the outflow wanders at random instead
    (a straight line between random points every ``every`` seconds), so the
    level does not cycle. ``tau``: the level's integrating time [s];
    ``noise``: the measurement's standard deviation [%]."""
    rng = np.random.default_rng(seed)
    h, kc, sp = 1.0, 2.0, 50.0
    pv, valve = sp, 40.0
    out_pv, out_op = np.empty(n), np.empty(n)
    knots = 40.0 + np.cumsum(rng.normal(0, 1.0, int(n // every) + 2))
    walk = np.interp(np.arange(n), np.arange(knots.size) * every, knots)
    for k in range(n):
        load = walk[k] if wander else 40.0 + 2.0 * np.sin(2 * np.pi * k * h / 1500.0)
        meas = pv + rng.normal(0, noise)
        op = 40.0 + sense * kc * (sp - meas)
        if not stick or abs(op - valve) > 1.0:
            valve = op
        pv += sense * h * (valve - load) / tau
        out_pv[k], out_op[k] = meas, op
    return out_pv, out_op, np.full(n, sp)


def test_a_levels_staircase_of_slips_is_read_from_its_kinks():
    pv, op, sp = _level_staircase()
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert e.found and e.kind == "stiction" and e.consistent >= 4, e.reason
    assert e.consistent >= 0.75 * e.events
    assert "level ran straight" in e.reason
    # the valve that follows the OP bends the level as the OP moves: no slip
    pv, op, sp = _level_staircase(stick=False)
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert not e.found and e.consistent == 0, e.reason
    # through the classifier, on an outflow that wanders without a cycle:
    # stick-slip events; not read from a PV the historian compressed and the
    # scan drew back onto its grid
    pv, op, sp = _level_staircase(wander=True)
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="integrating")
    assert d.verdict == "stiction" and "level ran straight" in d.reason, d.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="integrating",
                      pv_compressed=True)
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason
    # a reverse-acting loop (the PV falls as the OP rises) slips the same way
    pv, op, sp = _level_staircase(sense=-1.0)
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert e.found and e.kind == "stiction", e.reason


@pytest.mark.parametrize("seed", [0, 1])
def test_a_slow_levels_slips_far_apart_are_read_over_wide_windows(seed):
    # a level that integrates slowly (2000 s) under a load that wanders over
    # hours: the valve holds for about 20 minutes between slips, and each
    # slip of 1 % steps the level's slope by 1/2000 % a second: 0.7 standard
    # errors of the hinge read over half-windows of 128 samples, 6 over 512
    # and 17 over 1,024, where a kink needs 6 (before 2026-11-28 the kinks
    # were read over at most 128: no kink, no verdict)
    pv, op, sp = _level_staircase(seed=seed, wander=True, n=40_000, tau=2000.0, noise=0.05,
                                  every=3600.0)
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert e.found and e.kind == "stiction" and e.step > 128, e.reason
    assert e.consistent >= 10, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="integrating")
    assert d.verdict == "stiction", d.reason
    # the same loop on a valve that follows the OP: no kink
    pv, op, sp = _level_staircase(seed=seed, wander=True, n=40_000, tau=2000.0, noise=0.05,
                                  every=3600.0, stick=False)
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert not e.found and e.consistent < MIN_SLIPS, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


def _stepped_level(seed, sigma=0.05, stick=True, h=1.0, every=1200.0, steps=4, g=0.002,
                   kc=1.5, hold=400.0):
    """Hand-built: a level under proportional control whose set point steps by
    3 % every ``every`` seconds, alternately up and down. With ``stick``, the
    kick moves the valve (the level's slope steps to 0.005 %/s) and the valve
    holds there while the OP comes back, until it slips ``hold`` seconds after
    the step, 70 % of the way back; else the valve follows the OP (the level's
    slope is ``g`` times the OP's move)."""
    rng = np.random.default_rng(seed)
    n = int((steps + 0.5) * every / h)
    t = np.arange(n) * h
    sp = np.full(n, 50.0)
    slope = np.zeros(n)
    for i in range(steps):
        s = (0.5 + i) * every
        way = 1.0 if i % 2 == 0 else -1.0
        sp[t >= s] += 3.0 * way
        slope += way * 0.005 * ((t >= s) & (t < s + hold))
        slope += way * 0.0015 * ((t >= s + hold) & (t < s + every))
    noise = rng.normal(0.0, sigma, n)
    if stick:
        x = 50.0 + np.cumsum(slope) * h
    else:
        x = np.empty(n)
        x[0] = 50.0
        for k in range(1, n):
            x[k] = x[k - 1] + h * g * kc * (sp[k - 1] - x[k - 1] - noise[k - 1])
    pv = x + noise
    return pv, 40.0 + kc * (sp - pv), sp, h


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_levels_slips_in_its_answer_to_setpoint_steps_are_read(seed):
    # each slip steps the level's slope by 0.0035 %/s, 400 s after a set-point
    # step: over half-windows of 128 samples, too few standard errors; the
    # windows wide enough to read it (512) hold the step, whose kick kinks
    # the level too. Read over the window cut to begin a quarter window after
    # the step, all four are slips where they are (before 2026-12-01 the
    # windows that held a step were not read: none was)
    pv, op, sp, h = _stepped_level(seed)
    e = stick_slip_events(pv, op, h, process="integrating", sp=sp)
    assert e.found and e.kind == "stiction" and e.consistent == 4, e.reason
    assert e.after_step.all()
    np.testing.assert_allclose(e.index * h, 1000.0 + 1200.0 * np.arange(4), atol=60.0)
    assert np.all(np.sign(e.size) == -np.sign(np.diff(sp)[np.flatnonzero(np.diff(sp))]))
    # two stretches pooled keep each kink's reading, in turn
    parts = [stick_slip_events(pv[a:b], op[a:b], h, process="integrating", sp=sp[a:b])
             for a, b in ((0, 2400), (2400, pv.size))]
    pooled = pooled_stick_slip_events(parts, record_s=pv.size * h)
    np.testing.assert_array_equal(pooled.after_step,
                                  np.concatenate([r.after_step for r in parts]))
    # a valve that follows its OP answers the same steps with smooth turns
    pv, op, sp, h = _stepped_level(seed, stick=False)
    e = stick_slip_events(pv, op, h, process="integrating", sp=sp)
    assert e.events == 0 and not e.found, e.reason
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


def test_a_healthy_levels_answer_to_its_steps_kinks_it_but_is_not_called_sticky():
    """A healthy level of the realistic benchmark's generator (study seed 10,
    loop 0: PI control, a 4 h snapshot at 5 s) exported as 30 s means. The
    version that first read kinks in a step's answer read three slips here,
    one of them in its answer to a set-point step, and called the level
    ``stiction``: its two steps cannot check them against a following valve
    (three must answer to read its gain). A kink in a step's answer no
    longer counts towards the three that stand unchecked; and since a kink
    after a stretch over which the level held still says nothing, the
    record reads two slips, both over whole windows: a snapshot's two kinks,
    which stand only where the set-point steps check them."""
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop("level-healthy", benchmark_rng("level-healthy", 10, 0))
    m = int(round(30.0 / loop.sample_time))
    n = loop.pv.size // m * m
    pv, op, sp = (x[:n].reshape(-1, m).mean(axis=1) for x in (loop.pv, loop.op, loop.sp))
    e = stick_slip_events(pv, op, 30.0, process="integrating", sp=sp)
    assert e.found and e.consistent < MIN_SLIPS and not e.after_step.any(), e.reason
    d = classify_loop(pv, op, sp, sample_time=30.0, process_type="integrating",
                      pv_averaged=True)
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason
    assert d.evidence["kinks_unchecked"]["consistent"] == e.consistent


def test_a_kink_read_in_the_window_cut_after_a_step_is_fitted_there():
    from valvediag.analysis.signature import _cut_kink

    # a hinge of known size at sample 300 of a window that begins after the
    # step, on a parabola: read to within its standard error's few multiples
    rng = np.random.default_rng(4)
    t = np.arange(600.0) - 300.0
    y = 2.0 + 0.01 * t + 2e-6 * t * t + 0.004 * np.maximum(t, 0.0) + rng.normal(0, 0.05, 600)
    step, se = _cut_kink(y, 300, 512, 0.05)
    assert 0.0 < se < 0.001
    assert abs(step - 0.004) < 4.0 * se


@pytest.mark.parametrize("seed, index", [(12, 1), (18, 1)])
def test_two_kinks_and_no_other_make_a_level_snapshot_sticky(seed, index):
    """Sticky levels of the realistic benchmark's generator (proportional
    control, no cycle), exported as 4 h snapshots at 10 s: each reads two
    kinks, both after the level ran straight while the OP crept, both the
    way it crept, and no other. That is a fault in a snapshot, as two slips
    are on a flow, and too few in a day's record; and in the scan only where
    the set-point steps read the valve's gain and the kinks step the slope
    far beyond what the OP's change across them makes through it (two kinks
    alone may be a load's turns: healthy levels averaged over 30 s read
    two such kinks)."""
    from valvediag.analysis.bumps import SLIP_OVER_FOLLOWING
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop("level-stiction-events", benchmark_rng("level-stiction-events", seed, index))
    assert loop.duration_s <= 4 * 3600.0
    e = stick_slip_events(loop.pv, loop.op, loop.sample_time, process="integrating", sp=loop.sp)
    assert e.found and e.kind == "stiction" and e.consistent == e.events == 2, e.reason
    e = stick_slip_events(loop.pv, loop.op, loop.sample_time, process="integrating", sp=loop.sp,
                          record_s=86_400.0)
    assert not e.found and e.consistent == 2, e.reason
    assert "or, in a snapshot, 2 and all" in e.reason
    d = classify_loop(loop.pv, loop.op, loop.sp, sample_time=loop.sample_time,
                      process_type="integrating")
    assert d.verdict == "stiction" and "level ran straight" in d.reason, d.reason
    assert d.evidence["setpoint_bumps"]["kinks_over_following"] >= SLIP_OVER_FOLLOWING


def test_two_kinks_of_a_level_without_set_point_steps_stand_unchecked():
    """A hand-built sticky level snapshot (1.5 h) under a wandering load and
    a set point that never moves: two slips, read as two kinks and no
    other. Nothing reads the valve's gain to check them against a valve
    that follows its OP, so the scan does not call the valve on them."""
    pv, op, sp = _level_staircase(seed=1, wander=True, n=5400, tau=800.0, every=1800.0,
                                  noise=0.05)
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert e.found and e.consistent == e.events == 2, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason
    assert d.evidence["kinks_unchecked"]["consistent"] == 2
    # kept for a record cut by gaps, whose stretches' kinks the scan pools
    assert [r.consistent for r in d.events if r.process == "integrating"] == [2]


@pytest.mark.parametrize("seed, index", [(1, 14), (10, 3)])
def test_a_level_of_no_known_type_is_called_by_kinks_its_set_point_steps_checked(seed, index):
    """Day-long records of sticky levels from the realistic benchmark's
    generator (proportional control, no cycle, set-point steps every 20-60
    minutes), with no process type in the registry. The OP's lasting answer
    to the steps names no type (a sticky valve settles its OP anywhere in its
    band) and shows no lasting shift within two standard errors, and read as
    a flow the record shows nothing. Read as a level's,
    its kinks are slips, and the set-point steps read as bump tests clear
    them of a valve that follows its OP: the scan calls the valve sticky.
    Exported without its set point, the steps are read back from the OP's
    kicks, every one of them, and check the kinks as well."""
    from valvediag.analysis.bumps import SLIP_OVER_FOLLOWING
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop("level-stiction-events", benchmark_rng("level-stiction-events", seed, index))
    d = classify_loop(loop.pv, loop.op, loop.sp, sample_time=loop.sample_time,
                      process_type="unknown")
    assert d.evidence["setpoint_screen"]["process"] == "unknown"
    assert d.verdict == "stiction" and "type not known" in d.reason, d.reason
    bumps = d.evidence["setpoint_bumps"]
    assert bumps["found"] or bumps["kinks_over_following"] >= SLIP_OVER_FOLLOWING
    d = classify_loop(loop.pv, loop.op, None, sample_time=loop.sample_time,
                      process_type="unknown")
    assert d.evidence["setpoint_inferred"]["steps"] == np.count_nonzero(np.diff(loop.sp))
    assert d.verdict == "stiction" and "read from the OP's kicks" in d.reason, d.reason


def test_a_level_of_no_known_type_whose_kinks_nothing_checked_is_not_called():
    """A hand-built sticky level (3 h) under a wandering load, whose set point
    never moves and whose registry names no type: read as a level's, it shows
    slips enough for a fault, but no set-point step tells its type or reads
    the valve's gain to check them, and a flow's answers to its load kink
    its record as well: the scan names no fault."""
    pv, op, sp = _level_staircase(seed=2, wander=True, n=10_800, tau=400.0, every=900.0,
                                  noise=0.05)
    e = stick_slip_events(pv, op, 1.0, process="integrating", sp=sp)
    assert e.found and e.consistent >= MIN_SLIPS, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="integrating")
    assert d.verdict == "stiction", d.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="unknown")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason
    assert not [r for r in d.events if r.process == "integrating"]


@pytest.mark.parametrize("seed", [1, 3])
def test_a_tight_flow_of_no_known_type_is_not_read_as_a_level(seed):
    """A healthy flow under tight PI control (loop gain 3.5) whose load steps
    as pumps start and stop, and whose set point steps every 20-60 minutes,
    with no type in the registry. Read as a level its answers to the load
    are slips, and its set-point steps, read as a level's bump tests, would
    clear them. Its OP's lasting shift after the steps is about 1 / 3.5 of
    the kick, too near a level's nought for the screen to name a type; but
    it stands many standard errors above nought, as no level's does, so the
    record is not read as a level."""
    from valvediag.analysis.signature import stick_slip_events
    from valvediag.synth.cases import alternating_steps

    rng = np.random.default_rng(seed)
    h, n = 5.0, 17280
    load = alternating_steps(rng, n, every_s=(1800.0, 5400.0), size=(1.0, 3.0), sample_time=h)
    load = load + np.cumsum(rng.normal(0.0, 0.02, n))
    sp = alternating_steps(rng, n, every_s=(1200.0, 3600.0), size=(2.0, 6.0), sample_time=h)
    run = simulate_loop(kc=3.5, ti=80.0, sample_time=h, n_samples=n, process="self-regulating",
                        tau=50.0, lag=3.0, dead_time=5.0, sp=50.0, load_profile=load,
                        sp_profile=sp, noise_std=0.15, seed=seed)
    as_level = stick_slip_events(run.pv, run.op, h, process="integrating", sp=run.sp)
    assert as_level.found and as_level.kind == "stiction"          # the hazard is real
    d = classify_loop(run.pv, run.op, run.sp, sample_time=h, process_type="unknown")
    screen = d.evidence["setpoint_screen"]
    assert screen["process"] == "unknown"
    assert screen["shift_over_kick"] > 2.0 * screen["standard_error"]
    assert d.verdict == "no-oscillation", d.reason
    assert not [r for r in d.events if r.process == "integrating"]


def test_a_levels_kinks_that_the_op_did_not_drive_are_not_slips():
    """A healthy level under PI control whose inflow steps up and down at
    random times (a pump started and stopped): every step kinks the level,
    but the OP answers it only afterwards."""
    rng = np.random.default_rng(11)
    n = 20_000
    steps = np.zeros(n)
    for k in np.sort(rng.choice(np.arange(500, n - 500), 12, replace=False)):
        steps[k:] += rng.choice((-1.0, 1.0)) * 1.5
    sim = simulate_loop(process="integrating", valve="linear", sample_time=1.0, n_samples=n,
                        kc=1.5, ti=600.0, tau=300.0, sp=50.0, load=40.0, noise_std=0.02,
                        load_profile=steps, seed=4)
    e = stick_slip_events(sim.pv, sim.op, 1.0, process="integrating", sp=sim.sp)
    # (a step that comes after the OP crept the same way reads as a slip: one
    # of the twelve here; too few to name a fault)
    assert not e.found and e.consistent < MIN_SLIPS, e.reason
    d = classify_loop(sim.pv, sim.op, sim.sp, sample_time=1.0, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


def test_a_tight_level_loops_quick_turn_after_a_load_step_is_not_a_slip():
    """A healthy level under tight PI control (Kc 2.9, Ti 200 s, tau 150 s, 5 s
    samples) whose inflow steps by 2 every 67-100 minutes: after each step the
    level ramps for about 20 samples while the OP moves fast, then the valve,
    following the OP, turns it. Read over a 32-sample half-window the turn
    looks like a kink that the OP drove, after a straight run; but the
    stretch since the step is too short to tell a valve that held from one
    that followed, so it says nothing. (Before 2026-11-27, 16 of 16 such
    turns were read as slips.)"""
    rng = np.random.default_rng(3)
    n = 2 * 17_280
    steps, k = np.zeros(n), 400
    while True:
        k += int(rng.uniform(4000, 6000) / 2.5)
        if k >= n:
            break
        steps[k:] += rng.choice((-1.0, 1.0)) * 2.0
    sim = simulate_loop(process="integrating", valve="linear", sample_time=2.5, n_samples=n,
                        kc=2.9, ti=200.0, tau=150.0, dead_time=6.0, lag=12.0, sp=50.0,
                        load=50.0, noise_std=0.1, load_profile=steps, seed=3)
    pv, op, sp = sim.pv[::2], sim.op[::2], sim.sp[::2]
    e = stick_slip_events(pv, op, 5.0, process="integrating", sp=sp)
    assert not e.found and e.consistent < MIN_SLIPS, e.reason
    d = classify_loop(pv, op, sp, sample_time=5.0, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


@pytest.mark.parametrize("ti", [120.0, 360.0])
def test_a_level_held_still_while_its_op_crept_after_a_ramping_load_is_not_a_slip(ti):
    """A healthy level under tight PI control (Kc 3, tau 120 s) whose inflow
    ramps up and down by 1 % (a triangle of 40 minutes): along each ramp the
    valve follows the OP, which creeps by integral action against the load,
    and the level holds still at an offset; where the load turns, the
    level's slope steps the way the OP had crept within the loop's quick
    answer, as a slip's would. Before the level's slope over the stretch
    was asked to stand off nought, 16 and 4 such turns read as slips (Ti 120
    and 360 s) and the scan said ``stiction``; now 0 of 7 and 2 of 2, too
    few for a day's record. A sticky valve's kinks are still read
    (:func:`test_a_levels_staircase_of_slips_is_read_from_its_kinks` and the
    tests after it): a valve stuck off the load's flow runs the level at a
    slope."""
    from valvediag.synth.cases import _wave

    h, n = 2.0, int(6 * 3600 / 2.0)
    load = _wave("triangle", np.arange(n) * h, 2400.0, 0.0)
    sim = simulate_loop(process="integrating", valve="linear", sample_time=h, n_samples=n,
                        kc=3.0, ti=ti, tau=120.0, sp=50.0, load=30.0, load_profile=load,
                        noise_std=0.03, seed=5)
    e = stick_slip_events(sim.pv, sim.op, h, process="integrating", sp=sim.sp)
    assert not e.found and e.consistent < MIN_SLIPS, e.reason
    d = classify_loop(sim.pv, sim.op, sim.sp, sample_time=h, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


def _pumped_level(kind="square", period=3600.0, tau=60.0, kc=0.8, seed=25, noise=0.05):
    """A day of a healthy level at 5 s (controller at 2.5 s) under a load
    that steps or ramps between +-2 % every half ``period`` [s]: a pump that
    starts and stops, or an inflow that ramps up and down (PI, Ti 1.5 tau,
    a lag of 0.05 tau and a dead time of 0.02 tau)."""
    from valvediag.synth.cases import _wave

    hc, warm = 2.5, int(4 * 3600 / 2.5)
    n = warm + int(86400 / hc)
    load = 2.0 * _wave(kind, np.arange(n) * hc, period, 1.3)
    sim = simulate_loop(process="integrating", valve="linear", sample_time=hc, n_samples=n,
                        kc=kc, ti=1.5 * tau, tau=tau, lag=0.05 * tau, dead_time=0.02 * tau,
                        sp=50.0, load=50.0, load_profile=load, noise_std=noise, seed=seed)
    return sim.pv[warm::2], sim.op[warm::2], sim.sp[warm::2], 2 * hc


def test_a_levels_answer_to_a_quick_move_of_its_op_after_a_pumps_step_is_not_a_slip():
    """A healthy level whose inflow steps by 4 % every half hour (a pump that
    starts and stops) settles within minutes of each step. Read over a
    half-window of 128 samples, the level kinks two minutes after each step,
    where the valve, following the OP's quick answer, turns it: the OP stood
    still for three quarters of the window and moved only in its last one.
    Any valve that moves kinks a level after such a burst of its OP, so the
    kink says nothing (before, 48 of 48 such turns read as slips, and the
    scan said ``stiction``)."""
    from valvediag.analysis.signature import KINK_BURST_STILL

    pv, op, sp, h = _pumped_level()
    e = stick_slip_events(pv, op, h, process="integrating", sp=sp)
    assert not e.found and e.consistent < MIN_SLIPS, e.reason
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason
    # the burst: over the 128 samples before a turn, the OP stood still for
    # three quarters and made its move in the last one
    k = 24 + int(np.flatnonzero(np.abs(np.diff(op)) > 0.3)[0])
    q = op[k - 128:k].reshape(4, 32).mean(axis=1)
    assert np.ptp(q[:3]) < KINK_BURST_STILL * abs(q[3] - q[2]) and abs(q[3] - q[2]) > 1.0


@pytest.mark.parametrize("kind, tau, kc, why", [
    ("square", 120.0, 1.0, "rests at its set point"),
    ("triangle", 120.0, 1.0, "does not ramp between its turns"),
    ("square", 300.0, 2.5, "rests at its set point")])
def test_a_level_that_holds_still_between_its_turns_swings_with_its_load(kind, tau, kc, why):
    """A healthy level under a load of 90-minute period, 16 cycles a day
    (too few to read the phase's wander): after a pump's step it settles at
    its set point (and the loop's rests there say so first); under a ramping
    inflow it holds still off it while the OP follows the ramp. Either way
    it does not ramp from turn to turn as a level does whose valve rests,
    stuck or in its dead band; its sharp or lagged turns read ``stiction``
    before."""
    pv, op, sp, h = _pumped_level(kind, period=5400.0, tau=tau, kc=kc, seed=2, noise=0.01)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict == "linear-oscillation", d.reason
    assert d.evidence["ramp_share"] < 0.3 and why in d.reason


@pytest.mark.parametrize("kind, tau, kc, period", [
    ("clipped", 400.0, 2.6, 5700.0),
    ("square", 500.0, 1.4, 4800.0)])
def test_a_slow_level_that_runs_in_arcs_between_sharp_turns_swings_with_its_load(
        kind, tau, kc, period):
    """A healthy slow level (time constant 400-500 s) under a square or
    clipped load of 80-95 minutes' period: it does not settle between the
    load's steps, and where the load steps it turns sharply, so the
    Backlash Index reads 0.7-0.8, a slip's (``stiction`` before). Between
    its turns it runs in arcs: the flow through its valve changes all along
    each ramp. A valve at rest, stuck or in its dead band, passes a steady
    flow and ramps a level straight (curvature 0.012 at most on 155 of the
    156 sticky and loose level cycles of the realistic benchmark's study and
    development seeds)."""
    from valvediag.analysis.classify import RAMP_ARC_MIN

    pv, op, sp, h = _pumped_level(kind, period=period, tau=tau, kc=kc, seed=3, noise=0.02)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict == "linear-oscillation", d.reason
    assert d.evidence["ramp_curvature"] >= RAMP_ARC_MIN and "runs in arcs" in d.reason
    # the turns alone would name a sticky valve
    from valvediag.analysis.bi import backlash_index

    assert backlash_index(pv - sp, h).verdict == "stiction"


def test_a_level_that_rests_between_a_pumps_steps_is_read_as_cycling():
    """A healthy level under a pump that starts and stops every half hour,
    with noise of 5 % of its swing, settles at its set point after each step
    and rests there for most of the cycle. The ACF of such a record lingers
    about zero, and its noise crosses zero there a few times: every other
    crossing was then not half a period on, the regularity read 0.9 and the
    scan said ``no-oscillation``. The cycle is the load's, and its rests say
    so."""
    from valvediag.analysis.oscillation import detect_oscillation

    pv, op, sp, h = _pumped_level("square", period=3600.0, tau=60.0, kc=0.8, seed=3,
                                  noise=0.05)
    o = detect_oscillation(pv, h)
    assert o.period == pytest.approx(3600.0, rel=0.02) and o.is_regular
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict == "linear-oscillation" and "rests at its set point" in d.reason, d.reason


@pytest.mark.parametrize("noise", [0.03, 0.1])
def test_a_fast_level_that_rests_between_a_pumps_steps_is_segmented_at_the_pumps_period(noise):
    """A fast level (time constant 60 s, tight tuning) under a pump of
    90-minute period settles within minutes of each step and rests at its
    set point for most of the day, where its noise crosses the hysteresis
    band set by its swing: the cycles read 35-360 s long (a regularity of
    0.3-0.5) and the scan saw no oscillation. Across the band widened to
    four noise deviations, the crossings keep the ACF's period, all through
    the record, and swing by ten deviations or more. The same pump's swing
    at a tenth of that, within a few deviations of the noise, is left as a
    quiet record's (a slow load of the plant benchmark's healthy loops)."""
    from valvediag.analysis.oscillation import SWING_NOISE, detect_oscillation
    from valvediag.analysis.quality import white_noise_std

    pv, op, sp, h = _pumped_level("square", period=5400.0, tau=60.0, kc=2.0, seed=3,
                                  noise=noise)
    o = detect_oscillation(pv, h)
    assert o.period == pytest.approx(5400.0, rel=0.02) and o.is_regular
    assert 14 <= o.cycles <= 17
    assert o.amplitude >= SWING_NOISE * white_noise_std(pv)
    small = sp + 0.1 * (pv - sp)
    small += np.random.default_rng(4).normal(0.0, noise, pv.size)
    assert not detect_oscillation(small, h).is_regular


def test_loop_sense_reads_which_way_the_op_moves_the_pv():
    from valvediag.analysis.signature import loop_sense

    pv, op, _ = _level_staircase(stick=False)
    assert loop_sense(pv, op) == 1.0
    pv, op, _ = _level_staircase(stick=False, sense=-1.0)
    assert loop_sense(pv, op) == -1.0
    flat = np.full(500, 50.0)
    assert loop_sense(flat, flat) == 0.0


@pytest.mark.parametrize("skew", [-2, -1, 1, 2])
@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_loop_sense_holds_when_the_ops_time_stamps_are_skewed(skew, sense):
    # the two tags stored at different scans: at one sample of skew the moves
    # correlate the other way at lag zero, and every sense read there turned
    from valvediag.analysis.signature import controller_lag, loop_sense

    pv, op, _ = _level_staircase(stick=False, sense=sense)
    lag, _ = controller_lag(pv, op)
    assert lag == 0
    # the OP's answer stored ``skew`` samples after the PV's move it answers
    pv, op = (pv[skew:], op[:-skew]) if skew > 0 else (pv[:skew], op[-skew:])
    lag, r = controller_lag(pv, op)
    assert lag == skew, r
    assert loop_sense(pv, op) == sense


def _recorded_flow_loop(valve, valve_params=None, load=None, seed=1, h=5.0):
    """A PI flow loop run at half the record's sample time and recorded every
    second sample, with measurement noise fed back (tau 11.9 s, lag 1.4 s,
    dead time 0.7 s, kc 0.65, ti 14.2 s at h = 5 s; tau 6.2 s at h = 2 s)."""
    hc = h / 2.0
    n = int(3 * 3600 / hc)
    dyn = (dict(tau=11.9, lag=1.4, dead_time=0.7, kc=0.65, ti=14.2) if h == 5.0 else
           dict(tau=6.2, lag=0.0, dead_time=0.4, kc=0.685, ti=5.65))
    sigma = 0.03
    sim = simulate_loop(sample_time=hc, n_samples=n, sp=50.0, process="self-regulating",
                        valve=valve, valve_params=valve_params, sp_step=1.0, sp_step_time=60.0,
                        noise_std=sigma, valve_noise_band=6 * dyn["kc"] * sigma if
                        valve == "kano" else 0.0,
                        load_profile=None if load is None else load(np.arange(n) * hc),
                        seed=seed, **dyn)
    k0 = int(3600 / hc)
    return sim.pv[k0::2], sim.op[k0::2]


@pytest.mark.parametrize("h, S, J", [(5.0, 3.1, 2.2), (2.0, 2.1, 2.0)])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_sticky_flow_cycle_whose_band_is_most_of_the_ops_swing_is_stiction(h, S, J, seed):
    from valvediag.analysis.oscillation import detect_oscillation

    # the valve slips at the top of each OP swing, and the record keeps every
    # second sample: a model valve slips only for bands within a sample's OP
    # travel of the swing (or smaller, with a dead time making up the
    # difference); a grid 30-45 % apart misses that ridge and reads a linear
    # valve behind a long dead time on 3 of these 6 loops
    pv, op = _recorded_flow_loop("kano", {"S": S, "J": J}, seed=seed, h=h)
    osc = detect_oscillation(pv, h)
    s = valve_signature(pv, op, h, process="self-regulating", period=osc.period)
    assert s.verdict == "stiction", s.reason
    assert s.gain > 0.6 and s.S == pytest.approx(S, rel=0.3)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_sticky_valve_behind_a_slow_lag_whose_pv_swings_against_its_op_is_stiction(seed):
    from valvediag.analysis.oscillation import detect_oscillation

    # a cooler's temperature (tau 62 s, dead time 11.5 s) behind a valve that
    # sticks over most of the OP's swing: the PV rises for half a period after
    # each slip, so at lag zero it swings against the triangular OP though
    # the process gain is positive, and the best linear fit is that anti-phase
    # line with no dynamics. Its dynamics alone set the sticky valve's budget
    # before, and a sticky valve with the process's lag could not be fitted
    # (the synthetic plant's sticky temperature and pressure loops read
    # 'linear' this way)
    h, sigma, kc, n = 1.0, 0.03, 0.95, 4 * 3600
    sim = simulate_loop(kc=kc, ti=54.0, sample_time=h, n_samples=n, sp=50.0,
                        process="self-regulating", tau=62.0, dead_time=11.5, valve="kano",
                        valve_params={"S": 4.9, "J": 3.3}, sp_step=1.0, sp_step_time=60.0,
                        noise_std=sigma, valve_noise_band=6 * kc * sigma, seed=seed)
    pv, op = sim.pv[3600:], sim.op[3600:]
    assert np.corrcoef(pv, op)[0, 1] < -0.5
    s = valve_signature(pv, op, h, process="self-regulating",
                        period=detect_oscillation(pv, h).period)
    assert s.verdict == "stiction", s.reason
    assert s.gain > 0.6 and s.S == pytest.approx(4.9, rel=0.3)


@pytest.mark.parametrize("seed, index", [(21, 3), (24, 3)])
def test_a_cycle_is_fitted_on_an_ordinary_stretch_of_it_not_where_it_broke(seed, index):
    """Realistic benchmark draws (sticky temperature cycles of seeds 17-26),
    longer than the signature fits. The stretch where the OP swings widest,
    1.4-1.8 times the median stretch, holds what broke the cycle (24:3's
    cycle ends in one large excursion), and there the sticky valve does not
    fit: they read `linear-oscillation` when that stretch was fitted. The
    widest of the ordinary stretches shows the valve."""
    from valvediag.analysis.oscillation import detect_oscillation
    from valvediag.analysis.quality import most_active_window, typical_window
    from valvediag.analysis.signature import MAX_SAMPLES
    from valvediag.synth.cases import benchmark_rng, draw_loop

    klass = "temperature-stiction-cycle"
    loop = draw_loop(klass, benchmark_rng(klass, seed, index))
    h, m = loop.sample_time, MAX_SAMPLES
    period = detect_oscillation(loop.pv, h).period
    s = valve_signature(loop.pv, loop.op, h, process="self-regulating", period=period)
    assert s.step == 1 and s.start == typical_window(loop.op, m)
    assert s.nonlinear and s.gain >= SIGNATURE_LIMITS["gain"], s.reason
    w = most_active_window(loop.op, m)
    assert np.ptp(loop.op[w:w + m]) > np.ptp(loop.op[s.start:s.start + m])
    widest = valve_signature(loop.pv[w:w + m], loop.op[w:w + m], h, process="self-regulating",
                             period=period)
    assert not widest.nonlinear and widest.gain < s.gain - 0.4


@pytest.mark.parametrize("klass, seed, index", [
    ("flow-stiction-cycle", 20, 0), ("temperature-stiction-cycle", 2, 5)])
def test_a_sticky_cycle_that_a_linear_valve_behind_a_dead_time_nearly_follows_is_stiction(
        klass, seed, index):
    from valvediag.analysis.oscillation import detect_oscillation
    from valvediag.synth.cases import benchmark_rng, draw_loop

    # realistic benchmark draws: a linear valve behind a long dead time
    # follows the square PV to R2 0.96-0.97, so a sticky valve can add under
    # 0.03 however much of the rest it explains (61-82 % of the linear
    # valve's held-out error, with a slip jump that beats a dead band by
    # 45-58 %); they read 'linear' when that R2 margin was asked of them too.
    # (Flow 14:1 of the same seeds was a third such draw until the BLAS
    # kernels were pinned: its stretches read 33-64 %, and the kernels OpenBLAS
    # picks for a processor decide on which side of the limit.)
    loop = draw_loop(klass, benchmark_rng(klass, seed, index))
    h = loop.sample_time
    s = valve_signature(loop.pv, loop.op, h, process="self-regulating",
                        period=detect_oscillation(loop.pv, h).period)
    assert s.r2_valve - s.r2_linear < SIGNATURE_LIMITS["r2_gain"]
    assert s.verdict == "stiction", s.reason
    assert s.gain >= SIGNATURE_LIMITS["gain"] and s.J >= 0.5 * s.S


def test_the_kind_the_held_out_blocks_prefer_is_the_valve_judged():
    from valvediag.analysis.oscillation import detect_oscillation
    from valvediag.synth.cases import benchmark_rng, draw_loop

    # a sticky temperature cycle of the realistic benchmark (development seed
    # 2, loop 15; 4 h at 5 s): on the training blocks a dead band fits best
    # and removes 53 % of a linear valve's held-out error, under the 60 % a
    # dead band needs; the best valve with a slip jump leaves 61 % less
    # held-out error than that dead band, and it is the one judged
    klass = "temperature-stiction-cycle"
    loop = draw_loop(klass, benchmark_rng(klass, 2, 15))
    h = loop.sample_time
    s = valve_signature(loop.pv, loop.op, h, process="self-regulating",
                        period=detect_oscillation(loop.pv, h).period)
    assert s.kind_gain >= SIGNATURE_LIMITS["kind_gain"] and s.J > 0
    assert s.verdict == "stiction", s.reason
    assert s.gain > 0.6


@pytest.mark.parametrize("h", [5.0, 2.0])
@pytest.mark.parametrize("shape", ["sine", "clipped"])
def test_a_healthy_flow_loop_under_a_load_at_a_sticky_cycles_period_is_linear(h, shape):
    from valvediag.analysis.oscillation import detect_oscillation

    period, amp = (115.0, 2.0) if h == 5.0 else (36.0, 1.5)

    def load(t):
        x = amp * np.sin(2 * np.pi * t / period)
        return x if shape == "sine" else np.clip(1.6 * x, -amp, amp)

    pv, op = _recorded_flow_loop("linear", load=load, h=h)
    osc = detect_oscillation(pv, h)
    s = valve_signature(pv, op, h, process="self-regulating", period=osc.period)
    assert s.verdict == "linear", s.reason


def test_a_sticky_flow_valve_is_read_through_an_op_kept_at_its_corners():
    """A swinging door of 0.1 % keeps 5 % of the OP's samples, most of them
    the turns of its cycle: their differences from their neighbours' lines
    read as a noise band of 2.8 on a swing of 3.5, and the OP 'hardly moved'.
    An OP with fewer than a dozen stored points a period is read at its
    stored resolution."""
    from valvediag import simulate_loop
    from valvediag.analysis.quality import stored_points
    from valvediag.synth.plant import historian_record

    sim = simulate_loop(sample_time=0.5, n_samples=28800, sp=50.0, process="self-regulating",
                        tau=10.0, kc=0.8, ti=8.0, dead_time=2.0, valve="kano",
                        valve_params={"S": 3.0, "J": 2.0}, sp_step=1.0, sp_step_time=60.0,
                        noise_std=0.02, valve_noise_band=6 * 0.8 * 0.02, seed=4)
    pv, op = sim.pv[3600::2], historian_record(sim.op[3600::2], 0.1)
    assert stored_points(op).size < 0.1 * op.size
    d = classify_loop(pv, op, np.full(pv.size, 50.0), sample_time=1.0,
                      process_type="self-regulating")
    assert d.verdict == "stiction", d.reason


def test_a_square_load_through_an_op_kept_at_its_corners_is_no_valve_fault():
    """A healthy flow under a square load, its OP stored by swinging door: read
    at its stored resolution, the OP is seen to move, and a linear valve
    explains the PV (where the OP 'hardly moved', the valve was not read).
    The scan reads the loop as the load's before the signature: its fast
    motion leads away from the set point."""
    from valvediag import simulate_loop
    from valvediag.synth.plant import historian_record

    n = 28800
    t = np.arange(n) * 0.5
    sim = simulate_loop(sample_time=0.5, n_samples=n, sp=50.0, process="self-regulating",
                        tau=10.0, kc=0.5, ti=10.0, dead_time=1.0, valve="linear",
                        load_profile=2.0 * np.sign(np.sin(2 * np.pi * t / 120.0)),
                        noise_std=0.03, seed=2)
    pv, op = sim.pv[3600::2], historian_record(sim.op[3600::2], 0.1)
    d = classify_loop(pv, op, np.full(pv.size, 50.0), sample_time=1.0,
                      process_type="self-regulating")
    assert d.verdict == "linear-oscillation", d.reason
    s = valve_signature(pv, op, 1.0, process="self-regulating", period=d.period)
    assert s.verdict == "linear" and "valve follows the OP" in s.reason, s.reason


def test_a_sticky_valves_creeps_are_read_through_an_op_stored_by_swinging_door():
    """The slips of ``_slip_record`` with the OP stored by a swinging door of
    0.1 %: the door keeps the ends of the creeps and little else, and their
    differences from their neighbours' lines read as a noise band (0.46 x 6)
    larger than the 1 % creep, so no slip was counted and the loop read
    'insufficient-data'. Read at its stored resolution, the creeps count."""
    from valvediag.analysis.quality import resolved_noise_std, white_noise_std
    from valvediag.synth.plant import historian_record

    pv, op, sp = _slip_record(n_events=6)
    op = historian_record(op, 0.1)
    assert 6 * white_noise_std(op) > 1.0 > 6 * resolved_noise_std(op)
    e = stick_slip_events(pv, op, 1.0, process="self-regulating", sp=sp)
    assert e.found and e.kind == "stiction" and e.slips >= 5, e.reason
    d = classify_loop(pv, op, sp, sample_time=1.0, process_type="self-regulating")
    assert d.verdict == "stiction" and "stick-slip events" in d.reason, d.reason


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cascades_inner_flow_slips_while_its_set_point_wanders(seed):
    # the inner flow loop of a cascade: its set point is the outer loop's
    # output and wanders by about a percent over tens of minutes. A sticky
    # valve's slips still bring the PV back towards it at once (none was read
    # before: any move of the set point barred a jump); a valve that follows
    # the OP makes none
    rng = np.random.default_rng(seed)
    n = 4 * 3600
    t = np.arange(n, dtype=float)
    knots = np.arange(0.0, n + 900.0, 900.0)
    load = np.interp(t, knots, np.cumsum(rng.normal(0, 1.5, knots.size)))
    wander = 0.4 * np.sin(2 * np.pi * t / 2400.0) + 0.3 * np.sin(2 * np.pi * t / 5100.0 + 1.0)
    for valve, params in (("kano", {"S": 4.0, "J": 3.0}), ("linear", None)):
        sim = simulate_loop(process="self-regulating", tau=20.0, kc=0.2, ti=200.0, sp=50.0,
                            sample_time=1.0, n_samples=n, valve=valve, valve_params=params,
                            noise_std=0.05, valve_noise_band=0.06, load_profile=load,
                            sp_profile=wander, seed=seed)
        assert np.ptp(sim.sp) > 1.0
        e = stick_slip_events(sim.pv, sim.op, 1.0, process="self-regulating", sp=sim.sp)
        d = classify_loop(sim.pv, sim.op, sim.sp, sample_time=1.0,
                          process_type="self-regulating")
        if valve == "kano":
            assert e.found and e.kind == "stiction" and e.slips >= 2, e.reason
            assert d.verdict == "stiction", d.reason
        else:
            assert not e.found, e.reason
            assert d.verdict not in ("stiction", "backlash", "undecided"), d.reason


def test_a_level_kinks_at_the_ends_of_a_line_drawn_across_a_gap_and_those_are_not_read():
    """A healthy level running straight through its noise, a gap of 5 or 15
    minutes bridged by a straight line between the two samples either side
    (as the scan bridges a gap of up to a quarter of a cycle): the line
    kinks the level at its ends by about the noise over the gap, and the
    hinge fit reads those kinks anywhere in a window that holds the line.
    Given the drawn samples, no window that holds one is read."""
    from valvediag.analysis.quality import bridge_short_gaps

    n, lines, masked = 12000, 0, 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        pv = 50 + 0.002 * np.arange(n) + rng.normal(0, 0.3, n)
        op = 40 - 0.0006 * np.arange(n) + rng.normal(0, 0.02, n)
        for gap in (300, 900):
            drawn = np.zeros(n, bool)
            drawn[6000:6000 + gap] = True
            pv_b = bridge_short_gaps(np.where(drawn, np.nan, pv), gap)[0]
            op_b = bridge_short_gaps(np.where(drawn, np.nan, op), gap)[0]
            assert stick_slip_events(pv, op, H, process="integrating").events == 0
            lines += stick_slip_events(pv_b, op_b, H, process="integrating").events
            masked += stick_slip_events(pv_b, op_b, H, process="integrating",
                                        drawn=drawn).events
    assert lines >= 4
    assert masked == 0
    with pytest.raises(ValueError, match="drawn"):
        stick_slip_events(pv_b, op_b, H, process="integrating", drawn=drawn[1:])


def _slow_level_cycle(valve, valve_params=None, load=None, seed=0):
    """A day of a slow level loop recorded every 5 s (controller at 2.5 s):
    tau 576 s, a 55 s lag and 12.5 s dead time, PI 0.75 / 640 s. A dead band
    of 5 % makes it cycle in about 89 minutes (1,066 samples), so 3,000
    samples hold 2.8 periods."""
    hc, warm = 2.5, int(4 * 3600 / 2.5)
    n = warm + int(86400 / hc)
    sim = simulate_loop(process="integrating", valve=valve, valve_params=valve_params,
                        kc=0.75, ti=640.0, tau=576.0, lag=55.0, dead_time=12.5,
                        sample_time=hc, n_samples=n, sp=50.0, load=50.0, sp_step=1.0,
                        sp_step_time=60.0, load_profile=load, noise_std=0.075, seed=seed)
    return sim.pv[warm::2], sim.op[warm::2], 2 * hc


@pytest.mark.parametrize("seed", range(8))
def test_a_slow_loose_level_cycle_is_fitted_over_four_periods_and_is_not_linear(seed):
    """A dead band of more than half the OP's swing in a cycle of 89
    minutes: fitted over the 2.8 periods that 3,000 samples at 5 s hold, a
    linear valve explained the PV as well as a loose one in four of these
    eight records (removing 2-34 % of its error, under the 35 % the veto
    allows), and the Backlash Index's ``backlash`` was overruled. Fitted
    on the means of two samples over 5.6 periods the loose valve removes
    54-65 %."""
    from valvediag.analysis.classify import follows_op

    pv, op, h = _slow_level_cycle("backlash", {"DB": 5.0}, seed=seed)
    d = classify_loop(pv, op, sample_time=h, process_type="integrating")
    sig = valve_signature(pv, op, h, process="integrating", period=d.period)
    assert sig.step == 2 and sig.sample_time == 2 * h
    assert sig.samples * sig.sample_time >= 4 * d.period
    assert sig.gain > 0.45 and not follows_op(sig, d.period), sig.reason
    assert d.verdict == "backlash", d.reason


@pytest.mark.parametrize("kind", ["triangle", "sine", "square"])
def test_a_slow_load_on_a_healthy_level_stays_linear_over_four_periods(kind):
    """The same slow loop with a linear valve under a load of the dead band's
    cycle's period: fitted on block means over four periods or more, the
    valve still follows its OP. (A clipped sine load reads ``backlash``
    here, fitted either way: a dead band removes about 40 % of the linear
    valve's error, a load in step with the OP that the signature's Notes
    name.)"""
    from valvediag.synth.cases import _wave

    t = np.arange(int((4 * 3600 + 86400) / 2.5)) * 2.5
    pv, op, h = _slow_level_cycle("linear", load=3.0 * _wave(kind, t, 5330.0, 0.3), seed=1)
    d = classify_loop(pv, op, sample_time=h, process_type="integrating")
    assert d.verdict == "linear-oscillation", d.reason
    sig = valve_signature(pv, op, h, process="integrating", period=d.period)
    assert sig.step == 2 and sig.verdict == "linear", sig.reason
