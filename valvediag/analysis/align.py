"""
Per-loop alignment: put a loop's PV, OP, SP, MV and mode on one uniform grid.

Historian tags are stored at their own time stamps (scan rate, exception
reporting, compression). The analysis needs one uniform time base. The rules:

* **Analog signals (PV, OP, MV)** are interpolated linearly between two
  consecutive *good* samples, which is how a historian reconstructs
  compressed data [1]_. A grid point is valid only when it falls on a good
  sample or between two good samples that are at most the tag's ``max_gap``
  apart with no bad sample (digital state) between them. There is no
  extrapolation.
* **What is a gap.** A bad-state row always splits the data. Otherwise an
  interval between two good samples is a gap only when it is much longer
  than the tag's *own* typical spacing (:func:`tag_max_gap`): five times the
  median spacing for a regularly sampled tag, and for a compressed tag
  (irregular spacing: more than 2 % of its intervals longer than 1.5 x the
  median) also five times the 99th percentile of its spacings. A compressed tag stores no point while
  the signal stays on a straight line or inside its dead band, so long
  spacings are normal there and are bridged; the historian marks a real
  outage with a digital state (``I/O Timeout``, ``Shutdown``), which splits.
* **Held signals (SP, mode)** keep their last sample (step), as exception-
  reported tags mean "unchanged until the next sample". A bad state makes the
  signal invalid until the next good sample.
* A grid point is ``valid`` when PV (and OP, when the loop has one) are valid.
  SP, MV and mode do not affect ``valid``; their own masks are in
  ``role_valid``.

References
----------
.. [1] Thornhill, N. F., Choudhury, M. A. A. S., Shah, S. L. (2004). The impact
   of compression on data-driven process analyses. Journal of Process Control
   14, 389-398.
"""
from __future__ import annotations

import datetime as dt
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import polars as pl

__all__ = ["AlignedLoop", "align_loop", "median_spacing", "contiguous_segments",
           "to_epoch_us", "tag_max_gap", "MAX_GAP_FACTOR", "COMPRESSED_GAP_FACTOR",
           "REGULAR_SPREAD", "IRREGULAR_SHARE", "MAX_GRID_POINTS"]

#: Default ``max_gap``: multiples of a tag's median spacing (and of the grid step).
MAX_GAP_FACTOR = 5.0
#: Compressed tags: ``max_gap`` is at least this many times the 99th percentile
#: of the tag's spacings.
COMPRESSED_GAP_FACTOR = 5.0
#: A tag with more than ``IRREGULAR_SHARE`` of its intervals longer than
#: ``REGULAR_SPREAD`` times its median interval is taken as compressed
#: (exception or swinging-door storage), not as regularly sampled.
REGULAR_SPREAD = 1.5
IRREGULAR_SHARE = 0.02
#: Largest grid align_loop builds (about 1 GB of arrays).
MAX_GRID_POINTS = 20_000_000
_LINEAR_ROLES = ("pv", "op", "mv")
_HELD_ROLES = ("sp", "mode")
_US = 1_000_000


