"""
Tiny hand-written inline SVGs of the report: the PV sparkline of every table
row and the verdict history strip of a loop.

These are drawn without matplotlib because a plant report has thousands of
them (a matplotlib figure costs tens of milliseconds; these cost
microseconds). Numbers are rounded to 0.1 of a view-box unit and every text
from the data is XML-escaped, so the same data give the same bytes.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from markupsafe import Markup, escape

__all__ = ["sparkline_svg", "history_svg", "VERDICT_COLOURS"]

#: Colour of every verdict (also used by the CSS of the report).
VERDICT_COLOURS = {
    "stiction": "#b00020", "backlash": "#b34700", "undecided": "#8a6d00",
    "linear-oscillation": "#0b5394", "not-integrating": "#5f6b7a", "no-oscillation": "#2e7d32",
    "insufficient-data": "#9e9e9e",
}


def _f(x: float) -> str:
    return _g(round(float(x), 1))


def _g(v: float) -> str:
    """A number already rounded to 0.1, as short text."""
    return "0" if v == 0 else f"{v:g}"


def sparkline_svg(values, *, width: float = 96.0, height: float = 18.0,
                  colour: str | None = None, label: str | None = None) -> Markup:
    """A sparkline of ``values`` as an inline ``<svg>`` element.

    Parameters
    ----------
    values : array_like or None
        Points in time order; NaN breaks the line (a gap). Scaled to their own
        range (a sparkline shows the shape, not the level).
    width, height : float
        Size [CSS px].
    colour : str, optional
        Stroke colour (CSS); default the ``svg.spark`` rule of the page's CSS
        (a report has thousands of these: every byte counts).
    label : str, optional
        Accessible name (escaped); default none (the table cell says it).

    Returns
    -------
    markupsafe.Markup
        The ``<svg>``; an empty string when there is nothing to draw.
    """
    if values is None:
        return Markup("")
    y = np.asarray(values, dtype=float)
    ok = np.isfinite(y)
    if y.size < 2 or not ok.any():
        return Markup("")
    lo, hi = float(np.min(y[ok])), float(np.max(y[ok]))
    pad = 1.5
    span = hi - lo
    xs = np.linspace(0.5, width - 0.5, y.size)
    ys = (height - pad - (y - lo) / span * (height - 2 * pad)) if span > 0 else \
        np.full(y.size, height / 2)
    # _f on whole arrays: round once in numpy, format the Python floats
    fx = [_g(v) for v in np.round(xs, 1).tolist()]
    fy = [_g(v) for v in np.round(ys, 1).tolist()]
    lines, run = [], []
    for k, good in enumerate(ok.tolist()):
        if good:
            run.append(f"{fx[k]},{fy[k]}")
        elif run:
            lines.append(run)
            run = []
    if run:
        lines.append(run)
    body = "".join(f'<polyline points="{" ".join(r)}"/>' if len(r) > 1 else
                   f'<circle cx="{r[0].split(",")[0]}" cy="{r[0].split(",")[1]}" r="0.8"/>'
                   for r in lines)
    extra = f' aria-label="{escape(label)}" role="img"' if label else ""
    extra += f' stroke="{escape(colour)}"' if colour else ""
    return Markup(f'<svg class="spark" viewBox="0 0 {_f(width)} {_f(height)}"{extra}>'
                  f'{body}</svg>')


def history_svg(points: Sequence[dict], *, thresholds: tuple[float, float] = (2.2, 2.4),
                width: float = 320.0, height: float = 64.0) -> Markup:
    """The verdict history strip of one loop: its BI per run, coloured by verdict.

    Parameters
    ----------
    points : sequence of dict
        Oldest first, with ``verdict``, ``bi`` (float or None), ``label``
        (text of the tooltip, escaped here) and ``current`` (bool).
    thresholds : (float, float)
        Stiction and backlash limits of the BI, drawn as lines.
    width, height : float
        Size [CSS px].

    Returns
    -------
    markupsafe.Markup
        The ``<svg>``: one marker per run (a square when the BI was not
        measured), the current run ringed.
    """
    n = len(points)
    if n == 0:
        return Markup("")
    left, right, top, bottom = 26.0, 6.0, 6.0, 14.0
    bis = [p.get("bi") for p in points]
    finite = [b for b in bis if b is not None and math.isfinite(b)]
    ymax = max([thresholds[1] * 1.5] + [b * 1.1 for b in finite])
    plot_h = height - top - bottom
    step = (width - left - right) / max(n, 1)
    X = lambda i: left + step * (i + 0.5)
    Y = lambda b: top + plot_h * (1 - min(b, ymax) / ymax)
    out = [f'<svg class="hist" role="img" aria-label="Backlash Index and verdict per run" '
           f'width="{_f(width)}" height="{_f(height)}" viewBox="0 0 {_f(width)} {_f(height)}">',
           f'<rect x="{_f(left)}" y="{_f(top)}" width="{_f(width - left - right)}" '
           f'height="{_f(plot_h)}" fill="#fafafa" stroke="#ccc" stroke-width="0.5"/>']
    for th, colour in zip(thresholds, ("#b00020", "#b34700")):
        out.append(f'<line x1="{_f(left)}" x2="{_f(width - right)}" y1="{_f(Y(th))}" '
                   f'y2="{_f(Y(th))}" stroke="{colour}" stroke-width="0.6" '
                   f'stroke-dasharray="3 2"/>')
    for v in (0.0, thresholds[0], ymax):
        out.append(f'<text x="{_f(left - 3)}" y="{_f(Y(v) + 3)}" font-size="8" '
                   f'text-anchor="end" fill="#555">{v:.1f}</text>')
    out.append(f'<text x="{_f(left)}" y="{_f(height - 3)}" font-size="8" fill="#555">'
               f'BI per run, oldest first ({n} run{"s" if n != 1 else ""})</text>')
    prev = None
    for i, p in enumerate(points):
        b = p.get("bi")
        if b is not None and math.isfinite(b):
            if prev is not None:
                out.append(f'<line x1="{_f(X(prev[0]))}" y1="{_f(Y(prev[1]))}" x2="{_f(X(i))}" '
                           f'y2="{_f(Y(b))}" stroke="#999" stroke-width="0.6"/>')
            prev = (i, b)
    for i, p in enumerate(points):
        colour = VERDICT_COLOURS.get(p.get("verdict"), "#777")
        b = p.get("bi")
        tip = f"<title>{escape(p.get('label', ''))}</title>"
        ring = ' stroke="#000" stroke-width="1.2"' if p.get("current") else ""
        if b is not None and math.isfinite(b):
            out.append(f'<circle cx="{_f(X(i))}" cy="{_f(Y(b))}" r="3.2" fill="{colour}"{ring}>'
                       f'{tip}</circle>')
        else:
            out.append(f'<rect x="{_f(X(i) - 2.8)}" y="{_f(top + plot_h - 6.5)}" width="5.6" '
                       f'height="5.6" fill="{colour}"{ring}>{tip}</rect>')
    out.append("</svg>")
    return Markup("".join(out))
