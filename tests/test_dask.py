"""The nightly-scan flow with the per-loop analysis on Dask (prefect-dask's DaskTaskRunner),
and on worker processes without Dask (Prefect's ProcessPoolTaskRunner).

A real ``distributed.LocalCluster`` of two worker processes. The workers read
the Parquet partitions that the flow exports (they never open the DuckDB
file) and the results must be identical to the single-process run. A worker
killed with SIGKILL while it analyses a loop is replaced and the loop is run
again. Uses the session's Prefect server (``prefect_api`` in conftest.py).
"""
from __future__ import annotations

import json
import os
import signal
import threading
import time

import pytest

from valvediag.store.database import Store
from valvediag.store.partitions import partition_root
from valvediag.synth.plant import synth_plant

N_LOOPS, DAYS, SAMPLE_TIME, SEED = 8, 0.125, 5.0, 11


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    out = tmp_path_factory.mktemp("dask_plant")
    synth_plant(N_LOOPS, DAYS, SAMPLE_TIME, out, seed=SEED)
    return out


def _scan(plant, work, **kw):
    from valvediag.pipelines.nightly import nightly_scan

    state = nightly_scan(exports=str(plant / "exports"), loops=str(plant / "loops.csv"),
                         db=str(work / "plant.duckdb"), out=str(work / "out"),
                         return_state=True, **kw)
    assert state.is_completed(), state.message
    return state.result()


def _stored(work) -> dict:
    """Everything a run stored, without its run id: verdicts and episodes."""
    with Store(work / "plant.duckdb", read_only=True) as store:
        run_id = store.runs()["run_id"][-1]
        verdicts = store.verdicts(run_id).drop("run_id").sort("loop").to_dicts()
        episodes = store.episodes(run_id).drop("run_id").to_dicts()
    return {"verdicts": verdicts, "episodes": episodes}


def _loops_json(work) -> list:
    return json.loads((work / "out" / "verdicts.json").read_text())["loops"]


@pytest.fixture(scope="module")
def single(prefect_api, plant, tmp_path_factory):
    """The reference: the flow on threads of this process, reading DuckDB."""
    work = tmp_path_factory.mktemp("single")
    return work, _scan(plant, work)


@pytest.mark.system
def test_two_local_workers_give_the_single_process_results(single, plant, tmp_path):
    ref_work, ref = single
    summary = _scan(plant, tmp_path, workers=2)
    assert summary["counts"] == ref["counts"]
    assert _loops_json(tmp_path) == _loops_json(ref_work)
    assert _stored(tmp_path) == _stored(ref_work)
    with Store(tmp_path / "plant.duckdb", read_only=True) as store:
        assert store.runs()["status"].to_list() == ["complete"]
    # the run's partitions are gone; the directory for them is left empty
    assert list(partition_root(tmp_path / "plant.duckdb").iterdir()) == []


@pytest.mark.system
def test_worker_processes_give_the_thread_results(single, plant, tmp_path, monkeypatch):
    """The default analysis of a plant: batches of loops on Prefect's process pool."""
    import valvediag.pipelines.runners as runners

    started = []

    class Recorded(runners.ProcessPoolTaskRunner):
        def __enter__(self):
            started.append(self._max_workers)
            return super().__enter__()

    monkeypatch.setattr(runners, "MIN_LOOPS_FOR_PROCESSES", 1)   # 8 loops are few
    monkeypatch.setattr(runners, "ProcessPoolTaskRunner", Recorded)
    ref_work, ref = single
    summary = _scan(plant, tmp_path, processes=2)
    assert started == [2]
    assert len(runners.loop_batches(N_LOOPS, 2)) == N_LOOPS    # one loop per batch here
    assert summary["counts"] == ref["counts"]
    assert _loops_json(tmp_path) == _loops_json(ref_work)
    assert _stored(tmp_path) == _stored(ref_work)


@pytest.mark.parametrize("n, workers", [(1, 2), (8, 2), (100, 2), (1000, 2), (1000, 16), (37, 3)])
def test_loop_batches_cover_every_loop_once_in_order(n, workers):
    from valvediag.pipelines.runners import BATCH_LOOPS, BATCHES_PER_WORKER, loop_batches

    batches = loop_batches(n, workers)
    assert [k for b in batches for k in b] == list(range(n))
    assert max(len(b) for b in batches) <= BATCH_LOOPS
    assert len(batches) >= min(n, BATCHES_PER_WORKER * workers)


@pytest.mark.system
def test_killed_worker_is_replaced_and_its_loop_run_again(single, plant, tmp_path):
    """SIGKILL the worker process busy with a loop; the scan still completes, identically."""
    from distributed import Client, LocalCluster

    ref_work, _ = single
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster, Client(cluster) as client:
        client.wait_for_workers(2)
        killed = {}

        def kill_a_busy_worker():
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not killed:
                for addr, keys in client.processing().items():
                    if keys:
                        pid = client.run(os.getpid, workers=[addr])[addr]
                        os.kill(pid, signal.SIGKILL)
                        killed.update(addr=addr, pid=pid, key=sorted(keys)[0])
                        return
                time.sleep(0.02)

        killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
        killer.start()
        summary = _scan(plant, tmp_path, dask_address=cluster.scheduler_address)
        killer.join(timeout=5)
        assert killed, "no worker was seen busy with a loop"
        # the scheduler sent the killed worker's loop to a worker again
        log = [t for t in cluster.scheduler.transition_log if t[0] == killed["key"]]
        assert sum(1 for t in log if t[2] == "processing") >= 2, log
        assert summary["loops"] == N_LOOPS
    assert _loops_json(tmp_path) == _loops_json(ref_work)
    assert _stored(tmp_path) == _stored(ref_work)
