"""
A run in a few lines, for an orchestrator's dashboard: a table of the ranked
loops and a markdown summary linking the report (the nightly flow attaches them
to its Prefect run as artifacts).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

from ..plain import finite_or_none
from ..scan.types import LoopResult
from ..verdicts import count_verdicts

__all__ = ["ranked_table", "run_summary_markdown"]


def ranked_table(ranked: Sequence[LoopResult], max_rows: int) -> tuple[list[dict], str]:
    """The first ``max_rows`` loops by rank as table rows, and the table's caption.

    Parameters
    ----------
    ranked : sequence of LoopResult
        In rank order.
    max_rows : int

    Returns
    -------
    rows : list of dict
        ``rank, loop, verdict, confidence, severity, bi, period_s,
        amplitude_pct_span, reason``.
    caption : str
        Says when the table is cut.
    """
    rows = [{"rank": r.rank, "loop": r.loop, "verdict": r.verdict,
             "confidence": r.confidence, "severity": round(r.severity, 4),
             "bi": finite_or_none(r.bi, 4), "period_s": finite_or_none(r.period_s, 4),
             "amplitude_pct_span": finite_or_none(r.amplitude_pct_span, 4), "reason": r.reason}
            for r in ranked[:max_rows]]
    shown = ("" if len(ranked) <= max_rows
             else f" (first {max_rows} of {len(ranked)}; the report has all)")
    return rows, f"loops by rank{shown}"


def run_summary_markdown(ranked: Sequence[LoopResult], paths: Mapping[str, str], run_id: str,
                         new_faults: Sequence[str], title: str = "valvediag nightly scan", *,
                         status: str = "complete", problems: Sequence[str] = ()) -> str:
    """A markdown summary of a run: counts per verdict, new faults, the top loops, links.

    Parameters
    ----------
    ranked : sequence of LoopResult
    paths : mapping
        ``report``, ``work_orders``, ``verdicts`` (absolute paths).
    run_id : str
    new_faults : sequence of str
    title : str
    status : {'complete', 'partial'}
        How the run ended; a partial run is said first.
    problems : sequence of str
        One line each: exports not stored, files with rows quarantined.

    Returns
    -------
    str
    """
    act = [r for r in ranked if r.rank is not None]
    lines = [f"# {title} {run_id}", ""]
    if status != "complete":
        lines += [f"**This run is {status}**: some exports, or some of their rows, did not "
                  "reach the store (listed below).", ""]
    lines += [
             f"**{len(act)} of {len(ranked)} loops need action.** "
             f"[Open the report](file://{paths['report']})", "",
             "| verdict | loops |", "|---|---|",
             *(f"| {v} | {n} |" for v, n in count_verdicts(r.verdict for r in ranked).items()), ""]
    if new_faults:
        lines += [f"New since the last complete run: {', '.join(new_faults)}", ""]
    if act:
        lines += ["| rank | loop | verdict | confidence |", "|---|---|---|---|",
                  *(f"| {r.rank} | {r.loop} | {r.verdict} | {r.confidence:.2f} |"
                    for r in act[:20]), ""]
    if problems:
        lines += ["Problems with the input:", "", *(f"- {p}" for p in problems), ""]
    lines += [f"- report: `{paths['report']}`", f"- work orders: `{paths['work_orders']}`",
              f"- verdicts: `{paths['verdicts']}`"]
    return "\n".join(lines)
