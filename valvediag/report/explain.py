"""
Plain words for the report: what a verdict means to a maintenance planner,
how big the problem is, how we know, and how sure we are.

:func:`explain` returns a few short sentences per loop; the figures
(:mod:`valvediag.report.figures`) show the picture behind each of them.
"""
from __future__ import annotations

import math

from ..analysis.oscillation import regular_oscillation

__all__ = ["explain", "size_text", "duration_text", "confidence_word", "quality_label", "regularity_text",
           "read_from_events", "swings_regularly", "ACTIONS", "SHORT_ACTIONS", "VERDICT_LABELS"]

#: What to do about each verdict that needs action.
ACTIONS = {
    "stiction": "valve maintenance (packing, stem, actuator) or a positioner check",
    "backlash": "dead-band compensation (Hägglund 2007) or mechanical repair of the "
                "linkage or positioner",
    "linear-oscillation": "review the controller tuning or trace the external disturbance; "
                          "not a valve fault",
    "undecided": "inspect: a valve nonlinearity whose kind (stiction or backlash) is not "
                 "clear; check the trend and collect more data",
}

#: The same in a few words, for the ranked table.
SHORT_ACTIONS = {
    "stiction": "valve maintenance or positioner check",
    "backlash": "dead-band compensation or mechanical repair",
    "linear-oscillation": "review tuning or trace the disturbance",
    "undecided": "inspect the valve; collect more data",
}

#: Short words for the verdicts, for people who do not speak control.
VERDICT_LABELS = {
    "stiction": "sticky valve", "backlash": "loose valve (backlash)",
    "undecided": "valve problem, kind unclear", "linear-oscillation": "oscillation, not the valve",
    "not-integrating": "oscillates, not assessed (earlier version)", "no-oscillation": "healthy",
    "insufficient-data": "not enough data",
}


def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def duration_text(seconds: float) -> str:
    """A duration in the unit a person would use: ``45 s``, ``7.3 min``, ``2.5 h``.

    Parameters
    ----------
    seconds : float
        [s]
    """
    if not _finite(seconds):
        return "–"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.2g} min" if seconds < 600 else f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.2g} h" if seconds < 36000 else f"{seconds / 3600:.0f} h"


def regularity_text(regularity: float) -> str:
    """Thornhill's regularity in words: ``> 99 (very regular)``, ``3.2 (regular)``, ...

    Parameters
    ----------
    regularity : float
        [-]; above 1 means a regular oscillation.
    """
    if not _finite(regularity):
        return "–"
    if regularity > 99:
        return "> 99 (very regular)"
    return f"{regularity:.2g} ({'regular' if regularity > 1 else 'irregular'})"


def confidence_word(confidence: float) -> str:
    """``high`` (>= 0.75), ``medium`` (>= 0.5) or ``low``.

    Parameters
    ----------
    confidence : float
        [0-1]
    """
    if not _finite(confidence):
        return "unknown"
    return "high" if confidence >= 0.75 else "medium" if confidence >= 0.5 else "low"


def quality_label(quality: dict) -> tuple[str, str, float]:
    """A short data-quality label for the ranked table.

    Parameters
    ----------
    quality : dict
        :attr:`valvediag.scan.LoopResult.quality`.

    Returns
    -------
    label : str
        ``good`` or the worst findings, e.g. ``compressed; 82 % usable``.
    detail : str
        Every finding, one per line (for a tooltip).
    score : float
        Usable share of the window [%] (0 without data), for sorting.
    """
    q = quality or {}
    valid = q.get("valid_pct")
    issues = [str(i) for i in (q.get("issues") or [])]
    words = []
    if not _finite(valid):
        words.append("no usable data")
        valid = 0.0
    elif valid < 95:
        words.append(f"{valid:.0f} % usable")
    if q.get("compressed"):
        words.append("compressed")
    if _finite(q.get("frozen_pct")) and q["frozen_pct"] >= 5:
        words.append("PV frozen")
    if _finite(q.get("saturation_pct")) and q["saturation_pct"] >= 5:
        words.append("OP saturated")
    if _finite(q.get("manual_pct")) and q["manual_pct"] >= 5:
        words.append("manual mode")
    if _finite(q.get("bad_pct")) and q["bad_pct"] >= 5:
        words.append("bad states")
    label = "; ".join(words) if words else "good"
    return label, "\n".join(issues) if issues else "no findings", float(valid)


