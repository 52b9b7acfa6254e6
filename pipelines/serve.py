"""
Run the nightly deployment locally: a Prefect server, a process worker, and
``prefect deploy`` of ``nightly-scan/nightly`` from ``prefect.yaml``.

``make serve`` (through ``scripts/serve.py``) and ``tests/test_deployment.py``
both use these helpers, so the test exercises exactly what a user starts.
Everything goes through the ``prefect`` command line of the running Python
environment; this module does not import Prefect.

Notes
-----
* The server binds to loopback only and stores its state in SQLite under
  ``PREFECT_HOME`` (``<PREFECT_HOME>/prefect.db``).
* Every child gets ``PREFECT_SERVER_ANALYTICS_ENABLED=false`` and
  ``DO_NOT_TRACK=1``: the plant machines have no internet.
* Server and worker run in their own process groups (``start_new_session``),
  so :func:`stop` ends each of them with its children (the worker's flow-run
  subprocesses) and nothing else.
"""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Mapping
from pathlib import Path

__all__ = ["DEPLOYMENT", "POOL", "REPO_ROOT", "free_port", "prefect_env", "prefect_exe",
           "start_server", "wait_healthy", "create_pool", "deploy", "start_worker", "stop",
           "local_timezone", "api_get", "api_post"]

#: The deployment that ``prefect deployment run`` triggers.
DEPLOYMENT = "nightly-scan/nightly"
#: The process work pool of ``prefect.yaml``.
POOL = "valvediag"
#: The repository root: where ``prefect.yaml`` is and where flow runs start.
REPO_ROOT = Path(__file__).resolve().parent.parent


def free_port(host: str = "127.0.0.1", preferred: int | None = None) -> int:
    """A TCP port that is free on ``host``.

    Parameters
    ----------
    host : str
        Interface to bind, loopback by default.
    preferred : int, optional
        Returned when it is free (e.g. Prefect's usual 4200); otherwise the
        operating system picks one.
    """
    for port in ((preferred,) if preferred else ()) + (0,):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return s.getsockname()[1]
    raise OSError(f"no free port on {host}")


def prefect_exe() -> str:
    """The ``prefect`` command of the running Python environment."""
    exe = Path(sys.executable).with_name("prefect")
    return str(exe) if exe.exists() else "prefect"


def prefect_env(prefect_home: str | os.PathLike, api_url: str | None = None,
                extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment for a Prefect child process.

    Parameters
    ----------
    prefect_home : str or path-like
        ``PREFECT_HOME`` (profiles, the SQLite database, logs).
    api_url : str, optional
        ``PREFECT_API_URL`` of the server, e.g. ``http://127.0.0.1:4200/api``.
    extra : mapping, optional
        More variables (they win).

    Returns
    -------
    dict
        A copy of ``os.environ`` with these set.
    """
    env = dict(os.environ)
    env.update(PREFECT_HOME=os.fspath(prefect_home), PREFECT_SERVER_ANALYTICS_ENABLED="false",
               DO_NOT_TRACK="1", PYTHONUNBUFFERED="1")
    env.setdefault("MPLBACKEND", "Agg")
    if api_url:
        env["PREFECT_API_URL"] = api_url
    else:
        env.pop("PREFECT_API_URL", None)
    env.update(extra or {})
    return env


def _tail(path: str | os.PathLike, n: int = 20) -> str:
    try:
        lines = Path(path).read_text(errors="replace").splitlines()
    except OSError:
        return "(no log)"
    return "\n".join(lines[-n:])


def _spawn(args: list[str], env: Mapping[str, str], log_path: str | os.PathLike,
           cwd: str | os.PathLike | None = None) -> subprocess.Popen:
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "ab") as log:
        return subprocess.Popen(args, env=dict(env), cwd=cwd, stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)


def api_get(api_url: str, path: str, timeout: float = 10.0):
    """GET ``api_url + path`` and decode the JSON answer.

    Parameters
    ----------
    api_url : str
        ``http://host:port/api``.
    path : str
        E.g. ``/flow_runs/<id>``.
    timeout : float
        [s].
    """
    with urllib.request.urlopen(api_url + path, timeout=timeout) as resp:
        return json.load(resp)


def api_post(api_url: str, path: str, body: Mapping | None = None, timeout: float = 10.0):
    """POST JSON to ``api_url + path`` and decode the JSON answer.

    Parameters
    ----------
    api_url : str
        ``http://host:port/api``.
    path : str
        E.g. ``/artifacts/filter``.
    body : mapping, optional
        Request body (default ``{}``).
    timeout : float
        [s].
    """
    req = urllib.request.Request(api_url + path, data=json.dumps(body or {}).encode(),
                                 headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(req, timeout=timeout) as resp:
        return json.load(resp)


def wait_healthy(api_url: str, timeout: float = 120.0, proc: subprocess.Popen | None = None,
                 log_path: str | os.PathLike | None = None) -> None:
    """Wait until the server answers ``GET /health``.

    Parameters
    ----------
    api_url : str
        ``http://host:port/api``.
    timeout : float
        [s].
    proc : subprocess.Popen, optional
        The server process: fail at once if it exits.
    log_path : path-like, optional
        Its log, quoted in the error.

    Raises
    ------
    RuntimeError
        The server exited or did not answer in time; the message ends with
        the log's last lines.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"the Prefect server exited with code {proc.returncode}; "
                               f"log {log_path}:\n{_tail(log_path) if log_path else ''}")
        try:
            if api_get(api_url, "/health", timeout=2.0) is True:
                return
        except (OSError, ValueError):
            pass
        time.sleep(0.5)
    raise RuntimeError(f"the Prefect server at {api_url} did not answer within {timeout:.0f} s"
                       + (f"; log {log_path}:\n{_tail(log_path)}" if log_path else ""))


