"""A swing that keeps a clock's time (a load from outside the loop) against a
limit cycle, whose phase wanders with the noise the controller answers."""
import matplotlib
import numpy as np
import pytest

from valvediag.analysis.oscillation import (CLOCK_JITTER, CLOCK_WANDER, MIN_CROSSINGS,
                                            MIN_JITTER_CROSSINGS, detect_oscillation,
                                            phase_wander)

matplotlib.use("Agg")
P = 60.0            # samples per period
KC = 1.5


def _swing(phase, rng, noise=0.05):
    """A square-ish swing (a clipped sine) at the given phase [cycles], white
    measurement noise, and the OP of a proportional controller that answers it."""
    pv = 50.0 + np.clip(1.5 * np.sin(2 * np.pi * phase), -1, 1) + rng.normal(0, noise,
                                                                              phase.size)
    return pv, 40.0 - KC * (pv - 50.0)


def _read(pv, op):
    return phase_wander(pv, detect_oscillation(pv, 1.0), op)


def test_a_clock_keeps_time_and_a_random_walk_wanders():
    rng = np.random.default_rng(0)
    k = np.arange(12000)
    # a clock: the phase runs at one rate; only the noise jitters each crossing
    clock = _read(*_swing(k / P, rng))
    # a limit cycle: each period runs from where the last one ended, 1 % of a
    # period longer or shorter at random, so its phase random-walks
    ends = np.cumsum(P * (1.0 + 0.01 * rng.standard_normal(260)))
    walk = _read(*_swing(np.interp(k, np.r_[0.0, ends], np.arange(261.0)), rng))
    n = clock.crossings
    assert n >= 190 and walk.crossings >= 190
    # 1/2 for a clock read through jitter (a 99 % range of about 0.4-0.6 at 200 crossings)
    assert clock.keeps_clock and 0.35 <= clock.wander <= 0.65
    # about n / 15 for a random walk, 13 here; its 1 % quantile is well above 2
    assert not walk.keeps_clock and walk.wander > 2.0
    assert "keeps time like a clock" in clock.reason and "wanders" in walk.reason
    ax = clock.plot()
    assert ax.get_xlabel() == "cycle" and len(ax.lines) == 2


def test_no_reading_from_too_few_cycles_no_noise_or_noise_the_loop_never_saw():
    rng = np.random.default_rng(1)
    k = np.arange(12000)
    # a snapshot of three cycles: too few crossings to read even their periods
    tiny = _read(*_swing(k[:int(P * (MIN_JITTER_CROSSINGS - 1.5))] / P, rng))
    assert tiny.crossings < MIN_JITTER_CROSSINGS
    assert not tiny.keeps_clock and np.isnan(tiny.wander) and np.isnan(tiny.jitter_ratio)
    assert f"fewer than {MIN_CROSSINGS}" in tiny.reason
    # no noise at all: nothing moves a limit cycle's phase either
    pv, op = _swing(k / P, rng, noise=0.0)
    quiet = _read(pv, op)
    assert not quiet.keeps_clock and "too little noise" in quiet.reason
    # noise added to the record afterwards: the OP does not answer it
    pv, _ = _swing(k / P, rng)
    _, op = _swing(k / P, rng, noise=0.0)
    unseen = _read(pv, op)
    assert not unseen.keeps_clock and "does not answer" in unseen.reason
    # without the OP the same record is read
    assert phase_wander(pv, detect_oscillation(pv, 1.0)).keeps_clock


