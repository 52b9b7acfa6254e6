"""Tests of valvediag.report: the evidence figures (reproducible SVG), the plot data kept
by the scan, sparklines and history strips, and the verdicts in plain words."""
from __future__ import annotations

import dataclasses
import datetime as dt
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import polars as pl
import pytest
from scipy import signal

from valvediag.io.registry import LoopSpec
from valvediag.report.explain import duration_text, explain, quality_label
from valvediag.report.figures import loop_figure, render_loop_figures
from valvediag.report.history import LoopHistory
from valvediag.report.html import render_report
from valvediag.report.svg import history_svg, sparkline_svg
from valvediag.scan.loop import analyse_loop
from valvediag.scan.plant import rank_results
from valvediag.scan.types import SPARK_BUCKETS, TREND_BUCKETS, LoopJob, reduce_to_buckets

UTC = dt.timezone.utc
T0 = dt.datetime(2026, 1, 1, tzinfo=UTC)
P = 120.0


def frame(seconds, values):
    return pl.DataFrame({"ts": [T0 + dt.timedelta(seconds=float(s)) for s in seconds],
                         "value": pl.Series(values, dtype=pl.Float64),
                         "status": pl.Series([None] * len(values), dtype=pl.String)})


def analysed(kind: str, loop: str = "LIC1", seed: int = 1, hours: float = 2.0):
    """A loop analysed by the scan, with its plot data: 'stiction', 'linear' or 'quiet'."""
    rng = np.random.default_rng(seed)
    t = np.arange(hours * 3600.0)
    if kind == "stiction":
        tri = signal.sawtooth(2 * np.pi * t / P, 0.5)
        pv = 50 + tri + rng.normal(0, 0.01, t.size)
        op = 50 + 5 * signal.square(2 * np.pi * t / P + 0.3) + 2 * tri
    elif kind == "clock":
        # a clipped sine kept by a clock, whose noise a P controller answers
        pv = 50 + np.clip(1.5 * np.sin(2 * np.pi * t / P), -1, 1) + rng.normal(0, 0.05, t.size)
        op = 40 - 1.5 * (pv - 50)
    elif kind == "linear":
        pv = 50 + np.sin(2 * np.pi * t / P) + rng.normal(0, 0.01, t.size)
        op = 50 + 5 * np.sin(2 * np.pi * t / P + 1)
    else:
        pv = 50 + rng.normal(0, 0.05, t.size)
        op = 50 + rng.normal(0, 0.2, t.size)
    spec = LoopSpec(loop, f"{loop}.PV", f"{loop}.OP", f"{loop}.SP", process_type="integrating",
                    span=100.0, unit="%", description="Drum level")
    frames = {"pv": frame(t, pv), "op": frame(t, op), "sp": frame([0.0], [50.0])}
    job = LoopJob(spec, T0, T0 + dt.timedelta(seconds=t.size), ())
    return analyse_loop(job, frames)


@pytest.fixture(scope="module")
def loops():
    """Stiction (LIC1), linear oscillation (FIC2) and a quiet loop (TIC3), in that order."""
    ranked = {r.loop: r for r in rank_results([analysed("stiction"),
                                               analysed("linear", "FIC2", 2),
                                               analysed("quiet", "TIC3", 3)])}
    return [ranked["LIC1"], ranked["FIC2"], ranked["TIC3"]]


# ------------------------------------------------------------------ plot data of the scan

def test_scan_keeps_plot_data_only_where_the_report_needs_it(loops):
    by = {r.loop: r for r in loops}
    assert by["LIC1"].verdict == "stiction" and by["FIC2"].verdict == "linear-oscillation"
    assert by["TIC3"].verdict == "no-oscillation"
    for r in loops:                        # a sparkline for every loop
        assert r.detail.sparkline.size == 2 * SPARK_BUCKETS
    quiet = by["TIC3"].detail
    assert quiet.trend is None and quiet.diagnosis is None
    d = by["LIC1"].detail
    assert d.trend.pv.size <= 2 * TREND_BUCKETS and d.trend.sp is not None
    assert d.diagnosis.verdict == "stiction" and d.diagnosis.backlash is not None
    assert d.diagnosis_start == by["LIC1"].episodes[0].start
    # not in JSON, not in equality: the store and verdicts.json never see the arrays
    assert "detail" not in by["LIC1"].to_json()
    assert by["LIC1"] == dataclasses.replace(by["LIC1"], detail=None)


