"""
One loop of the plant scan: read its window, screen its data, find its episodes, classify and size.
"""
from __future__ import annotations

import dataclasses
import datetime as dt
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..analysis.align import AlignedLoop, align_loop, median_spacing, to_epoch_us
from ..analysis.bumps import MIN_BUMPS_AGAINST
from ..analysis.classify import LAG_DOUBT, LoopDiagnosis, classify_loop
from ..analysis.oscillation import (ACF_STRONG, MIN_CROSSINGS, PERIODIC_FRACTION_MIN, PhaseWander,
                                   detect_oscillation, pooled_phase_wander)
from ..analysis.reversals import pooled_reversal_rests
from ..analysis.signature import MIN_SLIPS, pooled_stick_slip_events
from ..analysis.quality import (BRIDGE_SAMPLES, DataQuality, bridge_short_breaks,
                                mask_frozen_pv, quality_metrics)
from ..io.registry import LoopSpec

if TYPE_CHECKING:  # pragma: no cover
    import polars as pl


from ..plain import to_plain
from ..verdicts import (ACTION_VERDICTS, EPISODE_VERDICTS, VALVE_FAULTS, VALVE_NONLINEARITY,
                        rank_position)
from .plant import severity
from .types import (
    SPARK_BUCKETS,
    Episode,
    LoopDetail,
    LoopJob,
    LoopResult,
    LoopTrend,
    ScanConfig,
    reduce_to_buckets,
)

_UTC = dt.timezone.utc
_log = logging.getLogger(__name__)

#: Shortest segment classified: at least this many grid points (over a few
#: dozen samples noise can pass for a short regular oscillation) ...
MIN_SEGMENT_SAMPLES = 64
#: ... and this many seconds (a few minutes at one second cannot rule out a
#: level's cycle) ...
MIN_SEGMENT_S = 600.0
#: ... or this many samples, where they last less: a loop sampled faster
#: than once a second is a fast one, and a few minutes of it at 0.1 s hold
#: dozens of its cycles.
ENOUGH_SAMPLES = 600
#: Longest gap in a record bridged by a straight line before it is analysed
#: [s] (at least :data:`~valvediag.analysis.quality.BRIDGE_SAMPLES` samples),
#: where the longest stretch shows no oscillation: a minute or two missing
#: now and then (a collector's restart, a lost page of an export) would
#: otherwise cut a day into snapshots, each judged alone.
BRIDGE_GAP_S = 120.0
#: Where the longest stretch oscillates, gaps of up to this share of its
#: period are bridged instead: a line over a quarter of a cycle leaves the
#: cycle's turns measured on either side, where a line over a fast flow's
#: cycles would erase them, and a slow level's cycle (20-75 minutes) in
#: stretches of 55 minutes is read as no oscillation at all ...
BRIDGE_PERIOD_SHARE = 0.25
#: ... up to this long [s].
BRIDGE_GAP_MAX_S = 1800.0
#: Block length of the activity screen inside a segment [periods].
BLOCK_PERIODS = 4.0
#: A block is active when its half range reaches this share of the segment amplitude ...
ACTIVE_AMPLITUDE = 0.4
#: ... and its autocorrelation at one period lag exceeds this.
ACTIVE_ACF = 0.3
#: A segment whose active blocks cover at least this share is one episode.
SPLIT_COVERAGE = 0.75
#: A segment is searched for a part-time cycle where the cycles counted and the
#: autocorrelation's period agree within this factor (:func:`_is_intermittent`).
PERIOD_AGREE = 1.5
#: Confidence factor for a compressed PV, and for one with fewer than
#: :data:`MIN_RAW_PER_CYCLE` raw samples per period.
COMPRESSION_PENALTY = (0.9, 0.7)
MIN_RAW_PER_CYCLE = 10.0
#: Loops read from the store in one query by :func:`analyse_stored_loops` [-].
READ_LOOPS = 10
#: Confidence of a loop read as driven by a clock over the stretches of a
#: record cut by gaps (one stretch's reading is 0.85 times its data's
#: confidence: the pooled one counts the gaps' cycles).
POOLED_CLOCK_CONFIDENCE = 0.75
#: Fewest cycles a stretch of a record cut by gaps must show for its cycle to
#: be read with its neighbours' (:func:`_pooled_cycles`): the classifier's own
#: floor for an oscillation at all [-].
POOL_MIN_CYCLES = 1.5
#: Least share of the pooled stretches' weight that one verdict must carry:
#: each stretch is read on a few cycles, and stretches that read apart say
#: too little to tell [-].
POOL_AGREEMENT = 2.0 / 3.0
#: The loop model's lag and the lag behind the Backlash Index's turns agree
#: within this factor when a valve slips behind a lag (:func:`lags_agree`).
LAG_AGREEMENT = 1.5


def load_loop_frames(db_path, job: LoopJob) -> dict[str, pl.DataFrame]:
    """Read one loop's samples over its window.

    Parameters
    ----------
    db_path : str, path-like or valvediag.store.Store
        The DuckDB file (opened read-only for the call), or an open store.
    job : LoopJob
        The loop and window.

    Returns
    -------
    dict of str to polars.DataFrame
        Role -> ``ts, value, status`` (see
        :meth:`valvediag.store.Store.fetch_loop`); set point and mode include
        their last sample before the window.

    Notes
    -----
    DuckDB lets one process write a file and refuses every other process,
    even read-only. Call this from worker processes only while no process
    holds the file for writing, or from threads of the writing process: when
    this process already has the file open read-write, the call shares that
    database instead of failing.
    """
    from ..store.database import Store

    if isinstance(db_path, Store):
        return db_path.fetch_loop(job.spec, job.start, job.end)
    import duckdb

    try:
        store = Store(db_path, read_only=True)
    except duckdb.ConnectionException:  # this process holds it read-write
        store = Store(db_path)
    with store:
        return store.fetch_loop(job.spec, job.start, job.end)


def analyse_stored_loops(db_path, jobs: Sequence[LoopJob], config: ScanConfig = ScanConfig(),
                         progress: Callable[[int, int], object] | None = None
                         ) -> list[LoopResult]:
    """Read and diagnose several loops with one connection to the store.

    Parameters
    ----------
    db_path : str or path-like
        The DuckDB file, opened once for all ``jobs`` (read-only, or shared
        with this process's writer as in :func:`load_loop_frames`).
    jobs : sequence of LoopJob
        The loops and windows.
    config : ScanConfig
        As for :func:`analyse_loop`.
    progress : callable(done, total), optional
        Called after each group of loops read.

    Returns
    -------
    list of LoopResult
        In the order of ``jobs``; unranked.

    Notes
    -----
    The loops are read :data:`READ_LOOPS` at a time, each group in one
    query (:func:`valvediag.store.partitions.fetch_loop_windows`, the frames
    :func:`load_loop_frames` reads): reading them tag by tag scanned the
    same row groups once per tag (0.19 s per loop-day at 1 s on a store of
    149 M samples). While a group is read and converted its samples are in
    memory a few times over: a worker peaked at 1.07 GB reading 20
    loop-days at 1 s at once, 0.84 GB reading 10 and 0.71 GB reading 5.
    """
    import duckdb

    from ..store.database import Store
    from ..store.partitions import fetch_loop_windows

    if not jobs:
        return []
    try:
        store = Store(db_path, read_only=True)
    except duckdb.ConnectionException:  # this process holds it read-write
        store = Store(db_path)
    results = []
    with store:
        for k0 in range(0, len(jobs), READ_LOOPS):
            chunk = jobs[k0:k0 + READ_LOOPS]
            frames = fetch_loop_windows(store, chunk)
            for k, job in enumerate(chunk):
                results.append(analyse_loop(job, frames[k], config))
                frames[k] = None      # free each loop's samples once analysed
            if progress is not None:
                progress(len(results), len(jobs))
    return results


