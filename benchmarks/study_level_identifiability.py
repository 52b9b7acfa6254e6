"""Can a level's PV and OP tell a sticky valve from a wandering load? A likelihood study.

Level loops of the realistic benchmark (``valvediag.synth.cases``) are read
with three pictures of the valve:

* ``linear``: the valve follows the OP;
* ``sticky``: Kano et al.'s (2004) valve driven by the recorded OP, over a
  grid of stick band ``S`` (0.5-8 % of the OP, geometric) and slip jump ``J``
  (0.15-0.9 of ``S``), with an actuator that ignores OP noise within six of
  the OP's noise standard deviations, as the scan's valve signature assumes;
* ``position``: the valve position the positioner reported
  (``SynthLoop.mv``), which no reader of PV and OP has.

Each picture is fitted with an unknown gain (least squares), dead time (0,
1, 2 or 4 samples) and first-order lag (0, 2 or 8 samples) and an unknown
load that wanders as an integrated random walk, by the innovations
log-likelihood of the steady-state Kalman filter, with the PV's measurement
noise known (:func:`valvediag.analysis.quality.white_noise_std`)::

    level[k+1] = level[k] + g u[k-d] (lagged) - w[k]
    w[k+1] = w[k] + w'[k],  w'[k+1] = w'[k] + eta[k],  var(eta) = r var(noise)
    pv[k] = level[k] + noise[k]

Printed for each loop, as the log-likelihood gain over the linear valve:

* ``sticky free``: the best sticky valve, the load's ``r`` free (1e-12 to
  1e-2: a load that may change as fast as the valve);
* ``sticky slow``: the same with the load held to slow changes (``r`` at
  most 1e-8);
* ``position``: the reported position, ``r`` free.

A gain of a few units or less says the record does not prefer that picture.
Compressed records are skipped (a swinging door's PV has no white noise),
and records are cut to their first 20,000 samples.

The point of the study: the reported position shows the sticky valves'
slips far above the linear valve's fit, so the record holds their trace; but
read from PV and OP alone the valve's path must be rebuilt from the OP, and
a linear valve with a load free to move as fast reads the sticky records
about as well, while holding the load to slow moves makes healthy levels
under stepping loads read sticky. The valve's nonlinearity and the load's
speed are then not separately identifiable without a prior on the load.

Measured 2026-12-01 (``--loops 12``, the uncompressed loops; min / median /
max of the gain):

==========================  =====================  =======================  ==================
set, class                  sticky free            sticky slow              position
==========================  =====================  =======================  ==================
dev, sticky events (11)     -296 / 7.4 / 160       -1181 / 16 / 270         -1.0 / 105 / 1940
dev, healthy (11)           -389 / -17.5 / 68      -241 / -12.3 / 1594      -117 / -25 / 5.5
dev, slow loads (7)         -712 / -24 / 129       -110797 / -11 / 13691    -783 / -159 / -35
dev, ringing (9)            -614 / -6.4 / 4013     -20593 / 748 / 62698     -1553 / -243 / -0.1
dev2, sticky events (10)    -856 / 29 / 250        -1898 / 200 / 4122       6.4 / 376 / 1738
dev2, healthy (11)          -119 / 0.1 / 44        -54 / 44 / 1364          -87 / -14 / -1.2
dev2, slow loads (10)       -257 / -39 / 32        -3444 / 2347 / 74214     -913 / -204 / -28
dev2, ringing (9)           -4682 / -718 / -20     -13370 / 4172 / 452130   -5584 / -792 / -12
==========================  =====================  =======================  ==================

The disturbed levels (``level-linear-disturbance``) read the sticky valve
up to 2,697 (dev) and 5,704 (dev2) better than the linear one with the load
free: their OP hardly moves (a standard deviation of 0.02-0.03 % on the
two looked at, dev 3 and 10, against a fast load), and a
valve that ignores the OP's noise reads them as well as one that passes it.
The reported position reads them worse than the OP: 0.1-0.5 % of
positioner noise on a valve that moves a few hundredths of a percent.

Usage: python benchmarks/study_level_identifiability.py [--set dev|dev2] [--loops N]
       [--classes C1,C2]

The held-out set (seed 3) is not offered: its misses are not to be looked at.

References
----------
.. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical
   model and detection algorithm for valve stiction. IFAC DYCOPS 7.
"""
from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np
from scipy import linalg, signal

from valvediag.analysis.quality import white_noise_std
from valvediag.analysis.signature import held_delay
from valvediag.models.valves import kano
from valvediag.synth.cases import benchmark_rng, draw_loop

CLASSES = ("level-stiction-events", "level-healthy", "level-linear-slow-load",
           "level-linear-disturbance", "level-linear-tuning")
SETS = {"dev": 1, "dev2": 2}
#: Load-acceleration variances over the PV's noise variance; the slow ones
#: are those at most :data:`SLOW_R`.
LOAD_R = (1e-12, 1e-11, 1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)
SLOW_R = 1e-8
LAGS = (0, 2, 8)            # [samples]
DEADS = (0, 1, 2, 4)        # [samples]
S_GRID = np.geomspace(0.5, 8.0, 15)
J_OVER_S = (0.15, 0.3, 0.6, 0.9)
MAX_SAMPLES = 20_000
SKIP = 60                   # innovations left out while the filter settles [samples]


