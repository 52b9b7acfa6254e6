"""
Data-quality screen of one loop: is the data fit for valve diagnosis?

:func:`quality_metrics` measures, from the raw samples and the aligned grid:

* **bad states**: share of PV/OP rows that are digital states (value NULL);
* **gaps**: intervals without any sample longer than the alignment's
  ``max_gap`` of that tag (see :func:`valvediag.analysis.align.tag_max_gap`);
* **frozen sensor**: long runs of exactly identical PV values;
* **compression**: raw samples per grid point, median raw spacing against the
  grid, irregular spacing, and step-held (repeated) values. Below about ten
  samples per oscillation period the waveform shape, and with it the
  stiction/backlash signature, is lost [1]_;
* **saturation**: OP at 0/100 % or stuck at its own minimum/maximum while it
  moves otherwise;
* **held OP**: an OP that stays exactly constant for long stretches (manual
  mode, or a frozen output), reported as such and not as saturation;
* **manual mode**: share of time in manual, when the loop has a mode tag;
* **PV resolution**: the smallest PV step, against the span when known.

Each finding that crosses a limit adds a human-readable line to ``issues``.

References
----------
.. [1] Thornhill, N. F., Choudhury, M. A. A. S., Shah, S. L. (2004). The impact
   of compression on data-driven process analyses. Journal of Process Control
   14, 389-398.
.. [2] Jelali, M., Huang, B. (eds.) (2010). Detection and Diagnosis of
   Stiction in Control Loops. Springer, ch. 2 (data pre-processing).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
import dataclasses
from dataclasses import asdict, dataclass, field

import numpy as np
import polars as pl

from .align import AlignedLoop, contiguous_segments, to_epoch_us

__all__ = ["DataQuality", "quality_metrics", "white_noise_std", "resolved_noise_std",
           "stored_resolution", "stored_points", "record_quantum", "despike",
           "bridge_short_gaps", "bridge_short_breaks", "drawn_lines", "drawn_counts",
           "drawn_within", "most_active_window", "typical_window", "longest_run",
           "mask_frozen_pv", "FROZEN_REST_REPEAT", "MANUAL_MODES", "AUTO_MODES", "LIMITS"]

#: Mode texts meaning "the controller is not closing the loop".
MANUAL_MODES = frozenset({"MAN", "MANUAL", "IMAN", "LO", "OOS", "O/S", "LOCAL", "TRK", "TRACK"})
#: Mode texts meaning "the loop is closed".
AUTO_MODES = frozenset({"AUTO", "AUTOMATIC", "CAS", "CASCADE", "RCAS", "ROUT", "BCAS", "B-CAS"})

#: Thresholds of the issues list.
LIMITS = {
    "bad_pct": 5.0,            # [%] of rows
    "valid_pct": 80.0,         # [%] of the grid, below -> issue
    "saturation_pct": 5.0,     # [%] of valid OP points
    "manual_pct": 5.0,         # [%] of time with a known mode
    "frozen_min_points": 50,   # [-] run length, together with frozen_min_s
    "frozen_min_s": 600.0,     # [s]
    "saturation_min_points": 20,
    "saturation_min_s": 60.0,  # [s]
    "spacing_ratio": 3.0,      # median raw spacing / grid, above -> compressed
    "spacing_spread": 4.0,     # p90 / p10 raw spacing, above -> irregular (compressed)
    "repeat_fraction": 0.5,    # share of repeated consecutive PV values -> step-held
    "resolution_pct": 0.1,     # [% of span] PV step, above -> coarse
    "op_limit_tol": 0.5,       # [%] distance from 0/100 counted as saturated
    "op_held_pct": 5.0,        # [%] of valid OP points in constant runs (>= frozen_min_s)
}


@dataclass(frozen=True)
class DataQuality:
    """Data-quality figures of one loop over one window.

    Attributes
    ----------
    rows : mapping of str to int
        Raw rows per role [rows].
    bad_pct : float
        Bad-state rows / all rows, over PV and OP together [%].
    bad_pct_by_role : mapping of str to float
        The same per role [%].
    valid_pct : float
        Valid grid points [%].
    gap_count : int
        Intervals without any PV or OP sample longer than ``max_gap``,
        counted per role and summed; the window edges count when the grid
        extends past the data.
    longest_gap_s : float
        Longest such interval [s] (0 when none).
    frozen_pct : float
        Valid PV grid points inside frozen runs [%].
    longest_frozen_s : float
        Longest run of identical PV values on the grid [s].
    compression_ratio : float
        Raw PV rows / grid points [-].
    median_spacing_s : float
        Median interval between raw PV samples [s].
    spacing_spread : float
        90th / 10th percentile of the raw PV spacing [-] (1 = regular).
    repeat_fraction : float
        Share of consecutive good raw PV values that repeat exactly [-].
    compressed : bool
        The raw PV looks compressed or step-held (see Notes).
    saturation_pct : float or None
        Valid OP points at 0/100 % or at its own min/max for a long stretch
        [%]; None without OP. Runs at the OP's own min/max count only when
        the OP moves outside them (not when it steps between held levels).
    manual_pct : float or None
        Time in a manual mode among the time with a known mode [%]; None
        without a mode tag or when no mode text is understood.
    pv_resolution : float or None
        Smallest non-zero step between raw PV values [PV unit].
    sample_time : float
        Grid spacing [s].
    op_held_pct : float or None
        Valid OP points inside runs of exactly identical values lasting at
        least ``frozen_min_points`` and ``frozen_min_s`` [%] (manual mode, a
        frozen output); None without OP.
    issues : tuple of str
        Human-readable findings, one line each.

    Notes
    -----
    ``compressed`` is set when the median raw spacing exceeds
    ``LIMITS["spacing_ratio"]`` grid steps, when the spacing is irregular
    (p90/p10 above ``LIMITS["spacing_spread"]``), or when more than
    ``LIMITS["repeat_fraction"]`` of consecutive values repeat exactly while
    the PV does move (a historian or export that re-samples a held value). A
    heuristic: a slow, coarsely quantised signal can look step-held.
    """

    rows: Mapping[str, int]
    bad_pct: float
    bad_pct_by_role: Mapping[str, float]
    valid_pct: float
    gap_count: int
    longest_gap_s: float
    frozen_pct: float
    longest_frozen_s: float
    compression_ratio: float
    median_spacing_s: float
    spacing_spread: float
    repeat_fraction: float
    compressed: bool
    saturation_pct: float | None
    manual_pct: float | None
    pv_resolution: float | None
    sample_time: float
    issues: tuple[str, ...] = field(default_factory=tuple)
    op_held_pct: float | None = None

    def samples_per_cycle(self, period_s: float) -> float:
        """Raw PV samples per oscillation period of ``period_s`` [s] (below ~10: shape lost)."""
        if not self.median_spacing_s or math.isnan(self.median_spacing_s):
            return float("nan")
        return period_s / self.median_spacing_s

    def as_dict(self) -> dict:
        """Plain dict for JSON (NaN kept as float; the store turns it into null)."""
        d = asdict(self)
        d["rows"] = dict(self.rows)
        d["bad_pct_by_role"] = dict(self.bad_pct_by_role)
        d["issues"] = list(self.issues)
        return d


def _pct(part: float, whole: float) -> float:
    return float(100.0 * part / whole) if whole else float("nan")


def _ts_seconds(frame: pl.DataFrame) -> np.ndarray:
    us = to_epoch_us(frame["ts"].drop_nulls())
    if us.size > 1 and not (us[1:] >= us[:-1]).all():   # the store's are sorted: skip the sort
        us = np.sort(us)
    return us / 1e6


def _gaps(frame: pl.DataFrame, aligned: AlignedLoop, role: str) -> list[float]:
    """Intervals [s] longer than the role's max_gap between samples, window edges included."""
    t = _ts_seconds(frame)
    if aligned.n and aligned.start is not None:
        t0 = aligned.start.timestamp()
        t = np.concatenate(([t0], t[(t >= t0) & (t <= t0 + aligned.t[-1])],
                            [t0 + aligned.t[-1]]))
    d = np.diff(t)
    limit = aligned.max_gaps.get(role, aligned.max_gap)
    return d[d > limit].tolist()