def test_trend_keeps_each_buckets_extremes_in_time_order():
    y = np.array([0, 5, -3, 1, 2, 9, 9, 8, np.nan, np.nan, np.nan, np.nan, 4.0])
    r = reduce_to_buckets(y, 4)                                     # buckets of 4 points
    assert r.tolist()[:4] == [5, -3, 2, 9]                # max before min, then min before max
    assert np.isnan(r[4:6]).all() and r[6:].tolist() == [4, 4]
    small = reduce_to_buckets(np.arange(5.0), 10)                   # fewer points than buckets: as is
    assert small.tolist() == [0, 1, 2, 3, 4]


# ----------------------------------------------------------------------- figures

def test_figure_is_reproducible_byte_for_byte(loops):
    r = loops[0]
    a, b = loop_figure(r, "f0"), loop_figure(r, "f0")
    assert a == b
    assert loop_figure(r, "f1") == a.replace('"f0-', '"f1-').replace("#f0-", "#f1-")
    # no date, no version, no comment; every id carries the prefix and every reference
    # points into the same figure
    assert "<metadata" not in a and "<!--" not in a and "<?xml" not in a
    assert not re.search(r"\d{4}-\d\d-\d\dT\d\d:", a)
    ids = re.findall(r'\bid="([^"]+)"', a)
    assert ids and all(i.startswith("f0-") for i in ids) and len(ids) == len(set(ids))
    refs = re.findall(r'(?:url\(#|href="#)([^")]+)', a)
    assert refs and set(refs) <= set(ids)
    root = ET.fromstring(a)                               # well-formed XML
    assert root.tag.endswith("svg") and root.get("role") == "img"


def test_figures_of_worker_processes_are_the_same_bytes(loops):
    jobs = [(r, f"f{k}") for k, r in enumerate(loops[:2])]
    here = render_loop_figures(jobs, workers=1)
    there = render_loop_figures(jobs, workers=2)
    assert here == there and all(s.startswith("<svg") for s in here)


def test_figure_draws_the_evidence_of_each_kind(loops):
    stiction, linear = loops[0], loops[1]
    s = loop_figure(stiction, "a")
    assert "Backlash Index of every half cycle" in s and "Zoom on 4 cycles" in s
    assert "Phase plot" in s and "Controller output" in s
    lin = loop_figure(linear, "b")
    assert "sine wave" in lin and "Backlash Index of every half cycle" not in lin
    assert loop_figure(loops[2], "c") is None              # healthy: no figure


def test_figure_of_a_swing_that_keeps_a_clock_shows_its_timing():
    r = analysed("clock", "FIC4", 4)
    assert r.verdict == "linear-oscillation" and r.detail.diagnosis.clock.keeps_clock, r.reason
    s = loop_figure(r, "k")
    assert "Each cycle&#39;s start against a steady clock" in s
    assert "sine wave" not in s and "Backlash Index of every half cycle" not in s
    ET.fromstring(s)


def test_figure_text_from_the_data_is_escaped(loops):
    r = dataclasses.replace(loops[0], unit="<b>&$x$")
    s = loop_figure(r, "e")
    assert "<b>" not in s and "&lt;b&gt;&amp;" in s
    ET.fromstring(s)


# ------------------------------------------------------------- sparklines and history

def test_sparkline_breaks_at_gaps_and_flat_lines_show():
    s = sparkline_svg([1, 2, np.nan, 3, 4, 5])
    assert s.count("<polyline") == 2
    assert sparkline_svg([2, 2, 2]).count("<polyline") == 1
    assert sparkline_svg(None) == "" and sparkline_svg([np.nan, np.nan]) == ""
    assert 'aria-label="&lt;x&gt;"' in sparkline_svg([1, 2], label="<x>")
    ET.fromstring(str(sparkline_svg([0, 1, 0.5])))


