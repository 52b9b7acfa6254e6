"""A loose flow valve read at the OP's reversals (valvediag.analysis.reversals)."""
import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")

from valvediag import classify_loop, simulate_loop  # noqa: E402
from valvediag.analysis.reversals import (DURATION_SPREAD, MIN_REST_SHARE,  # noqa: E402
                                          MIN_REST_SHARE_FIXED, MIN_RESTS,
                                          MIN_RESTS_FIXED, MIN_TURNS_FIXED,
                                          TRAVEL_SPREAD_SHARE, TURN_TRAVEL_SPREAD,
                                          pooled_reversal_rests, reversal_rests)

H, N = 1.0, 6 * 3600


def _wandering_load(seed=3, every=600.0, size=1.5):
    """A load that drifts piecewise-linearly through random points (OP units)."""
    rng = np.random.default_rng(seed)
    k = int(N * H / every) + 2
    pts = np.cumsum(rng.normal(0.0, size, k))
    return np.interp(np.arange(N) * H, np.arange(k) * every, pts - pts[0])


def _flow(valve="backlash", vp=None, load=None, noise=0.05, seed=0):
    """A PI flow loop (gain 1, 10 s lag) under ``load``, 6 h at 1 s."""
    sim = simulate_loop(kc=0.4, ti=20.0, sample_time=H, n_samples=N, valve=valve,
                        valve_params=vp if vp is not None else {"DB": 3.0},
                        process="self-regulating", process_gain=1.0, tau=10.0, sp=50.0,
                        load_profile=_wandering_load() if load is None else load,
                        noise_std=noise, seed=seed)
    return sim.pv, sim.op, np.full(N, 50.0)


def test_a_loose_valve_rests_at_the_reversals_of_a_wandering_load():
    pv, op, sp = _flow("backlash", {"DB": 3.0})
    r = reversal_rests(pv, op, H, sp=sp)
    assert r.found, r.reason
    assert r.rests >= 2 * MIN_RESTS
    # the OP's travel while the PV ran on is the band
    assert r.dead_band == pytest.approx(3.0, rel=0.15)
    assert np.all(np.abs(r.gain_rest) < 0.5 * r.gain_follow)


@pytest.mark.parametrize("valve, vp", [("linear", {}), ("kano", {"S": 3.0, "J": 1.5})])
def test_a_linear_or_sticky_valve_under_the_same_load_leaves_no_rest(valve, vp):
    # a linear valve answers the OP at once; a sticky one brings the PV back
    # by its slip, not by following the OP
    pv, op, sp = _flow(valve, vp)
    r = reversal_rests(pv, op, H, sp=sp)
    assert r.excursions >= MIN_RESTS
    assert not r.found and r.rests < MIN_RESTS, r.reason


def test_fewer_rests_name_a_dead_band_where_its_travel_is_fixed_and_its_time_is_not():
    # a load that turns every five minutes turns the PV between the OP's
    # reversals too: the rests make less than a third of the excursions, but
    # each came after the same travel of the OP, at whatever speed it moved
    pv, op, sp = _flow("backlash", {"DB": 3.0}, load=_wandering_load(seed=3, every=300.0,
                                                                      size=1.0), noise=0.15)
    r = reversal_rests(pv, op, H, sp=sp)
    assert MIN_RESTS_FIXED <= r.rests < MIN_REST_SHARE * r.excursions     # the share alone fails
    assert r.found, r.reason
    assert r.duration_spread >= DURATION_SPREAD
    assert r.travel_spread <= TRAVEL_SPREAD_SHARE * r.duration_spread
    assert r.dead_band == pytest.approx(3.0, rel=0.15)
    assert "fixed width" in r.reason