def _runs(mask: np.ndarray, min_points: int) -> list[tuple[int, int]]:
    return [(a, b) for a, b in contiguous_segments(mask) if b - a >= min_points]


def _flat_runs(aligned: AlignedLoop, span: float | None):
    """The PV's runs of identical values: (mask of points in any flat run,
    the runs of at least ``frozen_min_points`` and ``frozen_min_s``)."""
    pv, ok = aligned.pv, aligned.role_valid.get("pv", aligned.valid)
    same = np.zeros(pv.size, bool)
    if pv.size < 2 or not ok.any():
        return same, []
    tol = 1e-9 * span if span and math.isfinite(span) else 0.0
    step = ok[1:] & ok[:-1] & (np.abs(np.diff(pv)) <= tol)
    # a point belongs to a flat run when the step into or out of it is flat
    same[1:] |= step
    same[:-1] |= step
    return same, _runs(same, _frozen_points(aligned.sample_time))


def _frozen_points(h: float) -> int:
    """Fewest samples of a frozen run at sample time ``h`` [s]."""
    return max(LIMITS["frozen_min_points"], int(math.ceil(LIMITS["frozen_min_s"] / h)))


def _frozen(aligned: AlignedLoop, span: float | None) -> tuple[float, float]:
    """(% of valid PV points in frozen runs, longest identical run [s])."""
    ok = aligned.role_valid.get("pv", aligned.valid)
    if aligned.pv.size < 2 or not ok.any():
        return 0.0, 0.0
    same, long_runs = _flat_runs(aligned, span)
    longest = max(((b - a - 1) * aligned.sample_time for a, b in contiguous_segments(same)),
                  default=0.0)
    frozen = sum(b - a for a, b in long_runs)
    return _pct(frozen, ok.sum()), float(longest)


#: A frozen run is cut out of the record only where, outside such runs, at
#: most this share of the PV's consecutive values repeat: a PV stored coarsely
#: or held by a historian's exception test repeats all through, and its long
#: flat runs are the process standing within its resolution.
FROZEN_REST_REPEAT = 0.05


