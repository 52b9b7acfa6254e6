"""
The plant level of a scan: ranking the loops and storing their verdicts.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover

    from ..store.database import Store

from ..plain import finite_or_none
from ..verdicts import rank_position
from .types import LoopResult

#: Severity: amplitude scale [% of span] and the largest criticality weight.
AMPLITUDE_SCALE_PCT = 5.0
MAX_CRITICALITY = 10.0


def severity(amplitude_pct_span: float, regularity: float, time_share: float,
             criticality: float) -> tuple[float, dict]:
    """Severity of an oscillating loop: how much it matters to fix it.

    ``severity = f_amp * f_reg * f_time * f_crit`` with

    * ``f_amp = 1 - exp(-a / 5)``, ``a`` the amplitude in % of span: 0.18 at
      1 %, 0.63 at 5 %, 0.86 at 10 % (bounded by 1);
    * ``f_reg = r / (1 + r)``, ``r`` Thornhill's regularity: 0.5 at the
      regularity limit r = 1, 0.9 at r = 9 (bounded by 1);
    * ``f_time``: share of the window spent in oscillating episodes [0-1];
    * ``f_crit = min(criticality, 10)``: the registry's weight (default 1).

    Parameters
    ----------
    amplitude_pct_span : float
        Half peak-to-peak amplitude [% of span].
    regularity : float
        Thornhill regularity [-].
    time_share : float
        Share of the window oscillating [-].
    criticality : float
        Registry weight [-], >= 0.

    Returns
    -------
    severity : float
        In [0, 10]; 0 when any factor is missing (NaN).
    factors : dict
        ``f_amp, f_reg, f_time, f_crit``.

    Notes
    -----
    The factors multiply, so a loop must be large, regular, persistent and
    critical to rank first. The amplitude is relative to the span from
    ``loops.csv``; without one, to the PV's robust range in the window, which
    makes the amplitude factor large (the range is then mostly the
    oscillation itself); the evidence says which span was used.
    """
    def num(x):
        return float(x) if x is not None and math.isfinite(float(x)) else math.nan

    a, r, s, c = num(amplitude_pct_span), num(regularity), num(time_share), num(criticality)
    f = {"f_amp": 1.0 - math.exp(-max(a, 0.0) / AMPLITUDE_SCALE_PCT) if a == a else math.nan,
         "f_reg": max(r, 0.0) / (1.0 + max(r, 0.0)) if r == r else math.nan,
         "f_time": min(max(s, 0.0), 1.0) if s == s else math.nan,
         "f_crit": min(max(c, 0.0), MAX_CRITICALITY) if c == c else 1.0}
    value = f["f_amp"] * f["f_reg"] * f["f_time"] * f["f_crit"]
    return (round(value, 6) if math.isfinite(value) else 0.0), f


def _order_key(r: LoopResult):
    return (rank_position(r.verdict), r.loop)


def rank_results(results: Iterable[LoopResult]) -> list[LoopResult]:
    """Rank a plant's results: rank 1 is the most severe loop that needs action.

    Parameters
    ----------
    results : iterable of LoopResult
        One per loop (from :func:`analyse_loop`); their ``severity`` is used.

    Returns
    -------
    list of LoopResult
        Copies with ``rank`` set: loops with a verdict in
        :data:`ACTION_VERDICTS` get 1, 2, ... by decreasing severity (ties:
        higher confidence, then loop name), in that order; the others follow
        without a rank, by verdict and name. Every loop needing action thus
        ranks above every loop that does not.
    """
    results = list(results)
    act = sorted((r for r in results if r.needs_action),
                 key=lambda r: (-r.severity, -r.confidence, r.loop))
    rest = sorted((r for r in results if not r.needs_action), key=_order_key)
    return ([dataclasses.replace(r, rank=k) for k, r in enumerate(act, 1)]
            + [dataclasses.replace(r, rank=None) for r in rest])


def persist_results(store: Store, run_id: str, results: Sequence[LoopResult]) -> None:
    """Write a run's verdicts and episodes to the store (one transaction).

    Parameters
    ----------
    store : valvediag.store.Store
        Writable store.
    run_id : str
        A run with status ``running`` (:meth:`Store.start_run`). Writing again
        replaces the run's earlier results, so a retried task is idempotent.
    results : sequence of LoopResult
        Ranked results.
    """
    verdicts, episodes = [], []
    for r in results:
        verdicts.append({"loop": r.loop, "verdict": r.verdict, "confidence": r.confidence,
                         "rank": r.rank, "severity": r.severity, "process_type": r.process_type,
                         "bi": finite_or_none(r.bi), "period_s": finite_or_none(r.period_s),
                         "amplitude": finite_or_none(r.amplitude),
                         "regularity": finite_or_none(r.regularity), "reason": r.reason,
                         "evidence": r.evidence, "quality": r.quality})
        for e in r.episodes:
            episodes.append({"loop": r.loop, "start_ts": e.start, "end_ts": e.end,
                             "period_s": finite_or_none(e.period_s),
                             "amplitude": finite_or_none(e.amplitude),
                             "regularity": finite_or_none(e.regularity), "verdict": e.verdict,
                             "bi": finite_or_none(e.bi), "confidence": e.confidence})
    store.write_results(run_id, episodes=episodes, verdicts=verdicts)


