"""Hidden-effect benchmark of the model workbench: is the missing effect named?

Each case is a simulated loop whose data hold every effect of a starting
model plus ONE more, the hidden effect; the workbench starts from the model
without it (``forward_select``, two steps). The grid: every effect the
workbench suggests (stiction behind a dead band, a dead band behind a linear
valve, dead time, lag, drift, saturation, a curved valve characteristic, an
unmeasured sinusoidal load, a PV read on a grid) x four parameter points across its range x an
integrating and a self-regulating plant x two seeds. Each record:
4.5 h at 1 s, PI control (detuned where the hidden dead time or lag makes
it unstable), set-point steps every 25-50 min (of 0.5-1.5 PV units; of
8-12 where a curved characteristic or saturation stops are hidden, which
show only across the valve's travel: ``SP_STEPS``), measurement noise
of 1 % of the PV's swing on the recorded PV (the noise floor of the held-out
RMSE; for a PV read on a grid, the error of a perfect model of the reading).

Printed per effect: how often the hidden effect is ranked first, how often a
lag and a dead time were reported indistinguishable (and so not counted as
wrong when the other came first), the median fall of the held-out error when
the hidden effect is added, the median ratio of that error to the noise
floor, the share where the error falls >= 30 % or ends within 1.25 x the
noise floor, how often an effect absent from the data was accepted, and
how often a lag or dead time was accepted in place of the hidden other as
one of a pair the record could not tell apart (the ladder names the pair:
``LadderStep.alternatives``; not counted as absent). Then the confusion: the
effect ranked first against the hidden one, and the evidence behind the
accepted effects: the paired t of the held-out gain over the held-out
segments and the fall of the BIC, the hidden effect's against the start
and each absent effect's against the rung below.

Targets (the workbench issue): hidden effect first in >= 90 % (lag and dead
time: except where reported indistinguishable); error falls >= 30 % or ends
within 1.25 x the floor in >= 90 %; no absent effect accepted.

``--record clean`` drops the PV's measurement noise (the floor is then
NaN: the fall of the error decides), ``--record compressed`` stores the
noisy PV by swinging-door compression at twice its noise and scores it at
its stored points, as ``valvediag model ... --pv-points stored`` does (a PV
read on a grid stays as it is read).

Usage: python benchmarks/bench_hidden_effects.py [--workers W] [--seeds 2] [--hours 4.5]
       [--effects saturation,quantisation] [--record noisy|clean|compressed]
"""
from __future__ import annotations

import argparse
import math
import os
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor

import numpy as np

#: hidden effect -> (starting model, the four parameter points)
GRID = {
    "stiction": (("deadband",), [dict(S=1.0, J=0.1), dict(S=2.0, J=1.0), dict(S=4.0, J=4.0),
                                 dict(S=6.0, J=1.5)]),
    "deadband": ((), [dict(DB=1.0), dict(DB=2.0), dict(DB=4.0), dict(DB=6.0)]),
    "dead_time": (("deadband",), [dict(dead_time=5.0), dict(dead_time=10.0),
                                  dict(dead_time=20.0), dict(dead_time=30.0)]),
    "lag": (("deadband",), [dict(lag=5.0), dict(lag=15.0), dict(lag=30.0), dict(lag=60.0)]),
    "drift": (("deadband",), [dict(load_drift=5e-5), dict(load_drift=-1e-4),
                              dict(load_drift=2e-4), dict(load_drift=-4e-4)]),
    # stops that cut the free valve's largest excursions from its median to
    # this share of them, on both sides
    "saturation": (("deadband",), [dict(reach=0.75), dict(reach=0.65), dict(reach=0.55),
                                   dict(reach=0.5)]),
    "characteristic": (("deadband",), [dict(valve_curvature=0.04), dict(valve_curvature=0.1),
                                       dict(valve_curvature=0.25), dict(valve_curvature=-0.1)]),
    "oscillating_load": (("deadband",), [
        dict(load_sin_amplitude=0.5, load_sin_period=120.0),
        dict(load_sin_amplitude=1.0, load_sin_period=300.0),
        dict(load_sin_amplitude=2.0, load_sin_period=900.0),
        dict(load_sin_amplitude=4.0, load_sin_period=2400.0)]),
    # the PV read on a grid of this many noise standard deviations (the noise
    # ahead of the quantiser); below about 5 the noise dithers the staircase away
    "quantisation": (("deadband",), [dict(quantum=5.0), dict(quantum=10.0), dict(quantum=15.0),
                                     dict(quantum=25.0)]),
}
#: Size of the set-point steps [PV unit], drawn per step. A curved
#: characteristic changes the loop's gain only across the valve's travel:
#: steps of 0.5-1.5 move the valve by 2-4 % OP, over which no curvature of
#: the grid shows beyond the noise (the starting model's held-out error was
#: within 5 % of the floor in 11 of its 16 cases), so its cases step by
#: 8-12, which moves the valve over 10-20 % of its travel. Saturation stops
#: likewise: drawn within the 2-4 % the small steps move the valve, they lay
#: closer together than the dead band (a valve with no stroke).
SP_STEPS = {"characteristic": (8.0, 12.0), "saturation": (8.0, 12.0)}
SP_STEP_DEFAULT = (0.5, 1.5)
#: The valve of every case that does not hide a valve effect [% OP].
DEADBAND = 3.0
PLANTS = {
    "integrating": dict(process="integrating", process_gain=1.0, tau=60.0, kc=2.0, ti=60.0),
    "self-regulating": dict(process="self-regulating", process_gain=1.5, tau=30.0, kc=1.3,
                            ti=20.0),
}
NOISE_PCT = 1.0


