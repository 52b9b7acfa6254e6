"""A level's rounded turns against the OP's reversals: a slip behind a lag is not a dead band."""
from __future__ import annotations

import numpy as np
import pytest

from valvediag.analysis import classify_loop, detect_oscillation
from valvediag.analysis.bi import backlash_index
from valvediag.analysis.turn_timing import POOLED_SHARE, POOLED_Z, SLIP_SHARE, turn_timing
from valvediag.models.closedloop import simulate_loop

H = 1.0


def level_cycle(valve: str, lag: float, seed: int = 3):
    """A PI level loop (tau 200 s, Kc 3, Ti 300 s, dead time 2 s) in its valve's limit cycle,
    behind a first-order lag [s]: 6 h at 1 s after an hour's warm-up."""
    params = {"S": 3.0, "J": 2.4} if valve == "kano" else {"DB": 3.0}
    r = simulate_loop(kc=3.0, ti=300.0, sample_time=H, n_samples=7 * 3600,
                      process="integrating", tau=200.0, lag=lag, dead_time=2.0, valve=valve,
                      valve_params=params, sp=50.0, load=50.0, sp_step=1.0, sp_step_time=60.0,
                      noise_std=0.02, seed=seed,
                      valve_noise_band=0.36 if valve == "kano" else 0.0)
    return r.pv[3600:], r.op[3600:], r.sp[3600:]


@pytest.mark.parametrize("lag", [6.0, 12.0])
def test_a_sticky_level_behind_a_lag_turns_after_the_op_a_loose_one_before(lag):
    pv, op, _ = level_cycle("kano", lag)
    period = detect_oscillation(pv, H).period
    # the lag (2-4 % of the period) rounds the slip's turn: the index reads a dead band
    assert backlash_index(pv, H).verdict == "backlash"
    sticky = turn_timing(pv, op, H, period)
    assert sticky.kind == "stiction" and sticky.turns >= 100
    assert sticky.share >= 2 * SLIP_SHARE

    pv, op, _ = level_cycle("backlash", lag)
    loose = turn_timing(pv, op, H, detect_oscillation(pv, H).period)
    # a loose valve moves only while the OP moves on: the level has turned by its reversal
    assert loose.kind == "" and loose.turns >= 20
    assert loose.share < SLIP_SHARE / 4


def test_classify_names_the_slip_behind_a_lag_and_keeps_the_dead_band():
    pv, op, sp = level_cycle("kano", 12.0)
    d = classify_loop(pv, op, sp, sample_time=H, process_type="integrating")
    assert d.verdict == "stiction"
    assert d.evidence["turn_timing"]["kind"] == "stiction"
    assert "turns after the OP has reversed" in d.reason

    pv, op, sp = level_cycle("backlash", 12.0)
    d = classify_loop(pv, op, sp, sample_time=H, process_type="integrating")
    assert d.verdict == "backlash"
    assert d.evidence["turn_timing"]["kind"] == ""


def _benchmark_level(klass: str, seed: int, index: int):
    """PV, OP, set point and sample time [s] of a realistic benchmark draw."""
    from valvediag.synth.cases import benchmark_rng, draw_loop

    loop = draw_loop(klass, benchmark_rng(klass, seed, index))
    return loop.pv, loop.op, loop.sp, loop.sample_time


