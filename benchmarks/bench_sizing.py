"""Sizing of sticky and loose valves: recovered S, J and DB against the simulated ones.

Integrating loops of Farenzena & Trierweiler's (2012) ranges (PI controller,
integrator 1/(tau s) with tau 20-100 s, Kc and tau_I/tau from the paper's
grid) with a Kano valve (S 1, 2, 4, 6 %; J/S 0.1, 0.3, 0.6, 1) or a dead band
(DB 1, 2, 4, 6 %), simulated for a day with the controller at half the
historian's sample time. Each is recorded as a historian would: every second
controller sample (1, 3 or 10 s), white PV noise of 0.5, 1.5 or 3 % of the
oscillation amplitude (the OP gets the controller's response to it), and
either every sample stored or exception plus swinging-door compression (PV
deviation 1-3 % of the amplitude and at least 2 noise sigma; OP dead band
0.05-0.2 %), read back by linear interpolation. The size is what the scan
computes (``valvediag.workbench.size_window`` then ``estimate_valve_size``,
given the verdict).

Printed: median and 90th-percentile relative error of S, J and DB per cell,
the share of sticky valves sized with J ~ 0 (J < 0.05 S), and the count of
sticky valves with J/S >= 0.3 sized with J < 0.2 S. The targets hold at
noise <= 3 % and >= 20 samples per period.

Usage: python benchmarks/bench_sizing.py [--seed N] [--workers W]
"""
from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

S_VALUES = (1.0, 2.0, 4.0, 6.0)
JS_VALUES = (0.1, 0.3, 0.6, 1.0)
DB_VALUES = (1.0, 2.0, 4.0, 6.0)
SAMPLE_TIMES = (1.0, 3.0, 10.0)
NOISE_PCT = (0.5, 1.5, 3.0)
COMPRESSED = (False, True)
DAY = 86_400.0


def simulate(h: float, seed: int, noise_model: str = "loop"):
    """One day of every valve of the grid at every noise level, controller at h/2.

    Returns a list of cases (dicts with the valve, the noise and the
    controller-rate PV and OP).
    """
    from valvediag.models.closedloop import simulate_loop
    from valvediag.paper.tables import KC_GRID, TI_RATIO_GRID

    rng = np.random.default_rng(seed)
    valves = [("kano", {"S": S, "J": r * S}) for S in S_VALUES for r in JS_VALUES]
    valves += [("backlash", {"DB": d}) for d in DB_VALUES]
    m = len(valves)
    tau = rng.uniform(20.0, 100.0, m)
    kc = rng.choice(KC_GRID, m)
    ti = rng.choice(TI_RATIO_GRID, m) * tau
    band_factor = rng.uniform(5.0, 8.0, m)
    names = np.array([v for v, _ in valves], dtype=object)
    vp = {k: np.array([p.get(k, 0.0) for _, p in valves]) for k in ("S", "J", "DB")}
    hc = h / 2.0

    def run(sel, kind, noise=0.0, band=0.0):
        keys = ("S", "J") if kind == "kano" else ("DB",)
        return simulate_loop(kc=kc[sel], ti=ti[sel], tau=tau[sel], sample_time=hc, duration=DAY,
                             valve=kind, valve_params={k: vp[k][sel] for k in keys}, sp_step=1.0,
                             noise_std=noise, valve_noise_band=band if kind == "kano" else 0.0,
                             seed=int(rng.integers(1 << 31)))

    cases = []
    for kind in ("kano", "backlash"):
        sel = np.flatnonzero(names == kind)
        clean = run(sel, kind)
        n0 = clean.pv.shape[1] // 5                                   # start-up
        amp = 0.5 * (np.percentile(clean.pv[:, n0:], 99, axis=1)
                     - np.percentile(clean.pv[:, n0:], 1, axis=1))
        for noise_pct in NOISE_PCT:
            sigma = noise_pct / 100.0 * amp
            if noise_model == "loop":
                # measurement noise seen by the controller; the valve's actuator
                # does not reverse on the OP noise it causes (about kc sigma)
                sim = run(sel, kind, sigma, band_factor[sel] * kc[sel] * sigma)
                pvs, ops = sim.pv, sim.op
            else:
                # noise added to the clean record afterwards: the OP gets
                # the controller's proportional response, which the valve never saw
                n = rng.standard_normal(clean.pv.shape) * sigma[:, None]
                pvs, ops = clean.pv + n, clean.op - kc[sel, None] * n
            for j, i in enumerate(sel):
                cases.append(dict(kind=kind, params=valves[i][1], noise=noise_pct,
                                  sigma=float(sigma[j]), amp=float(amp[j]),
                                  pv=pvs[j, n0:], op=ops[j, n0:]))
    return cases


def record(case, compressed, rng):
    """Historian record: every 2nd controller sample, optionally compressed."""
    from valvediag.synth.plant import exception_deadband, swinging_door

    pv = case["pv"][::2].copy()
    op = case["op"][::2].copy()
    if compressed:
        t = np.arange(pv.size, dtype=float)
        dev = max(rng.uniform(0.01, 0.03) * case["amp"], 2.0 * case["sigma"])
        exc = np.flatnonzero(exception_deadband(pv, dev / 2))
        keep = exc[swinging_door(pv[exc], dev, t=exc.astype(float))]
        pv = np.interp(t, keep, pv[keep])
        kop = np.flatnonzero(exception_deadband(op, rng.uniform(0.05, 0.2)))
        op = np.interp(t, kop, op[kop])
    return pv, op


