"""
The verdicts: the words a loop (or an oscillating window of it) can get, their
order, and every named set of them.

Every module, template and query takes its verdict words from here; the SQL
queries get the sets they need as parameters. A loop gets the first verdict of
:data:`PRECEDENCE` that applies.

======================  ===============================================================
verdict                 meaning
======================  ===============================================================
``insufficient-data``   too little usable data to judge; the reason says why
``no-oscillation``      no oscillation and no valve fault in the data analysed
``linear-oscillation``  an oscillation that no valve nonlinearity explains (tuning or
                        an external disturbance)
``stiction``            a sticky valve: it sticks, then jumps
``backlash``            a loose valve: a dead band without a jump
``undecided``           a valve nonlinearity whose kind the evidence cannot settle
======================  ===============================================================

``not-integrating`` (earlier versions' verdict for an oscillating
self-regulating loop, where the Backlash Index does not apply) is retired:
such loops now get the valve verdict their valve signature supports. Stores
written with it still open and their history still reads
(:data:`STORED_VERDICTS`).
"""
from __future__ import annotations

__all__ = ["VERDICTS", "STORED_VERDICTS", "LEGACY_VERDICTS", "PRECEDENCE", "RANK_ORDER", "VALVE_FAULTS", "VALVE_NONLINEARITY",
           "ACTION_VERDICTS", "FAULT_VERDICTS", "EPISODE_VERDICTS", "HEALTHY_VERDICTS",
           "rank_position", "count_verdicts"]

#: Every verdict word, in the order a loop is checked for them.
PRECEDENCE = ("insufficient-data", "no-oscillation", "linear-oscillation", "stiction",
              "backlash", "undecided")
#: Every verdict word a scan gives.
VERDICTS = PRECEDENCE
#: Verdicts of earlier versions, retired: stores still hold them.
LEGACY_VERDICTS = ("not-integrating",)
#: Every verdict word the store accepts (a store written by an earlier version opens).
STORED_VERDICTS = VERDICTS + LEGACY_VERDICTS
#: Order of the ranked list, the report's sections and a loop's verdict when its
#: episodes disagree: valve faults first, healthy and unusable loops last.
RANK_ORDER = ("stiction", "backlash", "undecided", "linear-oscillation", "not-integrating",
              "no-oscillation", "insufficient-data")
#: The valve faults the Backlash Index tells apart (sized with the loop model).
VALVE_FAULTS = ("stiction", "backlash")
#: A nonlinearity of the valve, of a known kind or not: work for the valve crew.
VALVE_NONLINEARITY = VALVE_FAULTS + ("undecided",)
#: Verdicts that call for action: a rank, a work order and a section of the report.
ACTION_VERDICTS = ("stiction", "backlash", "linear-oscillation", "undecided")
#: Verdicts that name a fault: a loop that gets one and did not have one in the
#: previous complete run is a new fault. ``undecided`` is not among them: the
#: evidence has not settled what is wrong, so a later ``stiction`` or ``backlash``
#: is news.
FAULT_VERDICTS = ("stiction", "backlash", "linear-oscillation")
#: Verdicts that establish an oscillation (an episode of the loop).
EPISODE_VERDICTS = ("not-integrating", "linear-oscillation", "stiction", "backlash", "undecided")
#: Verdicts that close an open problem of an earlier run (``not-integrating``
#: for the history of stores written by earlier versions).
HEALTHY_VERDICTS = ("no-oscillation", "not-integrating")


def count_verdicts(verdicts) -> dict[str, int]:
    """Loops per verdict, every verdict listed (0 included), in :data:`VERDICTS` order.

    Parameters
    ----------
    verdicts : iterable of str
        One verdict per loop.

    Returns
    -------
    dict of str to int
        Words outside :data:`VERDICTS` are counted after them.

    Examples
    --------
    >>> count_verdicts(["stiction", "no-oscillation", "stiction"])["stiction"]
    2
    """
    counts = {v: 0 for v in VERDICTS}
    for v in verdicts:
        counts[v] = counts.get(v, 0) + 1
    return counts


def rank_position(verdict: str) -> int:
    """Position of a verdict in :data:`RANK_ORDER` (unknown words last).

    Parameters
    ----------
    verdict : str

    Returns
    -------
    int

    Examples
    --------
    >>> rank_position("stiction") < rank_position("no-oscillation")
    True
    """
    return RANK_ORDER.index(verdict) if verdict in RANK_ORDER else len(RANK_ORDER)
