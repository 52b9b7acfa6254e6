"""Valve travel: the recorded valve position against the OP (hand-built traces and loops)."""
import numpy as np
import pytest

from valvediag import classify_loop, simulate_loop
from valvediag.analysis.travel import TRAVEL_LIMITS, valve_travel
from valvediag.models.valves import apply_valve

H = 1.0


def _op(n=6000, seed=0):
    """An OP that reverses at wandering points: a triangle over a slow sine, with noise."""
    t = np.arange(n) * H
    rng = np.random.default_rng(seed)
    tri = 2 / np.pi * np.arcsin(np.sin(2 * np.pi * t / 400.0))
    return 50.0 + 4.0 * tri + 3.0 * np.sin(2 * np.pi * t / 1700.0) + rng.normal(0, 0.02, n)


def _sticky(op, S, J):
    """Kano's valve behind an actuator that does not reverse on the OP's noise."""
    return apply_valve("kano", op, S=S, J=J, noise_band=0.12)


def _position(valve, noise=0.1, seed=1):
    """A positioner's report of the valve: its position plus white noise."""
    return valve + np.random.default_rng(seed).normal(0, noise, valve.size)


def test_a_parallelogram_with_vertical_sides_is_a_sticky_valve():
    op = _op()
    mv = _position(_sticky(op, 3.0, 2.0))
    t = valve_travel(mv, op, H)
    assert t.verdict == "stiction", t.reason
    # every slip of 2 (20 noise sd) is seen, and none is expected from noise
    assert t.toward >= 20 and t.jumps_expected < 0.1 and t.toward >= 0.9 * t.jumps
    assert t.jump == pytest.approx(2.0, rel=0.15)
    assert t.S == pytest.approx(3.0, rel=0.2)
    # the grid holds neither S = 3 nor J/S = 2/3 exactly: the fit is close, not exact
    assert t.ratio < 0.5 and t.linear_over_noise > 5


def test_a_parallelogram_with_sloped_sides_is_a_dead_band():
    op = _op()
    mv = _position(apply_valve("backlash", op, DB=3.0))
    t = valve_travel(mv, op, H)
    assert t.verdict == "backlash", t.reason
    assert t.toward == 0
    assert t.S == pytest.approx(3.0, rel=0.2) and t.J == 0.0


def test_slips_too_small_to_count_one_by_one_show_pooled():
    # J = 0.9 against a position noise of 0.5: each slip is 1.3 standard
    # deviations of a sample-to-sample difference and 2.5 of the difference of
    # four samples' means, below the count's 4.5, so no slip is counted; over
    # the record's 30 cycles a valve that slips fits the position steadily
    # better than any dead band
    op = _op()
    for seed in (1, 3, 4):
        t = valve_travel(_position(_sticky(op, 3.0, 0.9), noise=0.5, seed=seed), op, H)
        assert t.toward == 0
        assert t.verdict == "stiction", t.reason
        assert t.slip_fit > TRAVEL_LIMITS["slip_fit"] and t.slip_t > TRAVEL_LIMITS["slip_t"]
        assert "show pooled" in t.reason


def test_slips_hidden_in_one_samples_noise_are_counted_on_four_samples_means():
    # J = 0.9 against a position noise of 0.25: 2.5 standard deviations of a
    # sample-to-sample difference (not counted), 5.1 of the difference of four
    # samples' means (counted)
    op = _op()
    for seed in (1, 2, 3):
        t = valve_travel(_position(_sticky(op, 3.0, 0.9), noise=0.25, seed=seed), op, H)
        assert t.verdict == "stiction", t.reason
        assert t.step == 4 and t.toward >= 3 and t.toward >= 0.9 * t.jumps
        assert "means of 4 samples" in t.reason
        assert t.jump == pytest.approx(0.9, rel=0.35)


def test_a_dead_band_through_the_same_noise_fits_no_pooled_slip():
    op = _op()
    for seed in (1, 2, 3):
        t = valve_travel(_position(apply_valve("backlash", op, DB=3.0), noise=0.25, seed=seed),
                         op, H)
        assert t.verdict == "backlash", t.reason
        # a slip jump fits worse than the dead band, block after block
        assert t.slip_fit < 0 and t.slip_t < 0