def mask_frozen_pv(aligned: AlignedLoop, span: float | None = None
                   ) -> tuple[AlignedLoop, int]:
    """Cut the runs of a frozen PV out of a loop's record.

    Parameters
    ----------
    aligned : AlignedLoop
    span : float, optional
        PV span [PV unit]: values within a billionth of it are identical.

    Returns
    -------
    masked : AlignedLoop
        ``valid`` false over each run of identical PV values lasting at
        least ``LIMITS['frozen_min_s']`` and ``LIMITS['frozen_min_points']``
        samples; the original when there is none, or where the rest of the
        record repeats its values too (:data:`FROZEN_REST_REPEAT`) or is too
        short to tell (as short as a frozen run).
    samples : int
        Grid samples made invalid.

    Notes
    -----
    A transmitter that hangs, or a data server that repeats its last good
    value, holds the PV exactly while the controller keeps acting on the
    frozen error: its integral action ramps the OP, and when the value
    comes back the PV jumps. That is a sticky valve's signature (the PV
    stands while the OP ramps, then jumps) on a healthy valve. A live
    measurement with noise does not repeat a value to the last digit for
    ten minutes; one stored to a coarse grid, or by exception and held
    between stored values, does so all the time, and is left alone (the
    quality screen reports it as step-held or coarse). A PV pinned at the
    end of its range (an over-range level) is cut out too: it says nothing
    of the valve either.
    """
    same, runs = _flat_runs(aligned, span)
    if not runs:
        return aligned, 0
    ok = aligned.role_valid.get("pv", aligned.valid)
    inside = np.zeros(aligned.n, bool)
    for a, b in runs:
        inside[a:b] = True
    rest = ok & ~inside
    if rest.sum() < _frozen_points(aligned.sample_time) or same[rest].mean() > FROZEN_REST_REPEAT:
        return aligned, 0
    valid = aligned.valid & ~inside
    masked = int(aligned.valid.sum() - valid.sum())
    if masked == 0:
        return aligned, 0
    return dataclasses.replace(aligned, valid=valid, segments=contiguous_segments(valid)), masked


def _held_runs(op: np.ndarray, ok: np.ndarray, min_pts: int) -> np.ndarray:
    """Mask of valid points inside runs of exactly identical values of >= min_pts points."""
    held = np.zeros(op.size, bool)
    if op.size < 2:
        return held
    same = ok[1:] & ok[:-1] & (np.diff(op) == 0)
    for a, b in _runs(same, max(min_pts - 1, 1)):
        held[a:b + 1] = True
    return held


def _saturation(aligned: AlignedLoop) -> tuple[float | None, float | None]:
    """(% of valid OP points saturated, % held constant); None without OP."""
    op = aligned.op
    if op is None:
        return None, None
    ok = aligned.role_valid["op"]
    if not ok.any():
        return float("nan"), float("nan")
    min_held = max(LIMITS["frozen_min_points"],
                   int(math.ceil(LIMITS["frozen_min_s"] / aligned.sample_time)))
    held = _held_runs(op, ok, min_held)
    tol = LIMITS["op_limit_tol"]
    sat = ok & ((op <= tol) | (op >= 100.0 - tol))
    lo, hi = np.nanmin(op[ok]), np.nanmax(op[ok])
    if hi - lo > 1e-9 * max(abs(hi), 1.0):
        eps = 1e-9 * (hi - lo)
        min_pts = max(LIMITS["saturation_min_points"],
                      int(math.ceil(LIMITS["saturation_min_s"] / aligned.sample_time)))
        edge_runs = np.zeros(op.size, bool)
        for edge in (lo, hi):
            for a, b in _runs(ok & (np.abs(op - edge) <= eps), min_pts):
                edge_runs[a:b] = True
        # an OP resting at its own min/max is at a limit only when it moves
        # elsewhere; an OP that steps between held levels (manual) is not
        rest = ok & ~edge_runs
        if rest.sum() >= LIMITS["saturation_min_points"] and held[rest].mean() < 0.5:
            sat |= edge_runs
    return _pct(sat.sum(), ok.sum()), _pct((held & ok).sum(), ok.sum())


def _manual(aligned: AlignedLoop) -> tuple[float | None, str | None]:
    if aligned.mode is None:
        return None, None
    text = np.array([str(m).strip().upper() if m is not None else "" for m in aligned.mode])
    manual = np.isin(text, list(MANUAL_MODES))
    auto = np.isin(text, list(AUTO_MODES))
    known = manual | auto
    if not known.any():
        seen = sorted({t for t in text if t})[:3]
        return None, (f"mode tag values not understood ({', '.join(seen)}); manual time unknown"
                      if seen else "mode tag has no data in the window")
    return _pct(manual.sum(), known.sum()), None


def _pv_raw_stats(pv: pl.DataFrame) -> tuple[float, float, float, float | None]:
    """(median spacing [s], spacing spread, repeat fraction, resolution) of raw PV."""
    t = _ts_seconds(pv)
    d = np.diff(t)
    if d.size and not (d > 0).all():   # repeated stamps: distinct ones only
        d = np.diff(np.unique(t))
    med = float(np.median(d)) if d.size else float("nan")
    spread = float(np.percentile(d, 90) / np.percentile(d, 10)) if d.size >= 10 else 1.0
    ts = pv["ts"]
    if ts.null_count() == 0 and ts.len() > 1 and \
            (np.diff(to_epoch_us(ts)) >= 0).all():     # sorted already (the store's)
        v = pv["value"].drop_nulls().to_numpy()
    else:
        v = pv.sort("ts")["value"].drop_nulls().to_numpy()
    dv = np.abs(np.diff(v)) if v.size > 1 else np.empty(0)
    repeat = float(np.mean(dv == 0)) if dv.size else float("nan")
    nz = dv[dv > 0]
    resolution = float(nz.min()) if nz.size else None
    return med, spread, repeat, resolution


