"""
Synthetic plant: historian exports of many control loops with known truth.

:func:`synth_plant` simulates a plant of ``n_loops`` PI loops with the
closed-loop simulator (:func:`valvediag.models.closedloop.simulate_loop`), makes the
records look like a process historian's (tag names, engineering units, digital
states, gaps, exception and swinging-door compression, status flags) and
writes them as exports, together with the loop registry (``loops.csv``) and
the answer key (``truth.csv``)::

    >>> from valvediag.synth.plant import synth_plant
    >>> plant = synth_plant(40, days=0.25, sample_time=1.0, out_dir="out/plant", seed=1)
    >>> plant.truth.group_by("truth_verdict").len()

The demo, the tests and the benchmarks use it. The library part is pure (the
numerics and :func:`swinging_door` / :func:`exception_deadband`); only
:func:`synth_plant` writes files.

References
----------
.. [1] Farenzena, M., Trierweiler, J. O. (2012). Valve backlash and stiction
   detection in integrating processes. 8th IFAC Symposium on Advanced Control
   of Chemical Processes (ADCHEM), Singapore, 320-325.
.. [2] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston.
.. [3] Bristol, E. H. (1990). Swinging door trending: adaptive trend recording?
   ISA National Conference Proceedings, 749-754.
"""
from __future__ import annotations

import datetime as _dt
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numba
import numpy as np
import polars as pl

from ..models.closedloop import simulate_loop

__all__ = [
    "synth_plant", "SynthPlant", "swinging_door", "exception_deadband", "historian_record",
    "cycle_stats",
    "CATEGORY_SHARES", "CATEGORY_VERDICT", "TRUTH_VERDICTS", "DIGITAL_STATES", "STATUS_FLAGS",
    "FORMATS", "LOOPS_COLUMNS", "TRUTH_COLUMNS", "EXPORT_COLUMNS",
]

# ----------------------------------------------------------------- contracts

#: Loop verdicts, in the order the classifier tests them.
TRUTH_VERDICTS = ("insufficient-data", "no-oscillation", "linear-oscillation", "stiction",
                  "backlash")

#: Category of synthetic loop -> nominal share of the plant.
CATEGORY_SHARES: dict[str, float] = {
    "stiction": 0.20,            # integrating, Kano valve
    "backlash": 0.15,            # integrating, dead-band valve
    "linear-oscillation": 0.10,  # integrating, linear valve, sine load or ringing tuning
    "healthy": 0.25,             # integrating, linear valve, well tuned
    "selfreg-stiction": 0.075,   # self-regulating, Kano valve
    "selfreg-healthy": 0.075,    # self-regulating, linear valve
    "bad-data": 0.15,            # any of the above behind unusable data
}

#: Category -> truth verdict.
CATEGORY_VERDICT: dict[str, str] = {
    "stiction": "stiction", "backlash": "backlash",
    "linear-oscillation": "linear-oscillation", "healthy": "no-oscillation",
    "selfreg-stiction": "stiction", "selfreg-healthy": "no-oscillation",
    "bad-data": "insufficient-data",
}

# order in which small plants get their first loop of each category
_PRIORITY = ("stiction", "healthy", "backlash", "linear-oscillation", "selfreg-stiction",
             "bad-data", "selfreg-healthy")

#: PI system digital states written as text into the value column.
DIGITAL_STATES = ("I/O Timeout", "Bad Input", "Comm Fail", "Scan Timeout", "Bad Data",
                  "Shutdown", "No Data")
_BURST_STATES = DIGITAL_STATES[:5]
_SHUTDOWN = DIGITAL_STATES.index("Shutdown") + 1

#: Status flags of good values.
STATUS_FLAGS = ("Questionable", "Substituted")
_QUESTIONABLE, _SUBSTITUTED = 1, 2

#: Export formats understood by :func:`synth_plant`.
FORMATS = ("long-csv", "wide-csv", "parquet")

LOOPS_COLUMNS = ("loop", "pv_tag", "op_tag", "sp_tag", "mv_tag", "process_type", "unit", "span",
                 "criticality", "description")
TRUTH_COLUMNS = ("loop", "truth_verdict", "process_type", "valve", "fault_params", "period_s",
                 "amplitude", "noise_pct", "notes")
EXPORT_COLUMNS = ("tag", "timestamp", "value", "status")

_BAD_KINDS = ("pv-missing", "pv-bad-states", "pv-frozen", "too-short")
_FAULTS = ("stiction", "backlash", "selfreg-stiction")
# share of usable loops given each artefact (at least one loop each)
_ARTEFACT_RATES = {"burst": 0.3, "gap": 0.2, "questionable": 0.1, "substituted": 0.05}
_STORAGE = (("sampled", 0.7), ("exception", 0.12), ("swinging-door", 0.18))
_SHUTDOWN_RATE = 0.4  # interface restarts per export group and day
_DAY = 86400.0


# ------------------------------------------------------ historian compression

@numba.njit(cache=True)
def _exception_kernel(x, dev, max_gap):
    n = x.size
    keep = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return keep
    keep[0] = True
    last = x[0]
    tl = 0
    for k in range(1, n):
        if abs(x[k] - last) > dev:
            keep[k] = True
            if k - 1 > tl:
                keep[k - 1] = True  # PI also reports the value before the exception
            last = x[k]
            tl = k
        elif k - tl >= max_gap:
            keep[k] = True
            last = x[k]
            tl = k
    return keep


@numba.njit(cache=True)
def _sdt_kernel(t, x, dev, max_gap):
    n = x.size
    keep = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return keep
    keep[0] = True
    keep[n - 1] = True
    ta = t[0]
    xa = x[0]
    s_up = -np.inf   # steepest slope from the upper pivot (xa + dev) to a point
    s_lo = np.inf    # flattest slope from the lower pivot (xa - dev) to a point
    j = 1
    while j < n:
        dt = t[j] - ta
        if dt >= max_gap and j > 0 and not keep[j - 1]:
            keep[j - 1] = True
            ta = t[j - 1]
            xa = x[j - 1]
            s_up = -np.inf
            s_lo = np.inf
            continue
        su = (x[j] - xa - dev) / dt
        sl = (x[j] - xa + dev) / dt
        nu = su if su > s_up else s_up
        nl = sl if sl < s_lo else s_lo
        if nu > nl:
            # the doors opened: archive the previous point and restart from it
            keep[j - 1] = True
            ta = t[j - 1]
            xa = x[j - 1]
            s_up = -np.inf
            s_lo = np.inf
            continue
        s_up = nu
        s_lo = nl
        j += 1
    return keep


def exception_deadband(x, deviation: float, max_interval: int | None = None) -> np.ndarray:
    """Exception reporting with a dead band, as a historian interface does it.

    Parameters
    ----------
    x : array_like, shape (n,)
        Snapshot values on a uniform grid [PV unit].
    deviation : float
        Exception deviation [PV unit]: a value is reported when it differs from
        the last reported value by more than this.
    max_interval : int, optional
        Exception maximum time [samples]: a value is reported at least this
        often. Default: never forced.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
        True where the sample is reported (stored).

    Notes
    -----
    As in OSIsoft PI, the value just before an exception is reported as well,
    so a step is stored as two points. A signal that stays inside the dead band
    is held: reading it back with step or linear interpolation shows flat runs
    that a valve model may take for a resting input.
    """
    xa = np.ascontiguousarray(x, dtype=float)
    mg = np.iinfo(np.int64).max if max_interval is None else int(max_interval)
    return _exception_kernel(xa, float(deviation), max(mg, 1))


def swinging_door(x, deviation: float, max_interval: float | None = None, t=None) -> np.ndarray:
    """Swinging-door trending compression (Bristol 1990).

    Parameters
    ----------
    x : array_like, shape (n,)
        Values to compress [PV unit].
    deviation : float
        Compression deviation [PV unit]: the half-width of the doors hinged
        at the last archived value (its pivots are that value +- deviation).
    max_interval : float, optional
        Compression maximum time [unit of ``t``]: the gap between stored points
        never exceeds it (the point before the gap limit is stored). Default:
        none.
    t : array_like, shape (n,), optional
        Sample times, increasing [any time unit]; default ``0, 1, ..., n-1``.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
        True where the value is archived. The first and last values are
        always archived.

    Notes
    -----
    Each archived value is the last snapshot for which a straight line from
    the previous archived value's door pivots still fits every value in
    between; the next one is archived when the doors open. Every discarded
    value then lies inside the closing triangle of the doors, so linear
    interpolation between archived values reproduces it to within
    ``2 * deviation`` (typically 80 % of values within ``deviation``).
    Straight ramps (a stiction triangle) compress to their corners, while
    rounded peaks keep more points; the waveform shape survives only if
    several points per cycle are kept.

    References
    ----------
    .. [1] Bristol, E. H. (1990). Swinging door trending: adaptive trend
       recording? ISA National Conference Proceedings, 749-754.
    """
    xa = np.ascontiguousarray(x, dtype=float)
    ta = np.arange(xa.size, dtype=float) if t is None else np.ascontiguousarray(t, dtype=float)
    if ta.shape != xa.shape:
        raise ValueError("t and x must have the same shape")
    mg = np.inf if max_interval is None else float(max_interval)
    return _sdt_kernel(ta, xa, max(float(deviation), 0.0), mg)


def historian_record(x, deviation: float) -> np.ndarray:
    """A record as a historian with compression on stores it and reads it back.

    Exception reporting at half the deviation (:func:`exception_deadband`),
    then a swinging door at the deviation (:func:`swinging_door`), then
    straight lines between the stored points on the original grid.

    Parameters
    ----------
    x : array_like, shape (n,)
        Snapshot values on a uniform grid [unit of x].
    deviation : float
        Compression deviation [unit of x].

    Returns
    -------
    numpy.ndarray, shape (n,)
        The record read back by linear interpolation [unit of x].
    """
    x = np.asarray(x, dtype=float)
    t = np.arange(x.size, dtype=float)
    exc = np.flatnonzero(exception_deadband(x, deviation / 2))
    keep = exc[swinging_door(x[exc], deviation, t=exc.astype(float))]
    return np.interp(t, keep, x[keep])


