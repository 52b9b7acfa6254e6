"""Tests of valvediag.store.ingest: readers, bad input, and ingest into a real DuckDB file."""
from __future__ import annotations

import datetime as dt
import shutil
from pathlib import Path

import hypothesis.strategies as st
import numpy as np
import polars as pl
import pytest
from hypothesis import HealthCheck, given, settings

from valvediag.io.exports import (
    QUARANTINE_SCHEMA,
    SAMPLE_SCHEMA,
    ExportError,
    expand_paths,
    iter_export,
    parse_export,
    read_export,
)
from valvediag.store.database import Store
from valvediag.store.ingest import _write_parsed, ingest_exports

DATA = Path(__file__).parent / "data" / "ingest"
UTC = dt.timezone.utc


def utc(*args) -> dt.datetime:
    return dt.datetime(*args, tzinfo=UTC)


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def by_key(samples: pl.DataFrame) -> dict:
    return {(r["tag"], r["ts"]): (r["value"], r["status"]) for r in samples.iter_rows(named=True)}


# --- long CSV ---------------------------------------------------------------
def test_long_csv_states_become_null_values_with_their_text():
    samples, quarantine = read_export(DATA / "pi_long.csv")
    assert samples.schema == pl.Schema(SAMPLE_SCHEMA)
    assert quarantine.schema == pl.Schema(QUARANTINE_SCHEMA)
    assert quarantine.is_empty()
    rows = by_key(samples)
    assert rows[("FIC101.PV", utc(2024, 3, 1, 0, 0, 2))] == (None, "I/O Timeout")
    assert rows[("FIC101.PV", utc(2024, 3, 1, 0, 0, 4))] == (None, "Bad Input")
    assert rows[("FIC101.OP", utc(2024, 3, 1, 0, 0, 3))] == (None, "Shutdown")
    assert rows[("FIC101.MODE", utc(2024, 3, 1, 0, 0, 3))] == (None, "MAN")


def test_long_csv_status_flags_are_kept_beside_the_value():
    samples, _ = read_export(DATA / "pi_long.csv")
    rows = by_key(samples)
    assert rows[("FIC101.PV", utc(2024, 3, 1, 0, 0, 3))] == (51.5, "Questionable")
    assert rows[("FIC101.OP", utc(2024, 3, 1, 0, 0, 1))] == (41.0, "Substituted")
    assert rows[("FIC101.OP", utc(2024, 3, 1, 0, 0, 4))] == (44.0, "Annotated")
    assert rows[("FIC101.PV", utc(2024, 3, 1, 0, 0, 0))] == (50.0, None)


def test_source_line_points_at_the_physical_line(tmp_path):
    path = write(tmp_path, "x.csv", "tag,timestamp,value\n\nA,2024-01-01T00:00:00Z,1\n"
                                    "\nA,2024-01-01T00:00:01Z,2\n")
    samples, _ = read_export(path)
    assert samples["source_line"].to_list() == [3, 5]
    assert samples["source_file"].unique().to_list() == [str(path)]


def test_column_aliases_are_case_insensitive(tmp_path):
    path = write(tmp_path, "a.csv", "TagName,TIME,Val,Quality\nT1,2024-01-01T00:00:00Z,3.5,Good\n")
    samples, quarantine = read_export(path)
    assert quarantine.is_empty()
    assert samples.select("tag", "value", "status").row(0) == ("T1", 3.5, "Good")


def test_state_and_flag_on_one_row_are_both_kept(tmp_path):
    path = write(tmp_path, "a.csv", 'tag,timestamp,value,status\n'
                                    '"T1","2024-01-01T00:00:00Z","Bad Input","Substituted"\n')
    samples, _ = read_export(path)
    assert samples.select("value", "status").row(0) == (None, "Bad Input; Substituted")


def test_quoted_field_with_separator_is_parsed(tmp_path):
    path = write(tmp_path, "a.csv", 'tag,timestamp,value\n"T,1",2024-01-01T00:00:00Z,"2.5"\n')
    samples, quarantine = read_export(path)
    assert quarantine.is_empty()
    assert samples.select("tag", "value").row(0) == ("T,1", 2.5)


def test_semicolon_separator_with_decimal_comma(tmp_path):
    path = write(tmp_path, "a.csv", "tag;timestamp;value\nT1;2024-01-01T00:00:00Z;12,5\n")
    samples, _ = read_export(path)
    assert samples["value"].to_list() == [12.5]


def test_phd_confidence_minus_one_means_no_data(tmp_path):
    path = write(tmp_path, "a.csv", "tag,timestamp,value,confidence\n"
                                    "T1,2024-01-01T00:00:00Z,5,100\nT1,2024-01-01T00:00:01Z,0,-1\n")
    samples, _ = read_export(path)
    assert samples.select("value", "status").rows() == [(5.0, "confidence 100"),
                                                         (None, "confidence -1")]


