"""Benchmark: the morning report of a 5,000-loop plant with 200 loops flagged.

The results are built, not scanned (the scan has its own benchmark): a small
synthetic plant (``synth_plant``, 1 day at 5 s) is scanned once, and its
results are copied under new names up to the plant size, the loops needing
action up to the flagged count, so every flagged loop carries real plot data
(trend and diagnosis) and the report draws real figures for all of them. A
store holds one earlier run of the same plant, so the history across runs is
read and compared for every loop.

Timed: :func:`valvediag.report.outputs.write_outputs` (history query, work orders,
``verdicts.json`` and the HTML report with its figures). Printed: seconds,
report size [MB], figures, workers, ``os.cpu_count()``.

Measured on 2 shared cores: 87.7 s and 22.8 MB with the matplotlib figures
(2 figure workers), 5.8 s and 18.0 MB with the figures written as SVG
directly (:mod:`valvediag.report.plot`, one process).

Usage::

    python benchmarks/bench_report.py [--loops 5000] [--flagged 200] [--workers N]
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from valvediag.io.registry import read_loops_csv  # noqa: E402
from valvediag.report.outputs import write_outputs  # noqa: E402
from valvediag.scan.loop import analyse_loop, load_loop_frames
from valvediag.scan.plan import plan_loops
from valvediag.scan.plant import persist_results, rank_results
from valvediag.scan.types import ScanConfig
from valvediag.store.database import Store  # noqa: E402
from valvediag.synth.plant import synth_plant  # noqa: E402

BASE_LOOPS, DAYS, SAMPLE_TIME, SEED = 24, 1.0, 5.0, 7


def base_results(work: Path):
    """Scan a small synthetic plant; return its results (with plot data)."""
    from valvediag.store.ingest import ingest_exports

    plant = work / "plant"
    synth_plant(BASE_LOOPS, DAYS, SAMPLE_TIME, plant, seed=SEED)
    loops, _ = read_loops_csv(plant / "loops.csv")
    with Store(work / "base.duckdb") as store:
        ingest_exports(store, [str(plant / "exports")])
        jobs = plan_loops(store, loops, ScanConfig())
        return [analyse_loop(j, load_loop_frames(store, j), ScanConfig()) for j in jobs]


def plant_results(base, n_loops: int, n_flagged: int):
    """``n_loops`` results, ``n_flagged`` of them needing action, copied from ``base``."""
    flagged = [r for r in base if r.needs_action and r.detail is not None
               and r.detail.trend is not None]
    healthy = [r for r in base if not r.needs_action]
    if not flagged or not healthy:
        raise SystemExit("the base plant has no flagged or no healthy loop; change SEED")
    out = []
    for k in range(n_loops):
        src = flagged[k % len(flagged)] if k < n_flagged else healthy[k % len(healthy)]
        out.append(dataclasses.replace(src, loop=f"{src.loop}-{k:05d}",
                                       description=f"{src.description} (copy {k})"))
    return rank_results(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops", type=int, default=5000)
    ap.add_argument("--flagged", type=int, default=200)
    ap.add_argument("--workers", type=int, default=None,
                    help="figure processes (default: automatic)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_report_") as tmp:
        work = Path(tmp)
        t0 = time.perf_counter()
        results = plant_results(base_results(work), args.loops, args.flagged)
        setup_s = time.perf_counter() - t0
        db = work / "plant.duckdb"
        now = dt.datetime.now(dt.timezone.utc)
        with Store(db) as store:       # one earlier run: history for every loop
            prev = store.start_run(run_id="bench-previous")
            persist_results(store, prev, results)
            store.finish_run(prev, "complete")
            run_id = store.start_run(run_id="bench-current")
            persist_results(store, run_id, results)
        info = {"plant": "benchmark plant", "window_start": results[0].window_start,
                "window_end": results[0].window_end, "generated": now, "db": str(db)}
        t1 = time.perf_counter()
        paths = write_outputs(results, work / "out", run_id=run_id, run_info=info,
                              workers=args.workers)
        render_s = time.perf_counter() - t1
        mb = paths["report"].stat().st_size / 1e6
        n_flagged = sum(r.needs_action for r in results)
        from valvediag.report.figures import _auto_workers

        workers = args.workers or _auto_workers(n_flagged)
        print(f"report of {len(results)} loops, {n_flagged} flagged (figures drawn): "
              f"{render_s:.1f} s, {mb:.1f} MB, {workers} figure worker(s), "
              f"os.cpu_count()={os.cpu_count()} (set-up {setup_s:.0f} s not counted)")
        print(f"  work orders {paths['work_orders'].stat().st_size / 1e3:.0f} kB, "
              f"verdicts.json {paths['verdicts'].stat().st_size / 1e6:.1f} MB")
        ok = render_s <= 60 and mb <= 25
        print(f"  target <= 60 s and <= 25 MB: {'met' if ok else 'MISSED'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