def _amount(r) -> str | None:
    unit = f" {r.unit}" if r.unit else ""
    if not _finite(r.amplitude):
        return None
    size = f"±{r.amplitude:.3g}{unit}"
    if _finite(r.amplitude_pct_span):
        size += f" ({r.amplitude_pct_span:.2g} % of the measuring span)"
    parts = [f"The {_what(r)} swings by {size}"]
    if _finite(r.period_s):
        parts.append(f"once every {duration_text(r.period_s)}")
    ev = r.evidence or {}
    window = (r.window_end - r.window_start).total_seconds()
    osc = ev.get("oscillating_s")
    text = " ".join(parts)
    if _finite(osc) and window > 0:
        text += (f", for {duration_text(osc)} of the {duration_text(window)} window "
                 f"({100 * osc / window:.0f} %)")
    return text + "."


def size_text(size) -> str:
    """A valve fault's size in a few words, e.g. ``'dead band 3.1 % OP (model fit 95 %)'``.

    Parameters
    ----------
    size : dict or None
        :attr:`valvediag.scan.LoopResult.size`.

    Returns
    -------
    str
        Empty when there is no size (no valve fault, or the fit found none).
    """
    if not size:
        return ""
    if _finite(size.get("DB")):
        text = f"dead band {size['DB']:.2g} % OP"
    elif _finite(size.get("S")) and _finite(size.get("J")):
        text = f"stick band S {size['S']:.2g} % OP, slip jump J {size['J']:.2g} % OP"
    else:
        return ""
    if _finite(size.get("fit_pct")):
        text += f" (model fit {size['fit_pct']:.0f} %"
        text += f", confidence {size['confidence']:.2f})" if _finite(size.get("confidence")) \
            else ")"
    return text


def _what(r) -> str:
    return "measurement" if not r.description else f"measurement ({r.description})"


def _position(r) -> str | None:
    """What the valve's reported position showed, where it backs the verdict."""
    vt = (r.evidence or {}).get("valve_travel") or {}
    v = vt.get("verdict")
    if v == "stiction" and r.verdict == "stiction":
        return (f"The valve reports its own position: it stands still while the controller "
                f"output moves, then catches up in jumps ({vt.get('toward')} of them).")
    if v == "backlash" and r.verdict == "backlash":
        return ("The valve reports its own position: after each reversal of the controller "
                "output it stands still, then follows without a jump.")
    if v == "undecided" and r.verdict == "undecided":
        return ("The valve reports its own position: it lags the controller output and "
                "jumps a few times, too few to tell sticking from play.")
    if v == "linear" and r.verdict in ("linear-oscillation", "no-oscillation"):
        return ("The valve reports its own position, and it follows the controller output: "
                "the valve is not what makes the loop swing.")
    return None


def _how(r) -> str | None:
    how = _how_shape(r)
    pos = _position(r)
    if pos is None:
        return how
    return f"{how} {pos}" if how else f"How we know: {pos[0].lower()}{pos[1:]}"


def _how_shape(r) -> str | None:
    how = _how_turns(r)
    avg = (r.evidence or {}).get("bi_averaging_s")
    if how and r.verdict in ("stiction", "backlash", "undecided") and _finite(avg) and avg > 0:
        how += (f" The export averages the measurement over each {avg:g} s sample (loops.csv), "
                f"which rounds every turn a little; the turns were read as so averaged.")
    return how


def _how_turns(r) -> str | None:
    ev = r.evidence or {}
    lo, hi = (ev.get("bi_thresholds") or [math.nan, math.nan])[:2]
    if r.verdict == "stiction" and _finite(r.bi):
        return (f"How we know: the measurement turns sharply at its peaks and valleys, as "
                f"steep there as in the middle of its ramps (zoom plot; Backlash Index "
                f"{r.bi:.2f}, and up to {lo:g} means stiction). A sticky valve moves in jumps, "
                f"so the flow changes abruptly.")
    if r.verdict == "backlash" and _finite(r.bi):
        return (f"How we know: the measurement runs in straight ramps and rounds off at its "
                f"peaks and valleys, where it is {r.bi:.1f} times flatter than mid-ramp (zoom "
                f"plot; Backlash Index {r.bi:.2f}, and {hi:g} or more means backlash). A valve "
                f"with play lags each reversal of the controller, then follows smoothly.")
    if r.verdict == "undecided" and _finite(r.bi):
        return (f"How we know: the swing is not a smooth wave, so the valve does not respond "
                f"in proportion, but its Backlash Index {r.bi:.2f} lies between {lo:g} "
                f"(stiction) and {hi:g} (backlash).")
    if r.verdict == "linear-oscillation":
        d = ev.get("pv_distortion")
        clock = ev.get("phase_wander") or {}
        if clock.get("keeps_clock") and _finite(clock.get("wander")):
            n = clock.get("crossings") or 0
            return (f"How we know: over {n} cycles the swing keeps time like a clock: each "
                    f"cycle comes a little early or late, but the error never carries over "
                    f"(its timing scatters {clock['wander']:.2f} times the spread of one "
                    f"cycle's length about a steady clock; a valve's own swing drifts with "
                    f"the noise, about {n / 15:.0f} times over so many cycles).")
        if ev.get("op_moves") is False:
            return ("How we know: the measurement swings while the controller output stands "
                    "still, so the swing comes from outside the loop.")
        if _finite(d):
            return (f"How we know: one average cycle of the swing is almost a perfect sine "
                    f"wave (harmonic distortion {d:.3f}; a sticky or loose valve makes "
                    f"corners or flat tops, as in the bottom plot).")
    return None


