"""End to end: the nightly deployment on a real Prefect server and a real process worker.

What ``make serve`` starts, in a private ``PREFECT_HOME`` on a free loopback
port: ``prefect server start`` (SQLite), the ``valvediag`` process work pool,
``prefect deploy --name nightly`` from the repository's ``prefect.yaml`` (with
the data paths of a small synthetic plant) and ``prefect worker start``. The
run is triggered with exactly ``prefect deployment run 'nightly-scan/nightly'``
and must complete, write ``verdicts.json`` with every loop and leave the
DuckDB ``runs`` row ``complete``. Server and worker are always stopped.

Runtime: about a minute (server start, worker poll, a fresh flow-run process);
a cold numba cache adds up to a minute to the flow run.
"""
from __future__ import annotations

import json
import re
import subprocess
import time

import pytest

from valvediag.pipelines import serve
from valvediag.io.registry import read_loops_csv
from valvediag.store.database import VERDICTS, Store
from valvediag.synth.plant import synth_plant

pytestmark = pytest.mark.system   # a Prefect server, a process worker and the deployment

# at least valvediag.pipelines.runners.MIN_LOOPS_FOR_PROCESSES loops: the flow run analyses them
# on worker processes of the process worker's flow run, as a plant's nightly run does
N_LOOPS, DAYS, SAMPLE_TIME, SEED = 16, 4 / 24, 5.0, 5
RUN_TIMEOUT_S = 300
TERMINAL = {"COMPLETED", "FAILED", "CRASHED", "CANCELLED"}


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    """Server + pool + deployment + worker; torn down whatever happens."""
    root = tmp_path_factory.mktemp("deployment")
    plant = root / "plant"
    synth_plant(N_LOOPS, DAYS, SAMPLE_TIME, plant, seed=SEED)
    home = root / "prefect_home"
    logs = root / "logs"
    params = {"exports": str(plant / "exports"), "loops": str(plant / "loops.csv"),
              "db": str(root / "data" / "plant.duckdb"), "out": str(root / "out")}
    server = worker = None
    try:
        server, api_url = serve.start_server(home, port=serve.free_port(), ui=False,
                                             log_path=logs / "server.log", timeout=180)
        env = serve.prefect_env(home, api_url, {"PREFECT_WORKER_QUERY_SECONDS": "1",
                                                "PREFECT_WORKER_PREFETCH_SECONDS": "5"})
        serve.create_pool(env)
        serve.deploy(env, params, timezone="UTC")
        worker = serve.start_worker(env, log_path=logs / "worker.log", name="e2e-worker")
        yield {"api_url": api_url, "env": env, "params": params, "plant": plant, "logs": logs}
    finally:
        serve.stop(worker)
        serve.stop(server)


def _wait_terminal(api_url: str, flow_run_id: str, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        run = serve.api_get(api_url, f"/flow_runs/{flow_run_id}")
        if run["state"]["type"] in TERMINAL or time.monotonic() > deadline:
            return run
        time.sleep(1.0)


def test_deployment_is_on_the_process_pool_with_a_nightly_schedule(stack):
    dep = serve.api_get(stack["api_url"], "/deployments/name/nightly-scan/nightly")
    assert dep["work_pool_name"] == serve.POOL
    assert [s["schedule"]["cron"] for s in dep["schedules"]] == ["0 2 * * *"]
    assert {k: dep["parameters"][k] for k in stack["params"]} == stack["params"]
    pool = serve.api_get(stack["api_url"], f"/work_pools/{serve.POOL}")
    assert pool["type"] == "process"


def test_prefect_deployment_run_completes_and_writes_results(stack):
    t0 = time.monotonic()
    res = subprocess.run([serve.prefect_exe(), "deployment", "run", "nightly-scan/nightly"],
                         env=stack["env"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    m = re.search(r"UUID:\s*([0-9a-f-]{36})", res.stdout)
    assert m, res.stdout
    run = _wait_terminal(stack["api_url"], m.group(1), RUN_TIMEOUT_S)
    worker_log = (stack["logs"] / "worker.log").read_text(errors="replace")
    assert run["state"]["type"] == "COMPLETED", (
        f"flow run {run['state']['type']} after {time.monotonic() - t0:.0f} s: "
        f"{run['state'].get('message')}\n--- worker log ---\n{worker_log[-6000:]}")

    loops, _ = read_loops_csv(stack["plant"] / "loops.csv")
    out = stack["params"]["out"]
    verdicts = json.loads(open(f"{out}/verdicts.json").read())
    assert sorted(v["loop"] for v in verdicts["loops"]) == sorted(l.loop for l in loops)
    assert all(v["verdict"] in VERDICTS for v in verdicts["loops"])
    for name in ("work_orders.csv", "report.html"):
        assert open(f"{out}/{name}", "rb").read(), name
    with Store(stack["params"]["db"], read_only=True) as store:
        runs = store.runs()
        stored = store.verdicts(verdicts["run_id"])
    assert runs["run_id"].to_list() == [verdicts["run_id"]]
    assert runs["status"].to_list() == ["complete"]
    assert stored.height == len(loops)

    # batches of several loops: the worker-process path, not the threads of a small plant
    from valvediag.pipelines.runners import MIN_LOOPS_FOR_PROCESSES

    assert N_LOOPS >= MIN_LOOPS_FOR_PROCESSES
    tasks = serve.api_post(stack["api_url"], "/task_runs/filter",
                           {"flow_runs": {"id": {"any_": [run["id"]]}}})
    batches = [t["name"] for t in tasks if t["name"].startswith("analyse-")]
    assert batches and all(re.search(r"\(\d+ loops\)$", n) for n in batches), batches

    arts = serve.api_post(stack["api_url"], "/artifacts/filter",
                          {"artifacts": {"flow_run_id": {"any_": [run["id"]]}}})
    assert {a["key"] for a in arts} == {"valvediag-ranked-loops", "valvediag-report"}