def test_nan_text_is_a_bad_sample_not_a_number(tmp_path):
    path = write(tmp_path, "a.csv", "tag,timestamp,value\nT1,2024-01-01T00:00:00Z,NaN\n")
    samples, quarantine = read_export(path)
    assert quarantine.is_empty()
    assert samples.select("value", "status").row(0) == (None, "NaN")


def test_windows_export_crlf_and_latin1(tmp_path):
    path = tmp_path / "win.csv"
    path.write_bytes(b"tag,timestamp,value\r\nT\xb0C,2024-01-01T00:00:00.123456789Z,1\r\n"
                     b"A,2024-01-01T00:00:01Z,Bad Input\r\n")
    parsed = parse_export(path)
    assert parsed.quarantine.is_empty()
    assert by_key(parsed.samples) == {
        ("T\u00b0C", utc(2024, 1, 1, 0, 0, 0, 123456)): (1.0, None),  # ns truncated to us
        ("A", utc(2024, 1, 1, 0, 0, 1)): (None, "Bad Input")}
    assert any("read as Latin-1" in n for n in parsed.notes)


def test_epoch_seconds_file(tmp_path):
    path = write(tmp_path, "e.csv", "tag,timestamp,value\n" + "".join(
        f"A,{1704067200 + s},{s}\n" for s in range(5)) + "A,17040672xx,9\n")
    samples, quarantine = read_export(path)
    assert samples["ts"].to_list() == [utc(2024, 1, 1, 0, 0, s) for s in range(5)]
    assert quarantine["reason"].to_list() == ["unparseable timestamp '17040672xx'"]


# --- wide CSV ---------------------------------------------------------------
def test_wide_csv_unpivots_and_handles_cells():
    parsed = parse_export(DATA / "wide.csv")
    assert parsed.shape == "wide"
    rows = by_key(parsed.samples)
    t0 = utc(2024, 2, 29, 23, 0, 0)  # +01:00 -> UTC
    assert rows[("FIC101.PV", t0)] == (50.0, None)
    assert rows[("FIC101.PV", t0 + dt.timedelta(seconds=2))] == (None, "Calc Failed")
    # the empty cell is "no sample", not a bad sample and not quarantined
    assert ("FIC101.OP", t0 + dt.timedelta(seconds=1)) not in rows
    assert parsed.samples.height == 10
    q = parsed.quarantine.row(0, named=True)
    assert parsed.quarantine.height == 1
    assert q["line"] == 5 and q["raw"].endswith("#VALUE!")
    assert "non-numeric value '#VALUE!'" in q["reason"] and "LIC200.PV" in q["reason"]


# --- Parquet ----------------------------------------------------------------
def test_parquet_long_with_typed_columns(tmp_path):
    ts = [utc(2024, 1, 1, 0, 0, s) for s in range(3)]
    frame = pl.DataFrame({"tagname": ["A", "A", "B"], "ts": ts, "val": [1.0, float("nan"), 3.0],
                          "status": [None, None, "Questionable"]})
    frame.write_parquet(tmp_path / "a.parquet")
    parsed = parse_export(tmp_path / "a.parquet")
    assert parsed.shape == "long" and parsed.quarantine.is_empty()
    assert parsed.samples.select("tag", "ts", "value", "status").rows() == [
        ("A", ts[0], 1.0, None), ("A", ts[1], None, "NaN"), ("B", ts[2], 3.0, "Questionable")]
    assert parsed.samples["source_line"].to_list() == [2, 3, 4]


def test_parquet_long_with_text_values_and_times(tmp_path):
    frame = pl.DataFrame({"tag": ["A", "A", "A"],
                          "timestamp": ["2024-01-01T01:00:00+01:00", "2024-01-01T00:00:01Z", "bad"],
                          "value": ["1.5", "Comm Fail", "2"]})
    frame.write_parquet(tmp_path / "a.parquet")
    samples, quarantine = read_export(tmp_path / "a.parquet")
    assert samples.select("ts", "value", "status").rows() == [
        (utc(2024, 1, 1, 0, 0, 0), 1.5, None), (utc(2024, 1, 1, 0, 0, 1), None, "Comm Fail")]
    assert quarantine.select("line", "raw", "reason").row(0) == (
        4, "A,bad,2", "unparseable timestamp 'bad'")


def test_parquet_wide_numeric_nan_is_no_sample_and_text_states_kept(tmp_path):
    ts = [utc(2024, 1, 1, 0, 0, s) for s in range(3)]
    frame = pl.DataFrame({"Time": ts, "T1": [1.0, float("nan"), 3.0],
                          "T2": ["5", "No Data", None]})
    frame.write_parquet(tmp_path / "w.parquet")
    parsed = parse_export(tmp_path / "w.parquet")
    assert parsed.shape == "wide"
    assert by_key(parsed.samples) == {("T1", ts[0]): (1.0, None), ("T1", ts[2]): (3.0, None),
                                      ("T2", ts[0]): (5.0, None),
                                      ("T2", ts[1]): (None, "No Data")}