def read_from_events(r) -> str | None:
    """What a valve verdict read from the valve's events stands on.

    Parameters
    ----------
    r : valvediag.scan.LoopResult

    Returns
    -------
    str or None
        ``'rests'`` (the valve resting at the OP's reversals), ``'jumps'``
        (a flow's slips or take-ups), ``'kinks'`` (a level's slope steps),
        ``'steps'`` (a level's answer to its set-point steps) or
        ``'events'``; None for a verdict read from a cycle, or no valve
        verdict.
    """
    ev = r.evidence or {}
    if not ev.get("from_events") or r.verdict not in ("stiction", "backlash", "undecided"):
        return None
    if r.verdict == "backlash" and (ev.get("reversal_rests") or {}).get("found"):
        return "rests"
    if (ev.get("stick_slip") or {}).get("found"):
        return "kinks" if ev.get("process_screen") == "integrating" else "jumps"
    if (ev.get("setpoint_bumps") or {}).get("found"):
        return "steps"
    return "events"


def swings_regularly(r) -> bool:
    """Does the loop swing regularly?

    Parameters
    ----------
    r : valvediag.scan.LoopResult

    Returns
    -------
    bool
        :func:`valvediag.analysis.oscillation.regular_oscillation` of the
        figures the result's evidence keeps (False where it keeps none).
    """
    ev = r.evidence or {}
    return regular_oscillation(ev.get("cycles"), ev.get("regularity"), ev.get("acf_at_period"),
                               ev.get("periodic_fraction"))


def _how_events(r, kind: str) -> str | None:
    """How a valve verdict without a limit cycle was read, in plain words."""
    ev = r.evidence or {}
    if kind == "rests":
        rr = ev["reversal_rests"]
        n = rr.get("excursions") if rr.get("by_turns") else rr.get("rests")
        band = rr.get("dead_band")
        far = f" about {band:.2g} %" if _finite(band) else ""
        return (f"How we know: at {n} of the controller's reversals the measurement ran on, "
                f"away from its set point, "
                f"until the output had moved back{far}, and only then followed it: the "
                f"slack in the valve, taken up each time.")
    ss = ev.get("stick_slip") or {}
    n = ss.get("consistent")
    crept = ss.get("op_travel")
    crept = f" about {crept:.2g} %" if _finite(crept) else ""
    if kind == "jumps" and r.verdict == "backlash":
        return (f"How we know: {n} times the error grew while the controller output "
                f"crept{crept} and the measurement did not answer; then the measurement came "
                f"back only as the output moved on: the valve took up its slack.")
    if kind == "jumps":
        return (f"How we know: {n} times the controller output crept{crept} while the "
                f"measurement did not answer, then the measurement jumped in one go: the "
                f"valve stuck, then slipped.")
    if kind == "kinks":
        return (f"How we know: {n} times the level ran in a straight line while the "
                f"controller output crept{crept}, then its slope changed at once: the valve "
                f"stood still, then jumped.")
    if kind == "steps":
        b = ev.get("setpoint_bumps") or {}
        return (f"How we know: at {b.get('against')} of the {b.get('steps')} set-point "
                f"changes the level did not answer the controller's kick as a free valve "
                f"would: the valve held.")
    return None


