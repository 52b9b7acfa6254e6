"""
The loop model (named, swappable effects) and its fitted result.

:class:`LoopModel` is the workbench's ``ModelChain``: it only orchestrates.
Each physical step is a named effect from :data:`~valvediag.workbench.EFFECTS`;
the model is driven by the measured OP and predicts the PV. Every
intermediate signal is kept in the frozen :class:`ModelFit`. Here on a
simulated loop (a loose valve of dead band 3, a dead time of 10 s, an
integrating process of gain 1/60)::

    >>> from valvediag import simulate_loop
    >>> sim = simulate_loop(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, duration=3600,
    ...                     sp_step=1.0, valve="backlash", valve_params={"DB": 3.0},
    ...                     dead_time=10.0, noise_std=0.005, seed=1)
    >>> pv, op = sim.pv, sim.op                   # or a measured record
    >>> from valvediag.workbench import LoopModel, prepare_loop
    >>> data = prepare_loop(pv, op, sample_time=1.0)
    >>> fit = LoopModel(("deadband", "dead_time")).fit(data)
    >>> fit.params, fit.fit_pct, fit.heldout_rmse, fit.bic
    ({'gain': 0.01666..., 'DB': 2.998..., 'dead_time': 10.000..., 'bias': 4.6...e-06}, 98.30..., 0.005054..., -19385.6...)
    >>> fit.plot()                 # measured vs model, held-out blocks shaded
    <Axes: title={'center': 'measured vs model (held-out blocks shaded; ...'}, ...>
    >>> fit.plot_chain()           # OP -> valve -> delayed -> lagged -> input -> PV
    [<Axes: ylabel='OP unit'>, <Axes: ylabel='OP unit'>, <Axes: xlabel='time [s]', ylabel='PV'>]
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import ndtr

from ..models.valves import HE, KANO
from ..plain import finite_or_none
from .data import LoopData, shade_heldout
from .effects import EFFECTS, PLANT_PARAMS, check_effects
from .fit import LOAD_HARMONICS, PROCESS_TYPES, Problem, Theta, refine, search
from .sensor import fit_quantiser

__all__ = ["LoopModel", "ModelFit", "fit_model"]


@dataclass(frozen=True)
class LoopModel:
    """A loop model made of named effects.

    Parameters
    ----------
    effects : str or tuple of str
        Effect names (see :data:`valvediag.workbench.EFFECTS`):
        ``'deadband'``, ``'stiction'``, ``'saturation'``, ``'dead_time'``,
        ``'lag'``, ``'bias'``, ``'drift'``, ``'characteristic'``,
        ``'oscillating_load'``, ``'quantisation'``; or one comma-separated
        string.
        ``'stiction'`` replaces ``'deadband'`` (a Kano valve with ``J = 0`` is
        a dead band of width ``S``). ``'bias'``, the loop's operating point,
        is part of every model whether named or not (see Notes).
    process_type : {'integrating', 'self-regulating'}
        Plant: ``g / s`` (gain ``g = K/tau`` [PV unit / (OP unit s)]) or
        ``K / (tau s + 1)``.
    valve_model : {'auto', 'kano', 'he'}
        Stiction model: Kano et al. (2004), or He et al. (2007) with the
        same ``S = fs + fd`` and ``J = fs - fd``. ``'auto'``: Kano, with a
        rest tolerance when more than 5 % of the OP samples repeat the
        previous one (held or compressed data would otherwise be false
        rests): short runs of repeated samples are not rests.
    drift_knots : int
        Interior knots of the piecewise-linear drift.

    Notes
    -----
    He's valve moves in slip steps of ``J`` even under a slowly ramping
    input and keeps the phase of those steps for ever, so its initial
    residual force is fitted too (``Theta.phase``); its error surface is far
    rougher than Kano's. A Kano valve driven by a noisy OP sticks at every
    noise reversal, as the model says; a real positioner may filter them.

    On a self-regulating plant a lag and the plant time constant are
    interchangeable in the transfer function ``K / ((tau s + 1)(lag s + 1))``;
    only the load (which enters after the lag) tells them apart, so read
    them as a pair.

    Every model fits the loop's operating point (the effect ``'bias'``): the
    OP at balance of an integrating plant, the steady-state offset of a
    self-regulating one, and any constant load with it. Real OPs sit at
    30-70 % and real PVs far from zero; a model without it would read the
    operating point as a missing effect. With it, shifting PV, OP and SP by
    constants or rescaling them changes no suggestion and no error ratio
    (the searched bands are relative to the OP's swings, the errors scale
    with the PV). Its cost is one linear coefficient.

    The chain is: OP -> valve (dead band or stiction, then saturation and
    the installed characteristic) -> dead time (fractional samples
    interpolate) -> first-order lag -> plant input minus load (bias, drift,
    oscillating load) -> plant -> PV -> reading. The load enters after the
    lag; for a constant or slowly varying load that is the same as before
    it. The reading (``'quantisation'``, :mod:`valvediag.workbench.sensor`)
    acts on the chain's prediction: the chain is fitted to the readings by
    least squares, then refitted to the process values the readings allow
    (:func:`_dequantised_refit`); a PV not on a grid costs nothing more.

    References
    ----------
    .. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical
       model and detection algorithm for valve stiction. IFAC DYCOPS 7.
    .. [2] He, Q. P., Wang, J., Pottmann, M., Qin, S. J. (2007). A curve
       fitting method for detecting valve stiction in oscillating control
       loops. Ind. Eng. Chem. Res. 46, 4549-4560.
    .. [3] Hägglund, T. (2007). Automatic on-line estimation of backlash in
       control loops. Journal of Process Control 17, 489-499.
    """

    effects: tuple[str, ...] = ()
    process_type: str = "integrating"
    valve_model: str = "auto"
    drift_knots: int = 3

    def __post_init__(self):
        # the operating point is part of every model
        eff = check_effects(check_effects(self.effects) + ("bias",))
        if "stiction" in eff and "deadband" in eff:
            eff = tuple(e for e in eff if e != "deadband")
        object.__setattr__(self, "effects", eff)
        if self.process_type not in PROCESS_TYPES:
            raise ValueError(f"process_type must be one of {PROCESS_TYPES}, not {self.process_type!r}")
        if self.valve_model not in ("auto", "kano", "he"):
            raise ValueError(f"valve_model must be 'auto', 'kano' or 'he', not {self.valve_model!r}")

    @property
    def name(self) -> str:
        """The effects joined by '+' (without the operating point, which every
        model has), or 'plant only'."""
        named = [e for e in self.effects if e != "bias"]
        return "+".join(named) if named else "plant only"

    def add(self, effect: str) -> "LoopModel":
        """This model with one more effect.

        Parameters
        ----------
        effect : str

        Returns
        -------
        LoopModel
        """
        return LoopModel(self.effects + (effect,), self.process_type, self.valve_model,
                         self.drift_knots)

    def candidates(self) -> tuple[str, ...]:
        """Effects that could still be added (stiction can replace a dead band)."""
        return tuple(e for e in EFFECTS if e not in self.effects
                     and not (e == "deadband" and "stiction" in self.effects))

    def evaluate(self, data: LoopData, theta: Theta) -> "ModelFit":
        """The model at given searched parameters (linear ones solved), no search.

        Parameters
        ----------
        data : LoopData
        theta : Theta
            Searched parameters; fields of effects not in the model are
            ignored.

        Returns
        -------
        ModelFit
        """
        vm = self.valve_model if "stiction" in self.effects else "kano"
        prob = Problem(data, self.effects, self.process_type, self.drift_knots, vm, theta.band)
        return _result(self, prob, theta)

    def fit(self, data: LoopData, *, start=None) -> "ModelFit":
        """Fit the model to prepared data.

        Parameters
        ----------
        data : LoopData
            From :func:`valvediag.workbench.prepare_loop`.
        start : ModelFit or Theta, optional
            Warm start for the searched parameters (a smaller model's fit);
            refined besides the grid's best points. A dead band width seeds
            the stick band ``S`` (with ``J = 0``).

        Returns
        -------
        ModelFit
        """
        vms = (self.valve_model,) if "stiction" in self.effects else ("kano",)
        # a sticky valve's actuator may or may not reverse on the OP's noise:
        # both are fitted and the data choose (LoopData.noise_band)
        bands = (0.0,)
        if "stiction" in self.effects and data.noise_band > 0:
            bands = (data.noise_band, 0.0)
        th0 = None
        if isinstance(start, ModelFit):
            if set(self.effects) - set(start.effects) == {"quantisation"} \
                    and set(start.effects) <= set(self.effects) \
                    and self.process_type == start.model.process_type:
                # the reading acts after the chain: the chain's fit stands, only
                # the quantiser's noise is fitted (in _result)
                prob = Problem(data, self.effects, self.process_type, self.drift_knots,
                               self.valve_model, start.theta.band)
                return _dequantised_refit(self, prob, start.theta)
            th0 = start.theta
            if "stiction" in self.effects and "stiction" not in start.effects and th0.DB > 0:
                th0 = th0.replace(S=th0.DB, J=0.0)
        elif start is not None:
            th0 = start
        best = None
        for vm in vms:
            for band in bands:
                prob = Problem(data, self.effects, self.process_type, self.drift_knots, vm, band)
                th = search(prob, None if th0 is None else th0.replace(band=band))
                sse = float(prob.score([th])[0, 0])
                if best is None or sse < best[2]:
                    best = (prob, th, sse)
        prob, th, _ = best
        if "quantisation" in self.effects:
            return _dequantised_refit(self, prob, th)
        return _result(self, prob, th)


@dataclass(frozen=True, eq=False)
class ModelFit:
    """A fitted loop model with every intermediate signal.

    Attributes
    ----------
    model : LoopModel
    params : dict
        Fitted parameters by name: ``gain``, ``tau`` (self-regulating),
        ``DB`` or ``S``, ``J``, ``sat_low``, ``sat_high``, ``dead_time``,
        ``lag``, ``bias``, ``drift``, ``curvature``, ``load_period``,
        ``quant_step``, ``quant_offset``, ``quant_noise`` (units in
        :attr:`units`).
    units : dict
        Unit of each parameter.
    derived : dict
        Quantities derived from the parameters: ``load_offset`` [OP unit]
        (``-bias/gain``), ``load_drift`` [OP unit/s], ``valve_model``.
    t : numpy.ndarray
        Time [s].
    op, valve, delayed, lagged, load, plant_input : numpy.ndarray
        The chain [OP unit]: controller output, valve position, delayed
        position, lagged position, estimated load, plant input
        (``lagged - load``).
    pv, pv_model, residual : numpy.ndarray
        Measured PV, model PV (each segment re-initialised to its best
        initial state; with ``'quantisation'`` its expected reading) and
        ``pv - pv_model`` [PV unit]; NaN outside scored segments.
    sample_set : numpy.ndarray of int
        0 training, 1 held-out, -1 not scored.
    fit_pct : float
        Held-out fit ``100 (1 - |e| / |y0|)`` [%], ``y0`` the PV with each
        segment's mean removed (the error of a model that predicts a
        constant PV per segment), as MATLAB's ``compare`` but per segment;
        with ``reinit='measured'``, minus each segment's first value.
    fit_pct_train : float
        The same on the training blocks [%].
    heldout_rmse, train_rmse : float
        Root-mean-square error [PV unit].
    bic : float
        ``n ln(SSE/n) + k ln(n)`` on the training samples.
    n_params : int
        ``k``: gain, load coefficients and searched parameters.
    n_train, n_heldout : int
        Scored samples.
    theta : Theta
        The searched parameters (for warm starts).
    data : LoopData
    """

    model: LoopModel
    params: dict
    units: dict
    derived: dict
    t: np.ndarray = field(repr=False)
    op: np.ndarray = field(repr=False)
    valve: np.ndarray = field(repr=False)
    delayed: np.ndarray = field(repr=False)
    lagged: np.ndarray = field(repr=False)
    load: np.ndarray = field(repr=False)
    plant_input: np.ndarray = field(repr=False)
    pv: np.ndarray = field(repr=False)
    pv_model: np.ndarray = field(repr=False)
    residual: np.ndarray = field(repr=False)
    sample_set: np.ndarray = field(repr=False)
    fit_pct: float
    fit_pct_train: float
    heldout_rmse: float
    train_rmse: float
    bic: float
    n_params: int
    n_train: int
    n_heldout: int
    theta: Theta = field(repr=False)
    data: LoopData = field(repr=False)

    @property
    def effects(self) -> tuple[str, ...]:
        """The model's effects."""
        return self.model.effects

    def summary(self) -> str:
        """A few lines: model, parameters with units, scores."""
        lines = [f"model: {self.model.name} ({self.model.process_type})"]
        for k, v in self.params.items():
            lines.append(f"  {k:10s} = {_fmt(v)} [{self.units.get(k, '')}]")
        lines.append(f"  fit {self.fit_pct:.1f} % held-out ({self.fit_pct_train:.1f} % training), "
                     f"held-out RMSE {self.heldout_rmse:.4g}, BIC {self.bic:.1f}, "
                     f"{self.n_params} parameters")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready summary (NaN as None)."""
        return {"effects": list(self.effects), "params": {k: finite_or_none(v) for k, v in self.params.items()},
                "fit_pct": finite_or_none(self.fit_pct), "heldout_rmse": finite_or_none(self.heldout_rmse),
                "bic": finite_or_none(self.bic)}

    def diagnose(self, **kw):
        """Where the model fails: see :func:`valvediag.workbench.diagnose_fit`.

        Parameters
        ----------
        **kw : dict
            Passed on (``n_worst``, ``max_lag``).

        Returns
        -------
        Diagnosis
        """
        from .diagnosis import diagnose_fit

        return diagnose_fit(self, **kw)

    def plot(self, ax=None, *, other: "ModelFit | None" = None, window=None):
        """Measured PV against the model (and optionally a second model).

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
        other : ModelFit, optional
            A second fit drawn for comparison ("before").
        window : tuple of float, optional
            Time range to show [s].

        Returns
        -------
        matplotlib.axes.Axes
        """
        if ax is None:
            import matplotlib.pyplot as plt

            _, ax = plt.subplots(figsize=(9, 3.2))
        shade_heldout(ax, self.data)
        sl = _window(self.t, window)
        ax.plot(self.t[sl], self.pv[sl], color="0.35", lw=0.8, label="measured PV")
        if other is not None:
            ax.plot(other.t[sl], other.pv_model[sl], color="C3", lw=0.9, alpha=0.8,
                    label=f"{other.model.name}: fit {other.fit_pct:.1f} %")
        ax.plot(self.t[sl], self.pv_model[sl], color="C0", lw=1.0,
                label=f"{self.model.name}: fit {self.fit_pct:.1f} %")
        if window is not None:
            ax.set_xlim(*window)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("PV")
        ax.legend(loc="upper right", fontsize=8)
        ax.set_title("measured vs model (held-out blocks shaded; prediction re-initialised "
                     f"every {self.data.horizon} samples)", fontsize=9)
        return ax

    def plot_chain(self, axes=None, *, window=None):
        """Every signal of the chain, OP to PV, on stacked axes.

        Parameters
        ----------
        axes : sequence of 3 matplotlib.axes.Axes, optional
        window : tuple of float, optional
            Time range to show [s].

        Returns
        -------
        list of matplotlib.axes.Axes
        """
        if axes is None:
            import matplotlib.pyplot as plt

            _, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
        sl = _window(self.t, window)
        t = self.t[sl]
        a0, a1, a2 = axes
        a0.plot(t, self.op[sl], color="C1", lw=0.8, label="OP")
        a0.plot(t, self.valve[sl], color="C2", lw=0.9, label="valve position")
        if "dead_time" in self.effects:
            a0.plot(t, self.delayed[sl], color="C4", lw=0.8, label="delayed")
        if "lag" in self.effects:
            a0.plot(t, self.lagged[sl], color="C5", lw=0.8, label="lagged")
        a0.set_ylabel("OP unit")
        a0.legend(loc="upper right", fontsize=8)
        a1.plot(t, self.plant_input[sl], color="C0", lw=0.8, label="plant input (lagged - load)")
        if np.any(np.nan_to_num(self.load[sl]) != 0):
            a1.plot(t, self.load[sl], color="C3", lw=0.8, label="load")
        a1.set_ylabel("OP unit")
        a1.legend(loc="upper right", fontsize=8)
        a2.plot(t, self.pv[sl], color="0.35", lw=0.8, label="measured PV")
        a2.plot(t, self.pv_model[sl], color="C0", lw=0.9, label="model PV")
        a2.set_ylabel("PV")
        a2.set_xlabel("time [s]")
        a2.legend(loc="upper right", fontsize=8)
        if window is not None:
            a2.set_xlim(*window)
        return list(axes)


def _window(t, window):
    if window is None:
        return slice(None)
    a, b = np.searchsorted(t, window)
    return slice(a, max(b, a + 1))


def _fmt(v):
    return v if isinstance(v, str) else f"{v:.5g}"


def _segment_demeaned(d: LoopData) -> np.ndarray:
    """PV minus its mean (or, re-initialised at the measured PV, minus its
    first value) in each scored segment; 0 elsewhere."""
    key = "pv_reference"
    if key not in d._cache:
        ss = d.sample_set
        use = ss >= 0
        sid = d.seg_id
        s = sid[use]
        nseg = d.seg_start.size
        y = np.where(use, np.nan_to_num(d.pv), 0.0)
        if d.reinit == "measured":
            m = y[d.seg_start]
        else:
            cnt = np.maximum(np.bincount(s, minlength=nseg), 1)
            m = np.bincount(s, weights=y[use], minlength=nseg) / cnt
        d._cache[key] = np.where(use, y - m[np.maximum(sid, 0)], 0.0)
    return d._cache[key]


#: Most refits of the chain to the process values the readings allow (EM steps).
DEQUANTISE_STEPS = 30
#: ... made while the readings' training RMSE falls by more than this share a step.
DEQUANTISE_TOL = 1e-3


def _dequantised_refit(model: LoopModel, prob: Problem, th: Theta) -> ModelFit:
    """Fit the chain behind a quantiser: refit it to the process values the
    readings allow, as long as the readings' training error falls.

    Least squares on the readings fits the chain to a staircase. Given the
    chain's prediction ``y`` and the quantiser's noise ``s``, the process
    value ahead of the quantiser lies in the reading's grid cell; its
    expectation there (a normal of mean ``y`` and deviation ``s`` truncated
    to the cell; the point of the cell nearest ``y`` when ``s`` is 0) is
    what the chain is refitted to, warm-started (an EM step for
    interval-censored least squares). The first step is a whole search,
    the later ones a local refinement (:func:`~valvediag.workbench.fit.refine`),
    until the training RMSE falls by less than :data:`DEQUANTISE_TOL` (at
    most :data:`DEQUANTISE_STEPS`).

    Notes
    -----
    EM converges slowly where the staircase is coarse (each step moves the
    chain by a part of the way: the training RMSE of a PV read on a grid of
    ten noise deviations fell 0.5, 0.4, ... 0.15 % a step, still falling
    after twelve). Stopped after two steps, the fit was left short of its
    optimum, and a candidate effect refitted on top of it went further
    along the same way and passed for a gain of 1-2 % in the held-out
    error: an effect absent from the data accepted.
    """
    fit = _result(model, prob, th)
    grid = prob.data.pv_grid
    d = prob.data
    for i in range(DEQUANTISE_STEPS):
        s = fit.params.get("quant_noise", math.inf)
        if not (grid.found and s < grid.step):
            break
        y = prob.evaluate(th)["pv_model"]
        lo = grid.offset + grid.step * (np.round((d.pv - grid.offset) / grid.step) - 0.5)
        hi = lo + grid.step
        v = np.clip(y, lo, hi) if s <= 0 else _truncated_mean(y, s, lo, hi)
        v = np.where(np.isfinite(v), v, d.pv)
        prob2 = Problem(replace(d, pv=v, _cache={}), model.effects, model.process_type,
                        model.drift_knots, model.valve_model, th.band)
        th2 = search(prob2, th) if i == 0 else refine(prob2, th)
        fit2 = _result(model, prob2, th2, readings=d)
        if not fit2.train_rmse < fit.train_rmse:
            break
        fall = 1.0 - fit2.train_rmse / fit.train_rmse
        fit, prob, th = fit2, prob2, th2
        if fall < DEQUANTISE_TOL:
            break
    return fit


def _truncated_mean(y, s, lo, hi):
    """Mean of a normal (mean ``y``, deviation ``s``) truncated to ``[lo, hi]``.

    As ``scipy.stats.truncnorm.mean``, which takes seconds for a day of
    samples. Where the cell lies more than about seven deviations from
    ``y`` the ratio of normal densities underflows, and the mean is the
    cell's nearer end moved in by ``s^2`` over its distance (the leading
    term of the Mills ratio).
    """
    a, b = (lo - y) / s, (hi - y) / s
    z = ndtr(b) - ndtr(a)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = y + s * (np.exp(-0.5 * a * a) - np.exp(-0.5 * b * b)) / (math.sqrt(2 * math.pi) * z)
        tail = np.where(a > 0, lo + s / a, hi + s / b)
    return np.clip(np.where(z > 1e-12, m, tail), lo, hi)


def _result(model: LoopModel, prob: Problem, th: Theta, readings: LoopData | None = None
            ) -> ModelFit:
    """The fitted model at ``th``; ``readings``: the record whose PV the
    quantiser reads and the errors are scored on, when the chain was fitted
    to other values of it (:func:`_dequantised_refit`)."""
    d = prob.data if readings is None else readings
    ev = prob.evaluate(th)
    ss = prob.sample_set
    e = ev["residual"]
    pv_model = ev["pv_model"]
    h = d.sample_time
    eff = model.effects
    grid = spread = None
    if "quantisation" in eff:
        grid = d.pv_grid
        spread, pv_model = fit_quantiser(d.pv, pv_model, ss == 0, grid)
        e = d.pv - pv_model
    n_tr, n_he = prob.n_train, prob.n_held
    sse_tr = float(np.nansum(e[ss == 0] ** 2))
    sse_he = float(np.nansum(e[ss == 1] ** 2))
    # reference: the PV with each segment's mean removed (the same for every
    # model of the record, so fit % compares across models and process types)
    y0 = _segment_demeaned(d)
    y0_tr = float(np.sum(y0[ss == 0] ** 2))
    y0_he = float(np.sum(y0[ss == 1] ** 2))
    params: dict = {"gain": ev["gain"]}
    units = {"gain": PLANT_PARAMS[model.process_type][0].unit}
    k = 1
    if model.process_type == "self-regulating":
        params["tau"], units["tau"] = th.tau, "s"
        k += 1
    if "deadband" in eff:
        params["DB"], units["DB"] = th.DB, "OP unit"
        k += 1
    if "stiction" in eff:
        params["S"], params["J"] = th.S, th.J
        units["S"] = units["J"] = "OP unit"
        k += 2
    if "saturation" in eff:
        params["sat_low"], params["sat_high"] = th.sat_low, th.sat_high
        units["sat_low"] = units["sat_high"] = "OP unit"
        k += 2
    if "characteristic" in eff:
        params["curvature"], units["curvature"] = th.curvature, "1/OP unit"
        k += 1
    if "dead_time" in eff:
        params["dead_time"], units["dead_time"] = th.delay * h, "s"
        k += 1
    if "lag" in eff:
        params["lag"], units["lag"] = th.lag, "s"
        k += 1
    lin = ev["lin"]
    integ = model.process_type == "integrating"
    derived: dict = {}
    if prob.vcode in (KANO, HE):
        derived["valve_model"] = prob.valve_model
        if prob.rest_tolerance:
            derived["rest_tolerance"] = int(prob.rest_tolerance)
        if prob.vcode == KANO:
            derived["noise_band"] = float(th.band)
    g = ev["gain"]
    if "bias" in eff:
        params["bias"] = lin["bias"]
        units["bias"] = "PV unit/s" if integ else "PV unit"
        derived["load_offset"] = -lin["bias"] / g if g else math.nan
        k += 1
    if "drift" in eff:
        # average slope of the fitted load over the scored span
        knots = prob.knots
        slope = lin["drift"] + sum(lin[f"drift_knot_{j + 1}"] * (0.5 - kn)
                                   for j, kn in enumerate(knots))
        params["drift"] = slope / prob.span
        units["drift"] = "PV unit/s^2" if integ else "PV unit/s"
        derived["load_drift"] = -params["drift"] / g if g else math.nan
        derived["drift_knots"] = int(len(knots))
        k += 1 + len(knots)
    if "oscillating_load" in eff:
        params["load_period"], units["load_period"] = th.load_period, "s"
        amp = math.hypot(lin["load_sin_1"], lin["load_cos_1"])
        derived["load_amplitude"] = amp / abs(g) if g else math.nan
        k += 1 + 2 * len(LOAD_HARMONICS)
    if grid is not None:
        params["quant_step"], params["quant_offset"] = grid.step, grid.offset
        params["quant_noise"] = spread
        units["quant_step"] = units["quant_offset"] = units["quant_noise"] = "PV unit"
        derived["pv_levels"] = grid.levels
        k += 3
    load = np.nan_to_num(ev["load"]) if prob.p else np.zeros(d.n)
    fit_he = 100.0 * (1.0 - math.sqrt(sse_he / y0_he)) if y0_he > 0 else math.nan
    fit_tr = 100.0 * (1.0 - math.sqrt(sse_tr / y0_tr)) if y0_tr > 0 else math.nan
    bic = n_tr * math.log(max(sse_tr, 1e-300) / n_tr) + k * math.log(n_tr)
    return ModelFit(model=model, params=params, units=units, derived=derived, t=d.t, op=d.op,
                    valve=ev["valve"], delayed=ev["delayed"], lagged=ev["lagged"], load=load,
                    plant_input=ev["lagged"] - load, pv=d.pv, pv_model=pv_model,
                    residual=e, sample_set=ss, fit_pct=fit_he, fit_pct_train=fit_tr,
                    heldout_rmse=math.sqrt(sse_he / n_he), train_rmse=math.sqrt(sse_tr / n_tr),
                    bic=bic, n_params=k, n_train=n_tr, n_heldout=n_he, theta=th, data=d)


def fit_model(pv, op, sample_time, effects=(), *, process_type="integrating", sp=None,
              **options) -> ModelFit:
    """Prepare a record and fit one loop model (a shortcut).

    Parameters
    ----------
    pv, op : array_like
        Measured PV [PV unit] and controller output [OP unit].
    sample_time : float
        [s]
    effects : str or tuple of str
        Effect names.
    process_type : {'integrating', 'self-regulating'}
    sp : array_like, optional
        Set point [PV unit].
    **options : dict
        Passed to :func:`valvediag.workbench.prepare_loop` (``horizon``,
        ``blocks``, ``band_max``, ``name``).

    Returns
    -------
    ModelFit
    """
    from .data import prepare_loop

    data = prepare_loop(pv, op, sample_time, sp=sp, **options)
    return LoopModel(effects, process_type).fit(data)
