"""Speed of ``valvediag reproduce-paper``: scenarios per second, both methods.

Runs the grids of Tables 1-3 of Farenzena & Trierweiler (2012) as printed
(73,920 + 13,440 + 840 = 88,200 scenarios). The first run of a fresh install
also compiles the kernels; that time is reported separately.

Usage: python benchmarks/bench_reproduce.py [--methods paper,robust]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time


def timed_run(method: str) -> tuple[float, dict]:
    from valvediag.paper.tables import reproduce_paper

    t0 = time.perf_counter()
    res = reproduce_paper(method)
    return time.perf_counter() - t0, res.to_json()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="paper,robust")
    args = ap.parse_args()
    n = 73_920 + 13_440 + 840
    # warm the compiled kernels in a child process (first-use compile time)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from valvediag.paper import reproduce_paper; "
                    "reproduce_paper('paper', tables=(3,)); reproduce_paper('robust', tables=(3,))"],
                   check=True)
    warm = time.perf_counter() - t0
    print(f"reproduce-paper: {n:,} scenarios (Tables 1-3 as printed), {os.cpu_count()} cores")
    print(f"  kernel start-up incl. compile on a cold cache, Table 3 both methods: {warm:.1f} s")
    for method in args.methods.split(","):
        secs, doc = timed_run(method)
        t1, t2 = doc["table1"], doc["table2"]
        t3 = " ".join(f"{r['sample_time']:g}s:{r['backlash']:.0f}%" for r in doc["table3"])
        print(f"  {method:6s}: {secs:6.1f} s  {n / secs:8,.0f} scenarios/s   "
              f"T1 stiction {t1['stiction']:.2f}% undecided {t1['undecided']:.2f}% "
              f"backlash {t1['backlash']:.2f}% | T2 backlash {t2['backlash']:.2f}% | T3 {t3}")


if __name__ == "__main__":
    main()
