#!/usr/bin/env python
"""Start, stop or inspect the local nightly-scan service (``make serve``).

``start`` runs a Prefect server (SQLite under ``$PREFECT_HOME``, loopback,
port 4200 or a free one) and a process worker in the background, creates the
work pool and deploys ``nightly-scan/nightly`` from ``prefect.yaml`` with the
data paths given here. Running it again redeploys (new paths) and keeps the
running server and worker. ``stop`` ends both. ``status`` says what runs.

State lives in ``$PREFECT_HOME/serve/``: ``server.pid``, ``worker.pid``,
``api_url``, ``env`` (source it to talk to the server) and the logs.
``api-url`` prints the server's API URL when it answers (``make demo`` uses
it to record its run there).
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
from pathlib import Path

from valvediag.pipelines import serve

DEFAULTS = {"exports": "data/exports", "loops": "data/loops.csv",
            "db": "data/valvediag.duckdb", "out": "out/nightly"}


def _home() -> Path:
    return Path(os.environ.get("PREFECT_HOME", serve.REPO_ROOT / ".prefect")).resolve()


def _state() -> Path:
    return _home() / "serve"


def _pid(name: str) -> int | None:
    f = _state() / f"{name}.pid"
    try:
        pid = int(f.read_text())
        os.killpg(pid, 0)
        # the pid may have been reused since: only a prefect process is ours
        cmdline = Path(f"/proc/{pid}/cmdline")
        if cmdline.parent.parent.is_dir() and b"prefect" not in cmdline.read_bytes():
            return None
    except (OSError, ValueError):
        return None
    return pid


def _api_url() -> str | None:
    f = _state() / "api_url"
    return f.read_text().strip() if f.exists() else None


def _abs(path: str) -> str:
    return path if os.path.isabs(path) else str(serve.REPO_ROOT / path)


def cmd_start(args) -> int:
    state = _state()
    state.mkdir(parents=True, exist_ok=True)
    api_url = _api_url()
    server = _pid("server")
    if server and api_url:
        serve.wait_healthy(api_url, timeout=30)
        print(f"Prefect server already running (pid {server}) at {api_url}")
    else:
        port = args.port or serve.free_port(preferred=4200)
        proc, api_url = serve.start_server(_home(), port=port, log_path=state / "server.log")
        (state / "server.pid").write_text(str(proc.pid))
        (state / "api_url").write_text(api_url)
        print(f"Prefect server started (pid {proc.pid}) at {api_url}; "
              f"log {state / 'server.log'}")
    env = serve.prefect_env(_home(), api_url)
    (state / "env").write_text(f"export PREFECT_API_URL={api_url}\n")
    serve.create_pool(env)
    params = {k: _abs(getattr(args, k) or os.environ.get(f"VALVEDIAG_{k.upper()}") or v)
              for k, v in DEFAULTS.items()}
    tz = args.schedule_timezone or serve.local_timezone()
    serve.deploy(env, params, timezone=tz)
    print(f"Deployed {serve.DEPLOYMENT} on work pool '{serve.POOL}' (cron 0 2 * * *, {tz})")
    for k, v in params.items():
        print(f"  {k:8s} {v}")
    missing = [params[k] for k in ("exports", "loops") if not glob.glob(params[k])]
    if missing:
        print(f"  note: {', '.join(missing)} not found yet: put the historian exports and "
              f"loops.csv there, or run 'make serve EXPORTS=... LOOPS=...'")
    worker = _pid("worker")
    if worker:
        print(f"Process worker already running (pid {worker})")
    else:
        proc = serve.start_worker(env, log_path=state / "worker.log")
        (state / "worker.pid").write_text(str(proc.pid))
        print(f"Process worker started (pid {proc.pid}); log {state / 'worker.log'}")
    print(f"""
Trigger the nightly scan now:
    export PREFECT_API_URL={api_url}      # or: source {state / 'env'}
    {Path(sys.executable).parent / 'prefect'} deployment run '{serve.DEPLOYMENT}'
Dashboard: {api_url.removesuffix('/api')}    Stop: {sys.executable} {Path(__file__)} stop""")
    return 0


def cmd_stop(args) -> int:
    for name in ("worker", "server"):
        pid = _pid(name)
        if pid:
            serve.stop(pid)
            print(f"stopped the Prefect {name} (pid {pid})")
        (_state() / f"{name}.pid").unlink(missing_ok=True)
    (_state() / "api_url").unlink(missing_ok=True)
    return 0


def cmd_status(args) -> int:
    for name in ("server", "worker"):
        pid = _pid(name)
        print(f"{name}: {'running, pid %d' % pid if pid else 'not running'}")
    if _api_url():
        print(f"api: {_api_url()}")
    return 0


def cmd_api_url(args) -> int:
    api_url = _api_url()
    if not (_pid("server") and api_url):
        return 1
    try:
        serve.wait_healthy(api_url, timeout=5)
    except RuntimeError:
        return 1
    print(api_url)
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("start", help="start server and worker, deploy nightly-scan/nightly")
    for k, v in DEFAULTS.items():
        s.add_argument(f"--{k}", help=f"flow parameter {k} (default $VALVEDIAG_{k.upper()} "
                                      f"or {v}; relative to the repository)")
    s.add_argument("--port", type=int, help="server port (default 4200 if free, else any)")
    s.add_argument("--schedule-timezone", help="IANA zone of the 02:00 schedule "
                                               "(default the machine's)")
    s.set_defaults(func=cmd_start)
    sub.add_parser("stop", help="stop server and worker").set_defaults(func=cmd_stop)
    sub.add_parser("status", help="what runs").set_defaults(func=cmd_status)
    sub.add_parser("api-url", help="print the API URL if the server answers (exit 1 if not)"
                   ).set_defaults(func=cmd_api_url)
    args = p.parse_args(argv)
    try:
        return args.func(args)
    except RuntimeError as exc:
        print(f"serve: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