def quality_metrics(aligned: AlignedLoop, frames: Mapping[str, pl.DataFrame], *,
                    span: float | None = None) -> DataQuality:
    """Measure the data quality of one loop.

    Parameters
    ----------
    aligned : AlignedLoop
        Output of :func:`valvediag.analysis.align.align_loop` for ``frames``.
    frames : mapping of str to polars.DataFrame
        The raw samples by role (``ts``, ``value``, ``status``), as given to
        ``align_loop``.
    span : float, optional
        PV span [PV unit]; sets the tolerance of the frozen test and allows the
        resolution check. NaN or None: exact equality, no resolution check.

    Returns
    -------
    DataQuality

    Notes
    -----
    Limits are in :data:`LIMITS`. Frozen runs and OP saturation at its own
    min/max must last at least ``frozen_min_points`` grid points and
    ``frozen_min_s`` (600 s), resp. ``saturation_min_points`` and
    ``saturation_min_s`` (60 s). A constant OP (manual mode or a frozen
    signal) is not counted as saturation, nor is an OP that steps between
    held levels (an operator moving it in manual): that is ``op_held_pct``.
    Manual time is time-weighted on the grid with the held mode; texts
    outside :data:`MANUAL_MODES` and :data:`AUTO_MODES` are left out of the
    share.
    """
    span = None if span is None or not math.isfinite(span) else float(span)
    issues: list[str] = []
    rows = {role: f.height for role, f in frames.items()}
    bad = {role: int(f["value"].null_count()) for role, f in frames.items()
           if role in ("pv", "op", "sp", "mv")}
    bad_by_role = {role: _pct(bad[role], rows[role]) for role in bad}
    core = [r for r in ("pv", "op") if r in frames]
    bad_pct = _pct(sum(bad[r] for r in core), sum(rows[r] for r in core))

    pv = frames.get("pv")
    if pv is None or pv.height == 0 or aligned.n == 0:
        issues.append("no PV data")
    valid_pct = _pct(aligned.valid.sum(), aligned.n)

    gaps = [g for r in core for g in _gaps(frames[r], aligned, r)] if aligned.n else []
    frozen_pct, longest_frozen = _frozen(aligned, span)
    med, spread, repeat, resolution = (_pv_raw_stats(pv) if pv is not None and pv.height
                                       else (float("nan"), float("nan"), float("nan"), None))
    ratio = rows.get("pv", 0) / aligned.n if aligned.n else float("nan")
    step_held = (repeat > LIMITS["repeat_fraction"]) and resolution is not None
    compressed = bool(
        (med > LIMITS["spacing_ratio"] * aligned.sample_time)
        or (spread > LIMITS["spacing_spread"]) or step_held)
    saturation, op_held = _saturation(aligned)
    manual, mode_issue = _manual(aligned)

    if bad_pct > LIMITS["bad_pct"]:
        issues.append(f"{bad_pct:.1f}% of PV/OP rows are bad states")
    if aligned.n and valid_pct < LIMITS["valid_pct"]:
        issues.append(f"only {valid_pct:.1f}% of the window is usable")
    if gaps:
        issues.append(f"{len(gaps)} gaps in PV/OP, longest {max(gaps):.0f} s")
    if frozen_pct > 0:
        issues.append(f"PV frozen (identical values) for {frozen_pct:.1f}% of the time, "
                      f"longest {longest_frozen:.0f} s")
    if step_held:
        issues.append(f"PV values look step-held ({100 * repeat:.0f}% of consecutive "
                      f"samples repeat)")
    if compressed and not step_held:
        issues.append(f"PV looks compressed (median spacing {med:.3g} s, grid "
                      f"{aligned.sample_time:.3g} s, spacing spread {spread:.1f}); "
                      f"waveform shape may be distorted")
    if saturation is not None and saturation > LIMITS["saturation_pct"]:
        issues.append(f"OP saturated for {saturation:.1f}% of the time")
    if op_held is not None and op_held > LIMITS["op_held_pct"]:
        issues.append(f"OP held constant for {op_held:.1f}% of the time (manual mode or a "
                      f"frozen output)")
    if manual is not None and manual > LIMITS["manual_pct"]:
        issues.append(f"loop in manual for {manual:.1f}% of the time")
    if mode_issue:
        issues.append(mode_issue)
    if span and resolution is not None and resolution > LIMITS["resolution_pct"] / 100 * span:
        issues.append(f"coarse PV resolution ({resolution:.3g}, "
                      f"{100 * resolution / span:.2f}% of span)")

    return DataQuality(
        rows=rows, bad_pct=bad_pct, bad_pct_by_role=bad_by_role, valid_pct=valid_pct,
        gap_count=len(gaps), longest_gap_s=float(max(gaps, default=0.0)),
        frozen_pct=frozen_pct, longest_frozen_s=longest_frozen, compression_ratio=ratio,
        median_spacing_s=med, spacing_spread=spread, repeat_fraction=repeat,
        compressed=compressed, saturation_pct=saturation, manual_pct=manual,
        pv_resolution=resolution, sample_time=aligned.sample_time, issues=tuple(issues),
        op_held_pct=op_held)


#: Fewest stored points whose residuals :func:`white_noise_std` reads as
#: corners when they are all alike ...
CORNERS_MIN = 20
#: ... their 10th percentile above this share of their 90th [-].
CORNERS_ALIKE = 0.5


