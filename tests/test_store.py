"""Tests of valvediag.store against real DuckDB files."""
from __future__ import annotations

import datetime as dt
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from valvediag.io.registry import LoopSpec
from valvediag.store.database import SQL_DIR, Store, StoreLockedError, load_sql
from valvediag.store.ingest import ingest_exports

DATA = Path(__file__).parent / "data" / "ingest"
UTC = dt.timezone.utc
T0 = dt.datetime(2024, 3, 1, tzinfo=UTC)


@pytest.fixture
def store(tmp_path):
    with Store(tmp_path / "s.duckdb") as s:
        ingest_exports(s, [DATA / "pi_long.csv"])
        yield s


LOOP = LoopSpec("FIC101", pv_tag="FIC101.PV", op_tag="FIC101.OP", sp_tag="FIC101.SP",
                mode_tag="FIC101.MODE")


# --- schema and plumbing ------------------------------------------------------
def test_schema_has_every_table_and_survives_reopen(tmp_path):
    path = tmp_path / "s.duckdb"
    with Store(path) as s:
        ingest_exports(s, [DATA / "wide.csv"])
        before = s.counts()
    with Store(path, read_only=True) as s:
        assert s.counts() == before
    assert set(before) == {"samples", "quarantine", "ingested_files", "loops", "runs",
                           "episodes", "verdicts"}


def test_every_named_query_file_is_loadable():
    names = sorted(p.name[:-4] for p in SQL_DIR.iterdir() if p.name.endswith(".sql"))
    assert "schema" in names and "new_faults_of_run" in names
    for name in names:
        assert load_sql(name).strip()
    with pytest.raises(KeyError, match="no named query 'nope'"):
        load_sql("nope")


def test_second_process_cannot_open_a_held_store(tmp_path):
    path = tmp_path / "s.duckdb"
    Store(path).close()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, duckdb; c = duckdb.connect(sys.argv[1]); "
                               "print('ready', flush=True); time.sleep(30)", str(path)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "ready"
        with pytest.raises(StoreLockedError, match="open in another process") as err:
            Store(path)
        assert "\n" not in str(err.value)
    finally:
        holder.kill()
        holder.wait()


# --- reading samples ------------------------------------------------------------
def test_tags_and_latest_timestamps(store):
    assert store.tags() == ["FIC101.MODE", "FIC101.OP", "FIC101.PV"]
    latest = {r["tag"]: r for r in store.latest_timestamps().iter_rows(named=True)}
    pv = latest["FIC101.PV"]
    assert pv["last_ts"] == T0 + dt.timedelta(seconds=4)        # a Bad Input sample
    assert pv["last_good_ts"] == T0 + dt.timedelta(seconds=3)
    assert pv["rows"] == 5


def test_fetch_tag_window_is_half_open_and_utc(store):
    frame = store.fetch_tag("FIC101.PV", T0 + dt.timedelta(seconds=1),
                            T0 + dt.timedelta(seconds=3))
    assert frame.schema == pl.Schema({"ts": pl.Datetime("us", "UTC"), "value": pl.Float64,
                                      "status": pl.String})
    assert frame["ts"].to_list() == [T0 + dt.timedelta(seconds=1), T0 + dt.timedelta(seconds=2)]
    assert frame["value"].to_list() == [50.5, None]
    assert frame["status"].to_list() == [None, "I/O Timeout"]


def test_fetch_tag_with_previous_sample_for_held_signals(store):
    start = T0 + dt.timedelta(seconds=2)
    plain = store.fetch_tag("FIC101.MODE", start)
    held = store.fetch_tag("FIC101.MODE", start, include_previous=True)
    assert plain["status"].to_list() == ["MAN"]
    assert held["status"].to_list() == ["AUTO", "MAN"]
    assert held["ts"][0] == T0


def test_fetch_tag_refuses_naive_datetimes(store):
    with pytest.raises(ValueError, match="has no time zone"):
        store.fetch_tag("FIC101.PV", dt.datetime(2024, 3, 1))


