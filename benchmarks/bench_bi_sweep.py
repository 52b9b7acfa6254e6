"""Accuracy sweep of the one-loop classifier, both BI methods side by side.

Loops drawn from the parameter ranges of Farenzena & Trierweiler (2012)
(``valvediag.paper.scenarios``): stiction (Kano), backlash, and linear oscillations
(a sinusoidal load on a well-tuned loop, or a loop tuned near its stability
limit and rung by load noise). Each loop is simulated once (20 cycles after
start-up) and recorded at 5, 10, 20, 50 and 100 samples per period with white
PV noise of 0, 0.5, 1, 3 and 5 % of the oscillation amplitude. The classifier
runs on exactly the same records with ``method='robust'`` and
``method='paper'``; a loop counts as correct when its verdict is its true
class (``undecided`` counts as wrong).

The robust thresholds were calibrated on another seed (101); this sweep uses
seed 0.

``--export average`` records every sample as the mean over its sample time
(a historian's average export) and tells the classifier so
(``pv_averaged``); ``--export average-untold`` reads the same records as
values at their time stamps, as the scan does without ``sampling = average``
in ``loops.csv``.

Usage: python benchmarks/bench_bi_sweep.py [--loops N] [--workers W]
       [--export point|average|average-untold]
"""
from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

SPP = (5, 10, 20, 50, 100)
NOISE = (0.0, 0.5, 1.0, 3.0, 5.0)
KINDS = ("stiction", "backlash", "linear")


def _work(args):
    kind, n, seed, cycles, averaged, told = args
    from valvediag import classify_loop
    from valvediag.paper.scenarios import draw_cases, record

    cases = draw_cases(kind, n, seed=seed, cycles=cycles)
    from valvediag import backlash_index
    out = []   # (spp, noise, method, correct); method 'literal' = paper BI alone
    for i, c in enumerate(cases):
        rng = np.random.default_rng(seed * 1000 + i)
        for spp in SPP:
            for nz in NOISE:
                pv, op, h = record(c, spp, nz, rng, averaged=averaged)
                for method in ("robust", "paper"):
                    d = classify_loop(pv, op, sample_time=h, process_type="integrating",
                                      method=method, pv_averaged=told)
                    out.append((spp, nz, method, d.verdict == c.truth))
                # the literal estimator alone, as the paper uses it: no screening
                try:
                    v = backlash_index(pv, h, method="paper").verdict
                except ValueError:
                    v = "insufficient-data"
                out.append((spp, nz, "literal", v == c.truth))
    return kind, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops", type=int, default=100, help="loops per class (default 100)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--export", choices=("point", "average", "average-untold"), default="point",
                    help="record each sample as the value at its time stamp (default), or as "
                         "the mean over its sample time, read as such ('average') or as "
                         "values ('average-untold')")
    args = ap.parse_args()
    averaged = args.export != "point"
    told = args.export == "average"
    t0 = time.perf_counter()
    # split each class into chunks so that the workers stay busy
    chunks = []
    per = max(1, args.loops // (2 * args.workers))
    for k, kind in enumerate(KINDS):
        done = 0
        j = 0
        while done < args.loops:
            n = min(per, args.loops - done)
            chunks.append((kind, n, args.seed * 100 + k * 10 + j, 20.0, averaged, told))
            done += n
            j += 1
    res = {kind: [] for kind in KINDS}
    with ProcessPoolExecutor(args.workers) as ex:
        for kind, out in ex.map(_work, chunks):
            res[kind].extend(out)
    secs = time.perf_counter() - t0
    print(f"BI sweep: {args.loops} loops per class ({', '.join(KINDS)}), "
          f"{os.cpu_count()} cores, {secs:.0f} s, export: {args.export}")
    print("% correct (verdict = true class); columns: robust | paper")
    head = f"{'spp':>5s} {'noise':>6s} | " + " | ".join(f"{k[:9]:>9s} r/p" for k in KINDS) + " |   mix r/p"
    print(head)
    print("-" * len(head))
    acc = {}
    for spp in SPP:
        for nz in NOISE:
            cells = []
            mix = {"robust": [], "paper": []}
            for kind in KINDS:
                pair = []
                for m in ("robust", "paper"):
                    v = [ok for s, n, mm, ok in res[kind] if s == spp and n == nz and mm == m]
                    a = 100.0 * np.mean(v)
                    acc[(kind, spp, nz, m)] = a
                    mix[m].append(a)
                    pair.append(a)
                cells.append(f"{pair[0]:5.0f} {pair[1]:5.0f}")
            print(f"{spp:5d} {nz:5.1f}% | " + " | ".join(f"{c:>13s}" for c in cells)
                  + f" | {np.mean(mix['robust']):5.0f} {np.mean(mix['paper']):5.0f}")
    print("\nthe literal estimator alone (paper BI, no oscillation or linearity screen), % correct:")
    print(f"{'spp':>5s} {'noise':>6s} | " + " | ".join(f"{k[:9]:>9s}" for k in KINDS) + " |   mix")
    for spp in SPP:
        for nz in NOISE:
            vals = [100.0 * np.mean([ok for s, n, mm, ok in res[kind]
                                     if s == spp and n == nz and mm == "literal"]) for kind in KINDS]
            print(f"{spp:5d} {nz:5.1f}% | " + " | ".join(f"{v:9.0f}" for v in vals)
                  + f" | {np.mean(vals):5.0f}")
    print("\nacceptance region (>= 20 samples per period, noise <= 3 %), robust, worst cell per class:")
    for kind in KINDS:
        worst = min(acc[(kind, s, n, "robust")] for s in SPP if s >= 20 for n in NOISE if n <= 3)
        pooled = np.mean([acc[(kind, s, n, "robust")] for s in SPP if s >= 20 for n in NOISE if n <= 3])
        print(f"  {kind:9s} worst {worst:5.1f} %   mean {pooled:5.1f} %")


if __name__ == "__main__":
    main()
