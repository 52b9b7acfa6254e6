"""
The evidence figure of a loop drawn straight as SVG text, without matplotlib.

:func:`loop_svg` draws the five panels of a loop's evidence (trend, OP,
zoom on a few cycles, phase plot, Backlash Index per half cycle, the
swing's timing against a clock, or mean cycle) as the report's matplotlib
figures did, with the same titles, colours, line widths and layout
(matplotlib's grid of the panels, its default 5 % margins and tick choice),
but writes the SVG elements itself: a figure costs a few milliseconds
instead of the ~0.5 s of matplotlib's artist, tick and text machinery,
which made the figures nearly all of a plant report's cost (450 figures:
~4 min on 2 cores).

Notes
-----
* Coordinates are integers in tenths of a CSS pixel (the ``viewBox`` is ten
  times the figure's size), formatted from numpy arrays in one pass; a line
  is one ``<path>`` with relative moves, a series of markers one ``<path>``.
* Output depends only on the data and the id prefix: no dates, no versions,
  no hash of anything, so the same data give the same bytes in any process.
* Every text from the data (the unit) is XML-escaped. Data lines are
  clipped to their panel (``clipPath`` ids carry the prefix).
* Tick positions come from :class:`matplotlib.ticker.MaxNLocator` and the
  time axis of the trend from :class:`matplotlib.dates.AutoDateLocator` with
  :class:`matplotlib.dates.ConciseDateFormatter` (pure computations, no
  figure), so the ticks are the ones matplotlib would choose.
"""
from __future__ import annotations

import datetime as dt
import math

import numpy as np
from markupsafe import escape

from ..analysis.bi import ANGLE_UNIT
from .explain import read_from_events, swings_regularly

__all__ = ["loop_svg", "WIDTH", "HEIGHT"]

#: Size of the figure [CSS px] (10 x 6.8 in at 72 dpi, as the matplotlib figure).
WIDTH, HEIGHT = 720.0, 489.6
_S = 10                       # coordinate units per px
_FONT = "DejaVu Sans, Verdana, sans-serif"
_C0, _C2, _C3 = "#1f77b4", "#2ca02c", "#d62728"
_TICK = 3.5                   # tick length and label pad [px]


def _grey(level: float) -> str:
    v = int(round(level * 255))
    return f"#{v:02x}{v:02x}{v:02x}"


def _i(v: float) -> int:
    return int(round(float(v) * _S))


def _tw(text: str, size: float) -> float:
    """Estimated width of a text in DejaVu Sans [px]."""
    return len(text) * size * 0.6


def _grid(nrows, ncols, height_ratios, hspace, wspace, left, right, top, bottom):
    """Panel edges like matplotlib's GridSpec: (tops, bottoms, lefts, rights) in figure fractions."""
    cell_h = (top - bottom) / (nrows + hspace * (nrows - 1))
    norm = cell_h * nrows / sum(height_ratios)
    hs = np.column_stack([[0] + [hspace * cell_h] * (nrows - 1),
                          [r * norm for r in height_ratios]]).ravel()
    cs = np.cumsum(hs)
    tops, bottoms = top - cs[0::2], top - cs[1::2]
    cell_w = (right - left) / (ncols + wspace * (ncols - 1))
    ws = np.column_stack([[0] + [wspace * cell_w] * (ncols - 1), [cell_w] * ncols]).ravel()
    cw = np.cumsum(ws)
    return tops, bottoms, left + cw[0::2], left + cw[1::2]


def _decimals(values) -> int:
    for d in range(8):
        if all(abs(round(v, d) - v) <= 1e-9 * max(1.0, abs(v)) for v in values):
            return d
    return 8


def _num_labels(ticks) -> list[str]:
    d = _decimals(ticks)
    out = []
    for v in ticks:
        s = f"{v:.{d}f}"
        out.append(s[1:] if s.startswith("-") and s.strip("-0.") == "" else s)
    return out


def _nice_ticks(lo: float, hi: float, n: int) -> np.ndarray:
    from matplotlib.ticker import MaxNLocator

    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([])
    t = MaxNLocator(n).tick_values(lo, hi)
    eps = (hi - lo) * 1e-10
    return t[(t >= lo - eps) & (t <= hi + eps)]


def _limits(lo: float, hi: float, margin: float = 0.05) -> tuple[float, float]:
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return 0.0, 1.0
    if hi == lo:
        d = abs(lo) * 0.05 if lo else 0.05     # matplotlib's expansion of a flat range
        return lo - d, hi + d
    m = (hi - lo) * margin
    return lo - m, hi + m