@pytest.mark.parametrize("seed", [3, 4])
def test_the_turns_name_a_dead_band_where_the_load_moves_the_pv_during_the_rests(seed):
    # a load that turns every 200 s by twice the usual size moves the PV while
    # the valve rests, so the PV's gain on the OP is not nought there and
    # the rests alone name nothing; but the PV still turns back once the OP
    # has crossed the band, at whatever speed it came back
    load = _wandering_load(seed=seed, every=200.0, size=2.0)
    pv, op, sp = _flow("backlash", {"DB": 3.0}, load=load, noise=0.15)
    r = reversal_rests(pv, op, H, sp=sp)
    assert r.found and r.by_turns, r.reason
    assert not (r.rests >= MIN_RESTS and r.rests >= MIN_REST_SHARE * r.excursions)
    assert r.excursions >= MIN_TURNS_FIXED
    assert r.turn_travel_spread <= TURN_TRAVEL_SPREAD
    assert r.turn_duration_spread >= DURATION_SPREAD
    assert r.dead_band == pytest.approx(3.0, rel=0.15)
    assert "fixed time" in r.reason
    assert r.start.size == r.turn.size == r.travel.size == r.excursions
    ax = r.plot()
    assert "fixed OP travel" in ax.get_title()
    # a linear valve under the same load: the PV turns a response after the
    # OP, at a travel that grows with the OP's speed
    pv, op, sp = _flow("linear", {}, load=load, noise=0.15)
    q = reversal_rests(pv, op, H, sp=sp)
    assert q.excursions >= MIN_TURNS_FIXED
    assert not q.found and q.turn_travel_spread > TURN_TRAVEL_SPREAD, q.reason


def test_a_pump_that_starts_and_stops_by_a_fixed_step_is_no_dead_band():
    # an on/off pump steps the load by the same amount each time: the PV
    # moves first, the OP answers by a fixed travel and the PV turns back
    # when it has, so the turns' travels spread little (8 %) while their
    # durations and the legs spread with the wandering load; but the PV
    # moved with the OP's travel before its turn, which no rest does
    rng = np.random.default_rng(3)
    lvl = np.zeros(N)
    for k in np.sort(rng.uniform(0, N, 40)).astype(int):
        lvl[k:] = 1.0 - lvl[k]
    load = 3.0 * lvl + _wandering_load(seed=3, size=0.5)
    pv, op, sp = _flow("linear", {}, load=load, seed=3)
    r = reversal_rests(pv, op, H, sp=sp)
    assert r.excursions >= MIN_TURNS_FIXED
    assert r.turn_travel_spread <= TURN_TRAVEL_SPREAD            # the travel alone would name it
    assert r.turn_duration_spread >= DURATION_SPREAD
    assert r.turn_gain_rest < -0.5 * r.turn_gain_follow
    assert not r.found and not r.by_turns, r.reason


def test_a_periodic_load_rests_at_a_fixed_time_and_names_no_dead_band():
    # a clipped load turns the PV at the same OP travel and after the same
    # time at every cycle: a linear valve behind the process's lag then shows
    # "rests" enough for the fixed-travel reading, but their durations do not
    # spread
    t = np.arange(N) * H
    load = 2.0 * np.clip(np.sin(2 * np.pi * t / 480.0), -0.5, 0.5) / 0.5
    pv, op, sp = _flow("linear", {}, load=load, noise=0.15)
    r = reversal_rests(pv, op, H, sp=sp)
    assert r.rests >= MIN_RESTS_FIXED and r.rests >= MIN_REST_SHARE_FIXED * r.excursions
    assert r.duration_spread < DURATION_SPREAD
    # its legs are all alike: the turns at a fixed travel say nothing either
    assert r.excursions >= MIN_TURNS_FIXED and r.leg_spread < DURATION_SPREAD
    assert not r.found and not r.by_turns, r.reason