def innovation_filters(r: float):
    """The steady-state Kalman filter's innovations as two transfer functions.

    Returns ``(b_pv, b_u, a)``: the innovations are
    ``lfilter(b_pv, a, pv) - g lfilter(b_u, a, u)``, and ``s``, their
    variance over the measurement noise's.
    """
    F = np.array([[1.0, -1.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    P = linalg.solve_discrete_are(F.T, H.T, np.diag([0.0, 0.0, r]), np.array([[1.0]]))
    s = float((H @ P @ H.T)[0, 0]) + 1.0
    K = F @ P @ H.T / s
    A = F - K @ H
    num_pv, a = signal.ss2tf(A, K, H, np.zeros((1, 1)))
    num_u, _ = signal.ss2tf(A, np.array([[1.0], [0.0], [0.0]]), H, np.zeros((1, 1)))
    return a - num_pv[0], num_u[0], a, s


def lagged(U: np.ndarray, lag: float) -> np.ndarray:
    """Rows of ``U`` through a first-order lag of ``lag`` samples, started at rest."""
    if lag <= 0:
        return U
    a = math.exp(-1.0 / lag)
    return signal.lfilter([1.0 - a], [1.0, -a], U - U[:, :1], axis=1) + U[:, :1]


def best_loglik(pv: np.ndarray, U: np.ndarray, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """Best innovations log-likelihood of each valve picture (rows of ``U``).

    Returns the best over all load speeds and over the slow ones only.
    """
    n = pv.size
    R = noise ** 2
    free = np.full(U.shape[0], -np.inf)
    slow = free.copy()
    shifted = {}
    for lag in LAGS:
        UL = lagged(U, lag)
        for d in DEADS:
            shifted[lag, d] = held_delay(UL, d)
    for r in LOAD_R:
        b_pv, b_u, a, s = innovation_filters(r)
        e_pv = signal.lfilter(b_pv, a, pv - pv[0])[SKIP:]
        for Ud in shifted.values():
            e_u = signal.lfilter(b_u, a, Ud - Ud[:, :1], axis=1)[:, SKIP:]
            g = (e_u @ e_pv) / np.maximum(np.einsum("ij,ij->i", e_u, e_u), 1e-300)
            res = e_pv - g[:, None] * e_u
            rss = np.einsum("ij,ij->i", res, res)
            ll = -0.5 * ((n - SKIP) * math.log(2 * math.pi * s * R) + rss / (s * R))
            free = np.maximum(free, ll)
            if r <= SLOW_R:
                slow = np.maximum(slow, ll)
    return free, slow


def read_loop(loop) -> dict:
    """The log-likelihood gains over the linear valve of one level loop."""
    pv, op = loop.pv[:MAX_SAMPLES], loop.op[:MAX_SAMPLES]
    S = np.repeat(S_GRID, len(J_OVER_S))
    J = S * np.tile(J_OVER_S, S_GRID.size)
    band = np.full(S.size, 6.0 * white_noise_std(op))
    sticky = kano(np.ascontiguousarray(np.broadcast_to(op, (S.size, op.size))), S, J,
                  noise_band=band)
    rows = [op[None], sticky]
    if loop.mv is not None:
        rows.append(loop.mv[:MAX_SAMPLES][None])
    free, slow = best_loglik(pv, np.vstack(rows), white_noise_std(pv))
    k = int(np.argmax(free[1:1 + S.size]))
    return dict(free=float(free[1:1 + S.size].max() - free[0]),
                slow=float(slow[1:1 + S.size].max() - slow[0]),
                position=float(free[-1] - free[0]) if loop.mv is not None else math.nan,
                S=float(S[k]), J=float(J[k]))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--set", choices=sorted(SETS), default="dev")
    ap.add_argument("--loops", type=int, default=10, help="loops per class (default 10)")
    ap.add_argument("--classes", default=",".join(CLASSES),
                    help="comma-separated level classes (default: %(default)s)")
    args = ap.parse_args(argv)
    seed = SETS[args.set]
    print(f"level identifiability study, {args.set} set (seed {seed}), {os.cpu_count()} cores")
    print(f"{'loop':30s} {'h':>3s} {'hours':>5s} {'sticky free':>11s} {'sticky slow':>11s} "
          f"{'position':>9s}  best S, J")
    t0 = time.perf_counter()
    summary = {}
    for klass in args.classes.split(","):
        for i in range(args.loops):
            loop = draw_loop(klass, benchmark_rng(klass, seed, i), name=f"{klass}-{i:02d}")
            if loop.params.get("compressed"):
                continue
            g = read_loop(loop)
            summary.setdefault(klass, []).append(g)
            print(f"{loop.name:30s} {loop.sample_time:3.0f} {loop.duration_s / 3600:5.1f} "
                  f"{g['free']:11.1f} {g['slow']:11.1f} {g['position']:9.1f}  "
                  f"{g['S']:.2f}, {g['J']:.2f}", flush=True)
    print(f"\nper class (uncompressed loops): min / median / max of the gain "
          f"({time.perf_counter() - t0:.0f} s)")
    for klass, rows in summary.items():
        line = f"{klass:28s} n={len(rows):2d}"
        for key in ("free", "slow", "position"):
            v = np.array([r[key] for r in rows])
            line += f"  {key} {v.min():9.1f} {np.median(v):9.1f} {v.max():9.1f}"
        print(line)


if __name__ == "__main__":
    main()