class _Panel:
    """One axes of the figure: data items and their scales, drawn on :meth:`svg`.

    Parameters
    ----------
    box : (float, float, float, float)
        Left, top, right, bottom [px].
    """

    def __init__(self, box):
        self.x0, self.y0, self.x1, self.y1 = box
        self.items: list = []
        self.xlim: tuple[float, float] | None = None
        self.ylim: tuple[float, float] | None = None
        self._dx = [math.inf, -math.inf]
        self._dy = [math.inf, -math.inf]
        self.title = ""
        self.xlabel = self.ylabel = ""
        self.xticks_n: int | None = 5            # None: no x ticks
        self.yticks_n = 3
        self.xfmt = None                         # callable(values) -> labels
        self.xticks_fn = None                    # callable(lo, hi) -> tick values
        self.off = False
        self.twin: _Panel | None = None          # right axis (same box)
        self.right = False
        self.legend: list[tuple[str, dict]] = []

    # ------------------------------------------------------------------ data
    def _extent(self, x, y):
        for arr, acc in ((x, self._dx), (y, self._dy)):
            if arr is None:
                continue
            a = np.asarray(arr, dtype=float)
            a = a[np.isfinite(a)]
            if a.size:
                acc[0] = min(acc[0], float(a.min()))
                acc[1] = max(acc[1], float(a.max()))

    def line(self, x, y, colour, lw, dash=None, alpha=None, label=None):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        self._extent(x, y)
        self.items.append(("line", x, y, colour, lw, dash, alpha))
        if label:
            self.legend.append((label, {"kind": "line", "colour": colour, "lw": lw,
                                        "dash": dash}))

    def markers(self, x, y, shape, colour, size, hollow=False, label=None):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        self._extent(x, y)
        self.items.append(("markers", x, y, shape, colour, size, hollow))
        if label:
            self.legend.append((label, {"kind": "markers", "shape": shape, "colour": colour,
                                        "size": size, "hollow": hollow}))

    def xspan(self, a, b, fill):
        self._extent([a, b], None)
        self.items.append(("xspan", float(a), float(b), fill))

    def yspan(self, a, b, fill):
        self.items.append(("yspan", float(a), float(b), fill))

    def hline(self, y, colour, lw, dash=None):
        self.items.append(("hline", float(y), colour, lw, dash))

    def text_at(self, xfrac, y, text, colour, size=6.5):
        """Text at ``xfrac`` of the width and data height ``y``, vertically centred."""
        self.items.append(("text", float(xfrac), float(y), text, colour, size))

    def blank(self, text):
        self.off = True
        self.items.append(("centre", text))

    # ------------------------------------------------------------------ scales
    def limits(self):
        xl = self.xlim or _limits(*self._dx)
        yl = self.ylim or _limits(*self._dy)
        return xl, yl

    def _sx(self, x, xl):
        return self.x0 + (x - xl[0]) / (xl[1] - xl[0]) * (self.x1 - self.x0)

    def _sy(self, y, yl):
        return self.y1 - (y - yl[0]) / (yl[1] - yl[0]) * (self.y1 - self.y0)

    # ------------------------------------------------------------------ drawing
    def svg(self, clip_id: str) -> list[str]:
        out: list[str] = []
        if self.off:
            for it in self.items:
                if it[0] == "centre":
                    out.append(_text((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2, it[1],
                                     7.5, anchor="middle", colour=_grey(0.4), middle=True))
            return out
        xl, yl = self.limits()
        body = [f'<clipPath id="{clip_id}"><rect x="{_i(self.x0)}" y="{_i(self.y0)}" '
                f'width="{_i(self.x1 - self.x0)}" height="{_i(self.y1 - self.y0)}"/></clipPath>',
                f'<g clip-path="url(#{clip_id})">']
        texts = []
        for it in self.items:
            kind = it[0]
            if kind == "xspan":
                a, b = sorted((self._sx(it[1], xl), self._sx(it[2], xl)))
                body.append(f'<rect x="{_i(a)}" y="{_i(self.y0)}" width="{max(_i(b) - _i(a), 1)}" '
                            f'height="{_i(self.y1 - self.y0)}" fill="{it[3]}"/>')
            elif kind == "yspan":
                a, b = sorted((self._sy(it[1], yl), self._sy(it[2], yl)))
                body.append(f'<rect x="{_i(self.x0)}" y="{_i(a)}" width="{_i(self.x1 - self.x0)}" '
                            f'height="{max(_i(b) - _i(a), 1)}" fill="{it[3]}"/>')
            elif kind == "hline":
                if math.isfinite(it[1]):
                    y = _i(self._sy(it[1], yl))
                    body.append(f'<path d="M{_i(self.x0)} {y}H{_i(self.x1)}" '
                                f'{_stroke(it[2], it[3], it[4])}/>')
            elif kind == "line":
                d = _polyline(self._sx(it[1], xl), self._sy(it[2], yl))
                if d:
                    op = f' stroke-opacity="{it[6]:g}"' if it[6] is not None else ""
                    body.append(f'<path d="{d}" {_stroke(it[3], it[4], it[5])}'
                                f' stroke-linejoin="round"{op}/>')
            elif kind == "markers":
                d = _marker_path(self._sx(it[1], xl), self._sy(it[2], yl), it[3], it[5])
                if d:
                    body.append(f'<path d="{d}" {_marker_paint(it[4], it[6])}/>')
            elif kind == "text":
                y = self._sy(it[2], yl)
                x = self.x0 + it[1] * (self.x1 - self.x0)
                texts.append(_text(x, y, it[3], it[5], colour=it[4], middle=True))
        body.append("</g>")
        out += body + texts
        out.append(f'<rect x="{_i(self.x0)}" y="{_i(self.y0)}" width="{_i(self.x1 - self.x0)}" '
                   f'height="{_i(self.y1 - self.y0)}" fill="none" stroke="#000" '
                   f'stroke-width="{_i(0.6)}"/>')
        out += self._yaxis(yl, right=self.right)
        out += self._xaxis(xl)
        if self.title:
            out.append(_text(self.x0, self.y0 - 4 - 2, self.title, 8.5, bold=True))
        if self.legend:
            out += self._legend()
        return out

    def _yaxis(self, yl, right=False) -> list[str]:
        out = []
        ticks = _nice_ticks(yl[0], yl[1], self.yticks_n)
        labels = _num_labels(ticks)
        x = self.x1 if right else self.x0
        sgn = 1 if right else -1
        d = "".join(f"M{_i(x)} {_i(self._sy(v, yl))}h{_i(sgn * _TICK)}" for v in ticks)
        if d:
            out.append(f'<path d="{d}" stroke="#000" stroke-width="{_i(0.8)}"/>')
        width = 0.0
        for v, s in zip(ticks, labels):
            out.append(_text(x + sgn * 2 * _TICK, self._sy(v, yl), s, 7,
                             anchor="start" if right else "end", middle=True))
            width = max(width, _tw(s, 7))
        if self.ylabel:      # read bottom to top on both sides, as matplotlib does
            lx = x + sgn * (2 * _TICK + width + 3) + (7.5 if right else 0)
            out.append(_text(lx, (self.y0 + self.y1) / 2, self.ylabel, 7.5, anchor="middle",
                             rotate=-90))
        return out

    def _xaxis(self, xl) -> list[str]:
        out = []
        below = self.y1
        if self.xticks_n is not None:
            ticks = (self.xticks_fn(*xl) if self.xticks_fn is not None
                     else _nice_ticks(xl[0], xl[1], self.xticks_n))
            labels = self.xfmt(ticks) if self.xfmt is not None else _num_labels(ticks)
            d = "".join(f"M{_i(self._sx(v, xl))} {_i(self.y1)}v{_i(_TICK)}" for v in ticks)
            if d:
                out.append(f'<path d="{d}" stroke="#000" stroke-width="{_i(0.8)}"/>')
            for v, s in zip(ticks, labels):
                out.append(_text(self._sx(v, xl), self.y1 + 2 * _TICK + 6, s, 7,
                                 anchor="middle"))
            below = self.y1 + 2 * _TICK + 7
        if self.xlabel:
            out.append(_text((self.x0 + self.x1) / 2, below + 9.5, self.xlabel, 7.5,
                             anchor="middle"))
        return out

    def _legend(self) -> list[str]:
        fs, row = 6.5, 9.0
        w = max(_tw(t, fs) for t, _ in self.legend) + 30
        h = row * len(self.legend) + 5
        x, y = self.x1 - 4 - w, self.y0 + 4
        out = [f'<rect x="{_i(x)}" y="{_i(y)}" width="{_i(w)}" height="{_i(h)}" fill="#fff" '
               f'fill-opacity="0.8" stroke="#ccc" stroke-width="{_i(0.8)}" rx="{_i(2)}"/>']
        for k, (label, spec) in enumerate(self.legend):
            cy = y + 2.5 + row * (k + 0.5)
            if spec["kind"] == "line":
                out.append(f'<path d="M{_i(x + 5)} {_i(cy)}h{_i(16)}" '
                           f'{_stroke(spec["colour"], spec["lw"], spec["dash"])}/>')
            else:
                d = _marker_path(np.array([x + 13.0]), np.array([cy]), spec["shape"],
                                 spec["size"])
                out.append(f'<path d="{d}" {_marker_paint(spec["colour"], spec["hollow"])}/>')
            out.append(_text(x + 25, cy, label, fs, middle=True))
        return out


def _text(x, y, text, size, *, anchor="start", colour=None, bold=False, middle=False,
          rotate=None) -> str:
    attrs = f'x="{_i(x)}" y="{_i(y)}" font-size="{_i(size)}"'
    if anchor != "start":
        attrs += f' text-anchor="{anchor}"'
    if middle:
        attrs += ' dominant-baseline="central"'
    if colour:
        attrs += f' fill="{colour}"'
    if bold:
        attrs += ' font-weight="bold"'
    if rotate:
        attrs += f' transform="rotate({rotate} {_i(x)} {_i(y)})"'
    return f"<text {attrs}>{escape(text)}</text>"


def _stroke(colour, lw, dash=None) -> str:
    s = f'fill="none" stroke="{colour}" stroke-width="{_i(lw)}"'
    if dash:
        s += f' stroke-dasharray="{" ".join(str(_i(d * lw)) for d in dash)}"'
    return s


def _marker_paint(colour, hollow) -> str:
    if hollow:
        return f'fill="none" stroke="{colour}" stroke-width="{_i(1.0)}"'
    return f'fill="{colour}" stroke="{colour}" stroke-width="{_i(1.0)}"'


_DASHED = (3.7, 1.6)          # matplotlib's "--" per unit of line width


def _polyline(px, py) -> str:
    """Path data of a line through the points; NaN breaks it (tenths of px, relative moves)."""
    ok = np.isfinite(px) & np.isfinite(py)
    if ok.sum() < 2:
        return ""
    X = np.zeros(px.size, dtype=np.int64)
    Y = np.zeros(py.size, dtype=np.int64)
    X[ok] = np.rint(px[ok] * _S)
    Y[ok] = np.rint(py[ok] * _S)
    edges = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
    parts = []
    for a, b in zip(edges[0::2], edges[1::2]):
        if b - a < 2:
            continue
        d = np.empty(2 * (b - a - 1), dtype=np.int64)
        d[0::2] = np.diff(X[a:b])
        d[1::2] = np.diff(Y[a:b])
        parts.append(f"M{X[a]} {Y[a]}l" + " ".join(map(str, d.tolist())))
    return "".join(parts)


def _marker_path(px, py, shape, size) -> str:
    """Path data of one marker per finite point: ``'v'``, ``'^'`` or ``'o'`` of ``size`` [pt]."""
    ok = np.isfinite(px) & np.isfinite(py)
    X = np.rint(px[ok] * _S).astype(np.int64).tolist()
    Y = np.rint(py[ok] * _S).astype(np.int64).tolist()
    r = size / 2 * _S
    if shape == "o":
        ri = int(round(r))
        return "".join(f"M{x - ri} {y}a{ri} {ri} 0 1 0 {2 * ri} 0a{ri} {ri} 0 1 0 {-2 * ri} 0"
                       for x, y in zip(X, Y))
    ri = int(round(r))
    if shape == "v":
        return "".join(f"M{x - ri} {y - ri}h{2 * ri}l{-ri} {2 * ri}z" for x, y in zip(X, Y))
    return "".join(f"M{x - ri} {y + ri}h{2 * ri}l{-ri} {-2 * ri}z" for x, y in zip(X, Y))


# ------------------------------------------------------------------------- the figure

def _date_axis(panel: _Panel, start: dt.datetime):
    """Ticks and labels of a time axis in seconds since ``start``, as matplotlib would choose."""
    import matplotlib.dates as mdates

    t0 = mdates.date2num(start)
    loc = mdates.AutoDateLocator(minticks=3, maxticks=7)
    fmt = mdates.ConciseDateFormatter(loc, show_offset=False)

    def ticks(lo, hi):
        a = start + dt.timedelta(seconds=float(lo))
        b = start + dt.timedelta(seconds=float(hi))
        v = np.asarray(loc.tick_values(a, b), dtype=float)
        s = (v - t0) * 86400.0
        keep = (s >= lo - 1e-6) & (s <= hi + 1e-6)
        panel._datenums = v[keep]
        return s[keep]

    panel.xticks_fn = ticks
    panel.xfmt = lambda _v: list(fmt.format_ticks(panel._datenums))


def _clock_axis(panel: _Panel, start: dt.datetime | None, seconds: bool):
    f = _clock_label(start, seconds)
    panel.xfmt = lambda v: [f(x) for x in v]


# ----------------------------------------------------------------- evidence windows
def _clock_label(start: dt.datetime | None, seconds: bool = False):
    """Tick label of seconds since ``start``: UTC clock time, or minutes without a start."""
    if start is None:
        return lambda x: f"{x / 60:.0f} min"
    fmt = "%H:%M:%S" if seconds else "%H:%M"
    return lambda x: (start + dt.timedelta(seconds=float(x))).strftime(fmt)


def _zoom_span(n: int, period_samples: float, cycles: float) -> tuple[int, int]:
    if not (math.isfinite(period_samples) and period_samples > 0):
        return 0, n
    span = int(cycles * period_samples)
    c = n // 2
    return max(0, c - span // 2), min(n, c + span // 2)


def _evidence_window(bres, cycles: float) -> tuple[int, int]:
    """The stretch of ``cycles`` periods holding the most measured apices and middle points.

    The robust Backlash Index measures a sample of the apices spread over the
    record, so the middle of the record may show none; this picks the
    stretch where the evidence is (ties: the one nearest the middle).
    """
    n = bres.pv.size
    h = bres.sample_time
    if not (math.isfinite(bres.period) and bres.period > 0):
        return 0, n
    span = max(8, int(cycles * bres.period / h))
    if span >= n:
        return 0, n
    ai = bres.apex_indices
    thp = np.asarray(bres.theta_peak, dtype=float)
    thm = np.asarray(bres.theta_middle, dtype=float)
    marks = np.sort(np.r_[ai[:thp.size][np.isfinite(thp[:ai.size])],
                          np.asarray(bres.middle)[:thm.size][np.isfinite(thm[:len(bres.middle)])]])
    if marks.size == 0:
        c = n // 2
        return max(0, c - span // 2), min(n, c + span // 2)
    starts = np.clip(marks - span // 8, 0, n - span)
    counts = np.searchsorted(marks, starts + span) - np.searchsorted(marks, starts)
    best = counts.max()
    cand = starts[counts == best]
    lo = int(cand[np.argmin(np.abs(cand + span // 2 - n // 2))])
    return lo, lo + span


def _slice_backlash(bres, lo: int, hi: int):
    """The Backlash Index result restricted to samples ``[lo, hi)``, re-indexed from 0.

    Only what :meth:`valvediag.analysis.bi.BacklashIndex.plot` draws is kept
    consistent (record, apices with their angles, middle points with theirs).
    """
    import dataclasses

    ai = bres.apex_indices
    ai = np.asarray(ai)
    thp = np.asarray(bres.theta_peak, dtype=float)
    mid = np.asarray(bres.middle)
    thm = np.asarray(bres.theta_middle, dtype=float)
    ka = (ai >= lo) & (ai < hi)
    km = (mid >= lo) & (mid < hi)
    inr = lambda idx: np.asarray(idx)[(np.asarray(idx) >= lo) & (np.asarray(idx) < hi)] - lo
    thp_full = np.full(ai.size, np.nan)
    thp_full[:min(thp.size, ai.size)] = thp[:ai.size]
    thm_full = np.full(mid.size, np.nan)
    thm_full[:min(thm.size, mid.size)] = thm[:mid.size]
    return dataclasses.replace(bres, pv=bres.pv[lo:hi], peaks=inr(bres.peaks),
                               valleys=inr(bres.valleys), middle=mid[km] - lo,
                               theta_peak=thp_full[ka], theta_middle=thm_full[km],
                               apex_index=ai[ka] - lo)


def _highlight(result, detail) -> int | None:
    """Index of the episode holding the diagnosed data."""
    if detail.diagnosis_start is None:
        return None
    mid = detail.diagnosis_start + (detail.diagnosis_end - detail.diagnosis_start) / 2 \
        if detail.diagnosis_end is not None else detail.diagnosis_start
    for j, e in enumerate(result.episodes):
        if e.start <= mid < e.end:
            return j
    return None


def _trend(ax_t: _Panel, ax_o: _Panel, result, detail, highlight):
    trend = detail.trend
    t = np.asarray(trend.t, dtype=float)
    start = trend.start
    for j, e in enumerate(result.episodes):
        a = (e.start - start).total_seconds()
        b = (e.end - start).total_seconds()
        fill = "#f8c471" if j == highlight else "#fdf2e0"
        ax_t.xspan(a, b, fill)
        ax_o.xspan(a, b, fill)
    ax_t.line(t, trend.pv, "#1f5fa8", 0.7)
    if trend.sp is not None and np.isfinite(trend.sp).any():
        ax_t.line(t, trend.sp, "#000000", 0.9, dash=_DASHED)
    if trend.op is not None:
        ax_o.line(t, trend.op, "#d35400", 0.6)
    if t.size:
        ax_t.xlim = ax_o.xlim = (float(t[0]), float(t[-1])) if t[-1] > t[0] else \
            (float(t[0]) - 1, float(t[0]) + 1)
    ax_t.xticks_n = None
    ax_t.yticks_n, ax_o.yticks_n = 4, 2
    ax_o.ylabel = "OP [%]"
    _date_axis(ax_o, start)


def _zoom_bi(ax: _Panel, b):
    """PV of the evidence window with peaks, valleys, middle points and measured angles."""
    h = b.sample_time
    pv = np.asarray(b.pv, dtype=float)
    t = np.arange(pv.size) * h
    ax.line(t, pv, _grey(0.35), 0.8, label="PV")
    pk, vl, md = (np.asarray(i, dtype=int) for i in (b.peaks, b.valleys, b.middle))
    ax.markers(t[pk], pv[pk], "v", _C3, 6, label="peaks")
    ax.markers(t[vl], pv[vl], "^", _C2, 6, label="valleys")
    ax.markers(t[md], pv[md], "o", _C0, 4, hollow=True, label="middle points")
    if np.isfinite(b.period) and b.amplitude > 0:
        unit = 2 * b.amplitude / (b.period / ANGLE_UNIT)
        seg = 0.06 * b.period
        ai = np.asarray(b.apex_indices, dtype=int)
        thp = np.asarray(b.theta_peak, dtype=float)
        thm = np.asarray(b.theta_middle, dtype=float)
        med = float(np.median(pv)) if pv.size else 0.0
        xs3, xs2 = np.array([-seg, 0, seg]), np.array([-seg, seg])
        xa, ya, xm, ym = [], [], [], []
        for j, k in enumerate(ai):
            if not (0 <= k < pv.size) or j >= thp.size or not np.isfinite(thp[j]):
                continue
            slope = np.tan(np.radians(thp[j])) * unit
            s = 1 if pv[k] >= med else -1
            xa += [*(t[k] + xs3), np.nan]
            ya += [*(pv[k] - s * slope * np.abs(xs3)), np.nan]
        for j, c in enumerate(np.asarray(b.middle, dtype=int)):
            if not (0 <= c < pv.size) or j >= thm.size or not np.isfinite(thm[j]):
                continue
            slope = np.tan(np.radians(thm[j])) * unit
            d = np.sign(pv[min(c + 1, pv.size - 1)] - pv[max(c - 1, 0)]) or 1
            xm += [*(t[c] + xs2), np.nan]
            ym += [*(pv[c] + d * slope * xs2), np.nan]
        if xa:
            ax.line(xa, ya, _C3, 1.6, alpha=0.8)
        if xm:
            ax.line(xm, ym, _C0, 1.6, alpha=0.8)


def _zoom_linear(ax: _Panel, box, diag, cycles: float):
    h = diag.sample_time
    pv = np.asarray(diag.pv, dtype=float)
    lo, hi = _zoom_span(pv.size, diag.period / h, cycles)
    t = np.arange(pv.size) * h
    ax.line(t[lo:hi], pv[lo:hi], _grey(0.3), 0.8, label="PV")
    osc = diag.oscillation
    if osc is not None and osc.apex_idx.size:
        ai, sg = np.asarray(osc.apex_idx), np.asarray(osc.apex_sign)
        keep = (ai >= lo) & (ai < hi)
        pk, vl = ai[keep & (sg > 0)], ai[keep & (sg < 0)]
        ax.markers(t[pk], pv[pk], "v", _C3, 5, label="peaks")
        ax.markers(t[vl], pv[vl], "^", _C2, 5, label="valleys")
    if diag.op is not None:
        tw = _Panel(box)
        tw.right = True
        tw.line(t[lo:hi], np.asarray(diag.op, dtype=float)[lo:hi], "#d35400", 0.7, alpha=0.7)
        tw.ylabel = "OP [%]"
        tw.xticks_n, tw.yticks_n = None, 5
        ax.twin = tw


def _bi_per_cycle(ax: _Panel, bres):
    b = np.asarray(bres.bi_per_cycle, dtype=float)
    lo, hi = bres.thresholds
    x = np.arange(1, b.size + 1)
    ok = np.isfinite(b)
    top = max(hi * 1.8, float(np.nanpercentile(b[ok], 95)) * 1.15 if ok.any() else 0.0)
    ax.yspan(0, lo, "#f6d5da")
    ax.yspan(hi, top, "#fae0cc")
    ax.text_at(0.005, lo * 0.5, "stiction zone", "#b00020")
    ax.text_at(0.005, (hi + top) / 2, "backlash zone", "#b34700")
    ax.markers(x[ok], np.clip(b[ok], 0, top), "o", _grey(0.25), 2.5)
    if math.isfinite(bres.bi):
        ax.hline(bres.bi, "#000000", 1.0, dash=_DASHED)
    ax.ylim = (0.0, top)
    ax.xlim = (0.0, float(max(b.size, 1) + 1))
    ax.xlabel, ax.ylabel = "half cycle", "BI"
    ax.title = (f"Backlash Index of every half cycle (dashed: the loop's BI, {bres.bi:.2f}); "
                f"stiction below {lo:g}, backlash above {hi:g}")


def _cycle_durations(ax: _Panel, diag):
    osc = diag.oscillation
    if osc is None or osc.apex_idx.size < 3:
        ax.blank("no cycles")
        return
    pk = osc.apex_idx[osc.apex_sign > 0]
    d = np.diff(pk) * diag.sample_time
    ax.markers(np.arange(1, d.size + 1), d, "o", _grey(0.25), 2.5)
    if math.isfinite(diag.period):
        ax.hline(diag.period, "#000000", 1.0, dash=_DASHED)
    ax.ylim = (0.0, max(float(d.max()) * 1.2, 1.0) if d.size else 1.0)
    ax.xlabel, ax.ylabel = "cycle", "duration [s]"
    ax.title = f"Duration of every cycle (dashed: the period, {diag.period:.4g} s)"


def _clock_wander(ax: _Panel, clock):
    """The swing's upward crossings against the best steady clock, cycle by cycle."""
    dev = clock.departures()
    if not dev.size:
        ax.blank("no crossings")
        return
    k = np.arange(dev.size, dtype=float)
    ax.hline(0.0, _grey(0.6), 1.0, dash=_DASHED)
    ax.line(k, dev, "#1f5fa8", 0.8)
    ax.markers(k, dev, "o", "#1f5fa8", 2.0)
    ax.xlabel, ax.ylabel = "cycle", "early / late [s]"
    ax.title = (f"Each cycle's start against a steady clock: it scatters but never drifts "
                f"off (wander {clock.wander:.2f}; a valve's own swing would read about "
                f"{dev.size / 15:.0f})")


def _mean_cycle(ax: _Panel, shape, linear: bool = True):
    y = np.asarray(shape.pv_cycle, dtype=float)
    n = y.size
    if n == 0 or not np.isfinite(y).all():
        ax.blank("no mean cycle")
        return
    ph = np.arange(n) / n
    F = np.fft.rfft(y - y.mean()) / n
    sine = 2 * np.abs(F[1]) * np.cos(2 * np.pi * ph + np.angle(F[1]))
    ax.line(ph, sine, _grey(0.6), 1.2, dash=_DASHED, label="sine")
    ax.line(ph, y - y.mean(), "#1f5fa8", 1.4, label="mean PV cycle")
    ax.xlabel, ax.ylabel = "phase [cycle]", "PV minus mean"
    ax.title = (f"Mean cycle of the PV against a sine wave (harmonic distortion "
                f"{shape.pv_distortion:.3f})")
    if linear:
        ax.title += ": a sine-like swing is not the valve's doing"


def _valve_position(ax: _Panel, travel):
    """The recorded valve position against the OP, its jumps towards the OP in red."""
    op = np.asarray(travel.op, dtype=float)
    mv = np.asarray(travel.mv, dtype=float)
    ax.line(op, mv, _C0, 0.8, label="position")
    k = np.asarray(travel.jump_index, dtype=int)
    if k.size:
        # one line through every jump, broken by NaN between them
        xs = np.full(3 * k.size, np.nan)
        ys = np.full(3 * k.size, np.nan)
        xs[0::3], xs[1::3] = op[k], op[k + 1]
        ys[0::3], ys[1::3] = mv[k], mv[k + 1]
        ax.line(xs, ys, _C3, 1.8, label="jumps")
    ax.xlabel, ax.ylabel = "OP [%]", "position [%]"
    ax.title = f"Valve position vs OP: {travel.verdict}"


def loop_svg(result, prefix: str, *, zoom_cycles: float = 4.0, title: str | None = None
             ) -> str | None:
    """The evidence figure of one loop needing action, as inline SVG text.

    Parameters
    ----------
    result : valvediag.scan.LoopResult
        A ranked result whose ``detail`` holds a trend (and a diagnosis).
    prefix : str
        Prefix of every id in the SVG, unique within the page (letters,
        digits, ``-`` and ``_``).
    zoom_cycles : float
        Cycles shown in the zoom panel [-].
    title : str, optional
        Accessible name (``aria-label``, escaped); default "Evidence behind
        the verdict <verdict>".

    Returns
    -------
    str or None
        The ``<svg>`` element (``role="img"``, class ``fig``, size
        :data:`WIDTH` x :data:`HEIGHT` px); None when the result carries no
        plot data.

    Notes
    -----
    See the module notes for what differs from a matplotlib drawing (text
    metrics are estimated, not measured).
    """
    detail = result.detail
    if detail is None or detail.trend is None:
        return None
    diag = detail.diagnosis
    bres = diag.backlash if diag is not None else None
    shape = diag.shape if diag is not None else None
    unit = f" [{result.unit}]" if result.unit else ""
    unit = unit.replace("$", "")

    tops, bottoms, lefts, rights = _grid(4, 3, (1.0, 0.42, 1.25, 0.85), 0.5, 0.3,
                                         0.065, 0.985, 0.96, 0.07)
    box = lambda r, c0, c1: (lefts[c0] * WIDTH, (1 - tops[r]) * HEIGHT,
                             rights[c1] * WIDTH, (1 - bottoms[r]) * HEIGHT)
    ax_t, ax_o = _Panel(box(0, 0, 2)), _Panel(box(1, 0, 2))
    zbox = box(2, 0, 1)
    ax_z, ax_p, ax_b = _Panel(zbox), _Panel(box(2, 2, 2)), _Panel(box(3, 0, 2))

    _trend(ax_t, ax_o, result, detail, _highlight(result, detail))
    ax_t.ylabel = f"PV{unit}"
    # a valve read from its events in a record without a regular swing
    events = read_from_events(result) is not None and not swings_regularly(result)
    ax_t.title = ("Trend over the window (UTC): process value (PV, blue) and set point (SP, "
                  "dashed); " + ("the stretch whose valve events were read shaded" if events
                                 else "oscillating stretches shaded, the one diagnosed darker"))
    ax_o.title = "Controller output (OP): what the controller asks of the valve"

    start = detail.diagnosis_start
    if bres is not None and bres.pv is not None and bres.pv.size:
        lo, hi = _evidence_window(bres, zoom_cycles)
        _zoom_bi(ax_z, _slice_backlash(bres, lo, hi))
        if start is not None:
            start = start + dt.timedelta(seconds=lo * bres.sample_time)
        ax_z.title = (f"Zoom on {zoom_cycles:g} cycles: peaks, valleys, middle points and "
                      f"the angles measured there (BI {bres.bi:.2f})")
    elif diag is not None and diag.pv is not None:
        _zoom_linear(ax_z, zbox, diag, zoom_cycles)
        ax_z.title = ("Zoom on a stretch: PV with its peaks and valleys, OP in orange (no "
                      "regular cycle: the verdict stands on the valve's events)" if events
                      else f"Zoom on {zoom_cycles:g} cycles: PV with its peaks and valleys, "
                      "OP in orange")
    else:
        ax_z.blank("no oscillation data kept")
    span_s = diag.period * zoom_cycles if diag is not None else math.nan
    _clock_axis(ax_z, start, seconds=not span_s > 900)
    ax_z.xlabel, ax_z.ylabel = "time (UTC)", f"PV{unit}"
    ax_z.xticks_n, ax_z.yticks_n = 5, 4

    travel = diag.travel if diag is not None else None
    if travel is not None and travel.mv is not None and travel.op is not None \
            and (travel.fault or travel.verdict == "linear"):
        _valve_position(ax_p, travel)
        ax_p.xticks_n = 3
    elif shape is not None and np.isfinite(np.asarray(shape.pv_cycle, dtype=float)).all() \
            and np.isfinite(np.asarray(shape.op_cycle, dtype=float)).all():
        pvc = np.asarray(shape.pv_cycle, dtype=float)
        opc = np.asarray(shape.op_cycle, dtype=float)
        n = pvc.size
        slope = np.gradient(np.r_[pvc, pvc[:1]])[:n] * n
        ax_p.line(np.r_[opc, opc[:1]], np.r_[slope, slope[:1]], _C0, 1.5)
        ax_p.title = "Phase plot of the mean cycle"
        ax_p.xlabel, ax_p.ylabel = "OP [%]", "PV slope ~ valve position"
        ax_p.xticks_n = 3
    else:
        ax_p.blank("no phase plot (no mean cycle)")

    clock = diag.clock if diag is not None else None
    if bres is not None and np.asarray(bres.bi_per_cycle).size:
        _bi_per_cycle(ax_b, bres)
    elif clock is not None and clock.keeps_clock:
        _clock_wander(ax_b, clock)
    elif shape is not None:
        _mean_cycle(ax_b, shape, linear=result.verdict == "linear-oscillation")
    elif diag is not None:
        _cycle_durations(ax_b, diag)
    else:
        ax_b.blank("no cycles")
    ax_b.xticks_n = 6

    if title is None:
        title = f"Evidence behind the verdict {result.verdict}"
    out = [f'<svg role="img" aria-label="{escape(title)}" class="fig" '
           f'xmlns="http://www.w3.org/2000/svg" width="{WIDTH:g}" height="{HEIGHT:g}" '
           f'viewBox="0 0 {_i(WIDTH)} {_i(HEIGHT)}" font-family="{_FONT}">',
           f'<rect width="{_i(WIDTH)}" height="{_i(HEIGHT)}" fill="#fff"/>']
    for k, ax in enumerate((ax_t, ax_o, ax_z, ax_p, ax_b)):
        cid = f"{prefix}-c{k}"
        if ax.twin is not None:          # the twin's data under the main axes' text
            tw = ax.twin
            xl, _ = ax.limits()
            tw.xlim = xl
            out += tw.svg(cid + "r")
        out += ax.svg(cid)
    out.append("</svg>")
    return "\n".join(out)
