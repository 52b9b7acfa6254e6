"""
The workbench's HTML page: one self-contained file per loop.

Overlay before/after, where the starting model fails, the evidence for each
candidate effect, the error ladder and the recommendation. Figures are SVG
embedded as ``data:`` URIs (no external resource, nothing to inject), drawn
with a fixed hash salt and no date, so the same data give the same bytes.
Every text from the data (file names) is HTML-escaped by jinja2.

The template is ``reports/workbench.html.j2`` of the repository, installed
with the package as ``valvediag.templates``.
"""
from __future__ import annotations

import base64
import importlib.resources
import io
import math
from pathlib import Path

from .suggest import ErrorLadder

__all__ = ["render_workbench_report", "write_workbench_report", "TEMPLATE", "REPORTS_DIR"]

#: The templates: ``reports/`` of the repository, shipped as ``valvediag.templates``.
REPORTS_DIR = importlib.resources.files("valvediag.templates")
TEMPLATE = "workbench.html.j2"

_RC = {"svg.hashsalt": "valvediag-workbench", "svg.fonttype": "none", "font.size": 8,
       "axes.titlesize": 9, "figure.dpi": 100, "path.simplify": True}


def _svg(fig) -> str:
    """A figure as a base64 ``data:`` URI of deterministic SVG."""
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None}, bbox_inches="tight")
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _fmt(v, unit=""):
    if isinstance(v, str):
        return v
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if isinstance(v, float) and math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return f"{v:.4g}" + (f" {unit}" if unit else "")


def _params(fit) -> list[tuple[str, str]]:
    return [(k, _fmt(v, fit.units.get(k, ""))) for k, v in fit.params.items()]