def start_server(prefect_home: str | os.PathLike, *, port: int, host: str = "127.0.0.1",
                 log_path: str | os.PathLike, ui: bool = True, timeout: float = 120.0
                 ) -> tuple[subprocess.Popen, str]:
    """Start ``prefect server start`` (SQLite under ``prefect_home``) and wait for it.

    Parameters
    ----------
    prefect_home : str or path-like
        ``PREFECT_HOME`` of the server; its database is ``prefect.db`` there.
    port : int
        TCP port (see :func:`free_port`).
    host : str
        Interface, loopback by default.
    log_path : str or path-like
        Where the server's output goes (appended).
    ui : bool
        Serve the dashboard too.
    timeout : float
        Seconds to wait for the health check (the first start migrates the
        database).

    Returns
    -------
    proc : subprocess.Popen
        The server, in its own process group.
    api_url : str
        ``http://host:port/api``.
    """
    api_url = f"http://{host}:{port}/api"
    args = [prefect_exe(), "server", "start", "--host", host, "--port", str(port),
            "--ui" if ui else "--no-ui"]
    proc = _spawn(args, prefect_env(prefect_home), log_path)
    try:
        wait_healthy(api_url, timeout, proc, log_path)
    except BaseException:
        stop(proc)
        raise
    return proc, api_url


def _run_cli(args: list[str], env: Mapping[str, str], cwd: str | os.PathLike | None = None,
             timeout: float = 180.0) -> subprocess.CompletedProcess:
    return subprocess.run([prefect_exe(), *args], env=dict(env), cwd=cwd, text=True,
                          capture_output=True, timeout=timeout, stdin=subprocess.DEVNULL)


def create_pool(env: Mapping[str, str], pool: str = POOL) -> None:
    """Create the process work pool unless it exists.

    Parameters
    ----------
    env : mapping
        From :func:`prefect_env` with the server's API URL.
    pool : str
        Work pool name.
    """
    if _run_cli(["work-pool", "inspect", pool], env).returncode == 0:
        return
    res = _run_cli(["work-pool", "create", pool, "--type", "process"], env)
    if res.returncode != 0 and "already exists" not in res.stdout + res.stderr:
        raise RuntimeError(f"prefect work-pool create {pool} failed:\n{res.stdout}{res.stderr}")