def white_noise_std(x) -> float:
    """Standard deviation of the white noise on a sampled, possibly compressed, signal.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled signal; NaN where missing [unit of x].

    Returns
    -------
    float
        Noise standard deviation [unit of x]; 0 for a noise-free signal.

    Notes
    -----
    Each stored point is compared with the straight line through its two
    neighbours; for white noise of standard deviation ``sigma`` on a signal
    that is locally straight the difference has the standard deviation
    ``sigma sqrt(1 + w1**2 + w2**2)`` (``w1 + w2 = 1``, the weights of the
    neighbours), and ``sigma`` is 1.4826 times the median absolute
    normalised difference. The stored points are the samples where the
    second difference is not zero: every sample of a raw record, the kept
    points of a record compressed by a historian and read back by linear
    interpolation (whose second differences are zero between them, so a
    plain second-difference estimate reads no noise at all), or the steps
    of a held one. Curvature of the signal between neighbours adds to the
    estimate; it is small where the signal is sampled several times per
    change of slope. An exception dead band biases the kept values towards
    the direction of travel (the first sample beyond the band is kept), so
    the estimate of a heavily compressed record is approximate.

    A swinging door whose deviation exceeds the noise keeps a regular
    signal's corners and nothing else: every stored point is then a turn of
    a triangle or a corner of a square wave, its difference from its
    neighbours' line is the swing itself, and the median would read the
    swing as noise (a sticky valve's triangular OP kept at 3 % of its
    samples read a noise of 2.1 on a swing of 1.8). White noise spreads the
    differences as a half-normal does (10th percentile 0.08 of the 90th);
    where :data:`CORNERS_MIN` or more of them are all alike (the 10th
    percentile above :data:`CORNERS_ALIKE` of the 90th), the record holds no
    reading of its noise, and the median bend of the drawn record at its
    stored points, per sample, is returned instead: the finest move it
    resolves. Where the noise closes the door now and then between the
    corners (some of the stored points are noise, most are corners), the
    differences are not alike and the median still reads the corners: the
    estimate is then too large. None of the 728 PV and OP records of the
    realistic benchmark's study seeds 10-16 (4 loops per class) is all
    corners; their estimates are unchanged.
    """
    return _noise_of(*_stored_residuals(x))


def _noise_of(y, knots, r) -> float:
    """:func:`white_noise_std` from :func:`_stored_residuals`' answer."""
    if r.size < 3:
        return 0.0
    lo, hi = np.percentile(np.abs(r), [10, 90])
    if r.size >= CORNERS_MIN and lo > CORNERS_ALIKE * hi:
        # all alike: the corners of a regular signal kept alone, not noise
        # (which spreads them as a half-normal does, 10th over 90th
        # percentile 0.08); the bend they make per sample is the finest
        # move the record resolves
        bend = np.diff(y, 2)[knots[1:-1] - 1] / np.sqrt(6.0)
        return float(1.4826 * np.median(np.abs(bend)))
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def _stored_residuals(x):
    """The finite samples, the stored points among them, and each inner stored
    point's normalised difference from its neighbours' line (see
    :func:`white_noise_std`); no residuals for fewer than five of either."""
    y = np.asarray(x, dtype=float)
    y = y[np.isfinite(y)]
    if y.size < 5:
        return y, np.arange(y.size), np.zeros(0)
    d2 = np.diff(y, 2)
    tiny = 1e-12 * max(float(np.max(np.abs(y))), 1.0)
    # rising, within 1 .. n - 2 between the ends: no duplicate to remove
    knots = np.r_[0, np.flatnonzero(np.abs(d2) > tiny) + 1, y.size - 1]
    if knots.size < 5:
        return y, knots, np.zeros(0)
    t = knots.astype(float)
    v = y[knots]
    w2 = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
    w1 = 1.0 - w2
    r = (v[1:-1] - (w1 * v[:-2] + w2 * v[2:])) / np.sqrt(1.0 + w1 ** 2 + w2 ** 2)
    return y, knots, r


def stored_resolution(x) -> float:
    """The finest move a compressed record stores: the 10th percentile of its
    stored points' differences from their neighbours' lines.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled record, read back by linear interpolation between
        the stored points; NaN where missing [unit of x].

    Returns
    -------
    float
        [unit of x]; 0 for fewer than five stored points.

    Notes
    -----
    A swinging door keeps a point only where the straight line past it would
    leave the record by more than its deviation, so every stored point
    differs from its neighbours' line by about that deviation or more: the
    corners of the signal by their size, the points where the noise closed
    the door by about the deviation. The low percentile reads the
    deviation where the stored points are mostly corners and the noise is
    not readable (:func:`white_noise_std` then reads the corners). On the
    OPs of the realistic benchmark's development set (seed 1: 8 sticky
    flow cycles, 8 disturbed flows, 8 sticky level cycles) stored by a
    swinging door of 0.1 %, it read 0.33-1.8 times the door's deviation; at
    0.3 %, where the door kept two or three points a period (the turns
    alone), 0.2-7.4 times: it is then the smallest turn. On a raw record it
    is about a tenth of the noise: it is no noise estimate.
    """
    return _resolution_of(_stored_residuals(x)[2])


def _resolution_of(r) -> float:
    return float(np.percentile(np.abs(r), 10)) if r.size else 0.0


#: Median spacing of a record's stored points [samples] from which its
#: noise is bounded by its stored resolution (:func:`resolved_noise_std`).
SPARSE_SPACING = 20
#: Fewest stored points a period of a regular signal from which its noise
#: is not bounded by its stored resolution (:func:`resolved_noise_std`):
#: fewer, and the record is kept at its cycle's turns.
CORNERS_PER_PERIOD = 12
#: Share of the stored resolution the noise of a sparsely stored record is
#: bounded by (:func:`resolved_noise_std`) [-].
SPARSE_NOISE_SHARE = 1.0 / 3.0


