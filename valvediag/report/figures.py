"""
Figures of the maintenance report: one inline SVG per loop, drawn reproducibly.

:func:`loop_figure` draws the evidence behind one loop's verdict in one
figure (five panels) from the plot data the scan kept
(:class:`valvediag.scan.LoopDetail`):

* the PV, SP and OP over the window with the oscillating episodes shaded
  (:meth:`valvediag.scan.LoopTrend.plot`);
* a zoom on a few cycles: for a valve fault the Backlash Index evidence,
  peaks, valleys, middle points and the measured angles
  (:meth:`valvediag.bi.BacklashIndex.plot`); for a linear oscillation the
  PV and OP with the apices;
* the phase plot of the mean cycle, OP against the implied valve position
  (:meth:`valvediag.linearity.CycleShape.plot`);
* for a valve fault, the Backlash Index of every half cycle against the
  verdict limits; for a linear oscillation, the mean PV cycle against a pure
  sine wave (its harmonic distortion is what makes it linear).

:func:`svg_text` turns a figure into SVG text that is the same, byte for
byte, for the same data: the hash salt of the ids, the metadata (no date, no
version), the font (DejaVu Sans, which matplotlib ships) and the text mode
(SVG ``<text>``) are fixed, and the ids get a prefix so that many figures can
live in one HTML page.
The report draws :func:`loop_figure` with :func:`valvediag.report.plot.loop_svg`,
which writes the SVG elements itself (5-15 ms a figure on one core, 450
figures of real plant data in ~7 s); the matplotlib drawing
(:func:`loop_figure_mpl`, ~0.5-1 s a figure, most of it matplotlib's tick
and text layout) made ~95 % of a plant report's cost. :func:`render_loop_figures`
can still spread the figures over worker processes, but starting them and
pickling the results costs more than it saves below :data:`PARALLEL_MIN`
figures (450 figures on 2 cores: 7.4 s in one process, 19.5 s with two
workers).
"""
from __future__ import annotations

import contextlib
import datetime as dt
import io
import math
import re

import numpy as np

__all__ = ["RC", "svg_text", "loop_figure", "mpl_style"]

#: matplotlib settings of every report figure (reproducible SVG output).
RC = {
    "svg.hashsalt": "valvediag-report",
    "svg.fonttype": "none",
    "svg.image_inline": True,
    "font.family": "DejaVu Sans",
    "font.size": 7.5,
    "axes.titlesize": 8.5,
    "axes.titleweight": "bold",
    "axes.labelsize": 7.5,
    "axes.linewidth": 0.6,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "legend.fontsize": 6.5,
    "lines.markersize": 4,
    "path.simplify": True,
    "path.simplify_threshold": 0.5,
    "axes.unicode_minus": False,
    "figure.dpi": 72,
}

_DROP = (re.compile(r"<\?xml[^>]*\?>\s*"), re.compile(r"<!DOCTYPE[^>]*>\s*"),
         re.compile(r"<!--.*?-->\s*", re.S), re.compile(r"<metadata>.*?</metadata>\s*", re.S))
_NUM_ATTR = re.compile(r'\b(d|x|y|width|height|transform|points)="([^"]*)"')
_LONG_FLOAT = re.compile(r"-?\d+\.\d{2,}")
_ID = re.compile(r'\bid="([^"]+)"')
_REF = re.compile(r'(url\(#|xlink:href="#|href="#)([^")]+)')
_VERDICT_COLOURS = {"stiction": "#b00020", "backlash": "#b34700", "undecided": "#7a5c00",
                    "linear-oscillation": "#0b5394"}


_FULL_RC = None
_depth = 0


@contextlib.contextmanager
def mpl_style():
    """Context with matplotlib's defaults and :data:`RC` in force, whatever the user's rc.

    The merged settings are validated once per process and then applied
    without validation (``rc_context`` restores the caller's on exit);
    nested use costs nothing.
    """
    global _FULL_RC, _depth
    import matplotlib as mpl

    if _depth:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return
    if _FULL_RC is None:
        merged = {k: v for k, v in {**mpl.rcParamsDefault, **RC}.items()
                  if k not in ("backend", "backend_fallback", "interactive")}
        _FULL_RC = dict(mpl.RcParams(merged))
    with mpl.rc_context():
        dict.update(mpl.rcParams, _FULL_RC)
        _depth = 1
        try:
            yield
        finally:
            _depth = 0