def test_parquet_epoch_seconds(tmp_path):
    pl.DataFrame({"tag": ["A"], "time": [1704067200], "value": [1.0]}).write_parquet(
        tmp_path / "e.parquet")
    samples, _ = read_export(tmp_path / "e.parquet")
    assert samples["ts"].to_list() == [utc(2024, 1, 1)]


def test_unreadable_parquet_is_a_one_line_error(tmp_path):
    path = write(tmp_path, "broken.parquet", "this is not parquet")
    with pytest.raises(ExportError, match="broken.parquet: not a readable Parquet file") as err:
        read_export(path)
    assert "\n" not in str(err.value)


# --- bad input: layout and empty files ----------------------------------------
@pytest.mark.parametrize("header", ["tag,timestamp,value,unit", "foo,bar"])
def test_unknown_columns_are_a_one_line_error_naming_file_and_columns(tmp_path, header):
    path = write(tmp_path, "odd.csv", header + "\nA,2024-01-01T00:00:00Z,1,m\n")
    with pytest.raises(ExportError) as err:
        read_export(path)
    msg = str(err.value)
    assert "\n" not in msg and "odd.csv" in msg
    for col in header.split(","):
        assert repr(col) in msg


def test_unknown_columns_in_parquet(tmp_path):
    pl.DataFrame({"tag": ["A"], "ts": [1.0], "value": [1.0], "extra": [1]}).write_parquet(
        tmp_path / "x.parquet")
    with pytest.raises(ExportError, match=r"x.parquet: unknown columns \['extra'\]"):
        read_export(tmp_path / "x.parquet")


@pytest.mark.parametrize("content", ["", "\n\n  \n"])
def test_empty_file_is_a_one_line_error(tmp_path, content):
    path = write(tmp_path, "empty.csv", content)
    with pytest.raises(ExportError, match=r"empty.csv: empty file"):
        read_export(path)


def test_header_only_file_gives_empty_result_and_a_note(tmp_path):
    parsed = parse_export(write(tmp_path, "h.csv", "tag,timestamp,value\n"))
    assert parsed.samples.is_empty() and parsed.quarantine.is_empty()
    assert any("header only" in n for n in parsed.notes)


def test_missing_file_is_an_error(tmp_path):
    with pytest.raises(ExportError, match="nope.csv: no such file"):
        read_export(tmp_path / "nope.csv")


# --- bad input: rows ------------------------------------------------------------
def test_garbage_rows_are_quarantined_with_raw_text_and_reason(tmp_path):
    text = ("tag,timestamp,value\n"
            "A,2024-01-01T00:00:00Z,1\n"
            "A,2024-01-01T00:00:01Z,12abc\n"
            ",2024-01-01T00:00:02Z,3\n"
            "A,not a time,4\n"
            "A,2024-01-01T00:00:04Z\n"
            "A,2024-01-01T00:00:05Z,\n"
            "A,2024-02-30T00:00:00Z,5\n")
    samples, quarantine = read_export(write(tmp_path, "g.csv", text))
    assert samples["source_line"].to_list() == [2]
    got = {r["line"]: (r["raw"], r["reason"]) for r in quarantine.iter_rows(named=True)}
    lines = text.splitlines()
    assert got == {
        3: (lines[2], "non-numeric value '12abc'"),
        4: (lines[3], "empty tag"),
        5: (lines[4], "unparseable timestamp 'not a time'"),
        6: (lines[5], "malformed line: expected 3 fields, found 2"),
        7: (lines[6], "empty value"),
        8: (lines[7], "unparseable timestamp '2024-02-30T00:00:00Z'"),
    }


def test_duplicate_timestamps_exact_dropped_and_different_quarantined(tmp_path):
    text = ("tag,timestamp,value\n"
            "A,2024-01-01T00:00:00Z,1\n"
            "A,2024-01-01T00:00:00Z,1\n"
            "A,2024-01-01T00:00:00Z,7\n"
            "B,2024-01-01T00:00:00Z,7\n")
    parsed = parse_export(write(tmp_path, "d.csv", text))
    assert parsed.duplicates_dropped == 1
    assert by_key(parsed.samples) == {("A", utc(2024, 1, 1)): (1.0, None),
                                      ("B", utc(2024, 1, 1)): (7.0, None)}
    q = parsed.quarantine.row(0, named=True)
    assert parsed.quarantine.height == 1 and q["line"] == 4
    assert q["reason"].startswith("duplicate timestamp with a different value")
    assert "kept line 2" in q["reason"]


