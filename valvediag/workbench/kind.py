"""
Sticky or loose: the loop model's reading of a valve's kind, with the process lag fitted.

The Backlash Index of Farenzena & Trierweiler (2012) reads the valve's kind
from the shape of the PV's turns: a sticky valve slips and the level turns
sharply, a loose valve follows the OP once its dead band is taken up and the
level turns along a curve. A first-order lag between valve and PV (a slow
sensor or positioner, a mixing volume) rounds a slip's turn as well, and the
index then reads a sticky valve as loose. :func:`valve_kind` asks the loop
model instead: a Kano valve (stick band ``S``, slip jump ``J``) and a dead
band, each with a fitted lag and dead time, are fitted to the same record
and compared on its held-out blocks. The slip jump is the only difference
between the two (a Kano valve with ``J = 0`` is a dead band of width ``S``),
so a sticky valve that predicts the held-out PV better, by a margin the
segment-by-segment comparison calls real, has shown its slips.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..plain import finite_or_none
from .data import WorkbenchDataError
from .model import LoopModel, ModelFit
from .size import NO_JUMP, prepare_valve_record, size_window
from .suggest import RIVAL_T, compare_heldout

__all__ = ["ValveKind", "valve_kind", "kind_window", "KIND_EFFECTS", "KIND_MAX_SAMPLES",
           "KIND_STEPS_PER_LAG"]

#: Effects fitted with either valve: the lag whose rounding the Backlash
#: Index mistakes for a dead band, and a dead time.
KIND_EFFECTS = ("lag", "dead_time")
#: Most samples fitted [-].
KIND_MAX_SAMPLES = 21_600
#: Periods fitted (the latest of the record): the size fit's most, without
#: its sample budget (:data:`~valvediag.workbench.size.SIZE_FIT_SAMPLES`) [-].
KIND_MAX_CYCLES = 100.0
#: A record is subsampled no coarser than this many steps per lag: a slip
#: behind the lag must span samples for the fit to see its shape [-].
KIND_STEPS_PER_LAG = 8.0


def kind_window(n: int, sample_time: float, *, period: float = math.nan,
                lag: float = math.nan) -> tuple[int, int]:
    """The part of a record that :func:`valve_kind` reads: its latest samples, subsampled.

    Parameters
    ----------
    n : int
        Samples in the record.
    sample_time : float
        [s]
    period : float, optional
        Oscillation period [s].
    lag : float, optional
        The lag behind the valve, as the Backlash Index's turns read it [s].

    Returns
    -------
    start, step : int
        Fit ``x[start::step]``; the subsampled record ends at the last sample.

    Notes
    -----
    The window of a size fit (:func:`~valvediag.workbench.size_window`: the
    latest :data:`KIND_MAX_CYCLES` periods, 120 samples per period, without
    the size fit's sample budget), with the step no coarser
    than ``lag / KIND_STEPS_PER_LAG`` (a slip behind a lag of 2 % of the
    period spans two or three samples at 120 per period, and the comparison
    loses it: measured on a level of 300 s with a 20 s lag, six standard
    errors at 1 s and 2 s, one at 4 s and 7 s), and no finer than keeps
    the span within :data:`KIND_MAX_SAMPLES` fitted samples. The many cycles
    matter as much as the step: on a sawtooth cycle of 22 minutes the fit
    found the slip in 24 hours at every step from 2 s to 10 s, and not
    always in 6 or 12 hours, so a long span is thinned, not cut.
    """
    h = float(sample_time)
    a, k = size_window(n, h, period, max_cycles=KIND_MAX_CYCLES,
                       min_cycles=KIND_MAX_CYCLES)
    if math.isfinite(lag) and lag > 0:
        k = max(1, min(k, int(lag / (KIND_STEPS_PER_LAG * h))))
    # the size fit's span kept whole, at a coarser step if it holds too many samples
    k = max(k, math.ceil((n - a) / KIND_MAX_SAMPLES))
    a += (n - 1 - a) % k
    return a, k


@dataclass(frozen=True)
class ValveKind:
    """A sticky and a loose valve fitted to one record, and which explains it.

    Attributes
    ----------
    kind : str
        ``'stiction'`` (the slip jump is real: the sticky valve predicts the
        held-out segments better by at least ``RIVAL_T`` standard errors,
        and ``J >= NO_JUMP S``), ``'backlash'`` (a dead band explains the
        record as well) or ``''`` when the record cannot be modelled.
    reason : str
        One sentence with the figures.
    S, J, DB : float
        Stick band and slip jump of the sticky valve, width of the dead band
        [OP unit].
    lag_stiction, lag_deadband : float
        Lag fitted with each valve [s].
    gain : float
        Share of the dead band's held-out RMSE that the sticky valve removes [-].
    t : float
        Mean paired difference of their held-out segments' squared errors in
        standard errors, positive where the sticky valve is better [-].
    segments : int
        Held-out segments compared.
    sample_time : float
        Of the record fitted [s]: the lags are resolved to about this.
    stiction_fit, deadband_fit : ModelFit or None
        The two fits (None when the record cannot be modelled).
    """

    kind: str
    reason: str
    S: float = math.nan
    J: float = math.nan
    DB: float = math.nan
    lag_stiction: float = math.nan
    lag_deadband: float = math.nan
    gain: float = math.nan
    t: float = math.nan
    segments: int = 0
    sample_time: float = math.nan
    stiction_fit: ModelFit | None = field(default=None, repr=False)
    deadband_fit: ModelFit | None = field(default=None, repr=False)

    def as_dict(self) -> dict:
        """The figures as plain types (NaN as None)."""
        def num(x):
            return finite_or_none(x, 4)

        return {"kind": self.kind, "S": num(self.S), "J": num(self.J), "DB": num(self.DB),
                "lag_stiction_s": num(self.lag_stiction),
                "lag_deadband_s": num(self.lag_deadband), "gain": num(self.gain),
                "t": num(self.t), "segments": int(self.segments),
                "sample_time_s": num(self.sample_time), "reason": self.reason}

    def plot(self, ax=None):
        """The measured PV with the sticky valve's model, the dead band's drawn for comparison.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(9, 3.5))
        if self.stiction_fit is None:
            ax.text(0.5, 0.5, self.reason, ha="center", va="center", transform=ax.transAxes)
            return ax
        return self.stiction_fit.plot(ax, other=self.deadband_fit)