def test_fetch_loop_and_missing_tags(store):
    frames = store.fetch_loop(LOOP, T0 + dt.timedelta(seconds=1))
    assert set(frames) == {"pv", "op", "sp", "mode"}
    assert frames["sp"].is_empty()
    assert frames["mode"].height == 2  # AUTO before the window is included
    assert frames["pv"].height == 4
    assert store.missing_tags(LOOP) == {"sp": "FIC101.SP"}
    # in a window after all data every tag is missing
    late = T0 + dt.timedelta(days=1)
    assert store.missing_tags(LOOP, late) == LOOP.tags


# --- registry -------------------------------------------------------------------
def test_loops_round_trip(store):
    loops = [LOOP, LoopSpec("TIC300", op_tag="TIC300.OP", span=math.nan, criticality=0.5,
                            issues=("no PV tag in loops.csv",))]
    assert store.replace_loops(loops) == 2
    back = store.loops()
    assert back[0] == LOOP
    assert back[1].issues == ("no PV tag in loops.csv",) and math.isnan(back[1].span)
    store.replace_loops(loops[:1])
    assert [l.loop for l in store.loops()] == ["FIC101"]


def test_a_store_made_before_the_sampling_column_reads_its_loops_as_point_values(tmp_path):
    db = tmp_path / "old.duckdb"
    averaged = LoopSpec("LIC200", pv_tag="LIC200.PV", op_tag="LIC200.OP", sampling="average")
    with Store(db) as store:
        store.replace_loops([LOOP, averaged])
        assert [l.sampling for l in store.loops()] == ["point", "average"]
        store.con.execute("ALTER TABLE loops DROP COLUMN sampling")   # as an older store
    with Store(db, read_only=True) as store:                         # not brought up to date
        assert [(l.loop, l.sampling) for l in store.loops()] == [("FIC101", "point"),
                                                                 ("LIC200", "point")]
    with Store(db) as store:                                          # brought up to date
        assert [l.sampling for l in store.loops()] == ["point", "point"]
        store.replace_loops([averaged])
        assert store.loops() == [averaged]


# --- runs and results -------------------------------------------------------------
def _verdict(loop, verdict, rank=1, **kw):
    return {"loop": loop, "verdict": verdict, "rank": rank, "confidence": 0.8, **kw}


def _complete_run(store, verdicts, status="complete"):
    run_id = store.start_run(window_start=T0, window_end=T0 + dt.timedelta(days=1),
                             exports=["a.csv", "b.csv"], params={"bi_limits": [0.3, 0.7]})
    store.write_results(run_id, verdicts=verdicts)
    store.finish_run(run_id, status)
    return run_id


def test_run_lifecycle_and_results(store):
    run_id = store.start_run(window_start=T0, params={"x": np.float64(1.5)})
    assert store.run(run_id)["status"] == "running"
    episodes = pl.DataFrame({"loop": ["FIC101", "FIC101"],
                             "start_ts": [T0, T0 + dt.timedelta(hours=1)],
                             "end_ts": [T0 + dt.timedelta(minutes=30), T0 + dt.timedelta(hours=2)],
                             "period_s": [60.0, 62.0], "verdict": ["stiction", "stiction"]})
    verdicts = [_verdict("FIC101", "stiction", bi=0.12,
                         evidence={"cycles": np.int64(12), "angle": float("nan")},
                         quality={"bad_pct": 0.0, "issues": ("gap",)})]
    store.write_results(run_id, episodes=episodes, verdicts=verdicts)
    store.write_results(run_id, episodes=episodes, verdicts=verdicts)  # retry is idempotent
    store.finish_run(run_id)
    run = store.run(run_id)
    assert run["status"] == "complete" and run["finished_at"] >= run["started_at"]
    assert json.loads(run["params"]) == {"x": 1.5}
    assert store.episodes(run_id).height == 2
    v = store.verdicts().row(0, named=True)
    assert v["run_id"] == run_id and v["bi"] == 0.12
    assert json.loads(v["evidence"]) == {"cycles": 12, "angle": None}
    assert json.loads(v["quality"])["issues"] == ["gap"]


def test_results_of_a_finished_run_cannot_change(store):
    run_id = _complete_run(store, [_verdict("FIC101", "stiction")])
    with pytest.raises(ValueError, match="is complete"):
        store.write_results(run_id, verdicts=[_verdict("FIC101", "backlash")])
    with pytest.raises(KeyError, match="no run 'ghost'"):
        store.finish_run("ghost")


