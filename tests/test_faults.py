"""Faults with real processes: scans killed with SIGKILL, and two scans on one store.

Each scan here is a separate ``valvediag scan`` process reporting to the
session's Prefect server (``prefect_api`` in conftest.py). The reference is
one clean scan of the same plant. After a kill, the next scan must complete
with exactly the reference's samples (no duplicate, none lost) and verdicts,
and the killed run must end ``aborted``, never ``complete``.
"""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from valvediag.store.database import Store
from valvediag.store.lock import ScanLock, ScanLockedError
from valvediag.synth.plant import synth_plant

N_LOOPS, DAYS, SAMPLE_TIME, SEED = 8, 0.125, 5.0, 11
TIMEOUT_S = 240


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    out = tmp_path_factory.mktemp("faults_plant")
    # small export groups: several files, so an ingest can be killed between files
    synth_plant(N_LOOPS, DAYS, SAMPLE_TIME, out, seed=SEED, group_size=2,
                formats=("long-csv", "parquet"))
    return out


@pytest.fixture(scope="module")
def reference(prefect_api, plant, tmp_path_factory):
    """One clean scan (in this process): the samples and verdicts every other run must match."""
    from valvediag.pipelines.nightly import nightly_scan

    work = tmp_path_factory.mktemp("reference")
    state = nightly_scan(exports=str(plant / "exports"), loops=str(plant / "loops.csv"),
                         db=str(work / "plant.duckdb"), out=str(work / "out"),
                         return_state=True)
    assert state.is_completed(), state.message
    return _contents(work / "plant.duckdb")


def _contents(db: Path) -> dict:
    """What a store holds, comparable between stores: counts, keys, latest verdicts."""
    with Store(db, read_only=True) as store:
        counts = store.counts()
        runs = store.runs()
        complete = runs.filter(runs["status"] == "complete")["run_id"].to_list()
        verdicts = (store.verdicts(complete[-1]).drop("run_id").sort("loop").to_dicts()
                    if complete else [])
        return {"samples": counts["samples"], "quarantine": counts["quarantine"],
                "ingested_files": counts["ingested_files"],
                "duplicate_keys": store.duplicate_keys(), "verdicts": verdicts,
                "runs": list(zip(runs["status"].to_list(), runs["owner"].to_list()))}


def _env(api: str) -> dict:
    env = dict(os.environ, PREFECT_API_URL=api, PREFECT_SERVER_ANALYTICS_ENABLED="false",
               DO_NOT_TRACK="1", MPLBACKEND="Agg")
    env.pop("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", None)
    return env


def _scan_args(plant: Path, work: Path, *extra: str) -> list[str]:
    return ["scan", "--exports", str(plant / "exports"), "--loops", str(plant / "loops.csv"),
            "--db", str(work / "plant.duckdb"), "--out", str(work / "out"), *extra]


