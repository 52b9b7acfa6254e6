"""Tests of valvediag.analysis.align: uniform grid, interpolation rules, segments."""
from __future__ import annotations

import datetime as dt

import hypothesis.strategies as st
import numpy as np
import polars as pl
import pytest
from hypothesis import given, settings

from valvediag.analysis.align import align_loop, contiguous_segments, median_spacing

UTC = dt.timezone.utc
T0 = dt.datetime(2024, 1, 1, tzinfo=UTC)


def frame(seconds, values, status=None) -> pl.DataFrame:
    """Samples at T0 + seconds; None values are bad states."""
    return pl.DataFrame({
        "ts": [T0 + dt.timedelta(seconds=float(s)) for s in seconds],
        "value": pl.Series(values, dtype=pl.Float64),
        "status": pl.Series(status if status is not None else
                            [None if v is not None else "Bad Input" for v in values],
                            dtype=pl.String),
    })


def test_linear_interpolation_between_good_samples():
    pv = frame([0, 2, 4], [0.0, 4.0, 2.0])
    a = align_loop({"pv": pv}, sample_time=0.5)
    np.testing.assert_allclose(a.t, np.arange(9) * 0.5)
    # hand calculation: 0 -> 4 over 2 s, then 4 -> 2 over 2 s
    np.testing.assert_allclose(a.pv, [0, 1, 2, 3, 4, 3.5, 3, 2.5, 2])
    assert a.valid.all() and a.segments == ((0, 9),)
    assert a.time[0] == np.datetime64("2024-01-01T00:00:00", "us")
    assert a.start == T0


def test_never_interpolates_across_a_bad_state():
    pv = frame([0, 1, 2, 3, 4], [0.0, 1.0, None, 3.0, 4.0])
    a = align_loop({"pv": pv}, sample_time=0.5)
    expected_valid = [True, True, True, False, False, False, True, True, True]
    assert a.valid.tolist() == expected_valid
    assert np.isnan(a.pv[~a.valid]).all()
    assert a.segments == ((0, 3), (6, 9))


def test_never_interpolates_across_a_long_gap():
    pv = frame([0, 1, 2, 12, 13], [0.0, 1.0, 2.0, 12.0, 13.0])
    a = align_loop({"pv": pv}, sample_time=1.0, max_gap=5.0)
    assert a.valid.tolist() == [True] * 3 + [False] * 9 + [True] * 2
    b = align_loop({"pv": pv}, sample_time=1.0, max_gap=10.0)
    assert b.valid.all()
    np.testing.assert_allclose(b.pv, np.arange(14.0))


def test_default_sample_time_is_robust_median_and_max_gap_is_five_times():
    seconds = np.r_[np.arange(0, 100, 2.0), np.arange(400, 500, 2.0)]  # one 300 s gap
    a = align_loop({"pv": frame(seconds, list(seconds))})
    assert a.sample_time == 2.0 and a.max_gap == 10.0
    assert median_spacing((seconds * 1e6).astype(np.int64)) == 2.0
    assert len(a.segments) == 2
    assert a.n == 250  # 0 .. 498 s every 2 s


def test_valid_requires_pv_and_op_and_segments_split_on_either():
    pv = frame(range(6), [0.0, 1, 2, 3, 4, 5])
    op = frame(range(6), [0.0, 1, None, 3, 4, 5])
    a = align_loop({"pv": pv, "op": op}, sample_time=1.0)
    assert a.role_valid["pv"].all()
    assert a.valid.tolist() == [True, True, False, True, True, True]
    assert a.segments == ((0, 2), (3, 6))


def test_set_point_is_held_and_a_bad_state_invalidates_it_until_the_next_sample():
    pv = frame(range(10), list(map(float, range(10))))
    sp = frame([-100, 3, 6], [5.0, None, 7.0])  # first sample before the window
    a = align_loop({"pv": pv, "sp": sp}, sample_time=1.0)
    assert a.sp[:3].tolist() == [5.0, 5.0, 5.0]
    assert np.isnan(a.sp[3:6]).all()
    assert a.sp[6:].tolist() == [7.0] * 4
    assert a.valid.all()  # SP does not limit validity
    assert a.role_valid["sp"].tolist() == [True] * 3 + [False] * 3 + [True] * 4


def test_set_point_before_its_first_sample_is_invalid():
    pv = frame(range(4), [0.0, 1, 2, 3])
    sp = frame([2], [9.0])
    a = align_loop({"pv": pv, "sp": sp}, sample_time=1.0)
    assert np.isnan(a.sp[:2]).all() and a.sp[2:].tolist() == [9.0, 9.0]


def test_mode_is_held_as_text():
    pv = frame(range(6), [0.0] * 6)
    mode = frame([0, 3], [None, None], status=["AUTO", "MAN"])
    a = align_loop({"pv": pv, "mode": mode}, sample_time=1.0)
    assert a.mode.tolist() == ["AUTO"] * 3 + ["MAN"] * 3
    assert a.to_polars()["mode"].to_list() == a.mode.tolist()


def test_window_start_and_end_extend_the_grid_without_extrapolating():
    pv = frame([10, 11, 12], [1.0, 2.0, 3.0])
    a = align_loop({"pv": pv}, sample_time=1.0, start=T0, end=T0 + dt.timedelta(seconds=15))
    assert a.n == 16
    assert a.valid.tolist() == [False] * 10 + [True] * 3 + [False] * 3


