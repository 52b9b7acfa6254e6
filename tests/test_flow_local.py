"""The nightly-scan flow run in-process (the path ``valvediag scan`` takes), and the command.

One temporary Prefect server for the session (``prefect_api`` in conftest.py); a
tiny synthetic plant (8 loops, 3 h at 10 s). The deployment path (server,
worker, ``prefect deployment run``) is tested in ``test_deployment.py``.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("DO_NOT_TRACK", "1")

from valvediag.cli import main  # noqa: E402
from valvediag.io.registry import read_loops_csv  # noqa: E402
from valvediag.report.outputs import VERDICT_KEYS, WORK_ORDER_COLUMNS  # noqa: E402
from valvediag.verdicts import ACTION_VERDICTS  # noqa: E402
from valvediag.store.database import VERDICTS, Store  # noqa: E402
from valvediag.synth.plant import synth_plant  # noqa: E402

N_LOOPS, DAYS, SAMPLE_TIME, SEED = 8, 0.125, 10.0, 11
CONSOLE_LEVEL = "PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL"


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    out = tmp_path_factory.mktemp("flow_plant")
    synth_plant(N_LOOPS, DAYS, SAMPLE_TIME, out, seed=SEED)
    return out


@pytest.fixture(scope="module")
def registry_loops(plant):
    loops, _ = read_loops_csv(plant / "loops.csv")
    return sorted(l.loop for l in loops)


def _scan(plant, db, out, **kw):
    from valvediag.pipelines.nightly import nightly_scan

    return nightly_scan(exports=str(plant / "exports"), loops=str(plant / "loops.csv"),
                        db=str(db), out=str(out), return_state=True, **kw)


@pytest.fixture(scope="module")
def first_run(prefect_api, plant, tmp_path_factory):
    from valvediag.pipelines.nightly import progress_to

    work = tmp_path_factory.mktemp("flow_run")
    events = []
    with progress_to(lambda stage, done, total: events.append((stage, done, total))):
        state = _scan(plant, work / "plant.duckdb", work / "out")
    return {"state": state, "db": work / "plant.duckdb", "out": work / "out", "events": events}


@pytest.mark.system
def test_flow_completes_and_writes_every_loop(first_run, registry_loops):
    state = first_run["state"]
    assert state.is_completed(), state.message
    summary = state.result()
    out = first_run["out"]
    for name in ("verdicts.json", "work_orders.csv", "report.html"):
        assert (out / name).stat().st_size > 0
    assert summary["outputs"]["report"] == str((out / "report.html").resolve())
    verdicts = json.loads((out / "verdicts.json").read_text())
    assert verdicts["run_id"] == summary["run_id"]
    assert sorted(v["loop"] for v in verdicts["loops"]) == registry_loops
    assert all(v["verdict"] in VERDICTS for v in verdicts["loops"])
    assert summary["loops"] == len(registry_loops) == sum(summary["counts"].values())
    with Store(first_run["db"], read_only=True) as store:
        runs = store.runs()
        stored = store.verdicts(summary["run_id"])
    assert runs["run_id"].to_list() == [summary["run_id"]]
    assert runs["status"].to_list() == ["complete"]
    assert runs["finished_at"][0] is not None
    assert sorted(stored["loop"].to_list()) == registry_loops
    # the work orders are exactly the loops that need action, in rank order
    lines = (out / "work_orders.csv").read_text().splitlines()
    assert lines[0].split(",")[:3] == list(WORK_ORDER_COLUMNS[:3])
    act = [v for v in verdicts["loops"] if v["verdict"] in ACTION_VERDICTS]
    assert [v["rank"] for v in act] == list(range(1, len(act) + 1))
    assert len(lines) - 1 == len(act)


@pytest.mark.system
def test_flow_reports_progress(first_run, registry_loops):
    events = first_run["events"]
    ingest = [e for e in events if e[0] == "ingest"]
    analyse = [e for e in events if e[0] == "analyse"]
    assert ingest and ingest[-1][1] == ingest[-1][2] >= 1
    n = len(registry_loops)
    done = [d for _, d, _ in analyse]     # batches of loops may finish together
    assert done[0] == 0 and done[-1] == n and done == sorted(done)
    assert {t for _, _, t in analyse} == {n}


@pytest.mark.system
def test_flow_creates_artifacts(first_run, registry_loops):
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import ArtifactFilter, ArtifactFilterFlowRunId

    from valvediag.pipelines.nightly import REPORT_ARTIFACT_KEY, TABLE_ARTIFACT_KEY

    flow_run_id = first_run["state"].state_details.flow_run_id
    with get_client(sync_client=True) as client:
        arts = client.read_artifacts(artifact_filter=ArtifactFilter(
            flow_run_id=ArtifactFilterFlowRunId(any_=[flow_run_id])))
    by_key = {a.key: a for a in arts}
    assert set(by_key) == {TABLE_ARTIFACT_KEY, REPORT_ARTIFACT_KEY}
    table = by_key[TABLE_ARTIFACT_KEY].data
    rows = json.loads(table) if isinstance(table, str) else table
    assert sorted(r["loop"] for r in rows) == registry_loops
    ranks = [r["rank"] for r in rows if r["rank"] is not None]
    assert ranks == sorted(ranks)
    report = str((first_run["out"] / "report.html").resolve())
    assert report in by_key[REPORT_ARTIFACT_KEY].data


@pytest.mark.system
def test_rerun_skips_ingested_exports_and_adds_a_complete_run(first_run, plant):
    before = first_run["state"].result()
    state = _scan(plant, first_run["db"], first_run["out"])
    assert state.is_completed(), state.message
    again = state.result()
    assert again["run_id"] != before["run_id"]
    assert again["ingest"]["rows_inserted"] == 0
    assert again["counts"] == before["counts"]
    assert again["new_faults"] == []          # same data, same faults: none is new
    with Store(first_run["db"], read_only=True) as store:
        runs = store.runs()
    assert runs["run_id"].to_list() == [before["run_id"], again["run_id"]]
    assert runs["status"].to_list() == ["complete", "complete"]


@pytest.mark.system
def test_failed_step_marks_the_run_failed(prefect_api, plant, tmp_path, monkeypatch):
    import valvediag.pipelines.nightly

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(valvediag.pipelines.nightly, "write_outputs", broken)
    state = _scan(plant, tmp_path / "plant.duckdb", tmp_path / "out")
    assert state.is_failed()
    with Store(tmp_path / "plant.duckdb", read_only=True) as store:
        runs = store.runs()
    assert runs["status"].to_list() == ["failed"]
    assert runs["finished_at"][0] is not None and "No space left" in runs["note"][0]


@pytest.mark.system
def test_an_output_path_that_is_a_file_fails_before_any_work(prefect_api, plant, tmp_path):
    blocker = tmp_path / "out"
    blocker.write_text("a file where the output directory should go")
    state = _scan(plant, tmp_path / "plant.duckdb", blocker)
    assert state.is_failed()
    assert "cannot write the outputs here" in str(state.result(raise_on_failure=False))
    if (tmp_path / "plant.duckdb").exists():
        with Store(tmp_path / "plant.duckdb", read_only=True) as store:
            assert store.runs().height == 0 and store.counts()["samples"] == 0


@pytest.mark.system
def test_no_export_fails_before_touching_the_store(prefect_api, plant, tmp_path):
    from valvediag.pipelines.nightly import nightly_scan

    state = nightly_scan(exports=str(tmp_path / "nothing" / "*.csv"),
                         loops=str(plant / "loops.csv"), db=str(tmp_path / "p.duckdb"),
                         out=str(tmp_path / "out"), return_state=True)
    assert state.is_failed()
    exc = state.result(raise_on_failure=False)
    assert isinstance(exc, FileNotFoundError)
    assert "no export file matches" in str(exc) and "nothing" in str(exc)
    assert not (tmp_path / "p.duckdb").exists()
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ valvediag scan
def _cli(args, capsys, monkeypatch):
    monkeypatch.delenv(CONSOLE_LEVEL, raising=False)   # the command sets it; undo afterwards
    rc = main(["scan", *map(str, args)])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.system
def test_scan_json_prints_every_loop(prefect_api, plant, registry_loops, tmp_path, capsys,
                                     monkeypatch):
    rc, out, err = _cli(["--exports", plant / "exports", "--loops", plant / "loops.csv",
                         "--db", tmp_path / "p.duckdb", "--out", tmp_path / "out", "--json",
                         "--window-hours", "3", "--method", "robust"], capsys, monkeypatch)
    assert rc == 0, err
    doc = json.loads(out)
    assert list(doc) == ["run_id", "status", "status_note", "ingest", "loops"]
    assert doc["status"] == "complete" and doc["status_note"] == ""
    assert {f["file"] for f in doc["ingest"]} == {str(p) for p in (plant / "exports").iterdir()}
    assert all(f["rows_read"] == f["rows_stored"] > 0 and f["rows_quarantined"] == 0
               and f["error"] is None for f in doc["ingest"])
    assert doc == json.loads((tmp_path / "out" / "verdicts.json").read_text())
    assert sorted(v["loop"] for v in doc["loops"]) == registry_loops
    for v in doc["loops"]:
        assert list(v)[:len(VERDICT_KEYS)] == list(VERDICT_KEYS)
        assert v["verdict"] in VERDICTS
        assert 0.0 <= v["confidence"] <= 1.0
        assert (v["rank"] is not None) == (v["verdict"] in ACTION_VERDICTS)
    assert "analysing loops" in err       # the progress display (stderr)


@pytest.mark.system
def test_scan_summary_names_the_outputs(prefect_api, plant, tmp_path, capsys, monkeypatch):
    rc, out, err = _cli(["--exports", plant / "exports", "--loops", plant / "loops.csv",
                         "--db", tmp_path / "p.duckdb", "--out", tmp_path / "out"],
                        capsys, monkeypatch)
    assert rc == 0, err
    assert f"{N_LOOPS} loops" in out
    for name in ("report.html", "work_orders.csv", "verdicts.json"):
        assert str((tmp_path / "out" / name).resolve()) in out


@pytest.mark.system
def test_scan_with_an_unreadable_export_is_partial_and_exits_3(prefect_api, plant, tmp_path,
                                                               capsys, monkeypatch):
    bad = tmp_path / "garbled.csv"
    bad.write_text("foo,bar\n1,2\n")
    db = tmp_path / "p.duckdb"
    rc, out, err = _cli(["--exports", plant / "exports", bad, "--loops", plant / "loops.csv",
                         "--db", db, "--out", tmp_path / "out"], capsys, monkeypatch)
    assert rc == 3, err
    assert f"{N_LOOPS} loops" in out                      # the loops were still analysed
    line = [x for x in err.splitlines() if " is partial: " in x]
    assert len(line) == 1 and str(bad) in line[0]
    with Store(db, read_only=True) as s:
        run = s.runs().row(0, named=True)
    assert run["status"] == "partial" and str(bad) in run["note"]
    report = (tmp_path / "out" / "report.html").read_text(encoding="utf-8")
    assert "This run is partial." in report and str(bad) in report


@pytest.mark.system
def test_scan_failed_flow_is_one_line_error(prefect_api, plant, tmp_path, capsys, monkeypatch):
    import valvediag.pipelines.nightly

    def broken(*args, **kwargs):
        raise RuntimeError("disk full\nwhile writing report.html")

    monkeypatch.setattr(valvediag.pipelines.nightly, "write_outputs", broken)
    rc, out, err = _cli(["--exports", plant / "exports", "--loops", plant / "loops.csv",
                         "--db", tmp_path / "p.duckdb", "--out", tmp_path / "out"],
                        capsys, monkeypatch)
    assert rc == 2
    assert out == ""
    assert err.strip().splitlines()[-1] == ("valvediag scan: error: the scan failed: "
                                            "disk full while writing report.html")
    with Store(tmp_path / "p.duckdb", read_only=True) as store:
        assert store.runs()["status"].to_list() == ["failed"]


@pytest.fixture
def bad(plant, tmp_path):
    """Valid arguments, to be spoiled one at a time."""
    (tmp_path / "bad_loops.csv").write_text("name;pv\nLIC1;LIC1.PV\n")
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_dir").mkdir()
    return {"--exports": str(plant / "exports"), "--loops": str(plant / "loops.csv"),
            "--db": str(tmp_path / "p.duckdb"), "--out": str(tmp_path / "out")}


@pytest.mark.parametrize("change, words", [
    ({"--loops": "{tmp}/missing.csv"}, ["missing.csv", "no such file"]),
    ({"--loops": "{tmp}/bad_loops.csv"}, ["bad_loops.csv"]),
    ({"--exports": "{tmp}/nothing/*.csv"}, ["nothing/*.csv", "no file matches"]),
    ({"--timezone": "Mars/Olympus"}, ["Mars/Olympus", "unknown time zone"]),
    ({"--window-hours": "-2"}, ["window_hours", "positive"]),
    ({"--end": "2026-11-01T00:00:00"}, ["no time zone"]),
    ({"--end": "yesterday"}, ["yesterday", "ISO 8601"]),
    ({"--db": "{tmp}/a_dir"}, ["a_dir", "is a directory"]),
    ({"--db": "{tmp}/a_file"}, ["a_file", "cannot open the store"]),
    ({"--out": "{tmp}/a_file"}, ["a_file", "not a directory"]),
    ({"--processes": "-1"}, ["--processes -1", "threads"]),
])
def test_scan_bad_input_one_line_error(bad, change, words, tmp_path, capsys, monkeypatch):
    args = dict(bad)
    args.update({k: v.format(tmp=tmp_path) for k, v in change.items()})
    rc, out, err = _cli([x for kv in args.items() for x in kv], capsys, monkeypatch)
    assert rc == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("valvediag scan: error: ")
    for w in words:
        assert w in lines[0]


def test_scan_locked_store_one_line_error(bad, tmp_path, capsys, monkeypatch):
    db = tmp_path / "locked.duckdb"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from valvediag.store import Store; "
         "s = Store(sys.argv[1]); print('open', flush=True); time.sleep(60)", str(db)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        rc, out, err = _cli([x for kv in {**bad, "--db": str(db)}.items() for x in kv],
                            capsys, monkeypatch)
    finally:
        holder.kill()
        holder.wait()
    assert rc == 2
    assert len(err.strip().splitlines()) == 1
    assert "locked.duckdb" in err and "another process" in err


@pytest.mark.system
def test_scan_console_script_exits_2_with_one_line(tmp_path):
    exe = Path(sys.executable).with_name("valvediag")
    t0 = time.perf_counter()
    res = subprocess.run([str(exe), "scan", "--exports", str(tmp_path / "none*.csv"),
                          "--loops", str(tmp_path / "loops.csv"), "--db", str(tmp_path / "d"),
                          "--out", str(tmp_path / "o")], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 2
    assert res.stdout == ""
    assert res.stderr.strip().splitlines() == [
        f"valvediag scan: error: --loops {tmp_path / 'loops.csv'}: no such file"]
    assert time.perf_counter() - t0 < 60     # fails before any Prefect start-up


def test_library_and_cli_do_not_import_prefect():
    code = ("import sys, valvediag, valvediag.scan, valvediag.report.outputs, valvediag.store.ingest, "
            "valvediag.store, valvediag.cli; valvediag.cli.build_parser(); "
            "print(sorted(m for m in sys.modules if m == 'prefect' or m.startswith('prefect.')))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert res.stdout.strip() == "[]"