def test_a_stick_band_as_wide_as_the_ops_swing_is_found():
    # the OP swings 3.2 and the valve sticks over 3.0 of it (a sawtooth's valve
    # slips at the top of each rise): the band is searched up to the OP's
    # 1-99 % range, and a valve with a slip fits better than a dead band
    n = 6000
    t = np.arange(n) * H
    for seed in (1, 2, 3):
        rng = np.random.default_rng(seed)
        op = (50.0 + 1.6 * 2 / np.pi * np.arcsin(np.sin(2 * np.pi * t / 400.0))
              + rng.normal(0, 0.02, n))
        tv = valve_travel(_position(_sticky(op, 3.0, 1.5), noise=0.5, seed=seed), op, H)
        assert tv.verdict == "stiction", tv.reason
        assert tv.S == pytest.approx(3.0, rel=0.03) and tv.J > 0
        assert tv.slip_fit > TRAVEL_LIMITS["slip_fit"]


def _staircase(op, band):
    """A valve that stands until the OP is ``band`` away, then jumps to it (stick-slip)."""
    out = np.empty_like(op)
    out[0] = op[0]
    for k in range(1, op.size):
        out[k] = op[k] if abs(op[k] - out[k - 1]) > band else out[k - 1]
    return out


def test_a_staircase_of_slips_on_a_creeping_op_is_a_sticky_valve():
    # the OP creeps one way for the whole record (no reversal): the valve stands
    # and jumps to the OP each time the OP has moved 2 on
    n = 4000
    op = 40.0 + 0.005 * np.arange(n) + np.random.default_rng(3).normal(0, 0.02, n)
    mv = _position(_staircase(op, 2.0))
    t = valve_travel(mv, op, H)
    assert t.verdict == "stiction", t.reason
    assert t.toward >= 8


@pytest.mark.parametrize("delay", [0, 1])
def test_a_valve_that_follows_the_op_is_linear(delay):
    op = _op()
    valve = 0.9 * op + 4.0
    if delay:
        valve = np.r_[valve[:1], valve[:-1]]
    t = valve_travel(_position(valve), op, H)
    assert t.verdict == "linear", t.reason
    assert t.linear_over_noise < TRAVEL_LIMITS["linear_over_noise"]
    assert t.toward == 0


def test_a_position_that_stands_still_while_the_op_travels_is_no_response():
    op = _op() * 4.0 - 150.0                        # travels about 50 %
    t = valve_travel(_position(np.full(op.size, 30.0)), op, H)
    assert t.verdict == "no-response"
    assert "stuck fast" in t.reason


def test_an_op_that_hardly_moves_tells_nothing():
    n = 3000
    op = 50.0 + np.random.default_rng(4).normal(0, 0.05, n)
    t = valve_travel(_position(op, noise=0.3), op, H)
    assert t.verdict == "unknown"


def test_a_gap_in_the_position_reads_the_longest_stretch():
    op = _op()
    mv = _position(_sticky(op, 3.0, 2.0))
    mv[2000:2100] = np.nan
    t = valve_travel(mv, op, H)
    assert t.verdict == "stiction" and t.samples == op.size - 2100


def test_unequal_lengths_are_refused():
    with pytest.raises(ValueError, match="mv has 10 samples but op has 11"):
        valve_travel(np.zeros(10), np.zeros(11), 1.0)
    with pytest.raises(ValueError, match="sample_time"):
        valve_travel(np.zeros(10), np.zeros(10), 0.0)


def test_the_plot_draws_the_position_against_the_op():
    import matplotlib

    matplotlib.use("Agg")
    op = _op(2000)
    t = valve_travel(_position(_sticky(op, 3.0, 2.0)), op, H)
    ax = t.plot()
    assert ax.get_xlabel() == "OP" and len(ax.lines) >= 1 + t.toward
    d = t.as_dict()
    assert d["verdict"] == "stiction" and isinstance(d["jumps"], int)


def _flow_loop(valve, valve_params, load_profile, n=7200, seed=5):
    """A PI flow loop (self-regulating, tau 10 s) recorded at 1 s, with its valve position."""
    run = simulate_loop(kc=0.4, ti=12.0, sample_time=H, n_samples=n, process="self-regulating",
                        tau=10.0, sp=50.0, sp_step=1.0, sp_step_time=60.0, load=0.0,
                        valve=valve, valve_params=valve_params, load_profile=load_profile,
                        noise_std=0.05, seed=seed,
                        valve_noise_band=0.3 if valve == "kano" else 0.0)
    mv = _position(run.mv, noise=0.2, seed=seed)
    return run.pv, run.op, run.sp, mv


def test_a_triangular_load_on_a_flow_loop_is_not_the_valve_when_its_position_is_recorded():
    # a PI loop turns a triangular load into a square PV and a triangular OP:
    # the picture of a sticky valve's limit cycle. The position follows the OP.
    n = 7200
    t = np.arange(n) * H
    load = 4.0 * 2 / np.pi * np.arcsin(np.sin(2 * np.pi * t / 300.0))
    pv, op, sp, mv = _flow_loop("linear", None, load, n)
    d = classify_loop(pv, op, sp, sample_time=H, process_type="self-regulating", mv=mv)
    assert d.verdict == "linear-oscillation", d.reason
    assert "valve position follows the OP" in d.reason
    assert d.evidence["valve_travel"]["verdict"] == "linear"