# ------------------------------------------------------------ cycle analysis


def cycle_stats(x, h):
    """Period, amplitude and regularity of a simulated record's oscillation.

    The synthetic data's own count of cycles, independent of the scan's
    oscillation detector (:func:`valvediag.analysis.detect_oscillation`), so
    that what a generator labels as cycling does not depend on the method
    under test.

    Parameters
    ----------
    x : array_like, shape (n,)
        The record, gap-free [any unit].
    h : float
        Sample time [s].

    Returns
    -------
    period : float
        Median period [s]; NaN when fewer than three upward crossings.
    amplitude : float
        Median half peak-to-peak amplitude [unit of x].
    cycles : int
        Number of whole cycles between upward crossings.
    cv : float
        Robust coefficient of variation of the period (1.4826 MAD / median),
        so that one odd cycle after a set-point step does not count.

    Notes
    -----
    Crossings of a hysteresis band (30 % of the half range between the 1st
    and 99th percentiles, centred on the mid-range) delimit the cycles;
    crossing times are interpolated linearly. A record whose oscillation is
    smaller than a third of its range (a cycle riding on large steps or
    drift) shows no cycle here, and noise larger than the band makes
    crossings at random (a large ``cv``).
    """
    x = np.asarray(x, dtype=float)
    if x.size < 4:
        return math.nan, math.nan, 0, math.nan
    lo, hi = np.quantile(x, [0.01, 0.99])
    half = 0.5 * (hi - lo)
    if not half > 0:
        return math.nan, 0.0, 0, math.nan
    c = x - 0.5 * (hi + lo)
    band = 0.3 * half
    state = np.where(c > band, 1, np.where(c < -band, -1, 0))
    idx = np.where(state != 0, np.arange(c.size), 0)
    np.maximum.accumulate(idx, out=idx)
    s = state[idx]
    ups = np.flatnonzero((s[1:] == 1) & (s[:-1] == -1)) + 1
    if ups.size < 3:
        return math.nan, math.nan, max(ups.size - 1, 0), math.nan
    c0, c1 = c[ups - 1], c[ups]
    tc = (ups - 1) + (band - c0) / np.where(c1 > c0, c1 - c0, 1.0)
    per = np.diff(tc) * h
    amp = 0.5 * (np.maximum.reduceat(c, ups)[:-1] - np.minimum.reduceat(c, ups)[:-1])
    med = float(np.median(per))
    return med, float(np.median(amp)), int(per.size), float(1.4826 * np.median(np.abs(per - med)) / med)


def _oscillates(P, A, ncyc, cv, min_cycles=8):
    return bool(np.isfinite(P) and A > 0 and ncyc >= min_cycles and cv < 0.15)


# --------------------------------------------------------------- loop specs

@dataclass
class _Loop:
    """Everything drawn for one loop (internal, mutable while building)."""

    idx: int
    category: str
    name: str = ""
    prefix: str = ""
    process: str = "integrating"
    meta_process: str = "integrating"
    unit: str = "%"
    lo: float = 0.0
    span: float = 100.0
    sp_pct: float = 50.0
    op0: float = 50.0
    description: str = ""
    criticality: float = 1.0  # ranking weight >= 0: 3 high, 2 medium, 1 low
    valve: str = "linear"
    S: float = 0.0
    J: float = 0.0
    DB: float = 0.0
    kc: float = 1.0      # normalised gain [%OP per normalised PV unit]
    ti_r: float = 1.0    # Ti / tau
    lag_r: float = 0.0   # lag / tau
    dt_r: float = 0.0    # dead time / tau
    tau_paper: float = 50.0  # drawn time constant before stretching [s]
    tau: float = 50.0    # time constant used [s]
    g: float = 1.0       # PV [% of span] per normalised PV unit
    variant: str = ""    # linear: sine-load|tuning ; bad-data: kind
    base: str = ""       # bad-data: underlying category
    zeta: float = math.nan
    p_n: float = math.nan  # pilot period / tau
    a_n: float = math.nan  # pilot amplitude [normalised PV]
    period: float = math.nan  # target period [s] then measured
    amp_pct: float = math.nan  # target amplitude [% span] then measured
    op_amp: float = math.nan   # target OP amplitude [%]
    noise_pct: float = 1.0     # noise [% of amplitude] (oscillating) or [% of span]
    noise_span: float = 0.1    # noise std [% of span]
    sp_step: float = 0.0       # [% of span]
    sp_step_t: float = math.inf  # [s into the record]
    load_step: float = 0.0     # [% OP]
    load_step_t: float = math.inf
    load_drift: float = 0.0    # [% OP over the record]
    sin_amp: float = 0.0       # slow load sinusoid [% OP]
    sin_period: float = math.inf
    sin_phase: float = 0.0
    comps: tuple = ()          # linear-oscillation loads: (period [s], phase [rad], amplitude)
    storage: str = "sampled"   # sampled | exception | swinging-door
    has_mv: bool = False
    fmt: str = "long-csv"
    group: int = 0
    oscillates: bool = False
    notes: list = field(default_factory=list)
    artefacts: list = field(default_factory=list)
    art: set = field(default_factory=set)
    pv_dec: int = 4

    @property
    def verdict(self):
        return CATEGORY_VERDICT[self.category]

    @property
    def sim_category(self):
        return self.base if self.category == "bad-data" else self.category


@dataclass(frozen=True)
class _Timing:
    ts: float        # historian sample time [s]
    n: int           # recorded samples
    m: int           # controller samples per historian sample
    h: float         # controller sample time [s]
    p_lo: float      # shortest oscillation period [s]
    p_hi: float      # longest oscillation period [s]
    duration: float  # record length [s]


def _timing(days, sample_time):
    ts = float(sample_time)
    if not (np.isfinite(ts) and ts > 0):
        raise ValueError(f"sample_time must be > 0 [s], got {sample_time!r}")
    if not (np.isfinite(days) and days > 0):
        raise ValueError(f"days must be > 0, got {days!r}")
    duration = float(days) * _DAY
    n = int(round(duration / ts))
    p_lo = max(30.0 * ts, 20.0)
    if duration < 15 * p_lo:
        raise ValueError(
            f"a record of {duration:g} s is too short for sample_time {ts:g} s: the plant needs "
            f"at least 15 oscillation periods of {p_lo:g} s (30 samples each), i.e. "
            f"days >= {15 * p_lo / _DAY:.4g}")
    p_hi = max(1.5 * p_lo, min(1200.0, duration / 15.0))
    m = max(1, math.ceil(ts / (p_lo / 60.0)))
    return _Timing(ts=ts, n=n, m=m, h=ts / m, p_lo=p_lo, p_hi=p_hi, duration=n * ts)


def _allocate(n, rng):
    """Category of every loop: shares rounded, at least one of each where n allows."""
    cats = list(CATEGORY_SHARES)
    if n < len(cats):
        chosen = list(_PRIORITY[:n])
    else:
        exact = np.array([CATEGORY_SHARES[c] * n for c in cats])
        cnt = np.maximum(np.floor(exact).astype(int), 1)
        while cnt.sum() < n:
            cnt[np.argmax(exact - cnt)] += 1
        while cnt.sum() > n:
            cand = np.where(cnt > 1, cnt - exact, -np.inf)
            cnt[np.argmax(cand)] -= 1
        chosen = [c for c, k in zip(cats, cnt) for _ in range(k)]
    order = rng.permutation(len(chosen))
    return [chosen[i] for i in order]


# engineering ranges: prefix -> list of (unit, low limits, spans, weight)
_UNITS = {
    "LIC": [("%", (0.0,), (100.0,), 0.6), ("m", (0.0,), (2.0, 2.5, 3.0, 4.0, 6.0), 0.25),
            ("mm", (0.0,), (800.0, 1000.0, 1500.0, 2000.0), 0.15)],
    "PIC-int": [("barg", (0.0,), (6.0, 10.0, 16.0), 0.6), ("kPa", (0.0,), (400.0, 600.0, 1000.0), 0.4)],
    "FIC": [("m3/h", (0.0,), (25.0, 50.0, 100.0, 200.0, 400.0), 0.4),
            ("t/h", (0.0,), (10.0, 20.0, 50.0, 100.0), 0.3),
            ("kg/h", (0.0,), (500.0, 1000.0, 2000.0, 5000.0), 0.15),
            ("Nm3/h", (0.0,), (1000.0, 2500.0, 5000.0), 0.15)],
    "TIC": [("degC", (0.0, 0.0, 50.0, 100.0), (150.0, 200.0, 300.0, 400.0), 1.0)],
    "PIC": [("barg", (0.0,), (6.0, 10.0, 16.0, 25.0, 40.0), 0.6), ("kPa", (0.0,), (250.0, 500.0, 1000.0), 0.4)],
}
_DESCRIPTIONS = {
    "LIC": ("Separator V-{e} level", "Reflux drum D-{e} level", "Surge tank TK-{e} level",
            "Flash drum V-{e} level", "Condensate pot V-{e} level", "Deaerator D-{e} level",
            "Column C-{e} bottoms level", "Knock-out drum V-{e} level"),
    "PIC-int": ("Fuel gas header pressure", "Flare knock-out drum V-{e} pressure",
                "Gas holder H-{e} pressure", "Steam header pressure"),
    "FIC": ("Feed to C-{e} flow", "Reflux to C-{e} flow", "Cooling water to E-{e} flow",
            "Product to TK-{e} flow", "Steam to E-{e} flow", "Recycle from P-{e} flow"),
    "TIC": ("Reboiler E-{e} outlet temperature", "Furnace H-{e} coil outlet temperature",
            "Reactor R-{e} inlet temperature", "Cooler E-{e} outlet temperature"),
    "PIC": ("Compressor K-{e} suction pressure", "Column C-{e} top pressure",
            "Pump P-{e} discharge pressure", "Reactor R-{e} pressure"),
}


