"""Tests for valvediag.synth.plant: the synthetic plant generator."""
from __future__ import annotations

import hashlib
import time

import numpy as np
import polars as pl
import pytest

from valvediag.analysis.oscillation import (CLOCK_WANDER, MIN_CROSSINGS, detect_oscillation,
                                            phase_wander)
from valvediag.synth import plant as sp
from valvediag.synth.plant import (
    DIGITAL_STATES,
    EXPORT_COLUMNS,
    LOOPS_COLUMNS,
    TRUTH_COLUMNS,
    TRUTH_VERDICTS,
    exception_deadband,
    swinging_door,
    synth_plant,
)

# A small plant: 16 loops, 3 h at 2 s. Periods are then 60-720 s (>= 30 samples,
# >= 15 cycles).
N_LOOPS, DAYS, TS, SEED = 16, 0.125, 2.0, 7


@pytest.fixture(scope="module")
def plant_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("plant")
    t0 = time.perf_counter()
    p = synth_plant(N_LOOPS, DAYS, TS, out, seed=SEED)
    return p, time.perf_counter() - t0


@pytest.fixture(scope="module")
def plant(plant_run):
    return plant_run[0]


@pytest.fixture(scope="module")
def samples(plant):
    """All long-CSV rows, parsed, with a numeric column ``x`` (null for states)."""
    frames = [pl.read_csv(f, schema_overrides={c: pl.String for c in EXPORT_COLUMNS})
              for f in plant.exports]
    df = pl.concat(frames)
    return df.with_columns(
        pl.col("timestamp").str.to_datetime("%Y-%m-%dT%H:%M:%S%:z", time_zone="UTC").alias("t"),
        pl.col("value").cast(pl.Float64, strict=False).alias("x"),
    )


def _series(samples, tag):
    d = samples.filter(pl.col("tag") == tag).sort("t")
    t = d["t"].dt.epoch("ms").to_numpy() / 1000.0
    return t, d["x"].to_numpy(), d


def _segment(t, x, ts):
    """The longest usable stretch of a tag, on a uniform grid.

    Breaks at digital states (which also mark gaps on compressed tags) and,
    on sampled tags, at holes of more than 60 s; linear interpolation inside.
    """
    sampled = np.median(np.diff(t)) <= ts
    brk = ~np.isfinite(x)
    if sampled:
        brk[1:] |= np.diff(t) > 60.0
    edges = np.r_[0, np.flatnonzero(brk), x.size]
    i = int(np.argmax(np.diff(edges)))
    a, b = edges[i], edges[i + 1]
    if not np.isfinite(x[a]):
        a += 1
    grid = np.arange(t[a], t[b - 1], ts)
    return grid, np.interp(grid, t[a:b], x[a:b])


def _deviation(samples, loop, ts):
    """PV minus the step-held SP on a uniform grid (removes operator set-point moves)."""
    t, x, _ = _series(samples, loop + ".PV")
    grid, y = _segment(t, x, ts)
    ts_sp, x_sp, _ = _series(samples, loop + ".SP")
    ok = np.isfinite(x_sp)
    k = np.searchsorted(ts_sp[ok], grid, side="right") - 1
    return grid, y - x_sp[ok][np.clip(k, 0, None)]


