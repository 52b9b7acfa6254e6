"""
Size of a valve fault for the nightly scan: dead band width, or Kano S and J.
"""
from __future__ import annotations

import math

import numpy as np

from ..analysis.quality import white_noise_std
from .data import (REBUILD_R2, WorkbenchDataError, prepare_loop, rebuild_compressed_op,
                   stored_points)
from .model import LoopModel

__all__ = ["estimate_valve_size", "size_window", "prepare_valve_record", "SIZE_EFFECTS",
           "SIZE_MAX_SAMPLES", "SIZE_MAX_CYCLES", "SIZE_MIN_CYCLES", "SIZE_FIT_SAMPLES",
           "SIZE_SAMPLES_PER_PERIOD"]

#: Effects fitted besides the valve: a load offset and slow drift are in
#: almost every historian record, and a dead time is confounded with the
#: band width if left out.
SIZE_EFFECTS = ("dead_time", "bias", "drift")
#: Effects of :data:`SIZE_EFFECTS` kept only when they earn their place: a
#: dead time trades off against the band along the OP's ramps.
SIZE_OPTIONAL = ("dead_time",)
#: An optional effect is kept when it lowers the held-out RMSE by more than
#: this fraction [-].
SIZE_OPTIONAL_GAIN = 0.03

#: Most samples (the latest of the record) fitted for a fault's size [-].
SIZE_MAX_SAMPLES = 43_200
#: Most oscillation periods (the latest of the record) fitted for a fault's size [-]:
#: more cycles than this barely change the size but cost time in proportion.
SIZE_MAX_CYCLES = 100.0
#: Fitted samples (after subsampling) beyond which the periods are cut from
#: :data:`SIZE_MAX_CYCLES` towards :data:`SIZE_MIN_CYCLES` [-].
SIZE_FIT_SAMPLES = 6000
#: Fewest oscillation periods fitted when the record holds them [-].
SIZE_MIN_CYCLES = 50.0
#: A record finer than this many samples per period is subsampled (every k-th
#: sample) for the size fit [samples per period].
SIZE_SAMPLES_PER_PERIOD = 120.0

#: A stick band ``S`` fitted with a slip jump below this share of it has no
#: jump to speak of [-].
NO_JUMP = 0.2
#: Above this share of interpolated (or held) samples the OP is compressed [-].
COMPRESSED_SHARE = 0.3

_FAULTS = {"stiction": "stiction", "backlash": "deadband", "deadband": "deadband"}