def _pick(rng, seq, p=None):
    return seq[int(rng.choice(len(seq), p=p))]


def _loguniform(rng, a, b):
    return float(np.exp(rng.uniform(np.log(a), np.log(b))))


def _describe(lp, rng):
    """Name, tag prefix, unit, span, set point and operating point."""
    if lp.process == "integrating":
        key = "LIC" if rng.random() < 0.85 else "PIC-int"
    else:
        key = _pick(rng, ("FIC", "TIC", "PIC"), p=(0.5, 0.25, 0.25))
    lp.prefix = key.split("-")[0]
    area = 1 + lp.idx // 90
    lp.name = f"{lp.prefix}{area}{1 + lp.idx % 90:02d}"
    units = _UNITS[key]
    unit, los, spans, _ = units[int(rng.choice(len(units), p=[u[3] for u in units]))]
    lp.unit = unit
    lp.lo = float(_pick(rng, los))
    lp.span = float(_pick(rng, spans))
    res = lp.span / 1000.0
    sp_eng = lp.lo + round(rng.uniform(0.3, 0.7) * lp.span / res) * res
    lp.sp_pct = 100.0 * (sp_eng - lp.lo) / lp.span
    lp.op0 = float(rng.uniform(25.0, 70.0))
    lp.pv_dec = int(np.clip(6 - math.ceil(math.log10(lp.span + lp.lo + 1e-12)), 1, 6))
    lp.description = _pick(rng, _DESCRIPTIONS[key]).format(e=f"{area}{rng.integers(1, 99):02d}")
    lp.criticality = float(_pick(rng, (3.0, 2.0, 1.0), p=(0.15, 0.45, 0.4)))


def _draw_valve_fault(lp, rng):
    """Paper ranges for the loop and the valve (normalised: tau = 1, K = 1)."""
    if lp.process == "integrating":
        lp.kc = float(rng.uniform(0.7, 4.0))
        lp.ti_r = float(rng.uniform(1.0, 2.4))
        lp.tau_paper = _loguniform(rng, 10.0, 100.0)
        lp.lag_r = 0.0
        lp.dt_r = 0.0
    else:
        lp.kc = float(rng.uniform(0.3, 1.5))
        lp.ti_r = float(rng.uniform(0.5, 1.5))
        lp.dt_r = float(rng.uniform(0.02, 0.3))
        lp.tau_paper = {"FIC": _loguniform(rng, 3.0, 30.0), "TIC": _loguniform(rng, 60.0, 300.0),
                        "PIC": _loguniform(rng, 10.0, 60.0)}[lp.prefix]
    if lp.sim_category == "backlash":
        lp.valve = "backlash"
        lp.DB = round(float(rng.uniform(0.5, 6.0)), 1)
    else:
        lp.valve = "kano"
        lp.S = round(float(rng.uniform(1.0, 6.0)), 1)
        lp.J = round(min(lp.S, lp.S * float(rng.uniform(0.5, 1.0))), 2)


def _damping(kc, ti, lag):
    """Damping of the least damped closed-loop pair of PI + K/(s (lag s + 1))."""
    r = np.roots([lag, 1.0, kc, kc / ti]) if lag > 0 else np.roots([1.0, kc, kc / ti])
    cx = r[np.abs(r.imag) > 1e-12]
    if cx.size == 0:
        return 1.0, math.nan
    d = cx[np.argmax(cx.real)]
    return float(-d.real / abs(d)), float(abs(d.imag))


def _ti_for_damping(kc, lag, zeta):
    lo, hi = math.log(1e-4), math.log(1e3)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        z, _ = _damping(kc, math.exp(mid), lag)
        if z < zeta:
            lo = mid
        else:
            hi = mid
    ti = math.exp(0.5 * (lo + hi))
    z, w = _damping(kc, ti, lag)
    return ti, z, w


def _draw_linear(lp, rng, tm):
    lp.valve = "linear"
    cat = lp.sim_category
    if cat == "linear-oscillation":
        lp.period = _loguniform(rng, tm.p_lo, tm.p_hi)
        lp.amp_pct = float(rng.uniform(0.6, 4.0))
        lp.op_amp = float(rng.uniform(1.5, 6.0))
        if lp.variant == "sine-load":
            lp.kc = float(rng.uniform(0.7, 4.0))
            lp.zeta = float(rng.uniform(0.6, 1.0))
            lp.ti_r = 4 * lp.zeta ** 2 / lp.kc
            lp.tau = lp.period / float(rng.uniform(4.0, 15.0))
            lp.comps = ((lp.period, float(rng.uniform(0, 2 * np.pi)), 1.0),)
        else:
            lp.kc = float(rng.uniform(0.5, 2.0))
            lp.lag_r = float(rng.uniform(0.02, 0.08))
            lp.ti_r, lp.zeta, w = _ti_for_damping(lp.kc, lp.lag_r, float(rng.uniform(0.04, 0.08)))
            p_res_n = 2 * np.pi / w
            lp.tau = lp.period / p_res_n
            # a narrow band of load around the resonance: one main line and weak side lines
            ratios = np.array([1.0, 0.8, 0.9, 1.12, 1.25]) * rng.uniform(0.98, 1.02, 5)
            weights = np.array([1.0, 0.2, 0.2, 0.2, 0.2])
            lp.comps = tuple((float(lp.period * r), float(rng.uniform(0, 2 * np.pi)), float(w))
                             for r, w in zip(ratios, weights))
        lp.noise_pct = float(rng.uniform(0.5, 2.0))
    else:  # healthy, integrating or self-regulating
        lp.zeta = float(rng.uniform(0.8, 1.3))
        if lp.process == "integrating":
            lp.kc = float(rng.uniform(0.7, 4.0))
            lp.ti_r = 4 * lp.zeta ** 2 / lp.kc
            lp.lag_r = float(rng.uniform(0.0, 0.03))
            lp.tau = _loguniform(rng, 20.0, 300.0)
        else:
            lp.kc = float(rng.uniform(0.3, 1.2))
            lp.ti_r = float(rng.uniform(0.7, 1.2))
            lp.dt_r = float(rng.uniform(0.0, 0.2))
            lp.tau = {"FIC": _loguniform(rng, 3.0, 30.0), "TIC": _loguniform(rng, 60.0, 300.0),
                      "PIC": _loguniform(rng, 10.0, 60.0)}[lp.prefix]
        lp.g = _loguniform(rng, 0.5, 2.0)
        lp.noise_span = float(rng.uniform(0.05, 0.4))
        lp.noise_pct = lp.noise_span
        lp.sin_amp = float(rng.uniform(1.0, 4.0))
        lp.sin_period = float(rng.uniform(3.0, 12.0)) * 3600.0
        lp.sin_phase = float(rng.uniform(0, 2 * np.pi))


def _draw_disturbances(lp, rng, tm):
    """Operator set-point moves and load changes of linear loops.

    Fault loops get neither: a Kano loop may have several limit cycles, and a
    set-point step can move it to another one with a different period (seen
    in about one loop in ten); a load ramp stretches the cycle. Their record
    is then exactly the cycle the second pilot checked.
    """
    if lp.sim_category in _FAULTS:
        return
    lp.load_drift = float(rng.uniform(-3.0, 3.0))
    if lp.variant == "tuning":
        return  # steps would ring for many cycles and mask the stated amplitude
    if rng.random() < 0.15:
        lp.sp_step = float(rng.choice([-1, 1]) * rng.uniform(1.0, 4.0))
        lp.sp_step_t = float(rng.uniform(0.2, 0.8) * tm.duration)
    if rng.random() < 0.4:
        lp.load_step = float(rng.choice([-1, 1]) * rng.uniform(0.5, 3.0))
        lp.load_step_t = float(rng.uniform(0.1, 0.9) * tm.duration)


# ----------------------------------------------------------------- simulation

_PILOT_H = 1.0 / 60.0
_PILOT_N = 30000
_SIM_BYTES = 256e6  # memory budget of one simulator call
_WARM_PERIODS = 20  # simulated periods before a fault loop's record starts


