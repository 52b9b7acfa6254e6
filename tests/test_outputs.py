"""Tests of valvediag.report.outputs: verdicts.json, work orders (CSV, JSON), report.html, and the
history across runs (new, repeat, resolved) read from the store."""
from __future__ import annotations

import csv
import datetime as dt
import html.parser
import json
import math
import re

import pytest

from valvediag.report.history import fault_kind, plant_history, read_history
from valvediag.report.outputs import (
    RECOMMENDED_ACTIONS,
    WORK_ORDER_COLUMNS,
    loop_anchor,
    render_report,
    write_outputs,
)
from valvediag.scan.plant import persist_results, rank_results
from valvediag.scan.types import Episode, LoopResult
from valvediag.store.database import Store

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


def read_csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


# --------------------------------------------------------------- verdicts and work orders

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
    paths = write_outputs(results, tmp_path, run_id="run-1",
                          run_info={"generated": T1})
    rows = read_csv(paths["work_orders"])
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
    # without a store every problem is new, first reported now
    assert {r["status"] for r in rows} == {"new"}
    assert {r["first_reported"] for r in rows} == {"2026-01-02T00:00:00+00:00"}
    doc = json.loads(paths["work_orders_json"].read_text(encoding="utf-8"))
    assert doc["run_id"] == "run-1" and doc["report"] == "report.html"
    assert [o["loop"] for o in doc["work_orders"]] == [r["loop"] for r in rows]
    o = doc["work_orders"][0]
    assert set(WORK_ORDER_COLUMNS) <= set(o) and o["confidence"] == 0.8 and o["rank"] == 1
    assert o["first_run_id"] == "run-1" and o["open_runs"] == 1


# ------------------------------------------------------------------- history

def _store_run(store, run_id, started, loops_verdicts):
    """Store a complete run with these (loop, verdict) results."""
    rs = rank_results([loop_result(lp, v, 0.5 if v in ("stiction", "backlash", "undecided",
                                                         "linear-oscillation") else 0.0)
                       for lp, v in loops_verdicts])
    store.start_run(run_id=run_id)
    persist_results(store, run_id, rs)
    store.finish_run(run_id, "complete")
    store.con.execute("UPDATE runs SET started_at = ? WHERE run_id = ?", [started, run_id])


@pytest.fixture()
def history_store(tmp_path):
    path = tmp_path / "h.duckdb"
    with Store(path) as st:
        _store_run(st, "r1", T0, [("A", "stiction"), ("B", "backlash"), ("C", "stiction"),
                                  ("D", "linear-oscillation"), ("E", "stiction"),
                                  ("F", "stiction")])
        _store_run(st, "r2", T0 + dt.timedelta(days=1),
                   [("A", "backlash"), ("B", "backlash"), ("C", "insufficient-data"),
                    ("D", "linear-oscillation"), ("E", "no-oscillation"),
                    ("F", "stiction")])
    return path


def test_history_new_repeat_resolved_and_first_reported(history_store, tmp_path):
    now = rank_results([loop_result("A", "stiction", 0.9),          # valve, both runs
                        loop_result("B", "no-oscillation"),         # resolved since r2
                        loop_result("C", "stiction", 0.8),          # r2 had no data: still r1
                        loop_result("D", "stiction", 0.7),          # other kind: new
                        loop_result("E", "stiction", 0.6),          # healthy in r2: new again
                        loop_result("F", "insufficient-data"),      # no longer assessable
                        loop_result("G", "backlash", 0.5)])         # never seen: new
    h = read_history(history_store, now, run_id="r3", started_at=T0 + dt.timedelta(days=2))
    assert not h.error and h.runs_compared == 2
    assert h.previous_run["run_id"] == "r2"
    st = {k: (v.status, v.first_run_id, v.open_runs) for k, v in h.loops.items()}
    assert st["A"] == ("repeat", "r1", 3)
    assert st["C"] == ("repeat", "r1", 2)
    assert st["D"] == ("new", "r3", 1) and st["E"] == ("new", "r3", 1)
    assert st["G"] == ("new", "r3", 1)
    assert h.loops["A"].first_reported == T0
    assert h.resolved == (("B", "backlash"),)
    assert h.unassessable == (("F", "stiction"),)
    assert [p.verdict for p in h.of("A").points] == ["stiction", "backlash", "stiction"]
    assert h.of("A").points[-1].current

    paths = write_outputs(now, tmp_path / "out", run_id="r3", store=history_store,
                          run_info={"generated": T0 + dt.timedelta(days=2)})
    rows = {r["loop"]: r for r in read_csv(paths["work_orders"])}
    assert set(rows) == {"A", "C", "D", "E", "G"}               # one row per open loop
    assert rows["A"]["status"] == "repeat"
    assert rows["A"]["first_reported"] == "2026-01-01T00:00:00+00:00"
    assert rows["D"]["status"] == "new" and rows["G"]["status"] == "new"
    text = paths["report"].read_text(encoding="utf-8")
    summary = text[text.index('id="summary"'):text.index('id="ranked"')]
    assert 'href="#loop-B">B</a> <span class="muted">(was backlash)' in summary
    assert "No longer assessable" in summary and 'href="#loop-F"' in summary
    assert "r2" in summary                                       # compared with r2