def test_verdicts_as_mappings_may_omit_different_keys(store):
    run_id = store.start_run()
    rows = [{"loop": f"L{i}", "verdict": "no-oscillation"} for i in range(150)]
    rows.append({"loop": "LAST", "verdict": "stiction", "bi": 0.2, "reason": "late key"})
    store.write_results(run_id, verdicts=rows)
    last = store.verdicts(run_id).filter(pl.col("loop") == "LAST").row(0, named=True)
    assert (last["bi"], last["reason"]) == (0.2, "late key")


@pytest.mark.parametrize("bad, match", [
    ([{"loop": "A", "verdict": "sticky"}], "unknown verdict values"),
    ([{"loop": "A", "verdict": "stiction", "colour": "red"}], r"unknown columns \['colour'\]"),
    ([_verdict("A", "stiction"), _verdict("A", "backlash")], "more than one verdict"),
])
def test_bad_verdicts_are_refused_and_nothing_is_written(store, bad, match):
    run_id = store.start_run()
    with pytest.raises(ValueError, match=match):
        store.write_results(run_id, verdicts=bad)
    assert store.counts()["verdicts"] == 0


def test_verdict_history_counts_only_complete_runs(store):
    a = _complete_run(store, [_verdict("FIC101", "no-oscillation")])
    time.sleep(0.002)
    _complete_run(store, [_verdict("FIC101", "backlash")], status="failed")
    time.sleep(0.002)
    c = _complete_run(store, [_verdict("FIC101", "stiction")])
    history = store.verdict_history("FIC101")
    assert history["run_id"].to_list() == [a, c]
    assert history["verdict"].to_list() == ["no-oscillation", "stiction"]


def test_new_since_last_run(store):
    _complete_run(store, [_verdict("L1", "no-oscillation"), _verdict("L2", "stiction"),
                          _verdict("L3", "backlash"), _verdict("L4", "undecided")])
    time.sleep(0.002)
    _complete_run(store, [_verdict("L1", "backlash")], status="failed")  # does not count
    time.sleep(0.002)
    latest = _complete_run(store, [
        _verdict("L1", "stiction", rank=2),            # new fault
        _verdict("L2", "stiction", rank=1),            # still a fault: not new
        _verdict("L3", "linear-oscillation", rank=3),  # fault before, fault now: not new
        _verdict("L4", "backlash", rank=4),            # undecided -> backlash: new
        _verdict("L5", "linear-oscillation", rank=5),  # loop absent before: new
        _verdict("L6", "no-oscillation", rank=6),      # not a fault
    ])
    time.sleep(0.002)
    store.start_run()  # a running scan does not count either
    new = store.new_since_last_run()
    assert new["loop"].to_list() == ["L1", "L4", "L5"]
    assert new["previous_verdict"].to_list() == ["no-oscillation", "undecided", None]
    assert set(new["run_id"]) == {latest}


def test_first_complete_run_reports_all_faults_as_new(store):
    _complete_run(store, [_verdict("L1", "stiction"), _verdict("L2", "no-oscillation")])
    assert store.new_since_last_run()["loop"].to_list() == ["L1"]


def _frame(rows):
    return pl.DataFrame(rows, schema={
        "tag": pl.String, "ts": pl.Datetime("us", "UTC"), "value": pl.Float64,
        "status": pl.String, "source_file": pl.String, "source_line": pl.Int64}, orient="row")


def test_insert_new_samples_stores_rows_sorted_with_their_own_files(tmp_path):
    store = Store(tmp_path / "empty.duckdb")
    """An unsorted frame of two files: stored sorted by (tag, ts) (zone maps), each row
    with its own file and line; a second insert of the same keys adds nothing."""
    t0 = dt.datetime(2024, 1, 1, tzinfo=dt.timezone.utc)
    rows = [("B", t0 + dt.timedelta(seconds=s), float(s), None, "b.csv", 10 + s)
            for s in (3, 1, 2)]
    rows += [("A", t0 + dt.timedelta(seconds=s), float(s), "Questionable", "a.csv", s)
             for s in (2, 0)]
    assert store.insert_new_samples(_frame(rows)) == 5
    stored = store.con.execute("SELECT tag, ts, source_file, source_line FROM samples "
                               "ORDER BY rowid").fetchall()
    assert [(r[0], r[1]) for r in stored] == sorted((r[0], r[1]) for r in rows)
    assert {(r[0], r[1]): (r[2], r[3]) for r in stored} == {
        (r[0], r[1]): (r[4], r[5]) for r in rows}
    assert store.insert_new_samples(_frame(rows), may_overlap=True) == 0
    assert store.insert_new_samples(_frame(rows)) == 0
    assert store.counts()["samples"] == 5