def test_time_running_backwards_is_sorted_and_reported(tmp_path):
    text = ("tag,timestamp,value\n"
            "A,2024-01-01T00:00:02Z,3\n"
            "A,2024-01-01T00:00:00Z,1\n"
            "A,2024-01-01T00:00:01Z,2\n"
            "B,2024-01-01T00:00:00Z,5\n")
    parsed = parse_export(write(tmp_path, "b.csv", text))
    assert parsed.samples.filter(pl.col("tag") == "A")["value"].to_list() == [1.0, 2.0, 3.0]
    assert parsed.backwards_rows == 1
    assert any("time runs backwards" in n and "line 3" in n for n in parsed.notes)


# --- time zones -----------------------------------------------------------------
def test_mixed_offsets_in_one_file_are_converted_row_by_row(tmp_path):
    text = ("tag,timestamp,value\n"
            "A,2024-01-01T01:00:00+01:00,1\n"
            "A,2024-01-01T00:00:01Z,2\n"
            "A,2023-12-31 19:00:02-05:00,3\n"
            "A,2024-01-01T05:30:03+0530,4\n"
            "A,1704067204,5\n")
    samples, quarantine = read_export(write(tmp_path, "m.csv", text))
    assert quarantine.is_empty()
    assert samples["ts"].to_list() == [utc(2024, 1, 1, 0, 0, s) for s in range(5)]


def test_naive_rows_are_quarantined_when_mixed_with_offsets_and_no_zone(tmp_path):
    text = ("tag,timestamp,value\n"
            "A,2024-01-01T00:00:00Z,1\n"
            "A,2024-01-01 00:00:01,2\n")
    samples, quarantine = read_export(write(tmp_path, "m.csv", text))
    assert samples.height == 1
    assert quarantine["line"].to_list() == [3]
    assert "no UTC offset" in quarantine["reason"][0]


def test_all_naive_without_zone_is_a_one_line_error(tmp_path):
    path = write(tmp_path, "n.csv", "tag,timestamp,value\nA,2024-01-01 00:00:00,1\n")
    with pytest.raises(ExportError, match=r"n.csv: time stamps carry no UTC offset.*timezone="):
        read_export(path)


def test_naive_local_times_with_zone_and_daylight_saving():
    samples, quarantine = read_export(DATA / "dst_berlin.csv", timezone="Europe/Berlin")
    assert samples.sort("source_line")["ts"].to_list() == [
        utc(2024, 10, 26, 23, 30),   # 01:30 CEST
        utc(2024, 10, 27, 0, 30),    # 02:30, the overlap's first pass: CEST
        utc(2024, 10, 27, 2, 30),    # 03:30 CET
        utc(2024, 3, 31, 1, 30),     # 03:30 CEST
    ]
    reasons = dict(zip(quarantine["line"], quarantine["reason"]))
    assert reasons[5].startswith("non-existent local time (daylight-saving gap")
    assert len(reasons) == 1


@pytest.mark.parametrize("layout", ["long", "wide"])
def test_a_time_ordered_naive_record_through_the_autumn_change_is_resolved_by_order(
        tmp_path, layout):
    # 15 min samples, 01:00 CEST to 03:15 CET: the local hour 02:00-02:59 comes twice,
    # first in daylight time, then in standard time; each tag's record is in time order
    local = ["01:00", "01:15", "01:30", "01:45", "02:00", "02:15", "02:30", "02:45",
             "02:00", "02:15", "02:30", "02:45", "03:00", "03:15"]
    if layout == "long":
        text = "tag,time,value\n" + "".join(f"{tag},2024-10-27 {t}:00,{i}\n" for tag in "AB"
                                            for i, t in enumerate(local))
    else:
        text = "time,A,B\n" + "".join(f"2024-10-27 {t}:00,{i},{-i}\n"
                                      for i, t in enumerate(local))
    samples, quarantine = read_export(write(tmp_path, "dst.csv", text),
                                      timezone="Europe/Berlin")
    assert quarantine.is_empty()
    for tag in "AB":
        ts = samples.filter(pl.col("tag") == tag).sort("source_line")["ts"].to_list()
        assert ts == [utc(2024, 10, 26, 23) + dt.timedelta(minutes=15 * k)
                      for k in range(len(local))]


def test_offset_times_ignore_the_configured_zone(tmp_path):
    path = write(tmp_path, "o.csv", "tag,timestamp,value\nA,2024-07-01T12:00:00Z,1\n")
    samples, _ = read_export(path, timezone="America/New_York")
    assert samples["ts"].to_list() == [utc(2024, 7, 1, 12)]


def test_unknown_time_zone_is_refused(tmp_path):
    with pytest.raises(ValueError, match="unknown IANA time zone 'Mars/Olympus'"):
        read_export(DATA / "pi_long.csv", timezone="Mars/Olympus")


def test_epoch_milliseconds_are_quarantined_not_guessed(tmp_path):
    path = write(tmp_path, "e.csv", "tag,timestamp,value\nA,1704067200000,1\nA,1704067200.5,2\n")
    samples, quarantine = read_export(path)
    assert samples["ts"].to_list() == [utc(2024, 1, 1, 0, 0, 0, 500000)]
    assert "milliseconds" in quarantine["reason"][0]