def test_history_strip_marks_each_run_and_escapes_tooltips():
    pts = [{"verdict": "stiction", "bi": 1.1, "label": "<r1>"},
           {"verdict": "insufficient-data", "bi": None, "label": "r2"},
           {"verdict": "backlash", "bi": 9.0, "label": "r3", "current": True}]
    s = str(history_svg(pts))
    root = ET.fromstring(s)
    assert len(root.findall("circle")) == 2                 # BI measured in two runs
    assert len(root.findall("rect")) == 2                   # the frame and the run without BI
    assert "&lt;r1&gt;" in s and 'stroke="#000"' in s


# ---------------------------------------------------------------- plain words

def test_plain_words_for_a_planner(loops):
    stiction, linear, quiet = loops
    words = " ".join(explain(stiction, LoopHistory("LIC1", status="new")))
    assert "sticks" in words and "Drum level" in words and "once every 2 min" in words
    assert "Backlash Index" in words and "First reported in this run" in words
    assert "Confidence" in words
    lin = " ".join(explain(linear))
    assert "sine wave" in lin and "not this valve" in lin
    assert explain(quiet)[0].startswith("The loop does not oscillate")
    # a valve verdict on a loop of unknown type says the loop was assumed integrating
    assert "assumed to be integrating" not in " ".join(explain(stiction))
    sticky = dataclasses.replace(stiction, evidence={**(stiction.evidence or {}),
                                                     "process_type_source": "unknown"})
    assert "assumed to be integrating" in " ".join(explain(sticky))
    rep = LoopHistory("LIC1", status="repeat", first_reported=T0, open_runs=4)
    assert "first reported on 2026-01-01; 4 runs" in " ".join(explain(stiction, rep))
    # turns read as a historian's averages say so
    assert "averages the measurement" not in words
    averaged = dataclasses.replace(stiction, evidence={**(stiction.evidence or {}),
                                                       "bi_averaging_s": 30.0})
    assert "averages the measurement over each 30 s sample" in " ".join(explain(averaged))


def test_plain_words_for_a_swing_that_keeps_a_clock(loops):
    # a swing read as a load from outside by its steady timing: the words say
    # so, and do not call it a smooth sine wave
    linear = loops[1]
    clock = dataclasses.replace(linear, evidence={
        **(linear.evidence or {}), "pv_distortion": 0.2,
        "phase_wander": {"keeps_clock": True, "crossings": 300, "wander": 0.51}})
    words = " ".join(explain(clock))
    assert "keeps its own time" in words and "like a sine wave" not in words
    assert "over 300 cycles the swing keeps time like a clock" in words
    assert "0.51 times" in words and "about 20 times" in words
    # a swing whose timing wanders keeps the words it had
    wanders = dataclasses.replace(linear, evidence={
        **(linear.evidence or {}),
        "phase_wander": {"keeps_clock": False, "crossings": 300, "wander": 9.0}})
    assert "keeps its own time" not in " ".join(explain(wanders))