def test_unusable_inputs():
    with pytest.raises(ValueError, match="needs a 'pv' frame"):
        align_loop({"op": frame([0, 1], [0.0, 1.0])})
    with pytest.raises(ValueError, match="unknown roles"):
        align_loop({"pv": frame([0, 1], [0.0, 1.0]), "temp": frame([0], [1.0])})
    with pytest.raises(ValueError, match="too large"):
        align_loop({"pv": frame([0, 1e6], [0.0, 1.0])}, sample_time=0.01)
    with pytest.raises(ValueError, match="no time zone"):
        align_loop({"pv": frame([0, 1], [0.0, 1.0])}, start=dt.datetime(2024, 1, 1))


def test_empty_pv_gives_an_empty_grid():
    a = align_loop({"pv": frame([], [])})
    assert a.n == 0 and a.segments == () and np.isnan(a.valid_fraction)


def test_result_arrays_are_read_only():
    a = align_loop({"pv": frame([0, 1], [0.0, 1.0])})
    with pytest.raises(ValueError):
        a.pv[0] = 5.0


@given(st.lists(st.booleans(), max_size=60))
def test_contiguous_segments_rebuild_the_mask(mask):
    mask = np.array(mask, bool)
    rebuilt = np.zeros(mask.size, bool)
    segs = contiguous_segments(mask)
    for a, b in segs:
        assert a < b
        rebuilt[a:b] = True
    assert (rebuilt == mask).all()
    assert all(b1 < a2 for (_, b1), (a2, _) in zip(segs, segs[1:]))  # separated runs


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 4), st.one_of(st.none(), st.floats(-10, 10))),
                min_size=2, max_size=40))
def test_valid_points_lie_between_neighbouring_good_samples(steps):
    seconds = np.cumsum([s for s, _ in steps])
    values = [v for _, v in steps]
    a = align_loop({"pv": frame(seconds, values)}, sample_time=0.5, max_gap=3.0)
    tg = seconds - seconds[0]
    good = np.array([v is not None for v in values])
    vals = np.array([np.nan if v is None else v for v in values])
    for k in np.flatnonzero(a.valid):
        t = a.t[k]
        i = np.searchsorted(tg, t, side="right") - 1
        if tg[i] == t:
            assert good[i] and a.pv[k] == vals[i]
            continue
        # strictly between samples i and i+1: both good, close enough, value in between
        assert good[i] and good[i + 1] and tg[i + 1] - tg[i] <= 3.0
        lo, hi = sorted((vals[i], vals[i + 1]))
        assert lo - 1e-9 <= a.pv[k] <= hi + 1e-9


# ------------------------------------------------ gaps of compressed tags

def test_tag_max_gap_regular_and_compressed_by_hand():
    from valvediag.analysis.align import tag_max_gap

    regular = np.r_[np.arange(0, 100), np.arange(400, 500)] * 1_000_000  # one 301 s gap
    assert tag_max_gap(regular, np.zeros(regular.size)) == 5.0
    # compressed: intervals 1,1,1,10 repeated -> median 1, 25 % long, p99 = 10
    steps = np.tile([1, 1, 1, 10], 30)
    ts = np.r_[0, np.cumsum(steps)] * 1_000_000
    assert tag_max_gap(ts, np.zeros(ts.size)) == pytest.approx(50.0)
    # a bad sample removes the intervals around it from the statistics
    v = np.zeros(ts.size)
    v[1:] = np.nan
    assert np.isnan(tag_max_gap(ts, v)) and tag_max_gap(ts, v, sample_time=2.0) == 10.0
    # fewer than 20 intervals: the median rule
    assert tag_max_gap(ts[:10], np.zeros(10)) == 5.0


def _compressed_sine(seconds=7200, period=300.0, dev=0.02, seed=0):
    from valvediag.synth.plant import swinging_door

    rng = np.random.default_rng(seed)
    t = np.arange(float(seconds))
    x = np.sin(2 * np.pi * t / period) + rng.normal(0, 0.003, t.size)
    keep = swinging_door(x, dev)
    return t, x, keep


def test_compressed_pv_is_bridged_across_its_usual_spacing():
    t, x, keep = _compressed_sine()
    assert keep.mean() < 0.2                                 # heavily compressed
    pv = frame(t[keep], x[keep])
    op = frame(t, np.cos(2 * np.pi * t / 300.0))             # sampled every second
    a = align_loop({"pv": pv, "op": op}, sample_time=1.0)
    assert a.segments == ((0, a.n),)                         # nothing split
    assert a.max_gaps["op"] == 5.0 and a.max_gaps["pv"] > 5 * np.median(np.diff(t[keep]))
    # the interpolated PV follows the signal within twice the compression deviation
    assert np.max(np.abs(a.pv - x[: a.n])) < 2 * 0.02 + 0.02
    # the old fixed rule (5 x median spacing) cut it into pieces
    old = align_loop({"pv": pv, "op": op}, sample_time=1.0, max_gap=5.0)
    assert len(old.segments) > 20


def test_a_bad_state_or_an_unusually_long_gap_still_splits_a_compressed_tag():
    t, x, keep = _compressed_sine()
    idx = np.flatnonzero(keep)
    vals = x[idx].copy()
    vals[len(idx) // 2] = np.nan                             # an I/O Timeout row
    a = align_loop({"pv": frame(t[idx], vals)}, sample_time=1.0)
    assert len(a.segments) == 2
    # an outage far longer than the tag's own longest usual spacings
    cut = (t[idx] < 3000) | (t[idx] > 4200)
    b = align_loop({"pv": frame(t[idx][cut], x[idx][cut])}, sample_time=1.0)
    assert len(b.segments) == 2 and b.max_gap < 1200
    assert not b.valid[3100:4100].any()