def _period(pv, h):
    from valvediag.analysis.oscillation import acf_period

    return float(acf_period(pv)[0]) * h


def _work(args):
    h, seed, noise_model = args
    from valvediag.workbench import estimate_valve_size, size_window

    rng = np.random.default_rng(seed + 1)
    rows = []
    for case in simulate(h, seed, noise_model):
        for comp in COMPRESSED:
            pv, op = record(case, comp, rng)
            period = _period(pv, h)
            a, k = size_window(pv.size, h, period)
            fault = "stiction" if case["kind"] == "kano" else "backlash"
            t0 = time.perf_counter()
            out = estimate_valve_size(pv[a::k], op[a::k], k * h, fault)
            rows.append(dict(h=h, noise=case["noise"], comp=comp, spp=period / h, fault=fault,
                             truth=case["params"], est={key: out.get(key) for key in
                                                         ("S", "J", "DB")},
                             conf=out["confidence"], secs=time.perf_counter() - t0))
    return rows


def _stats(x):
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if not x.size:
        return "   -      -      -  "
    a = np.abs(x)
    return f"{100 * np.median(a):5.1f}  {100 * np.percentile(a, 90):5.1f} {100 * np.median(x):+6.1f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=7, help="seed of the loop draws (default 7)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--noise-model", choices=("loop", "posthoc"), default="loop",
                    help="measurement noise fed back through the loop (default), or added "
                         "to a clean record afterwards (the OP gets -Kc n)")
    args = ap.parse_args()
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    t0 = time.perf_counter()
    jobs = [(h, args.seed + int(h), args.noise_model) for h in SAMPLE_TIMES]
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as ex:
        rows = [r for part in ex.map(_work, jobs) for r in part]
    wall = time.perf_counter() - t0
    for r in rows:
        t, e = r["truth"], r["est"]
        if r["fault"] == "stiction":
            r["eS"] = e["S"] / t["S"] - 1.0
            r["eJ"] = e["J"] / t["J"] - 1.0
            r["j0"] = e["J"] < 0.05 * e["S"] if np.isfinite(e["S"]) else True
            r["jlow"] = t["J"] >= 0.3 * t["S"] and not e["J"] >= 0.2 * e["S"]
        else:
            r["eDB"] = e["DB"] / t["DB"] - 1.0
    ok = [r for r in rows if r["spp"] >= 20]
    print(f"noise model: {args.noise_model}; {len(rows)} records ({len(ok)} with >= 20 samples per period), "
          f"{sum(r['secs'] for r in rows):.0f} s of fitting, {wall:.0f} s wall on "
          f"{os.cpu_count()} cores\n")
    print("relative error [%], median and 90th percentile, records with >= 20 samples per period")
    print("(bias: the median of the signed error)")
    print(f"{'cell':28s} {'n':>4s}   {'S med   p90   bias':19s}   {'J med   p90   bias':19s}   "
          f"{'DB med  p90   bias':19s}  J~0")

    def line(label, sel):
        st = [r for r in sel if r["fault"] == "stiction"]
        bl = [r for r in sel if r["fault"] == "backlash"]
        j0 = f"{100 * np.mean([r['j0'] for r in st]):4.0f} %" if st else "   -"
        print(f"{label:28s} {len(sel):4d}   {_stats([r['eS'] for r in st])}   "
              f"{_stats([r['eJ'] for r in st])}   {_stats([r['eDB'] for r in bl])}  {j0}")

    line("all", ok)
    for S in S_VALUES:
        for js in JS_VALUES:
            line(f"S {S:g} J/S {js:g}", [r for r in ok if r["fault"] == "stiction"
                                         and r["truth"]["S"] == S
                                         and abs(r["truth"]["J"] / S - js) < 1e-9])
    for d in DB_VALUES:
        line(f"DB {d:g}", [r for r in ok if r["fault"] == "backlash" and r["truth"]["DB"] == d])
    for nz in NOISE_PCT:
        line(f"noise {nz:g} %", [r for r in ok if r["noise"] == nz])
    for h in SAMPLE_TIMES:
        line(f"sample time {h:g} s", [r for r in ok if r["h"] == h])
    for c in COMPRESSED:
        line("compressed" if c else "every sample stored", [r for r in ok if r["comp"] == c])
    few = [r for r in rows if r["spp"] < 20]
    if few:
        line("< 20 samples per period", few)
    st = [r for r in rows if r["fault"] == "stiction"]
    bad = [r for r in st if r["jlow"]]
    print(f"\nsticky valves with J/S >= 0.3 sized with J < 0.2 S: {len(bad)} of "
          f"{sum(r['truth']['J'] >= 0.3 * r['truth']['S'] for r in st)}")
    for r in bad[:10]:
        print(f"   {r['truth']} -> S {r['est']['S']:.3g} J {r['est']['J']:.3g} "
              f"(h {r['h']:g} s, noise {r['noise']:g} %, {'compressed' if r['comp'] else 'raw'}, "
              f"{r['spp']:.0f} samples/period)")


if __name__ == "__main__":
    main()