def resolved_noise_std(x, *, period: float | None = None) -> float:
    """Noise of a record, bounded by its stored resolution where the
    historian kept too few points to show it.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled record, read back by linear interpolation between
        the stored points; NaN where missing [unit of x].
    period : float, optional
        Period of the signal's cycle, where it has one [samples].

    Returns
    -------
    float
        Noise standard deviation [unit of x]: :func:`white_noise_std`, or at
        most :data:`SPARSE_NOISE_SHARE` of :func:`stored_resolution` where
        the record is sparse: its stored points lie :data:`SPARSE_SPACING`
        samples apart or more (the median spacing), or, given a period, it
        keeps fewer than :data:`CORNERS_PER_PERIOD` a period.

    Notes
    -----
    A swinging door of deviation ``d`` over white noise of standard
    deviation ``sigma`` stores a point as soon as a sample leaves the band
    of ``d`` about the line from the last one. Over ``m`` samples white
    noise reaches about ``sigma sqrt(2 ln m)`` from its mean, so where the
    stored points lie ``m`` = 20 or more samples apart the noise is below
    about ``d / 2.4``: the record does not show it. Its stored points are
    then the signal's turns (the ends of an OP's creeps, the corners of its
    cycle) and the few the noise closed, and their differences from their
    neighbours' lines, which :func:`white_noise_std` reads, are mostly the
    turns: on the OPs of the realistic benchmark's study seeds 10-13 (all
    classes, 4 loops each) stored by a swinging door of 0.1 or 0.3 % with
    stored points 20 or more samples apart (210 records), it read 2-108
    times the noise of the OP as drawn (10th to 90th percentile; median
    16). A third of the stored resolution (about the door's deviation,
    :func:`stored_resolution`) read 0.14-10 times it (median 0.95). The
    analyses that count an OP's move as real where it leaves six noise
    deviations (the valve signature's actuator, a sticky valve's creep
    before a slip) then count a move of about twice the door's deviation,
    the finest the record resolves. A regular cycle faster than the door's
    spacing is kept at its turns too, two to four stored points a period a
    few samples apart; given its period, a record with fewer than
    :data:`CORNERS_PER_PERIOD` stored points a period is sparse as well (a
    sticky valve's triangular OP kept at 5 % of its samples read a noise
    band of 2.8 on a swing of 3.5).

    It fails where the record keeps nothing but the signal's turns (no
    point closed by the noise): :func:`stored_resolution` then reads the
    smallest turn, and a move smaller than about twice it is not counted
    (an OP creeping 1 % up and down over 300 samples with noise 0.01,
    stored by a door of 0.1 %, reads 0.2 here and 0.6 by
    :func:`white_noise_std`). Where the noise closes the door now and then,
    the bound reads a quarter to a half of the noise (the same OP with
    noise 0.03): the door hides the rest, and no move within it is stored.
    A record stored point by point and without noise (a simulated OP) is
    sparse too, and its turns bound a noise it does not have; the bound
    then only lowers the band an analysis ignores, as the missing noise
    would.
    """
    y, knots, r = _stored_residuals(x)
    noise = _noise_of(y, knots, r)
    sparse = knots.size > 1 and float(np.median(np.diff(knots))) >= SPARSE_SPACING
    if period is not None and math.isfinite(period) and period > 0:
        # a cycle kept at its turns: a swinging door wider than the noise
        # keeps two to four points a period, where a noise that closes it
        # keeps many
        sparse = sparse or knots.size < CORNERS_PER_PERIOD * y.size / period
    if sparse:
        noise = min(noise, SPARSE_NOISE_SHARE * _resolution_of(r))
    return noise


