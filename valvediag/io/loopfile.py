"""
Reader for single-loop CSV files, the input of every single-loop command.

A single-loop CSV has a header row and the columns ``timestamp,pv,op`` with
``sp`` and ``mv`` optional::

    timestamp,pv,op,sp
    2026-11-01T00:00:00+00:00,51.2,40.1,50.0
    2026-11-01T00:00:01+00:00,51.3,40.0,50.0

The timestamp is ISO 8601 (a UTC offset is honoured; a naive time is read as
UTC) or a number of seconds. Other column names are mapped with ``columns``.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from ..plain import printable

__all__ = ["LoopRecord", "read_loop_csv", "LoopFileError"]

ROLES = ("timestamp", "pv", "op", "sp", "mv")
#: Header aliases accepted without a mapping (case-insensitive).
ALIASES = {"timestamp": ("timestamp", "time", "ts", "datetime", "date"),
           "pv": ("pv",), "op": ("op", "out", "co"), "sp": ("sp",), "mv": ("mv", "position")}
#: A spacing longer than this many median spacings is a gap (not bridged).
GAP_FACTOR = 5.0
#: Most points of the uniform grid an irregular file is resampled onto [-]
#: (a year at 1 s is 31.5 million).
MAX_GRID_POINTS = 40_000_000


class LoopFileError(ValueError):
    """A single-loop file that cannot be read; the message names the file
    and the problem in one line.

    Characters of the message that are not printable (line breaks, form
    feeds and other controls, from the file's header or cells) are shown
    escaped, e.g. ``\\x0c``, so that the message stays one line.
    """

    def __init__(self, message: str):
        super().__init__(printable(message))


@dataclass(frozen=True)
class LoopRecord:
    """One loop's data on a uniform time grid.

    Attributes
    ----------
    t : numpy.ndarray
        Time since the first sample [s].
    pv, op : numpy.ndarray
        Process variable and controller output; NaN where a value was missing,
        not numeric or inside a gap.
    sp, mv : numpy.ndarray or None
        Set point (held between samples) and valve position, if present.
    sample_time : float
        Grid spacing [s] (the median spacing of the file).
    """

    t: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    sp: np.ndarray | None
    mv: np.ndarray | None
    sample_time: float


def _pick_columns(header, columns, path):
    lower = {h.strip().lower(): h for h in header}
    out = {}
    for role in ROLES:
        if columns and columns.get(role):
            name = columns[role]
            if name not in header and name.lower() not in lower:
                raise LoopFileError(f"{path}: no column {name!r} for {role} (columns: {', '.join(header)})")
            out[role] = name if name in header else lower[name.lower()]
            continue
        for alias in ALIASES[role]:
            if alias in lower:
                out[role] = lower[alias]
                break
    missing = [r for r in ("timestamp", "pv", "op") if r not in out]
    if missing:
        raise LoopFileError(f"{path}: missing column(s) {', '.join(missing)} (columns: {', '.join(header)}); "
                            "name them timestamp,pv,op or map them with the column options")
    return out


def _ragged_line(path: Path) -> str | None:
    """``'line N has K fields, the header M'`` for the first row whose field
    count differs from the header's, or None (the file is not ragged, or
    cannot be read as text)."""
    try:
        with open(path, newline="", encoding="utf-8", errors="replace") as fh:
            rows = csv.reader(fh)
            width = len(next(rows, []))
            for row in rows:
                if row and len(row) != width:
                    return (f"line {rows.line_num} has {len(row)} fields, the header "
                            f"{width}")
    except (OSError, csv.Error):
        return None
    return None


def _seconds(col: pl.Series, path) -> np.ndarray:
    """Timestamps to seconds since the epoch; ISO 8601 text or numbers."""
    if col.dtype.is_numeric():
        return col.cast(pl.Float64).to_numpy()
    s = col.cast(pl.Utf8).str.strip_chars()
    num = s.cast(pl.Float64, strict=False)
    if num.null_count() == s.null_count():
        return num.to_numpy()
    if 2 * (s.len() - num.null_count()) >= s.len() - s.null_count():
        # mostly epoch seconds: the odd one out is the value at fault
        i = int(np.flatnonzero((num.is_null() & s.is_not_null()).to_numpy())[0])
        j = int(np.flatnonzero(num.is_not_null().to_numpy())[0])
        raise LoopFileError(f"{path}: line {i + 2}: timestamp {s[i]!r} is not a number of "
                            f"seconds like the others (line {j + 2}: {s[j]!r})")
    parsed = s.str.to_datetime(time_unit="us", time_zone="UTC", strict=False)
    bad = parsed.is_null() & s.is_not_null()
    if bad.any():
        i = int(np.flatnonzero(bad.to_numpy())[0])
        # polars infers one format for the column: a valid value in another form (with an
        # offset where the first had none, or the reverse) fails only because of the mix
        alone = pl.Series([s[i]]).str.to_datetime(time_unit="us", time_zone="UTC", strict=False)
        if alone.null_count() == 0:
            first = int(np.flatnonzero(parsed.is_not_null().to_numpy())[0]) \
                if parsed.is_not_null().any() else 0
            raise LoopFileError(
                f"{path}: line {i + 2}: timestamp {s[i]!r} is written differently from line "
                f"{first + 2} ({s[first]!r}): time stamps with and without a UTC offset "
                f"(or in two formats) are mixed; write them all one way")
        raise LoopFileError(f"{path}: line {i + 2}: timestamp {s[i]!r} is neither ISO 8601 nor seconds")
    return parsed.dt.epoch("us").cast(pl.Float64).to_numpy() / 1e6


def read_loop_csv(path, *, columns: dict | None = None):
    """Read a single-loop CSV onto a uniform grid.

    Parameters
    ----------
    path : str or path-like
        The file.
    columns : dict, optional
        Map of role (``timestamp``, ``pv``, ``op``, ``sp``, ``mv``) to the
        file's column name, for files with other headers.

    Returns
    -------
    data : LoopRecord
    metadata : dict
        ``file``, ``rows``, ``non_numeric`` (values that were not numbers,
        e.g. historian states, per column), ``gaps`` (spacings longer than
        five median spacings), ``duplicates_dropped``, ``resampled`` (True
        when the file was not uniformly sampled).

    Raises
    ------
    LoopFileError
        Missing file or columns, an empty file, unreadable or infinite
        timestamps, time running backwards, duplicate timestamps with
        different values, or a span too long to resample (more than
        :data:`MAX_GRID_POINTS` median spacings); the message names the file
        and, where it applies, the line.

    Notes
    -----
    Irregular files (historian compression) are interpolated linearly onto
    the median spacing for PV, OP and MV, and held for SP; a spacing longer
    than ``GAP_FACTOR`` median spacings is a gap and stays NaN.
    """
    path = Path(path)
    if not path.is_file():
        raise LoopFileError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise LoopFileError(f"{path}: the file is empty")
    try:
        df = pl.read_csv(path, infer_schema=False, truncate_ragged_lines=False)
    except Exception as exc:   # polars raises several error types for malformed CSV
        raise LoopFileError(f"{path}: {_ragged_line(path) or 'not a readable CSV'} "
                            f"({str(exc).splitlines()[0]})") from None
    if df.height == 0:
        raise LoopFileError(f"{path}: the file has a header but no rows")
    cols = _pick_columns(df.columns, columns, path)
    t = _seconds(df[cols["timestamp"]], path)
    if np.isnan(t).any():
        i = int(np.flatnonzero(np.isnan(t))[0])
        raise LoopFileError(f"{path}: line {i + 2}: empty timestamp")
    if not np.isfinite(t).all():
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        raise LoopFileError(f"{path}: line {i + 2}: timestamp {df[cols['timestamp']][i]!r} "
                            f"is not a finite time")
    meta = {"file": str(path), "rows": df.height, "non_numeric": {}, "duplicates_dropped": 0}
    vals = {}
    for role in ("pv", "op", "sp", "mv"):
        if role not in cols:
            continue
        s = df[cols[role]].cast(pl.Utf8).str.strip_chars()
        num = s.cast(pl.Float64, strict=False)
        bad = int((num.is_null() & s.is_not_null() & (s != "")).sum())
        if bad:
            meta["non_numeric"][role] = bad
        vals[role] = num.fill_nan(None).to_numpy().astype(float)
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    if back.size:
        i = int(back[0])
        raise LoopFileError(f"{path}: line {i + 3}: time runs backwards "
                            f"({df[cols['timestamp']][i]} then {df[cols['timestamp']][i + 1]})")
    dup = np.flatnonzero(dt == 0)
    if dup.size:
        for i in map(int, dup):
            for role, v in vals.items():
                a, b = v[i], v[i + 1]
                if not (a == b or (np.isnan(a) and np.isnan(b))):
                    raise LoopFileError(f"{path}: line {i + 3}: duplicate timestamp "
                                        f"{df[cols['timestamp']][i]} with a different {role} value")
        keep = np.ones(t.size, bool)
        keep[dup + 1] = False
        t = t[keep]
        vals = {k: v[keep] for k, v in vals.items()}
        meta["duplicates_dropped"] = int(dup.size)
    if t.size < 2:
        raise LoopFileError(f"{path}: only {t.size} distinct timestamp(s)")
    dt = np.diff(t)
    h = float(np.median(dt))
    gap_after = dt > GAP_FACTOR * h
    meta["gaps"] = int(gap_after.sum())
    uniform = np.all(np.abs(dt - h) <= 1e-6 * max(h, 1.0))
    meta["resampled"] = not uniform
    if uniform:
        grid = t - t[0]
        out = {k: v for k, v in vals.items()}
    else:
        span = (t[-1] - t[0]) / h
        if not span < MAX_GRID_POINTS:
            raise LoopFileError(f"{path}: the record spans {t[-1] - t[0]:.6g} s, "
                                f"{span:.3g} times its median spacing of {h:.6g} s; resampling "
                                f"it would take more than {MAX_GRID_POINTS:,} points (a wrong "
                                f"timestamp, or mixed time units?)")
        n = int(np.floor(span + 1e-9)) + 1
        grid = np.arange(n) * h
        tt = t - t[0]
        seg = np.searchsorted(tt, grid, side="right") - 1        # sample at or before each grid point
        seg = np.clip(seg, 0, tt.size - 1)
        in_gap = np.r_[gap_after, False][seg] & (grid > tt[seg] + 1e-9)
        out = {}
        for role, v in vals.items():
            if role == "sp":
                g = v[seg]
            else:
                ok = ~np.isnan(v)
                g = np.interp(grid, tt[ok], v[ok]) if ok.sum() >= 2 else np.full(n, np.nan)
                # no interpolation across a missing value either
                nxt = np.clip(seg + 1, 0, tt.size - 1)
                g[~ok[seg] | (~ok[nxt] & (grid > tt[seg] + 1e-9))] = np.nan
            g = g.astype(float)
            g[in_gap] = np.nan
            out[role] = g
    data = LoopRecord(t=np.asarray(grid, float), pv=out["pv"], op=out["op"], sp=out.get("sp"),
                      mv=out.get("mv"), sample_time=h)
    return data, meta