def test_the_turns_pooled_over_a_noisy_record_name_the_slip_its_median_turn_misses():
    """Measurement noise adds to the level's distances from both ramps, read
    unsigned turn by turn, and pulls each turn's share of them towards a
    half: a noisy dead band reads more than its lag's tail, and the rule for
    a slip must sit above it. Signed, the noise cancels in the distances'
    means. The development draw ``level-stiction-cycle`` 1:17 (noise 2.6 %
    of its range, a lag of 7.7 s on a 375 s cycle, J/S 0.86) read a median
    share of 0.199, just under the slip's 0.2, and ``backlash``; pooled, its
    turns come 18 % after the OP's reversals, 14 standard errors above none.
    Noisy loose level valves (development seed 2 and study seed 10, noise
    1.9-3 %) read medians of 0.07-0.09 and pooled shares of at most 0.04."""
    pv, op, sp, h = _benchmark_level("level-stiction-cycle", 1, 17)
    sticky = turn_timing(pv, op, h, detect_oscillation(pv, h).period, sp=sp)
    assert sticky.share < SLIP_SHARE                       # the median turn misses it
    assert sticky.pooled >= 2 * POOLED_SHARE and sticky.pooled_z >= 3 * POOLED_Z
    assert sticky.kind == "stiction" and "standard errors above none" in sticky.reason
    assert sticky.as_dict()["pooled_share"] == round(sticky.pooled, 3)
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict == "stiction" and d.evidence["turn_timing"]["kind"] == "stiction"
    assert np.isfinite(d.confidence) and d.confidence > 0.3
    for seed, index in ((2, 3), (2, 11), (10, 0)):
        pv, op, sp, h = _benchmark_level("level-backlash-cycle", seed, index)
        loose = turn_timing(pv, op, h, detect_oscillation(pv, h).period, sp=sp)
        assert loose.kind == "" and loose.turns >= 100
        # the noise lifts the median turn's share, not the pooled one
        assert loose.share > 0.06 and loose.pooled < POOLED_SHARE / 2


def test_the_pooled_share_of_a_quiet_record_matches_its_median_turn():
    """Where the noise is small against the turns, each turn reads its share
    cleanly, and pooling the distances reads about the same share."""
    for valve, lag in (("kano", 12.0), ("backlash", 12.0)):
        pv, op, _ = level_cycle(valve, lag)
        t = turn_timing(pv, op, H, detect_oscillation(pv, H).period)
        assert abs(t.pooled - t.share) < 0.05


def test_a_loose_valve_behind_a_long_lag_reads_as_a_slip_pooled_before_it_does_turn_by_turn():
    """The limit the Notes give: the pooled share reads a dead band's lag tail
    as it is. Behind 24 s (2 % of the period) a loose level valve reads
    nothing; behind 48 s (5 %) its tail reads as a slip pooled, not yet by
    the median turn."""
    pv, op, _ = level_cycle("backlash", 24.0)
    t = turn_timing(pv, op, H, detect_oscillation(pv, H).period)
    assert t.kind == "" and t.pooled < POOLED_SHARE
    pv, op, _ = level_cycle("backlash", 48.0)
    t = turn_timing(pv, op, H, detect_oscillation(pv, H).period)
    assert t.kind == "stiction" and t.pooled >= POOLED_SHARE and t.share < SLIP_SHARE


def _stored(op, deadband):
    """``op`` stored by exception with ``deadband`` and read back by straight lines."""
    from valvediag.synth.plant import exception_deadband

    keep = np.flatnonzero(exception_deadband(op, deadband))
    return np.interp(np.arange(op.size), keep, op[keep])


def test_an_op_stored_far_apart_is_placed_by_the_controllers_law(monkeypatch):
    """A loose valve's OP stored by exception with a deadband of a tenth or a
    fifth of its swing: read back by straight lines, its extremes fall
    anywhere between two stored points, which made a dead band read as a
    slip (the synthetic plant's loose level valves, no lag, 0.36-0.82 after
    the reversal). Such a reversal is placed where the PI law, fitted to the
    stored moves, reverses; where the law is not trusted it is not read."""
    import valvediag.analysis.turn_timing as tt

    pv, op, sp = level_cycle("backlash", 0.0)
    period = detect_oscillation(pv, H).period
    swing = np.ptp(np.percentile(op, [5, 95]))
    for share in (0.1, 0.2):
        placed = turn_timing(pv, _stored(op, share * swing), H, period, sp=sp)
        # the dead band still reads as one: the level has turned by the reversal
        assert placed.kind == "" and placed.turns >= 20 and placed.share < SLIP_SHARE / 4
    fine = turn_timing(pv, _stored(op, 0.002 * swing), H, period)
    assert fine.kind == "" and fine.turns >= 20 and fine.share < SLIP_SHARE / 4
    # a law that explains too little of the stored moves places nothing
    monkeypatch.setattr(tt, "LAW_R2", 1.01)
    for share in (0.1, 0.2):
        assert turn_timing(pv, _stored(op, share * swing), H, period, sp=sp).turns == 0
    # and without the guard the coarsely stored OP reads a slip
    monkeypatch.setattr(tt, "OP_RESOLUTION", np.inf)
    assert turn_timing(pv, _stored(op, 0.2 * swing), H, period).kind == "stiction"