def longest_run(mask) -> tuple[int, int]:
    """``(start, stop)`` of the longest run of True in a boolean mask; ``(0, 0)`` if none.

    Parameters
    ----------
    mask : array_like of bool, shape (n,)
        Usually "every signal is finite here".

    Returns
    -------
    tuple of int
        ``mask[start:stop]`` is the run.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return 0, 0
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k])


def most_active_window(x, m: int) -> int:
    """Start of the ``m``-sample window in which ``x`` travels furthest.

    Parameters
    ----------
    x : array_like, shape (n,)
        A signal, usually the controller output [its unit].
    m : int
        Window length [samples].

    Returns
    -------
    int
        First sample of the window; 0 when ``n <= m``.

    Notes
    -----
    Windows start every quarter window (and at ``n - m``); the travel is the
    window's range. A long record is cut to the part that says most about
    the valve this way, at its native sampling.
    """
    starts, ranges = _window_travels(x, m)
    return int(starts[int(np.argmax(ranges))])


def typical_window(x, m: int, spread: float = 1.2) -> int:
    """Start of the widest ``m``-sample window among those whose travel is ordinary.

    Parameters
    ----------
    x : array_like, shape (n,)
        A signal, usually the controller output [its unit].
    m : int
        Window length [samples].
    spread : float
        Windows that travel more than this many times the median window's
        travel are not ordinary.

    Returns
    -------
    int
        First sample of the window; 0 when ``n <= m``.

    Notes
    -----
    The windows and their travel are :func:`most_active_window`'s. Through a
    limit cycle every window travels about as far (on the realistic
    benchmark's sticky cycles the widest within a few percent of the
    median), and a window that travels much further (1.4-1.8 times on the
    sticky temperature cycles that read ``linear-oscillation`` when it was
    fitted) holds whatever broke the cycle: an operator's move, a load's
    step, the cycle's end. A model of the cycle is fitted on the widest of
    the ordinary windows instead. Where the record is quiet but for one
    episode, the episode's windows are not ordinary: use
    :func:`most_active_window` there.
    """
    starts, ranges = _window_travels(x, m)
    ordinary = ranges <= spread * float(np.median(ranges))
    return int(starts[int(np.argmax(np.where(ordinary, ranges, -np.inf)))])


def _window_travels(x, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Starts of the ``m``-sample windows, every quarter window and at the end,
    and each window's range (one window at 0 when the signal is no longer)."""
    x = np.asarray(x, dtype=float)
    n = x.size
    if n <= m:
        return np.zeros(1, dtype=int), np.zeros(1)
    starts = np.unique(np.r_[np.arange(0, n - m, max(1, m // 4)), n - m])
    return starts, np.array([np.ptp(x[s:s + m]) for s in starts])


def stored_points(x) -> np.ndarray:
    """Indices of the samples a historian stored, for a record read back by
    linear interpolation: the ends and every sample off the straight line
    between its neighbours (a kink of the piecewise-linear record).

    Parameters
    ----------
    x : array_like, shape (n,)

    Returns
    -------
    numpy.ndarray of int
    """
    x = np.asarray(x, dtype=float)
    if x.size < 3:
        return np.arange(x.size)
    tiny = 1e-9 * max(float(np.nanmax(np.abs(x))), 1.0)
    kinks = np.flatnonzero(np.abs(np.diff(x, 2)) > tiny) + 1
    # the kinks lie within 1 .. n - 2 and rise: the ends make no duplicate
    # (np.unique would hash or sort them again, a tenth of a second a day at 1 s)
    return np.r_[0, kinks, x.size - 1]


#: Fewest moves between samples from which a record's quantum is read.
QUANTUM_MOVES = 20
#: Share of those moves that must be whole multiples of the quantum ...
QUANTUM_SHARE = 0.98
#: ... and share of the samples that must hold their predecessor's value.
QUANTUM_HELD = 0.2


def record_quantum(x) -> float:
    """The step of the grid a record's values lie on: its resolution as stored.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled record; NaN where missing [unit of x].

    Returns
    -------
    float
        The quantum [unit of x]: the smallest move from one sample to the
        next, where at least :data:`QUANTUM_SHARE` of the moves are whole
        multiples of it (to a hundredth of it) and at least
        :data:`QUANTUM_HELD` of the samples hold the value before them; 0
        otherwise, or for fewer than :data:`QUANTUM_MOVES` moves.

    Notes
    -----
    A transmitter's converter, a controller's fixed-point PV, or an export
    rounded to one or two decimals stores a value only to a grid. Where the
    noise is smaller than the grid's step, the record is a staircase: it
    holds a value and steps by a quantum as the signal crosses the half-way
    level, so the shape of a change of a few quanta (a cycle's apex, a
    level's kink) is not in the record at all. A record drawn back between
    stored points by straight lines and then rounded is a staircase too.

    The held samples tell a staircase from a straight ramp, whose moves are
    all alike too (a noise-free simulated triangle), and from a record in
    full floating-point precision, whose moves are no multiples of their
    smallest. Noise of two quanta or more moves nearly every sample (a sine
    of swing 6 at 500 samples a period, rounded to 0.1, held 27 % of its
    samples with noise of one quantum, 13 % with two), and the record is
    read as not rounded: its rounding is then a small part of its noise. It
    fails where the smallest move is never a single quantum (every move two
    quanta or more: the quantum read is a multiple of the true one).
    """
    y = np.asarray(x, dtype=float)
    y = y[np.isfinite(y)]
    if y.size < 3:
        return 0.0
    d = np.abs(np.diff(y))
    moved = d > 1e-9 * max(float(np.max(np.abs(y))), 1.0)
    if int(moved.sum()) < QUANTUM_MOVES or float(np.mean(~moved)) < QUANTUM_HELD:
        return 0.0
    d = d[moved]
    q = float(d.min())
    k = d / q
    on_grid = np.abs(k - np.round(k)) <= 0.01
    return q if float(np.mean(on_grid)) >= QUANTUM_SHARE else 0.0


#: A sample this many robust noise deviations from its 7-sample median, and
#: at least half the signal's 1-99 % range from it, is a spike.
SPIKE_SIGMAS = 10.0
SPIKE_RANGE = 0.5
#: Longest run of missing samples bridged by a straight line [samples].
BRIDGE_SAMPLES = 3


def despike(x) -> tuple[np.ndarray, int]:
    """Mask isolated gross outliers: placeholders (-9999, 9.9e37) and spikes.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled signal, NaN where missing.

    Returns
    -------
    y : numpy.ndarray
        ``x`` with the spikes set to NaN.
    spikes : int
        Samples masked.

    Notes
    -----
    A sample is a spike when it lies both ``SPIKE_SIGMAS`` robust standard
    deviations (of the deviations from the 7-sample running median) and
    ``SPIKE_RANGE`` of the record's 1-99 % range away from the running
    median of its neighbours (a Hampel filter with a gross-error floor). A
    step of the signal (a valve's slip, a set-point move) moves the median
    with it and is not a spike; a run of more than three outliers in seven
    samples is not caught (it is a bad state, not a spike).
    """
    from scipy.ndimage import median_filter

    y = np.asarray(x, dtype=float).copy()
    ok = np.isfinite(y)
    if ok.sum() < 8:
        return y, 0
    filled = np.where(ok, y, np.interp(np.arange(y.size), np.flatnonzero(ok), y[ok]))
    med = median_filter(filled, size=7, mode="nearest")
    dev = np.abs(filled - med)
    sigma = 1.4826 * float(np.median(dev[ok]))
    lo, hi = np.percentile(filled[ok], [1, 99])
    spike = ok & (dev > SPIKE_SIGMAS * sigma) & (dev > SPIKE_RANGE * (hi - lo))
    y[spike] = np.nan
    return y, int(spike.sum())


def bridge_short_gaps(x, max_len: int = BRIDGE_SAMPLES) -> tuple[np.ndarray, int]:
    """Join the two ends of each short run of missing samples by a straight line.

    Parameters
    ----------
    x : array_like, shape (n,)
        Uniformly sampled signal, NaN where missing.
    max_len : int
        Longest run bridged [samples]; longer runs stay missing.

    Returns
    -------
    y : numpy.ndarray
    bridged : int
        Samples filled.

    Notes
    -----
    Only runs with a finite sample on both sides are bridged, so a record is
    never extended at its ends. Keep ``max_len`` short against the
    oscillation period: a straight line through a valve's slip would turn
    a jump into a ramp.
    """
    y = np.asarray(x, dtype=float).copy()
    bad = ~np.isfinite(y)
    if not bad.any() or bad.all():
        return y, 0
    d = np.diff(np.r_[0, bad.astype(np.int8), 0])
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    short = (stops - starts <= max_len) & (starts > 0) & (stops < y.size)
    fill = np.zeros(y.size, bool)
    for a, b in zip(starts[short], stops[short]):
        fill[a:b] = True
    good = ~bad
    y[fill] = np.interp(np.flatnonzero(fill), np.flatnonzero(good), y[good])
    return y, int(fill.sum())


def drawn_lines(bridged, max_len: int = BRIDGE_SAMPLES) -> np.ndarray:
    """The samples of the lines drawn across gaps longer than ``max_len``.

    Parameters
    ----------
    bridged : array_like of bool, shape (n,)
        True where a sample was drawn rather than measured
        (:attr:`AlignedLoop.bridged`).
    max_len : int
        Longest run left out [samples]: a line over a few samples is what
        :func:`bridge_short_gaps` draws inside any stretch, shorter than
        anything a valve does.

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
    """
    drawn = np.asarray(bridged, dtype=bool).ravel()
    d = np.diff(np.r_[0, drawn.astype(np.int8), 0])
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    long = stops - starts > max_len
    edges = np.zeros(drawn.size + 1, int)
    np.add.at(edges, starts[long], 1)
    np.add.at(edges, stops[long], -1)
    return np.cumsum(edges[:-1]) > 0


def drawn_counts(drawn, n: int) -> np.ndarray | None:
    """Drawn samples before each of ``n + 1`` sample boundaries (None for no mask).

    Parameters
    ----------
    drawn : array_like of bool, shape (n,), or None
        True where a sample was drawn across a gap rather than measured.
    n : int
        Samples in the record the mask belongs to.

    Returns
    -------
    numpy.ndarray of int, shape (n + 1,), or None
        For :func:`drawn_within`.

    Raises
    ------
    ValueError
        A mask of another length.
    """
    if drawn is None:
        return None
    drawn = np.asarray(drawn, dtype=bool).ravel()
    if drawn.size != n:
        raise ValueError(f"drawn must have the PV's {n} samples, got {drawn.size}")
    return np.r_[0, np.cumsum(drawn)]


def drawn_within(counts: np.ndarray, a, b) -> np.ndarray:
    """Do the windows ``[a, b)`` (sample indices, clipped to the record) hold a
    drawn sample? ``counts`` from :func:`drawn_counts`."""
    n = counts.size - 1
    return counts[np.clip(b, 0, n)] > counts[np.clip(a, 0, n)]


def bridge_short_breaks(aligned: AlignedLoop, max_len: int = BRIDGE_SAMPLES
                        ) -> tuple[AlignedLoop, int]:
    """Join the stretches of a loop's record that short breaks separate.

    Parameters
    ----------
    aligned : AlignedLoop
    max_len : int
        Longest break bridged [samples].

    Returns
    -------
    bridged : AlignedLoop
        PV, OP and MV with each break of at most ``max_len`` invalid samples
        between two valid ones filled by a straight line
        (:func:`bridge_short_gaps`), the segments joined, and the points drawn
        marked (``bridged``, with those marked before); the original when
        there is none.
    samples : int
        Grid samples made valid.

    Notes
    -----
    Scattered bad samples (a historian's ``Bad Input`` now and then, one in
    twenty say) cut a record into stretches too short to analyse, though
    each break is shorter than anything a valve does. Breaks longer than
    ``max_len`` are left alone (the scan bridges up to two minutes, or up to
    a quarter of the period of a cycle that the record shows:
    :data:`valvediag.scan.loop.BRIDGE_GAP_S`,
    :data:`valvediag.scan.loop.BRIDGE_PERIOD_SHARE`). The record's data
    quality is measured before this, on what was recorded. A line drawn is
    no measurement: a model fitted to the record should not score it
    (:meth:`AlignedLoop.measured_pv`).
    """
    segs = aligned.segments
    breaks = [(b, a) for (_, b), (a, _) in zip(segs, segs[1:]) if a - b <= max_len]
    if not breaks:
        return aligned, 0
    arrays = {}
    for name in ("pv", "op", "mv"):
        x = getattr(aligned, name)
        if x is not None:
            y = np.array(x, dtype=float)
            for b, a in breaks:     # from the last valid sample before to the first after
                y[b - 1:a + 1] = bridge_short_gaps(y[b - 1:a + 1], max_len)[0]
            arrays[name] = y
    valid = aligned.valid.copy()
    for b, a in breaks:
        valid[b:a] = np.isfinite(arrays["pv"][b:a]) & np.isfinite(arrays["op"][b:a])
    bridged = valid & ~aligned.valid
    if aligned.bridged is not None:
        bridged |= aligned.bridged
    out = dataclasses.replace(aligned, **arrays, valid=valid,
                              segments=contiguous_segments(valid), bridged=bridged)
    return out, int(valid.sum() - aligned.valid.sum())
