"""
The named physical effects of the loop model, with their parameters.

A loop model is the chain::

    OP -> valve (deadband | stiction, saturation, characteristic) -> dead time -> lag
       -> plant input minus load (bias, drift, oscillating load) -> plant (gain) -> PV
       -> reading (quantisation)

Each effect is named by a string and can be added to or removed from the
chain (as pvlib's ``ModelChain`` swaps named models). The plant gain is
always there: an integrator ``g = K / tau`` [PV unit / (OP unit s)] or a
first-order plant (gain ``K`` [PV unit / OP unit], time constant ``tau`` [s]).

Parameters are either *searched* (grid search, then local refinement; they
count in the BIC like every other parameter), *linear* (solved exactly by
least squares for every searched candidate) or *read* from the record (the
grid of a quantised PV; they count in the BIC too).
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Param", "Effect", "EFFECTS", "EFFECT_NAMES", "PLANT_PARAMS", "check_effects"]


@dataclass(frozen=True)
class Param:
    """One model parameter.

    Attributes
    ----------
    name : str
        Key in the fitted ``params`` dict.
    unit : str
        Unit, e.g. ``'OP unit'`` (the unit of the controller output, usually
        %), ``'s'``.
    bounds : str
        The range searched, in words (it depends on the data).
    kind : {'searched', 'linear', 'read'}
        Searched on a grid and refined, solved by least squares, or read
        from the record.
    description : str
    """

    name: str
    unit: str
    bounds: str
    kind: str
    description: str


@dataclass(frozen=True)
class Effect:
    """A named, swappable physical effect of the loop model.

    Attributes
    ----------
    name : str
    stage : str
        Where it acts: ``'valve'``, ``'delay'``, ``'lag'``, ``'load'``,
        ``'sensor'`` (the PV's reading).
    params : tuple of Param
    description : str
    signature : str
        What its absence leaves in the residual.
    """

    name: str
    stage: str
    params: tuple[Param, ...]
    description: str
    signature: str


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("deadband", "valve",
           (Param("DB", "OP unit", "0 to band_max (1.5 x the median OP swing between reversals, at most "
                  "1.1 x the OP's 1-99 % range)", "searched",
                  "dead band (backlash) width: after a reversal the valve rests until the OP has "
                  "crossed DB, then follows it DB/2 behind"),),
           "Backlash of total width DB (Hägglund 2007); no jump.",
           "a pulse in the residual after each OP reversal"),
    Effect("stiction", "valve",
           (Param("S", "OP unit", "0 to band_max", "searched",
                  "dead band plus stick band (Kano et al. 2004)"),
            Param("J", "OP unit", "0 to S", "searched", "slip jump at breakaway")),
           "Kano (S, J) stick-slip valve (He et al. 2007 on request); with held or compressed "
           "OP samples short runs of repeated samples are not taken as rests. Replaces "
           "'deadband' (a Kano valve with J = 0 is a dead band of width S).",
           "steps in the residual just after each breakaway, alternating in sign with the "
           "direction of travel"),
    Effect("saturation", "valve",
           (Param("sat_low", "OP unit", "-inf or the OP's 0.5-15 % quantiles", "searched",
                  "valve position lower stop"),
            Param("sat_high", "OP unit", "the OP's 85-99.5 % quantiles or +inf", "searched",
                  "valve position upper stop")),
           "The valve stroke ends before the OP range does: the position is held at its stops.",
           "error only while the OP is near a limit"),
    Effect("characteristic", "valve",
           (Param("curvature", "1/OP unit", "+-4 / the OP's 1-99 % range", "searched",
                  "curvature of the installed characteristic: the flow through the valve is "
                  "m + expm1(c (x - m)) / c at position x (m: the OP's median, where its slope "
                  "is one)"),),
           "A non-linear installed valve characteristic: an equal-percentage valve (c > 0) "
           "gains as it opens, a quick-opening one (c < 0) loses; the loop's gain then "
           "changes with the operating point.",
           "residual that grows with the OP's distance from its median, of one sign on either "
           "side (the model's gain is right only at the median)"),
    Effect("dead_time", "delay",
           (Param("dead_time", "s", "0 to 30 % of the OP period (at most 300 samples or two horizons), "
                  "fractional samples", "searched",
                  "transport delay between valve and PV"),),
           "Pure delay of the valve position; a fraction of a sample interpolates linearly "
           "(exact for the integral of a held input).",
           "residual-OP cross-correlation peaking at the dead time"),
    Effect("lag", "lag",
           (Param("lag", "s", "sample time/2 to half the OP period", "searched",
                  "time constant of a first-order lag between valve and plant"),),
           "First-order lag (actuator, mixing, sensor) in series with the plant.",
           "residual correlated with the OP rate at short lags (the model leads the PV)"),
    Effect("bias", "load",
           (Param("bias", "PV unit/s (integrating) or PV unit (self-regulating)", "unbounded",
                  "linear", "the loop's operating point: -bias/gain is the OP at balance of an "
                  "integrating plant (a constant load or valve offset moves it), bias the "
                  "steady-state PV offset of a self-regulating one"),),
           "Operating point, part of every model (never suggested): real OPs sit at 30-70 % "
           "and real PVs far from zero, so shifting PV, OP and SP by constants must change no "
           "fit. On an integrator it is confounded with the Kano (S-J)/2 offset, so it is "
           "fitted jointly with the valve.",
           "a constant rate error: the residual ramps within every segment"),
    Effect("drift", "load",
           (Param("drift", "PV unit/s^2 (integrating) or PV unit/s (self-regulating)", "unbounded", "linear",
                  "mean slope of the fitted load over the record (reported; -drift/gain is the load "
                  "ramp in OP unit/s)"),
            Param("drift_knots", "-", "fixed (default 3)", "linear",
                  "interior knots of the piecewise-linear load; one slope change each")),
           "Slowly varying unmeasured load: a ramp plus a piecewise-linear random walk with a "
           "few knots (no constant term: that is 'bias').",
           "a ramp or slow wander in the rate error"),
    Effect("oscillating_load", "load",
           (Param("load_period", "s", "about the periodogram peaks of OP and PV (within 2 %), "
                  "refined", "searched", "period of an unmeasured periodic load"),
            Param("load_amplitude", "OP unit", "unbounded", "linear",
                  "amplitude of its fundamental, from sine and cosine terms at the period and "
                  "at three times its frequency (a square or triangular wave's first harmonics)")),
           "Unmeasured periodic load (a neighbouring loop's cycle, a pump, a batch step): the "
           "loop answers it with an OP that follows the load while the valve moves linearly. "
           "It tells a disturbance from a valve fault.",
           "a periodic residual at a period of its own, unrelated to the valve's reversals"),
    Effect("quantisation", "sensor",
           (Param("quant_step", "PV unit", "the smallest step between the PV's distinct values",
                  "read", "step of the grid the PV is read on"),
            Param("quant_offset", "PV unit", "a reading of the PV", "read",
                  "a point of that grid"),
            Param("quant_noise", "PV unit", "0 to one step", "searched",
                  "noise ahead of the quantiser: 0 reads a hard staircase, a step or more "
                  "dithers it away")),
           "The PV is read on a grid (a transmitter or analyser of coarse resolution, a "
           "historian storing few digits): the model predicts the expected reading, a "
           "staircase rounded by the noise ahead of the quantiser "
           "(valvediag.workbench.sensor.quantised_mean). Void when the PV is not on "
           "a grid.",
           "a staircase: an error of up to half a step that follows where the model's PV lies "
           "within its grid cell"),
)}

#: Names of the effects, in the order the chain applies them.
EFFECT_NAMES = tuple(EFFECTS)

#: The plant's own parameters, always present.
PLANT_PARAMS = {
    "integrating": (Param("gain", "PV unit/(OP unit s)", "unbounded", "linear",
                          "integrator gain g = K/tau"),),
    "self-regulating": (Param("gain", "PV unit/OP unit", "unbounded", "linear",
                              "steady-state gain K"),
                        Param("tau", "s", "sample time to 5 OP periods", "searched",
                              "plant time constant")),
}


def check_effects(effects) -> tuple[str, ...]:
    """Validate and normalise a list of effect names.

    Parameters
    ----------
    effects : str or iterable of str
        Effect names, or a comma-separated string (``'deadband,dead_time'``).

    Returns
    -------
    tuple of str
        Unique names in chain order.

    Raises
    ------
    ValueError
        An unknown name.
    """
    if isinstance(effects, str):
        effects = [e for e in (s.strip() for s in effects.split(",")) if e]
    names = list(effects or ())
    unknown = [e for e in names if e not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {', '.join(map(repr, unknown))}; choose from "
                         f"{', '.join(EFFECT_NAMES)}")
    return tuple(e for e in EFFECT_NAMES if e in names)