def test_a_sticky_level_with_its_op_stored_far_apart_still_turns_after_it(monkeypatch):
    """The slip behind a lag, its OP stored by exception with a fifth of its
    swing: no reversal is read from the stored points, and the controller's
    law places them: the level turns after them, as with the OP in full
    (the realistic benchmark's sticky levels with a compressed OP read
    ``backlash`` by the index, without a turn read)."""
    import valvediag.analysis.turn_timing as tt

    pv, op, sp = level_cycle("kano", 12.0)
    period = detect_oscillation(pv, H).period
    swing = np.ptp(np.percentile(op, [5, 95]))
    full = turn_timing(pv, op, H, period)
    placed = turn_timing(pv, _stored(op, 0.2 * swing), H, period, sp=sp)
    assert placed.kind == "stiction" and placed.turns >= 100
    assert abs(placed.share - full.share) < 0.1
    # the reversals the stored points did not place were placed by the law, and said so
    assert full.by_law == 0 and placed.by_law >= placed.turns // 2
    assert placed.as_dict()["reversals_by_law"] == placed.by_law
    assert "placed by the PI law" in placed.reason
    monkeypatch.setattr(tt, "LAW_R2", 1.01)
    assert turn_timing(pv, _stored(op, 0.2 * swing), H, period, sp=sp).turns == 0


def test_a_compressed_op_is_placed_by_a_law_that_explains_half_its_stored_moves(monkeypatch):
    """The development draw ``level-stiction-cycle`` 1:0 (PV and OP stored
    by exception, noise 2.9 % of the range, a lag of 7.9 s): the PI law
    fitted to the OP's stored moves explains 0.75 of them, too little for the
    workbench's fits, enough to place the OP's reversals. The level turns
    after them, where before no turn was read and the index said
    ``backlash``."""
    import valvediag.analysis.turn_timing as tt
    from valvediag.workbench.data import REBUILD_R2, rebuild_compressed_op

    pv, op, sp, h = _benchmark_level("level-stiction-cycle", 1, 0)
    _, r2 = rebuild_compressed_op(pv, op, h, sp=sp)
    assert tt.LAW_R2 <= r2 < REBUILD_R2
    period = detect_oscillation(pv, h).period
    placed = turn_timing(pv, op, h, period, sp=sp)
    assert placed.kind == "stiction" and placed.turns >= 100
    assert placed.by_law >= placed.turns // 2
    d = classify_loop(pv, op, sp, sample_time=h, process_type="integrating")
    assert d.verdict == "stiction" and "placed by the PI law" in d.reason
    monkeypatch.setattr(tt, "LAW_R2", REBUILD_R2)
    assert turn_timing(pv, op, h, period, sp=sp).turns < 3


def test_turn_timing_abstains_on_coarse_or_bad_records():
    pv, op, _ = level_cycle("kano", 12.0)
    period = detect_oscillation(pv, H).period
    # fewer than 20 samples per period: no turn is placed
    coarse = turn_timing(pv[::20], op[::20], 20 * H, period)
    assert coarse.kind == "" and coarse.turns == 0 and "too coarse" in coarse.reason
    assert turn_timing(pv, op, H, float("nan")).kind == ""
    with pytest.raises(ValueError, match="equal length"):
        turn_timing(pv, op[:-1], H, period)
    with pytest.raises(ValueError, match="positive"):
        turn_timing(pv, op, 0.0, period)


def test_turn_timing_plot_marks_the_reversals():
    import matplotlib

    matplotlib.use("Agg")
    pv, op, _ = level_cycle("kano", 12.0)
    t = turn_timing(pv[:4000], op[:4000], H, detect_oscillation(pv, H).period)
    ax = t.plot()
    assert len(ax.get_title()) > 0
    assert len(ax.lines) >= 1 + t.turns          # the PV and a line at each reversal read
    assert np.isfinite(t.as_dict()["share_after_op_reversal"])
    assert f"pooled {t.pooled:.2f}" in ax.get_title()