def _pilot(loops, seed, tm=None):
    """Simulate valve-fault loops in normalised time (tau = 1): cycle statistics per loop.

    Without ``tm`` the loops run at ``tau/60`` for 30000 samples and the
    second half is measured. With it, they run at the final controller rate
    (``tm.h / lp.tau``) and the window measured is the one the record will
    cover (after the same warm-up; at most 100 periods of it), so that the
    check sees the dynamics the record will have, slow convergence to the
    limit cycle included.
    """
    out = {}
    for process in ("integrating", "self-regulating"):
        every = [lp for lp in loops if lp.process == process]
        if tm is None:
            span_of = {lp.idx: (_PILOT_N // 2, _PILOT_N) for lp in every}
        else:  # the final run's warm-up, then the record (or 100 periods of it)
            span_of = {}
            for lp in every:
                per = lp.p_n * lp.tau
                a = int(np.ceil(_WARM_PERIODS * per / tm.h))
                span_of[lp.idx] = (a, a + int(np.ceil(min(tm.duration, 100 * per) / tm.h)))
        n_of = {k: v[1] for k, v in span_of.items()}
        every.sort(key=lambda lp: n_of[lp.idx])
        while every:
            n = n_of[every[-1].idx]
            k = max(1, int(_SIM_BYTES // (n * 32)))
            sel, every = every[-k:], every[:-k]
            h = np.full(len(sel), _PILOT_H) if tm is None else np.array([tm.h / lp.tau for lp in sel])
            sim = simulate_loop(
                kc=np.array([lp.kc for lp in sel]), ti=np.array([lp.ti_r for lp in sel]),
                sample_time=h, n_samples=n, valve=np.array([lp.valve for lp in sel], dtype=object),
                valve_params={"S": np.array([lp.S for lp in sel]), "J": np.array([lp.J for lp in sel]),
                              "DB": np.array([lp.DB for lp in sel])},
                process=process, tau=1.0, lag=np.array([lp.lag_r for lp in sel]),
                dead_time=np.array([lp.dt_r for lp in sel]), sp=0.0,
                load=np.array([lp.op0 for lp in sel]), load_step=1.0, load_step_time=h,
                seed=seed, op_limits=(0.0, 100.0))
            pv = np.atleast_2d(sim.pv)
            for i, lp in enumerate(sel):
                a, b = span_of[lp.idx]
                out[lp.idx] = cycle_stats(pv[i, a:b], h[i])
            del sim, pv
    return out


def _scenarios(lp, tm, warm):
    """Scenario parameter dicts of one loop (first: base; then load components)."""
    T = lambda s: warm + s  # record time -> simulation time
    total = warm + tm.duration
    base = dict(kc=lp.kc, ti=lp.ti_r * lp.tau, valve=lp.valve, S=lp.S, J=lp.J, DB=lp.DB,
                tau=lp.tau, lag=lp.lag_r * lp.tau, dead_time=lp.dt_r * lp.tau,
                sp_step=lp.sp_step / lp.g, sp_step_time=T(lp.sp_step_t),
                load=lp.op0, load_step=lp.load_step, load_step_time=T(lp.load_step_t),
                load_drift=lp.load_drift / total, sin_a=lp.sin_amp, sin_p=lp.sin_period,
                sin_phi=lp.sin_phase, noise=0.0, vband=0.0)
    if lp.valve != "linear":
        # Kick the stuck valve at the start of the warm-up. No load drift: a
        # steady load ramp changes a stiction cycle's period by up to 50 %, so
        # the record would no longer match the pilot's period.
        base["load_step"], base["load_step_time"] = 1.0, tm.h
        base["load_drift"] = 0.0
        # the measurement noise goes round the loop, as on a plant: the
        # controller answers it, and the limit cycle's phase wanders with it.
        # Kano's actuator ignores reversals within its noise band [OP units]
        sigma = _fault_noise_span(lp) / lp.g
        base["noise"] = sigma
        base["vband"] = 6.0 * abs(lp.kc) * sigma if lp.valve == "kano" else 0.0
    else:
        base["noise"] = lp.noise_span / lp.g
    rows = [base]
    for per, phi, w in lp.comps:
        rows.append(dict(base, sp_step=0.0, load=0.0, load_step=0.0, load_drift=0.0, sin_a=w,
                         sin_p=per, sin_phi=phi, noise=0.0, vband=0.0))
    return rows


def _simulate(loops, tm, seed, process, linear):
    """Simulate a batch of loops of one process type; yields (loop, record dict).

    Loops are simulated in chunks sized to keep memory bounded; a loop's load
    components stay in the same chunk so they can be summed.
    """
    if not loops:
        return
    warm_of = []
    for lp in loops:
        if np.isfinite(lp.period):
            warm_of.append(_WARM_PERIODS * lp.period)
        else:
            warm_of.append(min(7200.0, 10.0 * max(lp.tau, lp.ti_r * lp.tau)))
    warm = float(np.ceil(max(warm_of) / tm.ts) * tm.ts)
    n_warm = int(round(warm / tm.h))
    n_total = n_warm + tm.n * tm.m
    max_sc = max(1, int(_SIM_BYTES // (n_total * 32)))
    seeds = np.random.SeedSequence(seed).generate_state(len(loops) + 1)
    chunks, cur, cur_n = [], [], 0
    for lp in loops:
        k = 1 + len(lp.comps)
        if cur and cur_n + k > max_sc:
            chunks.append(cur)
            cur, cur_n = [], 0
        cur.append(lp)
        cur_n += k
    if cur:
        chunks.append(cur)
    for ci, chunk in enumerate(chunks):
        rows, owner = [], []
        for lp in chunk:
            sc = _scenarios(lp, tm, warm)
            rows += sc
            owner += [lp.idx] * len(sc)
        col = lambda key: np.array([r[key] for r in rows], dtype=float)
        sim = simulate_loop(
            kc=col("kc"), ti=col("ti"), sample_time=tm.h, n_samples=n_total,
            valve=np.array([r["valve"] for r in rows], dtype=object),
            valve_params={"S": col("S"), "J": col("J"), "DB": col("DB")},
            process=process, tau=col("tau"), lag=col("lag"), dead_time=col("dead_time"),
            sp=0.0, sp_step=col("sp_step"), sp_step_time=col("sp_step_time"),
            load=col("load"), load_step=col("load_step"), load_step_time=col("load_step_time"),
            load_drift=col("load_drift"), load_sin_amplitude=col("sin_a"),
            load_sin_period=col("sin_p"), load_sin_phase=col("sin_phi"),
            noise_std=col("noise"), valve_noise_band=col("vband"), seed=int(seeds[ci]),
            op_limits=(-np.inf, np.inf) if linear else (0.0, 100.0))
        pv, op, mv, sp = (np.atleast_2d(a) for a in (sim.pv, sim.op, sim.mv, sim.sp))
        owner = np.array(owner)
        rec = slice(n_warm, n_total, tm.m)
        for lp in chunk:
            rows_i = np.flatnonzero(owner == lp.idx)
            b = rows_i[0]
            out = {"pv": pv[b, rec].copy(), "op": op[b, rec].copy(), "mv": mv[b, rec].copy(),
                   "sp": sp[b, rec].copy()}
            if rows_i.size > 1:
                cpv = pv[rows_i[1:], n_warm:].sum(axis=0)
                cop = op[rows_i[1:], n_warm:].sum(axis=0)
                out["clean_pv"] = cpv[::tm.m].copy()
                out["clean_op"] = cop[::tm.m].copy()
                out["stats_pv"] = cycle_stats(cpv, tm.h)
                out["stats_op"] = cycle_stats(cop, tm.h)
            else:
                out["stats_pv"] = cycle_stats(pv[b, n_warm:] - sp[b, n_warm:], tm.h)
            yield lp, out
        del sim, pv, op, mv, sp


def _simulate_linear_osc(loops, tm, seed):
    """Linear oscillation loops: clean load responses first, then the scaled loop.

    The loop is linear, so the record is the noisy base run plus ``c`` times the
    sum of the responses to unit sinusoidal loads (superposition). ``c`` sets
    the OP amplitude and the PV scale ``g`` sets the PV amplitude.
    """
    recs = {}
    # pass 1: the load components (the base row is simulated too, and ignored)
    clean = {}
    for lp, out in _simulate(loops, tm, seed, "integrating", linear=True):
        P, A_pv, ncyc, cv = out["stats_pv"]
        _, A_op, _, _ = out["stats_op"]
        c = lp.op_amp / A_op
        lp.g = lp.amp_pct / (c * A_pv)
        lp.noise_span = lp.noise_pct / 100.0 * lp.amp_pct
        lp.period = P
        clean[lp.idx] = (c, out["clean_pv"], out["clean_op"], (P, A_pv * c * lp.g, ncyc, cv))
    # pass 2: the noisy base runs (noise scaled with the now known g)
    saved = {lp.idx: lp.comps for lp in loops}
    for lp in loops:
        lp.comps = ()
    try:
        for lp, out in _simulate(loops, tm, seed + 1, "integrating", linear=True):
            c, cpv, cop, stats = clean[lp.idx]
            out["pv"] = out["pv"] + c * cpv
            out["op"] = out["op"] + c * cop
            out["mv"] = out["op"].copy()
            out["stats_pv"] = (stats[0], stats[1] / lp.g, stats[2], stats[3])
            recs[lp.idx] = out
    finally:
        for lp in loops:
            lp.comps = saved[lp.idx]
    for lp in loops:
        yield lp, recs[lp.idx]


# ------------------------------------------------------------------ artefacts

@dataclass
class _Tag:
    tag: str
    values: np.ndarray            # engineering value per recorded sample
    dec: int                      # decimals written
    keep: np.ndarray              # row exists in the export
    state: np.ndarray             # 0 = good, else 1 + index into DIGITAL_STATES
    status: np.ndarray            # 0 = none, 1 Questionable, 2 Substituted
    exported: bool = True
    kind: str = "pv"


def _new_tag(tag, values, dec, kind):
    n = values.size
    return _Tag(tag, values, dec, np.ones(n, dtype=bool), np.zeros(n, dtype=np.int8),
                np.zeros(n, dtype=np.int8), kind=kind)


def _spans(rng, tm, n_per_day, dur_s):
    """Random [a, b) sample ranges, about ``n_per_day`` per day (at least one) of ``dur_s`` [s]."""
    k = max(1, rng.poisson(n_per_day * tm.duration / _DAY))
    out = []
    for _ in range(int(k)):
        d = max(1, int(round(rng.uniform(*dur_s) / tm.ts)))
        a = int(rng.integers(0, max(1, tm.n - d)))
        out.append((a, min(tm.n, a + d)))
    return out


def _compress(lp, tag, rng, tm, amp_eng, noise_eng):
    """Exception and swinging-door storage; returns a note."""
    x = tag.values
    max_exc = max(1, int(round(600.0 / tm.ts)))
    if tag.kind == "pv":
        ref = amp_eng if np.isfinite(amp_eng) and amp_eng > 0 else 3 * noise_eng
        dev = max(float(rng.uniform(0.01, 0.03)) * ref, 2 * noise_eng)
    else:
        dev = float(rng.uniform(0.05, 0.2))
    for _ in range(6):
        if lp.storage == "exception":
            keep = exception_deadband(x, dev, max_exc)
        else:
            exc = np.flatnonzero(exception_deadband(x, dev / 2, max_exc))
            k2 = swinging_door(x[exc], dev, 28800.0 / tm.ts, t=exc.astype(float))
            keep = np.zeros(x.size, dtype=bool)
            keep[exc[k2]] = True
        per_cycle = keep.sum() * lp.period / tm.duration if np.isfinite(lp.period) else np.inf
        if per_cycle >= 12 or tag.kind != "pv":
            break
        dev /= 2
    tag.keep &= keep
    frac = keep.mean()
    return f"{tag.tag} {lp.storage} dev {dev:.3g} {lp.unit if tag.kind == 'pv' else '%'} ({100 * frac:.0f} % of samples kept)"


def _apply_artefacts(lp, tags, rng, tm):
    """Historian artefacts that leave the truth intact."""
    pv = tags["pv"]
    # digital-state bursts on PV or OP
    if "burst" in lp.art:
        tgt = pv if rng.random() < 0.7 else tags["op"]
        spans = _spans(rng, tm, 1.5, (10.0, 180.0))
        for a, b in spans:
            st = 1 + DIGITAL_STATES.index(_pick(rng, _BURST_STATES))
            tgt.state[a:b] = st
            if lp.storage != "sampled":
                tgt.keep[a] = True
                tgt.keep[a + 1:b] = False
                if b < tm.n:
                    tgt.keep[b] = True
        lp.artefacts.append(f"{len(spans)} digital-state burst(s) on {tgt.tag}")
    # gaps: rows missing on every tag of the loop
    # (a compressed tag marks the gap's start with a digital state, or a reader
    # could not tell it from a well-compressed ramp; a sampled tag just lacks rows)
    if "gap" in lp.art:
        spans = _spans(rng, tm, 1.0, (120.0, 900.0))
        marker = 1 + DIGITAL_STATES.index(_pick(rng, ("I/O Timeout", "Comm Fail")))
        for a, b in spans:
            for t in tags.values():
                t.keep[a:b] = False
                if b < tm.n and (t.kind == "sp" or lp.storage != "sampled"):
                    t.keep[b] = True
                if t.kind != "sp" and lp.storage != "sampled":
                    t.keep[a] = True
                    t.state[a] = marker
        lp.artefacts.append(f"{len(spans)} gap(s) of 2-15 min"
                            + ("" if lp.storage == "sampled" else f" marked {DIGITAL_STATES[marker - 1]}"))
    # questionable stretches on the PV
    if "questionable" in lp.art:
        spans = _spans(rng, tm, 1.0, (600.0, 3600.0))
        for a, b in spans:
            pv.status[a:b] = _QUESTIONABLE
        lp.artefacts.append(f"Questionable status on {pv.tag}")
    # substituted set-point entries
    if "substituted" in lp.art:
        kept = np.flatnonzero(tags["sp"].keep)
        if kept.size:
            idx = rng.choice(kept, size=min(kept.size, int(rng.integers(1, 4))), replace=False)
            tags["sp"].status[idx] = _SUBSTITUTED
            lp.artefacts.append(f"Substituted rows on {tags['sp'].tag}")


def _make_bad(lp, tags, rng, tm):
    """Turn a loop's records into unusable data (the bad-data category)."""
    pv = tags["pv"]
    kind = lp.variant
    if kind == "pv-missing":
        pv.exported = False
        lp.notes.append(f"PV tag {pv.tag} absent from the exports")
    elif kind == "pv-bad-states":
        a = 0
        while a < tm.n:
            b = min(tm.n, a + max(1, int(rng.uniform(600, 7200) / tm.ts)))
            pv.state[a:b] = 1 + DIGITAL_STATES.index(_pick(rng, ("Bad Input", "I/O Timeout", "Comm Fail")))
            a = b
        lp.notes.append(f"PV {pv.tag} reads only digital states (transmitter failed)")
    elif kind == "pv-frozen":
        frozen = round(float(pv.values[0]), pv.dec)
        pv.values[:] = frozen
        op = tags["op"]
        level = np.full(tm.n, round(lp.op0, 1))
        for _ in range(int(rng.integers(1, 4))):
            k = int(rng.integers(0, tm.n))
            level[k:] += round(float(rng.uniform(-5, 5)), 1)
        op.values[:] = level
        tags["sp"].values[:] = frozen
        if "mv" in tags:
            tags["mv"].values[:] = level
        lp.notes.append(f"PV {pv.tag} frozen at {frozen:g} {lp.unit}; loop in manual, operator moves OP")
    elif kind == "too-short":
        w = 1.5 * lp.period if np.isfinite(lp.period) else 1200.0
        w = min(w, 0.04 * tm.duration)
        nw = max(10, int(round(w / tm.ts)))
        a = tm.n - nw if rng.random() < 0.5 else 0
        for t in tags.values():
            k = t.keep[a:a + nw].copy()
            t.keep[:] = False
            t.keep[a:a + nw] = k
            if t.kind == "sp":
                t.keep[a] = True
        lp.notes.append(f"only {nw * tm.ts:.0f} s of data ({'end' if a else 'start'} of the record)")


# ------------------------------------------------------------------- writing

def _timestamps(start, tm, d0, d1, tz):
    """UTC datetimes and ISO 8601 strings (local time with its UTC offset) of samples d0..d1-1."""
    us = int(round(tm.ts * 1e6))
    t0 = start + _dt.timedelta(microseconds=d0 * us)
    s = pl.datetime_range(t0, t0 + _dt.timedelta(microseconds=(d1 - d0 - 1) * us), f"{us}us",
                          time_zone="UTC", eager=True, time_unit="us")
    local = s.dt.convert_time_zone(tz) if tz != "UTC" else s
    whole = us % 1_000_000 == 0 and start.microsecond == 0
    fmt = "%Y-%m-%dT%H:%M:%S%:z" if whole else "%Y-%m-%dT%H:%M:%S%.3f%:z"
    return s, local.dt.strftime(fmt)


_STATE_NAMES = [None] + list(DIGITAL_STATES)       # state code -> text
_FLAG_NAMES = [None] + list(STATUS_FLAGS)          # status code -> text


def _tag_frame(t, d0, d1, ts_str, ts_dt, typed=False):
    """Long rows of one tag for samples d0..d1-1: value text (number or state) and flag.

    ``typed`` gives UTC datetimes instead of ISO text (Parquet).
    """
    idx = np.flatnonzero(t.keep[d0:d1])
    k = idx.size
    vals = pl.Series("v", t.values[d0 + idx]).round(t.dec)
    st = t.state[d0 + idx]
    stat = t.status[d0 + idx]
    state_names = pl.Series(_STATE_NAMES, dtype=pl.String)
    flag_names = pl.Series(_FLAG_NAMES, dtype=pl.String)
    st_txt = state_names.gather(pl.Series(st.astype(np.int64)))
    fl_txt = flag_names.gather(pl.Series(stat.astype(np.int64)))
    value = st_txt.fill_null(vals.cast(pl.String))
    stamp = ts_dt.gather(pl.Series(idx)) if typed else ts_str.gather(pl.Series(idx))
    return pl.DataFrame({"tag": pl.repeat(t.tag, k, eager=True, dtype=pl.String),
                         "timestamp": stamp, "value": value, "status": fl_txt})


def _write_long_csv(path, tag_list, d0, d1, ts_str):
    with open(path, "wb") as f:
        header = True
        batch = []
        rows = 0
        for t in tag_list:
            batch.append(_tag_frame(t, d0, d1, ts_str, None))
            rows += batch[-1].height
            if rows > 2_000_000:
                pl.concat(batch).write_csv(f, include_header=header)
                header, batch, rows = False, [], 0
        if batch or header:
            (pl.concat(batch) if batch else pl.DataFrame(schema={c: pl.String for c in EXPORT_COLUMNS})
             ).write_csv(f, include_header=header)


def _write_parquet(path, tag_list, d0, d1, ts_dt):
    import pyarrow.parquet as pq

    writer = None
    try:
        batch, rows = [], 0

        def flush(b):
            nonlocal writer
            tbl = pl.concat(b).to_arrow()
            if writer is None:
                writer = pq.ParquetWriter(str(path), tbl.schema, compression="zstd")
            writer.write_table(tbl)

        for t in tag_list:
            batch.append(_tag_frame(t, d0, d1, None, ts_dt, typed=True))
            rows += batch[-1].height
            if rows > 2_000_000:
                flush(batch)
                batch, rows = [], 0
        if batch:
            flush(batch)
    finally:
        if writer is not None:
            writer.close()


def _write_wide_csv(path, tag_list, d0, d1, ts_str):
    cols = {"timestamp": ts_str}
    state_names = pl.Series(_STATE_NAMES, dtype=pl.String)
    for t in tag_list:
        sl = slice(d0, d1)
        v = pl.Series(t.values[sl]).round(t.dec).cast(pl.String)
        st = state_names.gather(pl.Series(t.state[sl].astype(np.int64)))
        v = st.fill_null(v)
        cols[t.tag] = pl.DataFrame({"v": v, "k": t.keep[sl]}).select(
            pl.when(pl.col("k")).then(pl.col("v"))).to_series().alias(t.tag)
    df = pl.DataFrame(cols)
    tags = [t.tag for t in tag_list]
    if tags:
        df = df.filter(pl.any_horizontal(pl.col(tags).is_not_null()))
    df.write_csv(path)


# ---------------------------------------------------------------- public API

@dataclass(frozen=True)
class SynthPlant:
    """What :func:`synth_plant` wrote.

    Attributes
    ----------
    out_dir : pathlib.Path
        The output directory.
    exports : tuple of pathlib.Path
        Historian export files, in writing order.
    loops_csv, truth_csv : pathlib.Path
        Loop registry and answer key.
    loops : polars.DataFrame
        Contents of ``loops.csv``.
    truth : polars.DataFrame
        Contents of ``truth.csv``.
    sample_time : float
        Historian sample time [s].
    days : float
        Record length [d].
    start : datetime.datetime
        First timestamp (UTC).
    seed : int
        Seed used.
    """

    out_dir: Path
    exports: tuple
    loops_csv: Path
    truth_csv: Path
    loops: pl.DataFrame = field(repr=False)
    truth: pl.DataFrame = field(repr=False)
    sample_time: float = 1.0
    days: float = 1.0
    start: _dt.datetime | None = None
    seed: int = 0

    @property
    def files(self) -> tuple:
        """Every file written: exports, ``loops.csv`` and ``truth.csv``."""
        return tuple(self.exports) + (self.loops_csv, self.truth_csv)


def _parse_start(start):
    if isinstance(start, _dt.datetime):
        t = start
    else:
        t = _dt.datetime.fromisoformat(str(start))
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    return t.astimezone(_dt.timezone.utc)


def synth_plant(n_loops: int, days: float, sample_time: float, out_dir, *, seed: int = 0,
                start: str = "2026-11-01T00:00:00Z", formats: Sequence[str] = ("long-csv",),
                progress: Callable[[int, int], None] | None = None, timezone: str = "UTC",
                group_size: int = 50) -> SynthPlant:
    """Simulate a plant of control loops and write historian exports with known truth.

    Parameters
    ----------
    n_loops : int
        Number of control loops (>= 1).
    days : float
        Record length [d].
    sample_time : float
        Historian sample time [s] (the snapshot interval of uncompressed tags).
    out_dir : str or os.PathLike
        Output directory; created if needed. Gets ``exports/``, ``loops.csv``
        and ``truth.csv``. Export files of an earlier run there (names as
        below) are deleted first; other files are left alone.
    seed : int
        Seed; the output is a deterministic function of all the arguments.
    start : str or datetime.datetime
        First timestamp, ISO 8601 (naive means UTC).
    formats : sequence of {'long-csv', 'wide-csv', 'parquet'}
        Export formats. With several, each loop's tags go to exactly one
        format (assigned round-robin over a shuffled loop order), so a plant
        mixes export formats without duplicate data.
    progress : callable(done, total), optional
        Called after each simulated group and each file written.
    timezone : str
        IANA zone of the written timestamps, e.g. ``'America/Chicago'``; the
        UTC offset is always written. Default ``'UTC'`` (``+00:00``).
    group_size : int
        Loops per export file (files are also split per day).

    Returns
    -------
    SynthPlant
        The files written and the truth table.

    Notes
    -----
    **Loop mix.** Shares (:data:`CATEGORY_SHARES`, largest-remainder rounding,
    at least one loop of each category when ``n_loops >= 7``; below that the
    categories come in the order stiction, healthy, backlash, linear
    oscillation, self-regulating stiction, bad data, self-regulating healthy),
    shuffled over the loop names:

    ==================  =====  ================================================
    category            share  truth verdict and loop
    ==================  =====  ================================================
    stiction            20 %   ``stiction``: integrating, Kano S 1-6 %,
                               J/S 0.5-1
    backlash            15 %   ``backlash``: integrating, dead band 0.5-6 %
    linear-oscillation  10 %   ``linear-oscillation``: linear valve; 3 in 5
                               with a sinusoidal load, 2 in 5 with too much
                               integral action (zeta 0.04-0.08) ringing
    healthy             25 %   ``no-oscillation``: integrating, linear valve,
                               zeta 0.8-1.3
    selfreg-stiction    7.5 %  ``stiction``: self-regulating, Kano valve
    selfreg-healthy     7.5 %  ``no-oscillation``: self-regulating, linear valve
    bad-data            15 %   ``insufficient-data``: in turn PV tag missing
                               from the exports, PV only digital states, PV
                               frozen (loop in manual), far too little data
                               (at most 1.5 periods, <= 4 % of the record);
                               underneath alternately a sticky and a healthy
                               integrating loop
    ==================  =====  ================================================

    ``criticality`` is a ranking weight: 3 (15 % of loops), 2 (45 %) or 1.
    Integrating loops are level (``LIC``, 85 %) or gas-pressure (``PIC``)
    loops; self-regulating ones are flows (``FIC``), temperatures (``TIC``)
    and pressures (``PIC``). ``loops.csv`` says ``unknown`` for 25 % of the
    loops and always for the first self-regulating sticky loop and the first
    integrating fault loop, so that the data test for integrating processes
    is exercised; ``truth.csv`` has the real type.

    **Dynamics.** Integrating loops are ``K/(tau s)`` with PI control. Fault
    loops draw Kc 0.7-4, Ti/tau 1-2.4 and tau 10-100 s as Farenzena &
    Trierweiler [1]_; self-regulating fault loops are ``K/(tau s + 1)`` with
    dead time 0.02-0.3 tau (tau: flows 3-30 s, pressures 10-60 s,
    temperatures 60-300 s). A pilot run in normalised time finds each fault
    loop's limit cycle. The period range is ``max(30 sample_time, 20 s)`` to
    ``min(1200 s, record / 15)``. A loop whose period falls outside has all
    its times stretched together (its behaviour in normalised time does not
    change) to a period drawn within a factor 3 of the nearer edge. A second
    pilot at the final controller rate, over the window the record will cover
    (after 20 periods of warm-up), keeps the loop only if its cycle is
    regular and still in range; otherwise it is redrawn. So every oscillation
    has >= 30 samples per period (the record's measured period may undershoot
    by a few %) and >= 15 cycles. The controller runs at ``sample_time / m``
    with >= 60 controller samples per shortest period; the historian takes
    every ``m``-th sample. Healthy loops are tuned for zeta 0.8-1.3 (tau
    20-300 s integrating).

    **Noise.** Every loop feeds its white measurement noise back to the
    controller, as a plant does: fault loops 0.5-2 % of the oscillation
    amplitude the pilots found, linear loops 0.5-2 % of the amplitude, or
    0.05-0.4 % of span for healthy loops. So a limit cycle's phase wanders
    with the noise, as a real one's does; noise added to a record afterwards
    would leave it keeping perfect time, like a load driven by a clock.
    Kano's model sticks at every reversal of a noisy input [2]_, so its
    actuator ignores reversals within a noise band of ``6 Kc sigma`` (the
    OP's answer to the noise). The pilots run without noise. In the truth,
    ``noise_pct`` is the noise standard deviation in % of the oscillation
    amplitude, or in % of the span for loops that do not oscillate.

    **Linear oscillations** use superposition. The record is the base run
    (operating point, noise, set-point and load steps) plus scaled responses
    to sinusoidal loads: one sinusoid (an external disturbance), or a main
    line at the resonance of a lightly damped loop plus four weak lines at
    0.8-1.25 times its frequency, so the loop rings with a slowly varying
    amplitude.

    **Disturbances.** Linear-valve loops get a load drift of up to +-3 % of
    valve travel over the record; except for the ringing ones (whose
    transients would last many cycles), 15 % get a set-point step of 1-4 % of
    span and 40 % a load step. Healthy loops also get a slow sinusoidal load
    (1-4 %, period 3-12 h) that the controller removes. Fault loops get
    neither: a Kano loop can have several limit cycles and a set-point step
    may move it to another with a different period, and a steady load ramp
    changes a stiction cycle's period by up to 50 %; their records are the
    cycle the second pilot checked.

    **Scaling and units.** Simulations run in normalised units (K = 1). The
    PV is then scaled to a plausible amplitude (0.4-6 % of span for valve
    faults, 0.6-4 % for linear oscillations). That is the same as a process
    gain ``g`` with a controller gain ``Kc/g``, and the notes give the gain
    in %OP per % of span. PVs have engineering units and spans (levels in %,
    m or mm; flows in m3/h, t/h, kg/h or Nm3/h; temperatures in degC;
    pressures in barg or kPa). Set points sit at 30-70 % of span and valves
    at 25-70 % travel. The ``amplitude`` in the truth is the median half
    peak-to-peak of the clean PV [PV unit] and ``period_s`` its median period
    [s], both measured on the record before noise and artefacts. If a
    record's cycle came out irregular anyway, its truth says
    ``no-oscillation`` and the notes say why.

    **Artefacts** leave usable loops usable; only bad-data loops are made
    unusable. Each artefact below reaches at least one usable loop.

    * 30 % of loops get digital-state bursts (about 1.5 per day, 10-180 s,
      on the PV or the OP).
    * 20 % get gaps of 2-15 min (about one per day) on all their tags. Gaps on
      compressed tags start with an ``I/O Timeout`` or ``Comm Fail`` row;
      sampled tags just lack rows.
    * 10 % get a ``Questionable`` stretch of 10-60 min on the PV, and 5 % get
      ``Substituted`` set-point rows.
    * 70 % of loops store every sample. 12 % store by exception: a dead band
      of 1-3 % of the oscillation amplitude, and >= 2 noise sigma. 18 % store
      by exception plus swinging-door compression [3]_. In both, the dead
      band is halved until >= 12 PV points per cycle are kept. OPs and valve
      positions use a 0.05-0.2 % dead band.
    * Set points are stored by exception only: on change, and hourly.
    * Each export group has a 40 % chance per day of an interface restart: a
      ``Shutdown`` row on every tag, then 3-10 min of missing data.

    20 % of loops also have a valve-position tag (``LV101.POS``: the
    simulated stem position plus 0.02 % noise).

    **Exports** are written one file per export group (``group_size`` loops
    in one format) and day: ``exports/long_YYYYMMDD_gNN.csv``,
    ``wide_YYYYMMDD_gNN.csv`` or ``long_YYYYMMDD_gNN.parquet``.

    * Long CSV: ``tag,timestamp,value,status``. The digital state's text
      goes in ``value`` and the flags in ``status``.
    * Wide CSV: ``timestamp`` and then one column per tag, with no status.
      A cell is empty where its tag has no row.
    * Parquet: long, as the CSV (``value`` is text: a number or a state)
      but with ``timestamp`` a UTC datetime.

    CSV timestamps are ISO 8601 with the UTC offset of ``timezone``.

    **Limits.** Each loop is single-input single-output, with no interaction
    between loops. The noise is white. The valve is linear apart from its
    fault. A loop's parameters do not change within the record. Swinging-door
    points reproduce the signal to within twice the compression deviation.
    Memory is about ``group_size x samples x 40`` bytes, plus 256 MB per
    simulator call. On two cores, 200 loops for 1 day at 1 s (1.3 GB of CSV)
    take about 25 s, most of it writing CSV.

    References
    ----------
    .. [1] Farenzena, M., Trierweiler, J. O. (2012). Valve backlash and
       stiction detection in integrating processes. 8th IFAC ADCHEM,
       Singapore.
    .. [2] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical
       model and detection algorithm for valve stiction. IFAC DYCOPS 7.
    .. [3] Bristol, E. H. (1990). Swinging door trending: adaptive trend
       recording? ISA National Conference Proceedings, 749-754.
    """
    n_loops = int(n_loops)
    if n_loops < 1:
        raise ValueError(f"n_loops must be >= 1, got {n_loops}")
    formats = tuple(formats)
    bad = [f for f in formats if f not in FORMATS]
    if not formats or bad:
        raise ValueError(f"unknown export format(s) {bad}; choose from {FORMATS}")
    if group_size < 1:
        raise ValueError("group_size must be >= 1")
    tm = _timing(days, sample_time)
    t_start = _parse_start(start)
    if timezone != "UTC":
        import zoneinfo

        try:
            zoneinfo.ZoneInfo(timezone)
        except Exception as exc:
            raise ValueError(f"unknown time zone {timezone!r}") from exc
    out = Path(out_dir)
    (out / "exports").mkdir(parents=True, exist_ok=True)
    for old in (out / "exports").iterdir():  # exports of an earlier run, and nothing else
        if _EXPORT_NAME.fullmatch(old.name) and old.is_file():
            old.unlink()

    ss = np.random.SeedSequence(int(seed))
    r_alloc, r_par, r_art, r_sim = (np.random.default_rng(s) for s in ss.spawn(4))
    sim_seed = int(r_sim.integers(2**31))

    loops = _draw_plant(n_loops, tm, r_alloc, r_par)
    _fit_cycles(loops, tm, r_par, sim_seed)
    groups = _plan_groups(loops, formats, group_size, tm, r_par)
    day_edges = _day_edges(tm)
    n_days = len(day_edges) - 1
    restarts = r_par.random((len(groups), n_days)) < _SHUTDOWN_RATE
    if not restarts.any():
        restarts[0, 0] = True
    total = len(groups) * (1 + n_days)
    done = 0
    exports = []
    for gi, (fmt, members) in enumerate(groups):
        recs = _simulate_group(members, tm, sim_seed + 1000 * (gi + 1))
        done += 1
        if progress is not None:
            progress(done, total)
        tag_list = []
        for lp in members:
            _finish_loop(lp, recs.pop(lp.idx), tag_list, r_art, tm)
        for d in np.flatnonzero(restarts[gi]):
            _interface_restart(members, tag_list, day_edges[d], day_edges[d + 1], int(d), r_art, tm)
        exported = [t for t in tag_list if t.exported]
        for d in range(n_days):
            exports.append(_write_day(out, fmt, gi, exported, day_edges[d], day_edges[d + 1],
                                      t_start, tm, timezone))
            done += 1
            if progress is not None:
                progress(done, total)
        del tag_list, exported, recs

    loops_df, truth_df = _tables(loops)
    loops_csv, truth_csv = out / "loops.csv", out / "truth.csv"
    loops_df.write_csv(loops_csv)
    truth_df.write_csv(truth_csv)
    return SynthPlant(out_dir=out, exports=tuple(exports), loops_csv=loops_csv, truth_csv=truth_csv,
                      loops=loops_df, truth=truth_df, sample_time=tm.ts, days=tm.duration / _DAY,
                      start=t_start, seed=int(seed))


# ------------------------------------------------------------ plant stages

def _draw_plant(n_loops, tm, r_alloc, r_par):
    """Categories, names, ranges, tuning and artefact plan of every loop."""
    loops = [_Loop(idx=i, category=c) for i, c in enumerate(_allocate(n_loops, r_alloc))]
    k_lin = k_bad = 0
    for lp in loops:
        if lp.category == "linear-oscillation":
            lp.variant = ("sine-load", "tuning")[k_lin % 5 in (1, 3)]
            k_lin += 1
        elif lp.category == "bad-data":
            lp.variant = _BAD_KINDS[k_bad % len(_BAD_KINDS)]
            lp.base = "stiction" if (k_bad // len(_BAD_KINDS) + k_bad) % 2 == 0 else "healthy"
            k_bad += 1
        lp.process = "self-regulating" if lp.sim_category.startswith("selfreg") else "integrating"
        _describe(lp, r_par)
        lp.meta_process = "unknown" if r_par.random() < 0.25 else lp.process
        lp.has_mv = bool(r_par.random() < 0.2)
        lp.storage = _pick(r_par, [m for m, _ in _STORAGE], p=[w for _, w in _STORAGE])
        _draw_disturbances(lp, r_par, tm)
        if lp.sim_category in _FAULTS:
            _draw_valve_fault(lp, r_par)
            lp.noise_pct = float(r_par.uniform(0.5, 2.0))
        else:
            _draw_linear(lp, r_par, tm)
        if lp.category == "bad-data":
            lp.storage = "sampled"
    # every artefact somewhere: each kind of storage and each artefact on >= 1 usable loop
    usable = [lp for lp in loops if lp.category != "bad-data"]
    for lp in usable:
        lp.art = {k for k, rate in _ARTEFACT_RATES.items() if r_par.random() < rate}
    for k in _ARTEFACT_RATES:
        if usable and not any(k in lp.art for lp in usable):
            usable[int(r_par.integers(len(usable)))].art.add(k)
    if len(usable) >= 3:
        for mode, _ in _STORAGE[1:]:
            sampled = [lp for lp in usable if lp.storage == "sampled"]
            if sampled and not any(lp.storage == mode for lp in usable):
                sampled[int(r_par.integers(len(sampled)))].storage = mode
    # make the data test for integrating processes matter: the first
    # self-regulating sticky loop and the first integrating fault loop say 'unknown'
    for cat in ("selfreg-stiction", "stiction", "backlash"):
        first = next((lp for lp in loops if lp.category == cat), None)
        if first is not None:
            first.meta_process = "unknown"
            if cat != "selfreg-stiction":
                break
    return loops


def _fit_cycles(loops, tm, r_par, sim_seed):
    """Give every valve-fault loop a regular limit cycle within the period range.

    Stage A finds the cycle in normalised time; the loop is then stretched to
    the sampling; stage B re-runs it at the final controller rate and keeps it
    only if the cycle is regular and still within the period range. Loops that
    fail are redrawn (up to 10 rounds).
    """
    faulty = [lp for lp in loops if lp.valve != "linear"]
    todo = faulty
    for attempt in range(10):
        if not todo:
            break
        stats = _pilot(todo, sim_seed + attempt)
        failed, ok = [], []
        for lp in todo:
            P, A, ncyc, cv = stats[lp.idx]
            if _oscillates(P, A, ncyc, cv, min_cycles=5):
                lp.p_n, lp.a_n = P, A
                lp.tau = _stretch(P * lp.tau_paper, tm, r_par) / P
                ok.append(lp)
            else:
                failed.append(lp)
        stats = _pilot(ok, sim_seed + attempt, tm=tm) if ok else {}
        for lp in ok:
            P, A, ncyc, cv = stats[lp.idx]
            if (_oscillates(P, A, ncyc, cv, min_cycles=10)
                    and 0.9 * tm.p_lo <= P * lp.tau <= 1.2 * tm.p_hi):
                lp.p_n, lp.a_n = P, A
            else:
                failed.append(lp)
        for lp in failed:
            lp.p_n = lp.a_n = math.nan
            _draw_valve_fault(lp, r_par)
        todo = failed
    for lp in faulty:
        if np.isfinite(lp.p_n):
            lp.period = lp.p_n * lp.tau
            amp = float(np.clip(lp.a_n * _loguniform(r_par, 0.5, 2.0), 0.4, 6.0))
            lp.g = amp / lp.a_n
            lp.amp_pct = amp
        else:  # no regular cycle found: the record decides the truth
            lp.tau, lp.g = lp.tau_paper, 1.0


def _stretch(period, tm, rng):
    """Period [s] to give a loop: its own if in range, else drawn near the range's edge.

    Drawing (log-uniform over a factor of up to 3 inside the edge) rather than
    clipping avoids piling loops up at exactly 30 samples per period.
    """
    if period < tm.p_lo:
        return _loguniform(rng, tm.p_lo, min(3 * tm.p_lo, tm.p_hi))
    if period > tm.p_hi:
        return _loguniform(rng, max(tm.p_hi / 3, tm.p_lo), tm.p_hi)
    return period


def _plan_groups(loops, formats, group_size, tm, r_par):
    """Export format of each loop and the (format, loops) groups, one file set each."""
    order = r_par.permutation(len(loops))
    for i, li in enumerate(order):
        loops[li].fmt = formats[i % len(formats)]
    gsize = int(min(group_size, max(5, 2e9 // max(1, tm.n * 40))))
    groups = []
    for fmt in formats:
        members = [lp for lp in loops if lp.fmt == fmt]
        for k in range(0, len(members), gsize):
            groups.append((fmt, members[k:k + gsize]))
    for gi, (_, members) in enumerate(groups):
        for lp in members:
            lp.group = gi
    return groups


def _day_edges(tm):
    """Sample indices where each day of the record starts (and the end)."""
    n_days = max(1, int(math.ceil(tm.n * tm.ts / _DAY - 1e-9)))
    edges = [int(math.ceil(k * _DAY / tm.ts - 1e-9)) for k in range(n_days)] + [tm.n]
    return edges


def _simulate_group(members, tm, seed):
    """Records of a group's loops, simulated in batches of one kind each."""
    recs = {}
    kinds = (
        (lambda l: l.valve != "linear" and l.process == "integrating", "integrating", False),
        (lambda l: l.valve != "linear" and l.process == "self-regulating", "self-regulating", False),
        (lambda l: l.valve == "linear" and l.process == "integrating"
         and l.sim_category != "linear-oscillation", "integrating", True),
        (lambda l: l.valve == "linear" and l.process == "self-regulating", "self-regulating", True),
    )
    for k, (pred, process, linear) in enumerate(kinds):
        for lp, r in _simulate([lp for lp in members if pred(lp)], tm, seed + 1 + k, process, linear):
            recs[lp.idx] = r
    for lp, r in _simulate_linear_osc([lp for lp in members if lp.sim_category == "linear-oscillation"],
                                      tm, seed + 5):
        recs[lp.idx] = r
    return recs


def _interface_restart(members, tag_list, d0, d1, day, rng, tm):
    """A historian interface restart: a Shutdown row on every tag, then minutes of nothing."""
    dur = max(1, int(round(rng.uniform(180, 600) / tm.ts)))
    if d1 - d0 <= dur + 2:
        return
    a = int(rng.integers(d0, d1 - dur - 1))
    for t in tag_list:
        if not t.keep[a:].any():
            continue
        t.keep[a] = True
        t.state[a] = _SHUTDOWN
        # values typed in by hand afterwards (Substituted) survive the outage
        t.keep[a + 1:a + dur] = t.status[a + 1:a + dur] == _SUBSTITUTED
        t.keep[a + dur] = True
    for lp in members:
        lp.artefacts.append(f"interface restart (Shutdown, {dur * tm.ts / 60:.0f} min) on day {day + 1}")


_EXT = {"long-csv": ("long", "csv"), "wide-csv": ("wide", "csv"), "parquet": ("long", "parquet")}
_EXPORT_NAME = re.compile(r"(long|wide)_\d{8}_g\d{2,}\.(csv|parquet)")


def _write_day(out, fmt, gi, tags, d0, d1, t_start, tm, timezone):
    """Write one export file: one group of loops, one day."""
    ts_dt, ts_str = _timestamps(t_start, tm, d0, d1, timezone)
    day = (t_start + _dt.timedelta(seconds=d0 * tm.ts)).strftime("%Y%m%d")
    kind, suffix = _EXT[fmt]
    path = out / "exports" / f"{kind}_{day}_g{gi + 1:02d}.{suffix}"
    if fmt == "long-csv":
        _write_long_csv(path, tags, d0, d1, ts_str)
    elif fmt == "wide-csv":
        _write_wide_csv(path, tags, d0, d1, ts_str)
    else:
        _write_parquet(path, tags, d0, d1, ts_dt)
    return path


def _tables(loops):
    """The loop registry and the truth table."""
    loops_df = pl.DataFrame({
        "loop": [lp.name for lp in loops],
        "pv_tag": [f"{lp.name}.PV" for lp in loops],
        "op_tag": [f"{lp.name}.OP" for lp in loops],
        "sp_tag": [f"{lp.name}.SP" for lp in loops],
        "mv_tag": [_mv_tag(lp) if lp.has_mv else None for lp in loops],
        "process_type": [lp.meta_process for lp in loops],
        "unit": [lp.unit for lp in loops],
        "span": [lp.span for lp in loops],
        "criticality": [lp.criticality for lp in loops],
        "description": [lp.description for lp in loops],
    }, schema={c: (pl.Float64 if c in ("span", "criticality") else pl.String) for c in LOOPS_COLUMNS})
    truth_df = pl.DataFrame({
        "loop": [lp.name for lp in loops],
        "truth_verdict": [_truth_verdict(lp) for lp in loops],
        "process_type": [lp.process for lp in loops],
        "valve": [lp.valve for lp in loops],
        "fault_params": [_fault_params(lp) for lp in loops],
        "period_s": [_round_sig(lp.period, 4) if _has_cycle(lp) else None for lp in loops],
        "amplitude": [_round_sig(lp.span * lp.amp_pct / 100.0, 4) if _has_cycle(lp) else None
                      for lp in loops],
        "noise_pct": [round(lp.noise_pct, 2) for lp in loops],
        "notes": ["; ".join(lp.notes + lp.artefacts) for lp in loops],
    }, schema={"loop": pl.String, "truth_verdict": pl.String, "process_type": pl.String,
               "valve": pl.String, "fault_params": pl.String, "period_s": pl.Float64,
               "amplitude": pl.Float64, "noise_pct": pl.Float64, "notes": pl.String})
    return loops_df, truth_df


def _mv_tag(lp):
    return f"{lp.prefix[0]}V{lp.name[len(lp.prefix):]}.POS"


# --------------------------------------------------------------- per loop

def _round_sig(x, n):
    if x is None or not np.isfinite(x) or x == 0:
        return x
    return round(float(x), n - 1 - int(math.floor(math.log10(abs(x)))))


def _has_cycle(lp):
    return lp.category != "bad-data" and lp.oscillates


def _truth_verdict(lp):
    v = lp.verdict
    if lp.category != "bad-data" and v not in ("no-oscillation",) and not lp.oscillates:
        return "no-oscillation"   # the simulation did not give the intended cycle
    return v


def _fault_params(lp):
    if lp.valve == "kano":
        return f"S={lp.S:g};J={lp.J:g}"
    if lp.valve == "backlash":
        return f"DB={lp.DB:g}"
    return ""


def _fault_noise_span(lp):
    """Measurement noise std of a valve-fault loop [% of span]."""
    return lp.noise_pct / 100.0 * lp.amp_pct if np.isfinite(lp.amp_pct) else 0.05


def _finish_loop(lp, r, tag_list, rng, tm):
    """Scale a simulated record to engineering units, add artefacts."""
    P, A, ncyc, cv = r["stats_pv"]
    cat = lp.sim_category
    if lp.valve != "linear":
        lp.noise_span = _fault_noise_span(lp)   # what the simulation fed back
    if cat in _FAULTS + ("linear-oscillation",):
        lp.oscillates = _oscillates(P, A, ncyc, cv)
        lp.period = P
        lp.amp_pct = A * lp.g
        if lp.valve != "linear":
            # the truth states the noise against the amplitude as recorded
            lp.noise_pct = (100.0 * lp.noise_span / lp.amp_pct if lp.oscillates
                            else lp.noise_span)
        if not lp.oscillates and lp.category != "bad-data":
            lp.notes.append(f"the record's cycle is irregular ({ncyc} cycles, period spread "
                            f"{cv:.2f}): truth set to no-oscillation")
    else:
        lp.oscillates = False
    span = lp.span
    pv_pct = lp.sp_pct + lp.g * r["pv"]
    op = r["op"]
    mv = r["mv"]
    if lp.valve != "linear":
        mv = mv + 0.02 * rng.standard_normal(mv.size)
        desc = (f"{'Kano' if lp.valve == 'kano' else 'backlash'} valve; Kc={lp.kc / lp.g:.3g} %/% "
                f"Ti={lp.ti_r * lp.tau:.3g} s tau={lp.tau:.3g} s"
                + (f" dead time={lp.dt_r * lp.tau:.3g} s" if lp.dt_r else "")
                + ("" if abs(lp.tau - lp.tau_paper) < 1e-6 * lp.tau else
                   f" (drawn tau={lp.tau_paper:.3g} s, stretched for the sampling)"))
    elif cat == "linear-oscillation":
        if lp.variant == "sine-load":
            desc = (f"linear valve; sinusoidal load disturbance, period {lp.comps[0][0]:.4g} s; "
                    f"Kc={lp.kc / lp.g:.3g} %/% Ti={lp.ti_r * lp.tau:.3g} s tau={lp.tau:.3g} s "
                    f"zeta={lp.zeta:.2f}")
        else:
            desc = (f"linear valve; aggressive PI rings (zeta={lp.zeta:.3f}), driven by a "
                    f"band-limited load; Kc={lp.kc / lp.g:.3g} %/% Ti={lp.ti_r * lp.tau:.3g} s "
                    f"tau={lp.tau:.3g} s lag={lp.lag_r * lp.tau:.3g} s")
    else:
        desc = (f"linear valve, well tuned (zeta={lp.zeta:.2f}); Kc={lp.kc / lp.g:.3g} %/% "
                f"Ti={lp.ti_r * lp.tau:.3g} s tau={lp.tau:.3g} s; slow load "
                f"{lp.sin_amp:.2g} % / {lp.sin_period / 3600:.2g} h, noise fed back")
    if lp.category == "bad-data":
        extra = f" period {P:.4g} s" if _oscillates(P, A, ncyc, cv) else ""
        lp.notes.append(f"underlying {lp.base}: {desc}{extra}")
    else:
        lp.notes.append(desc)
    if lp.sp_step:
        lp.notes.append(f"SP step {lp.sp_step:+.2g} % of span at {lp.sp_step_t:.0f} s")
    sp_pct = lp.sp_pct + lp.g * r["sp"]
    to_eng = lambda x: lp.lo + span * x / 100.0
    tags = {"pv": _new_tag(f"{lp.name}.PV", to_eng(pv_pct), lp.pv_dec, "pv"),
            "op": _new_tag(f"{lp.name}.OP", op, 3, "op"),
            "sp": _new_tag(f"{lp.name}.SP", to_eng(sp_pct), lp.pv_dec, "sp")}
    if lp.has_mv:
        tags["mv"] = _new_tag(_mv_tag(lp), mv, 2, "mv")
    # set points: stored on change and hourly
    spv = np.round(tags["sp"].values, lp.pv_dec)
    tags["sp"].keep = exception_deadband(spv, 0.0, max(1, int(round(3600.0 / tm.ts))))
    if lp.category == "bad-data":
        _make_bad(lp, tags, rng, tm)
    elif lp.storage != "sampled":
        amp_eng = span * lp.amp_pct / 100.0 if lp.oscillates else math.nan
        noise_eng = span * lp.noise_span / 100.0
        for key in ("pv", "op", "mv"):
            if key in tags:
                lp.artefacts.append(_compress(lp, tags[key], rng, tm, amp_eng, noise_eng))
    if lp.category != "bad-data":
        _apply_artefacts(lp, tags, rng, tm)
    tag_list.extend(tags.values())