def test_a_short_snapshot_keeps_time_by_its_periods_and_a_limit_cycle_does_not():
    # 35 cycles: too few for a random walk's wander to show, but a clock's
    # periods vary only by the reading of its crossings (the noise's 0.14
    # samples, and a tick anywhere within TICK_WIDTH of a sample), and a
    # limit cycle's by more (1 % of a period at random here, 0.6 samples)
    rng = np.random.default_rng(0)
    k = np.arange(int(P * (MIN_CROSSINGS - 5)))
    clock = _read(*_swing(k / P, rng))
    ends = np.cumsum(P * (1.0 + 0.01 * rng.standard_normal(60)))
    walk = _read(*_swing(np.interp(k, np.r_[0.0, ends], np.arange(61.0)), rng))
    # a clock whose ticks fall on a grid of half a sample, as a load that
    # the control system moves at its scan does
    ticks = np.ceil(np.arange(61) * (P + 0.37) * 2.0) / 2.0
    grid = _read(*_swing(np.interp(k, ticks, np.arange(61.0)), rng))
    assert MIN_JITTER_CROSSINGS <= clock.crossings < MIN_CROSSINGS
    assert MIN_JITTER_CROSSINGS <= walk.crossings < MIN_CROSSINGS
    assert np.isnan(clock.wander) and np.isnan(walk.wander)
    # over twelve draws: 0.53-0.82 for the clock read without a tick's
    # spread, 0.68-1.11 for the one on the grid, 1.6-2.2 for this walk
    # (2.2-3.2 against the noise alone: the tick's spread narrows the margin)
    assert clock.steady_periods and 0.5 <= clock.jitter_ratio <= 1.0
    assert grid.steady_periods and 0.6 <= grid.jitter_ratio <= 1.3 < CLOCK_JITTER
    assert not walk.steady_periods and walk.jitter_ratio > CLOCK_JITTER
    # the wander's own reading needs more crossings
    assert not clock.keeps_clock and not walk.keeps_clock
    assert clock.as_dict()["jitter_ratio"] == round(clock.jitter_ratio, 3)
    # the same clock with noise the loop never saw: its periods are not read
    pv, _ = _swing(k / P, rng)
    _, op = _swing(k / P, rng, noise=0.0)
    unseen = _read(pv, op)
    assert not unseen.steady_periods and np.isnan(unseen.jitter_ratio)
    # nor where the PV was stored by exception: each stored point is joined
    # to the next by a straight line, and the noise between them is gone
    pv, op = _swing(k / P, rng)
    kept = np.r_[0, np.flatnonzero(np.abs(np.diff(pv)) > 0.08) + 1, pv.size - 1]
    stored = np.interp(k, kept, pv[kept])
    assert 0.1 < kept.size / pv.size < 0.7
    squeezed = _read(stored, op)
    assert not squeezed.steady_periods and np.isnan(squeezed.jitter_ratio)
    # nor where the PV jumps across its band between two samples (a fast
    # flow's slip, or a coarse export of it): the crossing is then placed by
    # the noise on the samples either side, whatever the jump's own timing
    sharp_pv = 50.0 + np.sign(np.sin(2 * np.pi * (k + 0.5) / P)) + rng.normal(0, 0.05, k.size)
    sharp = _read(sharp_pv, 40.0 - KC * (sharp_pv - 50.0))
    assert MIN_JITTER_CROSSINGS <= sharp.crossings < MIN_CROSSINGS and sharp.readable
    assert np.isnan(sharp.jitter_ratio) and not sharp.steady_periods


def test_a_clock_read_through_a_slowly_beating_error_still_keeps_time():
    # the sample grid beats against a period of 60.37 samples: the crossings'
    # error varies slowly and scatters more than a clock's jitter, yet it does
    # not grow as a random walk does
    rng = np.random.default_rng(2)
    k = np.arange(40000)
    pv, op = _swing(k / 60.37, rng, noise=0.01)
    pw = _read(pv, op)
    assert pw.crossings > 600 and pw.keeps_clock
    assert pw.wander < 0.1 * pw.crossings / 15


@pytest.mark.parametrize("klass, seed, index, clock", [
    ("flow-linear-disturbance", 15, 0, True),     # a triangular load: read sticky before
    ("level-linear-disturbance", 12, 1, True),     # a square load: read sticky before
    ("flow-stiction-cycle", 10, 0, False),
    ("level-stiction-cycle", 10, 1, False),
])
def test_realistic_loads_keep_time_and_valves_do_not(klass, seed, index, clock):
    """Loops of the realistic benchmark's study seeds: the periodic loads on
    healthy valves that the scan called sticky keep a clock's time, and read
    linear-oscillation; sticky valves' limit cycles wander and keep their verdict."""
    from valvediag import classify_loop
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop(klass, benchmark_rng(klass, seed, index))
    d = classify_loop(loop.pv, loop.op, loop.sp, sample_time=loop.sample_time,
                      process_type=loop.process_type)
    pw = d.evidence["phase_wander"]
    assert pw["keeps_clock"] == clock, (pw, d.reason)
    assert d.verdict == ("linear-oscillation" if clock else "stiction"), d.reason
    if not clock:
        assert pw["wander"] > CLOCK_WANDER