# --- nothing is lost (property) ---------------------------------------------------
good_line = st.builds(lambda tag, s, v: f"{tag},2024-01-01T00:00:{s:02d}Z,{v}",
                      st.sampled_from(["A", "B"]), st.integers(0, 20),
                      st.sampled_from(["1", "2.5", "-3e2", "I/O Timeout", "Bad Input"]))
bad_line = st.sampled_from(["A,xx,1", ",2024-01-01T00:00:00Z,1", "A,2024-01-01T00:00:00Z,zz",
                            "A,2024-01-01T00:00:00Z", "A,2024-01-01 00:00:00,1", "junk"])


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lines=st.lists(st.one_of(good_line, bad_line), min_size=1, max_size=40))
def test_every_line_is_stored_quarantined_or_counted_duplicate(tmp_path, lines):
    # one row with an offset, so an all-naive file (a whole-file error) cannot occur
    lines = ["Z,2024-01-01T00:00:00Z,0", *lines]
    path = tmp_path / "p.csv"
    path.write_text("tag,timestamp,value\n" + "\n".join(lines) + "\n")
    parsed = parse_export(path)
    stored = set(parsed.samples["source_line"])
    quarantined = set(parsed.quarantine["line"])
    assert not stored & quarantined
    assert len(stored) + len(quarantined) + parsed.duplicates_dropped == len(lines)
    assert parsed.samples.select("tag", "ts").is_duplicated().sum() == 0


# --- ingest into the store --------------------------------------------------------
def test_ingest_then_reingest_leaves_row_counts_unchanged(tmp_path):
    db = tmp_path / "plant.duckdb"
    exports = [DATA / "pi_long.csv", DATA / "wide.csv"]
    with Store(db) as store:
        first = ingest_exports(store, exports)
        counts = store.counts()
    assert first.ok and first.files == 2
    assert counts["samples"] == first.rows_inserted == 12 + 10
    assert counts["quarantine"] == first.rows_quarantined == 1
    for force in (False, True):
        with Store(db) as store:  # a fresh process would reopen the file like this
            again = ingest_exports(store, exports, force=force)
            assert store.counts() == counts
            assert store.duplicate_keys() == 0
        assert again.rows_inserted == 0
    assert again.rows_skipped_duplicate == counts["samples"]  # forced: all are duplicates


def test_overlapping_exports_do_not_duplicate(tmp_path):
    a = write(tmp_path, "a.csv", "tag,timestamp,value\n" + "".join(
        f"T,2024-01-01T00:00:{s:02d}Z,{s}\n" for s in range(0, 10)))
    b = write(tmp_path, "b.csv", "tag,timestamp,value\n" + "".join(
        f"T,2024-01-01T00:00:{s:02d}Z,{s}\n" for s in range(5, 15)))
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [a, b])
        assert store.counts()["samples"] == 15
        assert store.duplicate_keys() == 0
    assert report.rows_inserted == 15 and report.rows_skipped_duplicate == 5


def test_conflicting_value_in_a_later_export_is_quarantined(tmp_path):
    a = write(tmp_path, "a.csv", "tag,timestamp,value\nT,2024-01-01T00:00:00Z,1\n")
    b = write(tmp_path, "b.csv", "tag,timestamp,value\nT,2024-01-01T00:00:00Z,2\n")
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [a, b])
        assert store.fetch_tag("T")["value"].to_list() == [1.0]
        q = store.quarantine(str(b)).row(0, named=True)
    assert report.rows_quarantined == 1
    assert q["raw"] == "T,2024-01-01T00:00:00Z,2"
    assert q["reason"].startswith("duplicate timestamp with a different value")
    assert str(a) in q["reason"]


def test_failing_file_is_reported_and_others_continue(tmp_path):
    good = shutil.copy(DATA / "pi_long.csv", tmp_path / "good.csv")
    write(tmp_path, "bad.csv", "foo,bar\n1,2\n")
    write(tmp_path, "empty.csv", "")
    seen = []
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, str(tmp_path / "*.csv"),
                                progress=lambda done, total, path: seen.append((done, total)))
        assert store.counts()["samples"] == 12
    assert report.files == 3 and not report.ok
    assert seen == [(1, 3), (2, 3), (3, 3)]
    assert len(report.errors) == 2
    assert all("\n" not in e for e in report.errors)
    assert any("bad.csv" in e and "'foo'" in e for e in report.errors)
    assert any("empty.csv: empty file" in e for e in report.errors)
    assert [f.path for f in report.per_file if f.error is None] == [str(good)]


def test_glob_that_matches_nothing_is_an_error(tmp_path):
    files, errors = expand_paths([str(tmp_path / "*.parquet")])
    assert files == [] and errors == [f"{tmp_path / '*.parquet'}: no file matches"]