# ------------------------------------------------------------------ analysis

def _utc(aligned: AlignedLoop, k: int) -> dt.datetime:
    return aligned.start + dt.timedelta(seconds=float(k) * aligned.sample_time)


def _block_activity(y: np.ndarray, h: float, period: float, amplitude: float
                    ) -> list[tuple[int, int]]:
    """Runs of active blocks of ``BLOCK_PERIODS`` periods, as (start, stop) indices into ``y``.

    Each block has its least-squares line removed; it is active when half its
    2-98 % range is at least ``ACTIVE_AMPLITUDE * amplitude`` and its
    autocorrelation one period on exceeds ``ACTIVE_ACF``. The last block
    takes the remainder. The blocks of equal length are screened together
    as the rows of one matrix (a closed-form line fit instead of
    ``np.polyfit`` per block: the same line to rounding).
    """
    n = y.size
    L = int(round(BLOCK_PERIODS * period / h))
    lag = int(round(period / h))
    if L < 8 or n < 2 * L or not (amplitude > 0):
        return [(0, n)]
    nb = n // L
    edges = [k * L for k in range(nb)] + [n]
    y = np.asarray(y, dtype=float)
    active = np.concatenate([_active_blocks(y[:(nb - 1) * L].reshape(nb - 1, L), lag, amplitude),
                             _active_blocks(y[(nb - 1) * L:][None, :], lag, amplitude)]).tolist()
    runs, start = [], None
    for k, on in enumerate(active + [False]):
        if on and start is None:
            start = k
        elif not on and start is not None:
            runs.append((edges[start], edges[k]))
            start = None
    return runs


def _active_blocks(Y: np.ndarray, lag: int, amplitude: float) -> np.ndarray:
    """Activity of each row of ``Y`` (blocks of equal length), see :func:`_block_activity`."""
    m = Y.shape[1]
    t = np.arange(m, dtype=float)
    tc = t - t.mean()
    ym = Y.mean(axis=1, keepdims=True)
    slope = ((Y - ym) @ tc / (tc @ tc))[:, None]
    seg = Y - (ym + slope * tc)
    lo, hi = np.percentile(seg, [2, 98], axis=1)
    big = 0.5 * (hi - lo) >= ACTIVE_AMPLITUDE * amplitude
    x0, x1 = seg[:, :-lag], seg[:, lag:]
    den = np.sqrt(np.einsum("ij,ij->i", x0, x0) * np.einsum("ij,ij->i", x1, x1))
    num = np.einsum("ij,ij->i", x0, x1)
    acf = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    return big & (acf > ACTIVE_ACF)


def _record_s(aligned: AlignedLoop) -> float:
    """From the first valid sample of a record to its last [s]: the export's
    length, whatever gaps cut it into."""
    segs = aligned.segments
    return (segs[-1][1] - segs[0][0]) * aligned.sample_time if segs else 0.0


def _classify(aligned, a, b, process_type, config, compressed=False,
              averaged=False) -> LoopDiagnosis:
    sp = aligned.sp[a:b] if aligned.sp is not None else None
    mv = aligned.mv[a:b] if aligned.mv is not None else None
    drawn = aligned.bridged[a:b] if aligned.bridged is not None else None
    return classify_loop(aligned.pv[a:b], aligned.op[a:b], sp, sample_time=aligned.sample_time,
                         process_type=process_type, method=config.method,
                         min_cycles=config.min_cycles, pv_compressed=compressed,
                         pv_averaged=averaged, mv=mv,
                         record_s=_record_s(aligned), drawn=drawn)


def _is_episode(d: LoopDiagnosis, min_cycles: float) -> bool:
    if d.verdict in EPISODE_VERDICTS:
        return True
    # an oscillation that is there but cannot be diagnosed (BI failed, too few
    # samples per period) is still an episode
    osc = d.oscillation
    return (d.verdict == "insufficient-data" and osc is not None and osc.is_regular
            and d.cycles >= min_cycles)


def _is_intermittent(d: LoopDiagnosis, min_cycles: float) -> bool:
    """Whether a segment that is no episode as a whole may hold one in a part.

    A limit cycle that stops and starts again (a sticky valve that comes to
    rest where the load happens to balance it) keeps the record's
    autocorrelation high at its period and its ACF crossings regular, while
    the cycles folded over the whole record (``periodic_fraction``) blur.
    The cycles counted must come at the autocorrelation's period: where
    noise crosses the band all through a record whose ACF follows a slow
    swing, the short "cycles" are the noise's.
    """
    osc = d.oscillation
    return (d.verdict == "no-oscillation" and osc is not None and d.cycles >= min_cycles
            and math.isfinite(d.period)
            and abs(math.log(d.period / osc.acf_period)) <= math.log(PERIOD_AGREE)
            and osc.regularity > 1.0 and osc.acf_at_period > ACF_STRONG
            and osc.periodic_fraction <= PERIODIC_FRACTION_MIN)


def _segment_episodes(aligned, a, b, process_type, config, compressed=False, averaged=False
                      ) -> tuple[LoopDiagnosis, list[tuple[int, int, LoopDiagnosis]]]:
    """Classify one segment; return its diagnosis and its episodes (start, stop, diagnosis)."""
    d = _classify(aligned, a, b, process_type, config, compressed, averaged)
    whole = _is_episode(d, config.min_cycles)
    if not (whole or _is_intermittent(d, config.min_cycles)):
        return d, []
    if d.verdict == "backlash" and (d.evidence.get("reversal_rests") or {}).get("found"):
        # a dead band read at the OP's reversals stands on the whole segment:
        # its parts hold no limit cycle to find episodes in
        return d, [(a, b, d)]
    h = aligned.sample_time
    runs = _block_activity(aligned.pv[a:b], h, d.period, d.amplitude)
    covered = sum(rb - ra for ra, rb in runs)
    if covered >= SPLIT_COVERAGE * (b - a):
        return d, ([(a, b, d)] if whole else [])
    out = []
    for ra, rb in runs:
        if (rb - ra) * h < config.min_cycles * d.period:
            continue
        sub = _classify(aligned, a + ra, a + rb, process_type, config, compressed, averaged)
        if _is_episode(sub, config.min_cycles):
            out.append((a + ra, a + rb, sub))
    if d.evidence.get("from_events") and not any(e[2].verdict in VALVE_FAULTS for e in out):
        # a valve read from its events over the whole segment (slips, kinks,
        # set-point steps) stands, unless a part that cycles reads a valve
        # fault in its cycle: a part that reads none holds fewer of the events
        # and does not clear the valve
        return d, [(a, b, d)]
    return d, (out or ([(a, b, d)] if whole else []))


def _no_data_quality(frames: Mapping[str, pl.DataFrame] | None) -> dict:
    rows = {role: f.height for role, f in (frames or {}).items()}
    return {"rows": rows, "issues": []}


def _status_summary(frame: pl.DataFrame) -> str:
    vc = frame["status"].drop_nulls().value_counts(sort=True)
    names = [str(x) for x in vc[vc.columns[0]].to_list()[:3]]
    return ", ".join(names) if names else "no status text"