def test_history_of_a_store_that_cannot_be_read_is_reported_not_fatal(tmp_path):
    bad = tmp_path / "not-a-db.duckdb"
    bad.write_text("this is not a database")
    now = rank_results([loop_result("A", "stiction", 0.9)])
    paths = write_outputs(now, tmp_path / "out", run_id="r", store=bad)
    text = paths["report"].read_text(encoding="utf-8")
    assert "could not be read" in text
    assert read_csv(paths["work_orders"])[0]["status"] == "new"


def test_history_uses_run_info_db_and_counts_only_earlier_complete_runs(tmp_path):
    path = tmp_path / "s.duckdb"
    with Store(path) as st:
        _store_run(st, "old", T0, [("A", "stiction")])
        st.start_run(run_id="broken")                             # never completed
        st.finish_run("broken", "failed")
        st.start_run(run_id="now")                                # the run being reported
    now = rank_results([loop_result("A", "stiction", 0.9)])
    paths = write_outputs(now, tmp_path / "out", run_id="now", run_info={"db": str(path)})
    (row,) = read_csv(paths["work_orders"])
    assert row["status"] == "repeat" and row["first_reported"].startswith("2026-01-01")


def test_fault_kinds():
    assert {fault_kind(v) for v in ("stiction", "backlash", "undecided")} == {"valve"}
    assert fault_kind("linear-oscillation") == "oscillation"
    assert fault_kind("no-oscillation") is None and fault_kind("insufficient-data") is None
    h = plant_history([loop_result("A", "no-oscillation")], run_id="r")
    assert h.of("A").status == "" and h.of("zzz").points == ()


# --------------------------------------------------------------------- report.html