def test_ingested_files_are_recorded_with_hash(tmp_path):
    with Store(tmp_path / "s.duckdb") as store:
        ingest_exports(store, [DATA / "wide.csv"])
        files = store.ingested_files()
    assert files.height == 1
    row = files.row(0, named=True)
    assert row["path"] == str(DATA / "wide.csv")
    assert len(row["sha256"]) == 64 and row["rows_inserted"] == 10 and row["quarantined"] == 1


def test_many_files_stream_one_at_a_time(tmp_path):
    rng = np.random.default_rng(0)
    for k in range(12):
        pl.DataFrame({"tag": [f"T{k % 3}"] * 50,
                      "ts": [utc(2024, 1, 1) + dt.timedelta(seconds=k * 50 + i) for i in range(50)],
                      "value": rng.normal(size=50)}).write_parquet(tmp_path / f"e{k:02d}.parquet")
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, tmp_path / "e*.parquet")
        assert store.counts()["samples"] == 600
        assert store.tags() == ["T0", "T1", "T2"]
    assert report.ok and report.files == 12 and report.rows_inserted == 600


# --- slicing large files ------------------------------------------------------------
SLICED = ("tag,timestamp,value\n"
          "A,2024-01-01T00:00:00Z,1\n"
          "A,2024-01-01T00:00:01Z,2\n"
          "B,2024-01-01T00:00:00Z,3\n"
          "A,2024-01-01T00:00:00Z,1\n"       # exact duplicate of line 2, next slice
          "A,2024-01-01T00:00:01Z,9\n"       # conflicts with line 3, next slice
          "B,2024-01-01T00:00:01Z,I/O Timeout\n"
          "B,garbage,1\n")


@pytest.mark.parametrize("chunk_rows", [None, 1, 3, 100])
def test_slice_size_does_not_change_what_is_stored(tmp_path, chunk_rows):
    path = write(tmp_path, "s.csv", SLICED)
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [path], chunk_rows=chunk_rows)
        samples = store.query("tag_window", tag="A", start=None, end=None)
        quarantine = store.quarantine()
        assert store.counts()["samples"] == 4
    assert samples["value"].to_list() == [1.0, 2.0]
    assert report.rows_inserted == 4 and report.rows_skipped_duplicate == 1
    assert quarantine["line"].to_list() == [6, 8]
    assert quarantine["reason"][0].startswith("duplicate timestamp with a different value")


def test_naive_rows_in_a_later_slice_are_quarantined_like_a_mixed_file(tmp_path):
    path = write(tmp_path, "f.csv", "tag,timestamp,value\nA,2024-01-01T00:00:00Z,1\n"
                                    "A,2024-01-01 00:00:01,2\n")
    whole = parse_export(path)
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [path], chunk_rows=1)
        q = store.quarantine()
        assert store.counts()["samples"] == 1
    assert report.ok and q["line"].to_list() == whole.quarantine["line"].to_list() == [3]
    assert "no UTC offset" in q["reason"][0]


def test_all_naive_first_slice_fails_before_anything_is_written(tmp_path):
    path = write(tmp_path, "f.csv", "tag,timestamp,value\nA,2024-01-01 00:00:00,1\n"
                                    "A,2024-01-01T00:00:01Z,2\n")
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [path], chunk_rows=1)
        assert store.counts()["samples"] == 0 and store.counts()["ingested_files"] == 0
    assert len(report.errors) == 1 and "no UTC offset" in report.errors[0]


def test_interrupted_file_is_completed_by_the_next_run(tmp_path):
    path = write(tmp_path, "s.csv", SLICED)
    with Store(tmp_path / "s.duckdb") as store:
        first = next(iter_export(path, chunk_rows=3))   # as if the run died after slice 1
        with store.transaction():
            _write_parsed(store, first)
        assert store.counts()["ingested_files"] == 0
        report = ingest_exports(store, [path], chunk_rows=3)
        assert store.counts()["samples"] == 4 and store.duplicate_keys() == 0
    assert report.rows_inserted == 4 - first.samples.height


# --- fast paths must give what the general path gives -------------------------
def _general_only(monkeypatch):
    """Force the general sort-and-dedupe path and no prefetch thread."""
    import valvediag.io.exports as exports
    import valvediag.store.ingest as ingest
    monkeypatch.setattr(exports, "_sorted_runs", lambda good: None)
    monkeypatch.setattr(ingest, "_prefetched", lambda items: items)


def _stored(db: Path) -> tuple[list, list]:
    with Store(db) as store:
        rows = store.con.execute(
            "SELECT tag, ts, value, status, source_file, source_line FROM samples "
            "ORDER BY rowid").fetchall()
        quarantine = store.quarantine().drop("ingested_at").rows()
    return rows, quarantine


