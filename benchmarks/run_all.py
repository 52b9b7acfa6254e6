"""Run every benchmark and print its figures (``make bench``)."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ["bench_reproduce.py", "bench_bi_sweep.py", "bench_ingest.py", "bench_scan.py",
         "bench_report.py", "bench_workbench.py", "bench_plant.py"]
#: Benchmarks run a second time with these arguments.
AGAIN = {"bench_realistic.py": ["--valve-position"]}


def main():
    print(f"valvediag benchmarks on {os.cpu_count()} cores, python {sys.version.split()[0]}\n",
          flush=True)
    failed = []
    for name in ORDER + sorted(p.name for p in HERE.glob("bench_*.py") if p.name not in ORDER):
        path = HERE / name
        if not path.exists():
            continue
        for args in ([], AGAIN.get(name)):
            if args is None:
                continue
            print(f"== {' '.join([name, *args])}", flush=True)
            t0 = time.perf_counter()
            rc = subprocess.run([sys.executable, str(path), *args], cwd=HERE.parent).returncode
            print(f"   ({time.perf_counter() - t0:.0f} s)\n", flush=True)
            if rc:
                failed.append(" ".join([name, *args]))
    if failed:
        print("failed: " + ", ".join(failed))
        sys.exit(1)


if __name__ == "__main__":
    main()