def deploy(env: Mapping[str, str], parameters: Mapping[str, object] | None = None, *,
           timezone: str | None = None, name: str = "nightly",
           project_dir: str | os.PathLike = REPO_ROOT) -> str:
    """``prefect deploy --name nightly`` from ``prefect.yaml`` in ``project_dir``.

    Parameters
    ----------
    env : mapping
        From :func:`prefect_env` with the server's API URL.
    parameters : mapping, optional
        Flow parameters that override those of ``prefect.yaml`` (``--params``).
    timezone : str, optional
        IANA zone of the cron schedule (``--timezone``); default that of
        ``prefect.yaml``.
    name : str
        Deployment name in ``prefect.yaml``.
    project_dir : path-like
        Where ``prefect.yaml`` is; flow runs start in this directory.

    Returns
    -------
    str
        The command's output.
    """
    args = ["--no-prompt", "deploy", "--name", name]
    if parameters:
        args += ["--params", json.dumps(dict(parameters))]
    if timezone:
        args += ["--timezone", timezone]
    res = _run_cli(args, env, cwd=project_dir)
    if res.returncode != 0:
        raise RuntimeError(f"prefect deploy failed:\n{res.stdout}{res.stderr}")
    return res.stdout


def start_worker(env: Mapping[str, str], *, log_path: str | os.PathLike, pool: str = POOL,
                 name: str | None = None, timeout: float = 60.0) -> subprocess.Popen:
    """Start ``prefect worker start --type process`` on ``pool`` and wait until it polls.

    Parameters
    ----------
    env : mapping
        From :func:`prefect_env` with the server's API URL; flow runs inherit
        it.
    log_path : str or path-like
        Where the worker's output (and its flow runs' logs) goes.
    pool : str
        Work pool name.
    name : str, optional
        Worker name.
    timeout : float
        Seconds to wait for the "started" line.

    Returns
    -------
    subprocess.Popen
        The worker, in its own process group.
    """
    args = [prefect_exe(), "worker", "start", "--pool", pool, "--type", "process"]
    if name:
        args += ["--name", name]
    start = Path(log_path).stat().st_size if Path(log_path).exists() else 0
    proc = _spawn(args, env, log_path, cwd=REPO_ROOT)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with open(log_path, "rb") as fh:
            fh.seek(start)
            if b"started!" in fh.read():
                return proc
        if proc.poll() is not None:
            raise RuntimeError(f"the Prefect worker exited with code {proc.returncode}; "
                               f"log {log_path}:\n{_tail(log_path)}")
        time.sleep(0.3)
    stop(proc)
    raise RuntimeError(f"the Prefect worker did not start within {timeout:.0f} s; "
                       f"log {log_path}:\n{_tail(log_path)}")


def stop(proc: subprocess.Popen | int | None, timeout: float = 15.0) -> None:
    """End a process group started here: SIGTERM, then SIGKILL after ``timeout``.

    Parameters
    ----------
    proc : subprocess.Popen or int or None
        The group leader (a Popen or a pid from a pid file); None does nothing.
    timeout : float
        [s] before SIGKILL.
    """
    if proc is None:
        return
    pid = proc.pid if isinstance(proc, subprocess.Popen) else int(proc)
    try:
        os.killpg(pid, signal.SIGTERM)
    except (ProcessLookupError, PermissionError):
        return
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if isinstance(proc, subprocess.Popen):
            if proc.poll() is not None:
                break
        else:
            try:
                os.killpg(pid, 0)
            except ProcessLookupError:
                return
        time.sleep(0.2)
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    if isinstance(proc, subprocess.Popen):
        proc.wait(timeout=5)


def local_timezone() -> str:
    """The machine's IANA time zone (``TZ``, then ``/etc/localtime``), else ``"UTC"``."""
    tz = os.environ.get("TZ", "").lstrip(":")
    if tz and "/" in tz and not tz.startswith("/"):
        return tz
    try:
        target = os.path.realpath("/etc/localtime")
    except OSError:
        return "UTC"
    marker = "zoneinfo/"
    if marker in target:
        name = target.split(marker, 1)[1]
        return "UTC" if name in ("Etc/UTC", "UTC", "Etc/Universal") else name
    return "UTC"
