"""Tests of ``valvediag synth-plant``."""
from __future__ import annotations

import json

import polars as pl
import pytest

from valvediag.cli import main


def test_synth_plant_writes_the_plant(tmp_path, capsys):
    out = tmp_path / "plant"
    rc = main(["synth-plant", "--loops", "4", "--days", "0.01", "--sample-time", "1",
               "--out", str(out), "--seed", "5", "--quiet"])
    assert rc == 0
    loops = pl.read_csv(out / "loops.csv")
    truth = pl.read_csv(out / "truth.csv")
    assert loops.height == truth.height == 4
    assert sorted(loops["loop"]) == sorted(truth["loop"])
    exports = list((out / "exports").glob("long_*.csv"))
    assert len(exports) == 1
    text = capsys.readouterr().out
    assert "wrote 1 export file(s)" in text and str(out / "loops.csv") in text


def test_synth_plant_json_and_formats(tmp_path, capsys):
    out = tmp_path / "p"
    rc = main(["synth-plant", "--loops", "3", "--days", "0.01", "--sample-time", "1",
               "--out", str(out), "--seed", "6", "--formats", "parquet", "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["loops"] == 3 and doc["seed"] == 6 and doc["sample_time"] == 1.0
    assert sum(doc["truth_counts"].values()) == 3
    assert [p.endswith(".parquet") for p in doc["exports"]] == [True]


def test_synth_plant_same_seed_same_files(tmp_path):
    args = ["synth-plant", "--loops", "3", "--days", "0.02", "--sample-time", "2", "--quiet",
            "--seed", "9"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    for name in ("loops.csv", "truth.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_synth_plant_reports_bad_arguments_in_one_line(tmp_path, capsys):
    rc = main(["synth-plant", "--loops", "3", "--days", "0.001", "--sample-time", "1",
               "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("valvediag synth-plant: error: a record of 86.4 s is too short")
    assert err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:
        main(["synth-plant", "--loops", "0", "--days", "1", "--sample-time", "1",
              "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "must be > 0" in capsys.readouterr().err


def test_synth_plant_help_lists_the_options(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["synth-plant", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for opt in ("--loops", "--days", "--sample-time", "--out", "--seed", "--formats", "--json"):
        assert opt in text
    assert "truth.csv" in text
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "synth-plant" in capsys.readouterr().out