def svg_text(fig, prefix: str, *, title: str | None = None) -> str:
    """Render a figure as inline SVG text, reproducibly.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (drawn with :data:`RC` in force).
    prefix : str
        Prefix of every id in the SVG, unique within the page (letters,
        digits, ``-`` and ``_``).
    title : str, optional
        Accessible name of the image (``aria-label``); HTML-escaped here.

    Returns
    -------
    str
        An ``<svg>`` element without XML prolog, DOCTYPE, comments or
        metadata, with ``role="img"``.
    """
    from markupsafe import escape

    buf = io.StringIO()
    with mpl_style():
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
    text = buf.getvalue()
    for pat in _DROP:
        text = pat.sub("", text)
    text = _NUM_ATTR.sub(_round_attr, text)
    text = re.sub(r"\s*\n\s*", "\n", text)
    text = _ID.sub(lambda m: f'id="{prefix}-{m.group(1)}"', text)
    text = _REF.sub(lambda m: f"{m.group(1)}{prefix}-{m.group(2)}", text)
    label = f' aria-label="{escape(title)}"' if title else ""
    text = text.replace("<svg ", f'<svg role="img"{label} class="fig" ', 1)
    return text.strip()


def _round1(m: re.Match) -> str:
    t = "%.1f" % float(m.group(0))
    if t.endswith(".0"):
        t = t[:-2]
    return "0" if t == "-0" else t


def _round_attr(m: re.Match) -> str:
    """Coordinates to 0.1 pt: a tenth of a pixel, a third of the bytes."""
    return f'{m.group(1)}="{_LONG_FLOAT.sub(_round1, m.group(2))}"'


