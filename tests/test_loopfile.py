"""Single-loop CSV reader."""
import numpy as np
import pytest

from valvediag.io.loopfile import LoopFileError, read_loop_csv


def write(tmp_path, text, name="loop.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_iso_timestamps_with_offsets(tmp_path):
    p = write(tmp_path, "timestamp,pv,op,sp\n"
                        "2026-11-01T01:00:00+01:00,1.0,10,5\n"
                        "2026-11-01T00:00:05Z,2.0,11,5\n"
                        "2026-11-01T00:00:10+00:00,3.0,12,6\n")
    rec, meta = read_loop_csv(p)
    assert rec.sample_time == 5.0
    np.testing.assert_array_equal(rec.t, [0, 5, 10])
    np.testing.assert_array_equal(rec.pv, [1, 2, 3])
    np.testing.assert_array_equal(rec.sp, [5, 5, 6])
    assert meta["resampled"] is False and meta["rows"] == 3


def test_seconds_and_column_mapping(tmp_path):
    p = write(tmp_path, "t_s,LEVEL,VALVE\n0,1,2\n1,2,3\n2,3,4\n")
    rec, _ = read_loop_csv(p, columns={"timestamp": "t_s", "pv": "level", "op": "VALVE"})
    np.testing.assert_array_equal(rec.op, [2, 3, 4])


def test_irregular_file_is_resampled_without_bridging_gaps(tmp_path):
    t = [0, 1, 2, 3.5, 4, 5, 20, 21, 22]
    rows = "\n".join(f"{ti},{ti},{-ti}" for ti in t)
    rec, meta = read_loop_csv(write(tmp_path, "timestamp,pv,op\n" + rows + "\n"))
    assert rec.sample_time == 1.0 and meta["resampled"] and meta["gaps"] == 1
    assert rec.pv[3] == pytest.approx(3.0)               # interpolated between 2 and 3.5
    assert np.all(np.isnan(rec.pv[6:20]))                # the 15 s gap is not bridged
    assert rec.pv[20] == 20.0


def test_state_text_becomes_nan_and_is_counted(tmp_path):
    p = write(tmp_path, "timestamp,pv,op\n0,1,2\n1,I/O Timeout,3\n2,3,Bad Input\n3,4,5\n")
    rec, meta = read_loop_csv(p)
    assert np.isnan(rec.pv[1]) and np.isnan(rec.op[2])
    assert meta["non_numeric"] == {"pv": 1, "op": 1}


def test_identical_duplicates_are_dropped(tmp_path):
    rec, meta = read_loop_csv(write(tmp_path, "timestamp,pv,op\n0,1,2\n1,2,3\n1,2,3\n2,3,4\n"))
    assert meta["duplicates_dropped"] == 1 and rec.pv.size == 3


@pytest.mark.parametrize("text,match", [
    ("", "the file is empty"),
    ("timestamp,pv,op\n", "no rows"),
    ("time,level\n1,2\n", "missing column\\(s\\) pv, op"),
    ("timestamp,pv,op\n0,1,2\n1,2,3\n1,5,3\n", "line 4: duplicate timestamp 1 with a different pv value"),
    ("timestamp,pv,op\n0,1,2\n5,2,3\n3,5,3\n", "line 4: time runs backwards"),
    ("timestamp,pv,op\nyesterday,1,2\n", "line 2: timestamp 'yesterday'"),
])
def test_bad_files_name_file_and_problem(tmp_path, text, match):
    p = write(tmp_path, text)
    with pytest.raises(LoopFileError, match=match) as exc:
        read_loop_csv(p)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)


def test_missing_file(tmp_path):
    with pytest.raises(LoopFileError, match="no such file"):
        read_loop_csv(tmp_path / "nope.csv")