def _base(job: LoopJob) -> dict:
    s = job.spec
    return dict(loop=s.loop, unit=s.unit, rank=None, window_start=job.start,
                window_end=job.end, description=s.description or "",
                criticality=float(s.criticality))


def valve_fault_size(aligned: AlignedLoop, a: int, b: int, fault: str,
                     process_type: str = "integrating", *, period: float = math.nan) -> dict:
    """Size of a loop's valve fault from the loop model fitted to one episode.

    Parameters
    ----------
    aligned : valvediag.analysis.align.AlignedLoop
        The loop on its grid.
    a, b : int
        Grid points ``[a, b)`` of the episode behind the verdict; the part
        :func:`valvediag.workbench.size_window` chooses is fitted.
    fault : {'stiction', 'backlash'}
        The verdict.
    process_type : str
        ``'self-regulating'`` fits a first-order plant; anything else an
        integrating one.
    period : float, optional
        The episode's oscillation period [s].

    Returns
    -------
    dict
        :func:`valvediag.workbench.estimate_valve_size`'s result, floats to
        four significant digits. A fit that fails gives NaN sizes, confidence
        0 and the reason; it never raises.

    Notes
    -----
    The sizes are in the OP's unit (usually % of the valve's travel) and
    describe the valve as the controller sees it: the dead band or stick
    band that, put in front of the fitted plant, reproduces the PV best on
    held-out stretches. A low ``confidence`` means the model explains the PV
    poorly or the fault barely improves it over a linear valve.
    """
    from valvediag.workbench import estimate_valve_size, size_window

    h = aligned.sample_time
    off, k = size_window(b - a, h, period)
    a += off
    ptype = "self-regulating" if process_type == "self-regulating" else "integrating"
    sp = aligned.sp[a:b:k] if aligned.sp is not None else None
    try:
        out = estimate_valve_size(aligned.measured_pv(a, b)[::k], aligned.op[a:b:k], k * h,
                                  fault, ptype, sp=sp)
    except Exception as exc:  # noqa: BLE001 - a size is extra evidence, never a failed loop
        keys = ("S", "J") if fault == "stiction" else ("DB",)
        out = {k: math.nan for k in keys}
        out.update(confidence=0.0, reason=f"the model fit failed: {type(exc).__name__}: {exc}")
    return _four_digits(out)


def _four_digits(out: dict) -> dict:
    """A size's floats to four significant digits (NaN and text unchanged)."""
    return {k: (float(f"{v:.4g}") if isinstance(v, float) and math.isfinite(v) else v)
            for k, v in out.items()}


def lags_agree(model_lag: float, turn_lag: float, resolution: float = 0.0) -> bool:
    """Do the loop model's lag and the lag behind the Backlash Index's turns agree?

    Parameters
    ----------
    model_lag : float
        Lag fitted with the sticky valve (:func:`lag_checked_kind`) [s].
    turn_lag : float
        Lag fitted behind the turns
        (:func:`valvediag.analysis.bi.lagged_turns`) [s].
    resolution : float
        The coarser sample time of the two fits' records [s]: lags that
        differ by no more than this cannot be told apart.

    Returns
    -------
    bool
        True when both are positive and within :data:`LAG_AGREEMENT` of each
        other, or both are finite and at most ``resolution`` apart.

    Notes
    -----
    Two fits of different parts of the record, the apices' shape and the
    whole PV from the OP, see the same lag when a valve slips behind it. A
    loose valve's curved turn is fitted by the apex fit with a lag long
    enough to round it and by the loop model with a jump behind a shorter
    one: over the realistic benchmark's seeds 10-19, the six loose level
    valves whose check found a slip had model lags of 0.34-0.65 times the
    turns' lag, and 12 of the 21 sticky ones 0.69-1.3 times it.

    A lag shorter than a sample is read from the sampled record only
    roughly: where both lags are within a sample of each other, their ratio
    says nothing (a sawtooth sampled every 5 s behind 6 s of lag and dead
    time read 3.2 s at its turns and 5.0 s with the sticky valve, a ratio of
    1.56). Such lags agree.
    """
    if not (math.isfinite(model_lag) and math.isfinite(turn_lag)):
        return False
    if abs(model_lag - turn_lag) <= resolution:
        return True
    if not (model_lag > 0 and turn_lag > 0):
        return False
    r = model_lag / turn_lag
    return 1.0 / LAG_AGREEMENT <= r <= LAG_AGREEMENT


def lag_checked_kind(aligned: AlignedLoop, a: int, b: int, *, period: float = math.nan,
                     lag: float = math.nan):
    """Sticky or loose valve on a level, read by the loop model with the lag fitted.

    Parameters
    ----------
    aligned : valvediag.analysis.align.AlignedLoop
    a, b : int
        Grid points ``[a, b)`` of the episode; the part
        :func:`valvediag.workbench.kind.kind_window` chooses is fitted.
    period : float, optional
        The episode's oscillation period [s].
    lag : float, optional
        The lag fitted behind the turns [s].

    Returns
    -------
    valvediag.workbench.kind.ValveKind
        Never raises: a fit that fails gives ``kind`` ``''`` and the reason.

    Notes
    -----
    Run where the Backlash Index reads ``backlash`` or ``undecided`` and the
    turns fitted behind a first-order lag are sharp
    (:func:`valvediag.analysis.classify.sharp_behind_lag`): the index cannot
    tell a dead band from a slip behind a lag, the model with the lag
    fitted can (:func:`valvediag.workbench.kind.valve_kind`).
    """
    from valvediag.workbench.kind import ValveKind, kind_window, valve_kind

    h = aligned.sample_time
    off, k = kind_window(b - a, h, period=period, lag=lag)
    a += off
    sp = aligned.sp[a:b:k] if aligned.sp is not None else None
    try:
        return valve_kind(aligned.measured_pv(a, b)[::k], aligned.op[a:b:k], k * h, sp=sp)
    except Exception as exc:  # noqa: BLE001 - a check of the verdict, never a failed loop
        return ValveKind(kind="", reason=f"the model fit failed: {type(exc).__name__}: {exc}")


def kind_size(kind) -> dict:
    """The size of a sticky valve from :func:`lag_checked_kind`'s fit.

    Parameters
    ----------
    kind : valvediag.workbench.kind.ValveKind
        A result whose ``kind`` is ``'stiction'``.

    Returns
    -------
    dict
        In the shape of :func:`valve_fault_size`'s result: ``S`` and ``J``
        [OP unit], ``fit_pct``, ``heldout_rmse``, ``lag_s``, ``confidence``
        (the held-out fit times how clearly the slip shows: the paired
        held-out comparison's standard errors over 4, at most 1), ``model``
        and ``reason``.
    """
    fit = kind.stiction_fit
    conf = float(np.clip(fit.fit_pct / 100.0, 0, 1) * np.clip(kind.t / 4.0, 0, 1))
    return _four_digits({
        "S": kind.S, "J": kind.J, "fit_pct": float(fit.fit_pct),
        "heldout_rmse": float(fit.heldout_rmse), "lag_s": kind.lag_stiction,
        "confidence": round(conf, 2), "model": "+".join(fit.model.effects),
        "reason": f"held-out fit {fit.fit_pct:.0f} %, with the lag fitted; {kind.reason}"})


