"""
Labelled single loops of the kinds real plant records hold, for benchmarks and tests.

The synthetic plant (:func:`valvediag.synth.synth_plant`) holds textbook
cases: sustained limit cycles, mostly on integrating loops. Real historian
records show more, and the scan must be right on all of it
(:data:`CLASSES`):

* sticky and loose valves in limit cycles on level loops (the paper's case),
  among them sawtooth cycles with a slow rise and a fast fall (the valve
  closes fully on a net inflow);
* sticky valves on level loops under proportional-only control: no limit
  cycle, stick-slip events around set-point moves and load changes, at
  least three of them bending the level's record by more than its noise
  (:func:`_visible_slope_slips`: a valve that slips unseen is no labelled
  case);
* sticky flow and pressure valves (self-regulating, time constants 2-60 s):
  square-wave PV and triangular OP, periods 30 s to 20 min;
* sticky flow valves without a limit cycle: the OP ramps for minutes while the
  flow stays flat within its noise, then the flow jumps in a sample;
* loose flow valves: a dead band after each reversal, no jump;
* healthy valves under non-sinusoidal disturbances (square, triangular,
  clipped) at 10-60 samples per period, on level and flow loops;
* healthy valves on level loops under slow periodic loads (square, clipped,
  triangular, or a pump that runs for part of each period; 30-120 minutes):
  the level settles at its set point after each move of the load, or
  stands off it while the OP follows a ramping inflow;
* healthy valves in loops tuned too tightly (ringing), and quiet healthy
  loops with set-point moves, a wandering load and load steps (pumps that
  start and stop), half the flows behind slow integral action;
* dead responses: the OP moves over tens of percent and the PV does not;
* slow self-regulating loops (a temperature or a composition: time
  constants 60-600 s, dead times up to 0.3 of them): sticky valves in limit
  cycles, and healthy valves under periodic loads (square, triangular,
  clipped or sine, periods of 3-15 times the time constant and dead time),
  a snapshot of which holds too few cycles for their clock to be read.

Each loop is simulated in closed loop (:func:`valvediag.models.simulate_loop`)
with the controller at half the historian's sample time and measurement
noise fed back (a sticky valve's actuator does not reverse on the OP noise
that causes: ``valve_noise_band``), then recorded as a historian would: every
second sample, 1-10 s, as a 1-4 h snapshot around an event or a full day,
some exception-and-swinging-door compressed. Every draw is rejected and
redrawn until the record shows its class (enough cycles or events, at least
15 samples per period, counted once each), so the truth is what the data can
show. The cycles are counted by the generator's own crossings of the control
error (:func:`valvediag.synth.plant.cycle_stats`), not by the scan's detector:
the sets stay the same when the method under test changes. And redrawn
until the PV stays within its 0-100 % span (a level the valve at its limit
cannot hold runs away, which is no record of any class).
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..analysis.quality import stored_points, white_noise_std
from ..models.closedloop import simulate_loop
from .plant import cycle_stats, exception_deadband, historian_record

__all__ = ["CLASSES", "SynthLoop", "draw_loop", "benchmark_rng", "loop_set",
           "alternating_steps"]

#: Class -> (truth verdict, process type, whether the fault shows as a limit cycle).
CLASSES: dict[str, tuple[str, str, bool]] = {
    "level-stiction-cycle": ("stiction", "integrating", True),
    "level-backlash-cycle": ("backlash", "integrating", True),
    "level-stiction-sawtooth": ("stiction", "integrating", True),
    "level-stiction-events": ("stiction", "integrating", False),
    "flow-stiction-cycle": ("stiction", "self-regulating", True),
    "flow-stiction-events": ("stiction", "self-regulating", False),
    "flow-backlash-events": ("backlash", "self-regulating", False),
    "level-linear-disturbance": ("linear-oscillation", "integrating", True),
    "flow-linear-disturbance": ("linear-oscillation", "self-regulating", True),
    "level-linear-tuning": ("linear-oscillation", "integrating", True),
    "level-healthy": ("no-oscillation", "integrating", False),
    "flow-healthy": ("no-oscillation", "self-regulating", False),
    "dead-response": ("insufficient-data", "self-regulating", False),
    # appended last, so that every other class's draws stay as they were
    "level-linear-slow-load": ("linear-oscillation", "integrating", True),
    "temperature-stiction-cycle": ("stiction", "self-regulating", True),
    "temperature-linear-disturbance": ("linear-oscillation", "self-regulating", True),
}
#: Classes whose valve is faulty.
FAULT_CLASSES = tuple(k for k, v in CLASSES.items() if v[0] in ("stiction", "backlash"))

_DAY = 86_400.0


@dataclass(frozen=True)
class SynthLoop:
    """One labelled loop record.

    Attributes
    ----------
    name : str
    klass : str
        One of :data:`CLASSES`.
    truth : str
        The verdict a correct scan gives.
    process_type : str
        ``'integrating'`` or ``'self-regulating'``.
    pv, op, sp : numpy.ndarray
        The record [%: PV in % of span, OP in % of travel].
    sample_time : float
        [s]
    params : dict
        What was simulated (valve, tuning, disturbance, noise, storage).
    mv : numpy.ndarray or None
        The valve's position as a positioner would report it [% of travel]:
        the simulated position with 0.1-0.5 % white noise, stored like the
        OP when the record is compressed. None where no valve was simulated
        (``dead-response``). Drawn from its own stream, so the other signals
        are the same with or without it.
    """

    name: str
    klass: str
    truth: str
    process_type: str
    pv: np.ndarray = field(repr=False)
    op: np.ndarray = field(repr=False)
    sp: np.ndarray = field(repr=False)
    sample_time: float
    params: dict = field(default_factory=dict)
    mv: np.ndarray | None = field(default=None, repr=False)

    @property
    def duration_s(self) -> float:
        """Length of the record [s]."""
        return self.pv.size * self.sample_time


def _wave(kind: str, t: np.ndarray, period: float, phase: float) -> np.ndarray:
    """A unit disturbance of period ``period`` [s]: sine, square, triangle or clipped sine."""
    x = 2 * np.pi * t / period + phase
    if kind == "square":
        return np.sign(np.sin(x))
    if kind == "triangle":
        return 2 / np.pi * np.arcsin(np.sin(x))
    if kind == "clipped":
        return np.clip(1.6 * np.sin(x), -1, 1)
    return np.sin(x)


#: Process and tuning drawn for each kind of loop: time constant range [s]
#: (log-uniform), controller gain range, integral time range [time
#: constants], most dead time and most lag [time constants], the load that
#: the valve balances [% of travel]. A level integrates; a flow (or
#: pressure) regulates itself fast, a temperature (or composition) slowly,
#: behind a longer dead time.
_PROCESSES = {
    "level": ((60.0, 1000.0), (0.7, 3.0), (1.0, 2.4), 0.05, 0.1, 50.0),
    "flow": ((2.0, 60.0), (0.3, 1.2), (0.5, 1.5), 0.2, 0.2, 0.0),
    "temperature": ((60.0, 600.0), (0.3, 1.0), (0.7, 1.5), 0.3, 0.1, 0.0),
}

#: Amplitude range of each of the three sines of a cascade's set point [PV unit].
CASCADE_WANDER = (0.1, 0.5)


def _random_walk(rng, n: int, h: float, step_s: float, size: float) -> np.ndarray:
    """A load that wanders: piecewise-linear through random points ``step_s`` apart."""
    k = max(2, int(n * h / step_s) + 2)
    pts = np.cumsum(rng.normal(0, size, k))
    return np.interp(np.arange(n) * h, np.arange(k) * step_s, pts - pts[0])


def alternating_steps(rng: np.random.Generator, n: int, every_s=(1500.0, 3000.0),
                      size=(0.5, 1.5), sample_time: float = 1.0) -> np.ndarray:
    """Set-point steps alternating in sign, as an operator moves a loop.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Samples.
    every_s : tuple of float
        Range of the time between steps, drawn uniformly [s].
    size : tuple of float
        Range of the step size, drawn uniformly [PV unit].
    sample_time : float
        [s]

    Returns
    -------
    numpy.ndarray, shape (n,)
        Offset from the initial set point [PV unit], 0 until the first step.
    """
    sp, t, sign = np.zeros(n), 0, 1.0
    while True:
        t += int(rng.uniform(*every_s) / sample_time)
        if t >= n:
            return sp
        sp[t:] += sign * rng.uniform(*size)
        sign = -sign


def _random_steps(rng, n: int, h: float, every_s: tuple[float, float], size: float) -> np.ndarray:
    """Steps of +-``size`` at random intervals (set-point moves, load steps)."""
    out = np.zeros(n)
    t, level = rng.uniform(*every_s) * 0.3, 0.0
    while t < n * h:
        level += size * rng.choice((-1.0, 1.0)) * rng.uniform(0.5, 1.0)
        out[int(t / h):] = level
        t += rng.uniform(*every_s)
    return out


def _record(pv, op, sp, rng, compressed: bool, sigma: float):
    """Every second controller sample; exception and swinging-door storage if asked."""
    pv, op, sp = pv[::2].copy(), op[::2].copy(), sp[::2].copy()
    if compressed:
        t = np.arange(pv.size, dtype=float)
        amp = 0.5 * (np.percentile(pv, 99) - np.percentile(pv, 1))
        dev = max(rng.uniform(0.01, 0.03) * amp, 2.0 * sigma, 1e-6)
        pv = historian_record(pv, dev)
        kop = np.flatnonzero(exception_deadband(op, rng.uniform(0.05, 0.2)))
        op = np.interp(t, kop, op[kop])
    return pv, op, sp


def _cycles(pv: np.ndarray, sp: np.ndarray, h: float):
    """(period [s], cycles, regularity) of the record's control error.

    Counted by the generator's own crossings (:func:`cycle_stats`), not by
    the scan's oscillation detector, so that which draws a class accepts
    does not move with the method under test. The regularity is written as
    Thornhill's (mean period over three standard deviations, here robust):
    above 1 the period varies by less than a third.
    """
    period, _, cycles, cv = cycle_stats(np.asarray(pv) - np.asarray(sp), h)
    if not np.isfinite(cv):
        return period, float(cycles), 0.0
    regularity = 1.0 / (3.0 * cv) if cv > 0 else math.inf
    return period, float(cycles), regularity


def _visible_slope_slips(mv: np.ndarray, jump: float, gain: float, noise: float,
                         h: float) -> int:
    """Slips of a valve on an integrating process that its record can show.

    Parameters
    ----------
    mv : numpy.ndarray
        Valve position at the record's samples [OP unit].
    jump : float
        Slip jump ``J`` [OP unit]; a move of at least half of it in one
        sample is a slip.
    gain : float
        The level's slope per unit valve position [PV unit/s per OP unit].
    noise : float
        White measurement noise of the PV [PV unit].
    h : float
        Record sample time [s].

    Returns
    -------
    int

    Notes
    -----
    A slip steps the level's slope by ``gain`` times the valve's move, and
    between slips the level runs straight (the valve stands), so the best
    any reader of the record can do is to fit a line to the stretch on
    either side. A slip counts as visible when its slope step exceeds six
    standard errors of the difference of those two slopes (a line through
    ``m`` samples has a slope error of ``noise sqrt(12 / m^3) / h``): the
    six noise standard deviations by which :func:`_events` counts a flow's
    jumps.
    """
    if not jump > 0:
        return 0
    dm = np.diff(mv)
    at = np.flatnonzero(np.abs(dm) >= 0.5 * jump)
    if at.size == 0:
        return 0
    edges = np.r_[0, at, mv.size - 1].astype(float)
    before, after = np.diff(edges)[:-1], np.diff(edges)[1:]
    se = noise * math.sqrt(12.0) / h * np.sqrt(np.maximum(before, 2.0) ** -3.0
                                                + np.maximum(after, 2.0) ** -3.0)
    return int(np.sum(np.abs(dm[at]) * gain > 6.0 * se))


def _events(pv: np.ndarray, noise: float) -> int:
    """Slips the record shows: runs of consecutive sample-to-sample moves of the
    PV larger than 6 noise sigma, one slip per run (a slip behind the
    process's lag moves the PV over several samples)."""
    big = np.flatnonzero(np.abs(np.diff(pv)) > 6 * noise * math.sqrt(2))
    return int(big.size and 1 + np.count_nonzero(np.diff(big) > 1))


def draw_loop(klass: str, rng: np.random.Generator, *, name: str = "", tries: int = 60,
              cascade: bool = False, level_lag: float | None = None) -> SynthLoop:
    """Simulate one loop of a class, redrawn until its record shows the class.

    Parameters
    ----------
    klass : str
        One of :data:`CLASSES`.
    rng : numpy.random.Generator
    name : str
    tries : int
        Redraws before giving up.
    cascade : bool
        A flow class is drawn as a cascade's inner loop: its set point, the
        outer loop's output, wanders as three sines of 0.1-0.5 [PV unit]
        with periods of 20-120 minutes, on top of the class's own set-point
        moves (:data:`CASCADE_WANDER`). Levels and dead responses are drawn
        as without it. Without it the draws are as they were.
    level_lag : float, optional
        Largest first-order lag between a level's valve and its measured
        level (a damped transmitter, a positioner), as a share of the
        level's time constant; the lag is drawn uniformly below it. By
        default 0.1 (:data:`_PROCESSES`). The random draws are the same, so
        a level is the same draw with its lag scaled (where the record still
        shows its class).

    Returns
    -------
    SynthLoop

    Raises
    ------
    ValueError
        An unknown class, or no draw in ``tries`` showed it.
    """
    if klass not in CLASSES:
        raise ValueError(f"unknown class {klass!r}; choose from {', '.join(CLASSES)}")
    truth, ptype, _ = CLASSES[klass]
    for _ in range(tries):
        out = _try(klass, rng, cascade, level_lag)
        if out is not None:
            pv, op, sp, h, params, mv = out
            return SynthLoop(name=name or klass, klass=klass, truth=truth, process_type=ptype,
                             pv=pv, op=op, sp=sp, sample_time=h, params=params, mv=mv)
    raise ValueError(f"{klass}: no draw in {tries} tries showed the class")


def _try(klass: str, rng: np.random.Generator, cascade: bool = False,
         level_lag: float | None = None):
    """One draw: (pv, op, sp, h, params, mv) or None when the record does not show the class."""
    h = float(rng.choice((1.0, 2.0, 5.0, 10.0)))
    length = float(rng.choice((1.0, 2.0, 4.0))) * 3600 if rng.random() < 0.5 else _DAY
    compressed = bool(rng.random() < 0.3)
    noise_pct = float(rng.uniform(0.5, 3.0))
    hc = h / 2.0
    warm = 4 * 3600.0
    n = int((length + warm) / hc)
    t = np.arange(n) * hc
    p: dict = dict(sample_time=h, length_s=length, compressed=compressed, noise_pct=noise_pct)
    integ = klass.startswith("level")
    sim = dict(sample_time=hc, n_samples=n, sp=50.0, process_gain=1.0,
               process="integrating" if integ else "self-regulating")
    profile_load = np.zeros(n)
    profile_sp = np.zeros(n)
    cycle_expected = CLASSES[klass][2]
    (t_lo, t_hi), (k_lo, k_hi), (i_lo, i_hi), dead, lag, load0 = _PROCESSES[
        "level" if integ else "temperature" if klass.startswith("temperature") else "flow"]
    if integ and level_lag is not None:
        lag = float(level_lag)
    tau = float(np.exp(rng.uniform(np.log(t_lo), np.log(t_hi))))
    kc = float(rng.uniform(k_lo, k_hi))
    ti = float(rng.uniform(i_lo, i_hi)) * tau
    sim.update(tau=tau, kc=kc, ti=ti, load=load0, dead_time=float(rng.uniform(0, dead)) * tau,
               lag=float(rng.uniform(0, lag)) * tau)
    valve, vp = "linear", {}
    if "stiction" in klass:
        S = float(rng.uniform(1.0, 6.0))
        vp = {"S": S, "J": float(rng.uniform(0.2, 1.0)) * S}
        valve = "kano"
    elif "backlash" in klass:
        vp = {"DB": float(rng.uniform(1.0, 6.0))}
        valve = "backlash"
    sim.update(valve=valve, valve_params=vp or None)
    if klass == "level-stiction-sawtooth":
        # the valve closes fully (OP limited at 0) against a small net inflow
        sim.update(load=float(rng.uniform(0.15, 0.4)) * vp["S"], op_limits=(0.0, 100.0))
    elif klass == "level-stiction-events":
        # proportional-only level control: no integral action, no limit cycle
        sim.update(ti=1e12, kc=float(rng.uniform(0.5, 2.0)))
        profile_sp = _random_steps(rng, n, hc, (1200.0, 3600.0), float(rng.uniform(2.0, 6.0)))
        profile_load = _random_walk(rng, n, hc, 600.0, 0.3 * vp["S"])
    elif klass == "flow-stiction-events":
        # slow integral action and a wandering load: the OP creeps for minutes
        sim.update(kc=float(rng.uniform(0.05, 0.3)), ti=float(rng.uniform(60.0, 600.0)))
        profile_load = _random_walk(rng, n, hc, float(rng.uniform(600.0, 1800.0)),
                                    0.25 * vp["S"])
    elif klass == "flow-backlash-events":
        # ordinary tuning and a wandering load: the OP reverses now and then
        sim.update(kc=float(rng.uniform(0.2, 0.6)), ti=float(rng.uniform(1.0, 4.0)) * tau)
        profile_load = _random_walk(rng, n, hc, float(rng.uniform(300.0, 1200.0)),
                                    0.5 * vp["DB"])
    elif klass == "temperature-linear-disturbance":
        # a load from upstream, slow against the loop: a few to many of its
        # time constants a period, so that it settles or nearly between moves
        period = float(rng.uniform(3.0, 15.0)) * (tau + sim["dead_time"])
        kind = str(rng.choice(("square", "triangle", "clipped", "sine")))
        amp = float(rng.uniform(1.0, 5.0))
        profile_load = amp * _wave(kind, t, period, float(rng.uniform(0, 2 * np.pi)))
        p.update(disturbance=kind, disturbance_period_s=period, disturbance_amplitude=amp)
    elif klass.endswith("linear-disturbance"):
        spp = float(rng.uniform(10.0, 60.0))
        period = spp * h
        kind = str(rng.choice(("square", "triangle", "clipped", "sine")))
        amp = float(rng.uniform(1.0, 5.0))
        if integ:
            # a level loop rejects a fast load poorly: the load is a flow [%/s scale]
            sim.update(kc=float(rng.uniform(1.0, 3.0)), ti=float(rng.uniform(1.5, 3.0)) * tau)
        profile_load = amp * _wave(kind, t, period, float(rng.uniform(0, 2 * np.pi)))
        p.update(disturbance=kind, disturbance_period_s=period, disturbance_amplitude=amp)
    elif klass == "level-linear-slow-load":
        # a load that moves every half hour to two hours: a pump that runs for
        # part of each period, or a square, clipped or triangular inflow; the
        # level settles between the load's moves (the valve's flow balances it)
        period = float(rng.uniform(1800.0, 7200.0))
        kind = str(rng.choice(("square", "triangle", "clipped", "pump")))
        amp = float(rng.uniform(1.0, 4.0))
        phase = float(rng.uniform(0, 2 * np.pi))
        if kind == "pump":
            duty = float(rng.uniform(0.2, 0.5))
            on = ((t / period + phase / (2 * np.pi)) % 1.0) < duty
            profile_load = amp * (on - duty)
            p.update(pump_duty=duty)
        else:
            profile_load = amp * _wave(kind, t, period, phase)
        p.update(disturbance=kind, disturbance_period_s=period, disturbance_amplitude=amp)
    elif klass == "level-linear-tuning":
        theta = float(rng.uniform(0.1, 0.4)) * tau
        ti = float(rng.uniform(6.0, 20.0)) * theta
        from ..paper.scenarios import ultimate_gain_pi_integrator

        kc = float(rng.uniform(0.85, 0.97)) * ultimate_gain_pi_integrator(tau, theta, ti)
        sim.update(kc=kc, ti=ti, dead_time=theta, lag=0.0, load_noise_std=0.5)
    elif klass.endswith("healthy"):
        profile_sp = _random_steps(rng, n, hc, (1800.0, 7200.0), float(rng.uniform(1.0, 4.0)))
        profile_load = _random_walk(rng, n, hc, 900.0, 1.0)
        # pumps start and stop: the load steps, as a sticky valve's slip steps the PV
        profile_load += _random_steps(rng, n, hc, (1800.0, 7200.0), float(rng.uniform(1.0, 3.0)))
        if not integ and rng.random() < 0.5:
            # slow integral action, as on the sticky flow valves without a cycle:
            # the error outlasts a load's move and the OP creeps for minutes
            sim.update(kc=float(rng.uniform(0.05, 0.3)), ti=float(rng.uniform(60.0, 600.0)))
    elif klass == "dead-response":
        return _dead_response(rng, h, length, compressed, noise_pct, p)
    if cascade and not integ:
        # the outer loop's output, from a stream of its own (spawning draws
        # nothing from ``rng``): the loop is the same draw as without it
        g = np.random.default_rng(rng.bit_generator.seed_seq.spawn(1)[0])
        lo, hi = CASCADE_WANDER
        wander = sum(g.uniform(lo, hi) * np.sin(2 * np.pi * t / g.uniform(1200.0, 7200.0)
                                                + g.uniform(0, 2 * np.pi)) for _ in range(3))
        profile_sp = profile_sp + wander - wander[0]
        p.update(cascade=True)
    if "stiction" in klass or "backlash" in klass or klass in ("level-linear-tuning",):
        sim.update(sp_step=1.0, sp_step_time=60.0)
    # measurement noise: in % of the clean record's range, fed back to the controller
    # (seeded: a ringing loop's load noise must not make the record differ between runs)
    clean = simulate_loop(**sim, load_profile=profile_load, sp_profile=profile_sp,
                          seed=int(rng.integers(1 << 31)))
    k0 = int(warm / hc)
    rng_pv = float(np.ptp(clean.pv[k0:]))
    if not rng_pv > 0:
        return None
    sigma = noise_pct / 100.0 * rng_pv
    band = 6.0 * abs(sim["kc"]) * sigma if valve == "kano" else 0.0
    run = simulate_loop(**sim, load_profile=profile_load, sp_profile=profile_sp,
                        noise_std=sigma, valve_noise_band=band, seed=int(rng.integers(1 << 31)))
    pv, op, sp = run.pv[k0:], run.op[k0:], run.sp[k0:]
    pv, op, sp = _record(pv, op, sp, rng, compressed, sigma)
    if pv.min() < 0.0 or pv.max() > 100.0:
        # a PV that leaves its span ran away (a level that the valve at its
        # limit could not hold): no record of the class, and no record at all
        return None
    mv = _position_record(run.mv[k0::2][:pv.size], pv, compressed)
    if klass == "level-stiction-events":
        # of the valve's slips, those the level's record shows: at its samples,
        # and through its compression (a stored point's error spreads over the
        # samples drawn between stored points)
        stored = stored_points(pv).size
        noise = max(sigma, white_noise_std(pv) * math.sqrt(pv.size / stored))
        valve_slips = _visible_slope_slips(run.mv[k0::2], vp["J"], 1.0 / tau, noise, h)
    p.update(tau_s=tau, kc=sim["kc"], ti_s=sim["ti"], dead_time_s=sim.get("dead_time", 0.0),
             lag_s=sim.get("lag", 0.0), valve=valve, **vp, noise_sigma=sigma)
    # does the record show its class?
    period, cycles, regularity = _cycles(pv, sp, h)
    p.update(period_s=period, cycles=cycles)
    if cycle_expected:
        if not (np.isfinite(period) and period >= 15 * h and cycles >= 4 and regularity > 1.0):
            return None
        if klass.startswith("flow") and not 30.0 <= period <= 1200.0:
            return None
    elif klass == "flow-backlash-events":
        from ..workbench.kernels import turning_points

        idx, _, _ = turning_points(op, vp["DB"])
        if idx.size < 4:
            return None
        if np.isfinite(period) and cycles >= 4 and regularity > 1.0:
            return None
        p.update(reversals=int(idx.size))
    elif klass.endswith("events") and klass != "level-stiction-events":
        slips = _events(pv, sigma)
        if slips < 3 or np.ptp(op) < 1.0:
            return None
        if np.isfinite(period) and cycles >= 4 and regularity > 1.0:
            return None                      # that would be a limit cycle
        p.update(slips=slips)
    elif klass == "level-stiction-events":
        if np.isfinite(period) and cycles >= 4 and regularity > 1.0:
            return None
        if valve_slips < 3:
            return None                      # no three slips the record can show
        p.update(slips=valve_slips)
    elif klass.endswith("healthy"):
        if np.isfinite(period) and cycles >= 4 and regularity > 1.0:
            return None
    return pv, op, sp, h, p, mv


def _position_record(mv: np.ndarray, pv: np.ndarray, compressed: bool) -> np.ndarray:
    """The valve position as a positioner reports it: 0.1-0.5 % white noise, and
    the OP's exception storage where the record is compressed.

    Its own random stream is seeded from the recorded PV, so that drawing it
    leaves the draws of every other signal as they were."""
    g = np.random.default_rng(zlib.crc32(np.ascontiguousarray(pv).tobytes()))
    out = mv + g.normal(0.0, g.uniform(0.1, 0.5), mv.size)
    if compressed:
        t = np.arange(out.size, dtype=float)
        keep = np.flatnonzero(exception_deadband(out, g.uniform(0.05, 0.2)))
        out = np.interp(t, keep, out[keep])
    return out


def _dead_response(rng, h, length, compressed, noise_pct, p):
    """A PV that does not answer (a valve stuck shut, a closed block valve, a dead
    transmitter) while a PI controller moves its OP over tens of percent."""
    n = int(length / h)
    level = float(rng.choice((0.0, rng.uniform(10, 90))))
    noisy = rng.random() < 0.5
    pv = np.full(n, level) + (rng.normal(0, 0.05, n) if noisy else 0.0)
    # the operator or a cascade moves the set point around the stuck PV
    sp = level + _random_steps(rng, n, h, (900.0, 3600.0), float(rng.uniform(2.0, 8.0)))
    sp += np.where(sp == level, rng.choice((-1.0, 1.0)) * 3.0, 0.0)
    kc, ti = float(rng.uniform(0.2, 1.0)), float(rng.uniform(60.0, 600.0))
    e = sp - pv
    op = np.clip(float(rng.uniform(5, 60)) + kc * e + np.cumsum(e) * h / ti, 0.0, 100.0)
    if np.ptp(op) < 20:
        return None
    pv, op, sp = _record(np.repeat(pv, 2), np.repeat(op, 2), np.repeat(sp, 2), rng, compressed,
                         0.05 if noisy else 0.0)
    p.update(stuck_level=level, kc=kc, ti_s=ti, valve="unknown (no response)",
             period_s=math.nan, cycles=0.0)
    return pv, op, sp, h, p, None


def benchmark_rng(klass: str, seed: int, index: int, *more: int) -> np.random.Generator:
    """The random stream of the realistic benchmark's loop ``index`` of ``klass`` at ``seed``.

    Parameters
    ----------
    klass : str
        A class of :data:`CLASSES`.
    seed : int
        The set's seed (``benchmarks/bench_realistic.py``: study, development
        or held out).
    index : int
        The loop's number within its class.
    *more : int
        Further entries of the seed, for a stream of the loop's own beside
        its draw (the benchmark's gaps).

    Returns
    -------
    numpy.random.Generator
        Seeded by ``[seed, position of klass in CLASSES, index, *more]``:
        ``draw_loop(klass, benchmark_rng(klass, seed, index))`` is the loop
        the benchmark scans.
    """
    return np.random.default_rng([seed, list(CLASSES).index(klass), index, *more])


def loop_set(n_per_class: int, seed: int, classes=None) -> list[SynthLoop]:
    """``n_per_class`` loops of every class, reproducibly.

    Parameters
    ----------
    n_per_class : int
    seed : int
        Seed of the whole set (each loop gets its own stream).
    classes : sequence of str, optional
        Default every class of :data:`CLASSES`.

    Returns
    -------
    list of SynthLoop
    """
    out = []
    for ci, klass in enumerate(classes or CLASSES):
        for i in range(n_per_class):
            rng = np.random.default_rng([seed, ci, i])
            out.append(draw_loop(klass, rng, name=f"{klass}-{i:02d}"))
    return out