def test_a_healthy_flow_under_load_steps_is_no_loose_valve():
    # a pump that starts and stops moves the PV first and the OP with it: the
    # excursion grows with the OP's travel, the opposite of a rest
    rng = np.random.default_rng(5)
    steps = np.repeat(rng.choice([-3.0, 3.0], N // 900 + 1), 900)[:N]
    load = _wandering_load(size=0.5) + np.cumsum(np.r_[0.0, np.diff(steps)])
    pv, op, sp = _flow("linear", {}, load=load)
    r = reversal_rests(pv, op, H, sp=sp)
    assert r.excursions >= MIN_RESTS
    assert not r.found, r.reason


def test_classify_reads_the_rests_on_a_flow_and_not_on_a_level():
    pv, op, sp = _flow("backlash", {"DB": 3.0})
    d = classify_loop(pv, op, sp, sample_time=H, process_type="self-regulating")
    assert d.verdict == "backlash", d.reason
    assert "rests at the OP's reversals" in d.reason
    assert d.evidence["reversal_rests"]["found"]
    # a level runs on after its OP turns whatever its valve does: not read
    d = classify_loop(pv, op, sp, sample_time=H, process_type="integrating")
    assert "reversal_rests" not in d.evidence


def _hourly_stretches(pv, op, sp, missing_s=300.0):
    """Each hour's stretch of a record whose last ``missing_s`` of every hour
    were not exported, read alone."""
    keep = int((3600.0 - missing_s) / H)
    return [reversal_rests(pv[a:a + keep], op[a:a + keep], H, sp=sp[a:a + keep])
            for a in range(0, N, int(3600 / H))]


@pytest.mark.parametrize("valve, vp", [("backlash", {"DB": 3.0}), ("linear", {}),
                                       ("kano", {"S": 3.0, "J": 1.5})])
def test_rests_of_a_record_cut_by_gaps_are_judged_over_its_stretches(valve, vp):
    # five minutes missing every hour: an hour holds one or two of a loose
    # valve's rests, too few alone; the six hours hold enough, and the band
    # is the one a gap-free record reads. A linear or sticky valve's
    # stretches pool to no dead band
    pv, op, sp = _flow(valve, vp)
    parts = _hourly_stretches(pv, op, sp)
    assert len(parts) == 6 and not any(r.found for r in parts)
    pooled = pooled_reversal_rests(parts)
    assert pooled.legs == sum(r.legs for r in parts)
    assert pooled.excursions == sum(r.excursions for r in parts)
    if valve == "backlash":
        assert pooled.found and pooled.rests >= MIN_RESTS, pooled.reason
        assert pooled.dead_band == pytest.approx(3.0, rel=0.15)
    else:
        assert pooled.excursions >= MIN_RESTS
        assert not pooled.found and pooled.rests == 0, pooled.reason


def test_one_reading_pooled_is_that_reading():
    pv, op, sp = _flow("backlash", {"DB": 3.0})
    whole = reversal_rests(pv, op, H, sp=sp)
    pooled = pooled_reversal_rests([whole])
    assert pooled.as_dict() == whole.as_dict()


def test_stretches_read_in_the_other_sense_are_left_out():
    # the sense says which way an excursion runs: a stretch read the other
    # way (an OP exported reversed for an hour) is not pooled with the rest
    pv, op, sp = _flow("backlash", {"DB": 3.0})
    parts = _hourly_stretches(pv, op, sp)
    keep = int(3300 / H)
    flipped = reversal_rests(pv[:keep], 100.0 - op[:keep], H, sp=sp[:keep])
    assert flipped.sense == -parts[0].sense
    pooled = pooled_reversal_rests(parts + [flipped])
    assert pooled.sense == parts[0].sense
    assert pooled.legs == sum(r.legs for r in parts)
    assert not pooled_reversal_rests([]).found


def test_bad_input_and_the_plot():
    pv, op, sp = _flow("backlash", {"DB": 3.0})
    with pytest.raises(ValueError, match="one length"):
        reversal_rests(pv, op[:-1], H)
    with pytest.raises(ValueError, match="sample_time"):
        reversal_rests(pv, op, 0.0)
    short = reversal_rests(pv[:50], op[:50], H)
    assert not short.found and "samples" in short.reason
    r = reversal_rests(pv, op, H, sp=sp)
    ax = r.plot()
    assert "rests" in ax.get_title() and ax.get_legend() is not None
    assert r.as_dict()["rests"] == r.rests


def _scan(pv, op, sp, h):
    """The scan's per-loop analysis of a flow the registry calls self-regulating."""
    import datetime as dt

    import polars as pl

    from valvediag.io.registry import LoopSpec
    from valvediag.scan.loop import analyse_loop
    from valvediag.scan.types import LoopJob, ScanConfig

    n = pv.size
    t0 = dt.datetime(2026, 1, 1, tzinfo=dt.timezone.utc)
    ts = [t0 + dt.timedelta(seconds=float(k) * h) for k in range(n)]

    def frame(v):
        return pl.DataFrame({"ts": ts, "value": pl.Series(v, dtype=pl.Float64),
                             "status": pl.Series([None] * n, dtype=pl.String)})

    spec = LoopSpec("FIC1", "FIC1.PV", "FIC1.OP", sp_tag="FIC1.SP",
                    process_type="self-regulating", span=100.0)
    job = LoopJob(spec, t0, t0 + dt.timedelta(seconds=n * h), ())
    return analyse_loop(job, {"pv": frame(pv), "op": frame(op), "sp": frame(sp)},
                        ScanConfig(window_hours=24))


def test_the_scan_calls_a_loose_flow_valve_backlash_and_sizes_it_by_its_rests():
    r = _scan(*_flow("backlash", {"DB": 3.0}), H)
    assert r.verdict == "backlash", r.reason
    assert "rests at the OP's reversals" in r.reason
    assert r.size["DB"] == pytest.approx(3.0, rel=0.15) and r.size["confidence"] == 0.5


def test_rests_found_on_a_whole_record_are_not_split_into_cycles():
    # a loose flow valve of the realistic benchmark's study seeds (11, index 6)
    # whose record holds a weak, irregular period: its blocks, each read for a
    # cycle, read a valve that follows the OP, and outvoted the rests found
    # on the whole record (no-oscillation before the rests were read)
    from valvediag.synth.cases import benchmark_rng, draw_loop

    klass = "flow-backlash-events"
    loop = draw_loop(klass, benchmark_rng(klass, 11, 6))
    r = _scan(loop.pv, loop.op, loop.sp, loop.sample_time)
    assert r.verdict == "backlash", r.reason
    assert len(r.episodes) == 1


def test_ringing_healthy_flows_under_a_random_load_show_no_dead_band():
    # tight PI tuning behind a dead time rings; every ring turns the OP and the
    # PV overshoots it, but the PV answers the OP through the process, not
    # after a band (24 such loops drawn alike read no fault, at most 5 rests
    # in 62 excursions)
    rng = np.random.default_rng(7)
    for k in range(6):
        tau = float(rng.uniform(3, 40))
        kc, ti = float(rng.uniform(0.8, 2.5)), float(rng.uniform(0.3, 0.8)) * tau
        every = float(rng.uniform(120, 1200))
        load = _wandering_load(seed=k, every=every, size=2.0) + rng.normal(0, 0.5, N)
        sim = simulate_loop(kc=kc, ti=ti, sample_time=H, n_samples=N, valve="linear",
                            valve_params={}, process="self-regulating", process_gain=1.0,
                            tau=tau, dead_time=float(rng.uniform(0.1, 0.3)) * tau, sp=50.0,
                            load_profile=load, noise_std=0.05, seed=k)
        r = reversal_rests(sim.pv, sim.op, H, sp=np.full(N, 50.0))
        assert r.legs > 50 and not r.found, (k, r.reason)


def test_a_loose_flow_valve_under_a_ringing_load_is_read_by_its_rests_too():
    # a loose flow valve of the realistic benchmark's study seeds (13, index 3)
    # whose record rings with a wandering amplitude, as a noise-driven
    # resonance does: it read linear-oscillation before its rests were read
    from valvediag.synth.cases import benchmark_rng, draw_loop

    klass = "flow-backlash-events"
    loop = draw_loop(klass, benchmark_rng(klass, 13, 3))
    r = _scan(loop.pv, loop.op, loop.sp, loop.sample_time)
    assert r.verdict == "backlash", r.reason
    assert "rests at the OP's reversals" in r.reason


def test_a_loose_flow_valve_whose_events_are_undecided_is_named_by_its_turns():
    # a loose flow valve of the realistic benchmark's study seeds (12, index
    # 1): its valve events read 3 slips and 4 take-ups, undecided, but the PV
    # turns at a fixed travel of the OP after its reversals, as a dead band's
    from valvediag.synth.cases import benchmark_rng, draw_loop

    klass = "flow-backlash-events"
    loop = draw_loop(klass, benchmark_rng(klass, 12, 1))
    d = classify_loop(loop.pv, loop.op, loop.sp, sample_time=loop.sample_time,
                      process_type="self-regulating")
    assert d.verdict == "backlash", d.reason
    assert d.evidence["stick_slip"]["kind"] == "undecided"
    assert d.evidence["reversal_rests"]["found"]
    assert "take-ups" in d.reason and "valve events" in d.reason


def test_a_loose_flow_valve_named_by_its_turns_is_sized_from_them():
    # a loose flow valve of the realistic benchmark's study seeds (12, index
    # 3) that read no-oscillation before the turns were read: its rests are
    # too few, but the PV turned at a fixed OP travel at most of its 66
    # excursions
    from valvediag.synth.cases import benchmark_rng, draw_loop

    klass = "flow-backlash-events"
    loop = draw_loop(klass, benchmark_rng(klass, 12, 3))
    r = _scan(loop.pv, loop.op, loop.sp, loop.sample_time)
    assert r.verdict == "backlash", r.reason
    rests = r.evidence["reversal_rests"]
    assert rests["by_turns"] and rests["turn_travel_spread"] <= TURN_TRAVEL_SPREAD
    assert r.size["DB"] == pytest.approx(loop.params["DB"], rel=0.15)
    assert "turned at a fixed travel" in r.size["reason"]


def test_a_cascades_wandering_set_point_does_not_bar_the_legs():
    # the inner flow loop of a cascade: its set point, the outer loop's
    # output, wanders by about a percent over tens of minutes and moves the
    # PV only through the valve. Its legs were all barred (the set point not
    # steady); read through, a loose valve shows its rests, over four draws
    # at least half the time, and a valve that follows the OP never
    n = 4 * 3600
    t = np.arange(n, dtype=float)
    wander = 0.4 * np.sin(2 * np.pi * t / 2400.0) + 0.3 * np.sin(2 * np.pi * t / 5100.0 + 1.0)
    found = {"backlash": 0, "linear": 0}
    for seed in range(4):
        rng = np.random.default_rng(seed)
        knots = np.arange(0.0, n + 300.0, 300.0)
        load = np.interp(t, knots, np.cumsum(rng.normal(0, 2.0, knots.size)))
        for valve, params in (("backlash", {"DB": 4.0}), ("linear", None)):
            sim = simulate_loop(process="self-regulating", tau=20.0, kc=0.4, ti=60.0, sp=50.0,
                                sample_time=1.0, n_samples=n, valve=valve, valve_params=params,
                                noise_std=0.05, load_profile=load, sp_profile=wander, seed=seed)
            assert np.ptp(sim.sp) > 1.0
            r = reversal_rests(sim.pv, sim.op, 1.0, sp=sim.sp)
            assert r.legs >= 5, r.reason
            found[valve] += r.found
    assert found["backlash"] >= 2 and found["linear"] == 0, found


def test_a_leg_that_holds_a_line_drawn_across_a_gap_is_not_read():
    # the PV and OP drawn by straight lines over ten minutes of every hour:
    # the legs that hold a drawn sample are not read, the others are, and a
    # mask of the wrong length is refused
    pv, op, sp = _flow("backlash", {"DB": 3.0})
    drawn = (np.arange(N) % 3600) >= 3000
    full = reversal_rests(pv, op, H, sp=sp)
    kept = reversal_rests(pv, op, H, sp=sp, drawn=drawn)
    assert 0 < kept.legs < full.legs
    assert all(not drawn[a:j + 1].any() for a, j in zip(kept.read.start, kept.read.turn))
    assert reversal_rests(pv, op, H, sp=sp, drawn=np.zeros(N, bool)).legs == full.legs
    with pytest.raises(ValueError, match="drawn"):
        reversal_rests(pv, op, H, sp=sp, drawn=drawn[:-1])