def _figures(ladder: ErrorLadder) -> dict:
    import matplotlib
    from matplotlib.figure import Figure

    def subplots(*args, figsize, **kw):
        # figures without pyplot: no global state, no backend switch
        fig = Figure(figsize=figsize)
        return fig, fig.subplots(*args, **kw)

    first, final = ladder.first, ladder.final
    diag0 = ladder.steps[0].suggestions.diagnosis if ladder.steps[0].suggestions else first.diagnose()
    diag1 = ladder.steps[-1].suggestions.diagnosis if ladder.steps[-1].suggestions else final.diagnose()
    figs = {}
    with matplotlib.rc_context(_RC):
        fig, ax = subplots(figsize=(9, 3.2))
        final.plot(ax, other=first if final is not first else None)
        figs["overlay"] = _svg(fig)
        # a close-up of about three periods in the middle of the record
        d = final.data
        T = d.period if math.isfinite(d.period) else 40 * d.horizon * d.sample_time
        mid = d.t[(d.seg_start[len(d.seg_start) // 2])]
        win = (mid - 1.5 * T, mid + 1.5 * T)
        fig, ax = subplots(figsize=(9, 3.2))
        final.plot(ax, other=first if final is not first else None, window=win)
        figs["overlay_zoom"] = _svg(fig)
        fig, axes = subplots(3, 1, figsize=(9, 6.5), sharex=True)
        final.plot_chain(axes, window=win)
        figs["chain"] = _svg(fig)
        for key, dg, ft in (("start", diag0, first), ("final", diag1, final)):
            fig, ax = subplots(figsize=(9, 2.6))
            dg.plot("residual", ax, fit=ft)
            figs[f"resid_{key}"] = _svg(fig)
            fig, axs = subplots(1, 3, figsize=(10.5, 2.8))
            dg.plot("acf", axs[0])
            dg.plot("ccf", axs[1])
            dg.plot("reversals", axs[2])
            fig.tight_layout()
            figs[f"corr_{key}"] = _svg(fig)
        fig, ax = subplots(figsize=(6, 3))
        ladder.plot(ax)
        figs["ladder"] = _svg(fig)
        if ladder.steps[0].suggestions is not None:
            fig, ax = subplots(figsize=(6, 0.35 * len(ladder.steps[0].suggestions.items) + 1.3))
            ladder.steps[0].suggestions.plot(ax)
            figs["candidates"] = _svg(fig)
    return figs


def _recommendation(ladder: ErrorLadder) -> str:
    first, final = ladder.first, ladder.final
    added = [s.added for s in ladder.steps[1:]]
    if not added:
        return (f"No effect improves the held-out error and the BIC of the model "
                f"'{first.model.name}': keep it (held-out fit {first.fit_pct:.1f} %).")
    fall = 100 * (1 - final.heldout_rmse / first.heldout_rmse) if first.heldout_rmse > 0 else 0.0
    parts = [f"Add {', then '.join(added)}: the held-out RMSE falls {fall:.0f} % "
             f"({first.heldout_rmse:.4g} to {final.heldout_rmse:.4g}); held-out fit "
             f"{first.fit_pct:.1f} % to {final.fit_pct:.1f} %."]
    p = final.params
    if "S" in p:
        parts.append(f"Sticky valve: stick band S = {p['S']:.3g}, slip jump J = {p['J']:.3g} "
                     "(OP units).")
    elif "DB" in p:
        parts.append(f"Loose valve: dead band DB = {p['DB']:.3g} (OP units).")
    # rival effects the record could not tell apart: the choice is not evidence
    for st in ladder.steps:
        for r in (st.suggestions.rivals if st.suggestions is not None else ()):
            if not r.distinguishable:
                parts.append(r.summary[:1].upper() + r.summary[1:] + ".")
    return " ".join(parts)


def render_workbench_report(ladder: ErrorLadder, *, name: str = "", meta: dict | None = None) -> str:
    """Render the workbench page for one loop.

    Parameters
    ----------
    ladder : ErrorLadder
        From :func:`valvediag.workbench.forward_select` (its first step
        carries the evidence for every candidate).
    name : str
        Record name (file) shown in the title; escaped.
    meta : dict, optional
        Extra rows for the data table (label -> value), escaped.

    Returns
    -------
    str
        The HTML page.
    """
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(REPORTS_DIR)),
                             autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    first, final = ladder.first, ladder.final
    d = final.data
    sug = ladder.steps[0].suggestions
    data_rows = [("record", name or d.name or "–"), ("samples", f"{d.n:,}"),
                 ("sample time", f"{d.sample_time:g} s"),
                 ("OP period", _fmt(d.period, "s")),
                 ("horizon (re-initialised every)", f"{d.horizon} samples"),
                 ("scored from", f"{d.t[d.burn_in]:g} s (valve state known)"),
                 ("training / held-out samples", f"{final.n_train:,} / {final.n_heldout:,}"),
                 ("process type", final.model.process_type)]
    data_rows += [(str(k), str(v)) for k, v in (meta or {}).items()]
    cands = []
    if sug is not None:
        for s in sug.items:
            cands.append(dict(effect=s.effect, accepted=s.accepted, gain=f"{100 * s.gain:+.1f} %",
                              fit=f"{s.fit_pct:.1f}", rmse=f"{s.heldout_rmse:.4g}",
                              bic=f"{s.bic:.1f}", signature=s.evidence.signature,
                              statistic=_fmt(s.evidence.statistic), summary=s.evidence.summary,
                              params=", ".join(f"{k} = {v}" for k, v in _params(s.fit))))
    rows = []
    for i, (r, st) in enumerate(zip(ladder.rows(), ladder.steps)):
        added = r["added"] or "start"
        if r["alternatives"]:
            added += f" (or {' or '.join(r['alternatives'])}: indistinguishable)"
        rows.append(dict(step=i, model=r["model"], added=added, k=r["n_params"],
                         fit=f"{r['fit_pct']:.1f}", rmse=f"{r['heldout_rmse']:.4g}",
                         bic=f"{r['bic']:.1f}",
                         params=", ".join(f"{k} = {v}" for k, v in _params(st.fit))))
    diag0 = sug.diagnosis if sug is not None else first.diagnose()
    worst = [dict(span=f"{w.start:.0f}–{w.end:.0f} s", rms=f"{w.rms:.3g}", ratio=f"{w.ratio:.1f}",
                  labels=", ".join(w.labels), set="held-out" if w.heldout else "training")
             for w in diag0.worst]
    return env.get_template(TEMPLATE).render(
        name=name or d.name or "loop", data_rows=data_rows, first=first.model.name,
        final=final.model.name, first_params=_params(first), final_params=_params(final),
        first_fit=f"{first.fit_pct:.1f}", final_fit=f"{final.fit_pct:.1f}",
        recommendation=_recommendation(ladder), candidates=cands, ladder=rows, worst=worst,
        diag_summary=diag0.summary(), figs=_figures(ladder))


def write_workbench_report(ladder: ErrorLadder, path, *, name: str = "", meta: dict | None = None) -> Path:
    """Write the workbench page to ``path``.

    Parameters
    ----------
    ladder : ErrorLadder
    path : str or path-like
        Output file (its directory is created).
    name : str
        Record name shown in the page.
    meta : dict, optional
        Extra rows for the data table.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render_workbench_report(ladder, name=name, meta=meta), encoding="utf-8")
    return path
