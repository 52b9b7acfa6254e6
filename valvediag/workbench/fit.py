"""
Fitting engine: grid search plus local refinement of the searched
parameters, exact least squares for the linear ones (variable projection).

Given the searched parameters (valve bands, dead time, lag, plant time
constant), the chain from OP to the unit-gain plant response is fixed and the
PV prediction of every re-initialised segment is linear in the plant gain and
the load coefficients (bias, drift). The kernel
:func:`valvediag.workbench.kernels.score_batch` therefore scores a whole
batch of searched candidates in one pass over the data each, solving the
linear parameters exactly for each.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from ..models.closedloop import process_matrices
from ..models.valves import BACKLASH, HE, KANO, LINEAR
from . import kernels
from .data import LoopData, periodogram_band
from .effects import check_effects

__all__ = ["Theta", "Problem", "search", "linear_columns"]

PROCESS_TYPES = ("integrating", "self-regulating")
#: Above this fraction of repeated OP samples the Kano valve gets a rest tolerance.
HELD_FRACTION = 0.05


@dataclass(frozen=True)
class Theta:
    """Searched parameters of one candidate chain (unused ones are ignored).

    Attributes
    ----------
    DB : float
        Dead band [OP unit].
    S, J : float
        Kano stick band and slip jump [OP unit].
    sat_low, sat_high : float
        Valve stops [OP unit] (infinite: none).
    delay : float
        Dead time [samples]; fractional values interpolate linearly.
    lag : float
        Lag time constant [s] (0: none).
    tau : float
        Plant time constant of a self-regulating plant [s].
    phase : float
        Phase of He's stick-slip steps, in [0, 1): the valve starts at rest
        with the residual force ``fd + phase J`` [-]. It never forgets it
        (each slip leaves a force ``fd``, so the input points where it
        slips stay on a grid of step ``J``), so it is fitted.
    band : float
        Noise band of a Kano valve's actuator [OP unit]: a fall of the OP
        within it is not a reversal (:func:`valvediag.models.valves.valve_step`).
        Not searched: each fit holds it (see :class:`Problem`).
    load_period : float
        Period of an unmeasured oscillating load [s] (infinite: none).
    curvature : float
        Curvature of the valve's installed characteristic [1/OP unit] (0:
        linear; see :data:`~valvediag.workbench.effects.EFFECTS`).
    """

    DB: float = 0.0
    S: float = 0.0
    J: float = 0.0
    sat_low: float = -math.inf
    sat_high: float = math.inf
    delay: float = 0.0
    lag: float = 0.0
    tau: float = 1.0
    phase: float = 0.0
    band: float = 0.0
    load_period: float = math.inf
    curvature: float = 0.0

    def replace(self, **kw) -> "Theta":
        """Copy with some fields changed.

        Parameters
        ----------
        **kw : float
            New values by field name.

        Returns
        -------
        Theta
        """
        d = dict(self.__dict__)
        d.update(kw)
        return Theta(**d)


#: Largest curvature of the valve characteristic searched, times the OP's
#: 1-99 % range [-] (4: the valve's gain changes e^4 = 55-fold over it, an
#: equal-percentage valve of rangeability 55 over its whole stroke).
CURVATURE_MAX = 4.0

#: Harmonics of an oscillating load fitted (odd: a square or triangular wave
#: has no even ones) [-].
LOAD_HARMONICS = (1, 3)


def linear_columns(effects, data: LoopData, drift_knots: int, load_period: float = math.inf):
    """Basis of the rate (integrating) or level (self-regulating) load.

    Returns
    -------
    B : numpy.ndarray, shape (n, p)
        Basis functions of time (dimensionless time ``(t - t_mid)/span``).
    names : list of str
    span : float
        Time span of the used segments [s].
    knots : numpy.ndarray
        Interior knots in dimensionless time.
    """
    t = data.t
    a = data.t[data.seg_start[0]]
    b = data.t[data.seg_end[-1] - 1]
    span = max(b - a, data.sample_time)
    tau = (t - 0.5 * (a + b)) / span
    cols, names = [], []
    knots = np.array([])
    if "bias" in effects:
        cols.append(np.ones_like(t))
        names.append("bias")
    if "drift" in effects:
        cols.append(tau)
        names.append("drift")
        k = int(drift_knots)
        knots = -0.5 + np.arange(1, k + 1) / (k + 1)
        for j, kn in enumerate(knots):
            cols.append(np.maximum(0.0, tau - kn))
            names.append(f"drift_knot_{j + 1}")
    if "oscillating_load" in effects:
        w = 2.0 * math.pi / load_period if math.isfinite(load_period) and load_period > 0 else 0.0
        for k in LOAD_HARMONICS:
            cols += [np.sin(k * w * t), np.cos(k * w * t)]
            names += [f"load_sin_{k}", f"load_cos_{k}"]
    B = np.column_stack(cols) if cols else np.zeros((t.size, 0))
    return B, names, span, knots


#: Plant time constants (and load periods) whose load columns a problem keeps.
SETUPS_KEPT = 64


class Problem:
    """A loop model (effects, process type) posed on prepared data.

    Parameters
    ----------
    data : LoopData
    effects : tuple of str
    process_type : {'integrating', 'self-regulating'}
    drift_knots : int
        Interior knots of the drift.
    valve_model : {'auto', 'kano', 'he'}
        Stiction model: Kano et al. (2004) or He et al. (2007) with
        ``fs = (S + J)/2``, ``fd = (S - J)/2``. ``'auto'``: Kano, with a rest
        tolerance when more than :data:`HELD_FRACTION` of the OP samples
        repeat the previous one (held or compressed data): runs of up to
        ``data.hold_run`` repeated samples are not rests.
    noise_band : float
        Noise band of the Kano valve's actuator [OP unit], the
        :attr:`Theta.band` of the search's start (ignored by other valves).
    """

    def __init__(self, data: LoopData, effects, process_type="integrating", drift_knots=3,
                 valve_model="auto", noise_band=0.0):
        if process_type not in PROCESS_TYPES:
            raise ValueError(f"process_type must be one of {PROCESS_TYPES}, not {process_type!r}")
        self.data = data
        self.effects = check_effects(effects)
        self.process_type = process_type
        self.drift_knots = int(drift_knots)
        self.rest_tolerance = 0
        self.u = data.op
        self.noise_band = 0.0
        if "stiction" in self.effects:
            vm = valve_model
            if vm == "auto":
                vm = "kano"
                if data.held_fraction > HELD_FRACTION:
                    self.rest_tolerance = data.hold_run
                    self.u = data.op_nudged()
            self.noise_band = float(noise_band)
            if vm not in ("kano", "he"):
                raise ValueError(f"valve_model must be 'auto', 'kano' or 'he', not {valve_model!r}")
            self.vcode = KANO if vm == "kano" else HE
            self.valve_model = vm
        elif "deadband" in self.effects:
            self.vcode, self.valve_model = BACKLASH, "backlash"
        else:
            self.vcode, self.valve_model = LINEAR, "linear"
        B, names, span, knots = linear_columns(self.effects, data, self.drift_knots)
        self.lin_names, self.span, self.knots = names, span, knots
        self.oscillating = "oscillating_load" in self.effects
        self.characteristic = "characteristic" in self.effects
        # the characteristic's centre: the OP's median, so that shifting the
        # OP changes nothing (its slope there is one; the gain takes the rest)
        self.op_mid, self.op_span = 0.0, 1.0
        if self.characteristic:
            lo, self.op_mid, hi = (float(v) for v in np.percentile(data.op, [1, 50, 99]))
            self.op_span = hi - lo if hi > lo else 1.0
        self._bases = {math.inf: np.ascontiguousarray(B.T)}
        self.p = B.shape[1]
        self._setups: dict = {}
        self._mats: dict = {}
        # scores of the candidates already scored, shared by every problem of
        # the same model (and rest tolerance) on the same data, on which alone
        # a candidate's score depends: a fit's grid stages from the cold start,
        # and the point each stage starts from, come back in every fit of the
        # model from another warm start (a third of the scores, and three fifths
        # in valvediag.workbench.kind.valve_kind's four sticky fits)
        self._scores = data._cache.setdefault(
            ("scores", self.effects, self.process_type, self.drift_knots, self.valve_model,
             self.rest_tolerance), {})
        self.n_evals = 0
        d = data
        self.sample_set = d.sample_set
        self.anchored = d.reinit == "measured"
        self.seg_id = d.seg_id
        self.n_train = int((self.sample_set == 0).sum())
        self.n_held = int((self.sample_set == 1).sum())
        self.wt = (self.sample_set >= 0).astype(float)
        # the scored samples segment by segment (in time order within each),
        # where each segment's first one is among them, and each one's place
        # in its segment [samples]
        use = np.flatnonzero(self.sample_set >= 0)
        sid = self.seg_id[use]
        order = np.argsort(sid, kind="stable")
        self._use, sid = use[order], sid[order]
        self._seg_first = np.flatnonzero(np.diff(sid, prepend=-1) != 0)
        self._seg_place = self._use - data.seg_start[sid]
        # the scored PV, and each sample's set (0 where not scored)
        self._scored_pv = np.nan_to_num(np.where(self.sample_set >= 0, data.pv, 0.0))[None, :]
        self._sets = np.maximum(self.sample_set, 0)

    def basis(self, theta: Theta) -> np.ndarray:
        """Load basis of a candidate (its columns depend on the load's period)."""
        key = theta.load_period if self.oscillating else math.inf
        BT = self._bases.get(key)
        if BT is None:
            # (kept one column per row: the plant filters them along the rows)
            BT = np.ascontiguousarray(
                linear_columns(self.effects, self.data, self.drift_knots, key)[0].T)
            if len(self._bases) > 64:
                self._bases.clear()
            self._bases[key] = BT
        return BT.T

    def group(self, theta: Theta) -> tuple:
        """Candidates of one group share the linear part (plant time constant,
        load period)."""
        return (theta.tau if self.process_type == "self-regulating" else 0.0,
                theta.load_period if self.oscillating else 0.0)

    # -- the plant-dependent linear part ------------------------------------------------
    def qa(self, theta: Theta) -> float:
        """Free-response factor per sample of the plant."""
        if self.process_type == "integrating":
            return 1.0
        return math.exp(-self.data.sample_time / theta.tau)

    def free_response(self, qa: float) -> np.ndarray:
        """The plant's free response at each scored sample, ``qa**j`` at the
        ``j``-th sample of its segment (ones for an integrator)."""
        return np.ones(self._use.size) if qa == 1.0 else qa ** self._seg_place

    def project_rows(self, X, qa, w=None):
        """:meth:`project` of each row of ``X`` (shape (p, n), C order); ``w``
        is :meth:`free_response` when the caller has it."""
        out = np.zeros_like(X)
        w = self.free_response(qa) if w is None else w
        # (an integrator's rows less each segment's first value, for precision)
        kernels.project_free_response(X, self._use, self._seg_first, w, self.anchored,
                                      qa == 1.0, out)
        return out

    def project(self, X, qa):
        """Remove each segment's free response from the columns of ``X``:
        projected out (best initial state), or from the segment's first
        value (``data.reinit == 'measured'``)."""
        X = np.asarray(X, dtype=float)
        if X.ndim == 2:
            return self.project_rows(np.ascontiguousarray(X.T), qa).T
        return self.project_rows(X[None, :], qa)[0]

    def plant(self, theta: Theta) -> tuple[float, float]:
        """The plant with unit gain per sample, ``y_k = a y_(k-1) + g b_(k-1)``: (a, g)."""
        h = self.data.sample_time
        if self.process_type == "integrating":
            return 1.0, h
        a = math.exp(-h / theta.tau)
        return a, 1.0 - a

    def setup(self, theta: Theta):
        """Projected load columns, projected PV and their inner products."""
        key = self.group(theta)
        st = self._setups.pop(key, None)
        if st is not None:
            self._setups[key] = st        # (the most recently used last)
            return st
        qa = self.qa(theta)
        w = self.free_response(qa)
        Py = self.project_rows(self._scored_pv, qa, w)[0]
        # the load columns, one per row and sample set: through the plant, projected
        n = self.data.n
        WT = np.empty((2, self.p, n))
        kernels.plant_load_columns(self.basis(theta).T, *self.plant(theta), self._use,
                                   self._seg_first, w, self._sets, self.anchored, qa == 1.0,
                                   WT, np.empty(n))
        ystats = np.zeros((2, 1 + self.p))
        ystats[:, 0] = np.bincount(self._sets[self._use], weights=Py[self._use] ** 2,
                                   minlength=2)
        G2 = np.zeros((2, self.p, self.p))
        for s in (0, 1):
            ystats[s, 1:] = WT[s] @ Py
            G2[s] = WT[s] @ WT[s].T
        Ginv = np.linalg.pinv(G2[0]) if self.p else np.zeros((0, 0))
        Lmax = int((self.data.seg_end - self.data.seg_start).max())
        qv = qa ** np.arange(Lmax, dtype=float) if qa != 1.0 else np.ones(Lmax)
        nseg = self.data.seg_start.size
        qW = np.zeros((nseg, self.p))
        if self.anchored and self.p:
            # each segment's sum of its free response times the load columns
            present = self.seg_id[self._use[self._seg_first]]
            qW[present] = np.add.reduceat((WT[0] + WT[1])[:, self._use] * w, self._seg_first,
                                          axis=1).T
        st = dict(qa=qa, qv=qv, qW=qW, Py=Py, WT=WT, ystats=ystats,
                  G2=G2, Ginv=Ginv, GinvWy=Ginv @ ystats[0, 1:] if self.p else np.zeros(0))
        if len(self._setups) >= SETUPS_KEPT:
            # the least recently used one goes: the simplex returns to the
            # time constants of its last steps
            del self._setups[next(iter(self._setups))]
        self._setups[key] = st
        return st

    def matrices(self, theta: Theta):
        """Exact ZOH matrices of lag and plant with unit gain (cached)."""
        lag = theta.lag if "lag" in self.effects else 0.0
        tau = theta.tau if self.process_type == "self-regulating" else 1.0
        key = (lag, tau)
        m = self._mats.get(key)
        if m is None:
            m = zoh_matrices(self.process_type, lag, tau, self.data.sample_time)
            if len(self._mats) > 4096:
                self._mats.clear()
            self._mats[key] = m
        return m

    def row(self, theta: Theta) -> np.ndarray:
        """Kernel parameter row of a candidate."""
        if self.vcode == BACKLASH:
            p0, p1 = theta.DB, 0.0
        elif self.vcode == KANO:
            p0, p1 = theta.S, theta.J
        elif self.vcode == HE:
            p0, p1 = 0.5 * (theta.S + theta.J), 0.5 * (theta.S - theta.J)
        else:
            p0, p1 = 0.0, 0.0
        sat = "saturation" in self.effects
        lo = theta.sat_low if sat else -np.inf
        hi = theta.sat_high if sat else np.inf
        delay = theta.delay if "dead_time" in self.effects else 0.0
        us0 = p1 + (theta.phase % 1.0) * theta.J if self.vcode == HE else 0.0
        band = theta.band if self.vcode == KANO else 0.0
        curv = theta.curvature if self.characteristic else 0.0
        return np.array([p0, p1, lo, hi, delay, *self.matrices(theta), us0, band, curv,
                         self.op_mid])

    def score(self, thetas) -> np.ndarray:
        """Score candidates; rows ``[sse_train, sse_heldout, gain, coef...]``.

        Candidates with different plant time constants are scored per group.
        A batch is scored on all cores (:func:`kernels.score_batch`) in the
        main thread only; in other threads (a scan's pool of loops, which
        already keeps the cores busy) one after the other without the GIL
        (:func:`kernels.score_serial`). Both give the same numbers. A
        candidate scored before, by this problem or another of the same model
        on the same data, is not scored again.
        """
        thetas = list(thetas)
        out = np.empty((len(thetas), 3 + self.p))
        memo = self._scores
        groups: dict = {}
        for i, th in enumerate(thetas):
            row = memo.get(th)
            if row is None:
                groups.setdefault(self.group(th), []).append(i)
            else:
                out[i] = row
        d = self.data
        for key, idx in groups.items():
            # (a candidate twice in one batch is scored twice: the same numbers)
            st = self.setup(thetas[idx[0]])
            P = np.ascontiguousarray(np.array([self.row(thetas[i]) for i in idx]))
            o = np.empty((len(idx), 3 + self.p))
            fn = kernels.score_batch if len(idx) >= 4 and _main_thread() else kernels.score_serial
            fn(self.u, self.vcode, P, d.seg_start, d.seg_end, d.seg_set, self.wt, st["qv"],
               st["WT"], st["qW"], self.anchored, st["Py"], st["ystats"], st["G2"], st["Ginv"],
               st["GinvWy"], o)
            out[idx] = o
            for j, i in enumerate(idx):
                memo[thetas[i]] = o[j]
            self.n_evals += len(idx)
        return out

    # -- full evaluation of one candidate ------------------------------------------------------
    def evaluate(self, theta: Theta) -> dict:
        """Every signal and metric of one candidate."""
        d = self.data
        n = d.n
        row = self.row(theta)
        x, xd, z, r = (np.empty(n) for _ in range(4))
        kernels.simulate_chain(self.u, self.vcode, row[0], row[1], row[12], row[11], row[2], row[3],
                               row[4], *row[5:11], row[13], row[14], x, xd, z, r)
        st = self.setup(theta)
        qa = st["qa"]
        Pr = self.project(r, qa)
        X = np.column_stack([Pr, (st["WT"][0] + st["WT"][1]).T])
        tr = self.sample_set == 0
        coef, *_ = np.linalg.lstsq(X[tr], st["Py"][tr], rcond=None)
        e = st["Py"] - X @ coef
        used = self.sample_set >= 0
        e[~used] = np.nan
        gain = float(coef[0])
        lin = dict(zip(self.lin_names, map(float, coef[1:])))
        # load signal in OP units (rate or level divided by the gain)
        beta = self.basis(theta) @ coef[1:] if self.p else np.zeros(n)
        load = -beta / gain if gain != 0 else np.full(n, np.nan)
        lagged = z if "lag" in self.effects else xd
        pv_model = np.where(used, d.pv - e, np.nan)
        return dict(theta=theta, gain=gain, lin=lin, valve=x, delayed=xd, lagged=lagged,
                    load=load, response=r, residual=e, pv_model=pv_model, Py=st["Py"])


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def zoh_matrices(process_type, lag, tau, h):
    """Exact zero-order-hold matrices of lag + unit-gain plant.

    Returns ``(f00, f01, f10, f11, g0, g1)`` of ``s_{k+1} = Phi s_k + Gam x_k``
    with ``s = [z, r]`` (lag output, plant output); closed forms of
    :func:`valvediag.models.closedloop.process_matrices` (which they match), as that
    function's matrix exponential is too slow to call per candidate.
    """
    if lag <= 0:
        if process_type == "integrating":
            return (0.0, 0.0, 0.0, 1.0, 0.0, h)
        b = math.exp(-h / tau)
        return (0.0, 0.0, 0.0, b, 0.0, 1.0 - b)
    a = math.exp(-h / lag)
    if process_type == "integrating":
        return (a, 0.0, lag * (1.0 - a), 1.0, 1.0 - a, h - lag * (1.0 - a))
    if abs(lag - tau) < 1e-6 * tau:
        _, _, pg, gg, _ = process_matrices(process_type, [1.0], [tau], [lag], [0.0], [h])
        return (pg[0, 0, 0], pg[0, 0, 1], pg[0, 1, 0], pg[0, 1, 1], gg[0, 0], gg[0, 1])
    b = math.exp(-h / tau)
    c = lag / (lag - tau)
    f10 = c * (a - b)
    g1 = 1.0 - (lag * a - tau * b) / (lag - tau)
    return (a, 0.0, f10, b, 1.0 - a, g1)


# -- search ------------------------------------------------------------------------------------
def max_delay(data: LoopData) -> float:
    """Longest dead time searched [samples]: 30 % of the OP period, at most
    300 samples or two horizons."""
    h = data.sample_time
    P = data.period if np.isfinite(data.period) else data.horizon * 4 * h
    return float(max(5, min(round(0.3 * P / h), 300, data.horizon * 2)))


def _period(data: LoopData) -> float:
    h = data.sample_time
    return data.period if np.isfinite(data.period) else data.horizon * 4 * h


def _valve_values(prob: Problem, coarse: bool, joint: bool = False):
    """Valve band candidates as field dicts (``DB``; ``S``, ``J``; He's
    ``phase``). ``joint``: a smaller set, to be crossed with another axis."""
    bm = prob.data.band_max
    if prob.vcode == BACKLASH:
        k = 12 if coarse else 32
        vals = bm * np.arange(1, k + 1) / k
        if coarse:
            vals = np.r_[vals, barely_moving_bands(prob.data)]
        return [dict(DB=float(v)) for v in vals]
    if prob.vcode in (KANO, HE):
        if joint:
            k, rs, phs = 8, (0.0, 1 / 3, 2 / 3, 1.0), (0.0, 0.5)
        elif coarse:
            k, rs, phs = 10, (0.0, 0.25, 0.5, 0.75, 1.0), (0.0, 0.25, 0.5, 0.75)
        else:
            k, rs, phs = 24, np.linspace(0, 1, 11), (None,)
        if prob.vcode == KANO:
            phs = (0.0,)
        out = []
        for v in bm * np.arange(1, k + 1) / k:
            for r in rs:
                for ph in (phs if r > 0 else phs[:1]):
                    c = dict(S=float(v), J=float(v * r))
                    if ph is not None and prob.vcode == HE:
                        c["phase"] = float(ph)
                    out.append(c)
        return out
    return [dict()]


def barely_moving_bands(data: LoopData) -> np.ndarray:
    """Dead bands just under the OP's smaller swings [OP unit].

    A dead band's limit cycle can keep the OP's swings only just above the
    band (a quantised PV, slow integral action): the valve then moves a
    small fraction of each swing, and the training error is a valley in the
    band about as narrow as that move, which a grid spaced by a twelfth of
    ``band_max`` can miss altogether. These candidates sit 1 % and 4 %
    under the 5th, 10th and 25th percentile swings between OP reversals.
    """
    rev = data.reversals
    if rev.size < 3:
        return np.array([])
    sw = np.abs(np.diff(data.op[rev]))
    v = np.outer(np.percentile(sw, [5, 10, 25]), [0.96, 0.99]).ravel()
    return v[(v > 0) & (v <= data.band_max)]


#: Farthest a saturation stop reaches into the OP's range: the OP percentile
#: (from either end) [%]. A valve held at its stops more than about half the
#: time is not a saturating valve: stops closer together make a relay, which
#: a fit then uses to mimic a sticky valve's jumps.
SAT_REACH = 45.0


#: OP percentiles (from either end) of the saturation stops searched [%]: a
#: stop acts on the valve's position, which lies inside the OP's range by
#: half a dead band or stick band, so the grid reaches well inside it (and
#: under windup the OP spends long beyond the stop it pushes against).
SAT_GRID = (0.5, 1, 2, 3, 5, 7.5, 10, 15, 20, 25, 30, 35, 40, SAT_REACH)
#: ... and, once the simplex has placed the plant, also these further out
#: [%]: an OP that rests at a few set-point levels has lumpy tails, and a
#: stop that the valve reaches for 0.2-0.4 % of the record can lie several
#: OP units beyond the 0.5 % percentile (a simulated record's 0.2 % and
#: 0.5 % percentiles were -3.7 and -0.13, its stop -1.78; from the 0.5 %
#: point the line search of :func:`_stop_lines` never reached it). Not in
#: the grid stage: there, at a plant not yet placed, a stop that clips a
#: few extremes can win and lead the simplex to a plant a tenth too slow.
SAT_TAIL = (0.05, 0.1, 0.2, 0.3)
#: ... and the fewer crossed with a self-regulating plant's time constant.
SAT_JOINT = (2, 10, 25, SAT_REACH)


def _stops(data: LoopData, q) -> list[dict]:
    """Pairs of saturation stops at the OP's percentiles ``q`` from either
    end, each side also absent (infinite), as field dicts."""
    q = np.asarray(q, dtype=float)
    lows = np.r_[-np.inf, np.percentile(data.op, q)]
    highs = np.r_[np.percentile(data.op, 100 - q[::-1]), np.inf]
    return [dict(sat_low=float(a), sat_high=float(b)) for a in lows for b in highs]


def _stop_lines(prob: Problem, theta: Theta, f_best: float, rounds: int = 2):
    """Each finite saturation stop on a fine line about its value, the other
    held, twice over.

    The training error is a staircase in a stop (it changes where a sample
    of the valve's path crosses the stop), and the path dwells at a stop it
    reaches: a stop a tenth of a band off mispredicts every dwell, and the
    simplex, whose steps are a fortieth of the largest band, stops on a
    step of that staircase. The line spans a valve band (or a tenth of the
    OP's range) either side in 40 steps. A stop is then removed unless it
    pays for its parameter: the training error without it must be higher by
    more than the BIC's price (``n ln(SSE_without / SSE) > ln n``, ``n`` the
    training samples). A stop that no training sample reaches changes
    nothing; one that clips a few noisy extremes of a valve without stops
    lowered the training error by a ten-millionth.
    """
    d = prob.data
    span = max(theta.DB if prob.vcode == BACKLASH else theta.S if prob.vcode in (KANO, HE)
               else 0.0, 0.1 * float(np.ptp(d.op)))
    lo_reach, hi_reach = sat_reach(d)
    grid = np.linspace(-1.0, 1.0, 41) * span
    for _ in range(rounds):
        for nm in ("sat_low", "sat_high"):
            v = getattr(theta, nm)
            if not math.isfinite(v):
                continue
            vals = v + grid
            vals = vals[vals <= lo_reach] if nm == "sat_low" else vals[vals >= hi_reach]
            if vals.size:
                theta, f_best, _, _ = _best(prob, [theta.replace(**{nm: float(x)})
                                                   for x in vals], current=theta)
    # a stop that no training sample reaches is not seen: absent, not placed
    # wherever the search left it (where it may cut the held-out moves); nor
    # is one that clips a few noisy extremes and does not pay for its
    # parameter (the BIC's price, log n)
    n = max(prob.n_train, 2)
    for nm, off in (("sat_low", -math.inf), ("sat_high", math.inf)):
        if math.isfinite(getattr(theta, nm)):
            cand = theta.replace(**{nm: off})
            f = float(prob.score([cand])[0, 0])
            if n * math.log(max(f, 1e-300) / max(f_best, 1e-300)) <= math.log(n):
                theta, f_best = cand, f
    return theta, f_best


def sat_reach(data: LoopData) -> tuple[float, float]:
    """Highest low stop and lowest high stop searched [OP unit]."""
    lo, hi = np.percentile(data.op, [SAT_REACH, 100.0 - SAT_REACH])
    return float(lo), float(hi)


def tau_range(data: LoopData) -> tuple[float, float]:
    """Searched range of a self-regulating plant's time constant [s]: one
    sample to five OP periods (at least ten samples)."""
    h = data.sample_time
    return h, max(5 * _period(data), 10 * h)


def load_periods(data: LoopData, k: int = 2) -> np.ndarray:
    """Candidate periods of an oscillating load [s]: the ``k`` highest peaks
    of the periodograms of the OP and of the PV (linear trend removed),
    between four samples and half the record, highest first.

    A load that drives the loop shows in both: in the PV, and in the OP
    that answers it. The periodogram's resolution is one cycle per record,
    so a peak's period is known to about ``period / record`` of itself (15 %
    for a 40-minute load in 4.5 hours): each peak is placed between its
    bins by a parabola through the log powers of the three, and the fit
    searches about it and refines it.
    """
    key = ("load_periods", k)
    if key in data._cache:
        return data._cache[key]
    h = data.sample_time
    out: list[float] = []
    for x in (data.op, data.pv):
        y = np.nan_to_num(np.asarray(x, dtype=float) - np.nanmean(x))
        f, p = periodogram_band(y, h, detrend="linear")
        if f.size < 3:
            continue
        pk = 1 + np.flatnonzero((p[1:-1] >= p[:-2]) & (p[1:-1] >= p[2:]))
        lp = np.log(np.maximum(p, 1e-300))
        for i in pk[np.argsort(p[pk])[::-1][:k]]:
            # the peak between the bins: a parabola through the log powers
            c = lp[i - 1] - 2.0 * lp[i] + lp[i + 1]
            shift = 0.5 * (lp[i - 1] - lp[i + 1]) / c if c < 0 else 0.0
            period = 1.0 / (f[i] + float(np.clip(shift, -0.5, 0.5)) * (f[1] - f[0]))
            if all(abs(period / q - 1.0) > 0.02 for q in out):
                out.append(float(period))
    res = np.array(out[:2 * k] or [4.0 * h * 10])
    data._cache[key] = res
    return res


#: Most coarse periods searched about each periodogram peak.
PERIOD_POINTS = 11


def _period_axis(data: LoopData, coarse: bool) -> list[dict]:
    """Candidate periods of the oscillating load, as field dicts.

    About each periodogram peak (:func:`load_periods`), 2 % or a quarter of
    the periodogram's resolution (one cycle per record) either side, where
    that is wider. The coarse grid is spaced by 0.05 / m of the period for a
    record of m cycles, at most :data:`PERIOD_POINTS` a peak (each period
    needs its own load basis, and the grid is crossed with the valve's band
    and the plant's time constant): a period off by ``e``
    puts the load out of phase by ``m e`` cycles at the record's ends, and
    a load a twentieth of a cycle out of phase is one a wrong time constant
    or band can make up for better than the right ones can.
    """
    span = data.n * data.sample_time
    out = []
    for q in load_periods(data):
        half = max(0.02, 0.25 * q / span)
        if coarse:
            k = int(min(PERIOD_POINTS, max(3, 2 * math.ceil(half / (0.05 * q / span)) + 1)))
        else:
            k = 9
        out += [dict(load_period=float(q * (1.0 + r))) for r in np.linspace(-half, half, k)]
    return out


def _grid(prob: Problem, coarse: bool):
    """The grid of one searched stage at a time, as lists of field dicts."""
    d = prob.data
    h = d.sample_time
    P = _period(d)
    axes = []
    if prob.process_type == "self-regulating":
        taus = np.geomspace(*tau_range(d), 10 if coarse else 24)
        axes.append([dict(tau=float(v)) for v in taus])
    if prob.vcode != LINEAR:
        axes.append(_valve_values(prob, coarse))
    if "saturation" in prob.effects:
        axes.append(_stops(d, SAT_GRID))
    if prob.oscillating:
        axes.append(_period_axis(d, coarse))
    if prob.characteristic:
        cs = np.linspace(-CURVATURE_MAX, CURVATURE_MAX, 9 if coarse else 25)
        axes.append([dict(curvature=float(c / prob.op_span)) for c in cs])
    if "dead_time" in prob.effects:
        dmax = max_delay(d)
        k = 12 if coarse else int(dmax) + 1
        axes.append([dict(delay=float(v)) for v in np.unique(np.round(np.linspace(0, dmax, k)))])
    if "lag" in prob.effects:
        axes.append([dict(lag=float(v)) for v in
                     np.geomspace(0.5 * h, max(0.5 * P, 2 * h), 8 if coarse else 20)])
    return axes


def _best(prob: Problem, cands, current=None):
    if current is not None:
        cands = [current] + [c for c in cands if c != current]
    sc = prob.score(cands)
    i = int(np.nanargmin(sc[:, 0]))
    return cands[i], float(sc[i, 0]), cands, sc[:, 0]


def _continuous(prob: Problem, theta: Theta):
    """Names, values and initial steps of the continuous searched parameters
    (transformed: bands in units of the largest band searched, ratios and
    logarithms, so that the search takes the same steps whatever the OP's
    unit)."""
    bm = prob.data.band_max
    names, x0, steps = [], [], []
    if prob.vcode == BACKLASH:
        names.append("DB")
        x0.append(theta.DB / bm)
        steps.append(1 / 20)
    elif prob.vcode in (KANO, HE):
        names += ["S", "Jr"]
        x0 += [theta.S / bm, theta.J / theta.S if theta.S > 0 else 0.0]
        steps += [1 / 20, 0.1]
        if prob.vcode == HE:
            names.append("phase")
            x0.append(theta.phase % 1.0)
            steps.append(0.25)
    if "saturation" in prob.effects:
        # finite stops are refined with the rest (an absent stop stays absent)
        for nm in ("sat_low", "sat_high"):
            v = getattr(theta, nm)
            if math.isfinite(v):
                names.append(nm)
                x0.append(v / bm)
                steps.append(1 / 40)
    if prob.characteristic:
        names.append("curv")
        x0.append(theta.curvature * prob.op_span)
        steps.append(0.3)
    if "dead_time" in prob.effects:
        names.append("delay")
        x0.append(theta.delay)
        steps.append(2.0)
    if "lag" in prob.effects:
        names.append("loglag")
        x0.append(math.log(max(theta.lag, 0.05 * prob.data.sample_time)))
        steps.append(0.4)
    if prob.process_type == "self-regulating":
        names.append("logtau")
        x0.append(math.log(theta.tau))
        steps.append(0.4)
    return names, np.array(x0, dtype=float), np.array(steps, dtype=float)


#: Step of the simplex's natural logarithm of the plant's time constant: each
#: new time constant passes the load columns through the plant again (a pass
#: over the record, the dearest part of a candidate), and the simplex's last
#: steps, well inside the error's valley, would each make a new one.
TAU_STEP = 1e-3


def _from_vector(theta: Theta, names, v, dmax, bm, tau_max=math.inf,
                 sat_reach=(math.inf, -math.inf), span=1.0) -> Theta:
    kw = {}
    for nm, val in zip(names, v):
        if nm == "DB":
            kw["DB"] = max(float(val), 0.0) * bm
        elif nm == "S":
            kw["S"] = max(float(val), 0.0) * bm
        elif nm == "Jr":
            kw["Jr"] = min(max(float(val), 0.0), 1.0)      # np.clip, without its overhead
        elif nm == "phase":
            kw["phase"] = float(val % 1.0)
        elif nm == "sat_low":
            kw[nm] = min(float(val) * bm, sat_reach[0])
        elif nm == "sat_high":
            kw[nm] = max(float(val) * bm, sat_reach[1])
        elif nm == "curv":
            c = min(max(float(val), -2.0 * CURVATURE_MAX), 2.0 * CURVATURE_MAX)
            kw["curvature"] = c / span
        elif nm == "delay":
            kw["delay"] = min(max(float(val), 0.0), dmax)
        elif nm == "loglag":
            kw["lag"] = float(math.exp(min(val, 50.0)))
        elif nm == "logtau":
            # within the searched range: beyond it the plant is an integrator
            # whose gain and operating point run off together; on a grid of
            # TAU_STEP, so that the simplex's last steps reuse the load columns
            val = round(min(float(val), 50.0) / TAU_STEP) * TAU_STEP
            kw["tau"] = float(min(math.exp(val), tau_max))
    if "S" in kw:
        kw["J"] = kw.pop("Jr", 0.0) * kw["S"]
    lo, hi = kw.get("sat_low", theta.sat_low), kw.get("sat_high", theta.sat_high)
    if lo > hi:
        kw["sat_low"], kw["sat_high"] = hi, lo
    return theta.replace(**kw)


def _refine(prob: Problem, theta: Theta, maxfev: int) -> tuple[Theta, float]:
    """Nelder-Mead on all continuous searched parameters jointly (valve
    bands, dead time, lag, time constant): their errors trade off along
    valleys that a coordinate-wise search crosses slowly. The plant's time
    constant is read on a grid of :data:`TAU_STEP` in its logarithm (0.1 %),
    which the simplex's last steps reach inside the error's valley."""
    names, x0, steps = _continuous(prob, theta)
    f0 = float(prob.score([theta])[0, 0])
    if not names:
        return theta, f0
    dmax = max_delay(prob.data)
    tau_max = tau_range(prob.data)[1]
    reach = sat_reach(prob.data)
    cache = {}

    def f(v):
        th = _from_vector(theta, names, v, dmax, prob.data.band_max, tau_max, reach,
                          prob.op_span)
        if th not in cache:
            cache[th] = float(prob.score([th])[0, 0])
        return cache[th]

    simplex = [x0] + [x0 + np.eye(len(x0))[i] * steps[i] for i in range(len(x0))]
    res = minimize(f, x0, method="Nelder-Mead",
                   options=dict(initial_simplex=np.array(simplex), maxfev=maxfev,
                                xatol=1e-3, fatol=0.0))
    fb = f(res.x)
    if fb <= f0:
        return _from_vector(theta, names, res.x, dmax, prob.data.band_max, tau_max, reach,
                            prob.op_span), fb
    return theta, f0


def _simplex_budget(names, maxfev: int | None) -> int:
    """Evaluations of one simplex run: ``maxfev``, else 40 per parameter and 20."""
    return maxfev or 40 * len(names) + 20


def refine(prob: Problem, theta: Theta, maxfev: int | None = None) -> Theta:
    """Local refinement alone: Nelder-Mead on every continuous searched
    parameter from ``theta`` (no grid), for a problem whose optimum moved a
    little from ``theta``'s (``maxfev`` as in :func:`search`)."""
    names, _, _ = _continuous(prob, theta)
    return _refine(prob, theta, _simplex_budget(names, maxfev))[0]


def initial_theta(prob: Problem) -> Theta:
    """A starting point: mid-range values of the searched parameters."""
    d = prob.data
    h = d.sample_time
    P = _period(d)
    return Theta(DB=0.3 * d.band_max, S=0.3 * d.band_max, J=0.15 * d.band_max,
                 sat_low=-math.inf, sat_high=math.inf, delay=0.0,
                 lag=float(max(0.05 * P, h)), tau=float(max(P / 4, 2 * h)),
                 band=prob.noise_band,
                 load_period=float(load_periods(d)[0]) if prob.oscillating else math.inf)


#: Ratio of time constants between the grid's best starts and one more.
TAU_APART = 3.0


def _distinct_starts(cands, scores, k):
    """The ``k`` best candidates, at most one per value of the non-valve
    parameters and of the slip-jump ratio (so that the starts lie in
    different valleys), and the best whose time constant lies a factor
    :data:`TAU_APART` from all of theirs."""
    order = np.argsort(scores)
    seen, out = set(), []
    for i in order:
        c = cands[i]
        key = (round(c.delay, 3), round(c.lag, 6), round(c.tau, 6), c.sat_low, c.sat_high,
               round(4 * c.J / c.S) if c.S > 0 else 0, round(c.load_period, 6),
               round(c.curvature, 9))
        if key in seen:
            continue
        seen.add(key)
        out.append(c)
        if len(out) == k:
            break
    # and the best with a time constant a factor TAU_APART from theirs: a
    # slow plant forgives a band a little off, a fast one does not, so on a
    # coarse grid the slow ones can take every start while the fast valley
    # holds the optimum
    for i in order:
        c = cands[i]
        if all(max(c.tau / o.tau, o.tau / c.tau) >= TAU_APART for o in out):
            out.append(c)
            break
    return out


def _fine_period(prob: Problem, theta: Theta) -> tuple[Theta, float]:
    """The load's period on ever finer grids about ``theta``'s (0.5, 0.1
    and 0.02 %; each period needs its own load basis, too dear for every
    step of the simplex).

    Over a record of ``m`` cycles a period off by ``e`` puts the load out of
    phase by ``m e`` cycles at the ends: a load of many cycles needs its
    period to a small fraction of a per cent, finer than any grid of the
    stages, before the other parameters can be searched at it.
    """
    f = float(prob.score([theta])[0, 0])
    for rel in (0.005, 0.001, 0.0002):
        q = theta.load_period * (1.0 + np.linspace(-rel, rel, 11))
        theta, f, _, _ = _best(prob, [theta.replace(load_period=float(v)) for v in q],
                               current=theta)
    return theta, f


def search(prob: Problem, start: Theta | None = None, *, starts: int = 3,
           maxfev: int | None = None) -> Theta:
    """Global grid search, then local refinement from the best few points.

    Parameters
    ----------
    prob : Problem
    start : Theta, optional
        Warm start (e.g. the parameters of a smaller model); it is also
        refined.
    starts : int
        Number of grid points refined locally (distinct in dead time, lag,
        time constant, saturation).
    maxfev : int, optional
        Evaluations allowed per local refinement; default ``40 dim + 20``.

    Returns
    -------
    Theta

    Notes
    -----
    The grid is searched one stage at a time except that the valve band is
    crossed with the dead time, the lag and the plant's time constant on a
    coarse joint grid: a longer dead time or lag otherwise passes for a
    wider band, and a time constant searched at the starting band alone can
    settle where a wrong one, with the operating point (which every model
    fits) making up for it, fits best. Crossing the time constant costs
    about 1.6 times the search time on a self-regulating loop. The time
    constant is crossed with a few saturation stops too (a valve held at
    its stops a part of the time passed for a plant a hundred times
    slower), and with the load's periods (a load a few tenths of a per cent
    off its period, out of phase at the record's ends, passed for a plant
    fifteen times slower), and with the characteristic's curvature (a
    curved valve read as a straight one passed for a plant a quarter
    faster with a band half as wide again); the valve band is crossed with the load's
    periods (on an integrating plant, a band too narrow by half made up for
    a load out of phase). With a warm
    start the stages run from it and from the cold start: from a smaller
    model's optimum alone they can stay in its valley (a dead band's fit
    with a dead time standing in for the slip jump gave a stiction fit
    with a dead time of 6.5 s for a true 3 s). The local
    step is Nelder-Mead on all continuous parameters jointly, finite
    saturation stops included (at most :data:`SAT_REACH` % into the OP's
    range); the stops are searched again after it, on their grid and
    further into the OP's tails (:data:`SAT_TAIL`), then on a fine line each
    (:func:`_stop_lines`), which removes a stop that does not pay for its
    parameter; where that moved them, the simplex runs again from there.
    The load's period is searched on finer grids after its stage and after
    the simplex (:func:`_fine_period`).
    """
    # the grid's stages run from the cold start and from the warm one: from a
    # smaller model's optimum alone they can stay in its valley (a dead time
    # that stood in for a slip jump)
    origins = [initial_theta(prob)] + ([prob_clip(prob, start)] if start is not None else [])
    axes = _grid(prob, coarse=True)
    pool_c, pool_s = [], []
    best_grid = (np.inf, origins[-1])
    valve_axis = _valve_values(prob, True, joint=True) if prob.vcode != LINEAR else [{}]
    stops_axis = _stops(prob.data, SAT_JOINT) if "saturation" in prob.effects else [{}]
    # (the load's period, too: a period a few tenths of a per cent off and a
    # time constant tens of times too slow make up for each other)
    period_axis = next((ax for ax in axes if "load_period" in ax[0]), [{}])
    curv_axis = next((ax for ax in axes if "curvature" in ax[0]), [{}])
    for theta in origins if axes else ():
        for ax in axes:
            if "tau" in ax[0]:
                # a self-regulating plant's time constant trades off with the
                # valve's band and its stops: searched at the start's band and
                # without stops, a valve held at its stops part of the time
                # passes for a plant tens of times slower
                cands = [theta.replace(**a, **v, **s) for a in ax for v in valve_axis
                         for s in stops_axis]
                if prob.oscillating:
                    cands += [theta.replace(**a, **q) for a in ax for q in period_axis]
                if prob.characteristic:
                    # (and the curvature: a curved valve read as a straight one
                    # passes for a plant of another time constant and a wider
                    # band, and from there the simplex stays in that valley)
                    cands += [theta.replace(**a, **c) for a in ax for c in curv_axis]
            elif prob.vcode != LINEAR and any(k in ax[0] for k in ("delay", "lag")):
                cands = [theta.replace(**a, **v) for a in ax for v in valve_axis]
            else:
                cands = [theta.replace(**a) for a in ax]
                if prob.oscillating and any(k in ax[0] for k in ("DB", "S")):
                    # (and the valve's band: a band too narrow by half makes up
                    # for a load out of phase, on an integrating plant too)
                    cands += [theta.replace(**v, **q) for v in valve_axis for q in period_axis]
            theta, _, c, sc = _best(prob, cands, current=theta)
            pool_c += c
            pool_s += list(sc)
            if "load_period" in ax[0]:
                theta, f = _fine_period(prob, theta)
                pool_c.append(theta)
                pool_s.append(f)
        # one coordinate sweep on the fine grids
        for ax in _grid(prob, coarse=False):
            theta, f, c, sc = _best(prob, [theta.replace(**a) for a in ax], current=theta)
            pool_c += c
            pool_s += list(sc)
            if f < best_grid[0]:
                best_grid = (f, theta)
    theta = best_grid[1]
    names, _, _ = _continuous(prob, theta)
    if not names and not prob.oscillating:
        return theta
    starts_ = _distinct_starts(pool_c, np.array(pool_s), starts) if pool_c else [theta]
    if start is not None and start not in starts_:
        starts_.append(prob_clip(prob, start))
    fev = _simplex_budget(names, maxfev)
    best, fb = None, np.inf
    for s0 in starts_ if names else [theta]:
        th, f = _refine(prob, s0, fev)
        if f < fb:
            best, fb = th, f
    if "saturation" in prob.effects:
        stops = (best.sat_low, best.sat_high)
        best, fb, _, _ = _best(prob, [best.replace(**x)
                                      for x in _stops(prob.data, SAT_TAIL + SAT_GRID)],
                               current=best)
        best, fb = _stop_lines(prob, best, fb)
        if names and (best.sat_low, best.sat_high) != stops:
            # stops placed anew: the plant that made up for the old ones moves
            th, f = _refine(prob, best, fev)
            if f < fb:
                best, fb = _stop_lines(prob, th, f)
    if prob.oscillating:
        best, fb = _fine_period(prob, best)
    if prob.vcode == KANO:
        best = _cliff_guard(prob, best, fb)
    return best


#: Where to place the stick band inside the interval of equal training error,
#: from its low end (0) to its high end (1).
FLAT_POSITION = 0.3


def _cliff_guard(prob: Problem, theta: Theta, f_best: float) -> Theta:
    """Place the stick band ``S`` inside its interval of equal training error.

    With ``S - J`` fixed (the valve's offset while moving), the valve output
    depends on ``S`` only through the samples at which it slips, so the
    training error is piecewise constant in ``S``. In a stick-slip limit
    cycle the controller often reverses the OP on the sample after the
    slip, so a model ``S`` a hair above the true one misses that slip
    altogether and its prediction diverges until the next reversal; a hair
    below, it slips a sample early, a small error. The optimiser stops
    anywhere on the optimal interval, often right at its upper edge, where a
    held-out event with a smaller excess is missed. We find the interval's
    ends (bisection, within two median OP steps) and place ``S`` at
    :data:`FLAT_POSITION` of it, nearer its lower end.
    """
    if theta.S <= 0:
        return theta
    step = float(np.median(np.abs(np.diff(prob.data.op))))
    if not step > 0:
        return theta
    c = theta.S - theta.J
    f0 = float(prob.score([theta])[0, 0])

    def at(S):
        return theta.replace(S=float(S), J=float(max(S - c, 0.0)))

    def same(v):
        return abs(v - f0) <= 1e-9 * max(abs(f0), 1e-300)

    def edge(direction):
        lim = theta.S + direction * 2.0 * step
        if direction < 0:
            lim = max(lim, c, 0.0)
        pts = theta.S + (lim - theta.S) * np.arange(1, 9) / 8
        sc = prob.score([at(x) for x in pts])[:, 0]
        bad = [k for k in range(pts.size) if not same(sc[k])]
        if not bad:
            return float(pts[-1])
        k = bad[0]
        inside, outside = (theta.S if k == 0 else float(pts[k - 1])), float(pts[k])
        for _ in range(6):
            mid = 0.5 * (inside + outside)
            if same(prob.score([at(mid)])[0, 0]):
                inside = mid
            else:
                outside = mid
        return inside

    hi = edge(+1)
    lo = edge(-1)
    return at(lo + FLAT_POSITION * (hi - lo))


def prob_clip(prob: Problem, theta: Theta) -> Theta:
    """Keep a warm start inside the searched ranges (and give it a load
    period where the model has an oscillating load and the start none)."""
    theta = theta.replace(delay=float(min(theta.delay, max_delay(prob.data))))
    if prob.oscillating and not math.isfinite(theta.load_period):
        theta = theta.replace(load_period=float(load_periods(prob.data)[0]))
    return theta