def test_the_stretches_of_a_record_cut_by_gaps_are_read_on_one_clock():
    # four stretches of 25 cycles, 1,234 samples missing between them: too few
    # crossings each to read the wander, enough together. A clock holds its
    # phase through the gaps; a limit cycle's wanders on through them, unseen
    from valvediag.analysis.oscillation import pooled_phase_wander

    rng = np.random.default_rng(5)
    k = np.arange(4 * int(25 * P) + 3 * 1234)
    ends = np.cumsum(P * (1.0 + 0.01 * rng.standard_normal(k.size // int(P) + 2)))
    walk_phase = np.interp(k, np.r_[0.0, ends], np.arange(ends.size + 1.0))
    starts = [i * (int(25 * P) + 1234) for i in range(4)]
    for phase, keeps in ((k / P, True), (walk_phase, False)):
        pv, op = _swing(phase, rng)
        reads = [_read(pv[s:s + int(25 * P)], op[s:s + int(25 * P)]) for s in starts]
        # too few crossings each for a wander; each stretch's periods alone
        # already tell the clock from the walk
        assert all(not r.keeps_clock and r.readable and 20 <= r.crossings < MIN_CROSSINGS
                   and r.steady_periods is keeps for r in reads)
        pooled = pooled_phase_wander(reads, [float(s) for s in starts])
        assert pooled.crossings == sum(r.crossings for r in reads)
        assert pooled.keeps_clock is keeps, pooled.reason
        # the gaps' cycles are counted: 25 a stretch and 20 or 21 a gap
        assert pooled.cycle[-1] - pooled.cycle[0] + 1 >= 4 * 24 + 3 * 20
        if keeps:
            assert 0.3 <= pooled.wander <= 0.75 and "over 4 stretches" in pooled.reason
            assert pooled.departures().size == pooled.crossings
        else:
            assert pooled.wander > 2.0 and "wanders" in pooled.reason
    # stretches whose phase cannot be read (noise the loop never saw) are not pooled
    pv, _ = _swing(k / P, rng)
    _, op = _swing(k / P, rng, noise=0.0)
    unseen = [_read(pv[s:s + int(25 * P)], op[s:s + int(25 * P)]) for s in starts]
    assert not any(r.readable for r in unseen)
    assert not pooled_phase_wander(unseen, starts).keeps_clock


@pytest.mark.parametrize("klass, seed, index, steady", [
    ("temperature-linear-disturbance", 1, 4, True),   # a square load, 6 crossings in 2 h
    ("temperature-linear-disturbance", 2, 13, True),  # a triangular load, 5 in 1 h
    ("flow-linear-disturbance", 1, 12, True),         # a clipped sine, 14 in 2 h
    ("flow-linear-disturbance", 1, 0, True),          # a sine, 26 in 2 h
    # a square load whose moves fall on the simulation's steps of half a
    # sample: 22 crossings in 2 h, its periods 2.1 times the noise's reading
    ("temperature-linear-disturbance", 11, 2, True),
    ("temperature-stiction-cycle", 10, 3, False),     # 9 crossings in 2 h
    ("flow-stiction-cycle", 12, 3, False),            # 38 in 2 h
])
def test_short_records_of_loads_keep_time_by_their_periods_and_valves_do_not(klass, seed, index,
                                                                          steady):
    """Loops of the realistic benchmark's development and study seeds with too
    few crossings for a wander. The periodic loads on healthy valves, which
    the valve signature called sticky, vary their periods about as little
    as the noise's reading of a clock, and read linear-oscillation; sticky
    valves' limit cycles vary theirs over twice as much and keep their verdict."""
    from valvediag import classify_loop
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop(klass, benchmark_rng(klass, seed, index))
    d = classify_loop(loop.pv, loop.op, loop.sp, sample_time=loop.sample_time,
                      process_type=loop.process_type)
    pw = d.evidence["phase_wander"]
    assert pw["wander"] is None and not pw["keeps_clock"], pw
    if steady:
        assert pw["jitter_ratio"] <= CLOCK_JITTER, pw
        assert d.verdict == "linear-oscillation" and "periods' jitter" in d.reason, d.reason
    else:
        assert pw["jitter_ratio"] > 1.5 * CLOCK_JITTER, pw
        assert d.verdict == "stiction", d.reason


def test_a_limit_cycle_whose_noise_was_added_afterwards_keeps_time_but_a_level_is_read_as_ever():
    """The paper's experiment, as its scenarios are drawn here, adds the PV's
    noise and the controller's answer to it after the simulation: the noise
    never moves the valve, and a sticky valve's limit cycle keeps a clock's
    time over the 20 cycles recorded (at 40 samples a period, where its
    ramps cross the band over 4 samples). On an integrating loop the periods
    are not read as a load's, and the Backlash Index names the valve as
    before."""
    from valvediag import classify_loop
    from valvediag.paper.scenarios import draw_cases, record

    rng = np.random.default_rng(5)
    reads = []
    for c in draw_cases("stiction", 6, seed=77, cycles=20):
        pv, op, h = record(c, 40, 1.0, rng)
        pw = phase_wander(pv, detect_oscillation(pv, h), op)
        if pw.steady_periods:
            reads.append(classify_loop(pv, op, sample_time=h, process_type="integrating"))
    assert len(reads) >= 3
    assert all(d.verdict == "stiction" for d in reads), [d.reason for d in reads]
