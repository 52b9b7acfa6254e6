"""Benchmark: plant-scan throughput (loops/s) for one-day loops at 1 s and at 10 s.

For each sampling rate a synthetic plant (:func:`valvediag.synth.plant.synth_plant`,
one day, seed 1) is written to a temporary directory. A child process then
ingests its exports into a fresh DuckDB store and scans every loop the way
:func:`valvediag.scan.run.run_scan` does, timing separately

* the ingest (CSV -> DuckDB),
* reading each loop's window from the store (``load_loop_frames``),
* the numerics (``analyse_loop``: alignment, quality, episodes,
  classification), after one warm-up loop so that numba compilation (or
  loading its cache) is not counted,
* the same read + numerics on a thread pool of ``os.cpu_count()`` workers
  (each task opening the store read-only), to show whether threads would help
  (the numba kernels hold the GIL).

The ingest and the scan run in separate child processes, so each peak memory
(maximum resident set size) is that of one stage; the scan holds one loop at a
time. Prints plain lines and, with ``--json``, one JSON document. Not a timed
test; about 1.5 minutes on two cores.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

CASES = {"1s": (30, 1.0), "10s": (120, 10.0)}   # name -> (loops, sample time [s])


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _child_ingest(plant_dir: str, db: str) -> None:
    """Ingest one plant into a fresh store; print JSON figures."""
    from valvediag.store.database import Store
    from valvediag.store.ingest import ingest_exports

    with Store(db) as store:
        t = time.perf_counter()
        report = ingest_exports(store, Path(plant_dir) / "exports")
        ingest_s = time.perf_counter() - t
        rows = store.counts()["samples"]
    print(json.dumps({"rows": rows, "files": report.files, "ingest_s": ingest_s,
                      "ingest_peak_mb": _peak_mb()}))


def _child_scan(plant_dir: str, db: str) -> None:
    """Scan every loop of an ingested plant, one at a time as run_scan does; print JSON."""
    from valvediag.io.registry import read_loops_csv
    from valvediag.scan.loop import analyse_loop, load_loop_frames
    from valvediag.scan.plan import plan_loops
    from valvediag.scan.types import ScanConfig
    from valvediag.store.database import Store

    cfg = ScanConfig()
    loops, _ = read_loops_csv(Path(plant_dir) / "loops.csv")
    with Store(db, read_only=True) as store:
        jobs = plan_loops(store, loops, cfg)
        t = time.perf_counter()
        analyse_loop(jobs[0], load_loop_frames(store, jobs[0]), cfg)  # numba compile/cache
        warm_s = time.perf_counter() - t
        read_s = analyse_s = 0.0
        serial = []
        for job in jobs:
            t = time.perf_counter()
            frames = load_loop_frames(store, job)
            t1 = time.perf_counter()
            serial.append(analyse_loop(job, frames, cfg).verdict)
            t2 = time.perf_counter()
            read_s, analyse_s = read_s + t1 - t, analyse_s + t2 - t1
    serial_peak = _peak_mb()
    workers = os.cpu_count() or 1
    t = time.perf_counter()
    with ThreadPoolExecutor(workers) as pool:   # each task opens the store read-only
        threaded = list(pool.map(lambda j: analyse_loop(j, load_loop_frames(db, j), cfg).verdict,
                                 jobs))
    threaded_s = time.perf_counter() - t
    assert threaded == serial
    print(json.dumps({"loops": len(jobs), "read_s": read_s, "warmup_s": warm_s,
                      "analyse_s": analyse_s, "threads_s": threaded_s, "threads": workers,
                      "scan_peak_mb": serial_peak}))


def _run(mode: str, plant: Path, db: Path) -> dict:
    cmd = [sys.executable, __file__, "--child", mode, str(plant), str(db)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES),
                        help="sampling rates to run (default both)")
    parser.add_argument("--json", action="store_true", help="also print the figures as JSON")
    parser.add_argument("--child", nargs=3, metavar=("MODE", "PLANT", "DB"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        mode, plant_dir, db = args.child
        (_child_ingest if mode == "ingest" else _child_scan)(plant_dir, db)
        return

    from valvediag.synth.plant import synth_plant

    print(f"cpu_count: {os.cpu_count()}")
    out = {"cpu_count": os.cpu_count(), "cases": {}}
    with tempfile.TemporaryDirectory(prefix="bench_scan_") as tmp:
        for name in args.cases:
            n, st = CASES[name]
            t = time.perf_counter()
            plant = synth_plant(n, 1.0, st, Path(tmp) / name, seed=1)
            gen_s = time.perf_counter() - t
            db = Path(tmp) / f"{name}.duckdb"
            res = {"generate_s": gen_s, "sample_time_s": st,
                   **_run("ingest", plant.out_dir, db), **_run("scan", plant.out_dir, db)}
            out["cases"][name] = res
            k = res["loops"]
            scan_s = res["read_s"] + res["analyse_s"]
            print(f"scan {name}: {k} one-day loops at {st:g} s, {res['rows']:,} samples "
                  f"(generated in {gen_s:.1f} s)")
            print(f"  ingest:              {res['ingest_s']:6.1f} s  "
                  f"({res['rows'] / res['ingest_s']:,.0f} rows/s, peak {res['ingest_peak_mb']:.0f} MB)")
            print(f"  read windows:        {res['read_s']:6.1f} s  ({k / res['read_s']:.1f} loops/s)")
            print(f"  analyse:             {res['analyse_s']:6.1f} s  "
                  f"({k / res['analyse_s']:.2f} loops/s; warm-up {res['warmup_s']:.1f} s)")
            print(f"  scan (read+analyse): {scan_s:6.1f} s  ({k / scan_s:.2f} loops/s, "
                  f"peak {res['scan_peak_mb']:.0f} MB)")
            print(f"  same on {res['threads']} threads:   {res['threads_s']:6.1f} s  "
                  f"({k / res['threads_s']:.2f} loops/s)")
    if args.json:
        print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
