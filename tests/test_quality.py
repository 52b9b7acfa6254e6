"""Tests of valvediag.analysis.quality on small synthetic loops with hand-counted answers."""
from __future__ import annotations

import datetime as dt
import json

import numpy as np
import polars as pl
import pytest

from valvediag.analysis.align import align_loop
from valvediag.analysis.quality import mask_frozen_pv, quality_metrics

UTC = dt.timezone.utc
T0 = dt.datetime(2024, 1, 1, tzinfo=UTC)
N = 3600  # one hour at 1 s


def frame(seconds, values, status=None) -> pl.DataFrame:
    values = [None if (v is None or (isinstance(v, float) and np.isnan(v))) else float(v)
              for v in values]
    if status is None:
        status = [None if v is not None else "I/O Timeout" for v in values]
    return pl.DataFrame({"ts": [T0 + dt.timedelta(seconds=float(s)) for s in seconds],
                         "value": pl.Series(values, dtype=pl.Float64),
                         "status": pl.Series(status, dtype=pl.String)})


def clean_loop(n=N, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    pv = 50 + 5 * np.sin(2 * np.pi * t / 120) + rng.normal(0, 0.05, n)
    op = 50 + 20 * np.sin(2 * np.pi * t / 120 + 1)
    return t, pv, op


def measure(frames, **kw):
    span = kw.pop("span", None)
    aligned = align_loop(frames, **kw)
    return quality_metrics(aligned, frames, span=span)


def test_clean_loop_has_no_issues():
    t, pv, op = clean_loop()
    q = measure({"pv": frame(t, pv), "op": frame(t, op)}, span=100.0)
    assert q.issues == ()
    assert q.bad_pct == 0.0 and q.valid_pct == 100.0 and q.gap_count == 0
    assert q.frozen_pct == 0.0 and not q.compressed and q.saturation_pct == 0.0
    assert q.compression_ratio == 1.0 and q.median_spacing_s == 1.0
    assert q.manual_pct is None
    assert q.samples_per_cycle(120.0) == 120.0
    json.dumps(q.as_dict())  # serialisable for the verdicts table


def test_bad_percentage_counts_state_rows_over_pv_and_op():
    t, pv, op = clean_loop()
    pv = pv.astype(object)
    pv[100:280] = None            # 180 bad PV rows
    op = op.astype(object)
    op[2000:2036] = None          # 36 bad OP rows
    q = measure({"pv": frame(t, pv), "op": frame(t, op)})
    assert q.bad_pct == pytest.approx(100 * (180 + 36) / (2 * N))
    assert q.bad_pct_by_role == {"pv": pytest.approx(5.0), "op": pytest.approx(1.0)}
    assert q.gap_count == 0  # bad states are rows, not gaps
    assert q.valid_pct < 100
    assert not any("bad states" in i for i in q.issues)  # 3.0 % < 5 % limit


def test_gaps_are_counted_with_the_longest():
    t, pv, op = clean_loop()
    keep = np.ones(N, bool)
    keep[1000:1100] = False   # 101 s interval
    keep[2000:2010] = False   # 11 s interval
    q = measure({"pv": frame(t[keep], pv[keep]), "op": frame(t, op)})
    assert q.gap_count == 2
    assert q.longest_gap_s == pytest.approx(101.0)
    assert any("2 gaps in PV/OP, longest 101 s" == i for i in q.issues)


def test_frozen_sensor_is_detected():
    t, pv, op = clean_loop()
    pv = pv.copy()
    pv[1200:2400] = 51.234   # 20 min of identical values
    q = measure({"pv": frame(t, pv), "op": frame(t, op)})
    assert q.longest_frozen_s == pytest.approx(1199.0)
    assert q.frozen_pct == pytest.approx(100 * 1200 / N)
    assert any(i.startswith("PV frozen") for i in q.issues)


def test_a_frozen_run_is_cut_out_of_the_record_and_a_coarse_record_kept_whole():
    t, pv, op = clean_loop()
    pv = pv.copy()
    pv[1200:2400] = 51.234   # 20 min of identical values
    aligned = align_loop({"pv": frame(t, pv), "op": frame(t, op)})
    masked, n = mask_frozen_pv(aligned, span=100.0)
    assert n == 1200 and masked.segments == ((0, 1200), (2400, N))
    assert mask_frozen_pv(masked, span=100.0)[1] == 0
    # one minute flat is no frozen sensor
    t, pv, op = clean_loop()
    pv[100:160] = 50.0
    aligned = align_loop({"pv": frame(t, pv), "op": frame(t, op)})
    assert mask_frozen_pv(aligned)[0] is aligned
    # a quiet PV stored to a coarse grid repeats all through: its 20 flat minutes
    # are the process standing within a step, and stay
    rng = np.random.default_rng(1)
    quiet = np.round(50 + np.cumsum(rng.normal(0, 0.002, N)) + rng.normal(0, 0.01, N), 1)
    quiet[1200:2400] = quiet[1200]
    aligned = align_loop({"pv": frame(t, quiet), "op": frame(t, op)})
    assert mask_frozen_pv(aligned)[0] is aligned
    # a PV that moved three times in an hour, held by its export in between:
    # the rest is too short to say it does not repeat
    t, pv, op = clean_loop()
    held = np.repeat([50.0, 50.4, 50.1, 50.6], N // 4)
    held[[899, 1799, 2699]] += 0.05
    aligned = align_loop({"pv": frame(t, held), "op": frame(t, op)})
    assert mask_frozen_pv(aligned)[0] is aligned


def test_short_flat_stretch_is_not_frozen():
    t, pv, op = clean_loop()
    pv = pv.copy()
    pv[100:160] = 50.0   # one minute: below the 10 min limit
    q = measure({"pv": frame(t, pv), "op": frame(t, op)})
    assert q.frozen_pct == 0.0 and q.longest_frozen_s == pytest.approx(59.0)


def test_compressed_pv_is_flagged():
    t, pv, op = clean_loop()
    rng = np.random.default_rng(3)
    # keep an irregular subset, as swinging-door compression does
    keep = np.sort(rng.choice(N, size=400, replace=False))
    keep[0], keep[-1] = 0, N - 1
    q = measure({"pv": frame(t[keep], pv[keep]), "op": frame(t, op)}, sample_time=1.0,
                max_gap=60.0)
    assert q.compressed
    assert q.compression_ratio == pytest.approx(400 / N)
    assert q.median_spacing_s > 3.0
    assert any("looks compressed" in i for i in q.issues)


def test_step_held_values_are_flagged():
    t, pv, op = clean_loop()
    held = pv[(t // 10) * 10]  # a 10 s value re-exported every second
    q = measure({"pv": frame(t, held), "op": frame(t, op)})
    assert q.repeat_fraction == pytest.approx(0.9, abs=0.01)
    assert q.compressed
    assert any("step-held" in i for i in q.issues)


def test_op_saturation_at_100_and_at_its_own_limit():
    t, pv, op = clean_loop()
    op = op.copy()
    op[0:360] = 100.0                      # 10 % of the time at 100 %
    q = measure({"pv": frame(t, pv), "op": frame(t, op)})
    assert q.saturation_pct == pytest.approx(10.0, abs=0.1)
    # stuck at its own maximum (a configured high limit of 65 %) for 10 minutes
    op2 = 50 + 10 * np.sin(2 * np.pi * t / 120)
    op2[1000:1600] = 65.0
    q2 = measure({"pv": frame(t, pv), "op": frame(t, op2)})
    assert q2.saturation_pct == pytest.approx(100 * 600 / N)
    assert any("OP saturated" in i for i in q2.issues)


def test_constant_op_is_not_saturation():
    t, pv, _ = clean_loop()
    q = measure({"pv": frame(t, pv), "op": frame(t, np.full(N, 42.0))})
    assert q.saturation_pct == 0.0


def test_manual_mode_share_from_the_mode_tag():
    t, pv, op = clean_loop()
    mode = frame([0, 900, 1800], [None] * 3, status=["AUTO", "MAN", "CAS"])
    q = measure({"pv": frame(t, pv), "op": frame(t, op), "mode": mode})
    assert q.manual_pct == pytest.approx(25.0, abs=0.05)
    assert any("manual for 25.0%" in i for i in q.issues)


def test_numeric_mode_codes_are_not_guessed():
    t, pv, op = clean_loop()
    q = measure({"pv": frame(t, pv), "op": frame(t, op), "mode": frame([0], [3.0])})
    assert q.manual_pct is None
    assert any("mode tag values not understood (3.0)" in i for i in q.issues)


def test_coarse_resolution_against_span():
    t, pv, op = clean_loop()
    coarse = np.round(pv)          # 1 unit steps on a 100 unit span = 1 %
    q = measure({"pv": frame(t, coarse), "op": frame(t, op)}, span=100.0)
    assert q.pv_resolution == 1.0
    assert any("coarse PV resolution" in i for i in q.issues)


def test_no_pv_data():
    q = measure({"pv": frame([], []), "op": frame([0, 1], [1.0, 2.0])})
    assert "no PV data" in q.issues


def test_frozen_manual_loop_is_held_not_saturated():
    t, _, _ = clean_loop()
    pv = np.full(N, 42.0)
    op = np.where(t < 1800, 50.0, 53.0)       # an operator moves the OP once, in manual
    q = measure({"pv": frame(t, pv), "op": frame(t, op)})
    assert q.saturation_pct == 0.0
    assert q.op_held_pct == pytest.approx(100.0)
    assert not any("saturated" in i for i in q.issues)
    assert any(i.startswith("OP held constant for 100.0% of the time") for i in q.issues)
    assert any("PV frozen" in i for i in q.issues)


def test_short_breaks_are_bridged_and_long_ones_kept():
    from valvediag.analysis.quality import bridge_short_breaks

    t, pv, op = clean_loop()
    pv = pv.copy()
    pv[100::20] = np.nan                    # a bad state every 20 samples (5 %)
    pv[2000:2010] = np.nan                  # and one stretch of ten
    aligned = align_loop({"pv": frame(t, pv), "op": frame(t, op)})
    assert max(b - a for a, b in aligned.segments) < 1800
    joined, samples = bridge_short_breaks(aligned)
    assert joined.segments == ((0, 2000), (2010, N))
    assert samples == np.isnan(pv).sum() - 10
    k = 120                                 # a bridged sample lies on the line
    assert joined.pv[k] == pytest.approx(0.5 * (pv[k - 1] + pv[k + 1]))
    assert np.isnan(joined.pv[2000:2010]).all()
    assert np.array_equal(joined.op, aligned.op)
    assert bridge_short_breaks(joined) == (joined, 0)
    # the samples drawn are marked; a second, longer bridge adds its own marks
    assert np.array_equal(joined.bridged, np.isnan(pv) & ~np.isin(np.arange(N), range(2000, 2010)))
    whole, _ = bridge_short_breaks(joined, 10)
    assert whole.segments == ((0, N),) and np.array_equal(whole.bridged, np.isnan(pv))


def test_a_bridged_break_holds_the_set_point_and_draws_pv_and_op():
    """Ten rows missing from every tag (an export's lost page): bridged by
    a straight line in PV and OP. The set point is held at its value before
    the break by the alignment (a set point stays where it was put), so the
    readers that need it whole (the set-point steps, the valve events) still
    have it over the bridged stretch."""
    from valvediag.analysis.quality import bridge_short_breaks

    t, pv, op = clean_loop()
    sp = np.where(t < 1000, 50.0, 52.0)
    keep = (t < 2000) | (t >= 2010)
    aligned = align_loop({"pv": frame(t[keep], pv[keep]), "op": frame(t[keep], op[keep]),
                          "sp": frame(t[keep], sp[keep])}, sample_time=1.0, max_gap=2.0)
    assert len(aligned.segments) == 2
    joined, samples = bridge_short_breaks(aligned, 20)
    assert len(joined.segments) == 1 and samples >= 10
    gap = slice(2000, 2010)
    assert np.all(joined.sp[gap] == 52.0)
    assert np.all(np.isfinite(joined.pv[gap])) and np.all(np.isfinite(joined.op[gap]))
    # the line is marked as drawn, not measured: a model fitted to the
    # record scores only the samples that were measured
    assert aligned.bridged is None
    assert np.array_equal(np.flatnonzero(joined.bridged), np.flatnonzero(~aligned.valid))
    measured = joined.measured_pv(1990, 2020)
    assert np.isnan(measured[10:20]).all()
    assert np.isfinite(np.delete(measured, range(10, 20))).all()
    assert np.array_equal(joined.measured_pv(0, 1000), joined.pv[:1000])


def _triangle(n=20000, period=600, swing=1.8, noise=0.01, seed=0):
    t = np.arange(n)
    tri = swing * np.abs(((t / period) % 1) * 2 - 1)
    return tri + np.random.default_rng(seed).normal(0.0, noise, n)


def test_white_noise_is_read_from_every_sample_of_a_raw_record():
    from valvediag.analysis.quality import white_noise_std

    x = _triangle(noise=0.05)
    assert white_noise_std(x) == pytest.approx(0.05, rel=0.05)


def test_a_record_kept_at_its_corners_alone_reads_no_swing_as_noise():
    """A swinging door wider than the noise keeps a triangle's turns and
    nothing else: each stored point differs from its neighbours' line by the
    swing, which the median read as noise (1.86 on a swing of 1.8)."""
    from valvediag.analysis.quality import stored_points, white_noise_std
    from valvediag.synth.plant import historian_record

    stored = historian_record(_triangle(noise=0.01), 0.1)
    assert stored_points(stored).size < 0.01 * stored.size   # the corners, and hardly more
    est = white_noise_std(stored)
    assert 0.0 < est < 0.05 * 1.8


def test_the_stored_resolution_of_a_swinging_door_record_is_about_its_deviation():
    """Noise of a third of the door's deviation closes the door now and then on
    a triangle's ramps: the turns dominate what the median reads, the low
    percentile reads the deviation."""
    from valvediag.analysis.quality import stored_resolution, white_noise_std
    from valvediag.synth.plant import historian_record

    dev = 0.1
    stored = historian_record(_triangle(period=200, noise=0.03), dev)
    assert white_noise_std(stored) > 10 * dev                # the turns, read as noise
    assert 0.3 * dev < stored_resolution(stored) < 2.0 * dev
    # no noise estimate: on a raw record it reads a tenth of the noise
    assert stored_resolution(_triangle(noise=0.05)) < 0.2 * 0.05



def test_a_sparse_record_is_read_at_its_stored_resolution():
    """An OP that creeps 1 % over 300 s and back, with white noise of 0.03,
    stored by a swinging door of 0.1 %: the noise closes the door now and
    then, but most stored points are the ends of the creeps, and their
    differences from their neighbours' lines read as a noise ten times the
    door. Read at its stored resolution, the noise is below a third of the
    door's deviation (a band of six of it about the door's deviation, the
    finest move the record resolves; it reads a quarter to a half of the
    noise drawn on seeds 3-7); a raw record's is what white_noise_std
    reads."""
    from valvediag.analysis.quality import (SPARSE_SPACING, resolved_noise_std,
                                            stored_points, stored_resolution, white_noise_std)
    from valvediag.synth.plant import historian_record

    rng = np.random.default_rng(3)
    creep = np.concatenate([40.0 + np.linspace(0.0, 1.0, 300)[::(-1) ** k] for k in range(10)])
    raw = creep + rng.normal(0.0, 0.03, creep.size)
    kept = historian_record(raw, 0.1)
    assert np.median(np.diff(stored_points(kept))) >= SPARSE_SPACING
    assert white_noise_std(kept) > 0.5
    assert 0.0 < resolved_noise_std(kept) < 0.1 / 3
    assert resolved_noise_std(raw) == white_noise_std(raw)
    # a record the noise keeps closing the door on is not sparse, and its
    # noise is read as before
    noisy = historian_record(creep + rng.normal(0.0, 0.2, creep.size), 0.1)
    assert resolved_noise_std(noisy) == white_noise_std(noisy) > 0.1
    # a fast cycle (30 samples) kept at its turns, four stored points a
    # period and five or six samples apart: sparse only given its period
    t = np.arange(3000)
    fast = historian_record(50.0 + 4.0 / np.pi * np.arcsin(np.sin(2 * np.pi * t / 30.0))
                            + rng.normal(0.0, 0.01, t.size), 0.1)
    assert np.median(np.diff(stored_points(fast))) < SPARSE_SPACING
    assert resolved_noise_std(fast) == white_noise_std(fast) > 0.2
    bounded = resolved_noise_std(fast, period=30.0)
    assert bounded == pytest.approx(stored_resolution(fast) / 3) and \
        bounded < white_noise_std(fast) / 4


@pytest.mark.parametrize("step", [0.01, 0.1, 1.0])
def test_the_rounding_of_an_export_is_read_as_the_records_quantum(step):
    from valvediag.analysis.quality import record_quantum

    # a swing of 1.8 with noise of a hundredth: every rounding holds values
    x = 40.0 + _triangle(noise=0.01)
    assert record_quantum(np.round(x / step) * step) == pytest.approx(step, rel=1e-6)


def test_a_record_in_full_precision_or_a_straight_ramp_has_no_quantum():
    from valvediag.analysis.quality import record_quantum
    from valvediag.synth.plant import historian_record

    assert record_quantum(_triangle(noise=0.01)) == 0.0
    # a noise-free triangle's moves are all alike, but it holds no value
    assert record_quantum(_triangle(noise=0.0)) == 0.0
    # drawn back between a swinging door's points: straight lines, no grid
    assert record_quantum(historian_record(_triangle(noise=0.01), 0.1)) == 0.0
    # noise of several quanta moves nearly every sample: no staircase
    assert record_quantum(np.round(_triangle(noise=0.5) / 0.1) * 0.1) == 0.0
    assert record_quantum(np.round(_triangle(n=30, noise=0.01), 1)) == 0.0   # too few moves


def test_drawn_lines_keep_the_lines_longer_than_a_short_bridge():
    from valvediag.analysis.quality import BRIDGE_SAMPLES, drawn_lines

    m = np.zeros(30, bool)
    m[2:2 + BRIDGE_SAMPLES] = True            # a short bridge: left out
    m[10:10 + BRIDGE_SAMPLES + 1] = True      # one sample longer: kept
    m[25:] = True                             # to the end: kept
    out = drawn_lines(m)
    assert not out[:10].any()
    assert out[10:10 + BRIDGE_SAMPLES + 1].all() and not out[10 + BRIDGE_SAMPLES + 1:25].any()
    assert out[25:].all()
    assert not drawn_lines(np.zeros(5, bool)).any()
    with pytest.raises(ValueError, match="drawn"):
        from valvediag import classify_loop
        classify_loop(np.zeros(100), np.zeros(100), sample_time=1.0, drawn=np.zeros(99, bool))


def test_the_typical_window_is_an_ordinary_stretch_and_the_most_active_the_widest():
    """Through a cycle that one large move broke, the window that travels
    furthest holds the move; the one whose travel is the median of all does
    not. A record no longer than the window starts at 0."""
    from valvediag.analysis.quality import most_active_window, typical_window

    x = np.sin(np.arange(20000) / 50.0)
    x[15000:15500] += 5.0
    wide, typical = most_active_window(x, 3000), typical_window(x, 3000)
    assert wide <= 15000 < wide + 3000
    assert not (typical <= 15500 and 15000 < typical + 3000)
    assert np.ptp(x[typical:typical + 3000]) == pytest.approx(2.0, abs=0.01)
    assert typical_window(x[:100], 3000) == most_active_window(x[:100], 3000) == 0