def test_insert_of_one_file_binds_the_file_and_keeps_rows(tmp_path):
    store = Store(tmp_path / "empty.duckdb")
    t0 = dt.datetime(2024, 1, 1, tzinfo=dt.timezone.utc)
    rows = [("A", t0 + dt.timedelta(seconds=s), float(s), None, "/x/one.parquet", s + 2)
            for s in range(5)]
    assert not store.may_overlap(_frame(rows))
    assert store.insert_new_samples(_frame(rows), may_overlap=False) == 5
    assert store.may_overlap(_frame(rows[2:3]))
    frame = store.fetch_tag("A")
    assert frame["value"].to_list() == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert store.con.execute("SELECT DISTINCT source_file FROM samples").fetchall() == [
        ("/x/one.parquet",)]


def test_insert_refuses_a_row_without_a_file(store):
    t0 = dt.datetime(2024, 1, 1, tzinfo=dt.timezone.utc)
    with pytest.raises(Exception, match="(?i)not null|constraint"):
        store.insert_new_samples(_frame([("A", t0, 1.0, None, None, 2)]))


def test_sample_bounds_follow_inserts_and_are_rebuilt_for_an_older_store(tmp_path):
    """sample_bounds (per-tag stored time range) decides most overlap checks without reading
    samples; a store made before it existed gets it filled on open."""
    t0 = dt.datetime(2024, 1, 1, tzinfo=dt.timezone.utc)
    sec = lambda s: t0 + dt.timedelta(seconds=s)  # noqa: E731
    db = tmp_path / "b.duckdb"
    with Store(db) as store:
        store.insert_new_samples(_frame([("A", sec(s), 1.0, None, "f", s) for s in (0, 10)]))
        store.insert_new_samples(_frame([("A", sec(20), 1.0, None, "g", 2),
                                         ("B", sec(5), 1.0, None, "g", 3)]))
        bounds = store.con.execute("SELECT tag, ts_min, ts_max FROM sample_bounds "
                                   "ORDER BY tag").fetchall()
        assert bounds == [("A", sec(0), sec(20)), ("B", sec(5), sec(5))]
        # inside the stored range but on no stored sample: the exact check still says no
        assert not store.may_overlap(_frame([("A", sec(5), 2.0, None, "h", 2)]))
        assert store.may_overlap(_frame([("A", sec(10), 2.0, None, "h", 2)]))
        assert not store.may_overlap(_frame([("A", sec(21), 2.0, None, "h", 2)]))
        assert not store.may_overlap(_frame([("C", sec(10), 2.0, None, "h", 2)]))
        store.con.execute("DROP TABLE sample_bounds")  # as a store made before it existed
    with Store(db) as store:
        assert store.con.execute("SELECT tag, ts_min, ts_max FROM sample_bounds "
                                 "ORDER BY tag").fetchall() == bounds
        assert store.may_overlap(_frame([("B", sec(5), 2.0, None, "h", 2)]))
        assert store.insert_new_samples(_frame([("B", sec(5), 2.0, None, "h", 2)])) == 0


def test_a_failed_insert_leaves_sample_bounds_as_they_were(tmp_path):
    t0 = dt.datetime(2024, 1, 1, tzinfo=dt.timezone.utc)
    with Store(tmp_path / "r.duckdb") as store:
        with pytest.raises(Exception), store.transaction():
            store.insert_new_samples(_frame([("A", t0, 1.0, None, "f", 2)]))
            raise RuntimeError("rolled back")
        assert store.con.execute("SELECT count(*) FROM sample_bounds").fetchall() == [(0,)]
        assert store.counts()["samples"] == 0