def test_a_sticky_flow_valve_in_a_limit_cycle_is_named_from_its_position():
    pv, op, sp, mv = _flow_loop("kano", {"S": 3.0, "J": 2.5}, None)
    d = classify_loop(pv, op, sp, sample_time=H, process_type="self-regulating", mv=mv)
    assert d.verdict == "stiction", d.reason
    assert "recorded valve position" in d.reason


def test_a_sticky_valve_without_a_limit_cycle_is_named_from_its_position():
    # slow integral action and a wandering load: the OP creeps, the valve sticks
    # at the OP's reversals and slips (five times in 4 h; no cycle for the
    # oscillation detector)
    n = 14400
    rng = np.random.default_rng(8)
    pts = np.cumsum(rng.normal(0, 4.0, n // 600 + 2))
    load = np.interp(np.arange(n), np.arange(pts.size) * 600, pts - pts[0])
    run = simulate_loop(kc=0.2, ti=120.0, sample_time=H, n_samples=n, process="self-regulating",
                        tau=8.0, sp=50.0, valve="kano", valve_params={"S": 2.0, "J": 1.5},
                        load_profile=load, noise_std=0.05, seed=9, valve_noise_band=0.3)
    mv = _position(run.mv, noise=0.15, seed=9)
    d = classify_loop(run.pv, run.op, run.sp, sample_time=H, process_type="self-regulating",
                      mv=mv)
    assert d.verdict == "stiction", d.reason
    assert d.evidence["valve_travel"]["toward"] >= 2


def test_a_position_of_the_wrong_length_is_refused():
    with pytest.raises(ValueError, match="mv"):
        classify_loop(np.zeros(100), np.zeros(100), sample_time=1.0, mv=np.zeros(99))


def _scan(pv, op, sp, mv=None):
    """The scan's verdict on one self-regulating loop recorded at 1 s, with ``mv`` as its
    registry's position tag when given."""
    import datetime as dt

    import polars as pl

    from valvediag.io.registry import LoopSpec
    from valvediag.scan import LoopJob, ScanConfig, analyse_loop

    n = pv.size
    t0 = dt.datetime(2026, 6, 1, tzinfo=dt.timezone.utc)
    ts = pl.Series([t0 + dt.timedelta(seconds=k) for k in range(n)],
                   dtype=pl.Datetime("us", "UTC"))

    def frame(x):
        return pl.DataFrame({"ts": ts, "value": pl.Series(x, dtype=pl.Float64),
                             "status": pl.Series([None] * n, dtype=pl.String)})

    end = t0 + dt.timedelta(seconds=n)
    spec = LoopSpec(loop="FIC1", pv_tag="FI1", op_tag="FC1", sp_tag="FS1",
                    mv_tag="FV1.POS" if mv is not None else None,
                    process_type="self-regulating", span=100.0)
    frames = {"pv": frame(pv), "op": frame(op), "sp": frame(sp)}
    if mv is not None:
        frames["mv"] = frame(mv)
    job = LoopJob(spec=spec, start=end - dt.timedelta(hours=24), end=end, problems=())
    return analyse_loop(job, frames, ScanConfig(window_hours=24))


def test_the_scan_reads_the_registrys_valve_position_tag():
    n = 7200
    t = np.arange(n) * H
    # a triangular load whose periods vary by 2 % (another loop's cycle): no
    # clock's steady timing names it
    ends = np.cumsum(300.0 * (1.0 + 0.02 * np.random.default_rng(1).standard_normal(n)))
    phase = np.interp(t, np.r_[0.0, ends], np.arange(n + 1.0))
    load = 4.0 * 2 / np.pi * np.arcsin(np.sin(2 * np.pi * phase))
    pv, op, sp, mv = _flow_loop("linear", None, load, n)
    without, with_position = _scan(pv, op, sp), _scan(pv, op, sp, mv)
    # the PV and OP alone show a sticky valve's picture; the position clears the valve
    assert without.verdict == "stiction"
    assert with_position.verdict == "linear-oscillation", with_position.reason
    assert with_position.evidence["valve_travel"]["verdict"] == "linear"


def test_the_report_draws_the_reported_position_behind_the_verdict():
    from valvediag.report.plot import loop_svg

    pv, op, sp, mv = _flow_loop("kano", {"S": 3.0, "J": 2.5}, None)
    r = _scan(pv, op, sp, mv)
    assert r.verdict == "stiction", r.reason
    travel = r.detail.diagnosis.travel
    # the result keeps only the stretch the figure draws, as its own copy
    assert travel.mv.size == travel.op.size == 1500 and travel.mv.base is None
    assert travel.jump_index.size >= 3 and travel.jump_index.max() < 1499
    k = travel.jump_index
    assert np.all(np.abs(np.diff(travel.mv)[k]) > 5 * travel.noise)   # each a real jump
    svg = loop_svg(r, "f1")
    assert "Valve position vs OP: stiction" in svg
    assert ">jumps<" in svg                                 # the jumps, in red, named
    # without a position the panel is the mean cycle's phase plot
    svg = loop_svg(_scan(pv, op, sp), "f2")
    assert "Valve position vs OP" not in svg and "Phase plot of the mean cycle" in svg


def test_the_report_says_what_the_reported_position_showed():
    from types import SimpleNamespace

    from valvediag.report.explain import explain

    def result(verdict, travel):
        return SimpleNamespace(verdict=verdict, bi=float("nan"), reason="", description="",
                               evidence={"valve_travel": travel}, size=None, needs_action=False,
                               quality={}, amplitude_pct_span=float("nan"),
                               amplitude=float("nan"), period_s=float("nan"), unit="%")

    text = " ".join(explain(result("stiction", {"verdict": "stiction", "toward": 12})))
    assert "catches up in jumps (12 of them)" in text
    text = " ".join(explain(result("linear-oscillation", {"verdict": "linear"})))
    assert "its valve follows the controller" in text and "smoothly, like a sine" not in text
    # a position that does not back the verdict is not quoted as if it did
    text = " ".join(explain(result("backlash", {"verdict": "stiction", "toward": 3})))
    assert "reports its own position" not in text


def test_spikes_of_the_reading_are_not_slips():
    # a valve that follows the OP, read with single-sample spikes: a spike
    # comes back at once, a slip stays
    op = _op()
    mv = _position(0.9 * op + 4.0)
    at = np.arange(300, op.size, 500)
    mv[at] += np.where(np.arange(at.size) % 2, 0.6, -0.6)
    t = valve_travel(mv, op, H)
    assert t.jumps == 0
    assert t.verdict not in ("stiction", "backlash", "undecided"), t.reason


def test_a_step_that_a_compressed_op_hides_is_not_a_slip():
    # a linear valve whose OP the historian kept every 200th sample (a
    # swinging door on a slow OP): between stored points the OP is a straight
    # line and the position, which follows the real OP, steps off it; a jump
    # must exceed what the stored line can hide
    op = _op(6000)
    mv = _position(op, noise=0.01)
    t_idx = np.arange(op.size)
    kept = np.r_[t_idx[::200], op.size - 1]
    op_stored = np.interp(t_idx, kept, op[kept])
    t = valve_travel(mv, op_stored, H)
    assert t.toward == 0, t.reason
    assert t.verdict not in ("stiction", "backlash")


@pytest.mark.parametrize("ti", [100.0, 250.0])
def test_a_slip_seen_in_the_position_names_stiction_where_a_lag_rounds_the_turns(ti):
    # a sticky level valve behind a 15 s lag (10 % of the level's time
    # constant): the lag rounds the PV's turns and the Backlash Index reads
    # backlash; the recorded position shows the valve slip
    run = simulate_loop(kc=1.5, ti=ti, sample_time=H, n_samples=14400, process="integrating",
                        tau=150.0, lag=15.0, sp=50.0, sp_step=1.0, sp_step_time=60.0, load=50.0,
                        valve="kano", valve_params={"S": 3.0, "J": 2.4}, noise_std=0.02, seed=3,
                        valve_noise_band=0.15)
    without = classify_loop(run.pv, run.op, run.sp, sample_time=H, process_type="integrating")
    assert without.bi > 2.4
    d = classify_loop(run.pv, run.op, run.sp, sample_time=H, process_type="integrating",
                      mv=_position(run.mv, noise=0.15, seed=2))
    assert d.verdict == "stiction", d.reason
    if ti == 100.0:
        # strong integral action: the controller reverses once the turn is
        # nearly done (3 % of it after, pooled over the turns), the turns'
        # timing reads nothing, and only the position names the slip
        assert without.verdict == "backlash" and without.evidence["turn_timing"]["kind"] == ""
        assert "shows the valve slip" in d.reason and f"{d.bi:.2f}" in d.reason
    else:
        # the level turns after the OP's reversal: the timing names the slip
        # from PV and OP alone, and the position agrees
        assert without.verdict == "stiction" and "turns after the OP" in without.reason
        assert "the recorded valve position agrees" in d.reason