def simulate_case(hidden: str, point: dict, plant: str, seed: int, hours: float,
                  record: str = "noisy"):
    """PV, OP, SP, the noise floor of one case, and where the valve stood
    at a saturation stop (``{'low': mask, 'high': mask}``, else None).

    ``record``: the PV with its measurement noise (``'noisy'``), without it
    (``'clean'``: the floor is then NaN), or with it and stored by
    swinging-door compression at twice the noise, read back by straight
    lines (``'compressed'``). A PV read on a grid is always read so."""
    from valvediag import simulate_loop
    from valvediag.synth.cases import alternating_steps
    from valvediag.workbench.data import growing_swing

    rng = np.random.default_rng(seed)
    n = int(hours * 3600)
    steps = alternating_steps(rng, n, size=SP_STEPS.get(hidden, SP_STEP_DEFAULT))
    kw = dict(PLANTS[plant], sample_time=1.0, n_samples=n, sp_profile=steps,
              noise_std=0.002, seed=seed, valve="backlash", valve_params={"DB": DEADBAND})
    p = dict(point)
    if hidden == "stiction":
        kw.update(valve="kano", valve_params=p)
    elif hidden == "deadband":
        kw.update(valve_params=p)
    elif hidden == "quantisation":
        pass
    elif hidden == "saturation":
        # the valve's travel limited to a share of its free excursions; the
        # OP itself is not limited: that would leave no trace between the
        # recorded OP and the PV
        free = simulate_loop(**kw).mv[n // 10:]
        mid = np.median(free)
        kw.update(valve_limits=(mid - p["reach"] * (mid - free.min()),
                                mid + p["reach"] * (free.max() - mid)))
    else:
        kw.update(p)
    sim = simulate_loop(**kw)
    # a long dead time or lag makes the plant's PI loop unstable: an engineer
    # would have detuned it, and the workbench refuses a growing swing
    # (growing_swing), so the controller's gain is halved and its integral
    # time doubled until it holds
    for _ in range(4):
        if growing_swing(sim.op) is None:
            break
        kw.update(kc=0.5 * kw["kc"], ti=2.0 * kw["ti"])
        sim = simulate_loop(**kw)
    pv, op = sim.pv, sim.op
    sigma = NOISE_PCT / 100.0 * np.ptp(pv[n // 10:])
    clean = pv
    pv = pv + sigma * rng.standard_normal(n)
    if hidden == "quantisation":
        # read on a grid; the floor is the error of a perfect model of the
        # reading (its expected value given the process value)
        from valvediag.workbench.sensor import quantised_mean

        step = p["quantum"] * sigma
        pv = step * np.round(pv / step)
        perfect = pv - quantised_mean(clean, step, 0.0, sigma)
        floor = float(np.sqrt(np.mean(perfect[n // 10:] ** 2)))
        return pv, op, kw["sp_profile"], floor, None
    if record == "clean":
        pv, sigma = clean, math.nan
    elif record == "compressed":
        from valvediag.synth.plant import swinging_door

        t = np.arange(n, dtype=float)
        keep = np.flatnonzero(swinging_door(pv, 2.0 * sigma, t=t))
        pv = np.interp(t, keep, pv[keep])
    at_stop = None
    if hidden == "saturation":
        lo, hi = kw["valve_limits"]
        at_stop = dict(low=sim.mv <= lo + 1e-9, high=sim.mv >= hi - 1e-9)
    return pv, op, kw["sp_profile"], sigma, at_stop


def run_case(args):
    """Forward selection from the starting model; the figures of one case."""
    from valvediag.workbench import forward_select, prepare_loop
    from valvediag.workbench.data import WorkbenchDataError
    from valvediag.workbench.suggest import compare_heldout

    def gain_t(a, b):
        # > 0 where a's held-out error is the lower
        c = compare_heldout(a, b, ("a", "b"))
        return c.t if c.effects[0] == "a" else -c.t

    hidden, k, point, plant, seed, hours, record = args
    start, _ = GRID[hidden]
    pv, op, sp, sigma, at_stop = simulate_case(hidden, point, plant, seed, hours, record)
    out = dict(hidden=hidden, point=k, plant=plant, seed=seed)
    t0 = time.perf_counter()
    # a compressed PV is scored at its stored points (`--pv-points stored`)
    stored = record == "compressed" and hidden != "quantisation"
    try:
        data = prepare_loop(pv, op, 1.0, sp=sp, pv_points="stored" if stored else "all")
    except WorkbenchDataError as exc:
        out.update(refused=str(exc), seconds=time.perf_counter() - t0)
        return out
    if at_stop is not None:
        # a stop that the valve reaches in no training block cannot be fitted
        # (the fit sees only those), only checked on the held-out blocks
        ss = data.sample_set
        out["stop_samples"] = {side: (int((m & (ss == 0)).sum()), int((m & (ss == 1)).sum()))
                               for side, m in at_stop.items()}
    ladder = forward_select(data, start, process_type=plant, max_steps=2)
    sug = ladder.steps[0].suggestions
    top = sug.items[0]
    mine = next(s for s in sug.items if s.effect == hidden)
    tie = any(not r.distinguishable and hidden in r.effects and top.effect in r.effects
              for r in sug.rivals)
    # an effect accepted as one of a pair the record could not tell apart,
    # the hidden one the other, is the pair's (counted as such, not absent)
    steps = ladder.steps[1:]
    absent = [s.added for s in steps if s.added != hidden and hidden not in s.alternatives]
    paired = [s.added for s in steps if s.added != hidden and hidden in s.alternatives]
    # how far beyond the noise of the held-out segments each gain lies: the
    # hidden effect's against the start, each added effect's against the rung
    # below (paired t over the held-out segments, compare_heldout)
    t_added = [gain_t(s.fit, r.fit) for r, s in zip(ladder.steps, steps)]
    out.update(first=top.effect if top.accepted else "none", tie=tie,
               t_mine=gain_t(mine.fit, sug.base), t_added=t_added,
               bic_mine=sug.base.bic - mine.bic,
               bic_added=[r.fit.bic - s.fit.bic for r, s in zip(ladder.steps, steps)],
               steps=[s.added for s in steps],
               fall=1.0 - mine.heldout_rmse / sug.base.heldout_rmse,
               floor=mine.heldout_rmse / sigma, absent=absent, paired=paired,
               seconds=time.perf_counter() - t0)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seeds", type=int, default=2, help="seeds per grid point")
    ap.add_argument("--hours", type=float, default=4.5, help="record length [h]")
    ap.add_argument("--effects", default=None,
                    help="comma-separated hidden effects to run (default all; a case's seed "
                         "does not depend on which run)")
    ap.add_argument("--record", choices=("noisy", "clean", "compressed"), default="noisy",
                    help="the PV with its noise (default), without it, or with it and "
                         "stored by swinging-door compression (scored at its stored points)")
    args = ap.parse_args()
    effects = list(GRID) if args.effects is None else args.effects.split(",")
    unknown = [e for e in effects if e not in GRID]
    if unknown:
        ap.error(f"unknown effect(s) {', '.join(unknown)}; choose from {', '.join(GRID)}")
    cases = [(h, k, p, plant, 1000 * s + 10 * k + j, args.hours, args.record)
             for j, h in enumerate(GRID) if h in effects for k, p in enumerate(GRID[h][1])
             for plant in PLANTS for s in range(args.seeds)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as ex:
        res = list(ex.map(run_case, cases))
    wall = time.perf_counter() - t0
    print(f"hidden-effect benchmark: {len(res)} cases ({len(effects)} effects x 4 points x "
          f"{len(PLANTS)} plants x {args.seeds} seeds), {args.hours:g} h at 1 s, "
          f"PV {args.record}, "
          f"{os.cpu_count()} cores, {args.workers} workers, {wall:.0f} s wall, "
          f"{sum(r['seconds'] for r in res):.0f} s of fitting")
    print(f"\n{'effect':12s} {'plant':16s} {'n':>3s} {'first':>6s} {'tie':>4s} {'fall med':>9s} "
          f"{'err/floor':>10s} {'fall>=30%|<=1.25':>17s} {'absent acc':>11s} {'as pair':>8s} "
          f"{'refused':>8s}")
    rows = [(h, plant) for h in effects for plant in PLANTS] + [(h, None) for h in effects]
    for h, plant in rows:
        sel = [r for r in res if r["hidden"] == h and (plant is None or r["plant"] == plant)]
        ok = [r for r in sel if "refused" not in r]
        if not ok:
            print(f"{h:12s} {plant or 'both':16s} {len(sel):3d}  all refused")
            continue
        first = np.mean([r["first"] == h or r["tie"] for r in ok])
        tie = sum(r["tie"] and r["first"] != h for r in ok)
        fall = np.median([r["fall"] for r in ok])
        floor = np.median([r["floor"] for r in ok])
        good = np.mean([r["fall"] >= 0.3 or r["floor"] <= 1.25 for r in ok])
        absent = sum(bool(r["absent"]) for r in ok)
        paired = sum(bool(r["paired"]) for r in ok)
        print(f"{h:12s} {plant or 'both':16s} {len(sel):3d} {100 * first:5.0f}% {tie:4d} "
              f"{100 * fall:8.0f}% {floor:10.2f} {100 * good:16.0f}% {absent:11d} "
              f"{paired:8d} {len(sel) - len(ok):8d}")
    print("\nconfusion (rows: hidden effect; columns: effect ranked first, "
          "'none' if none accepted)")
    cols = list(GRID) + ["none"]
    print(f"{'':12s} " + " ".join(f"{c[:9]:>9s}" for c in cols))
    for h in effects:
        c = Counter(r["first"] for r in res if r["hidden"] == h and "refused" not in r)
        print(f"{h:12s} " + " ".join(f"{c.get(x, 0):9d}" for x in cols))
    unseen = [r for r in res if any(n[0] == 0 for n in r.get("stop_samples", {}).values())]
    if any("stop_samples" in r for r in res):
        print(f"\nsaturation cases with a stop the valve reaches in no training block (it can "
              f"only be checked, not fitted): {len(unseen)}, of which the hidden effect came "
              f"first in {sum(r.get('first') == 'saturation' for r in unseen)}")
    ok = [r for r in res if "refused" not in r]
    firsts = sorted((r["t_mine"], r["bic_mine"]) for r in ok if r["first"] == r["hidden"])
    absent_t = [(t, b) for r in ok for s, t, b in zip(r["steps"], r["t_added"], r["bic_added"])
                if s != r["hidden"] and s not in r["paired"]]
    if firsts:
        print("\nthe evidence for an accepted effect, as (paired t of its held-out gain over "
              "the held-out segments, fall of the BIC): the hidden effect ranked first, "
              "against the start, lowest t: "
              + ", ".join(f"({t:.1f}, {b:.0f})" for t, b in firsts[:8])
              + f"; lowest fall of the BIC {min(b for _, b in firsts):.0f}; absent effects "
              "accepted, against the rung below: "
              + (", ".join(f"({t:.1f}, {b:.1f})" for t, b in absent_t) or "none"))
    bad = [r for r in res if "refused" in r or (r["first"] != r["hidden"] and not r["tie"])
           or r["absent"]]
    if bad:
        print("\ncases off target:")
        for r in bad:
            what = r.get("refused") or (
                f"first {r['first']}, fall {100 * r['fall']:.0f} %, "
                f"err/floor {r['floor']:.2f}, absent accepted {r['absent']}"
                + (f", accepted as a pair {r['paired']}" if r["paired"] else "")
                + f", t {r['t_mine']:.1f}, BIC fall {r['bic_mine']:.1f}"
                + (" (added: " + ", ".join(f"t {x:.1f}, BIC fall {b:.1f}" for x, b in
                                          zip(r["t_added"], r["bic_added"])) + ")"
                   if r["t_added"] else "")
                + ("; valve samples at its stops (training, held-out): " + ", ".join(
                    f"{side} {n[0]}, {n[1]}" for side, n in r["stop_samples"].items())
                   if "stop_samples" in r else ""))
            print(f"  {r['hidden']:10s} point {r['point']} {r['plant']:15s} "
                  f"seed {r['seed']}: {what}")


if __name__ == "__main__":
    main()