def signature_size(evidence: Mapping, fault: str) -> dict:
    """Size of a valve fault from the valve signature behind the verdict.

    Parameters
    ----------
    evidence : mapping
        The diagnosis' evidence, with ``signature``
        (:meth:`valvediag.analysis.signature.ValveSignature.as_dict`) or
        ``stick_slip`` (:meth:`~valvediag.analysis.signature.StickSlipEvents.as_dict`)
        or ``setpoint_bumps``
        (:meth:`~valvediag.analysis.bumps.SetPointBumps.as_dict`) or
        ``reversal_rests``
        (:meth:`~valvediag.analysis.reversals.ReversalRests.as_dict`).
    fault : {'stiction', 'backlash'}
        The verdict.

    Returns
    -------
    dict
        In the shape of :func:`valve_fault_size`'s result: ``S`` and ``J``
        (stiction) or ``DB`` (backlash) [OP unit], ``fit_pct`` (held-out R2
        of the signature [%]), ``confidence`` (at most 0.5: these sizes are
        not benchmarked) and ``reason``. From stick-slip
        events alone the OP travel before a slip is a lower bound of the
        stick band, and a level's answer to its set-point steps gives no
        band at all; no size is given then (NaN, confidence 0). A dead band
        found by the valve's rests at the OP's reversals is the OP's median
        travel during the rests (confidence 0.5: 0.85-1.02 of the simulated
        band, median 0.94, on 37 loose flow valves of the realistic
        benchmark's study seeds), or, where only the PV's turns at a fixed
        travel name it, from each reversal to the PV's turn (0.94-1.06,
        median 1.00, on the 13 loose flow valves of seeds 1, 2 and 10-26 so
        named; 0.86-1.10, median 0.97, on the 101 named by their rests).
    """
    sig = evidence.get("signature") or {}
    S, J = sig.get("S"), sig.get("J")
    rests = evidence.get("reversal_rests") or {}
    if fault == "backlash" and rests.get("found") and rests.get("dead_band") is not None:
        return {"DB": float(rests["dead_band"]), "confidence": 0.5,
                "model": "the OP's travel while the valve rested at its reversals",
                "reason": "the median OP travel from a reversal to the PV's turn, over the "
                          + ("excursions that turned at a fixed travel" if rests.get("by_turns")
                             else "valve's rests")
                          + ": the dead band and what the OP moves within the process's dead "
                          "time and lag"}
    if sig.get("verdict") not in ("stiction", "backlash", "undecided") or S is None:
        slips = evidence.get("stick_slip") or {}
        bumps = evidence.get("setpoint_bumps") or {}
        out = {"S": math.nan, "J": math.nan} if fault == "stiction" else {"DB": math.nan}
        out.update(confidence=0.0, reason=(
            f"found by its valve events, not sized: the OP crept about "
            f"{slips.get('op_travel')} % before each" if slips else
            "found by the level's answer to its set-point steps, not sized"
            if bumps.get("found") else "no valve signature to size from"))
        return out
    r2, gain = sig.get("r2_valve") or 0.0, sig.get("gain") or 0.0
    out = {"DB": float(S)} if fault == "backlash" else {"S": float(S), "J": float(J)}
    # at most 0.5: the sizing benchmark (benchmarks/bench_sizing.py) measures
    # the loop model's sizes on integrating loops, not these
    out.update(fit_pct=round(100.0 * r2, 1),
               confidence=round(float(np.clip(0.5 * r2 * min(1.0, gain), 0.0, 0.5)), 3),
               model="valve signature: Kano valve, dead time, lag, drifting load",
               reason="the valve signature's grid fit (held-out blocks); indicative, its "
                      "sizes are not benchmarked")
    return out


def _sparkline(aligned: AlignedLoop) -> np.ndarray | None:
    """The PV's sparkline (see :attr:`LoopDetail.sparkline`), or None without valid PV."""
    valid = aligned.role_valid.get("pv", np.isfinite(aligned.pv))
    if aligned.n == 0 or not valid.any():
        return None
    pv = np.where(valid, aligned.pv, np.nan)
    return reduce_to_buckets(pv, SPARK_BUCKETS)


def _own(d: LoopDiagnosis | None) -> LoopDiagnosis | None:
    """``d`` with its data copied, so that it does not keep the whole aligned grid alive.

    The Backlash Index is measured on the diagnosed PV itself, so its record
    shares the one copy (a third of a result's memory: 2 MB per loop-day at
    1 s, held by the flow for every loop needing action). Of a recorded
    valve position only the stretch a report draws is kept.
    """
    if d is None:
        return None
    own = lambda a: None if a is None else np.array(a)
    pv = own(d.pv)
    bres = d.backlash
    if bres is not None:
        same = (bres.pv is not None and pv is not None and bres.pv.shape == pv.shape
                and np.array_equal(bres.pv, pv, equal_nan=True))
        bres = dataclasses.replace(bres, pv=pv if same else own(bres.pv))
    travel = d.travel.excerpt() if d.travel is not None else None
    return dataclasses.replace(d, pv=pv, op=own(d.op), backlash=bres, travel=travel)


def _detail(aligned: AlignedLoop, verdict: str, rep: LoopDiagnosis | None = None,
            span: tuple[int, int] | None = None) -> LoopDetail:
    """Report data of one loop: the sparkline always; trend and diagnosis when it needs action."""
    if verdict not in ACTION_VERDICTS or rep is None:
        return LoopDetail(sparkline=_sparkline(aligned))
    a, b = span if span is not None else (0, aligned.n)
    return LoopDetail(sparkline=_sparkline(aligned), trend=LoopTrend.from_aligned(aligned),
                      diagnosis=_own(rep), diagnosis_start=_utc(aligned, a),
                      diagnosis_end=_utc(aligned, b))


def _insufficient(job: LoopJob, reason: str, *, frames=None, quality: dict | None = None,
                  evidence: dict | None = None, confidence: float = 0.95,
                  detail: LoopDetail | None = None) -> LoopResult:
    spec = job.spec
    ev = {"problems": list(job.problems)}
    ev.update(evidence or {})
    nan = math.nan
    return LoopResult(**_base(job), verdict="insufficient-data", confidence=confidence,
                      severity=0.0, process_type=spec.process_type, bi=nan, period_s=nan,
                      amplitude=nan, amplitude_pct_span=nan, regularity=nan, reason=reason,
                      evidence=to_plain(ev), quality=quality if quality is not None
                      else _no_data_quality(frames), episodes=(), detail=detail)


def _check_frames(job: LoopJob, frames: Mapping[str, pl.DataFrame]) -> str | None:
    """Reason the loop cannot be analysed at all, or None."""
    spec = job.spec
    if not spec.pv_tag:
        return "no PV tag in loops.csv"
    if not spec.op_tag:
        return "no OP tag in loops.csv"
    window = f"{job.start:%Y-%m-%d %H:%M} to {job.end:%Y-%m-%d %H:%M} UTC"
    for role, tag in (("pv", spec.pv_tag), ("op", spec.op_tag)):
        f = frames.get(role)
        if f is None or f.height == 0:
            absent = any(p == f"{role.upper()} tag {tag} not found in the exports"
                         for p in job.problems)
            return (f"{role.upper()} tag {tag} not found in the exports" if absent
                    else f"{role.upper()} tag {tag} has no samples from {window}")
        if f["value"].null_count() == f.height:
            return (f"all {f.height} {role.upper()} samples of {tag} in the window are bad "
                    f"states ({_status_summary(f)})")
        valid = f.height - f["value"].null_count()
        if valid < 2 or f["ts"].drop_nulls().n_unique() < 2:
            return (f"{role.upper()} tag {tag} has a single valid sample from {window}: no "
                    f"sample time, no trend")
    return None