def _acf_period(y, ts):
    """Period from the first autocorrelation peak after the first zero crossing [s]."""
    y = y - y.mean()
    n = y.size
    f = np.fft.rfft(y, 2 * n)
    r = np.fft.irfft(f * np.conj(f))[:n]
    r /= r[0]
    z = np.flatnonzero(r < 0)
    if z.size == 0:
        return np.nan, 0.0
    k0 = z[0]
    k = k0 + int(np.argmax(r[k0:n // 2]))
    return k * ts, float(r[k])


# ---------------------------------------------------------------- contracts

def test_files_and_columns(plant):
    assert plant.loops_csv.exists() and plant.truth_csv.exists()
    assert len(plant.exports) >= 1 and all(f.exists() for f in plant.exports)
    loops = pl.read_csv(plant.loops_csv)
    truth = pl.read_csv(plant.truth_csv)
    assert tuple(loops.columns) == LOOPS_COLUMNS
    assert tuple(truth.columns) == TRUTH_COLUMNS
    assert loops.height == truth.height == N_LOOPS
    for f in plant.exports:
        head = pl.read_csv(f, n_rows=5, infer_schema=False)
        assert tuple(head.columns) == EXPORT_COLUMNS
    assert set(truth["truth_verdict"]) <= set(TRUTH_VERDICTS)
    assert set(truth["process_type"]) <= {"integrating", "self-regulating"}
    assert set(loops["process_type"]) <= {"integrating", "self-regulating", "unknown"}
    assert "unknown" in set(loops["process_type"])
    assert set(truth["valve"]) <= {"kano", "backlash", "linear"}


def test_timestamps_iso_with_offset(samples):
    ts = samples["timestamp"]
    assert ts.str.contains(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?[+-]\d\d:\d\d$").all()
    assert samples["t"].null_count() == 0
    assert samples["t"].min() == pl.Series(["2026-11-01T00:00:00+00:00"]).str.to_datetime(
        time_zone="UTC")[0]


def test_truth_and_loops_agree(plant, samples):
    loops, truth = plant.loops, plant.truth
    assert loops["loop"].to_list() == truth["loop"].to_list()
    assert loops["loop"].n_unique() == N_LOOPS
    # the types in loops.csv are right or 'unknown'
    j = loops.join(truth, on="loop", suffix="_truth")
    assert ((j["process_type"] == j["process_type_truth"]) | (j["process_type"] == "unknown")).all()
    # every exported tag is registered; every registered tag is exported, except missing PVs
    tags = set(samples["tag"].unique())
    registered = set(loops["pv_tag"]) | set(loops["op_tag"]) | set(loops["sp_tag"]) | \
        set(loops["mv_tag"].drop_nulls())
    assert tags <= registered
    missing = registered - tags
    bad = set(truth.filter(pl.col("truth_verdict") == "insufficient-data")["loop"])
    assert all(t.split(".")[0] in bad for t in missing)
    assert any(t.endswith(".PV") for t in missing), "the PV-missing case is absent"
    # loop names follow the tag prefix and the process type
    for row in j.iter_rows(named=True):
        assert row["pv_tag"] == row["loop"] + ".PV"
        if row["loop"].startswith(("FIC", "TIC")):
            assert row["process_type_truth"] == "self-regulating"


def test_every_category_present(plant):
    counts = dict(plant.truth.group_by("truth_verdict").len().iter_rows())
    assert set(counts) == set(TRUTH_VERDICTS)
    assert counts["no-oscillation"] >= 2  # healthy integrating and self-regulating


@pytest.mark.parametrize("n", [1, 3, 7, 20, 200])
def test_allocation_shares(n):
    cats = sp._allocate(n, np.random.default_rng(0))
    assert len(cats) == n
    got = {c: cats.count(c) for c in sp.CATEGORY_SHARES}
    if n >= 7:
        assert min(got.values()) >= 1
    if n == 200:
        assert got == {"stiction": 40, "backlash": 30, "linear-oscillation": 20, "healthy": 50,
                       "selfreg-stiction": 15, "selfreg-healthy": 15, "bad-data": 30}
    if n == 3:
        assert sorted(cats) == ["backlash", "healthy", "stiction"]


def test_span_and_units_consistent(plant, samples):
    truth = plant.truth
    usable = truth.filter(pl.col("truth_verdict") != "insufficient-data")["loop"]
    for row in plant.loops.filter(pl.col("loop").is_in(usable.implode())).iter_rows(named=True):
        x = samples.filter(pl.col("tag") == row["pv_tag"])["x"].drop_nulls()
        assert x.len() > 0
        assert x.max() - x.min() < 0.3 * row["span"], row["loop"]
        assert x.min() >= 0.0
        if row["unit"] == "%":
            assert 0 < x.min() and x.max() < 100
        op = samples.filter(pl.col("tag") == row["op_tag"])["x"].drop_nulls()
        assert 0 < op.min() and op.max() < 100
    amp = truth.filter(pl.col("amplitude").is_not_null()).join(plant.loops, on="loop")
    rel = amp["amplitude"] / amp["span"]
    assert ((rel > 0.002) & (rel < 0.1)).all()


# ---------------------------------------------------------------- artefacts

def test_artefacts_present(plant, samples):
    states = samples.filter(pl.col("x").is_null())["value"]
    assert states.len() > 0
    assert set(states.unique()) <= set(DIGITAL_STATES)
    assert "Shutdown" in set(states)
    assert {"Questionable", "Substituted"} <= set(samples["status"].drop_nulls())
    # gaps and compression: irregular intervals on some tags
    dt = (samples.sort("tag", "t").group_by("tag", maintain_order=True)
          .agg(pl.col("t").diff().dt.total_seconds().alias("dt"))
          .explode("dt").drop_nulls())
    per_tag = dt.group_by("tag").agg(pl.col("dt").max().alias("max"),
                                     (pl.col("dt") > TS).mean().alias("irregular"))
    assert (per_tag["max"] >= 120).any(), "no gap of 2 minutes or more"
    assert (per_tag["irregular"] > 0.3).any(), "no compressed tag"
    assert (per_tag["irregular"] < 0.05).any(), "no uncompressed tag"
    # set points are stored by exception only
    sp_rows = samples.filter(pl.col("tag").str.ends_with(".SP")).group_by("tag").len()
    assert (sp_rows["len"] < 0.05 * DAYS * 86400 / TS).all()


def test_bad_data_loops_are_bad(plant, samples):
    bad = plant.truth.filter(pl.col("truth_verdict") == "insufficient-data")
    assert bad.height >= 1
    usable_rows = []
    for row in bad.join(plant.loops, on="loop").iter_rows(named=True):
        x = samples.filter(pl.col("tag") == row["pv_tag"])["x"]
        usable_rows.append((x.len(), x.drop_nulls().n_unique()))
        # missing, all states, frozen or far too short
        assert x.len() == 0 or x.drop_nulls().len() == 0 or x.drop_nulls().n_unique() == 1 \
            or x.len() < 0.05 * DAYS * 86400 / TS, row["loop"]


def test_artefacts_leave_usable_loops_usable(plant, samples):
    usable = plant.truth.filter(pl.col("truth_verdict") != "insufficient-data").join(plant.loops, on="loop")
    n_total = DAYS * 86400 / TS
    for row in usable.iter_rows(named=True):
        d = samples.filter(pl.col("tag") == row["pv_tag"])
        t = d["t"].dt.epoch("s").to_numpy()
        covered = (t.max() - t.min()) / (DAYS * 86400)
        assert covered > 0.95, row["loop"]
        assert d["x"].null_count() < 0.02 * n_total, row["loop"]


# ---------------------------------------------------------------- truth vs data

def test_stiction_loop_oscillates_at_stated_period(plant, samples):
    rows = plant.truth.filter(pl.col("truth_verdict").is_in(["stiction", "backlash",
                                                             "linear-oscillation"]))
    assert rows.height >= 4
    for row in rows.iter_rows(named=True):
        grid, y = _deviation(samples, row["loop"], TS)
        P, r = _acf_period(y, TS)
        assert r > 0.5, (row["loop"], r)
        assert P == pytest.approx(row["period_s"], rel=0.1), row["loop"]
        assert row["period_s"] >= 20 * TS
        assert DAYS * 86400 / row["period_s"] >= 15
        # amplitude: half the 2nd-98th percentile range of the data vs the truth
        lo, hi = np.nanpercentile(y, [2, 98])
        assert 0.5 * (hi - lo) == pytest.approx(row["amplitude"], rel=0.35), row["loop"]


def test_a_valve_faults_limit_cycle_wanders_with_the_noise_its_loop_answers(plant, samples):
    """The noise goes round a faulty loop, as on a plant: the OP answers it and
    the limit cycle's phase random-walks. Noise added to the record afterwards
    would leave a cycle that keeps a clock's time, as a load from outside does."""
    rows = plant.truth.filter(pl.col("truth_verdict").is_in(["stiction", "backlash"]))
    read = 0
    for row in rows.iter_rows(named=True):
        t, x, _ = _series(samples, row["loop"] + ".PV")
        t_op, x_op, _ = _series(samples, row["loop"] + ".OP")
        if np.mean(np.diff(t) > TS) > 0.05 or np.mean(np.diff(t_op) > TS) > 0.05:
            continue  # compressed
        grid, y = _segment(t, x, TS)
        ok = np.isfinite(x_op)
        u = np.interp(grid, t_op[ok], x_op[ok])
        pw = phase_wander(y, detect_oscillation(y, TS), u)
        if pw.crossings < MIN_CROSSINGS:
            continue
        assert not pw.keeps_clock and pw.wander > 2 * CLOCK_WANDER, (row["loop"], pw.reason)
        read += 1
    assert read >= 1


def test_healthy_loop_does_not_oscillate(plant, samples):
    rows = plant.truth.filter(pl.col("truth_verdict") == "no-oscillation")
    assert rows.height >= 2
    for row in rows.iter_rows(named=True):
        assert row["period_s"] is None and row["amplitude"] is None
        grid, y = _deviation(samples, row["loop"], TS)
        P, r = _acf_period(y, TS)
        assert r < 0.3, (row["loop"], P, r)


def test_noise_is_as_stated(plant, samples):
    """PV noise: sigma of the first difference / sqrt(2) on sampled oscillating loops."""
    rows = plant.truth.filter(pl.col("amplitude").is_not_null()).join(plant.loops, on="loop")
    checked = 0
    for row in rows.iter_rows(named=True):
        t, x, _ = _series(samples, row["pv_tag"])
        if np.mean(np.diff(t) > TS) > 0.05:
            continue  # compressed
        dx = np.diff(x[np.isfinite(x)])
        # the wave itself adds slope; the noise floor is the smallest robust estimate
        est = 1.4826 * np.median(np.abs(dx - np.median(dx))) / np.sqrt(2)
        want = row["noise_pct"] / 100 * row["amplitude"]
        assert est >= 0.5 * want, row["loop"]
        checked += 1
    assert checked >= 1


# ---------------------------------------------------------------- behaviour

def test_deterministic(plant, tmp_path):
    again = synth_plant(N_LOOPS, DAYS, TS, tmp_path / "again", seed=SEED)
    assert again.truth.equals(plant.truth)
    assert again.loops.equals(plant.loops)
    digest = lambda fs: [hashlib.sha256(f.read_bytes()).hexdigest() for f in fs]
    assert [f.name for f in again.exports] == [f.name for f in plant.exports]
    assert digest(again.exports) == digest(plant.exports)
    other = synth_plant(N_LOOPS, DAYS, TS, tmp_path / "other", seed=SEED + 1)
    assert not other.truth.equals(plant.truth)


def test_runtime_small(plant_run):
    # includes loading the compiled kernels from numba's cache
    assert plant_run[1] < 20.0


def test_formats_and_timezone(tmp_path):
    (tmp_path / "exports").mkdir()
    (tmp_path / "exports" / "long_20250101_g07.csv").write_text("stale")
    (tmp_path / "exports" / "README.txt").write_text("keep me")
    calls = []
    p = synth_plant(9, 0.35, 10.0, tmp_path, seed=3, formats=("long-csv", "wide-csv", "parquet"),
                    timezone="America/Chicago", progress=lambda d, t: calls.append((d, t)))
    assert not (tmp_path / "exports" / "long_20250101_g07.csv").exists()
    assert (tmp_path / "exports" / "README.txt").read_text() == "keep me"
    assert sorted((tmp_path / "exports").glob("*_g*.*")) == sorted(p.exports)
    kinds = {f.suffix + ("-wide" if f.name.startswith("wide") else "") for f in p.exports}
    assert kinds == {".csv", ".csv-wide", ".parquet"}
    assert calls and calls[-1][0] == calls[-1][1]
    tags = set()
    for f in p.exports:
        if f.suffix == ".parquet":
            d = pl.read_parquet(f)
            assert tuple(d.columns) == EXPORT_COLUMNS
            assert d.schema["value"] == pl.String
            assert str(d.schema["timestamp"].time_zone) == "UTC"
            tags |= set(d["tag"])
        elif f.name.startswith("wide"):
            d = pl.read_csv(f, infer_schema=False)
            assert d.columns[0] == "timestamp"
            tags |= set(d.columns[1:])
            # US daylight saving ends at 07:00 UTC on 2026-11-01: both offsets appear
            offs = set(d["timestamp"].str.slice(-6))
            assert offs == {"-05:00", "-06:00"}
        else:
            d = pl.read_csv(f, infer_schema=False)
            tags |= set(d["tag"])
    # each loop's tags are in exactly one format
    registered = set(p.loops["op_tag"])
    assert registered <= tags


def test_project_readers_accept_the_plant(plant):
    """The project's own ingest and registry read the plant without complaint."""
    ingest = pytest.importorskip("valvediag.io.exports")
    registry = pytest.importorskip("valvediag.io.registry")
    for f in plant.exports:
        samples, quarantine = ingest.read_export(f)
        assert quarantine.height == 0, quarantine.head(3)
        assert samples.filter(pl.col("value").is_null()).height > 0  # states kept as bad samples
    specs, issues = registry.read_loops_csv(plant.loops_csv)
    assert len(specs) == N_LOOPS and issues == []


def test_public_functions_document_their_parameters():
    import inspect

    for name in sp.__all__:
        obj = getattr(sp, name)
        if inspect.isfunction(obj):
            doc = inspect.getdoc(obj) or ""
            lost = [p for p in inspect.signature(obj).parameters if p not in doc]
            assert doc and not lost, (name, lost)


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="n_loops"):
        synth_plant(0, 1, 1, tmp_path)
    with pytest.raises(ValueError, match="format"):
        synth_plant(3, 0.1, 1, tmp_path, formats=("xlsx",))
    with pytest.raises(ValueError, match="too short"):
        synth_plant(3, 0.001, 1, tmp_path)
    with pytest.raises(ValueError, match="sample_time"):
        synth_plant(3, 0.1, 0, tmp_path)


# ---------------------------------------------------------------- compression

def test_swinging_door_line_and_error_bound():
    x = np.linspace(0.0, 10.0, 101)
    keep = swinging_door(x, 0.01)
    assert np.flatnonzero(keep).tolist() == [0, 100]
    rng = np.random.default_rng(0)
    w = np.cumsum(rng.standard_normal(5000))
    dev = 0.5
    keep = swinging_door(w, dev)
    k = np.flatnonzero(keep)
    assert 10 < k.size < 0.5 * w.size
    rebuilt = np.interp(np.arange(w.size), k, w[k])
    err = np.abs(rebuilt - w)
    assert err.max() <= 2 * dev + 1e-9     # inside the doors' triangle
    assert np.mean(err <= dev) > 0.7
    # the maximum interval forces points
    keep = swinging_door(x, 0.01, max_interval=10)
    assert np.diff(np.flatnonzero(keep)).max() <= 10


def test_exception_deadband():
    x = np.r_[np.zeros(10), np.ones(10)]
    keep = exception_deadband(x, 0.5)
    assert np.flatnonzero(keep).tolist() == [0, 9, 10]   # the value before the step too
    keep = exception_deadband(np.zeros(100), 0.5, max_interval=30)
    assert np.flatnonzero(keep).tolist() == [0, 30, 60, 90]


def test_a_sticky_levels_labelled_slips_are_the_ones_its_record_can_show():
    from valvediag.synth.cases import _visible_slope_slips, draw_loop

    # a valve resting 600 samples between jumps of 2 %: on a level of 200 s
    # the slope steps by 0.01 PV unit/s, against slope errors of about 1e-5
    mv = np.repeat(40.0 + 2.0 * np.arange(6), 600)
    assert _visible_slope_slips(mv, 2.0, 1.0 / 200.0, 0.02, 1.0) == 5
    # the same slips under noise a thousand times larger are not labelled
    assert _visible_slope_slips(mv, 2.0, 1.0 / 200.0, 20.0, 1.0) == 0
    # jumps 30 samples apart show only where the stretches are long enough
    mv = np.repeat(40.0 + 2.0 * np.arange(6), 30)
    assert _visible_slope_slips(mv, 2.0, 1.0 / 200.0, 1.0, 1.0) == 0
    loop = draw_loop("level-stiction-events", np.random.default_rng([1, 3, 0]))
    assert loop.params["slips"] >= 3 and loop.truth == "stiction"


def test_a_sticky_flows_slips_are_counted_once_however_many_samples_they_span():
    from valvediag.synth.cases import _events, draw_loop

    # one slip through a 3 s lag, sampled every second, moves the PV by more
    # than six noise sigma on four samples running: one slip, not four
    step = 2.0 * (1 - np.exp(-np.arange(100) / 3.0))
    pv = np.r_[np.full(100, 50.0), 50.0 + step]
    assert np.count_nonzero(np.abs(np.diff(pv)) > 6 * 0.01 * np.sqrt(2)) >= 4
    assert _events(pv, 0.01) == 1
    # three slips with rests between them are three
    assert _events(np.r_[pv, 52.0 - step, 50.0 + step], 0.01) == 3
    assert _events(np.full(300, 50.0), 0.01) == 0
    # the benchmark's sticky flows without a cycle show three slips at least
    loop = draw_loop("flow-stiction-events", np.random.default_rng([1, 5, 0]))
    assert loop.params["slips"] >= 3 and loop.truth == "stiction"


def test_a_sawtooths_level_stays_within_its_span():
    from valvediag.synth.cases import draw_loop

    # a valve closed against a net inflow it cannot hold lets the level run
    # away (study seed 13 drew one to 870 % of span, its OP pinned at 0):
    # such draws are redrawn
    for i in (2, 3):
        loop = draw_loop("level-stiction-sawtooth", np.random.default_rng([13, 2, i]))
        assert 0.0 <= loop.pv.min() and loop.pv.max() <= 100.0
        assert np.ptp(np.percentile(loop.op, [1, 99])) > 0.5


def test_cycle_stats_reads_a_noisy_square_waves_period():
    from valvediag.synth.plant import cycle_stats

    rng = np.random.default_rng(4)
    t = np.arange(6000) * 2.0
    x = np.sign(np.sin(2 * np.pi * t / 300.0)) + 0.1 * rng.standard_normal(t.size)
    period, amp, cycles, cv = cycle_stats(x, 2.0)
    assert period == pytest.approx(300.0, rel=0.02)
    assert 1.0 < amp < 1.0 + 4 * 0.1        # half the swing, peaks of the noise included
    # 40 periods from a rising start: 39 upward crossings, 38 whole cycles between them
    assert cycles == 38 and cv < 0.05
    # white noise alone crosses at random: no regular period
    assert cycle_stats(rng.standard_normal(6000), 2.0)[3] > 1 / 3


def test_the_benchmark_generator_does_not_count_cycles_with_the_scans_detector(monkeypatch):
    """Which draws a class accepts must not move with the method under test."""
    import valvediag.analysis.oscillation as osc
    from valvediag.synth.cases import CLASSES, draw_loop

    def refuse(*a, **k):
        raise AssertionError("the generator called the scan's oscillation detector")

    monkeypatch.setattr(osc, "detect_oscillation", refuse)
    for ci, klass in enumerate(CLASSES):
        loop = draw_loop(klass, np.random.default_rng([7, ci, 0]))
        assert loop.klass == klass


def test_a_flow_drawn_as_a_cascade_inner_loop_is_the_same_draw_with_a_wandering_set_point():
    from valvediag.synth.cases import CASCADE_WANDER, CLASSES, draw_loop

    for klass in ("flow-stiction-events", "flow-healthy", "level-stiction-cycle"):
        key = [10, list(CLASSES).index(klass), 0]
        plain = draw_loop(klass, np.random.default_rng(key))
        inner = draw_loop(klass, np.random.default_rng(key), cascade=True)
        assert inner.params["kc"] == plain.params["kc"]
        assert inner.params["tau_s"] == plain.params["tau_s"]
        wander = inner.sp - plain.sp
        if klass.startswith("flow"):
            # three sines of 0.1-0.5 each, over 20-120 minutes: smooth, and
            # no more than the three amplitudes' sum either way of the start
            assert inner.params["cascade"] and np.ptp(wander) > 0.1
            assert np.max(np.abs(wander - wander[0])) <= 6 * CASCADE_WANDER[1]
            assert np.max(np.abs(np.diff(wander))) < 0.01 * inner.sample_time
        else:
            assert "cascade" not in inner.params and np.array_equal(inner.sp, plain.sp)


def test_a_level_drawn_with_a_longer_lag_is_the_same_draw_with_its_lag_scaled():
    from valvediag.synth.cases import benchmark_rng, draw_loop

    for klass in ("level-backlash-cycle", "flow-stiction-cycle"):
        for index in range(3):
            plain = draw_loop(klass, benchmark_rng(klass, 10, index))
            slow = draw_loop(klass, benchmark_rng(klass, 10, index), level_lag=0.3)
            assert slow.params["tau_s"] == plain.params["tau_s"]
            if klass.startswith("level"):
                # drawn up to 0.3 of the time constant where the sets draw up to 0.1
                assert slow.params["lag_s"] == pytest.approx(3.0 * plain.params["lag_s"])
                assert slow.params["lag_s"] <= 0.3 * slow.params["tau_s"]
            else:
                assert np.array_equal(slow.pv, plain.pv)


def test_the_temperature_classes_draw_slow_self_regulating_loops_and_leave_the_others_alone():
    """Time constants of 60-600 s, dead times up to 0.3 of them; the loads of
    the disturbed class 3-15 times the time constant and dead time a period.
    Appended last, the two classes leave every other class's draws as they
    were: each loop's stream is keyed by its class's index."""
    from valvediag.synth.cases import CLASSES, draw_loop

    names = list(CLASSES)
    assert names[-2:] == ["temperature-stiction-cycle", "temperature-linear-disturbance"]
    assert names.index("level-linear-slow-load") == 13
    for klass in names[-2:]:
        for i in range(3):
            loop = draw_loop(klass, np.random.default_rng([5, names.index(klass), i]))
            p = loop.params
            assert loop.process_type == "self-regulating"
            assert 60.0 <= p["tau_s"] <= 600.0 and p["dead_time_s"] <= 0.3 * p["tau_s"]
            assert loop.truth == ("stiction" if "stiction" in klass else "linear-oscillation")
            if "disturbance" in klass:
                slow = p["disturbance_period_s"] / (p["tau_s"] + p["dead_time_s"])
                assert 3.0 <= slow <= 15.0 and p["valve"] == "linear"
            else:
                assert p["valve"] == "kano" and 0.2 * p["S"] <= p["J"] <= p["S"]
