"""A swing that keeps a clock's time (a load from outside the loop) against a
limit cycle, whose phase wanders with the noise the controller answers."""
import matplotlib
import numpy as np
import pytest

from valvediag.analysis.oscillation import (CLOCK_WANDER, MIN_CROSSINGS, detect_oscillation,
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
    # a short snapshot: fewer crossings than a wander can be read from
    n_short = int(P * (MIN_CROSSINGS - 5))
    short = _read(*_swing(k[:n_short] / P, rng))
    assert not short.keeps_clock and np.isnan(short.wander)
    assert f"fewer than {MIN_CROSSINGS}" in short.reason
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
        assert all(not r.keeps_clock and r.readable and 20 <= r.crossings < MIN_CROSSINGS
                   for r in reads)
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
