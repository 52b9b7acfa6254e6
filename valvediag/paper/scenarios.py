"""
Test scenarios drawn from the parameter ranges of Farenzena & Trierweiler
(2012), for benchmarks, calibration and tests.

Three kinds of oscillating integrating loops:

``'stiction'``
    Kano valve, S in 1-6 %, J/S in 0.5-1, Kc, tau_I/tau and tau from the
    paper's grid.
``'backlash'``
    Backlash valve, DB in 0.5-6 %, same loop grid.
``'linear'``
    A linear valve, so the oscillation is not the valve's fault. Half of the
    cases: a well-tuned loop disturbed by a sinusoidal load whose period is
    0.5-4 times the loop's natural period. Half: an integrator with dead time
    tuned too tightly (80-95 % of the ultimate gain) and driven by white
    measurement noise, so that it rings at its critical frequency.

Each case is simulated once, finely (0.1 s), and can then be recorded at any
number of samples per period with white PV noise of a chosen share of the
oscillation amplitude (:func:`record`). The OP is given the controller's
proportional reaction to that noise, ``Kc * noise``, so that PV and OP stay
consistent.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..analysis.oscillation import acf_period, linear_detrend
from ..models.closedloop import simulate_loop
from .tables import DB_GRID, JS_GRID, KC_GRID, S_GRID, TAU_GRID, TI_RATIO_GRID

__all__ = ["LoopCase", "draw_cases", "record"]

FINE_STEP = 0.1


@dataclass(frozen=True)
class LoopCase:
    """One simulated loop, finely sampled.

    Attributes
    ----------
    kind : str
        ``'stiction'``, ``'backlash'`` or ``'linear'``.
    params : dict
        Loop and valve parameters.
    pv, op : numpy.ndarray
        PV and OP after the start-up transient, at ``FINE_STEP``.
    period : float
        Oscillation period [s].
    amplitude : float
        Half peak-to-peak amplitude of the PV [PV unit].
    """

    kind: str
    params: dict
    pv: np.ndarray
    op: np.ndarray
    period: float
    amplitude: float

    @property
    def truth(self) -> str:
        """The verdict a correct classifier gives."""
        return "linear-oscillation" if self.kind == "linear" else self.kind


def _finish(kind, params, sim, cycles):
    pv = sim.pv
    x = pv[pv.size // 4:]
    per, _ = acf_period(linear_detrend(np.ascontiguousarray(x)))
    if not np.isfinite(per):
        return None
    P = per * FINE_STEP
    # drop two periods of start-up (at least a quarter of the record)
    start = max(int(2 * per), pv.size // 4)
    stop = min(pv.size, start + int(np.ceil(cycles * per)) + 1)
    pv = pv[start:stop]
    op = sim.op[start:stop]
    if pv.size < 2 * per:
        return None
    amp = 0.5 * (np.percentile(pv, 99.5) - np.percentile(pv, 0.5))
    return LoopCase(kind, params, pv.copy(), op.copy(), P, float(amp))


def _critical_frequency(theta, ti):
    """Frequency [rad/s] where PI + integrator + dead time has -180 degrees:
    omega theta + atan(1 / (omega ti)) = pi / 2."""
    from scipy.optimize import brentq

    f = lambda w: w * theta + np.arctan(1.0 / (w * ti)) - 0.5 * np.pi
    return brentq(f, 1e-6 / theta, 0.5 * np.pi / theta)


def ultimate_gain_pi_integrator(tau, theta, ti):
    """Controller gain at which PI control of ``e^{-theta s}/(tau s)`` is at
    its stability limit.

    Parameters
    ----------
    tau, theta, ti : float
        Integration time, dead time and integral time [s].

    Returns
    -------
    float
        Ultimate gain [OP unit per PV unit].
    """
    w = _critical_frequency(theta, ti)
    return tau * w / np.sqrt(1.0 + 1.0 / (w * ti) ** 2)


def draw_cases(kind: str, n: int, *, seed: int = 0, cycles: float = 12.0) -> list[LoopCase]:
    """Simulate ``n`` loops of one kind with parameters drawn from the paper's grid.

    Parameters
    ----------
    kind : {'stiction', 'backlash', 'linear'}
    n : int
        Number of cases.
    seed : int
        Seed of the parameter draws.
    cycles : float
        Oscillation cycles kept after the start-up transient.

    Returns
    -------
    list of LoopCase
        Cases whose simulation did not oscillate (rare) are redrawn.
    """
    rng = np.random.default_rng(seed)
    out: list[LoopCase] = []
    tries = 0
    while len(out) < n and tries < 5 * n + 20:
        tries += 1
        tau = float(rng.choice(TAU_GRID))
        kc = float(rng.choice(KC_GRID))
        ti = float(rng.choice(TI_RATIO_GRID)) * tau
        if kind in ("stiction", "backlash"):
            if kind == "stiction":
                S = float(rng.choice(S_GRID))
                vp = {"S": S, "J": float(rng.choice(JS_GRID)) * S}
                valve = "kano"
            else:
                vp = {"DB": float(rng.choice(DB_GRID))}
                valve = "backlash"
            # slowest limit cycles (Kc 0.7, tau_I = 2.4 tau) last about 18 tau
            dur = (cycles + 4) * 20.0 * tau
            sim = simulate_loop(kc=kc, ti=ti, tau=tau, sample_time=FINE_STEP, duration=dur,
                                valve=valve, valve_params=vp, sp_step=1.0)
            case = _finish(kind, dict(kc=kc, ti=ti, tau=tau, valve=valve, **vp), sim, cycles)
        elif kind == "linear":
            if rng.random() < 0.5:
                # well-tuned loop, external sinusoidal load
                wn = np.sqrt(kc / (tau * ti))
                Pd = float(rng.uniform(0.5, 4.0)) * 2 * np.pi / wn
                dur = (cycles + 4) * Pd
                sim = simulate_loop(kc=kc, ti=ti, tau=tau, sample_time=FINE_STEP, duration=dur,
                                    load_sin_amplitude=1.0, load_sin_period=Pd,
                                    load_sin_phase=float(rng.uniform(0, 2 * np.pi)))
                params = dict(kc=kc, ti=ti, tau=tau, valve="linear", source="sinusoidal load",
                              load_period=Pd)
            else:
                # integrator + dead time, PI close to its stability limit, rung by load noise
                theta = float(rng.uniform(0.1, 0.4)) * tau
                ti = float(rng.uniform(6.0, 20.0)) * theta
                kc = float(rng.uniform(0.92, 0.98)) * ultimate_gain_pi_integrator(tau, theta, ti)
                Pu = 2 * np.pi / _critical_frequency(theta, ti)
                dur = (cycles + 8) * Pu
                sim = simulate_loop(kc=kc, ti=ti, tau=tau, dead_time=theta, sample_time=FINE_STEP,
                                    duration=dur, sp_step=1.0, load_noise_std=0.5,
                                    seed=int(rng.integers(1 << 31)))
                params = dict(kc=kc, ti=ti, tau=tau, dead_time=theta, valve="linear",
                              source="tight tuning")
            case = _finish(kind, params, sim, cycles)
        else:
            raise ValueError(f"kind must be 'stiction', 'backlash' or 'linear', not {kind!r}")
        if case is not None:
            out.append(case)
    return out


def record(case: LoopCase, samples_per_period: float | None, noise_pct: float,
           rng: np.random.Generator, averaged: bool = False):
    """Record a case as a historian would: resample and add PV noise.

    Parameters
    ----------
    case : LoopCase
    samples_per_period : float or None
        Nominal samples per oscillation period; ``None`` keeps the fine
        record. The sampling phase is random and the sample time is the
        nominal one times a random factor within +-3 %: plant historians are
        not phase-locked to an oscillation (a sample time of exactly P/n
        would sample every cycle at the same phases).
    noise_pct : float
        White PV noise, standard deviation as a percentage of the oscillation
        amplitude [%].
    rng : numpy.random.Generator
    averaged : bool, default False
        Record each sample as the mean of the PV and OP over the sample time
        that ends at it (a historian's average export), not their values at
        its time stamp.

    Returns
    -------
    pv, op : numpy.ndarray
    sample_time : float
        [s]
    """
    t = np.arange(case.pv.size) * FINE_STEP
    if samples_per_period is None:
        h = FINE_STEP
        pv, op = case.pv.copy(), case.op.copy()
    else:
        h = case.period / samples_per_period * rng.uniform(0.97, 1.03)
        tn = np.arange(rng.uniform(0, h), t[-1], h)
        if averaged:
            tn = tn[tn >= h]

            def mean(x):   # over (tn - h, tn], the trapezoid rule on the fine record
                c = np.r_[0.0, np.cumsum(0.5 * (x[1:] + x[:-1]) * FINE_STEP)]
                return (np.interp(tn, t, c) - np.interp(tn - h, t, c)) / h
            pv, op = mean(case.pv), mean(case.op)
        else:
            pv = np.interp(tn, t, case.pv)
            op = np.interp(tn, t, case.op)
    noise = rng.normal(0.0, noise_pct / 100.0 * case.amplitude, pv.size)
    return pv + noise, op + case.params["kc"] * noise, h