# A `valvediag scan` whose ingest reads every file in slices of 400 rows and says on stdout
# when a slice's transaction has committed, so a test can kill it in the middle of a file.
# (The ingest parses the next slice while it writes this one, so the reader running
# ahead says nothing about what is committed.)
_SLICED_SCAN = textwrap.dedent("""
    import contextlib, sys
    import valvediag.store.ingest as ig
    from valvediag.store import Store
    _iter, _write, _transaction = ig.iter_export, ig._write_parsed, Store.transaction
    written = []
    def sliced(path, **kw):
        kw["chunk_rows"] = 400
        return _iter(path, **kw)
    def write(store, parsed, *counters):
        written.append(parsed.path)
        return _write(store, parsed, *counters)
    @contextlib.contextmanager
    def transaction(self):
        before = len(written)
        with _transaction(self) as store:
            yield store
        if len(written) > before:
            print("committed", written[-1], len(written), flush=True)
    ig.iter_export, ig._write_parsed, Store.transaction = sliced, write, transaction
    from valvediag.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _start(args: list[str], api: str, *, sliced: bool = False) -> subprocess.Popen:
    code = _SLICED_SCAN if sliced else "import sys; from valvediag.cli import main; " \
                                       "sys.exit(main(sys.argv[1:]))"
    return subprocess.Popen([sys.executable, "-c", code, *args], env=_env(api),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _kill_when(proc: subprocess.Popen, stream, predicate) -> str:
    """SIGKILL ``proc`` (and its process group) at the first line of ``stream`` matching."""
    deadline = time.monotonic() + TIMEOUT_S
    seen = []
    for line in stream:
        seen.append(line)
        if predicate(line):
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
            return line
        if time.monotonic() > deadline:
            break
    proc.kill()
    raise AssertionError(f"never saw the moment to kill; output:\n{''.join(seen)[-3000:]}")


def _run(args: list[str], api: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "valvediag", *args], env=_env(api),
                          capture_output=True, text=True, timeout=TIMEOUT_S)


@pytest.mark.system
def test_scan_killed_during_analysis_is_aborted_and_the_next_completes(
        prefect_api, plant, reference, tmp_path):
    proc = _start(_scan_args(plant, tmp_path), prefect_api)
    # the progress display (stderr, not a terminal) prints each tenth of the loops
    _kill_when(proc, proc.stderr, lambda l: l.startswith("analysing loops: ")
               and not l.startswith("analysing loops: 0/"))
    assert proc.returncode == -signal.SIGKILL
    with Store(tmp_path / "plant.duckdb", read_only=True) as store:
        runs = store.runs()
    assert runs["status"].to_list() == ["running"]          # never 'complete'
    assert runs["owner"][0].startswith(f"{proc.pid}@")

    res = _run(_scan_args(plant, tmp_path), prefect_api)
    assert res.returncode == 0, res.stderr
    got = _contents(tmp_path / "plant.duckdb")
    assert [s for s, _ in got["runs"]] == ["aborted", "complete"]
    assert got["duplicate_keys"] == 0
    assert {k: got[k] for k in ("samples", "quarantine", "ingested_files", "verdicts")} == \
           {k: reference[k] for k in ("samples", "quarantine", "ingested_files", "verdicts")}
    with Store(tmp_path / "plant.duckdb", read_only=True) as store:
        aborted = store.runs().row(0, named=True)
        assert "died" in aborted["note"] and aborted["finished_at"] is not None
        assert store.verdicts(aborted["run_id"]).is_empty()


@pytest.mark.system
def test_scan_killed_in_the_middle_of_a_file_is_completed_by_the_next(
        prefect_api, plant, reference, tmp_path):
    proc = _start(_scan_args(plant, tmp_path), prefect_api, sliced=True)
    line = _kill_when(proc, proc.stdout, lambda l: l.startswith("committed ")
                      and int(l.split()[-1]) >= 2)
    assert proc.returncode == -signal.SIGKILL, line
    with Store(tmp_path / "plant.duckdb", read_only=True) as store:
        partial = store.counts()
        assert store.duplicate_keys() == 0
        assert store.runs().is_empty()                # killed before the run was planned
    assert 0 < partial["samples"] < reference["samples"]    # slices of a file were committed
    assert partial["ingested_files"] < reference["ingested_files"]

    res = _run(_scan_args(plant, tmp_path), prefect_api)
    assert res.returncode == 0, res.stderr
    got = _contents(tmp_path / "plant.duckdb")
    assert [s for s, _ in got["runs"]] == ["complete"]
    assert got["duplicate_keys"] == 0
    for k in ("samples", "quarantine", "ingested_files", "verdicts"):
        assert got[k] == reference[k], k


@pytest.mark.system
def test_two_scans_at_once_one_runs_the_other_fails_in_one_line(
        prefect_api, plant, reference, tmp_path):
    procs = [_start(_scan_args(plant, tmp_path), prefect_api) for _ in range(2)]
    results = [(p.wait(timeout=TIMEOUT_S), p.stdout.read(), p.stderr.read()) for p in procs]
    codes = sorted(rc for rc, _, _ in results)
    assert codes == [0, 2], results
    rc, out, err = next(r for r in results if r[0] == 2)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("valvediag scan: error: ")
    assert "another scan is running on this store" in lines[0]
    assert str(tmp_path / "plant.duckdb") in lines[0]
    assert out == ""
    got = _contents(tmp_path / "plant.duckdb")
    assert [s for s, _ in got["runs"]] == ["complete"]
    assert got["duplicate_keys"] == 0
    for k in ("samples", "quarantine", "ingested_files", "verdicts"):
        assert got[k] == reference[k], k


# ------------------------------------------------------------------- the lock itself
_HOLD = textwrap.dedent("""
    import sys, time
    from valvediag.store.lock import ScanLock
    with ScanLock(sys.argv[1]):
        print("held", flush=True)
        time.sleep(float(sys.argv[2]))
""")


def _holder(db: Path, seconds: float) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(db), str(seconds)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_second_scan_waits_a_bounded_time_for_the_lock(tmp_path):
    db = tmp_path / "plant.duckdb"
    holder = _holder(db, 1.5)
    try:
        t0 = time.monotonic()
        with pytest.raises(ScanLockedError) as err:
            ScanLock(db, timeout=0.3).acquire()
        assert 0.25 < time.monotonic() - t0 < 5
        msg = str(err.value)
        assert "\n" not in msg and str(db) in msg and f"pid {holder.pid}" in msg
        assert "after waiting 0.3 s" in msg
        with ScanLock(db, timeout=30) as lock:       # waits for the holder to finish
            assert lock.held
            assert lock.holder()["pid"] == os.getpid()
    finally:
        holder.kill()
        holder.wait()


_TRY = textwrap.dedent("""
    import sys
    from valvediag.store.lock import ScanLock, ScanLockedError
    try:
        ScanLock(sys.argv[1]).acquire()
        print("got it")
    except ScanLockedError:
        print("busy")
""")


def _other_process_gets(db: Path) -> bool:
    out = subprocess.run([sys.executable, "-c", _TRY, str(db)], capture_output=True, text=True,
                         timeout=60).stdout.strip()
    assert out in ("got it", "busy"), out
    return out == "got it"


def test_lock_is_reentrant_in_one_process_and_held_until_the_last_release(tmp_path):
    """The command line holds the lock around the flow, which takes it again."""
    db = tmp_path / "plant.duckdb"
    outer = ScanLock(db).acquire()
    inner = ScanLock(db, timeout=0).acquire()       # same process: granted at once
    assert outer.held and inner.held
    inner.release()
    assert not _other_process_gets(db)              # the outer one still holds it
    outer.release()
    assert _other_process_gets(db)


@pytest.mark.system
def test_lock_of_a_killed_process_is_free_at_once(tmp_path):
    db = tmp_path / "plant.duckdb"
    holder = _holder(db, 60)
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    with ScanLock(db, timeout=0) as lock:
        assert lock.held


def test_stale_running_run_is_aborted_and_old_store_migrated(tmp_path):
    import duckdb

    db = tmp_path / "old.duckdb"
    con = duckdb.connect(str(db))     # a store made before runs.owner/note and 'aborted'
    con.execute("CREATE TABLE runs (run_id VARCHAR PRIMARY KEY, started_at TIMESTAMPTZ NOT "
                "NULL, finished_at TIMESTAMPTZ, status VARCHAR NOT NULL CHECK (status IN "
                "('running', 'complete', 'failed')), window_start TIMESTAMPTZ, window_end "
                "TIMESTAMPTZ, exports VARCHAR, params JSON)")
    con.execute("INSERT INTO runs VALUES ('r1', now(), now(), 'complete', NULL, NULL, NULL, "
                "NULL), ('r2', now(), NULL, 'running', NULL, NULL, NULL, NULL)")
    con.close()
    with ScanLock(db), Store(db) as store:
        aborted = store.abort_stale_runs()
        runs = store.runs()
    assert aborted == [{"run_id": "r2", "owner": None}]
    assert runs["status"].to_list() == ["complete", "aborted"]
    assert runs["finished_at"][1] is not None


def test_store_made_before_partial_runs_is_migrated_and_keeps_owner_and_note(tmp_path):
    import duckdb

    db = tmp_path / "before_partial.duckdb"
    con = duckdb.connect(str(db))     # owner/note and 'aborted', but no 'partial' status
    con.execute("CREATE TABLE runs (run_id VARCHAR PRIMARY KEY, started_at TIMESTAMPTZ NOT "
                "NULL, finished_at TIMESTAMPTZ, status VARCHAR NOT NULL CHECK (status IN "
                "('running', 'complete', 'failed', 'aborted')), window_start TIMESTAMPTZ, "
                "window_end TIMESTAMPTZ, exports VARCHAR, params JSON, owner VARCHAR, "
                "note VARCHAR)")
    con.execute("INSERT INTO runs VALUES ('r1', now(), now(), 'failed', NULL, NULL, NULL, "
                "NULL, '12@host', 'disk full'), ('r2', now(), NULL, 'running', NULL, NULL, "
                "NULL, NULL, '13@host', NULL)")
    con.close()
    with Store(db) as store:
        store.finish_run("r2", "partial", note="x.csv: unreadable")
        runs = store.runs()
    assert runs["status"].to_list() == ["failed", "partial"]
    assert runs["owner"].to_list() == ["12@host", "13@host"]
    assert runs["note"].to_list() == ["disk full", "x.csv: unreadable"]
    with Store(db) as store, pytest.raises(ValueError, match="run status must be one of"):
        store.finish_run("r2", "half-done")


def _children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of the live child processes of ``pid``."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.append((int(d.name), cmd))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.system
def test_a_scan_killed_by_sigkill_does_not_leave_its_temporary_server_running(plant, tmp_path):
    env = _env("unused")
    env.pop("PREFECT_API_URL")          # the scan starts its own temporary server
    env["PREFECT_HOME"] = str(tmp_path / "prefect_home")
    proc = subprocess.Popen([sys.executable, "-m", "valvediag", *_scan_args(plant, tmp_path)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        # the server, once its watchdog runs (from the moment the server answers)
        deadline, server, watchdog = time.monotonic() + TIMEOUT_S, None, None
        while watchdog is None and time.monotonic() < deadline and proc.poll() is None:
            children = _children(proc.pid)
            server = next((p for p, cmd in children if "uvicorn" in cmd), None)
            watchdog = next((p for p, cmd in children if "getppid" in cmd), None)
            time.sleep(0.1)
        assert server is not None and watchdog is not None, "no temporary server seen"
        proc.send_signal(signal.SIGKILL)            # the scan alone, not its process group
        proc.wait(timeout=30)
        assert _alive(server)
        deadline = time.monotonic() + 30
        while _alive(server) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(server), "the temporary server outlived the killed scan"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.system
def test_a_failed_scan_prints_one_line_and_no_traceback(prefect_api, tmp_path):
    # every export unreadable: the run fails; the command says so in one line (the
    # tracebacks stay in the Prefect API's logs and behind --verbose)
    (tmp_path / "exports").mkdir()
    (tmp_path / "exports" / "garbled.csv").write_text("foo,bar\n1,2\n")
    (tmp_path / "loops.csv").write_text("loop,pv_tag,op_tag\nLIC1,LIC1.PV,LIC1.OP\n")
    res = _run(["scan", "--exports", str(tmp_path / "exports"), "--loops",
                str(tmp_path / "loops.csv"), "--db", str(tmp_path / "s.duckdb"), "--out",
                str(tmp_path / "out")], prefect_api)
    assert res.returncode == 2, res.stderr
    lines = [x for x in res.stderr.splitlines() if not x.startswith(("ingesting", "analysing"))]
    assert "Traceback" not in res.stderr and len(lines) == 1, res.stderr
    assert lines[0].startswith("valvediag scan: error: the scan failed: no export reached "
                               "the store: ") and "garbled.csv" in lines[0]