def _grid_step(pv: pl.DataFrame) -> float | None:
    """The PV's median sample spacing [s], as align_loop's default, or None."""
    h = median_spacing(to_epoch_us(pv["ts"].drop_nulls()))
    return h if math.isfinite(h) and h > 0 else None


def _grid_start(pv: pl.DataFrame, start: dt.datetime, h: float | None = None) -> dt.datetime:
    """The first instant at or after ``start`` in phase with the PV's first sample.

    A grid in phase with the samples takes them as they are; a grid offset by
    a fraction of the spacing would interpolate every point, which low-passes
    the PV and rounds its peaks (biasing the Backlash Index towards backlash).
    ``h`` is :func:`_grid_step`'s result when the caller has it already.
    """
    if h is None:
        h = _grid_step(pv)
    if h is None:
        return start
    step = max(int(round(h * 1e6)), 1)
    first = int(to_epoch_us(pv["ts"].drop_nulls()).min())
    s_us = (start - dt.datetime(1970, 1, 1, tzinfo=_UTC)) // dt.timedelta(microseconds=1)
    t0 = first - ((first - s_us) // step) * step
    return dt.datetime(1970, 1, 1, tzinfo=_UTC) + dt.timedelta(microseconds=int(t0))


def _span(spec: LoopSpec, aligned: AlignedLoop) -> tuple[float, str]:
    if spec.span is not None and math.isfinite(spec.span) and spec.span > 0:
        return float(spec.span), "loops.csv"
    pv = aligned.pv[aligned.valid]
    if pv.size >= 2:
        lo, hi = np.percentile(pv, [0.5, 99.5])
        if hi > lo:
            return float(hi - lo), "data (robust PV range in the window)"
    return math.nan, "unknown"


def _quality_note(q: DataQuality, period: float) -> tuple[float, str]:
    """(confidence factor, reason suffix) for a compressed PV."""
    if not q.compressed:
        return 1.0, ""
    spc = q.samples_per_cycle(period) if math.isfinite(period) else math.nan
    if math.isfinite(spc) and spc < MIN_RAW_PER_CYCLE:
        return COMPRESSION_PENALTY[1], (f"; the PV is compressed to {spc:.0f} stored samples "
                                        f"per period, so its waveform may be distorted")
    return COMPRESSION_PENALTY[0], "; the PV is compressed, which may distort the waveform"


def analyse_loop(job: LoopJob, frames: Mapping[str, pl.DataFrame],
                 config: ScanConfig = ScanConfig()) -> LoopResult:
    """Diagnose one loop over its window: pure numerics, no store.

    Parameters
    ----------
    job : LoopJob
        The loop and its window (from :func:`plan_loops`).
    frames : mapping of str to polars.DataFrame
        The loop's samples by role (from :func:`load_loop_frames`).
    config : ScanConfig
        ``method``, ``min_cycles``, ``max_gap_s`` and ``min_coverage`` are
        used.

    Returns
    -------
    LoopResult
        Unranked (``rank`` None); :func:`rank_results` ranks a plant.

    Notes
    -----
    The steps are described in the module docstring: alignment and quality,
    episodes, integrating screen, verdict per episode and per loop, severity.
    A loop without a PV or OP tag, without samples in the window or with only
    bad-state samples is ``insufficient-data`` and the reason names the tag.
    A frozen PV's runs are cut out first
    (:func:`~valvediag.analysis.quality.mask_frozen_pv`, ``frozen_masked``
    in the evidence). Where no stretch holds an episode, the loop's verdict
    is its longest stretch's, or, where a stretch reads a dead response (its
    PV ignored the OP's travel), the longest such stretch's: a shorter
    stretch's OP may have travelled where the longest one's did not.
    Gaps of up to :data:`BRIDGE_GAP_S`, or of up to a quarter of the period
    of the oscillation the longest stretch shows (where the record so joined
    shows it regular), are bridged by straight lines first
    (``breaks_bridged`` in the evidence counts the samples drawn; the model
    fits score only measured samples: :meth:`AlignedLoop.measured_pv`).
    The classifier analyses one gap-free segment at a time, so a day
    split by longer gaps is analysed in pieces, those of at least
    :data:`MIN_SEGMENT_S` (or :data:`ENOUGH_SAMPLES` samples, where they
    last less). Where gaps cut a cycle into stretches that each hold fewer
    than ``min_cycles`` of it, but together enough, each is read on its own
    few cycles and the readings vote (:func:`_pooled_cycles`). A record
    whose stretches show no oscillation, no event and no
    dead response reads ``no-oscillation`` only where its usable stretches
    last ``min_cycles`` times the shortest stretch analysed (30 minutes at
    one sample a second or slower): a cycle of 10 minutes, a slow level's,
    needs that long to show ``min_cycles`` times, and a shorter record is
    ``insufficient-data`` (20 minutes of a level, or 13 minutes holding 1.5
    cycles of a sticky valve's cycle of 8.7 minutes, would otherwise read as a
    healthy valve's). An oscillation that occupies
    less than about a third of a segment may be missed by the segment's
    classification (the block screen only splits segments found
    oscillating). An unexpected error in the analysis gives the loop
    ``insufficient-data`` with the error as its reason (and logs the
    traceback) rather than stopping the scan.
    """
    try:
        return _analyse_loop(job, frames, config)
    except Exception as exc:   # one loop's failure must not stop the plant's scan
        _log.exception("analysis of loop %s failed", job.spec.loop)
        return _insufficient(job, f"analysis failed ({type(exc).__name__}: {exc}); "
                                  "please report this with the loop's data", frames=frames)


def _pooled_events(seg_diag, record_s: float, process_type: str):
    """(verdict, confidence, reason, stretches pooled, evidence) from a valve's events
    pooled over a record's stretches, or None where they make no fault.

    Each stretch read alone may hold too few of the valve's slips (a record
    cut by gaps); summed over the stretches, the counts are judged as a
    gap-free record's (:func:`~valvediag.analysis.signature.pooled_stick_slip_events`),
    a flow's jumps and a level's kinks apart. A level's kinks that a valve
    following the OP explains (read against each stretch's set-point steps)
    are not counted, unless the stretches' steps together found the level
    going against the OP's kicks (at :data:`~valvediag.analysis.bumps.MIN_BUMPS_AGAINST`
    steps or more, as a gap-free record's would): the gain those steps read
    is then a slipping valve's, and explains nothing. A level's pooled
    kinks need the full rule's three: two, which a snapshot allows, stand
    only where a stretch's own set-point steps checked them, and kinks read
    in the controller's answer to a set-point step are not counted among
    the three."""
    quiet = [e for e in seg_diag if e[2].verdict in ("no-oscillation", "insufficient-data")]
    against = sum(e[2].bumps.against for e in quiet if e[2].bumps is not None)
    for process in ("self-regulating", "integrating"):
        held = process == "integrating" and against >= MIN_BUMPS_AGAINST
        read = [(e, r) for e in quiet for r in e[2].events + (e[2].followed if held else ())
                if r.process == process and r.events > 0]
        readings = [r for _, r in read]
        if len(readings) < 2:
            continue
        pooled = pooled_stick_slip_events(readings, record_s=record_s)
        whole = pooled.consistent - int(np.count_nonzero(pooled.after_step))
        if not pooled.found or (process == "integrating" and whole < MIN_SLIPS):
            # a level's two kinks pooled from stretches were checked against no
            # set-point steps as two, and its kinks in the controller's answer
            # to a step not at all (classify_loop's kinks_unchecked)
            continue
        src = "loop registry" if process_type != "unknown" else \
            "data test: the OP after the set-point steps" if process == "integrating" \
            else "assumed"
        reason = (f"{pooled.what}: {pooled.reason} ({process} process, {src}); method: valve "
                  "events (slips and take-ups) pooled over the record's stretches")
        if held and any(r is f for e, r in read for f in e[2].followed):
            reason += (f"; over them the level went against the OP's kick at {against} "
                       "set-point steps, so the gain the steps read is a slipping valve's, "
                       "which clears no kink")
        return pooled.kind, pooled.confidence, reason, [e for e, _ in read], {}
    return None


def _pooled_rests(seg_diag, process_type: str):
    """(verdict, confidence, reason, stretches pooled, evidence) from a loose
    valve's rests at the OP's reversals pooled over a record's stretches, or
    None where they make no fault.

    Each stretch read alone may hold too few of the OP's reversals (a record
    cut by gaps); the excursions of the stretches where the rests were read
    (self-regulating, no cycle) are judged together as a gap-free record's
    (:func:`~valvediag.analysis.reversals.pooled_reversal_rests`). The
    evidence is the pooled reading (``reversal_rests``, with the stretches
    it stands on), from which the dead band is sized."""
    read = [e for e in seg_diag if e[2].rests is not None and e[2].rests.legs > 0]
    if len(read) < 2:
        return None
    pooled = pooled_reversal_rests([d.rests for _, _, d in read])
    if not pooled.found:
        return None
    used = [e for e in read if e[2].rests.sense == pooled.sense]
    known = process_type != "unknown"
    src = "self-regulating process, loop registry" if known else \
        "process type not known, read as self-regulating"
    reason = (f"a dead band at the OP's reversals: over {len(used)} stretches, {pooled.reason} "
              f"({src}); method: the valve's rests at the OP's reversals pooled over the "
              "record's stretches")
    return ("backlash", pooled.confidence * (1.0 if known else 0.8), reason, used,
            {"reversal_rests": dict(pooled.as_dict(), stretches=len(used))})


def _pooled_cycles(aligned: AlignedLoop, seg_diag, process_type: str, config: ScanConfig,
                   compressed: bool = False, averaged: bool = False) -> tuple[list, float]:
    """Episodes of a cycle that gaps cut into stretches too short to show it alone.

    Parameters
    ----------
    aligned : AlignedLoop
    seg_diag : list of (start, stop, LoopDiagnosis)
        Each stretch's diagnosis at the scan's ``min_cycles``.
    process_type : str
    config : ScanConfig
    compressed, averaged : bool
        The PV was stored compressed; each PV sample is a mean over its
        sample time (:func:`~valvediag.analysis.classify.classify_loop`'s
        ``pv_compressed`` and ``pv_averaged``).

    Returns
    -------
    episodes : list of (start, stop, LoopDiagnosis)
        The stretches re-read with :data:`POOL_MIN_CYCLES` as their floor,
        those whose verdict is an episode's; empty where the stretches do not
        make up a cycle together.
    cycles : float
        The cycles they hold in all.

    Notes
    -----
    A record cut every hour by a few minutes' gap (a collector that drops
    its link, an export that lost a page) holds a 20-minute cycle in
    stretches of 55 minutes: two or two and a half cycles each, fewer than
    the ``min_cycles`` a verdict needs, and each stretch reads
    ``insufficient-data``, though the day holds seventy cycles. Gaps that
    long are not bridged (a line over a quarter of a cycle or more erases
    its turns). Where two or more stretches each show a regular oscillation
    of at least :data:`POOL_MIN_CYCLES` cycles, at periods within
    :data:`PERIOD_AGREE` of their median, and together ``min_cycles`` or
    more, each is read again with :data:`POOL_MIN_CYCLES` as its floor and
    the readings vote as a gap-free record's episodes do. Each stretch's
    reading rests on its own few cycles (its confidence falls with them),
    so the vote must carry :data:`POOL_AGREEMENT` of their weight, or the
    loop reads ``insufficient-data`` (on the realistic benchmark's study
    seeds 10-16 with three gaps of 10-30 minutes at random places, a sticky
    temperature loop's two stretches of four hours read 51 % a linear valve,
    49 % a sticky one, where the valve signature asked a sticky valve on a
    self-regulating loop for a level's 60 % of the linear valve's error); the
    record's clock (:func:`_pooled_clock`) is read
    over all of them. A stretch that shows a different period holds another
    oscillation and is left out.
    """
    short = [(a, b, d) for a, b, d in seg_diag
             if d.verdict == "insufficient-data" and d.oscillation is not None
             and d.oscillation.is_regular and math.isfinite(d.period) and d.period > 0
             and POOL_MIN_CYCLES <= d.cycles < config.min_cycles]
    if len(short) < 2:
        return [], 0.0
    mid = float(np.median([d.period for _, _, d in short]))
    agree = [e for e in short if abs(math.log(e[2].period / mid)) <= math.log(PERIOD_AGREE)]
    cycles = sum(d.cycles for _, _, d in agree)
    if len(agree) < 2 or cycles < config.min_cycles:
        return [], 0.0
    relaxed = dataclasses.replace(config, min_cycles=POOL_MIN_CYCLES)
    out = []
    for a, b, _ in agree:
        d = _classify(aligned, a, b, process_type, relaxed, compressed, averaged)
        if d.verdict in EPISODE_VERDICTS:
            out.append((a, b, d))
    if len(out) < 2:
        return [], 0.0
    return out, float(sum(d.cycles for _, _, d in out))


def _pooled_clock(seg_diag, h: float) -> PhaseWander | None:
    """The phase's wander read over a record's stretches, or None.

    Where gaps cut a record into stretches too short to read the phase's
    wander alone (fewer than :data:`~valvediag.analysis.oscillation.MIN_CROSSINGS`
    crossings each), their crossings are pooled on the record's clock
    (:func:`~valvediag.analysis.oscillation.pooled_phase_wander`). None where
    a stretch read alone wanders (a limit cycle), where the recorded valve
    position shows a fault, or where fewer than two stretches have their
    phase read."""
    clocks = [(d.clock, a * h) for a, _, d in seg_diag if d.clock is not None]
    if any(c.readable and c.crossings >= MIN_CROSSINGS and not c.keeps_clock
           for c, _ in clocks):
        return None
    if any(d.travel is not None and d.travel.fault for _, _, d in seg_diag):
        return None
    if sum(c.readable for c, _ in clocks) < 2:
        return None
    return pooled_phase_wander([c for c, _ in clocks], [s for _, s in clocks])


def _longest_oscillation(aligned: AlignedLoop) -> tuple[float, bool]:
    """Period of the oscillation the record's longest stretch shows [s] (NaN
    where it shows none), and whether it is regular."""
    a, b = max(aligned.segments, key=lambda s: s[1] - s[0], default=(0, 0))
    if b - a < MIN_SEGMENT_SAMPLES:
        return math.nan, False
    osc = detect_oscillation(aligned.pv[a:b], aligned.sample_time)
    return osc.period, bool(osc.is_regular)


def _bridged(aligned: AlignedLoop) -> tuple[AlignedLoop, int]:
    """The record with its short breaks bridged, and the samples drawn.

    Scattered bad samples first (:data:`~valvediag.analysis.quality.BRIDGE_SAMPLES`
    in a row), then the gaps between stretches: up to :data:`BRIDGE_GAP_S`,
    or, where the longest stretch oscillates, up to
    :data:`BRIDGE_PERIOD_SHARE` of its period (at most
    :data:`BRIDGE_GAP_MAX_S`). A period that makes the limit shorter counts
    only where the stretch keeps it regularly: the noise of a quiet record
    reads a period of a few samples that no cycle keeps, and a quarter of it
    bridged nothing (a minute missing every hour cut such a day into 24
    stretches). A bridge longer than :data:`BRIDGE_GAP_S` stands only
    where the record it joins shows a regular oscillation whose period
    makes every gap bridged short enough: a stretch of 55 minutes shows one
    or two cycles of a slow level, whose period it reads roughly, and a
    wandering load's half swing reads as a period too."""
    aligned, drawn = bridge_short_breaks(aligned)
    if len(aligned.segments) < 2:
        return aligned, drawn
    h = aligned.sample_time
    limit = BRIDGE_GAP_S
    period, regular = _longest_oscillation(aligned)
    if math.isfinite(period) and (regular or BRIDGE_PERIOD_SHARE * period > BRIDGE_GAP_S):
        limit = min(BRIDGE_GAP_MAX_S, BRIDGE_PERIOD_SHARE * period)
        if limit > BRIDGE_GAP_S:
            segs = aligned.segments
            widest = max((a - b for (_, b), (a, _) in zip(segs, segs[1:])
                          if a - b <= limit // h), default=0)
            wide, more = bridge_short_breaks(aligned, max(BRIDGE_SAMPLES, int(limit // h)))
            joined, steady = _longest_oscillation(wide) if more else (math.nan, False)
            if steady and math.isfinite(joined) and widest * h <= BRIDGE_PERIOD_SHARE * joined:
                return wide, drawn + more
            limit = BRIDGE_GAP_S
    aligned, more = bridge_short_breaks(aligned, max(BRIDGE_SAMPLES, int(limit // h)))
    return aligned, drawn + more


def _duration(seconds: float) -> str:
    """A record's length in words: hours, or minutes under an hour."""
    return f"{seconds / 60:.2g} min" if seconds < 3600.0 else f"{seconds / 3600:.2g} h"


def _shortest_stretch(h: float) -> int:
    """Fewest grid points of a stretch analysed at sample time ``h`` [s]:
    :data:`MIN_SEGMENT_S`, or :data:`ENOUGH_SAMPLES` where they last less."""
    return max(MIN_SEGMENT_SAMPLES, min(int(math.ceil(MIN_SEGMENT_S / h)), ENOUGH_SAMPLES))


def _analyse_loop(job: LoopJob, frames: Mapping[str, pl.DataFrame],
                  config: ScanConfig) -> LoopResult:
    spec = job.spec
    why = _check_frames(job, frames)
    if why is not None:
        return _insufficient(job, why, frames=frames)
    roles = {r: f for r, f in frames.items() if r in ("pv", "op", "sp", "mv", "mode")}
    step = _grid_step(roles["pv"])
    aligned = align_loop(roles, sample_time=step,
                         start=_grid_start(roles["pv"], job.start, step), end=job.end,
                         max_gap=config.max_gap_s)
    q = quality_metrics(aligned, roles, span=spec.span)
    qd = to_plain(q.as_dict())
    # a frozen PV (a hung transmitter) under a controller that winds its OP
    # on the frozen error is a sticky valve's picture: cut out
    aligned, frozen_masked = mask_frozen_pv(aligned, spec.span)
    # scattered bad samples and short gaps must not cut the record into
    # stretches too short to use (the gaps' limit read once the scattered
    # samples are bridged)
    aligned, breaks_bridged = _bridged(aligned)
    window_s = (job.end - job.start).total_seconds()
    h = aligned.sample_time
    min_len = _shortest_stretch(h)
    segs = [(a, b) for a, b in aligned.segments if b - a >= min_len]
    usable_s = sum(b - a for a, b in segs) * h
    ev: dict = {"problems": list(job.problems), "sample_time_s": h, "segments": len(segs),
                "breaks_bridged": breaks_bridged, "frozen_masked": frozen_masked,
                "usable_s": usable_s, "coverage": usable_s / window_s if window_s else 0.0}
    if not segs:
        issues = "; ".join(q.issues) or "no overlap of valid PV and OP samples"
        longest = max((b - a for a, b in aligned.segments), default=0) * h
        return _insufficient(job, f"no stretch of usable PV and OP data lasting "
                             f"{min_len * h / 60:.3g} min ({min_len} samples) in the window; the "
                             f"longest lasts {longest / 60:.3g} min ({issues})",
                             quality=qd, evidence=ev, detail=_detail(aligned, "insufficient-data"))

    seg_diag: list[tuple[int, int, LoopDiagnosis]] = []
    episodes: list[tuple[int, int, LoopDiagnosis]] = []
    averaged = spec.sampling == "average"   # each PV sample a mean over its sample time
    for a, b in segs:
        d, eps = _segment_episodes(aligned, a, b, spec.process_type, config, q.compressed,
                                   averaged)
        seg_diag.append((a, b, d))
        episodes.extend(eps)

    span, span_source = _span(spec, aligned)
    ev.update(span=span, span_source=span_source)
    pooled_cycles = 0.0
    if len(segs) > 1 and not any(e[2].verdict != "insufficient-data" for e in episodes):
        # a cycle that gaps cut into stretches of too few cycles each
        read, pooled_cycles = _pooled_cycles(aligned, seg_diag, spec.process_type, config,
                                             q.compressed, averaged)
        if read:
            episodes = read
            ev["pooled_cycles"] = {"stretches": len(read), "cycles": round(pooled_cycles, 2)}
    diagnostic = [e for e in episodes if e[2].verdict != "insufficient-data"]
    voters = diagnostic or episodes
    too_short = False
    if voters:
        weights: dict[str, float] = {}
        for a, b, d in voters:
            weights[d.verdict] = weights.get(d.verdict, 0.0) + (b - a) * h * max(d.confidence, 0.05)
        total = sum(weights.values())
        verdict = max(weights, key=lambda v: (weights[v], -rank_position(v)))
        mine = [(a, b, d) for a, b, d in voters if d.verdict == verdict]
        dur = sum((b - a) for a, b, _ in mine)
        conf_mean = sum((b - a) * d.confidence for a, b, d in mine) / dur
        agreement = weights[verdict] / total
        ra, rb, rep = max(mine, key=lambda e: (e[1] - e[0]) * e[2].confidence)
        confidence = conf_mean * agreement
        reason = rep.reason
        # the verdicts' shares of the weight, the largest first
        votes = ", ".join(f"{v} {100 * w / total:.0f}%" for v, w in
                          sorted(weights.items(), key=lambda kv: (-kv[1], kv[0] != verdict)))
        if agreement < 0.999:
            reason += f" (episodes disagree: {votes})"
        if pooled_cycles and agreement < POOL_AGREEMENT:
            verdict, confidence = "insufficient-data", 0.7
            reason = (f"only {pooled_cycles:.1f} cycles of a {rep.period:.4g} s oscillation over "
                      f"{len(voters)} stretches cut by gaps, fewer than {config.min_cycles:g} "
                      f"in each, and the stretches, each read on its own cycles, read apart "
                      f"({votes}): too little to tell")
            episodes = []
        elif pooled_cycles:
            reason = (f"over {len(voters)} stretches cut by gaps, of fewer than "
                      f"{config.min_cycles:g} cycles each ({pooled_cycles:.1f} in all), each read "
                      f"on its own cycles: {reason}")
        ev.update(episode_votes={v: round(w / total, 4) for v, w in weights.items()},
                  agreement=round(agreement, 4))
        clock = _pooled_clock(seg_diag, h) \
            if verdict in VALVE_NONLINEARITY and len(segs) > 1 else None
        if clock is not None:
            ev["pooled_phase_wander"] = clock.as_dict()
        if clock is not None and clock.keeps_clock:
            # a load that a clock drives keeps its phase through the gaps
            verdict, confidence = "linear-oscillation", POOLED_CLOCK_CONFIDENCE
            reason = (f"{clock.reason}: a periodic load from outside the loop drives it, not "
                      "the valve, whose own limit cycle would wander with the noise; trace the "
                      "disturbance; method: the phase's wander over the cycles of the record's "
                      f"stretches. Read stretch by stretch: {reason}")
            rep = dataclasses.replace(rep, clock=clock)
            episodes = [(a, b, dataclasses.replace(d, verdict=verdict))
                        if d.verdict in VALVE_NONLINEARITY else (a, b, d)
                        for a, b, d in episodes]
    else:
        # a stretch whose PV ignored its OP's travel says more than a longer
        # one that shows nothing (its OP may not have travelled as far)
        dead = [e for e in seg_diag if e[2].evidence.get("dead_response")]
        ra, rb, rep = max(dead or seg_diag, key=lambda e: e[1] - e[0])
        verdict, confidence, reason = rep.verdict, rep.confidence, rep.reason
        if len(segs) > 1:
            ev["segment_verdicts"] = sorted({d.verdict for _, _, d in seg_diag})
            pooled = (_pooled_events(seg_diag, _record_s(aligned), spec.process_type)
                      or _pooled_rests(seg_diag, spec.process_type)) \
                if verdict == "no-oscillation" else None
            if pooled is not None:
                # the stretches whose events were pooled are the fault's episodes
                verdict, confidence, reason, used, pooled_ev = pooled
                ev.update(from_events=True, pooled_stretches=len(used), **pooled_ev)
                rep = dataclasses.replace(rep, evidence={**rep.evidence, **pooled_ev})
                episodes = [(a, b, dataclasses.replace(d, verdict=verdict,
                                                       confidence=confidence))
                            for a, b, d in used]
        rule_out_s = config.min_cycles * min_len * h
        too_short = verdict == "no-oscillation" and usable_s < rule_out_s
        if too_short:
            # too short to see the cycles it would rule out
            verdict, confidence = "insufficient-data", 0.9
            reason = (f"too little data to rule out an oscillation (a quiet record must hold "
                      f"{config.min_cycles:g} cycles as long as the shortest stretch analysed, "
                      f"{_duration(min_len * h)}: {_duration(rule_out_s)}); {reason}")
        elif verdict == "no-oscillation" and ev["coverage"] < config.min_coverage:
            # a snapshot: say what the verdict covers rather than refuse it
            reason = (f"no oscillation in the {_duration(usable_s)} of data available (of the "
                      f"{window_s / 3600:.3g} h window): {reason}")
            confidence *= 0.5 + 0.5 * ev["coverage"] / config.min_coverage
    if verdict != "no-oscillation" and ev["coverage"] < config.min_coverage:
        # any other verdict on a snapshot says what it stands on too
        reason += (f" (from the {_duration(usable_s)} of data available of the "
                   f"{window_s / 3600:.3g} h window)")

    osc_s = sum((b - a) for a, b, _ in episodes) * h
    # a quiet record's period and amplitude are its noise's
    quiet = verdict == "no-oscillation" or too_short
    amp = rep.amplitude if not quiet else math.nan
    amp_pct = 100.0 * amp / span if math.isfinite(amp) and span and math.isfinite(span) else math.nan
    if verdict in EPISODE_VERDICTS:
        factor, note = _quality_note(q, rep.period)
        confidence *= factor
        reason += note
        sev, factors = severity(amp_pct, rep.regularity, osc_s / window_s, spec.criticality)
    else:
        sev, factors = 0.0, {}
    if spec.process_type != "unknown":
        ptype, source = spec.process_type, "loops.csv"
    else:
        screen = rep.process_screen if rep.process_screen in ("integrating", "self-regulating") \
            else "unknown"
        ptype, source = screen, "data test" if screen != "unknown" else "unknown"
    ev.update({k: v for k, v in rep.evidence.items() if k not in ev})
    ev.update(process_type_source=source, process_screen=rep.process_screen,
              oscillating_s=osc_s, time_share=osc_s / window_s if window_s else 0.0,
              severity_factors=factors, episodes=len(episodes))
    size = None
    turns = rep.evidence.get("lagged_turns") or {}
    if (config.size_estimate and ptype == "integrating" and verdict in ("backlash", "undecided")
            and turns.get("sharp_behind_lag")):
        # rounded turns that are also a slip's behind a short lag: the loop
        # model, with the lag fitted, says whether the valve slips
        kind = lag_checked_kind(aligned, ra, rb, period=rep.period, lag=turns["lag_s"])
        # the model is fitted at a multiple of the record's step: the coarser of the two
        agree = lags_agree(kind.lag_stiction, turns["lag_s"], resolution=kind.sample_time)
        ev["valve_kind"] = dict(kind.as_dict(), lags_agree=agree)
        if kind.kind == "stiction" and agree:
            verdict = "stiction"
            confidence = min(0.95, confidence / LAG_DOUBT) * (0.6 + 0.4 * min(1.0, kind.t / 4.0))
            reason = (f"sharp turns behind a {turns['lag_s']:.3g} s lag (Backlash Index "
                      f"{turns['bi']:.2f} with the lag fitted), and {kind.reason}, the two lags "
                      "alike; method: Backlash Index with the lag fitted, and the loop model's "
                      f"sticky against loose valve. The Backlash Index as read: {reason}")
            size = kind_size(kind)
            episodes = [(a, b, dataclasses.replace(d, verdict="stiction"))
                        if (a, b) == (ra, rb) else (a, b, d) for a, b, d in episodes]
    if config.size_estimate and verdict in VALVE_FAULTS and size is None:
        if ptype == "self-regulating" or "stick_slip" in rep.evidence \
                or (rep.evidence.get("setpoint_bumps") or {}).get("found"):
            # the valve signature is itself a fit of the valve behind the
            # process: its band and jump are the size (no second, slower fit);
            # valve events and set-point steps give none
            size = signature_size(rep.evidence, verdict)
        else:
            size = valve_fault_size(aligned, ra, rb, verdict, ptype, period=rep.period)
    if size is not None:
        ev["size"] = size
    eps = tuple(Episode(start=_utc(aligned, a), end=_utc(aligned, b), period_s=d.period,
                        amplitude=d.amplitude, regularity=d.regularity, verdict=d.verdict,
                        bi=d.bi, confidence=d.confidence) for a, b, d in sorted(episodes,
                                                                               key=lambda e: e[0]))
    return LoopResult(**_base(job), verdict=verdict,
                      confidence=round(float(np.clip(confidence, 0.0, 1.0)), 3), severity=sev,
                      process_type=ptype,
                      bi=rep.bi if verdict in EPISODE_VERDICTS else math.nan,
                      period_s=rep.period if not quiet else math.nan,
                      amplitude=amp, amplitude_pct_span=amp_pct,
                      regularity=rep.regularity, reason=reason, evidence=to_plain(ev),
                      quality=qd, episodes=eps, size=size,
                      detail=_detail(aligned, verdict, rep, (ra, rb)))


# ------------------------------------------------------------- plant level