def _messy_parquet(path: Path) -> Path:
    """Tags in blocks out of order, states, flags, blanks, null tags, duplicates,
    conflicts, time running backwards and (per file) naive time stamps."""
    t0 = dt.datetime(2024, 3, 1)
    rows = []
    for tag in ("PIC2.PV", "FIC1.OP", "FIC1.PV"):  # blocks, not in tag order
        for s in range(40):
            value = f" {s * 1.5} " if s % 7 else "Bad Input"
            rows.append((tag, t0 + dt.timedelta(seconds=s), value,
                         "Questionable" if s % 11 == 0 else None))
    rows += [("FIC1.PV", t0 + dt.timedelta(seconds=3), "4.5", None),    # exact duplicate
             ("FIC1.PV", t0 + dt.timedelta(seconds=4), "99", None),     # conflict
             ("FIC1.OP", t0 + dt.timedelta(seconds=1), "1.5", None),    # backwards, duplicate
             (None, t0, "1", None), ("  ", t0, "2", None),              # no tag
             ("FIC1.PV", None, "3", None),                              # no time
             ("FIC1.PV", t0 + dt.timedelta(seconds=50), "garbage", None),
             ("FIC1.PV", t0 + dt.timedelta(seconds=51), "NaN", None)]
    frame = pl.DataFrame(rows, schema={"tag": pl.String, "timestamp": pl.Datetime("us"),
                                       "value": pl.String, "status": pl.String}, orient="row")
    frame.write_parquet(path)
    return path


@pytest.mark.parametrize("clean", [True, False])
@pytest.mark.parametrize("chunk_rows", [None, 7, 50])
def test_fast_paths_store_what_the_general_path_stores(tmp_path, monkeypatch, clean, chunk_rows):
    """The block-sorted shortcut, the single-file insert and the prefetch thread change
    nothing: the same stored rows (in the same order) and the same quarantine."""
    src = _messy_parquet(tmp_path / "messy.parquet")
    if clean:  # only the blocks out of tag order: the shortcut takes every slice
        frame = pl.read_parquet(src).filter(pl.col("tag").str.strip_chars() != "",
                                            pl.col("value") != "garbage")
        frame = frame.unique(["tag", "timestamp"], keep="first", maintain_order=True)
        frame = frame.drop_nulls("timestamp").sort("tag", "timestamp", descending=[True, False])
        frame.write_parquet(src)
    again = tmp_path / "again.parquet"  # the same rows again, another file
    shutil.copy(src, again)
    results = []
    for label in ("fast", "general"):
        with monkeypatch.context() as m:
            if label == "general":
                _general_only(m)
            db = tmp_path / f"{label}.duckdb"
            with Store(db) as store:
                first = ingest_exports(store, [src], timezone="Europe/Berlin",
                                       chunk_rows=chunk_rows)
                second = ingest_exports(store, [src, again], timezone="Europe/Berlin",
                                        chunk_rows=chunk_rows, force=True)
                assert store.duplicate_keys() == 0
            results.append((_stored(db), [(r.rows_read, r.rows_inserted,
                                           r.rows_skipped_duplicate, r.rows_quarantined,
                                           r.notes) for r in first.per_file + second.per_file]))
    assert results[0] == results[1]
    (rows, quarantine), counts = results[0]
    assert rows and counts[0][1] == len(rows)
    assert bool(quarantine) != clean


def test_parse_of_blocks_out_of_tag_order_is_sorted_like_the_general_path(tmp_path, monkeypatch):
    src = _messy_parquet(tmp_path / "m.parquet")
    frame = pl.read_parquet(src).filter(pl.col("tag").str.strip_chars() != "")
    frame = frame.unique(["tag", "timestamp"], keep="first", maintain_order=True).drop_nulls()
    frame.write_parquet(src)
    fast = parse_export(src, timezone="UTC")
    with monkeypatch.context() as m:
        _general_only(m)
        general = parse_export(src, timezone="UTC")
    assert fast.samples.equals(general.samples)
    assert fast.samples["tag"].is_sorted()
    assert fast.quarantine.equals(general.quarantine)


def test_an_error_while_parsing_a_later_slice_reaches_the_caller(tmp_path, monkeypatch):
    """With the parse one slice ahead in a thread, an exception is still one file's error."""
    import valvediag.io.exports as ingest
    src = _messy_parquet(tmp_path / "m.parquet")
    real = ingest._finish
    calls = []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("boom in slice 2")
        return real(*args, **kwargs)

    monkeypatch.setattr(ingest, "_finish", failing)
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [src], timezone="UTC", chunk_rows=20)
        assert not report.ok and "boom in slice 2" in report.errors[0]
        assert store.ingested_files().is_empty()  # not recorded: read again next time
        assert store.counts()["samples"] > 0      # the first slice was committed


