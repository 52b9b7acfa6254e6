"""Tests of valvediag.outputs: verdicts.json, work_orders.csv and report.html."""
from __future__ import annotations

import csv
import datetime as dt
import html.parser
import json
import math
import re

import pytest

from valvediag.outputs import (RECOMMENDED_ACTIONS, WORK_ORDER_COLUMNS, loop_anchor,
                               render_report, write_outputs)
from valvediag.scan import Episode, LoopResult, rank_results

UTC = dt.timezone.utc
T0 = dt.datetime(2026, 1, 1, tzinfo=UTC)
T1 = T0 + dt.timedelta(hours=24)
EVIL = '<script>alert("x")</script> & "FIC-1"'
NAN = math.nan


def loop_result(loop, verdict, severity=0.0, *, bi=NAN, period=NAN, amplitude=NAN,
                description="", episodes=(), reason=None):
    return LoopResult(
        loop=loop, unit="m3/h", verdict=verdict, confidence=0.8, severity=severity, rank=None,
        process_type="integrating", bi=bi, period_s=period, amplitude=amplitude,
        amplitude_pct_span=NAN if amplitude != amplitude else 100 * amplitude / 50,
        regularity=NAN, reason=reason or f"because {verdict}",
        evidence={"problems": [], "cycles": 12.0}, quality={"issues": ["2 gaps in PV/OP"]},
        episodes=episodes, window_start=T0, window_end=T1, description=description)


@pytest.fixture()
def results():
    ep = Episode(start=T0, end=T0 + dt.timedelta(hours=3), period_s=120.0, amplitude=1.0,
                 regularity=5.0, verdict="stiction", bi=1.1, confidence=0.9)
    return rank_results([
        loop_result("LIC100", "no-oscillation"),
        loop_result("LIC101", "stiction", 0.5, bi=1.1, period=120.0, amplitude=1.0,
                    episodes=(ep,), description="Drum <D-1> level"),
        loop_result(EVIL, "backlash", 0.7, bi=4.0, period=300.0, amplitude=2.0,
                    reason="rounded peaks <b>bold</b>"),
        loop_result("LIC103", "undecided", 0.1, bi=2.3, period=200.0, amplitude=0.5),
        loop_result("LIC104", "linear-oscillation", 0.3, period=600.0, amplitude=1.5),
        loop_result("LIC105", "insufficient-data", reason="no PV tag in loops.csv"),
        loop_result("LIC106", "not-integrating", 0.9, period=50.0, amplitude=1.0),
    ])


def test_verdicts_json_has_exactly_the_contract(results, tmp_path):
    paths = write_outputs(results, tmp_path, run_id="run-1", run_info={})
    text = paths["verdicts"].read_text(encoding="utf-8")
    assert "NaN" not in text
    doc = json.loads(text)
    assert set(doc) == {"run_id", "loops"} and doc["run_id"] == "run-1"
    required = {"loop", "verdict", "rank", "severity", "confidence", "process_type", "bi",
                "period_s", "amplitude", "reason"}
    assert all(required <= set(e) for e in doc["loops"])
    assert [e["loop"] for e in doc["loops"]] == [r.loop for r in results]
    by = {e["loop"]: e for e in doc["loops"]}
    assert by[EVIL]["rank"] == 1 and by["LIC101"]["rank"] == 2
    assert by["LIC100"]["rank"] is None and by["LIC100"]["bi"] is None
    assert by["LIC100"]["period_s"] is None and by["LIC101"]["bi"] == 1.1


def test_work_orders_list_the_loops_needing_action_in_rank_order(results, tmp_path):
    paths = write_outputs(results, tmp_path, run_id="run-1", run_info={})
    with open(paths["work_orders"], newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == WORK_ORDER_COLUMNS
    assert [r["loop"] for r in rows] == [EVIL, "LIC101", "LIC104", "LIC103"]
    assert [r["fault"] for r in rows] == ["backlash", "stiction", "linear-oscillation",
                                          "undecided"]
    assert [int(r["rank"]) for r in rows] == [1, 2, 3, 4]
    act = {r["fault"]: r["recommended_action"] for r in rows}
    assert "Hägglund 2007" in act["backlash"] and "mechanical repair" in act["backlash"]
    assert "valve maintenance" in act["stiction"] and "positioner" in act["stiction"]
    assert "tuning" in act["linear-oscillation"] and "disturbance" in act["linear-oscillation"]
    assert act["undecided"].startswith("inspect")
    assert act == {k: RECOMMENDED_ACTIONS[k] for k in act}
    assert rows[1]["report_link"] == "report.html#loop-LIC101"
    assert rows[0]["severity"] == "0.7" and rows[0]["confidence"] == "0.80"


class _Collect(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids, self.hrefs, self.tags = [], [], set()

    def handle_starttag(self, tag, attrs):
        self.tags.add(tag)
        a = dict(attrs)
        if "id" in a:
            self.ids.append(a["id"])
        if "href" in a:
            self.hrefs.append(a["href"])
        if "src" in a:
            self.hrefs.append(a["src"])


def test_report_is_self_contained_escaped_and_linked(results, tmp_path):
    info = {"window_start": T0, "window_end": T1, "generated": T1, "exports": ["a<b>.csv"],
            "registry_problems": ["loops.csv line 3 (loop X): no PV tag in loops.csv"],
            "ingest_errors": ["/x/bad.csv: unknown columns ['foo']"], "new_faults": ["LIC101"],
            "config": {"window_hours": 24.0, "end": None}}
    paths = write_outputs(results, tmp_path, run_id="run-<1>", run_info=info)
    text = paths["report"].read_text(encoding="utf-8")
    assert "<script" not in text and "<b>bold</b>" not in text
    assert "&lt;script&gt;" in text and "&lt;b&gt;bold&lt;/b&gt;" in text
    assert "run-&lt;1&gt;" in text and "a&lt;b&gt;.csv" in text
    p = _Collect()
    p.feed(text)
    assert "link" not in p.tags and "script" not in p.tags and "img" not in p.tags
    assert all(h.startswith("#") for h in p.hrefs)                 # no external resources
    assert len(p.ids) == len(set(p.ids))
    for r in results:                                              # every loop has a section
        assert loop_anchor(r.loop) in p.ids
    with open(paths["work_orders"], newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):                             # every link resolves
            assert row["report_link"].split("#", 1)[1] in p.ids
    # ranked table in rank order, problems and the new-fault mark shown
    first = text.index("Loops needing action")
    order = [text.index(f'href="#{loop_anchor(lp)}"', first) for lp in
             (EVIL, "LIC101", "LIC104", "LIC103")]
    assert order == sorted(order)
    assert "unknown columns" in text and "no PV tag in loops.csv" in text
    assert re.search(r'LIC101</a> <span class="new">new</span>', text)
    assert "Drum &lt;D-1&gt; level" in text


def test_report_without_any_fault_or_run_info():
    text = render_report([loop_result("A", "no-oscillation")], run_id="r")
    assert "No loop needs action." in text and 'id="loop-A"' in text


def test_loop_anchor_is_unique_and_url_safe():
    names = ["LIC101", "LIC 101", "LIC/101", "LIC-101", EVIL, "Ü-1"]
    anchors = [loop_anchor(n) for n in names]
    assert anchors[0] == "loop-LIC101" and anchors[3] == "loop-LIC-101"
    assert len(set(anchors)) == len(anchors)
    assert all(re.fullmatch(r"loop-[A-Za-z0-9_.\-]+", a) for a in anchors)
