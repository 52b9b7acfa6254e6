"""A wheel of the project works outside the repository.

The wheel is built from the checkout, installed into a new virtual environment
in a temporary directory (its dependencies come from the project's own
environment through a ``.pth`` line, so nothing is downloaded), and
``valvediag synth-plant`` and ``valvediag scan`` run there from a directory
outside the repository: the SQL, the templates and the flow must all come from
the installed package.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.system

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "-q", "-w", str(out), str(ROOT)], check=True, capture_output=True, text=True)
    wheels = list(out.glob("valvediag-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def test_the_wheel_holds_the_sql_the_templates_and_the_flows(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for p in (ROOT / "sql").glob("*.sql"):
        assert f"valvediag/sql/{p.name}" in names, p.name
    for p in (ROOT / "reports").rglob("*"):
        if p.is_file() and p.suffix in (".j2", ".css", ".js"):
            assert f"valvediag/templates/{p.relative_to(ROOT / 'reports').as_posix()}" in names, p
    for p in ("nightly.py", "runners.py", "serve.py"):
        assert f"valvediag/pipelines/{p}" in names
    assert not any(n.startswith(("pipelines/", "sql/", "reports/", "tests/")) for n in names)


def test_an_installed_wheel_scans_a_plant_outside_the_repository(wheel, tmp_path, prefect_api):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                                "['purelib'])"], check=True, capture_output=True,
                               text=True).stdout.strip())
    # the project's dependencies, without its editable install (a plain path line in a
    # .pth file is not processed for .pth files of its own)
    (site / "project_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    "--target", str(site), str(wheel)], check=True, capture_output=True, text=True)
    console = env_dir / "bin" / "valvediag"
    console.write_text(f"#!{py}\nimport sys\nfrom valvediag.cli import main\nsys.exit(main())\n")
    console.chmod(0o755)
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env.update(PREFECT_SERVER_ANALYTICS_ENABLED="false", DO_NOT_TRACK="1", MPLBACKEND="Agg",
               PREFECT_API_URL=prefect_api, PREFECT_HOME=str(tmp_path / "prefect"))
    where = subprocess.run([str(py), "-c", "import valvediag.store.database as d, valvediag; "
                            "print(valvediag.__file__); print(d.SQL_DIR)"], cwd=work, env=env,
                           check=True, capture_output=True, text=True).stdout.split()
    assert all(Path(p).resolve().is_relative_to(env_dir.resolve()) for p in where), where

    def run(*args):
        return subprocess.run([str(console), *args], cwd=work, env=env, capture_output=True,
                              text=True, timeout=600)

    synth = run("synth-plant", "--loops", "6", "--days", "0.1", "--sample-time", "5",
                "--out", "plant")
    assert synth.returncode == 0, synth.stderr
    scan = run("scan", "--exports", "plant/exports", "--loops", "plant/loops.csv",
               "--db", "plant.duckdb", "--out", "out")
    assert scan.returncode == 0, scan.stderr
    doc = json.loads((work / "out" / "verdicts.json").read_text())
    loops = [e["loop"] for e in doc["loops"]]
    assert len(loops) == 6
    html = (work / "out" / "report.html").read_text()
    assert all(name in html for name in loops)
    assert (work / "out" / "work_orders.csv").is_file()