@dataclass(frozen=True)
class AlignedLoop:
    """A loop's signals on a uniform time grid.

    Attributes
    ----------
    t : numpy.ndarray
        Time since ``start`` [s], ``t[k] = k * sample_time``.
    time : numpy.ndarray
        The same instants as ``datetime64[us]``, in UTC.
    pv : numpy.ndarray
        Process variable [PV unit]; NaN where invalid.
    op, sp, mv : numpy.ndarray or None
        Controller output [%], set point [PV unit], valve position [%]; NaN
        where invalid, None when the loop has no such tag.
    mode : numpy.ndarray or None
        Controller mode text held on the grid (object array, None where
        unknown), or None without a mode tag.
    valid : numpy.ndarray
        Boolean mask: PV and OP are both valid.
    segments : tuple of (int, int)
        Contiguous runs of ``valid``, as ``(start, stop)`` index pairs with
        ``stop`` exclusive.
    sample_time : float
        Grid spacing [s].
    max_gap : float
        Longest interval interpolated across in the PV [s].
    start : datetime.datetime
        Time of ``t = 0`` (UTC).
    role_valid : mapping of str to numpy.ndarray
        Validity mask of every role present.
    max_gaps : mapping of str to float
        Longest interval interpolated across, per analog role (``pv``, ``op``,
        ``mv``) [s].
    bridged : numpy.ndarray or None
        Boolean mask of the grid points drawn by a straight line across a
        break between two stretches
        (:func:`~valvediag.analysis.quality.bridge_short_breaks`): valid, but
        not measured. None where nothing was bridged.
    """

    t: np.ndarray
    time: np.ndarray
    pv: np.ndarray
    op: np.ndarray | None
    sp: np.ndarray | None
    mv: np.ndarray | None
    mode: np.ndarray | None
    valid: np.ndarray
    segments: tuple[tuple[int, int], ...]
    sample_time: float
    max_gap: float
    start: dt.datetime | None
    role_valid: Mapping[str, np.ndarray] = field(default_factory=dict)
    max_gaps: Mapping[str, float] = field(default_factory=dict)
    bridged: np.ndarray | None = None

    def __post_init__(self):
        for name in ("t", "time", "pv", "op", "sp", "mv", "mode", "valid", "bridged"):
            arr = getattr(self, name)
            if arr is not None:
                arr.flags.writeable = False
        for arr in self.role_valid.values():
            arr.flags.writeable = False

    def measured_pv(self, a: int = 0, b: int | None = None) -> np.ndarray:
        """The PV over grid points ``[a, b)``, NaN where a break was bridged.

        A model fitted to the record scores only what was measured: a line
        drawn over a break is no measurement, and its kinks at either end
        would be fitted as the valve's."""
        pv = np.array(self.pv[a:b], dtype=float)
        if self.bridged is not None:
            pv[self.bridged[a:b]] = np.nan
        return pv

    @property
    def n(self) -> int:
        """Number of grid points."""
        return int(self.t.size)

    @property
    def valid_fraction(self) -> float:
        """Share of valid grid points [-]; NaN for an empty grid."""
        return float(self.valid.mean()) if self.n else float("nan")

    def to_polars(self) -> pl.DataFrame:
        """The grid as a frame: ``time, t, pv, op, sp, mv, mode, valid``."""
        cols = {"time": pl.Series(self.time).dt.replace_time_zone("UTC"), "t": self.t,
                "pv": self.pv}
        for name in ("op", "sp", "mv"):
            if getattr(self, name) is not None:
                cols[name] = getattr(self, name)
        if self.mode is not None:
            cols["mode"] = pl.Series(self.mode.tolist(), dtype=pl.String)
        cols["valid"] = self.valid
        return pl.DataFrame(cols)

    def plot(self, ax=None):
        """Draw PV and OP against time, shading invalid stretches; return the axes."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(10, 3))
        ax.plot(self.t, self.pv, lw=0.8, label="PV")
        if self.sp is not None:
            ax.plot(self.t, self.sp, lw=0.8, ls="--", label="SP")
        if self.op is not None:
            ax.plot(self.t, self.op, lw=0.8, label="OP")
        for a, b in contiguous_segments(~self.valid):
            ax.axvspan(self.t[a], self.t[b - 1], color="0.85", lw=0)
        ax.set_xlabel("time since start [s]")
        ax.legend(loc="upper right", fontsize="small")
        return ax


def to_epoch_us(ts: pl.Series) -> np.ndarray:
    """Microseconds since the epoch of a datetime series.

    Parameters
    ----------
    ts : polars.Series
        Datetime of any unit; timezone-aware is converted to UTC, naive is
        taken as UTC.

    Returns
    -------
    numpy.ndarray
        int64 [us].

    Notes
    -----
    A series in microseconds is returned as its physical values (polars
    stores an aware datetime as UTC epoch time, so the time zone changes no
    value); converting through the time zone cost milliseconds per call.
    """
    if ts.dtype == pl.Null:  # an empty frame built without a schema
        ts = ts.cast(pl.Datetime("us", "UTC"))
    if ts.dtype.time_unit == "us":  # type: ignore[union-attr]
        return ts.to_physical().to_numpy().astype(np.int64)
    if ts.dtype.time_zone is not None:  # type: ignore[union-attr]
        ts = ts.dt.convert_time_zone("UTC").dt.replace_time_zone(None)
    return ts.dt.cast_time_unit("us").to_physical().to_numpy().astype(np.int64)


def _datetime_us(value: dt.datetime, what: str) -> int:
    """Aware datetime -> int microseconds since the epoch."""
    if value.tzinfo is None or value.utcoffset() is None:
        raise ValueError(f"{what} {value.isoformat()} has no time zone; give an aware datetime")
    epoch = dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc)
    return (value - epoch) // dt.timedelta(microseconds=1)


def _prepare(frame: pl.DataFrame, role: str) -> pl.DataFrame:
    missing = {"ts", "value"} - set(frame.columns)
    if missing:
        raise ValueError(f"{role} frame lacks columns {sorted(missing)}; has {frame.columns}")
    if "status" not in frame.columns:
        frame = frame.with_columns(status=pl.lit(None, pl.String))
    ts = frame["ts"]
    if ts.dtype != pl.Null and ts.null_count() == 0:
        us = to_epoch_us(ts)
        if (us[1:] > us[:-1]).all():   # the store's frames: already sorted and distinct
            return frame
    return frame.filter(pl.col("ts").is_not_null()).sort("ts").unique("ts", keep="first",
                                                                      maintain_order=True)


def median_spacing(ts_us: np.ndarray) -> float:
    """Median of the positive intervals between time stamps [s].

    Parameters
    ----------
    ts_us : numpy.ndarray
        Time stamps [us since the epoch], any order; repeats are ignored.

    Returns
    -------
    float
        NaN with fewer than two distinct time stamps.

    Notes
    -----
    Time stamps from the store or from :func:`align_loop` are already sorted
    and distinct; they are recognised by one pass over their differences and
    not sorted again (the sort of ~10^5 stamps dominated the cost). Any other
    input is sorted and de-duplicated first, with the same result.
    """
    ts_us = np.asarray(ts_us)
    d = np.diff(ts_us)
    if d.size and not (d > 0).all():
        d = np.diff(np.unique(ts_us))
    return float(np.median(d)) / _US if d.size else float("nan")


def tag_max_gap(ts_us: np.ndarray, value: np.ndarray, sample_time: float = 0.0) -> float:
    """Longest interval between two good samples of one tag that is not a gap [s].

    Parameters
    ----------
    ts_us : numpy.ndarray
        Time stamps, sorted and distinct [us since the epoch].
    value : numpy.ndarray
        Values; NaN marks a bad sample (digital state).
    sample_time : float, optional
        Grid step [s]; the result is never below ``MAX_GAP_FACTOR`` grid steps.

    Returns
    -------
    float
        ``MAX_GAP_FACTOR * median(d)`` for a regularly sampled tag, and
        ``max(MAX_GAP_FACTOR * median(d), COMPRESSED_GAP_FACTOR * p99(d))``
        for a compressed one, where ``d`` are the intervals between
        consecutive good samples with no bad sample between them; at least
        ``MAX_GAP_FACTOR * sample_time``. NaN when the tag has fewer than two
        consecutive good samples and no ``sample_time`` is given.

    Notes
    -----
    A tag is compressed when more than ``IRREGULAR_SHARE`` (2 %) of ``d``
    exceed ``REGULAR_SPREAD`` (1.5) times the median; a regularly sampled tag
    has nearly all intervals equal, its few real gaps excepted. Even light
    exception reporting (80-90 % of the points kept) leaves the flat stretches
    near the apices with intervals of many scan periods. A compressed tag's
    normal spacing reaches up to the historian's compression or exception
    maximum time (which the data do not state), so the threshold scales with
    its longest usual spacings, not the median. An unmarked outage shorter
    than that cannot be told from a compressed flat stretch and is bridged by
    a straight line; historians normally mark outages with a digital state
    (``I/O Timeout``, ``Shutdown``), which always splits. With fewer than 20
    intervals the median rule is used.
    """
    v = np.asarray(value, dtype=float)
    ok = ~np.isnan(v)
    d = np.diff(np.asarray(ts_us, dtype=np.int64))[ok[1:] & ok[:-1]] / _US
    d = d[d > 0]
    floor = MAX_GAP_FACTOR * sample_time if sample_time and np.isfinite(sample_time) else 0.0
    if d.size == 0:
        return floor if floor > 0 else float("nan")
    med = float(np.median(d))
    gap = MAX_GAP_FACTOR * med
    if d.size >= 20 and np.mean(d > REGULAR_SPREAD * med) > IRREGULAR_SHARE:
        gap = max(gap, COMPRESSED_GAP_FACTOR * float(np.percentile(d, 99)))
    return max(gap, floor)


def contiguous_segments(mask: np.ndarray) -> tuple[tuple[int, int], ...]:
    """``(start, stop)`` index pairs of the runs of True in ``mask`` (stop exclusive)."""
    m = np.concatenate(([False], np.asarray(mask, bool), [False]))
    edges = np.flatnonzero(m[1:] != m[:-1])
    return tuple((int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]))


def _interpolate(grid: np.ndarray, ts: np.ndarray, value: np.ndarray, max_gap_us: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation between consecutive good samples; never across bad or long gaps."""
    good = ~np.isnan(value)
    tg, vg, tb = ts[good], value[good], ts[~good]
    out = np.full(grid.size, np.nan)
    if tg.size == 0:
        return out, np.zeros(grid.size, bool)
    i = np.searchsorted(tg, grid, side="right") - 1
    inside = i >= 0
    ic = np.clip(i, 0, tg.size - 1)
    exact = inside & (tg[ic] == grid)
    if tg.size > 1:
        span = np.diff(tg)
        bad_between = (np.searchsorted(tb, tg[1:], side="left")
                       - np.searchsorted(tb, tg[:-1], side="right"))
        ok_interval = (span <= max_gap_us) & (bad_between == 0)
        j = np.clip(i, 0, tg.size - 2)
        interior = inside & (i < tg.size - 1) & ok_interval[j] & ~exact
        frac = (grid[interior] - tg[j[interior]]) / span[j[interior]]
        out[interior] = vg[j[interior]] + frac * (vg[j[interior] + 1] - vg[j[interior]])
    else:
        interior = np.zeros(grid.size, bool)
    out[exact] = vg[ic[exact]]
    return out, exact | interior