def valve_kind(pv, op, sample_time, *, process_type: str = "integrating", sp=None
               ) -> ValveKind:
    """Fit a sticky and a loose valve, each behind a fitted lag, and say which the record shows.

    Parameters
    ----------
    pv, op : array_like, shape (n,)
        PV [PV unit] and OP [OP unit, usually %], uniformly sampled, NaN
        where missing (one episode of a limit cycle; :func:`kind_window`
        chooses the part of a long record to read).
    sample_time : float
        [s]
    process_type : {'integrating', 'self-regulating'}
    sp : array_like, optional
        Set point [PV unit].

    Returns
    -------
    ValveKind
        Never raises on data the workbench refuses: ``kind`` is then ``''``
        and ``reason`` says why.

    Notes
    -----
    Both valves are fitted with :data:`KIND_EFFECTS` (and the operating
    point) to the same prepared record (every PV sample scored, the OP
    rebuilt where it is compressed:
    :func:`~valvediag.workbench.size.prepare_valve_record`), the sticky one
    from its own start and from the dead band's fit with no, half and a full
    jump (the best on the training blocks: the search may stay at a jump of
    zero or of S), and the two are compared by
    :func:`~valvediag.workbench.suggest.compare_heldout`. The thresholds are
    the workbench's own (``RIVAL_T`` for a real held-out difference, the
    sizing's ``NO_JUMP`` for a slip jump worth the name), not set for this
    test. No share of the held-out error is asked for: near the noise floor
    a real slip lowers the error by a few percent (a Kano valve with J = S
    behind a 20 s lag on a level of 300 s, PV noise 1 % of its swing: 4 %,
    six standard errors), so the paired comparison decides.

    It assumes one valve, a process of the given type, and a lag the model
    can fit (first order, up to the workbench's bounds). It fails where a
    loose valve's curved turn is fitted better by a jump behind a long lag
    (6 of the 100 loose level valves of the realistic benchmark's seeds
    10-19 whose turns read as a slip behind a lag: a dead band read as
    stiction, which the scan's check of the two lags turns back,
    :func:`valvediag.scan.loop.lags_agree`), where a sticky valve's
    jump is small against the noise (J/S under about 0.3: read as a dead
    band, which it nearly is), and on a PV stored so coarsely that the slip
    is a ramp between stored points. It is a check of a Backlash Index
    reading that the lag puts in doubt, not a detector: run it on records
    that already show a valve nonlinearity. Cost: five fits, about half a
    second each on 10,800 samples.

    References
    ----------
    .. [1] Farenzena, M., Trierweiler, J. O. (2012). Valve backlash and
       stiction detection in integrating processes. ADCHEM 2012, 320-325.
    .. [2] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical
       model and detection algorithm for valve stiction. IFAC DYCOPS 7.
    """
    if process_type not in ("integrating", "self-regulating"):
        raise ValueError(f"process_type must be 'integrating' or 'self-regulating', "
                         f"not {process_type!r}")
    try:
        data, _, _ = prepare_valve_record(pv, op, sample_time, "stiction", sp=sp)
    except WorkbenchDataError as exc:
        return ValveKind(kind="", reason=str(exc))
    db = LoopModel(("deadband",) + KIND_EFFECTS, process_type).fit(data)
    # the sticky valve from its own grid and from the dead band (S = DB, J = 0),
    # the better on the training blocks: it nests the dead band, and a search
    # that lands in a worse optimum must not count against the slip
    model = LoopModel(("stiction",) + KIND_EFFECTS, process_type)
    th = db.theta
    starts = [None, th.replace(S=th.DB, J=0.0), th.replace(S=th.DB, J=th.DB),
              th.replace(S=th.DB, J=0.5 * th.DB)]
    st = min((model.fit(data, start=s0) for s0 in starts), key=lambda f: f.train_rmse)
    cmp = compare_heldout(st, db, ("stiction", "deadband"))
    t = cmp.t if cmp.effects[0] == "stiction" else -cmp.t
    gain = 1.0 - st.heldout_rmse / db.heldout_rmse if db.heldout_rmse > 0 else 0.0
    S, J = float(st.params["S"]), float(st.params["J"])
    slips = t >= RIVAL_T and J >= NO_JUMP * S
    figures = (f"a sticky valve (S {S:.3g}, J {J:.3g}, lag {st.params['lag']:.3g} s) removes "
               f"{100 * gain:.0f} % of a dead band's held-out error (DB {db.params['DB']:.3g}, "
               f"lag {db.params['lag']:.3g} s), {t:.1f} standard errors over {cmp.segments} "
               "held-out segments")
    if slips:
        reason = f"{figures}: the valve slips"
    else:
        need = f"need {RIVAL_T:g} standard errors and J at least {100 * NO_JUMP:.0f} % of S"
        reason = f"{figures} ({need}): a dead band explains the record as well"
    return ValveKind(kind="stiction" if slips else "backlash", reason=reason, S=S, J=J,
                     DB=float(db.params["DB"]), lag_stiction=float(st.params["lag"]),
                     lag_deadband=float(db.params["lag"]), gain=float(gain), t=float(t),
                     segments=int(cmp.segments), sample_time=float(sample_time),
                     stiction_fit=st, deadband_fit=db)