def test_plain_words_for_a_valve_read_from_its_events(loops):
    # a verdict read from the valve's events stands on no regular swing: the
    # words say so, say what was seen, and where its size comes from
    stiction = loops[0]
    base = {**{k: v for k, v in (stiction.evidence or {}).items()
               if k not in ("process_screen", "process_type_source")},
            "regularity": 0.4, "cycles": 2.0}
    rests = dataclasses.replace(
        stiction, verdict="backlash",
        evidence={**base, "from_events": True, "process_type_source": "loops.csv",
                  "reversal_rests": {"found": True, "rests": 7, "excursions": 20,
                                     "by_turns": False, "dead_band": 2.1}},
        size={"DB": 2.1, "confidence": 0.5,
              "model": "the OP's travel while the valve rested at its reversals"})
    words = " ".join(explain(rests))
    assert "swings regularly" not in words and "once every" not in words
    assert "at 7 of the controller's reversals" in words and "about 2.1 %" in words
    assert "Size, from the OP's travel while the valve rested at its reversals: dead band" \
        in words
    assert "loop model" not in words
    # and the figure does not call the stretch it shades an oscillation
    svg = loop_figure(rests, "ev")
    assert "the stretch whose valve events were read shaded" in svg
    assert "oscillating stretches shaded" in loop_figure(stiction, "cy")
    jumps = dataclasses.replace(
        stiction, evidence={**base, "from_events": True, "process_screen": "self-regulating",
                            "process_type_source": "unknown",
                            "stick_slip": {"found": True, "kind": "stiction", "consistent": 5,
                                           "slips": 5, "takeups": 0, "op_travel": 0.8}},
        size={"S": math.nan, "J": math.nan, "confidence": 0.0})
    words = " ".join(explain(jumps))
    assert "never settles" not in words and "once every" not in words
    assert "5 times the controller output crept about 0.8 %" in words
    assert "jumped in one go" in words
    # a loop of unknown type read by its events was read as a flow, not a level
    assert "read as a self-regulating loop's" in words
    assert "assumed to be integrating" not in words
    kinks = dataclasses.replace(jumps, evidence={**jumps.evidence,
                                                 "process_screen": "integrating",
                                                 "process_type_source": "loops.csv"})
    words = " ".join(explain(kinks))
    assert "ran in a straight line" in words and "not in the loop list" not in words
    # the cycle's own words where there is a cycle
    assert "once every" in " ".join(explain(stiction))
    # valve events read beside a regular swing (a loose flow valve under a
    # ringing load): the swing is sized, the events say how we know
    ringing = dataclasses.replace(rests, evidence={**rests.evidence, "regularity": 5.0,
                                                   "cycles": 12.0, "acf_at_period": 0.8,
                                                   "periodic_fraction": 0.9})
    words = " ".join(explain(ringing))
    assert "once every" in words and "beside the loop's swing" in words
    assert "at 7 of the controller's reversals" in words


def test_durations_and_quality_labels():
    assert [duration_text(x) for x in (45, 437, 3000, 9000, 86400)] == \
        ["45 s", "7.3 min", "50 min", "2.5 h", "24 h"]
    assert duration_text(math.nan) == "–"
    assert quality_label({"valid_pct": 99.0, "issues": []})[0] == "good"
    label, detail, score = quality_label({"valid_pct": 80.0, "compressed": True,
                                          "issues": ["x", "y"]})
    assert label == "80 % usable; compressed" and detail == "x\ny" and score == 80.0


def test_report_with_figures_renders_each_fault_once(loops):
    text = render_report(loops, run_id="r", workers=1)
    assert text.count('<figure><svg role="img"') == 2        # stiction and linear
    assert text.count('class="spark"') == 3                  # every loop in the table
    assert 'id="loop-TIC3"' in text


def test_report_of_worker_processes_is_the_same_bytes(loops):
    info = {"generated": T0}         # else "now" is the run's start: it would differ
    serial = render_report(loops, run_id="r", run_info=info, workers=1)
    assert render_report(loops, run_id="r", run_info=info, workers=2) == serial
    assert render_report(loops, run_id="r", run_info=info, workers=1) == serial


def test_figure_panels_scales_and_gaps(loops):
    from valvediag.report.plot import HEIGHT, WIDTH, _polyline

    s = loop_figure(loops[0], "g")
    root = ET.fromstring(s)
    assert root.get("viewBox") == f"0 0 {round(WIDTH * 10)} {round(HEIGHT * 10)}"
    assert s.count("<clipPath") == 5                     # one per panel
    # every coordinate is an integer number of tenths of a pixel
    assert not re.search(r'\bd="[^"]*\d\.\d', s)
    # NaN breaks a line: two sub-paths; a lone point between gaps draws nothing
    d = _polyline(np.array([0.0, 1, 2, 3, 4, 5, 6]), np.array([0, 1, np.nan, 2, np.nan, 3, 4.0]))
    assert d == "M0 0l10 10M50 30l10 10"
    # the ticks of the OP panel are clock times, as matplotlib's date locator picks them
    assert re.search(r">\d\d:\d\d</text>", s)


