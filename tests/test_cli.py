"""The command line: help, bi, reproduce-paper."""
import json
import subprocess
import sys

import numpy as np
import pytest

from valvediag import simulate_loop
from valvediag.cli import build_parser, main


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "valvediag", *args], capture_output=True,
                          text=True, timeout=600)


@pytest.mark.system
def test_help_lists_every_command_and_each_has_help(capsys):
    out = run_cli("--help")
    assert out.returncode == 0
    for cmd in ("bi", "reproduce-paper"):
        assert cmd in out.stdout
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():
        assert p.description, f"{name} has no description"


@pytest.fixture(scope="module")
def loop_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("loops")
    files = {}
    for name, valve, vp in [("sticky", "kano", {"S": 3.0, "J": 1.5}), ("loose", "backlash", {"DB": 3.0})]:
        sim = simulate_loop(kc=2.0, ti=40.0, tau=40.0, sample_time=2.0, duration=12000,
                            valve=valve, valve_params=vp, sp_step=1.0)
        pv = sim.pv[300:] + np.random.default_rng(1).normal(0, 0.01, sim.pv.size - 300)
        rows = "\n".join(f"2026-11-01T00:00:00Z,{p:.5f},{o:.5f}" for p, o in zip(pv[:1], sim.op[300:301]))
        lines = ["timestamp,pv,op"] + [f"{2.0 * i:.1f},{p:.6f},{o:.6f}" for i, (p, o) in
                                       enumerate(zip(pv, sim.op[300:]))]
        (d / f"{name}.csv").write_text("\n".join(lines) + "\n")
        files[name] = d / f"{name}.csv"
        del rows
    (d / "broken.csv").write_text("when,what\n1,2\n")
    files["broken"] = d / "broken.csv"
    return files


def test_bi_json(loop_files, capsys):
    code = main(["bi", "--json", str(loop_files["sticky"]), str(loop_files["loose"]),
                 str(loop_files["broken"])])
    assert code == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["verdict"] for r in rows] == ["stiction", "backlash", "insufficient-data"]
    for r in rows:
        assert set(r) == {"file", "verdict", "bi", "cycles", "period_s", "confidence", "reason"}
    assert rows[0]["bi"] < 2.2 < 2.4 < rows[1]["bi"]
    assert rows[0]["cycles"] > 10 and rows[0]["period_s"] > 0
    assert "missing column" in rows[2]["reason"] and rows[2]["bi"] is None


def test_bi_exits_2_when_no_file_could_be_read(loop_files, tmp_path, capsys):
    other = tmp_path / "empty.csv"
    other.write_text("")
    assert main(["bi", str(loop_files["broken"]), str(other)]) == 2
    out = capsys.readouterr().out
    assert out.count("insufficient-data") == 2 and "missing column" in out
    assert main(["bi", "--json", str(loop_files["broken"])]) == 2
    assert json.loads(capsys.readouterr().out)[0]["verdict"] == "insufficient-data"


def test_bi_reads_an_average_export_as_averaged_where_told(loop_files, tmp_path, capsys):
    # the sticky loop (period 154 s) as an export of 12 s averages: each
    # turn rounded over a sample reads as a dead band unless the CLI is told
    rows = np.loadtxt(loop_files["sticky"], delimiter=",", skiprows=1)
    m = rows.shape[0] // 6
    blocks = rows[:m * 6].reshape(m, 6, 3).mean(axis=1)
    blocks[:, 0] = 12.0 * np.arange(m)
    path = tmp_path / "averaged.csv"
    np.savetxt(path, blocks, delimiter=",", header="timestamp,pv,op", comments="", fmt="%.6f")
    assert main(["bi", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)[0]["verdict"] == "backlash"
    assert main(["bi", "--json", "--sampling", "average", str(path)]) == 0
    row = json.loads(capsys.readouterr().out)[0]
    assert row["verdict"] == "stiction" and row["bi"] < 1.2


def test_bi_table_and_paper_method(loop_files, capsys):
    assert main(["bi", "--method", "paper", str(loop_files["sticky"])]) == 0
    out = capsys.readouterr().out
    assert "stiction" in out and "Backlash Index" in out


def test_reproduce_paper_json_path_error(tmp_path, capsys):
    code = main(["reproduce-paper", "--json", str(tmp_path / "no" / "such" / "dir.json")])
    assert code == 2
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.system
def test_unknown_option_exits_nonzero():
    out = run_cli("bi")
    assert out.returncode != 0 and "FILE" in out.stderr