def test_prefetch_stops_its_worker_when_the_caller_stops():
    import threading

    from valvediag.store.ingest import _prefetched
    produced = []

    def items():
        for i in range(1000):
            produced.append(i)
            yield i

    before = threading.active_count()
    gen = _prefetched(items())
    assert next(gen) == 0
    gen.close()
    assert threading.active_count() == before
    assert len(produced) <= 3


def test_rows_quarantined_for_a_missing_time_zone_are_recovered_by_a_rerun_with_it(tmp_path):
    # naive rows among offset ones: quarantined without a time zone, a cause the user fixes
    # by giving one; the file must not count as read, so the re-run recovers them
    path = write(tmp_path, "m.csv", "tag,timestamp,value\n"
                                    "A,2024-01-01T00:00:00Z,1\n"
                                    "A,2024-01-01 00:00:01,2\n"
                                    "A,2024-01-01 00:00:02,3\n"
                                    "A,2024-01-01T00:00:03Z,x\n")
    with Store(tmp_path / "s.duckdb") as store:
        first = ingest_exports(store, [path]).per_file[0]
        assert (first.rows_inserted, first.rows_quarantined, first.fixable) == (1, 3, 2)
        assert first.reasons[0] == ("timestamp has no UTC offset and no time zone is "
                                    "configured (the file mixes naive and offset time stamps)", 2)
        assert first.reasons[1] == ("non-numeric value '…'", 1)
        report = ingest_exports(store, [path])
        assert not report.per_file[0].unchanged          # read again: not recorded as read
        assert any("a cause a setting fixes" in line for line in report.incomplete)
        fixed = ingest_exports(store, [path], timezone="UTC").per_file[0]
        assert (fixed.rows_inserted, fixed.rows_skipped_duplicate, fixed.fixable) == (2, 1, 0)
        again = ingest_exports(store, [path], timezone="UTC")
        assert again.per_file[0].unchanged and again.incomplete == ()
        assert store.counts()["samples"] == 3 and store.duplicate_keys() == 0
        line = fixed.summary()
    assert line == (f"{path}: 3 rows read, 2 stored, 1 already stored, 1 quarantined "
                    f"(1 like: non-numeric value 'x')")


def test_a_file_with_most_rows_quarantined_is_named_with_an_example(tmp_path):
    # text where numbers belong: the file must not look read; it is named, with a
    # row's reason as the example
    path = write(tmp_path, "dc.csv", "tag,timestamp,value\n" + "".join(
        f"A,2024-01-01T00:00:{i:02d}Z,v{i}?\n" for i in range(20)) +
        "A,2024-01-01T00:01:00Z,3.5\n")
    with Store(tmp_path / "s.duckdb") as store:
        report = ingest_exports(store, [path])
    assert report.incomplete == (f"{path}: 20 of 21 rows quarantined (e.g. non-numeric value "
                                 f"'v0?')",)
    assert report.per_file[0].as_dict()["quarantine_reasons"] == [
        {"reason": "non-numeric value '…'", "rows": 20,
         "example": "non-numeric value 'v0?'"}]


@pytest.mark.parametrize("values, stored, quarantined", [
    (['"12,5"', '"0,25"', "3"], [12.5, 0.25, 3.0], []),             # decimal commas
    (['"1,234"', '"2,500"'], [], ["'1,234'", "'2,500'"]),           # a thousands separator?
    (['"1,5"', "2.5"], [2.5], ["'1,5'"]),                          # decimal points elsewhere
    (['"1,5"', "0.0", "-0.0"], [0.0, -0.0], ["'1,5'"]),             # a point, whole values
])
def test_quoted_decimal_commas_in_a_comma_separated_export(tmp_path, values, stored,
                                                           quarantined):
    text = "tag,timestamp,value\n" + "".join(f"A,2024-01-01T00:00:{i:02d}Z,{v}\n"
                                             for i, v in enumerate(values))
    samples, quarantine = read_export(write(tmp_path, "c.csv", text))
    assert samples.sort("ts")["value"].to_list() == stored
    assert [r.split(" ", 2)[2] for r in quarantine["reason"].to_list()] == quarantined


def test_a_parquet_text_value_with_a_comma_is_not_a_decimal(tmp_path):
    """Parquet types its numbers: a text value "1,5" beside whole numbers
    (which a comma-separated file's detection would read as decimal commas)
    is quarantined, not read as 1.5."""
    import datetime as dt

    ts = [dt.datetime(2024, 1, 1, 0, 0, i, tzinfo=dt.timezone.utc) for i in range(3)]
    path = tmp_path / "p.parquet"
    frame = pl.DataFrame({"tag": ["A"] * 3, "timestamp": ts, "value": ["1,5", "0", "2"]})
    frame.write_parquet(path)
    samples, quarantine = read_export(path)
    assert sorted(samples["value"].to_list()) == [0.0, 2.0]
    assert quarantine.height == 1 and "'1,5'" in quarantine["reason"][0]