def _opening(r) -> str:
    v = r.verdict
    events = read_from_events(r)
    if events and v in ("stiction", "backlash"):
        what = ("sticks: it holds its position while the controller pushes, then jumps"
                if v == "stiction" else
                "has play (backlash or dead band): each time the controller reverses, the "
                "valve does not move until the slack in the linkage or positioner is taken "
                "up")
        if swings_regularly(r):
            return (f"The control valve {what}. Its movements show in the record, read one by "
                    f"one beside the loop's swing.")
        return (f"The control valve {what}. The loop does not swing regularly, but the "
                f"valve's movements show in the record and cost control all the same.")
    if v == "stiction":
        return ("The control valve sticks: it holds its position while the controller "
                "pushes, then jumps. The loop therefore never settles and swings in a "
                "regular saw-tooth.")
    if v == "backlash":
        return ("The control valve has play (backlash or dead band): each time the "
                "controller reverses, the valve does not move until the slack in the linkage "
                "or positioner is taken up. The loop therefore swings regularly.")
    if v == "undecided":
        return ("The control valve does not follow the controller in proportion, but the "
                "data cannot tell whether it sticks or has play.")
    if v == "linear-oscillation":
        if ((r.evidence or {}).get("phase_wander") or {}).get("keeps_clock"):
            return ("The loop swings regularly, in step with something outside it that "
                    "keeps its own time (a machine, a timer, a batch step elsewhere in the "
                    "plant): a sticky or loose valve's swing would drift in timing with the "
                    "noise. The likely cause is that disturbance, not this valve; trace it.")
        if ((r.evidence or {}).get("valve_travel") or {}).get("verdict") == "linear":
            return ("The loop swings regularly, but its valve follows the controller, as its "
                    "reported position shows. The likely cause is the controller tuning or a "
                    "disturbance coming from elsewhere in the plant, not this valve.")
        return ("The loop swings regularly, but smoothly, like a sine wave: a sticky or loose "
                "valve would distort the swing. The likely cause is the controller tuning or "
                "a disturbance coming from elsewhere in the plant, not this valve.")
    if v == "not-integrating":
        return ("An earlier version of this tool found the loop oscillating on a "
                "self-regulating process and did not assess its valve.")
    if v == "no-oscillation":
        return "The loop does not oscillate: nothing to do."
    return "The loop could not be assessed."


def explain(r, history=None) -> list[str]:
    """A few plain sentences on one loop's verdict, for a maintenance planner.

    Parameters
    ----------
    r : valvediag.scan.LoopResult
        The loop's result.
    history : valvediag.report.history.LoopHistory, optional
        Its history across runs (new or repeat, since when).

    Returns
    -------
    list of str
        Plain text (not escaped): what is wrong, how big, how we know, how
        sure, since when.
    """
    out = [_opening(r)]
    if r.verdict in ("insufficient-data",):
        out.append(f"Why: {r.reason}.")
        return out
    events = read_from_events(r)
    amount = _amount(r)
    if amount and r.verdict != "no-oscillation" and (not events or swings_regularly(r)):
        # a record read by its events may hold no regular swing to size
        out.append(amount)
    how = (_how_events(r, events) if events else None) or _how(r)
    if how:
        out.append(how)
    ev = r.evidence or {}
    type_unknown = ev.get("process_type_source") == "unknown"
    size_d = getattr(r, "size", None) or {}
    size = size_text(size_d)
    if size and r.verdict in ("stiction", "backlash"):
        src = "a loop model fitted to the data" if _finite(size_d.get("fit_pct")) else \
            str(size_d.get("model") or "the data")
        out.append(f"Size, from {src}: {size}.")
    if r.needs_action:
        sure = confidence_word(r.confidence)
        notes = []
        q = r.quality or {}
        if q.get("compressed"):
            notes.append("the historian compresses this measurement, which can distort its "
                         "shape")
        if _finite(ev.get("agreement")) and ev["agreement"] < 0.999:
            notes.append("parts of the day disagree on the verdict")
        if type_unknown and r.verdict in ("stiction", "backlash", "undecided"):
            # valve events on a loop of unknown type are read as a flow's, a
            # cycle by the data test of its ramps, else as a level's
            screen = ev.get("process_screen")
            if events:
                kind = "integrating" if screen == "integrating" else "self-regulating"
                notes.append("the process type is not in the loop list, so the record was "
                             f"read as a {kind} loop's")
            elif screen in ("integrating", "self-regulating"):
                notes.append("the process type is not in the loop list; the shape of the "
                              f"swing reads as a {screen} process's")
            else:
                notes.append("the process type is not in the loop list, so it was assumed "
                             "to be integrating")
        s = f"Confidence {r.confidence:.2f} ({sure})"
        s += f": {'; '.join(notes)}." if notes else "."
        out.append(s)
    if history is not None and history.status:
        if history.status == "new":
            out.append("First reported in this run.")
        else:
            when = history.first_reported.strftime("%Y-%m-%d") if history.first_reported \
                else "an earlier run"
            out.append(f"Still open: first reported on {when}; {history.open_runs} runs have "
                       f"found it so far.")
    return out