def _hold(grid: np.ndarray, ts: np.ndarray, value: np.ndarray, good: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order hold of the last sample; invalid after a bad one and before the first."""
    i = np.searchsorted(ts, grid, side="right") - 1
    ok = i >= 0
    ic = np.clip(i, 0, max(ts.size - 1, 0))
    if ts.size:
        ok &= good[ic]
    out = value[ic] if ts.size else np.full(grid.size, np.nan)
    out = np.array(out, copy=True)
    if out.dtype == object:
        out[~ok] = None
    else:
        out[~ok] = np.nan
    return out, ok


def align_loop(frames: Mapping[str, pl.DataFrame], *, sample_time: float | None = None,
               max_gap: float | None = None, start: dt.datetime | None = None,
               end: dt.datetime | None = None) -> AlignedLoop:
    """Align a loop's tags on a uniform time grid.

    Parameters
    ----------
    frames : mapping of str to polars.DataFrame
        Role (``pv`` required; ``op``, ``sp``, ``mv``, ``mode`` optional) ->
        samples with columns ``ts`` (datetime; naive is taken as UTC),
        ``value`` (float, null = bad sample) and optionally ``status``. This is
        what :meth:`valvediag.store.Store.fetch_loop` returns.
    sample_time : float, optional
        Grid spacing [s]. Default: median spacing of the PV time stamps, which
        is robust to occasional gaps and to compression.
    max_gap : float, optional
        Longest interval between two good samples that is interpolated across,
        for every analog role [s]. Default: per tag, :func:`tag_max_gap` (five
        times the tag's median spacing; for a compressed tag at least five
        times the 99th percentile of its spacings).
    start, end : datetime, optional
        Grid extent (timezone-aware). Default: first and last PV time stamp.

    Returns
    -------
    AlignedLoop

    Raises
    ------
    ValueError
        No ``pv`` frame, an unknown role, a non-positive sample time, or a grid
        larger than :data:`MAX_GRID_POINTS`.

    Notes
    -----
    * A PV with fewer than two time stamps (and no ``sample_time``) gives an
      empty grid; the quality screen then reports "no PV data".
    * The mode tag's samples are held as text: the status text when the value
      is NULL (``MAN``, ``AUTO``...), else the number formatted as text.
    * Gaps are judged per tag against its own spacing (:func:`tag_max_gap`),
      so a compressed PV is bridged across its usual long spacings while a
      regularly sampled OP still splits at a few missing samples. A bad-state
      row always splits. Pass ``max_gap`` to impose one limit on all tags.
    * SP and mode are held for any length of time (exception reporting);
      :meth:`Store.fetch_loop` includes their last sample before the window.
    """
    unknown = set(frames) - set(_LINEAR_ROLES) - set(_HELD_ROLES)
    if unknown:
        raise ValueError(f"unknown roles {sorted(unknown)}; expected pv, op, sp, mv, mode")
    if "pv" not in frames:
        raise ValueError("align_loop needs a 'pv' frame")
    prepared = {role: _prepare(f, role) for role, f in frames.items()}
    pv_us = to_epoch_us(prepared["pv"]["ts"])
    if sample_time is None:
        sample_time = median_spacing(pv_us)
    if sample_time is not None and not np.isnan(sample_time) and sample_time <= 0:
        raise ValueError(f"sample_time must be positive, got {sample_time}")
    fixed_gap = None if max_gap is None else float(max_gap)

    t0 = _datetime_us(start, "start") if start else (int(pv_us[0]) if pv_us.size else None)
    t1 = _datetime_us(end, "end") if end else (int(pv_us[-1]) if pv_us.size else None)
    dt_us = None if np.isnan(sample_time) else max(int(round(sample_time * _US)), 1)
    if t0 is None or t1 is None or dt_us is None or t1 < t0:
        n = 0
        t0 = t0 or 0
        dt_us = dt_us or 1
    else:
        n = (t1 - t0) // dt_us + 1
    if n > MAX_GRID_POINTS:
        raise ValueError(f"grid of {n:,} points is too large (sample time {sample_time} s over "
                         f"{(t1 - t0) / _US:.0f} s); pass a larger sample_time or a shorter window")
    grid = t0 + np.arange(n, dtype=np.int64) * dt_us

    signals: dict[str, np.ndarray] = {}
    role_valid: dict[str, np.ndarray] = {}
    max_gaps: dict[str, float] = {}
    st = float(sample_time) if sample_time is not None and np.isfinite(sample_time) else 0.0
    for role, f in prepared.items():
        ts = to_epoch_us(f["ts"])
        if role in _LINEAR_ROLES:
            value = f["value"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            gap = fixed_gap if fixed_gap is not None else tag_max_gap(ts, value, st)
            max_gaps[role] = gap
            gap_us = (int(round(gap * _US)) if np.isfinite(gap) and gap < 1e12
                      else np.iinfo(np.int64).max)
            signals[role], role_valid[role] = _interpolate(grid, ts, value, gap_us)
        elif role == "sp":
            value = f["value"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            signals[role], role_valid[role] = _hold(grid, ts, value, ~np.isnan(value))
        else:  # mode: text
            text = f.select(pl.coalesce(pl.col("status"), pl.col("value").cast(pl.String)))
            text = np.asarray(text.to_series().to_list(), dtype=object)
            good = np.array([x is not None for x in text], bool)
            signals[role], role_valid[role] = _hold(grid, ts, text, good)

    valid = role_valid["pv"].copy()
    if "op" in role_valid:
        valid &= role_valid["op"]
    start_dt = dt.datetime.fromtimestamp(t0 / _US, dt.timezone.utc) if n else None
    return AlignedLoop(
        t=(grid - t0) / _US, time=grid.astype("datetime64[us]"), pv=signals["pv"],
        op=signals.get("op"), sp=signals.get("sp"), mv=signals.get("mv"),
        mode=signals.get("mode"), valid=valid, segments=contiguous_segments(valid),
        sample_time=float(sample_time), max_gap=float(max_gaps.get("pv", float("nan"))),
        start=start_dt, role_valid=role_valid, max_gaps=max_gaps)