def _clock(start: dt.datetime | None, seconds: bool = False):
    """Tick formatter: seconds since ``start`` as UTC clock time."""
    from matplotlib.ticker import FuncFormatter

    if start is None:
        return FuncFormatter(lambda x, _pos: f"{x / 60:.0f} min")
    fmt = "%H:%M:%S" if seconds else "%H:%M"
    return FuncFormatter(lambda x, _pos: (start + dt.timedelta(seconds=float(x))).strftime(fmt))


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
    ai = bres._apex_idx if bres._apex_idx is not None else np.sort(np.r_[bres.peaks, bres.valleys])
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

    Only what :meth:`valvediag.bi.BacklashIndex.plot` draws is kept
    consistent (record, apices with their angles, middle points with theirs).
    """
    import dataclasses

    ai = bres._apex_idx if bres._apex_idx is not None else np.sort(np.r_[bres.peaks, bres.valleys])
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
                               _apex_idx=ai[ka] - lo)


def _zoom_linear(ax, diag, cycles: float):
    """PV (and OP) over a few cycles with the apices, for an oscillation without BI."""
    h = diag.sample_time
    pv = np.asarray(diag.pv, dtype=float)
    lo, hi = _zoom_span(pv.size, diag.period / h, cycles)
    t = np.arange(pv.size) * h
    ax.plot(t[lo:hi], pv[lo:hi], color="0.3", lw=0.8, label="PV")
    osc = diag.oscillation
    if osc is not None and osc.apex_idx.size:
        ai, sg = osc.apex_idx, osc.apex_sign
        keep = (ai >= lo) & (ai < hi)
        pk, vl = ai[keep & (sg > 0)], ai[keep & (sg < 0)]
        ax.plot(t[pk], pv[pk], "v", color="C3", ms=5, label="peaks")
        ax.plot(t[vl], pv[vl], "^", color="C2", ms=5, label="valleys")
    if diag.op is not None:
        ax2 = ax.twinx()
        ax2.plot(t[lo:hi], np.asarray(diag.op, dtype=float)[lo:hi], color="#d35400", lw=0.7,
                 alpha=0.7)
        ax2.set_ylabel("OP [%]")
    ax.set_ylabel("PV")
    ax.legend(loc="upper right", fontsize=6.5)
    return ax


def _bi_per_cycle(ax, bres):
    """Backlash Index of every half cycle against the limits."""
    b = np.asarray(bres.bi_per_cycle, dtype=float)
    lo, hi = bres.thresholds
    x = np.arange(1, b.size + 1)
    ok = np.isfinite(b)
    top = max(hi * 1.8, float(np.nanpercentile(b[ok], 95)) * 1.15 if ok.any() else 0.0)
    ax.axhspan(0, lo, color="#f6d5da", lw=0, zorder=0)
    ax.axhspan(hi, top, color="#fae0cc", lw=0, zorder=0)
    ax.text(0.005, lo * 0.5, "stiction zone", transform=ax.get_yaxis_transform(),
            fontsize=6.5, color="#b00020", va="center")
    ax.text(0.005, (hi + top) / 2, "backlash zone", transform=ax.get_yaxis_transform(),
            fontsize=6.5, color="#b34700", va="center")
    ax.plot(x[ok], np.clip(b[ok], 0, top), "o", ms=2.5, color="0.25", zorder=3)
    if math.isfinite(bres.bi):
        ax.axhline(bres.bi, color="black", lw=1.0, ls="--", zorder=4)
    ax.set_ylim(0, top)
    ax.set_xlim(0, max(b.size, 1) + 1)
    ax.set_xlabel("half cycle")
    ax.set_ylabel("BI")
    _title(ax, f"Backlash Index of every half cycle (dashed: the loop's BI, {bres.bi:.2f}); "
               f"stiction below {lo:g}, backlash above {hi:g}")
    return ax


def _cycle_durations(ax, diag):
    """Duration of every cycle (peak to peak): how regular the oscillation is."""
    osc = diag.oscillation
    if osc is None or osc.apex_idx.size < 3:
        ax.text(0.5, 0.5, "no cycles", ha="center", va="center", transform=ax.transAxes)
        return ax
    pk = osc.apex_idx[osc.apex_sign > 0]
    d = np.diff(pk) * diag.sample_time
    ax.plot(np.arange(1, d.size + 1), d, "o", ms=2.5, color="0.25")
    if math.isfinite(diag.period):
        ax.axhline(diag.period, color="black", ls="--", lw=1.0)
    ax.set_ylim(0, max(float(d.max()) * 1.2, 1.0) if d.size else 1.0)
    ax.set_xlabel("cycle")
    ax.set_ylabel("duration [s]")
    _title(ax, f"Duration of every cycle (dashed: the period, {diag.period:.4g} s)")
    return ax


def _mean_cycle(ax, shape):
    """The mean PV cycle against a sine of the same fundamental."""
    y = np.asarray(shape.pv_cycle, dtype=float)
    n = y.size
    if n == 0 or not np.isfinite(y).all():
        ax.text(0.5, 0.5, "no mean cycle", ha="center", va="center", transform=ax.transAxes)
        return ax
    ph = np.arange(n) / n
    F = np.fft.rfft(y - y.mean()) / n
    sine = 2 * np.abs(F[1]) * np.cos(2 * np.pi * ph + np.angle(F[1]))
    ax.plot(ph, sine, color="0.6", lw=1.2, ls="--", label="sine")
    ax.plot(ph, y - y.mean(), color="#1f5fa8", lw=1.4, label="mean PV cycle")
    ax.set_xlabel("phase [cycle]")
    ax.set_ylabel("PV minus mean")
    _title(ax, f"Mean cycle of the PV against a sine wave (harmonic distortion "
               f"{shape.pv_distortion:.3f}): a sine-like swing is not the valve's doing")
    ax.legend(loc="upper right", fontsize=6.5)
    return ax


def _blank(ax, text):
    ax.set_axis_off()
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _title(ax, text):
    # a fixed position spares matplotlib measuring every tick label to place it
    ax.set_title("")
    ax.set_title(text, fontsize=8.5, loc="left", y=1.0, pad=4)


def _few_ticks(*axes, x: int = 5, y: int = 3):
    # every tick is a few artists to build and measure: a figure's cost is mostly its ticks
    from matplotlib.ticker import MaxNLocator

    for ax in axes:
        ax.yaxis.set_major_locator(MaxNLocator(y))
        if x:
            ax.xaxis.set_major_locator(MaxNLocator(x))


def _figure_panels(fig):
    gs = fig.add_gridspec(4, 3, height_ratios=(1.0, 0.42, 1.25, 0.85), hspace=0.5, wspace=0.3,
                          left=0.065, right=0.985, top=0.96, bottom=0.07)
    ax_t = fig.add_subplot(gs[0, :])
    ax_o = fig.add_subplot(gs[1, :])      # same time span as ax_t, set after plotting
    return (ax_t, ax_o, fig.add_subplot(gs[2, :2]), fig.add_subplot(gs[2, 2]),
            fig.add_subplot(gs[3, :]))


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


def loop_figure(result, prefix: str, *, zoom_cycles: float = 4.0) -> str | None:
    """The evidence figure of one loop needing action, as inline SVG.

    Parameters
    ----------
    result : valvediag.scan.LoopResult
        A ranked result whose ``detail`` holds a trend and a diagnosis.
    prefix : str
        Id prefix, unique in the page.
    zoom_cycles : float
        Cycles shown in the zoom panel [-].

    Returns
    -------
    str or None
        The ``<svg>`` element; None when the result carries no plot data.

    Notes
    -----
    Drawn by :func:`valvediag.report.plot.loop_svg`, which writes the SVG
    directly (a few ms per figure); :func:`loop_figure_mpl` draws the same
    panels with matplotlib (~0.5 s per figure) and is kept for comparison
    and for figures outside the report.
    """
    from .plot import loop_svg

    return loop_svg(result, prefix, zoom_cycles=zoom_cycles)


def loop_figure_mpl(result, prefix: str, *, zoom_cycles: float = 4.0) -> str | None:
    """The evidence figure of one loop needing action, drawn with matplotlib, as inline SVG.

    Parameters
    ----------
    result : valvediag.scan.LoopResult
        A ranked result whose ``detail`` holds a trend and a diagnosis.
    prefix : str
        Id prefix, unique in the page (see :func:`svg_text`).
    zoom_cycles : float
        Cycles shown in the zoom panel [-].

    Returns
    -------
    str or None
        The ``<svg>`` element; None when the result carries no plot data.

    Notes
    -----
    The figure uses matplotlib's object API (no pyplot state), so rendering
    does not depend on or change the global backend. Names from the data
    (loop, tags) are never drawn in the figure: matplotlib would read ``$``
    as mathematics.
    """
    detail = result.detail
    if detail is None or detail.trend is None:
        return None
    from matplotlib.figure import Figure

    diag = detail.diagnosis
    bres = diag.backlash if diag is not None else None
    shape = diag.shape if diag is not None else None
    unit = f" [{result.unit}]" if result.unit else ""
    unit = unit.replace("$", "")
    with mpl_style():
        fig = Figure(figsize=(10.0, 6.8))
        ax_t, ax_o, ax_z, ax_p, ax_b = _figure_panels(fig)

        detail.trend.plot(ax_t, episodes=list(result.episodes),
                          highlight=_highlight(result, detail), op_ax=ax_o)
        from matplotlib.ticker import NullLocator

        ax_t.set_ylabel(f"PV{unit}")
        ax_o.set_xlim(ax_t.get_xlim())
        ax_o.xaxis.set_major_locator(ax_t.xaxis.get_major_locator())
        ax_o.xaxis.set_major_formatter(ax_t.xaxis.get_major_formatter())
        ax_t.xaxis.set_major_locator(NullLocator())   # ticks cost time; the OP panel has them
        if ax_t.get_legend() is not None:
            ax_t.get_legend().remove()                 # the title says what is drawn
        _few_ticks(ax_t, x=0, y=4)
        _few_ticks(ax_o, x=0, y=2)
        _title(ax_t, "Trend over the window (UTC): process value (PV, blue) and set point (SP, "
                     "dashed); oscillating stretches shaded, the one diagnosed darker")
        _title(ax_o, "Controller output (OP): what the controller asks of the valve")

        start = detail.diagnosis_start
        if bres is not None and bres.pv is not None and bres.pv.size:
            lo, hi = _evidence_window(bres, zoom_cycles)
            _slice_backlash(bres, lo, hi).plot(ax_z)
            if start is not None:
                start = start + dt.timedelta(seconds=lo * bres.sample_time)
            if ax_z.lines:
                ax_z.lines[0].set_marker("")      # one dot per sample: bytes, no insight
            _title(ax_z, f"Zoom on {zoom_cycles:g} cycles: peaks, valleys, middle points and "
                         f"the angles measured there (BI {bres.bi:.2f})")
        elif diag is not None and diag.pv is not None:
            _zoom_linear(ax_z, diag, zoom_cycles)
            _title(ax_z, f"Zoom on {zoom_cycles:g} cycles: PV with its peaks and valleys, "
                         "OP in orange")
        else:
            _blank(ax_z, "no oscillation data kept")
        span_s = diag.period * zoom_cycles if diag is not None else math.nan
        ax_z.xaxis.set_major_formatter(_clock(start, seconds=not span_s > 900))
        ax_z.set_xlabel("time (UTC)")
        ax_z.set_ylabel(f"PV{unit}")
        _few_ticks(ax_z, x=5, y=4)

        if shape is not None and np.isfinite(np.asarray(shape.pv_cycle, dtype=float)).all() \
                and np.isfinite(np.asarray(shape.op_cycle, dtype=float)).all():
            shape.plot(ax_p)
            _title(ax_p, "Phase plot of the mean cycle")
            ax_p.set_xlabel("OP [%]")
            ax_p.set_ylabel("PV slope ~ valve position")
            _few_ticks(ax_p, x=3)
        else:
            _blank(ax_p, "no phase plot (no mean cycle)")

        if bres is not None and np.asarray(bres.bi_per_cycle).size:
            _bi_per_cycle(ax_b, bres)
        elif shape is not None:
            _mean_cycle(ax_b, shape)
        elif diag is not None:
            _cycle_durations(ax_b, diag)
        else:
            _blank(ax_b, "no cycles")
        _few_ticks(ax_b, x=6)
        return svg_text(fig, prefix, title=f"Evidence behind the verdict {result.verdict}")


#: Fewest figures for which :func:`render_loop_figures` starts worker processes.
PARALLEL_MIN = 2000


def _auto_workers(n: int) -> int:
    import os

    env = os.environ.get("VALVEDIAG_REPORT_WORKERS")
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            pass
    if n < PARALLEL_MIN:
        return 1
    return max(1, min(os.cpu_count() or 1, 4, n // (PARALLEL_MIN // 2)))


def _render_chunk(jobs) -> list[str | None]:
    return [loop_figure(r, p, zoom_cycles=z) for r, p, z in jobs]


def _worker_main(argv) -> int:
    """``python -m valvediag.report.figures IN OUT``: render pickled jobs, pickle the SVGs."""
    import pickle

    with open(argv[0], "rb") as fh:
        jobs = pickle.load(fh)
    out = _render_chunk(jobs)
    with open(argv[1], "wb") as fh:
        pickle.dump(out, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return 0


def render_loop_figures(jobs, *, workers: int | None = None, zoom_cycles: float = 4.0
                        ) -> list[str | None]:
    """Render many loop figures, in worker processes when there are many.

    Parameters
    ----------
    jobs : sequence of (LoopResult, str)
        Results and their id prefixes.
    workers : int, optional
        Processes; default: one below :data:`PARALLEL_MIN` figures, else up
        to ``min(os.cpu_count(), 4)`` (environment variable
        ``VALVEDIAG_REPORT_WORKERS`` overrides).
    zoom_cycles : float
        See :func:`loop_figure` [-].

    Returns
    -------
    list of str or None
        One SVG per job, in order; the same bytes whichever the number of
        workers.

    Notes
    -----
    The workers are plain subprocesses (``python -m
    valvediag.report.figures``) that get their share of the jobs as a pickle
    file: unlike :mod:`multiprocessing` they never re-import the caller's
    ``__main__``, so a script without an ``if __name__ == "__main__"`` guard,
    a notebook or a Prefect worker is safe. Each costs about a second to
    start. A worker that fails has its share drawn in this process. Workers
    run in the directory holding this package (``python -m`` puts the working
    directory first on ``sys.path``), so they import the same ``valvediag``
    as the caller whatever its working directory.
    """
    import os
    import pickle
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    jobs = [(r, p, zoom_cycles) for r, p in jobs]
    n = len(jobs)
    workers = _auto_workers(n) if workers is None else max(1, int(workers))
    if workers <= 1 or n < 2:
        return _render_chunk(jobs)
    workers = min(workers, n)
    chunks = [jobs[k::workers] for k in range(workers)]     # interleaved: similar cost
    package_root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([package_root] + [p for p in
                                         env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.setdefault("MPLBACKEND", "Agg")
    results: list = [None] * workers
    with tempfile.TemporaryDirectory(prefix="valvediag-figures-") as tmp:
        procs = []
        for k, chunk in enumerate(chunks):
            src, dst = os.path.join(tmp, f"in{k}.pkl"), os.path.join(tmp, f"out{k}.pkl")
            with open(src, "wb") as fh:
                pickle.dump(chunk, fh, protocol=pickle.HIGHEST_PROTOCOL)
            try:
                proc = subprocess.Popen([sys.executable, "-m", "valvediag.report.figures",
                                         src, dst], env=env, cwd=package_root,
                                        stdin=subprocess.DEVNULL,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            except OSError:
                proc = None
            procs.append((proc, dst))
        for k, (proc, dst) in enumerate(procs):
            if proc is not None:
                _, err = proc.communicate()
                if proc.returncode == 0 and os.path.isfile(dst):
                    with open(dst, "rb") as fh:
                        results[k] = pickle.load(fh)
                    continue
            results[k] = _render_chunk(chunks[k])    # the worker failed: draw here
    out: list = [None] * n
    for k in range(workers):
        out[k::workers] = results[k]
    return out


if __name__ == "__main__":   # a worker of render_loop_figures
    import sys

    raise SystemExit(_worker_main(sys.argv[1:]))
