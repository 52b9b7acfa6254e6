"""Speed of the model workbench: ``diagnose`` on one day of 1 s data.

Simulates one loop for 86,400 samples (integrating plant, or with
``--process self-regulating`` a first-order plant of 30 s; PI, a sticky Kano
valve with a dead time, PV noise) and times ``valvediag.workbench.diagnose`` from
the default starting model (the plant alone) and from a dead band, i.e. the
starting fit plus one refit per candidate effect. Target: at most 30 s on a
2-core machine. Compilation of the kernels is timed separately (a cold
cache only).

Usage: python benchmarks/bench_workbench.py [--repeat 2] [--start deadband]
       [--process self-regulating]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2, help="timed runs per starting model")
    ap.add_argument("--start", action="append", default=None,
                    help="starting effects, comma-separated (repeatable); default '' and 'deadband'")
    ap.add_argument("--process", choices=("integrating", "self-regulating"),
                    default="integrating")
    args = ap.parse_args()
    starts = args.start if args.start is not None else ["", "deadband"]

    t0 = time.perf_counter()
    from valvediag import simulate_loop
    from valvediag.workbench import diagnose, estimate_valve_size, forward_select, prepare_loop

    truth = dict(valve="kano", valve_params={"S": 3.0, "J": 1.0}, dead_time=12.0)
    plant = dict(kc=1.5, ti=90, tau=60) if args.process == "integrating" else \
        dict(process="self-regulating", process_gain=1.5, tau=30.0, kc=1.3, ti=20.0)
    sim = simulate_loop(**plant, sample_time=1.0, n_samples=86_400, sp_step=1.0,
                        noise_std=0.005, seed=7, **truth)
    # PV measurement noise (about 1 % of the oscillation) on top of the loop noise
    pv = sim.pv + 0.03 * np.random.default_rng(7).standard_normal(sim.pv.size)
    # warm-up on a short record compiles the kernels (or loads them from the cache)
    diagnose(pv[:4000], sim.op[:4000], 1.0, ("deadband",), process_type=args.process)
    warm = time.perf_counter() - t0
    print(f"workbench diagnose: one loop, {pv.size:,} samples at 1 s, {os.cpu_count()} cores "
          f"(os.cpu_count()), load average {os.getloadavg()[0]:.1f}")
    print(f"  truth: {truth}, {args.process} plant {plant}")
    print(f"  import + kernel start-up (compile on a cold cache): {warm:.1f} s")
    for start in starts:
        times = []
        for _ in range(args.repeat):
            t1 = time.perf_counter()
            sug = diagnose(pv, sim.op, 1.0, start, process_type=args.process)
            times.append(time.perf_counter() - t1)
        b = sug.base
        print(f"\n  start '{start or 'plant only'}': {min(times):.1f} s best, "
              f"{max(times):.1f} s worst of {len(times)} (target <= 30 s)")
        print(f"    base {b.model.name}: fit {b.fit_pct:.1f} %, held-out RMSE {b.heldout_rmse:.4g}, "
              f"horizon {b.data.horizon} samples")
        for i, s in enumerate(sug.items, 1):
            ps = ", ".join(f"{k}={v:.4g}" for k, v in s.params.items())
            print(f"    {i}. {s.effect:10s} {'accepted' if s.accepted else 'rejected'}  "
                  f"fit {s.fit_pct:6.1f} %  held-out RMSE {s.heldout_rmse:.4g}  "
                  f"({100 * s.gain:+.0f} %)  {ps}")
    t1 = time.perf_counter()
    ladder = forward_select(prepare_loop(pv, sim.op, 1.0), (), process_type=args.process)
    print(f"\n  forward selection (what 'valvediag model report' runs), from the plant alone: "
          f"{time.perf_counter() - t1:.1f} s")
    print("    " + ladder.table().replace("\n", "\n    "))
    t1 = time.perf_counter()
    size = estimate_valve_size(pv, sim.op, 1.0, "stiction", process_type=args.process)
    print(f"\n  estimate_valve_size(stiction), one day: {time.perf_counter() - t1:.1f} s -> {size}")


if __name__ == "__main__":
    main()
