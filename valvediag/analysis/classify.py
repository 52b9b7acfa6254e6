"""
One-loop classifier: what, if anything, is wrong with this loop's valve?

:func:`classify_loop` adds to the Backlash Index what Farenzena & Trierweiler
(2012) assume away. A loop gets the first verdict that applies:

1. ``insufficient-data``: too little usable data (gaps, a frozen PV, too few
   cycles, too few samples per cycle); the reason says which.
2. ``no-oscillation``: no regular oscillation, and no valve events
   (:func:`valvediag.analysis.signature.stick_slip_events`: a sticky valve
   without a limit cycle gets ``stiction`` from its slips, a loose one
   ``backlash`` from its dead-band take-ups; the events are also read on a
   self-regulating loop whose cycle the valve signature cannot explain). A
   record of unknown process type is read as a flow: a level's kinks are
   read alone only where the registry calls the process integrating (or
   the OP's answer to the set-point steps does), for a healthy flow's
   answers to its load's steps kink its record as a sticky level valve's
   slips do. Where that answer names no type but shows no lasting shift
   of the OP within two standard errors, the record is read as a level
   too, and its kinks count only where the set-point steps, read as a
   level's bump tests, check them (a tight flow's shift, a third of its
   kick, stands many standard errors above nought).
3. ``linear-oscillation``: a regular oscillation that no valve nonlinearity
   explains (tuning or an external disturbance); send no one to the valve.
   A swing that keeps a clock's time, read before any valve method
   (:func:`~valvediag.analysis.oscillation.phase_wander`: a valve's limit
   cycle is the loop's own, and its phase wanders with the noise; a load
   driven from outside keeps its phase; on a self-regulating process with
   too few cycles for the wander, periods that vary no more than the PV's
   noise and the time grid make a steady clock's read,
   :attr:`~valvediag.analysis.oscillation.PhaseWander.steady_periods`), a
   sinusoidal PV, an OP that stands
   still, a valve position implied by
   the PV that follows the OP (:func:`follows_op`), or cycles whose
   amplitude wanders as a noise-driven resonance's does
   (:attr:`~valvediag.analysis.oscillation.Oscillation.amplitude_variation`:
   a valve's limit cycle keeps its amplitude) says so; on a self-regulating
   process the wandering cycle is still a sticky or loose valve's where its
   valve events make it up, at least one event per two cycles
   (:data:`RESONANCE_SLIPS`: a sticky valve slipping every few minutes
   behind slow integral action makes an irregular cycle of its slips, where
   a ringing loop's thousands of turns pass for a slip a few times a day).
   On a process the registry calls integrating, a level that does not ramp
   from turn to turn says so too (its ramps between turns cover less than
   :data:`RAMP_SHARE_MIN` of its swing: it holds still for much of each
   cycle, where its valve passes the load's flow, as after a pump's step or
   while the OP follows a ramping inflow). A valve at rest, stuck or inside
   its dead band, passes a flow that is not the load's, so its limit cycle
   ramps the level between its turns (the sticky, sawtooth and loose level
   cycles of the realistic benchmark's study and development seeds ramp over
   0.93 of their swing or more). Healthy levels under slow loads of 30-120
   minutes' period, with too few cycles for their clock to be read, turned
   sharply or lagged and read ``stiction`` before. A level that runs in
   arcs between its turns (their curvature :data:`RAMP_ARC_MIN` of its
   swing or more, where all but one of those cycles curve by 0.012 at
   most) has a flow that
   changes all along each ramp, not a valve at rest: a slow level under a
   square or clipped load, whose turns are sharp where the load steps. On
   any process, a loop
   that rests at its set point with its OP still for
   :data:`REST_SHARE_MIN` of its mean cycle or more says so as well
   (:func:`~valvediag.analysis.linearity.rest_share`: a valve's limit cycle
   never rests at the set point, a loop that settles after each move of its
   load does). On a self-regulating process, a sinusoidal PV says so, and so
   does a loop whose fast motion leads away from its set point for
   :data:`AWAY_SHARE_MIN` of it or more
   (:func:`~valvediag.analysis.linearity.away_share`: a sticky valve's slip
   is the controller's correction arriving at once and moves the PV towards
   its set point fastest; a load's step pushes it away), and so does a PV
   whose swings gather speed as gradually as they lose it, their speed over
   a sixth of a period before their fastest point :data:`ONSET_SMOOTH` of
   that after it or more (:func:`~valvediag.analysis.linearity.move_onset`:
   a slip steps the valve and the process answers at once; a load that
   turns without a step, a triangle or a clipped sine, moves the PV through
   the process's lag).
4. ``stiction``, ``backlash`` or ``undecided``. On an integrating process the
   Backlash Index decides, as the paper does, and the valve signature
   (:func:`valvediag.analysis.signature.valve_signature`) settles a BI
   between its limits (its sharp turns give way only where the ramps are
   curved and a linear valve explains the valve position the PV's slope
   implies: a load's turns, stored by swinging door, meet at sharp corners
   too); rounded turns that come after the OP's reversals are a slip behind
   a lag, not a dead band (:func:`valvediag.analysis.turn_timing.turn_timing`).
   On a self-regulating process (a flow, pressure, temperature), where the
   BI does not apply, the valve signature decides.

Where the valve's position is recorded (``mv``), it is read against the OP
directly (:func:`valvediag.analysis.travel.valve_travel`), with no process
between the two: a position that follows the OP clears the valve whatever
the PV looks like, and a sticky or loose valve read from the position is
named on any loop. On an integrating loop the Backlash Index still names the
kind where it reads one, but a position that shows the valve slip names
stiction (a dead band never jumps, and the index reads a slip behind a lag as
a rounded turn); a position without jumps does not overrule the index's
stiction (a small slip hides in the position's noise), and is said.

Every verdict carries a confidence in [0, 1] and its evidence.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .bi import THRESHOLDS, BacklashIndex, backlash_index, lagged_turns
from .bumps import (SLIP_OVER_FOLLOWING, SetPointBumps, kinks_over_following, setpoint_bumps,
                    setpoint_process_screen)
from .linearity import (CycleShape, away_share, cycle_shape, mean_cycles, move_onset,
                        rest_share)
from .oscillation import (Oscillation, PhaseWander, detect_oscillation, phase_wander,
                          turned_cycles)
from .quality import (bridge_short_gaps, despike, drawn_lines, longest_run, record_quantum,
                      stored_points, white_noise_std)
from .reversals import ReversalRests, reversal_rests
from .setpoint import infer_setpoint
from .signature import (KIND_SHARE, MIN_SLIPS, SENSE_SKEW, ValveSignature,
                        controller_lag, cycle_transitions, horch_correlation,
                        stick_slip_events, valve_signature)
from .travel import ValveTravel, valve_travel
from .trend import pv_op_trend
from .turn_timing import POOLED_SHARE, SLIP_SHARE, turn_timing

__all__ = ["classify_loop", "LoopDiagnosis", "integrating_screen"]

PROCESS_TYPES = ("integrating", "self-regulating", "unknown")

MIN_SAMPLES = 32
MIN_SAMPLES_PER_PERIOD = 8.0
#: Steps of the PV's stored resolution (:func:`record_quantum`) across a
#: cycle's swing (peak to peak) below which a valve verdict read from its
#: waveform is given with a caveat: about a tenth of a period either side
#: of an apex, where the Backlash Index reads the turn, a triangle drops by
#: two fifths of its swing, four steps at ten a swing ...
MIN_QUANTA_PER_SWING = 10.0
#: ... and its confidence is scaled by this.
COARSE_CONFIDENCE = 0.5
#: Below this harmonic distortion of the mean PV cycle the oscillation is
#: sinusoidal: a linear loop (calibrated on benchmarks/bench_bi_sweep.py).
DIST_LINEAR = 0.03
#: Straight ramps (see :func:`integrating_screen`): curvature below and ramp
#: share above these mean an integrating process.
RAMP_CURVATURE_MAX = 0.011
RAMP_SHARE_MIN = 0.6
#: A level whose ramps between turns curve by at least this much (the
#: :func:`integrating_screen`'s curvature; a sine's reads about 0.012) has a
#: valve that is not at rest between its turns: it swings with its load.
RAMP_ARC_MIN = 0.02
#: A loop that rests at its set point with its OP still for at least this
#: share of its mean cycle swings with its load (:func:`rest_share`).
REST_SHARE_MIN = 0.1
#: A self-regulating loop whose fast motion leads away from its set point for
#: at least this share (:func:`~valvediag.analysis.linearity.away_share`) is
#: pushed off it by its load: a sticky valve's slips move it back (the
#: benchmark's sticky flow and temperature cycles read at most 0.42, one
#: biased to one side of its set point 0.50; most square loads 0.6-0.85).
#: Sinusoidal loads, at 0.5, are told by their harmonics (:data:`DIST_LINEAR`).
AWAY_SHARE_MIN = 0.55
#: A self-regulating PV whose swings run, over the sixth of a period before
#: their fastest point, at least this share of their speed over the sixth
#: after it (:func:`~valvediag.analysis.linearity.move_onset`) starts them
#: gradually, as a load that turns without a step moves it: a slip starts the
#: PV at once (the benchmark's sticky flow and temperature cycles read at
#: most 0.44 as the classifier reads them; the triangular and clipped loads
#: on its temperature loops that reach the reading 0.73 and more, square
#: loads 0.30-0.53).
ONSET_SMOOTH = 0.7
#: A valve "follows the OP" when a linear valve explains at least this share of
#: the held-out variance of the valve position the PV implies ...
FOLLOWS_R2 = 0.9
#: ... and the best sticky or loose valve removes less than this share of the rest ...
FOLLOWS_GAIN = 0.35
#: ... in a record that resolves the valve's motion: at least this many
#: slope windows per oscillation period.
FOLLOWS_RESOLUTION = 6.0


#: An oscillation whose half-cycle swings vary by this share of their mean
#: or more (:attr:`Oscillation.amplitude_variation`) is a linear loop's
#: noise-driven resonance, not a valve's limit cycle.
RESONANCE_VARIATION = 0.3
#: ... unless, on a self-regulating process, valve events make up the cycle:
#: at least this many slips or take-ups per cycle (a sticky valve slips once
#: or twice a cycle; a ringing loop's turns pass for one now and then).
RESONANCE_SLIPS = 0.5
#: A Backlash Index reading of rounded turns may be a lag's, not the valve's,
#: when the turns fitted behind a first-order lag read at most this BI ...
LAG_SHARP_BI = 1.5
#: ... with a lag of at most this share of the period; the confidence of a
#: backlash or undecided verdict is then multiplied by ``LAG_DOUBT``.
LAG_MAX_SHARE = 0.05
LAG_DOUBT = 0.6


def sharp_behind_lag(turns) -> bool:
    """Could a record's rounded turns be a sharp valve turn behind a short lag?

    Parameters
    ----------
    turns : valvediag.analysis.bi.LaggedTurns or None

    Returns
    -------
    bool
        True when the turn fitted behind a first-order lag is sharp (its
        Backlash Index at most ``LAG_SHARP_BI``, the paper's own stiction
        limit, or the turn no longer than one sample of the record) and the
        lag is at most ``LAG_MAX_SHARE`` of the period.

    Notes
    -----
    A lag rounds a sticky valve's turns as a dead band does (a lag of 2 % of
    the period lifts the BI of a J/S 0.8 valve from 1.0 to 3.7), but the
    shapes of the two are too alike to tell apart from the PV alone (see
    :func:`~valvediag.analysis.bi.lagged_turns`): this is a doubt on a
    backlash verdict, not a stiction verdict.

    A record cannot show a turn shorter than its sample, and below 75
    samples a period a sample is longer than the limit's turn (0.013
    periods): a sticky level cycle at 23 samples a period (sampled every
    10 s, behind a 7 s lag) read a turn of 0.016 periods, 0.4 of a sample,
    whose Backlash Index (1.68) is above the limit. A turn that takes no
    longer than a sample is sharp as far as the record can show. On the
    realistic benchmark's level classes (study seeds 10-16, 4 loops a
    class; development seeds 1-2, 20 a class) and its level cycle classes
    (study seeds 17-26, 4 a class), this put two sticky valves' backlash
    readings in doubt (a sawtooth sampled every 10 s then read stiction by
    the loop model) and no loose valve's.
    """
    if turns is None or not turns.lag <= LAG_MAX_SHARE * turns.period:
        return False
    return bool(turns.bi <= LAG_SHARP_BI or turns.duration * turns.period <= turns.sample_time)


def follows_op(sig: ValveSignature, period: float) -> bool:
    """Does the valve position implied by the PV follow the OP linearly?

    Parameters
    ----------
    sig : ValveSignature
    period : float
        Oscillation period [s].

    Returns
    -------
    bool
        True when a linear valve explains at least ``FOLLOWS_R2`` of the
        held-out variance of the implied valve position, the best sticky or
        loose valve removes less than ``FOLLOWS_GAIN`` of what is left, and
        the record resolves the valve's motion (the slope is read over at
        most a sixth of the period): whatever the shape of the PV, the valve
        is not what makes it.

    Notes
    -----
    At 20 samples per period (the paper's experiment) the PV slope is read
    over a fifth of the period, a sticky valve's jump is smeared and a
    linear valve with a lag explains the slope almost as well: there the
    Backlash Index is the better evidence and this test abstains. With the
    limit at a sixth of the period rather than a tenth, the Backlash Index
    sweep (``benchmarks/bench_bi_sweep.py``, seeds 0 and 101) reads every
    cell the same, and a level loop under a triangular load at 27 samples
    per period is not called loose.
    """
    resolved = (np.isfinite(period) and sig.window > 0
                and period / sig.sample_time >= FOLLOWS_RESOLUTION * 2 * sig.window)
    return bool(resolved and sig.verdict == "linear" and sig.r2_linear >= FOLLOWS_R2
                and sig.gain < FOLLOWS_GAIN)


#: OP travel [OP unit] that a PV must answer before its silence is a dead response.
DEAD_OP_RANGE = 10.0


def dead_response(pv, op, sp=None) -> str:
    """A PV that does not answer its loop: the reason, or ``''``.

    Parameters
    ----------
    pv, op : numpy.ndarray
        One gap-free stretch [PV unit, OP unit].
    sp : numpy.ndarray, optional
        Set point over the same samples [PV unit].

    Returns
    -------
    str
        One sentence when the OP travels at least ``DEAD_OP_RANGE`` (1-99 %
        range) and the PV stays put: it never changes, or the set point
        moves by more than five times the PV's noise while the PV moves by
        less than a fifth of that. Empty otherwise.

    Notes
    -----
    The data alone cannot tell a valve stuck shut from a closed block valve,
    a dead transmitter or a loop whose OP is not wired to this valve; the
    sentence says so, as an action item with its evidence, rather than a
    valve verdict read from a shape. A good loop holding its PV at a fixed
    set point against a changing load also moves its OP while the PV stays
    put, so without set-point moves only a PV that never changes at all
    counts.
    """
    lo, hi = np.percentile(op, [1, 99])
    op_range = float(hi - lo)
    if op_range < DEAD_OP_RANGE:
        return ""
    where = ("a valve stuck shut, a closed block or bypass valve, a dead transmitter or an OP "
             "wired elsewhere; the data cannot tell which: check on site")
    if np.ptp(pv) == 0:
        return (f"the PV does not change while the OP travels over {op_range:.3g} %: {where}")
    if sp is None or not np.all(np.isfinite(sp)):
        return ""
    sp_range = float(np.subtract(*np.percentile(sp, [99, 1])))
    pv_range = float(np.subtract(*np.percentile(pv, [99, 1])))
    noise = white_noise_std(pv)
    if sp_range > 5.0 * noise and sp_range > 0 and pv_range < 0.2 * sp_range:
        return (f"the PV does not answer: the set point moves over {sp_range:.3g} and the OP "
                f"over {op_range:.3g} %, the PV over only {pv_range:.3g}: {where}")
    return ""


def _self_regulating_verdict(verdict, x, u, h, osc, src, c_data, ev, **kw):
    """Verdict on an oscillating self-regulating loop, from the valve signature."""
    sig = valve_signature(x, u, h, process="self-regulating", period=osc.period)
    horch = horch_correlation(x, u, h, osc.period)
    ev.update(signature=sig.as_dict(), horch_ratio=horch)
    where = f"on a self-regulating process ({src})"
    if sig.nonlinear:
        conf = c_data * (0.5 + 0.45 * min(1.0, sig.gain))
        kind, reason = sig.verdict, f"{sig.reason}, {where}; method: valve signature"
        if kind != "stiction":
            # the kind the signature leaves open (or reads as a dead band) from
            # what the OP did at each half-cycle's fastest PV move
            slips, takeups = cycle_transitions(x, u, h, osc.period, osc.apex_idx,
                                               sig.noise_band)
            ev["cycle_transitions"] = {"slips": slips, "takeups": takeups}
            if slips >= 3 and slips >= KIND_SHARE * (slips + takeups):
                kind = "stiction"
                reason += (f"; at {slips} of {slips + takeups} half-cycles the PV's fastest "
                           "move came while the OP stood or turned back: the valve jumped "
                           "(method: valve signature and the cycle's slips)")
        if kind == "undecided":
            conf *= 0.6
        return verdict(kind, conf, reason, **kw)
    if sig.verdict == "linear":
        return verdict("linear-oscillation", c_data * (0.5 + 0.4 * max(0.0, sig.r2_linear)),
                       f"an oscillation {where} that no valve nonlinearity explains: "
                       f"{sig.reason}; review the tuning or trace an external disturbance", **kw)
    if sig.verdict == "no-response":
        return verdict("linear-oscillation", 0.5 * c_data,
                       f"the PV oscillates {where} but does not answer the OP ({sig.reason}): "
                       "the oscillation comes from outside the loop", **kw)
    return verdict("insufficient-data", 0.6,
                   f"oscillates with a period of {osc.period:.4g} s {where}, but the valve's "
                   f"signature cannot be read: {sig.reason}", **kw)


@dataclass(frozen=True)
class LoopDiagnosis:
    """Verdict on one loop, with its evidence.

    Attributes
    ----------
    verdict : str
        One of :data:`VERDICTS`.
    confidence : float
        Confidence in the verdict, 0-1.
    reason : str
        One sentence explaining the verdict.
    process_type : str
        As given by the caller (metadata).
    process_screen : str
        ``'metadata'`` when the type came from the caller, else the data
        test's result: ``'integrating'``, ``'self-regulating'`` or
        ``'unknown'``.
    bi : float
        Backlash Index, NaN when not computed.
    period : float
        Oscillation period [s], NaN when none.
    amplitude : float
        Half peak-to-peak oscillation amplitude [PV unit].
    cycles : float
        Complete cycles seen.
    regularity : float
        Thornhill regularity of the cycle durations.
    evidence : dict
        Every figure behind the verdict (JSON-serialisable). ``from_events``
        is true where the verdict was read from the valve's events over the
        whole stretch (a flow's slips or take-ups, a level's kinks, its
        set-point steps, rests at the OP's reversals) rather than from a cycle.
    oscillation, backlash, shape : optional
        The intermediate results, for plots.
    travel : valvediag.analysis.travel.ValveTravel or None
        What the recorded valve position showed, where one was given.
    clock : valvediag.analysis.oscillation.PhaseWander or None
        The swing's timing, wherever it was read (it decided the verdict
        where it kept a clock's time).
    events : tuple of valvediag.analysis.signature.StickSlipEvents
        The valve events read in the stretch, one reading per process type
        tried, whether or not they made a fault (a level's kinks that a
        following valve explains are left out): a record cut by gaps pools
        them (:func:`~valvediag.analysis.signature.pooled_stick_slip_events`).
    rests : valvediag.analysis.reversals.ReversalRests or None
        The valve's rests at the OP's reversals, wherever they were read,
        fault or not: a record cut by gaps pools them
        (:func:`~valvediag.analysis.reversals.pooled_reversal_rests`).
    followed : tuple of valvediag.analysis.signature.StickSlipEvents
        A level's kinks that the set-point steps' gain explained as a
        following valve's (:func:`~valvediag.analysis.bumps.kinks_over_following`),
        left out of ``events``.
    bumps : valvediag.analysis.bumps.SetPointBumps or None
        The level's set-point steps read as bump tests, where read. A record
        cut by gaps counts the steps its level went against over all its
        stretches: where they make a fault, the gain its steps read is a
        slipping valve's, and the kinks in ``followed`` are pooled too.
    pv, op : numpy.ndarray
        The analysed stretch of data.
    sample_time : float
        [s]
    """

    verdict: str
    confidence: float
    reason: str
    process_type: str
    process_screen: str
    bi: float
    period: float
    amplitude: float
    cycles: float
    regularity: float
    evidence: dict
    oscillation: Oscillation | None = field(default=None, repr=False)
    backlash: BacklashIndex | None = field(default=None, repr=False)
    shape: CycleShape | None = field(default=None, repr=False)
    travel: ValveTravel | None = field(default=None, repr=False)
    clock: PhaseWander | None = field(default=None, repr=False)
    events: tuple = field(default=(), repr=False)
    rests: ReversalRests | None = field(default=None, repr=False)
    followed: tuple = field(default=(), repr=False)
    bumps: SetPointBumps | None = field(default=None, repr=False)
    pv: np.ndarray = field(default=None, repr=False)
    op: np.ndarray = field(default=None, repr=False)
    sample_time: float = 1.0

    def to_dict(self) -> dict:
        """The verdict and its evidence as plain JSON types."""
        def clean(v):
            if isinstance(v, (float, np.floating)):
                return None if not np.isfinite(v) else round(float(v), 6)
            if isinstance(v, (np.integer,)):
                return int(v)
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            return v
        return clean({"verdict": self.verdict, "confidence": self.confidence, "reason": self.reason,
                      "process_type": self.process_type, "process_screen": self.process_screen,
                      "bi": self.bi, "period_s": self.period, "amplitude": self.amplitude,
                      "cycles": self.cycles, "regularity": self.regularity,
                      "evidence": self.evidence})

    def plot(self, ax=None):
        """Trend of PV (and OP on a twin axis) with the apices marked.

        Returns
        -------
        matplotlib.axes.Axes
        """
        ax, t = pv_op_trend(ax, self.pv, self.op, self.sample_time, self.reason, pv_width=0.8)
        if t is None:
            return ax
        if self.oscillation is not None and self.oscillation.apex_idx.size:
            ai, sg = self.oscillation.apex_idx, self.oscillation.apex_sign
            ax.plot(t[ai[sg > 0]], self.pv[ai[sg > 0]], "v", color="C3", ms=4)
            ax.plot(t[ai[sg < 0]], self.pv[ai[sg < 0]], "^", color="C2", ms=4)
        ax.set_title(f"{self.verdict} (confidence {self.confidence:.2f})")
        return ax


def _longer_ramp(C):
    """(curvature, share) of the straight line through the longer half of the
    mean of the cycles ``C`` (rows), or None: see :func:`integrating_screen`."""
    if C.shape[0] < 2:
        return None
    m = C.mean(axis=0)
    span = m.max() - m.min()
    p = int(np.argmax(m))
    a, b = max(((0, p), (p, m.size - 1)), key=lambda ab: ab[1] - ab[0])
    L = b - a
    if L < 8 or span <= 0:
        return None
    x = np.arange(a + int(0.2 * L), a + int(np.ceil(0.8 * L)) + 1)
    coef = np.polyfit(x, m[x], 1)
    return (float(np.sqrt(np.mean((m[x] - np.polyval(coef, x)) ** 2)) / span),
            float(abs(coef[0]) * L / span))


def integrating_screen(pv_detrended, apex_idx, apex_sign, pv_distortion):
    """Data test for an integrating process, from the shape of the mean cycle.

    An integrating process integrates the valve position: a valve that
    sticks, or rests in a dead band, holds still while the controller winds
    up, and the PV runs in *straight ramps*. A self-regulating process settles
    towards each new valve position: its PV curves (a first-order approach),
    or, when it is fast, steps and then stays flat.

    The test looks at the longer half of the mean cycle (valley to peak or
    peak to valley) and fits a straight line to its central 60 %; both
    figures are the means over the mean cycle cut from valley to valley and
    the one cut from peak to peak, so that a PV and its mirror image (a
    reverse-acting loop) screen alike:

    * ``ramp_curvature``: residual RMS of that line over the cycle's
      peak-to-peak range; below 0.011 the ramp is straight;
    * ``ramp_share``: the line's rise over that half-cycle divided by the
      peak-to-peak range; about 1 for a ramp, small for a flat plateau.

    Parameters
    ----------
    pv_detrended : array_like
        PV without drift [PV unit].
    apex_idx, apex_sign : array_like
        PV apices.
    pv_distortion : float
        Harmonic distortion of the mean cycle (:func:`cycle_shape`): below
        ``DIST_LINEAR`` the oscillation is sinusoidal and says nothing about
        the process.

    Returns
    -------
    screen : str
        ``'integrating'``, ``'self-regulating'`` or ``'unknown'``.
    evidence : dict
        ``ramp_curvature`` and ``ramp_share``.

    Notes
    -----
    Calibrated on simulations: integrating loops with stiction or backlash
    from the paper's parameter ranges stay below a curvature of 0.009 up to
    5 % noise with a ramp share above 0.9; self-regulating sticky loops
    (time constant 3-100 s, a few hundredths to several periods) either curve
    (curvature above 0.013) or plateau (ramp share below 0.5). A sinusoidal
    oscillation gives a curvature of about 0.012 on any process, so a linear
    oscillation leaves the process type ``'unknown'``.
    """
    ev = {"ramp_curvature": np.nan, "ramp_share": np.nan}
    # the means over both cuts (see turned_cycles)
    fits = [f for f in (_longer_ramp(mean_cycles([pv_detrended], apex_idx, apex_sign, 128)[0]),
                        _longer_ramp(turned_cycles(pv_detrended, apex_idx, apex_sign, 128)))
            if f is not None]
    if not fits:
        return "unknown", ev
    curv, share = (float(np.mean(v)) for v in zip(*fits))
    ev.update(ramp_curvature=curv, ramp_share=share)
    if curv < RAMP_CURVATURE_MAX and share > RAMP_SHARE_MIN:
        return "integrating", ev
    if np.isfinite(pv_distortion) and pv_distortion >= DIST_LINEAR:
        return "self-regulating", ev
    return "unknown", ev


def _margin(x, limit, scale):
    """Confidence from the distance of ``x`` beyond ``limit`` on a log scale."""
    if not np.isfinite(x) or x <= 0:
        return 0.0
    d = abs(np.log(x / limit))
    return float(1.0 - np.exp(-d / scale))


#: A skew of the OP's time stamps is removed where the controller's answer
#: at that lag is this many times as strong as at lag zero (white noise's
#: second differences correlate by -2/3 with their neighbours' and 1/6 with
#: the next: a skew of one sample makes it 1.5 times as strong, of two 6
#: times; an OP smeared by its storage, about as strong).
SKEW_CLEAR = 1.25
#: ... and only where the OP keeps at least this share of its samples (an OP
#: stored by exception and drawn back by straight lines shows no answer to
#: the noise in each sample, and its stored points set the lag).
SKEW_STORED = 0.7
#: Most samples of skew read either way (a PV and an OP read from different
#: collectors or clocks: a few seconds apart at one second). Beyond
#: ``SENSE_SKEW`` samples the answer must also stand :data:`SKEW_CLEAR` times
#: over its neighbours' (white noise's second differences make them -2/3 of
#: it, a smooth swing of the correlation about as much).
DESKEW_MAX = 10


def _deskew_op(pv: np.ndarray, op: np.ndarray, mv: np.ndarray | None):
    """The OP (and the valve position with it) drawn back onto the PV's time
    stamps where the controller's answer to the PV's noise comes up to
    :data:`DESKEW_MAX` samples late or early
    (:func:`~valvediag.analysis.signature.controller_lag`);
    the samples shifted off the record's end are missing. Returns the OP, the
    position and the skew removed [samples]."""
    if stored_points(op).size < SKEW_STORED * np.count_nonzero(np.isfinite(op)):
        return op, mv, 0
    lag, r = controller_lag(pv, op, max_lag=DESKEW_MAX)
    zero = DESKEW_MAX
    if lag is not None and abs(lag) > SENSE_SKEW and not (
            abs(lag) < DESKEW_MAX and abs(r[lag + zero]) >= SKEW_CLEAR * max(
                abs(r[lag + zero - 1]), abs(r[lag + zero + 1]))):
        # a far lag counts only as a peak over its neighbours: a smooth swing of
        # the correlation (a sine's moves, where the noise is small) peaks
        # anywhere. Else the answer within a couple of samples is read alone
        lag, r = controller_lag(pv, op)
        zero = SENSE_SKEW
    if not lag or abs(r[lag + zero]) < SKEW_CLEAR * abs(r[zero]):
        return op, mv, 0
    gap = np.full(abs(lag), np.nan)

    def shift(x):
        return np.r_[x[lag:], gap] if lag > 0 else np.r_[gap, x[:lag]]
    return shift(op), (None if mv is None else shift(mv)), lag


#: A set point that moves by at most this many of the PV's noise standard
#: deviations from one sample to the next, and moves, wanders (a cascade's);
#: the loop's oscillation is read in its control error.
SP_WANDER = 3.0


def _oscillates(osc: Oscillation) -> bool:
    """A regular oscillation of at least 1.5 cycles was read."""
    return bool(np.isfinite(osc.period) and osc.cycles >= 1.5 and osc.is_regular)


def classify_loop(pv, op, sp=None, *, sample_time: float, process_type: str = "unknown",
                  method: str = "robust", min_cycles: float = 3.0,
                  pv_compressed: bool = False, pv_averaged: bool = False, mv=None,
                  record_s: float | None = None, drawn=None) -> LoopDiagnosis:
    """Classify one control loop from its recorded PV and OP.

    Parameters
    ----------
    pv : array_like, shape (n,)
        Process variable, uniformly sampled; NaN marks bad or missing samples
        [PV unit].
    op : array_like, shape (n,)
        Controller output, same sampling [%].
    sp : array_like, shape (n,), optional
        Set point [PV unit]; used as evidence (set-point moves). Where it
        moves by at most :data:`SP_WANDER` noise standard deviations of the
        PV a sample (a cascade's inner loop, whose set point is the outer
        loop's output), the oscillation is read in the control error
        ``PV - SP``: the PV follows the wander, which blurs the loop's own
        swing (``oscillation_read_in`` in the evidence). A step under that
        limit, small against the noise, is read so too. Without it, the set
        point is read back from the OP
        (:func:`~valvediag.analysis.setpoint.infer_setpoint`: its steps from
        the controller's kicks, or, where it stood, its level from the
        integral action; ``setpoint_inferred`` in the evidence).
    sample_time : float
        [s]
    process_type : {'unknown', 'integrating', 'self-regulating'}
        From the loop registry. ``'unknown'`` runs a data test. A type given
        is checked against the OP's answer to the set-point steps
        (:func:`~valvediag.analysis.bumps.setpoint_process_screen`): where
        that reads the other type, the reason says so (``registry_doubt`` in
        the evidence), and the verdict still stands on the type given.
    method : {'robust', 'paper'}
        Backlash Index estimator.
    min_cycles : float
        Fewest complete cycles for a verdict on the valve.
    pv_compressed : bool
        The historian stored the PV only where it left a band, and the record
        was drawn back onto the sample grid between stored points
        (:class:`~valvediag.analysis.quality.DataQuality`'s ``compressed``):
        a level's kinks are not read from it (the straight lines drawn
        between stored points kink every bend).
    pv_averaged : bool
        Each PV sample is the mean over its sample time (a historian's
        average export, the registry's ``sampling``), not the value at its
        time stamp. The Backlash Index then reads each turn as averaged
        (its ``averaging_time``): averaging alone rounds a sharp turn over a
        sample, which read as a value would be a dead band.
    mv : array_like, shape (n,), optional
        Recorded valve position, same sampling [% of travel]; NaN where
        missing. Read against the OP by
        :func:`~valvediag.analysis.travel.valve_travel`.
    record_s : float, optional
        Length of the record this stretch was cut from, where gaps cut it
        [s]; by default the stretch's own. A flow's two slips make a fault
        only in a snapshot that short
        (:func:`~valvediag.analysis.signature.stick_slip_events`).
    drawn : array_like of bool, shape (n,), optional
        True where the PV was not measured but drawn across a gap (the
        scan bridges gaps of up to a quarter of a cycle): the valve events
        and the rests at the OP's reversals are not read there.

    Returns
    -------
    LoopDiagnosis

    Raises
    ------
    ValueError
        Arrays of different lengths, a non-positive sample time, an unknown
        process type or method.

    Notes
    -----
    Isolated gross outliers (placeholders such as -9999 or 9.9e37, spikes)
    are masked (:func:`~valvediag.analysis.quality.despike`) and runs of up
    to three missing samples bridged by a straight line
    (:func:`~valvediag.analysis.quality.bridge_short_gaps`); longer gaps are
    not bridged: the longest gap-free stretch is analysed. An OP whose time
    stamps are skewed against the PV's by a sample or two (two tags stored at
    different scans) is shifted back onto the PV's, where the controller's
    answer to the PV's noise shows the skew clearly (``op_skew_samples`` in
    the evidence; the valve position moves with the OP, whose controller or
    positioner stores it): the valve's readers all assume that the controller
    answers the PV within its sample. An OP that keeps fewer than 70 % of
    its samples (stored by exception) is left as it is. Where the set point
    moves within the stretch, a regular oscillation of the PV must show in
    the PV less the set point (the control error) too: an operator's steps,
    up and down every half hour, swing a PV that follows them as regularly
    as a valve's cycle, and the record is then read as quiet (valve events,
    set-point steps, reversal rests). A process lag comparable to
    the period rounds a stiction apex and biases the BI towards backlash.

    A PV stored to a grid (an export rounded to a decimal or two, a
    converter's or a fixed-point controller's steps:
    :func:`~valvediag.analysis.quality.record_quantum`, ``pv_quantum`` and
    ``quanta_per_swing`` in the evidence) whose cycle swings over fewer than
    :data:`MIN_QUANTA_PER_SWING` steps is a staircase whose corners are
    partly the rounding's: a valve verdict read from such a cycle says so
    in its reason, at :data:`COARSE_CONFIDENCE` of its confidence (not
    where the recorded valve position shows the fault). On the realistic
    benchmark's study and development seeds (10-16 at 4 loops per class, 1
    and 2 at 8) with the PV rounded to one decimal, the scan's valve
    verdicts on records whose cycle swings over fewer than ten steps were
    right 35 times in 46 and named a fault on a healthy valve 4 times; over
    ten steps or more, 201 times in 213 and once. Withholding the verdict there instead
    (``insufficient-data``) cost more sticky valves than it spared healthy
    ones (held out, 10 per class: 41 to 34 of 50 found, 1 to 0 of 60 false
    alarms), so the verdict stands with its caveat.

    References
    ----------
    .. [1] Farenzena, M., Trierweiler, J. O. (2012). Valve backlash and
       stiction detection in integrating processes. ADCHEM 2012, 320-325.
    .. [2] Thornhill, N. F., Huang, B., Zhang, H. (2003). Detection of multiple
       oscillations in control loops. J. Process Control 13, 91-100.
    """
    if process_type not in PROCESS_TYPES:
        raise ValueError(f"process_type must be one of {PROCESS_TYPES}, not {process_type!r}")
    if method not in THRESHOLDS:
        raise ValueError(f"method must be 'robust' or 'paper', not {method!r}")
    h = float(sample_time)
    if not np.isfinite(h) or h <= 0:
        raise ValueError(f"sample_time must be a positive number of seconds, got {sample_time!r}")
    pv = np.asarray(pv, dtype=float).ravel()
    op = np.asarray(op, dtype=float).ravel()
    if op.size != pv.size:
        raise ValueError(f"pv has {pv.size} samples but op has {op.size}")
    if sp is not None:
        sp = np.asarray(sp, dtype=float).ravel()
        if sp.size != pv.size:
            raise ValueError(f"pv has {pv.size} samples but sp has {sp.size}")
    if mv is not None:
        mv = np.asarray(mv, dtype=float).ravel()
        if mv.size != pv.size:
            raise ValueError(f"pv has {pv.size} samples but mv has {mv.size}")
    if drawn is not None:
        drawn = np.asarray(drawn, dtype=bool).ravel()
        if drawn.size != pv.size:
            raise ValueError(f"pv has {pv.size} samples but drawn has {drawn.size}")
        # a line over a few samples is what this function bridges itself
        drawn = drawn_lines(drawn)
    base = dict(process_type=process_type, sample_time=h)
    ev: dict = {"method": method, "samples": int(pv.size)}
    travel = None
    coarse: list[str] = []     # why the PV's rounding hides a cycle's waveform
    events_read: dict = {}     # valve events read, by process type
    followed_read: dict = {}   # a level's kinks its set-point steps explained
    read: dict = {}            # what was read: valve events by process type, set-point steps
    rests_read: dict = {}      # the valve's rests at the OP's reversals, where read

    def verdict(v, conf, reason, **kw):
        out = dict(process_screen="metadata" if process_type != "unknown" else "unknown",
                   bi=np.nan, period=np.nan, amplitude=np.nan, cycles=0.0, regularity=np.nan,
                   travel=travel, events=tuple(events_read.values()),
                   rests=rests_read.get("rests"), followed=tuple(followed_read.values()),
                   bumps=read.get("bumps"))
        out.update(kw)
        if coarse and v in ("stiction", "backlash", "undecided") and not (
                travel is not None and travel.fault):
            # a waveform of a few steps of the PV's rounding names a valve
            # fault less surely (the recorded position, where it shows one,
            # is as sure as ever)
            reason += f"; but {coarse[0]}"
            conf *= COARSE_CONFIDENCE
        read_back = ev.get("setpoint_inferred", {})
        if read_back.get("read") and (v in ("stiction", "backlash", "undecided")
                                      or ev.get("dead_response")):
            reason += (f"; the set point was not exported: its {read_back['steps']} moves were "
                       "read from the OP's kicks" if read_back["steps"] else
                       "; the set point was not exported: it stood (no kick of the OP), where "
                       "the integral action holds the PV")
        doubt = ev.get("registry_doubt")
        if doubt:
            reason += (f"; but the loop registry names the process {process_type}, and "
                       f"{doubt}: check the registry")
        return LoopDiagnosis(verdict=v, confidence=round(float(np.clip(conf, 0.05, 0.99)), 2),
                             reason=reason, evidence=ev, **base, **out)

    def travel_verdict(**kw):
        """The valve read from its recorded position: a sticky, loose or unnamed fault."""
        conf = 0.5 if travel.verdict == "undecided" else 0.85
        return verdict(travel.verdict, conf, f"valve position: {travel.reason}; method: "
                       "recorded valve position against the OP (Kano et al. 2004)", **kw)

    # placeholders and spikes are masked, and short runs of missing or bad
    # samples bridged, before the longest gap-free stretch is taken: one
    # -9999 or a few scattered bad samples must not cut or flatten the record
    pv, pv_spikes = despike(pv)
    op, op_spikes = despike(op)
    pv, pv_bridged = bridge_short_gaps(pv)
    op, op_bridged = bridge_short_gaps(op)
    ev.update(spikes_masked=pv_spikes + op_spikes, samples_bridged=pv_bridged + op_bridged)
    op, mv, skew = _deskew_op(pv, op, mv)
    if skew:
        ev["op_skew_samples"] = skew
    good = np.isfinite(pv) & np.isfinite(op)
    a, b = longest_run(good)
    ev["usable_samples"] = b - a
    ev["usable_fraction"] = round((b - a) / max(pv.size, 1), 4)
    if b - a < MIN_SAMPLES:
        return verdict("insufficient-data", 0.95,
                       f"only {b - a} consecutive usable samples (need at least {MIN_SAMPLES})")
    x, u = pv[a:b], op[a:b]
    drawn_ab = drawn[a:b] if drawn is not None and drawn[a:b].any() else None
    if sp is None:
        # an export without its set point: the steps are read back from the
        # controller's kicks, so that a step's answer is not read as the valve's
        inferred = infer_setpoint(x, u)
        ev["setpoint_inferred"] = inferred.as_dict()
        if inferred.sp is not None:
            sp = np.full(pv.size, np.nan)
            sp[a:b] = inferred.sp
    if mv is not None:
        m, _ = bridge_short_gaps(despike(mv)[0])
        if np.isfinite(m[a:b]).sum() >= MIN_SAMPLES:
            travel = valve_travel(m[a:b], u, h)
            ev["valve_travel"] = travel.as_dict()
    if process_type != "unknown" and sp is not None:
        # the registry's type is checked against the OP's answer to the
        # set-point steps: a flow registered as a level is read by the wrong tests
        check = setpoint_process_screen(x, u, sp[a:b], h)
        if check.process not in ("unknown", process_type):
            ev["registry_doubt"] = check.reason
    dead = dead_response(x, u, sp[a:b] if sp is not None else None)
    if dead:
        ev["dead_response"] = True
        return verdict("insufficient-data", 0.9, dead, pv=x, op=u)
    if np.ptp(x) == 0:
        return verdict("insufficient-data", 0.9, "the PV does not change: frozen sensor or no data",
                       pv=x, op=u)
    s_ab = sp[a:b] if sp is not None else None
    wanders = (s_ab is not None and bool(np.all(np.isfinite(s_ab))) and np.ptp(s_ab) > 0
               and float(np.max(np.abs(np.diff(s_ab)))) <= SP_WANDER * white_noise_std(x))
    # a set point that wanders without a step (a cascade's inner loop follows
    # the outer loop's output) moves the PV with it: the loop's own swing is
    # read in the control error, without the wander
    osc = detect_oscillation(x - s_ab if wanders else x, h)
    if wanders:
        ev["oscillation_read_in"] = "control error (the set point wanders)"
    in_error = None
    if (s_ab is not None and not wanders and _oscillates(osc)
            and bool(np.all(np.isfinite(s_ab))) and np.ptp(s_ab) > 0):
        # where the set point moves, the loop's own oscillation shows in its
        # control error too: a PV that follows a set point stepped up and down
        # swings as regularly as a valve's cycle (an error that swings alone,
        # where the PV has not followed the steps, leaves the PV's reading)
        in_error = detect_oscillation(x - s_ab, h)
        ev["error_oscillation"] = dict(period_s=in_error.period, cycles=in_error.cycles,
                                       regularity=in_error.regularity)
    spp = osc.period / h if np.isfinite(osc.period) else np.nan
    ev.update(period_s=osc.period, cycles=osc.cycles, regularity=osc.regularity,
              acf_at_period=osc.acf_at_period, periodic_fraction=osc.periodic_fraction,
              samples_per_period=spp, amplitude=osc.amplitude)
    common = dict(period=osc.period, amplitude=osc.amplitude, cycles=osc.cycles,
                  regularity=osc.regularity, oscillation=osc, pv=x, op=u)
    # a period of which the record holds less than one cycle was never seen
    # to repeat: a drift (a slow load over a day) is no cycle cut short
    looks_periodic = (osc.acf_at_period > 0.3 and np.isfinite(osc.period)
                      and osc.cycles >= 1.0)
    quiet = None
    if not np.isfinite(osc.period) or osc.cycles < 1.5:
        if looks_periodic:
            quiet = ("insufficient-data", 0.7,
                     f"only {osc.cycles:.1f} cycles of an oscillation of about "
                     f"{osc.period:.4g} s; need at least {min_cycles:g}")
        else:
            quiet = ("no-oscillation", 0.8, "no oscillation: the PV has no repeating cycle")
    elif not osc.is_regular:
        quiet = ("no-oscillation", 0.6 + 0.3 * min(1.0, max(0.0, 1.0 - osc.regularity)),
                 f"no regular oscillation (regularity {osc.regularity:.2f}, "
                 f"autocorrelation at one period {osc.acf_at_period:.2f})")
    elif in_error is not None and not _oscillates(in_error):
        quiet = ("no-oscillation", 0.7,
                 f"the PV swings with its set point's steps ({osc.cycles:.0f} swings of about "
                 f"{osc.period:.0f} s), but its control error does not oscillate (regularity "
                 f"{in_error.regularity:.2f}): the PV follows the operator's moves")

    def level_bumps():
        """The level's set-point steps read as bump tests (once a record)."""
        if "bumps" not in read:
            read["bumps"] = setpoint_bumps(x, u, sp[a:b], h)
        return read["bumps"]

    def valve_events(screened: str = "unknown", min_events: float = 0.0):
        """A sticky or loose valve shown by its slips or take-ups, or None.

        ``screened``: the process type the data test found, tried alone when
        the registry has none (a square load's turns on a flow are no level's
        slips). ``min_events``: the fewest valve events that count."""
        ev_sp = sp[a:b] if sp is not None else None
        # a level's kinks are read as a fault alone only where the process is
        # known to integrate: a healthy flow's answer to a load's step kinks
        # its record as a slip kinks a level's, and a loose flow valve's
        # take-ups do too. Without the registry's word, the OP's lasting
        # answer to the set-point steps may name the process. Where it names
        # none but shows no lasting shift either (none within two standard
        # errors: a sticky level's OP rests anywhere in its band, and scatters
        # the shifts), the record is read as a flow and then as a level, whose
        # kinks count only where the set-point steps, read as a level's bump
        # tests, cleared them of a valve that follows its OP
        level_too = False
        if process_type == "unknown" and screened == "unknown" and ev_sp is not None:
            steps = setpoint_process_screen(x, u, ev_sp, h)
            ev["setpoint_screen"] = steps.as_dict()
            screened = steps.process
            level_too = steps.shift_over_kick - 2.0 * steps.standard_error <= 0.0
        guessed = process_type == "unknown" and screened == "unknown"
        kinds = (process_type,) if process_type != "unknown" else \
            (screened,) if not guessed else \
            ("self-regulating", "integrating") if level_too else ("self-regulating",)
        if pv_compressed:
            kinds = tuple(k for k in kinds if k != "integrating")
        for kind in kinds:
            slips = stick_slip_events(x, u, h, process=kind, sp=ev_sp, record_s=record_s,
                                      drawn=drawn_ab)
            read[kind] = slips
            if slips.found and slips.consistent < min_events:
                # too few to make up the cycle: kept as evidence, not a verdict
                ev["stick_slip_too_few"] = dict(slips.as_dict(), process=kind,
                                                needed=round(float(min_events), 1))
            checked = False      # the set-point steps cleared the kinks of a following valve
            if kind == "integrating" and ev_sp is not None and slips.consistent > 0:
                # a valve that follows the OP kinks a level by about its gain
                # (read at the set-point steps) times the OP's move: no slip
                # (read on kinks too few for a fault too: a record cut by gaps
                # pools its stretches' kinks)
                bumps = level_bumps()
                ratio = kinks_over_following(slips, bumps)
                if slips.found:
                    ev["setpoint_bumps"] = dict(bumps.as_dict(),
                                                kinks_over_following=round(ratio, 2))
                # a valve that held through the set-point kicks does not follow: its
                # gain read at the steps is a slipping valve's, and the ratio errs low
                if ratio < SLIP_OVER_FOLLOWING and not bumps.found:
                    if slips.found:
                        ev["kinks_followed"] = dict(slips.as_dict(), ratio=round(ratio, 2))
                    followed_read[kind] = slips
                    continue
                checked = bumps.found or ratio >= SLIP_OVER_FOLLOWING
            level_unchecked = kind == "integrating" and not checked
            if not (level_unchecked and guessed):
                # pooled over a record's stretches, which read no set-point steps:
                # a level of no known type stands only on its own steps' check
                events_read[kind] = slips
            # kinks in the controller's answer to a set-point step, where a
            # healthy loop's own answer bends the level, count only checked
            whole = slips.consistent - int(np.count_nonzero(slips.after_step))
            if level_unchecked and slips.found and (guessed or whole < MIN_SLIPS):
                # kinks of a record of no known type, or two kinks (the most a
                # snapshot holds: too few alone to rule out a load's turns after
                # the OP crept their way), make a fault only where the set-point
                # steps cleared them of a following valve
                ev["kinks_unchecked"] = slips.as_dict()
                continue
            if slips.found and slips.consistent >= min_events:
                ev.update(stick_slip=slips.as_dict(), process_screen=kind, from_events=True)
                if slips.kind == "undecided" and kind == "self-regulating":
                    # as many take-ups as slips: where the PV turns at a fixed
                    # OP travel after its reversals, the band is a loose valve's
                    loose = rests_at_reversals(
                        f"; its events read {slips.slips} slips and {slips.takeups} take-ups, "
                        "which alone leave sticky and loose undecided")
                    if loose is not None:
                        return loose
                src = "loop registry" if process_type != "unknown" else \
                    "data test: the OP after the set-point steps" if level_by_steps() \
                    else ("type not known, read as a level's where its set-point steps "
                          "cleared the kinks of a valve that follows its OP"
                          if kind == "integrating" else "assumed")
                # a type the data named is the loop's type in the result
                named = {} if process_type != "unknown" or screened == "unknown" else \
                    {"process_screen": kind}
                return verdict(slips.kind, slips.confidence,
                               f"{slips.what}: {slips.reason} ({kind} process, {src}); method: "
                               "valve events (slips and take-ups)", **named, **common)
        return None

    def level_by_steps() -> bool:
        """The registry has no type, and the OP after the set-point steps reads a level."""
        return ev.get("setpoint_screen", {}).get("process") == "integrating"

    def setpoint_steps():
        """A level's valve that held through the kicks of its set-point steps, or None."""
        if not (process_type == "integrating" or level_by_steps()) or sp is None \
                or pv_compressed:
            return None
        src = "loop registry" if process_type == "integrating" else \
            "data test: the OP after the set-point steps"
        named = {} if process_type == "integrating" else {"process_screen": "integrating"}
        bumps = level_bumps()
        ev.setdefault("setpoint_bumps", bumps.as_dict())
        if not bumps.found:
            return None
        ev["from_events"] = True
        kinks = read.get("integrating")
        method = "method: set-point steps as bump tests"
        if kinks is not None and kinks.slips > 0:
            # a dead band makes no slip: the level's kinks name the kind
            return verdict("stiction", 0.5 + 0.3 * min(1.0, bumps.against / 6.0),
                           f"{bumps.reason}; and {kinks.slips} of the level's kinks were "
                           f"slips (integrating process, {src}); {method} and valve "
                           "events", **named, **common)
        return verdict("undecided", 0.4 + 0.2 * min(1.0, bumps.against / 6.0),
                       f"{bumps.reason}: a sticky valve, or a loose one inside its dead band "
                       f"(integrating process, {src}); {method}", **named, **common)

    def rests_at_reversals(also: str = ""):
        """A flow's valve that rests in a dead band at the OP's reversals, or None
        (read where no limit cycle, or no valve model of the cycle, names a fault).

        ``also``: what else was read, said after the rests."""
        if process_type == "integrating" or level_by_steps():
            # a level runs on after the OP turns, whatever its valve does
            return None
        rests = reversal_rests(x, u, h, sp=sp[a:b] if sp is not None else None,
                               drawn=drawn_ab)
        rests_read["rests"] = rests
        ev["reversal_rests"] = rests.as_dict()
        if not rests.found:
            return None
        ev["from_events"] = True
        src = "self-regulating process, loop registry" if process_type != "unknown" else \
            "process type not known, read as self-regulating"
        return verdict("backlash", rests.confidence * (1.0 if process_type != "unknown" else 0.8),
                       f"a dead band at the OP's reversals: {rests.reason} ({src}){also}; "
                       "method: the valve's rests at the OP's reversals"
                       + (" and valve events" if also else ""), **common)

    def slips_or(v, conf, reason):
        """No limit cycle to judge: a sticky valve may still show itself by its slips,
        by its answer to set-point steps, a loose one by its rests at the OP's
        reversals, or either by its recorded position."""
        if travel is not None and travel.fault:
            return travel_verdict(**common)
        if travel is not None and travel.verdict == "linear":
            # a valve that follows the OP makes no slips
            return verdict(v, conf, f"{reason}; {travel.reason}", **common)
        found = valve_events() or setpoint_steps() or rests_at_reversals()
        if found is not None:
            return found
        if v == "no-oscillation" and process_type == "unknown" and level_by_steps():
            reason += ("; the process type is not in the loop registry, and the OP after the "
                       "set-point steps reads it as integrating: " + (
                           "a level's kinks are not read from a compressed record"
                           if pv_compressed else "the level's kinks were read"))
        elif v == "no-oscillation" and process_type == "unknown":
            # valve_events read the record as self-regulating only: say how
            # to have a level's kinks read
            reason += ("; the process type is not in the loop registry, so the record was read "
                       "as a self-regulating loop's (a level's kinks are read alone only where "
                       "the registry names it integrating, or where the OP's answer to the "
                       "set-point steps shows it; else only where that answer shows no lasting "
                       "shift and the steps check the kinks)")
        steps = ev.get("setpoint_screen", {}).get("process", "unknown")
        named = {"process_screen": steps} if process_type == "unknown" and steps != "unknown" \
            else {}
        return verdict(v, conf, reason, **named, **common)

    if quiet is not None:
        return slips_or(*quiet)
    if spp < MIN_SAMPLES_PER_PERIOD:
        if travel is not None and travel.fault:
            return travel_verdict(**common)
        return verdict("insufficient-data", 0.8,
                       f"only {spp:.1f} samples per oscillation period; the waveform is lost "
                       f"(need at least {MIN_SAMPLES_PER_PERIOD:g})", **common)
    quantum = record_quantum(x)
    if quantum > 0:
        ev["pv_quantum"] = quantum
        steps = 2.0 * osc.amplitude / quantum
        ev["quanta_per_swing"] = steps
        if steps < MIN_QUANTA_PER_SWING:
            # a cycle of a few steps of the PV's rounding is a staircase: its
            # turns and jumps are the steps' as much as the valve's
            coarse.append(f"the cycle swings over only {steps:.0f} steps of the PV's stored "
                          f"resolution ({quantum:.3g}), where a valve's fault is misread about "
                          "one time in four: export the PV with more decimals to confirm")
    if osc.cycles < min_cycles:
        return slips_or("insufficient-data", 0.7,
                        f"only {osc.cycles:.1f} cycles of a {osc.period:.4g} s oscillation; "
                        f"need at least {min_cycles:g}")
    # confidence from the amount and resolution of the data
    c_data = min(1.0, np.sqrt(osc.cycles / 10.0)) * float(np.clip((spp - 5.0) / 15.0, 0.3, 1.0))
    # the shape of the mean cycle: harmonics (a valve nonlinearity at all?)
    shape = cycle_shape(osc.baseline_removed, u, osc.apex_idx, osc.apex_sign)
    op_moves = np.std(u) > 1e-9 * max(1.0, np.abs(u).max())
    ev.update(pv_distortion=shape.pv_distortion, valve_linearity=shape.valve_linearity,
              op_lag_cycles=shape.op_lag, op_moves=bool(op_moves))
    # process type: metadata first, then the straightness of the ramps
    screen, sev = integrating_screen(osc.baseline_removed, osc.apex_idx, osc.apex_sign,
                                     shape.pv_distortion)
    ev.update(sev, process_screen=screen)
    proc_conf = 1.0
    selfreg = process_type == "self-regulating" or (process_type == "unknown"
                                                    and screen == "self-regulating")
    pscreen = "metadata" if process_type != "unknown" else screen
    if process_type == "unknown" and screen == "unknown":
        proc_conf = 0.75
    if not op_moves:
        return verdict("linear-oscillation", 0.8 * c_data,
                       "the PV oscillates while the OP stands still: the oscillation comes from "
                       "outside the loop (manual mode, or a disturbance)", process_screen=pscreen,
                       shape=shape, **common)
    if travel is not None and travel.verdict == "linear":
        return verdict("linear-oscillation", c_data * proc_conf * 0.9,
                       f"{travel.reason}: the oscillation is not the valve's; review the tuning "
                       "or trace an external disturbance; method: recorded valve position "
                       "against the OP", process_screen=pscreen, shape=shape, **common)
    if travel is not None and travel.fault and selfreg:
        return travel_verdict(process_screen=pscreen, shape=shape, **common)
    clock = phase_wander(x, osc, u)
    ev["phase_wander"] = clock.as_dict()
    # a record cut by gaps pools the stretches' crossings: timed from the
    # first sample given, not the first usable one
    common["clock"] = replace(clock, times=clock.times + a * h)
    # too few cycles for the wander: on a self-regulating loop, whose valve
    # signature a periodic load deceives, periods as steady as the noise's
    # reading of a clock are a load's too
    steady = selfreg and clock.steady_periods
    if (clock.keeps_clock or steady) and not (travel is not None and travel.fault):
        # a valve's limit cycle is the loop's own oscillation: noise moves its
        # phase for good. One that keeps a clock's time is driven from outside
        why = clock.reason if clock.keeps_clock else (
            f"the oscillation keeps time like a clock over {np.size(clock.times)} crossings: "
            f"its periods vary {clock.jitter_ratio:.2f} times as much as the PV's noise and "
            "the time grid make a steady clock's read, where the noise that the controller "
            "answers would move a sticky valve's slips as well")
        return verdict(
            "linear-oscillation", c_data * proc_conf * 0.85,
            f"{why}: a periodic load from outside the loop (a timer, a machine, a batch step) "
            "drives it, not the valve, whose own limit cycle would wander with the noise; "
            "trace the disturbance; method: "
            + ("the phase's wander over the cycles" if clock.keeps_clock
               else "the periods' jitter against the PV's noise"),
            process_screen=pscreen, shape=shape, **common)
    if s_ab is not None and bool(np.all(np.isfinite(s_ab))) and not (
            travel is not None and travel.fault):
        rests = rest_share(x - s_ab, u, osc.apex_idx, osc.apex_sign)
        ev["rest_share"] = rests
        if rests >= REST_SHARE_MIN:
            # a valve's limit cycle never rests at the set point: with the
            # error at zero a stuck valve would hold, and the cycle end
            return verdict(
                "linear-oscillation", c_data * proc_conf * 0.8,
                f"the loop rests at its set point with its OP still for {100 * rests:.0f}% of "
                "each cycle: it settles after each move of its load, which drives the swing "
                "(a pump that starts and stops, a batch step); a sticky or loose valve's limit "
                "cycle never rests at the set point; trace the disturbance; method: the "
                "loop's rests at its set point", process_screen=pscreen, shape=shape, **common)
    amp_cv = osc.amplitude_variation
    ev["amplitude_variation"] = amp_cv
    if np.isfinite(amp_cv) and amp_cv >= RESONANCE_VARIATION:
        # a sticky flow valve's slips make an irregular cycle of their own, at
        # least one slip a cycle; a ringing loop's turns pass for a slip only
        # now and then (a level's kinks are not read here)
        found = (valve_events("self-regulating", RESONANCE_SLIPS * osc.cycles)
                 or rests_at_reversals()) if selfreg else None
        if found is not None:
            return found
        few = ev.get("stick_slip_too_few")
        also = (f" ({few['consistent']} valve events in {osc.cycles:.0f} cycles, too few to make "
                "up the cycle)") if few else ""
        return verdict(
            "linear-oscillation", c_data * (0.5 + 0.4 * min(1.0, amp_cv / 0.5)),
            f"the cycles' amplitude wanders (variation {amp_cv:.2f} of the mean swing) as a "
            "noise-driven resonance's does, where a valve's limit cycle keeps its amplitude"
            f"{also}: review the tuning or trace an external disturbance", process_screen=pscreen,
            shape=shape, **common)
    sinusoidal = bool(np.isfinite(shape.pv_distortion) and shape.pv_distortion < DIST_LINEAR)

    def sinusoid():
        """A PV without harmonics beyond its noise's: no valve nonlinearity."""
        conf = c_data * proc_conf * (0.5 + 0.5 * (1.0 - shape.pv_distortion / DIST_LINEAR))
        return verdict("linear-oscillation", conf,
                       f"a sinusoidal oscillation (harmonic distortion {shape.pv_distortion:.3f}) "
                       "that no valve nonlinearity explains: review the tuning or trace an "
                       "external disturbance", process_screen=pscreen, shape=shape, **common)

    if selfreg and not (travel is not None and travel.fault):
        if sinusoidal:
            # a valve that sticks or is loose makes harmonics that a process
            # filters but does not remove (the benchmark's sticky flow and
            # temperature cycles of the study and development seeds, 104, read
            # 0.086 and more); a sinusoidal load makes none
            return sinusoid()
        # read about the cycle's own centre, not the set point given: integral
        # action holds the mean PV over a cycle at the set point, and a set
        # point exported stale or offset would read every move either way
        sp_ok = s_ab is not None and bool(np.all(np.isfinite(s_ab)))
        away = away_share(osc.baseline_removed, h, osc.period, sp=s_ab if sp_ok else None)
        ev["away_share"] = away
        if away >= AWAY_SHARE_MIN:
            # a slip is the controller's correction arriving at once: it moves
            # the PV towards its set point fastest; a load's step pushes it away
            return verdict(
                "linear-oscillation", c_data * proc_conf * 0.8,
                f"{100 * away:.0f}% of the PV's fast motion leads away from its set point: "
                "a load pushes it off and the controller brings it back, where a sticky "
                "valve's slip, the controller's correction arriving at once, moves it "
                "towards the set point fastest; trace the disturbance; method: the "
                "direction of the PV's fast moves", process_screen=pscreen, shape=shape,
                **common)
        onset = move_onset(osc.baseline_removed, h, osc.period, osc.apex_idx, osc.apex_sign,
                           sp=s_ab if sp_ok else None)
        ev["move_onset"] = onset
        if onset >= ONSET_SMOOTH:
            # a slip steps the valve, and the process answers a step at once
            return verdict(
                "linear-oscillation", c_data * proc_conf * 0.8,
                f"the PV's swings gather speed gradually (over a sixth of a period before "
                f"their fastest point they run at {100 * onset:.0f}% of their speed after it): "
                "a load that turns without a step moves it through the process's lag, where "
                "a sticky valve's slip starts it at once; trace the disturbance; method: the "
                "onset of the PV's swings", process_screen=pscreen, shape=shape, **common)
    if selfreg:
        src = "loop registry" if process_type == "self-regulating" else \
            (f"data test: the PV does not run in straight ramps (curvature "
             f"{sev['ramp_curvature']:.3f}, ramp share {sev['ramp_share']:.2f})")
        d = _self_regulating_verdict(verdict, x, u, h, osc, src, c_data, ev,
                                     process_screen=pscreen, shape=shape, **common)
        # a valve the signature cannot read in the cycle may still show its events
        return d if d.verdict in ("stiction", "backlash", "undecided") else \
            (valve_events("self-regulating") or rests_at_reversals() or d)
    valve_faulty = travel is not None and travel.fault
    share = sev["ramp_share"]
    if process_type == "integrating" and not valve_faulty and share < RAMP_SHARE_MIN:
        # a valve at rest, stuck or inside its dead band, passes a flow that
        # is not the load's, and the level runs in a ramp from turn to turn.
        # One that holds still for much of each half-cycle (at its set point
        # after a pump's step, or off it while the OP follows a ramping load)
        # has a valve passing the load's flow there: the swing is the load's.
        # (The level's kinks are not read: where it held still while the OP
        # followed a ramping load, each turn reads as a slip after a stuck
        # valve's straight run.)
        return verdict(
            "linear-oscillation", c_data * 0.8,
            f"the level does not ramp between its turns (its ramp covers {share:.2f} of its "
            "swing): it holds still for much of each cycle, where its valve passes the "
            "load's flow, and swings as the load changes; a sticky or loose valve's limit "
            "cycle ramps a level from turn to turn; trace the disturbance (a pump that "
            "starts and stops, a batch step); method: the level's ramps between its turns",
            process_screen=pscreen, shape=shape, **common)
    curv = sev["ramp_curvature"]
    if process_type == "integrating" and not valve_faulty and curv >= RAMP_ARC_MIN:
        # a valve at rest, stuck or inside its dead band, passes a steady flow,
        # and the level runs straight between turns (the sticky, sawtooth and
        # loose level cycles of the realistic benchmark's study and development
        # seeds curve by 0.012 at most, 155 of 156; one at 0.033 read as a load's
        # before too). A level that runs in arcs has a flow
        # that changes all along the ramp: a linear valve answering its load.
        # Its turns may still be sharp where the load steps (a square or
        # clipped load on a slow level), and they read as slips
        return verdict(
            "linear-oscillation", c_data * 0.8,
            f"the level runs in arcs between its turns (curvature {curv:.3f} of its swing, "
            f"where a valve at rest ramps it straight, below {RAMP_CURVATURE_MAX:g}): the "
            "flow through its valve changes all along each ramp, as a linear valve's does "
            "when it answers a changing load, and the turns are the load's; trace the "
            "disturbance; method: the straightness of the level's ramps",
            process_screen=pscreen, shape=shape, **common)
    if sinusoidal and not valve_faulty:
        return sinusoid()
    bres = backlash_index(x, h, method=method, averaging_time=h if pv_averaged else 0.0)
    def finite_mean(a):
        a = np.asarray(a, dtype=float)
        a = a[np.isfinite(a)]
        return float(a.mean()) if a.size else None

    ev.update(bi=bres.bi, theta_peak_mean=finite_mean(bres.theta_peak),
              theta_middle_mean=finite_mean(bres.theta_middle), rounding=bres.rounding,
              bi_thresholds=list(bres.thresholds))
    if bres.averaging_time > 0:
        ev["bi_averaging_s"] = bres.averaging_time     # turns read as averaged over a sample
    if bres.verdict == "insufficient-data":
        if valve_faulty:
            return travel_verdict(process_screen=pscreen, shape=shape, backlash=bres, **common)
        return verdict("insufficient-data", 0.6, f"the Backlash Index could not be measured: {bres.reason}",
                       process_screen=pscreen, shape=shape, backlash=bres, **common)
    lo, hi = bres.thresholds
    # the valve signature checks a rounded-apex (backlash) or an undecided
    # reading: a disturbance or a ringing loop rounds a PV's peaks too. Sharp
    # turns (stiction) are the paper's own evidence and cost no fit where the
    # PV runs in the straight ramps of a valve at rest; on curved ramps (a
    # load's turns, stored by swinging door, meet at sharp corners too) they
    # give way where a linear valve explains the implied valve position as
    # :func:`follows_op` asks, not where a linear signature merely fits poorly
    curved = np.isfinite(curv) and curv >= RAMP_CURVATURE_MAX
    sharp = bres.verdict == "stiction"
    sig = ValveSignature(process="integrating", verdict="unknown",
                         reason="not read: the Backlash Index finds sharp turns on straight ramps")
    if curved or not sharp:
        sig = valve_signature(x, u, h, process="integrating", period=osc.period)
        ev["signature"] = sig.as_dict()
    curved_linear = curved and sig.verdict == "linear" and (
        not sharp or (sig.r2_linear >= FOLLOWS_R2 and sig.gain < FOLLOWS_GAIN))
    if not valve_faulty and (follows_op(sig, osc.period) or curved_linear):
        why = (f"the valve position implied by the PV slope follows the OP (held-out R2 "
               f"{sig.r2_linear:.2f} with a linear valve; a sticky or loose valve removes only "
               f"{max(0.0, 100 * sig.gain):.0f}% of the rest)")
        if curved:
            why += (f", and the PV does not run in the straight ramps the Backlash Index "
                    f"assumes (curvature {sev['ramp_curvature']:.3f})")
        return verdict("linear-oscillation",
                       c_data * proc_conf * (0.5 + 0.4 * max(0.0, sig.r2_linear)),
                       f"{why}: a disturbance or the tuning, not the valve, although the "
                       f"Backlash Index reads {bres.bi:.2f}",
                       process_screen=pscreen, bi=bres.bi, shape=shape, backlash=bres, **common)
    bres_verdict = bres.verdict
    turns = lagged_turns(bres) if bres.verdict != "stiction" else None
    if turns is not None:
        ev["lagged_turns"] = {"bi": turns.bi, "bi_without_lag": turns.bi_without_lag,
                              "duration": turns.duration, "lag_s": turns.lag,
                              "sharp_behind_lag": sharp_behind_lag(turns)}
    if bres.verdict == "stiction":
        conf = c_data * proc_conf * (0.55 + 0.45 * _margin(bres.bi, lo, 0.15))
        reason = (f"sharp turns at the peaks (Backlash Index {bres.bi:.2f} <= {lo:g}): the valve "
                  "sticks and then jumps")
    elif bres.verdict == "backlash":
        conf = c_data * proc_conf * (0.55 + 0.45 * _margin(bres.bi, hi, 0.15))
        reason = (f"rounded peaks after straight ramps (Backlash Index {bres.bi:.2f} >= {hi:g}): "
                  "the valve moves smoothly once it has crossed a dead band")
    elif sig.verdict in ("stiction", "backlash"):
        conf = 0.5 * c_data * proc_conf * (0.5 + 0.5 * min(1.0, sig.gain))
        reason = (f"the Backlash Index {bres.bi:.2f} lies between {lo:g} and {hi:g}, and the "
                  f"valve signature decides: {sig.reason}")
        bres_verdict = sig.verdict
    else:
        conf = 0.3 * c_data * proc_conf
        reason = (f"a valve nonlinearity, but the Backlash Index {bres.bi:.2f} lies between "
                  f"{lo:g} and {hi:g}: stiction and backlash cannot be told apart")
    if bres_verdict in ("backlash", "undecided"):
        # a rounded turn is a dead band's only if the level has turned by the
        # time the OP reverses; a slip behind a lag turns it after
        timing = turn_timing(x, u, h, osc.period, sp=s_ab)
        ev["turn_timing"] = timing.as_dict()
        if timing.kind == "stiction":
            late = np.nanmax([timing.share / SLIP_SHARE, timing.pooled / POOLED_SHARE])
            conf = c_data * proc_conf * (0.5 + 0.4 * min(1.0, late / 2.0))
            reason = (f"rounded turns (Backlash Index {bres.bi:.2f}), but {timing.reason}, "
                      "which a dead band cannot do (a loose valve moves only while the OP moves "
                      "on); method: Backlash Index and the turns' timing against the OP's "
                      "reversals")
            bres_verdict = "stiction"
    if bres_verdict != "stiction" and sharp_behind_lag(turns):
        conf *= LAG_DOUBT
        reason += (f"; but the turns are also those of a sharp turn behind a {turns.lag:.3g} s "
                   f"lag (BI {turns.bi:.2f} with the lag fitted): if the loop has such a lag (a "
                   "slow sensor or positioner, a mixing volume) the valve may stick instead")
    if valve_faulty:
        if travel.verdict == "stiction" and bres_verdict != "stiction":
            # a slip seen in the position is a slip: a dead band never jumps, and
            # the index reads a slip behind a lag as a rounded turn (a position
            # without jumps says less: a small slip hides in its noise)
            reason += (f"; but the recorded valve position shows the valve slip, which names "
                       f"the fault: {travel.reason}")
            bres_verdict, conf = "stiction", max(conf, 0.7)
        elif bres_verdict not in ("stiction", "backlash") and travel.verdict != "undecided":
            # the index cannot name the kind: the recorded position does
            bres_verdict, conf = travel.verdict, max(conf, 0.6)
            reason += f"; the recorded valve position names it: {travel.reason}"
        elif travel.verdict != bres_verdict:
            conf *= 0.6
            reason += (f"; but the recorded valve position reads {travel.verdict}: "
                       f"{travel.reason}")
        else:
            conf = max(conf, 0.85)
            reason += f"; the recorded valve position agrees: {travel.reason}"
    if pscreen == "unknown" and process_type == "unknown":
        reason += "; the process type is not known, the loop is assumed integrating"
    return verdict(bres_verdict, conf, reason, process_screen=pscreen, bi=bres.bi, shape=shape,
                   backlash=bres, **common)