def size_window(n: int, sample_time: float, period: float = math.nan, *,
                max_cycles: float = SIZE_MAX_CYCLES, min_cycles: float = SIZE_MIN_CYCLES,
                fit_samples: int = SIZE_FIT_SAMPLES,
                per_period: float = SIZE_SAMPLES_PER_PERIOD) -> tuple[int, int]:
    """The part of a record that a size fit reads: its latest samples, subsampled.

    Parameters
    ----------
    n : int
        Samples in the record.
    sample_time : float
        [s]
    period : float, optional
        Oscillation period [s]. Without it (NaN) only :data:`SIZE_MAX_SAMPLES`
        limits the record and it is not subsampled.
    max_cycles, min_cycles : float, optional
        Most and fewest periods kept (:data:`SIZE_MAX_CYCLES`,
        :data:`SIZE_MIN_CYCLES`) [-].
    fit_samples : int, optional
        Fitted samples beyond which periods are cut down to ``min_cycles``
        (:data:`SIZE_FIT_SAMPLES`) [-].
    per_period : float, optional
        Samples per period above which the record is subsampled
        (:data:`SIZE_SAMPLES_PER_PERIOD`) [-].

    Returns
    -------
    start, step : int
        Fit ``x[start::step]`` (sample time ``step * sample_time``); the
        subsampled record ends at the record's last sample.

    Notes
    -----
    The fit's cost grows with the samples times the model evaluations
    (about a thousand), so a record with more than ``per_period`` samples
    per period is subsampled by the integer factor that brings it to at
    least that many, and the record is limited to its latest
    ``max_cycles`` periods, or fewer (down to ``min_cycles``) where these
    hold more than ``fit_samples`` fitted samples. On the 100-loop synthetic
    plant (1 s, 24 h) the first two limits cut the work about fourfold and
    left the median ratio of the size to the simulated one at 0.84 (0.85
    with the whole episode) on the sizes of confidence >= 0.8.

    The sample budget cuts the work by a third on the sizing benchmark
    (``benchmarks/bench_sizing.py``, 360 records of a day: 595 s of fitting
    with 100 periods, 402 s with the budget) and leaves the sizes' errors as
    they were (median error of S, J and DB 11.3, 23.6 and 10.3 % with 100
    periods; 10.9, 22.5 and 9.2 % with the budget). The floor of 50 periods
    matters: with a floor of 30, J's median error grew to 27 % (36 % at
    1 s). So does the budget: cut to 50 periods throughout, 5 of 216 sticky
    valves sampled at 10 s (7-43 samples per period, where 100 periods are
    few samples) were sized without a slip jump (J < 0.2 S, true
    J/S >= 0.3), against none with 100 periods or the budget. Subsampling
    more instead (60 samples per period) cost accuracy (median error of S
    15 %, DB 20 %). A dead time shorter than ``step * sample_time`` is still
    fitted (it is fractional).
    """
    h = float(sample_time)
    keep = SIZE_MAX_SAMPLES
    k = 1
    if math.isfinite(period) and period > 0 and h > 0:
        k = max(1, int(period / h // per_period))
        cycles = min(max_cycles, max(min_cycles, fit_samples * k * h / period))
        keep = min(keep, int(math.ceil(cycles * period / h)))
    a = max(0, n - keep)
    a += (n - 1 - a) % k          # the subsampled record ends at the last sample
    return a, k


def estimate_valve_size(pv, op, sample_time, fault, process_type="integrating", *, sp=None,
                        effects=SIZE_EFFECTS) -> dict:
    """Estimate the size of a valve fault by fitting the loop model.

    Parameters
    ----------
    pv : array_like, shape (n,)
        Process variable, uniformly sampled, NaN where missing [PV unit].
    op : array_like, shape (n,)
        Controller output [OP unit, usually %].
    sample_time : float
        [s]
    fault : {'stiction', 'backlash'}
        The scan's verdict (``'deadband'`` is taken as ``'backlash'``).
    process_type : {'integrating', 'self-regulating'}
        Plant type.
    sp : array_like, optional
        Set point [PV unit].
    effects : tuple of str
        Other effects fitted with the valve (default :data:`SIZE_EFFECTS`).

    Returns
    -------
    dict
        ``{"DB": ...}`` (backlash) or ``{"S": ..., "J": ...}`` (stiction) in
        OP units, plus ``fit_pct`` (held-out fit [%]), ``heldout_rmse`` [PV
        unit], ``confidence`` (0-1), ``model`` (the effects fitted) and
        ``reason``. When the record cannot be modelled the sizes are NaN,
        ``confidence`` is 0 and ``reason`` says why (no exception).

    Raises
    ------
    ValueError
        An unknown ``fault`` or ``process_type``.

    Notes
    -----
    The confidence multiplies two factors: how well the model predicts the
    held-out blocks (``fit_pct / 100``) and how much the valve fault itself
    improves the held-out error over the same model with a linear valve
    (full credit from a 30 % fall). A size at the edge of the searched range
    (larger than the OP swings) halves it, and so does a stick band fitted
    without a slip jump (``J < NO_JUMP S``: the record then shows a dead
    band, which the reason says); an OP stored compressed lowers it by a
    fifth. Sizes are in the unit of the OP (not clipped to 0-100 %). Cost: a
    few seconds for a day at 1 s.

    The fitted valve takes a fall of the OP within its noise band for noise,
    not a reversal (:attr:`LoopData.noise_band`), and a dead time is kept
    only where it lowers the held-out error (:func:`_parsimonious_fit`).
    A compressed OP (more than :data:`COMPRESSED_SHARE` of its samples on
    straight lines) is rebuilt between its stored points from the
    controller's law where that law explains at least
    :data:`~valvediag.workbench.data.REBUILD_R2` of its stored moves
    (:func:`~valvediag.workbench.data.rebuild_compressed_op`),
    with the noise band read from the stored points.

    A PV stored compressed (more than :data:`COMPRESSED_SHARE` of its
    samples on straight lines) is read back by straight lines between its
    stored points, and those lines cut every smooth turn of the PV short:
    behind a dead band the valve follows the OP through the turn, the PV
    turns along a curve, and the cut turn, scored as data, pulls the fitted
    valve's reversal early (taken up by a dead time the loop does not have:
    a band sized 20-30 % small). A dead band is therefore fitted to the
    stored samples only (``pv_points='stored'`` of
    :func:`~valvediag.workbench.data.prepare_loop`). A sticky valve's PV
    turns at kinks (the slip), which the compression stores, and the lines
    between them are close to the truth; scored on the stored samples alone
    the fit loses the straight runs that tell a slip from a smooth turn
    (measured: 8 of 216 sticky valves with J/S >= 0.3 then sized with
    J < 0.2 S, against none), so a stiction fit scores every sample.

    On the sizing benchmark (``benchmarks/bench_sizing.py``: integrating
    loops, S 1-6 %, J/S 0.1-1, DB 1-6 %, noise 0.5-3 %, 1-10 s) the median
    error of S, J and DB is 4.9, 14 and 3.5 % on records storing every sample,
    and 14, 51 and 19 % (S and DB too small, J too large) where PV and OP are stored by exception
    and swinging door (DB 23 % with the compressed PV's lines scored): the
    record's remaining timing errors are taken up by a fitted dead time,
    which trades off against the band along the OP's ramps. Relative errors
    of J are large where J is small (J/S = 0.1).

    References
    ----------
    .. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical
       model and detection algorithm for valve stiction. IFAC DYCOPS 7.
    .. [2] Hägglund, T. (2007). Automatic on-line estimation of backlash in
       control loops. Journal of Process Control 17, 489-499.
    """
    if fault not in _FAULTS:
        raise ValueError(f"fault must be 'stiction' or 'backlash', not {fault!r}")
    if process_type not in ("integrating", "self-regulating"):
        raise ValueError(f"process_type must be 'integrating' or 'self-regulating', not {process_type!r}")
    valve = _FAULTS[fault]
    keys = ("S", "J") if valve == "stiction" else ("DB",)
    out = {k: math.nan for k in keys}
    out.update(fit_pct=math.nan, heldout_rmse=math.nan, confidence=0.0,
               model="+".join((valve,) + tuple(effects)), reason="")
    try:
        data, interpolated, rebuilt_r2 = prepare_valve_record(pv, op, sample_time, valve, sp=sp)
    except WorkbenchDataError as exc:
        out["reason"] = str(exc)
        return out
    fit, effects = _parsimonious_fit(data, valve, tuple(effects), process_type)
    out["model"] = "+".join((valve,) + effects)
    lin = LoopModel(effects, process_type).fit(data)
    for k in keys:
        out[k] = float(fit.params[k])
    out["fit_pct"] = float(fit.fit_pct)
    out["heldout_rmse"] = float(fit.heldout_rmse)
    if "valve_model" in fit.derived:
        out["valve_model"] = fit.derived["valve_model"]
    if "dead_time" in fit.params:
        out["dead_time"] = float(fit.params["dead_time"])
    gain = 1.0 - fit.heldout_rmse / lin.heldout_rmse if lin.heldout_rmse > 0 else 0.0
    conf = float(np.clip(fit.fit_pct / 100.0, 0, 1) * np.clip(gain / 0.3, 0, 1))
    band = out[keys[0]]
    why = [f"held-out fit {fit.fit_pct:.0f} %",
           f"the {valve} lowers the held-out error by {100 * gain:.0f} % against a linear valve"]
    if band >= 0.97 * data.band_max:
        conf *= 0.5
        why.append("the size is at the edge of the range searched")
    if valve == "stiction" and not out["J"] >= NO_JUMP * out["S"]:
        conf *= 0.5
        why.append(f"no slip jump found (J = {out['J']:.2g}, under {NO_JUMP:.0%} of S): on this "
                   "record the valve moves as a dead band of width S would, which a stiction "
                   "verdict does not explain")
    if data.pv_scored is not None:
        why.append(f"the PV is stored compressed: only its {int(data.pv_scored.sum())} stored "
                   f"samples of {data.n} are scored, not the straight lines between them")
    if interpolated > COMPRESSED_SHARE:
        conf *= 0.8
        if rebuilt_r2 >= REBUILD_R2:
            why.append(f"the OP is stored compressed ({100 * interpolated:.0f} % of its samples "
                       f"interpolated) and was rebuilt between its stored points from the "
                       f"controller's law (which explains {100 * rebuilt_r2:.0f} % of its moves)")
        else:
            why.append(f"the OP is stored compressed ({100 * interpolated:.0f} % of its samples "
                       "interpolated): its reversals are cut, and the band may read small")
    out["confidence"] = round(conf, 2)
    out["reason"] = "; ".join(why)
    return out


def prepare_valve_record(pv, op, sample_time, valve: str, *, sp=None):
    """A historian record prepared for a valve model's fit.

    Parameters
    ----------
    pv, op : array_like, shape (n,)
        PV [PV unit] and OP [OP unit], NaN where missing.
    sample_time : float
        [s]
    valve : {'stiction', 'deadband'}
        The valve the record will be fitted with.
    sp : array_like, optional
        Set point [PV unit].

    Returns
    -------
    data : LoopData
    interpolated : float
        Share of the OP's samples on straight lines between stored points [-].
    rebuilt_r2 : float
        Share of the stored OP moves the controller's law explains, where the
        OP was compressed (NaN otherwise) [-].

    Raises
    ------
    WorkbenchDataError
        What :func:`~valvediag.workbench.data.prepare_loop` refuses.

    Notes
    -----
    An OP compressed on more than :data:`COMPRESSED_SHARE` of its samples is
    rebuilt between its stored points from the controller's law where that
    law explains at least :data:`~valvediag.workbench.data.REBUILD_R2` of its
    stored moves (a straight line between them cuts each reversal), with the
    noise band read from the stored points. A PV so compressed is scored on
    its stored samples only for a dead band (its lines cut a smooth turn
    short; see :func:`estimate_valve_size`), on every sample for a sticky valve (its
    kinks are stored).
    """
    interpolated = _interpolated_share(op)
    rebuilt_r2 = math.nan
    op_noise = None
    if interpolated > COMPRESSED_SHARE:
        # a compressed OP cuts its reversals: rebuild it from the controller's law
        # where that law explains the stored moves, keeping the noise of the stored
        # points (the rebuilt OP is smooth; the valve's noise band is read from it)
        rebuilt, rebuilt_r2 = rebuild_compressed_op(pv, op, sample_time, sp=sp)
        if rebuilt_r2 >= REBUILD_R2:
            op_noise = white_noise_std(op)
            op = rebuilt
    if valve == "deadband" and _interpolated_share(pv) > COMPRESSED_SHARE:
        try:
            return (prepare_loop(pv, op, sample_time, sp=sp, op_noise=op_noise,
                                 pv_points="stored"), interpolated, rebuilt_r2)
        except WorkbenchDataError:
            pass            # too few stored samples: every sample is scored
    return prepare_loop(pv, op, sample_time, sp=sp, op_noise=op_noise), interpolated, rebuilt_r2


def _parsimonious_fit(data, valve: str, effects: tuple, process_type: str):
    """Fit the valve with the required effects, then add each optional one
    (:data:`SIZE_OPTIONAL`) only where it lowers the held-out error by more
    than :data:`SIZE_OPTIONAL_GAIN`.

    In a steady limit cycle the OP ramps at a nearly constant rate, so a
    dead time ``theta`` shifts the valve's motion as a band wider by
    ``rate x theta`` would: the record fixes their sum, not each. A dead
    time that the data do not need then drifts along that valley and takes
    a share of the band (a sticky or loose valve sized 20-30 % small). The
    simpler model is kept unless the dead time pays for itself on the
    held-out blocks, where set-point steps, load changes or cycles of
    different rates tell the two apart.

    The model with the optional effect is fitted once, warm-started from the
    simpler fit (its grid also runs from the cold start). A second fit from
    the cold start alone, the better of the two kept, cost 28 % more
    time on the sizing benchmark (``benchmarks/bench_sizing.py``: 402 s of
    fitting against 314 s) for sizes about as good: median error of S, J
    and DB 10.9, 22.5 and 9.2 % with it, 10.2, 24.7 and 9.2 % without
    (records sampled at 10 s: S 17.0 against 19.1 %). The cold fit alone
    sized S worse (12.5 %; 11.2 against 5.9 % at 1 s).
    """
    opt = tuple(e for e in effects if e in SIZE_OPTIONAL)
    base = tuple(e for e in effects if e not in SIZE_OPTIONAL)
    fit = LoopModel((valve,) + base, process_type).fit(data)
    for e in opt:
        model = LoopModel((valve,) + base + (e,), process_type)
        # from the simpler fit: the search runs its grid's stages from there and
        # from the cold start (see :func:`valvediag.workbench.fit.search`)
        cand = model.fit(data, start=fit)
        if cand.heldout_rmse < (1.0 - SIZE_OPTIONAL_GAIN) * fit.heldout_rmse:
            fit, base = cand, base + (e,)
    return fit, tuple(x for x in effects if x in base)


def _interpolated_share(x) -> float:
    """Share of samples on a straight line between their neighbours (or held):
    what a historian's compression leaves, read back by interpolation [-]."""
    x = np.asarray(x, dtype=float)
    return 1.0 - stored_points(x).size / x.size if x.size >= 3 else 0.0