class _Collect(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.ids, self.refs, self.tags, self.scripts = [], [], set(), []

    def handle_starttag(self, tag, attrs):
        self.tags.add(tag)
        a = dict(attrs)
        if "id" in a:
            self.ids.append(a["id"])
        for key in ("href", "src", "xlink:href", "data", "poster", "action", "srcset"):
            if key in a:
                self.refs.append(a[key])
        if tag == "script":
            self.scripts.append(a)


def test_report_is_self_contained_escaped_and_linked(results, tmp_path):
    info = {"window_start": T0, "window_end": T1, "generated": T1, "exports": ["a<b>.csv"],
            "registry_problems": ["loops.csv line 3 (loop X): no PV tag in loops.csv"],
            "ingest_errors": ["/x/bad.csv: unknown columns ['foo']"],
            "config": {"window_hours": 24.0, "end": None}, "plant": "Unit <7>"}
    paths = write_outputs(results, tmp_path, run_id="run-<1>", run_info=info)
    text = paths["report"].read_text(encoding="utf-8")
    # names and texts from the data are escaped: the only script is the report's own
    assert text.count("<script") == 1 and "<b>bold</b>" not in text
    assert "&lt;script&gt;alert" in text and "&lt;b&gt;bold&lt;/b&gt;" in text
    assert "run-&lt;1&gt;" in text and "a&lt;b&gt;.csv" in text and "Unit &lt;7&gt;" in text
    p = _Collect()
    p.feed(text)
    # nothing is fetched from anywhere: no link/img/iframe, no src, only in-page references
    assert not {"link", "img", "iframe", "object", "embed", "audio", "video"} & p.tags
    assert p.scripts == [{}]                                        # inline, no src
    assert all(r.startswith("#") for r in p.refs), [r for r in p.refs if not r.startswith("#")]
    assert "@import" not in text and not re.search(r"url\((?!#)", text)
    assert len(p.ids) == len(set(p.ids))
    for r in results:                                              # every loop has a section
        assert loop_anchor(r.loop) in p.ids
    for row in read_csv(paths["work_orders"]):                     # every link resolves
        assert row["report_link"].split("#", 1)[1] in p.ids
    # ranked table in rank order, problems and the new marks shown
    first = text.index('id="ranked-table"')
    order = [text.index(f'href="#{loop_anchor(lp)}"', first) for lp in
             (EVIL, "LIC101", "LIC104", "LIC103")]
    assert order == sorted(order)
    assert "unknown columns" in text and "no PV tag in loops.csv" in text
    assert re.search(r'LIC101</a> <span class="badge new">new</span>', text)
    assert "Drum &lt;D-1&gt; level" in text


def test_report_without_any_fault_or_run_info():
    text = render_report([loop_result("A", "no-oscillation")], run_id="r")
    assert "No loop needs action." in text and 'id="loop-A"' in text


def test_report_reads_the_same_without_script(results):
    """The table is in rank order in the HTML itself; the script only adds controls."""
    text = render_report(results, run_id="r")
    assert re.search(r'<div id="controls" class="controls" hidden>', text)
    rows = re.findall(r'<tr class="v-[a-z-]+" data-verdict="([a-z-]+)"', text)
    assert rows[:4] == ["backlash", "stiction", "linear-oscillation", "undecided"]


def test_loop_anchor_is_unique_and_url_safe():
    names = ["LIC101", "LIC 101", "LIC/101", "LIC-101", EVIL, "Ü-1"]
    anchors = [loop_anchor(n) for n in names]
    assert anchors[0] == "loop-LIC101" and anchors[3] == "loop-LIC-101"
    assert len(set(anchors)) == len(anchors)
    assert all(re.fullmatch(r"loop-[A-Za-z0-9_.\-]+", a) for a in anchors)


@pytest.mark.parametrize("text", ['=HYPERLINK("http://example.com","x")', "+1+2", "-2+3",
                                  "@SUM(A1)", "\t=1"])
def test_work_orders_csv_never_holds_a_formula(text, tmp_path):
    rows = rank_results([loop_result("LIC200", "stiction", 0.8, bi=1.1, period=100.0,
                                     amplitude=1.0, description=text, reason=text)])
    path = write_outputs(rows, tmp_path, run_id="run-1", run_info={})["work_orders"]
    row = read_csv(path)[0]
    for col in ("description", "reason"):
        assert row[col] == "'" + text and not row[col].startswith(("=", "+", "-", "@", "\t"))
    # the JSON list keeps the text as written
    doc = json.loads((tmp_path / "work_orders.json").read_text(encoding="utf-8"))
    assert doc["work_orders"][0]["description"] == text


def test_a_store_with_the_retired_not_integrating_verdict_still_reads(tmp_path):
    # a store written by an earlier version: a self-regulating loop got
    # 'not-integrating', which scans no longer give
    path = tmp_path / "old.duckdb"
    with Store(path) as st:
        _store_run(st, "old", T0, [("FIC1", "stiction"), ("FIC2", "no-oscillation")])
        st.con.execute("UPDATE verdicts SET verdict = 'not-integrating' "
                       "WHERE run_id = 'old' AND loop = 'FIC1'")
        st.start_run(run_id="now")
    now = rank_results([loop_result("FIC1", "stiction", 0.9),
                        loop_result("FIC2", "no-oscillation")])
    paths = write_outputs(now, tmp_path / "out", run_id="now", run_info={"db": str(path)})
    (row,) = read_csv(paths["work_orders"])
    # the old verdict was no valve fault: the sticky valve is news
    assert row["loop"] == "FIC1" and row["status"] == "new"
    # and its history holds the old verdict
    with Store(path) as st:
        earlier = st.history_before("now")
    h = plant_history(now, run_id="now", earlier=earlier)
    assert [p.verdict for p in h.of("FIC1").points] == ["not-integrating", "stiction"]


def test_the_run_summary_artifact_says_a_partial_run_and_its_problems(results):
    from valvediag.report.artifacts import run_summary_markdown

    paths = {"report": "/o/report.html", "work_orders": "/o/wo.csv", "verdicts": "/o/v.json"}
    complete = run_summary_markdown(results, paths, "run-1", [])
    assert "partial" not in complete and "Problems with the input" not in complete
    partial = run_summary_markdown(results, paths, "run-1", [], status="partial",
                                   problems=["/x/garbled.csv: unknown columns"])
    assert "**This run is partial**" in partial
    assert "- /x/garbled.csv: unknown columns" in partial
    assert partial.index("partial") < partial.index("loops need action")
