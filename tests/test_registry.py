"""Tests of valvediag.io.registry (loops.csv)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from valvediag.io.registry import LoopSpec, RegistryError, read_loops_csv
from valvediag.store.database import Store
from valvediag.store.ingest import ingest_exports

DATA = Path(__file__).parent / "data" / "ingest"


def write(tmp_path: Path, text: str, name: str = "loops.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_reads_loops_with_defaults():
    loops, _ = read_loops_csv(DATA / "loops.csv")
    fic, lic = loops[0], loops[1]
    assert fic == LoopSpec("FIC101", pv_tag="FIC101.PV", op_tag="FIC101.OP", sp_tag="FIC101.SP",
                           process_type="self-regulating", unit="m3/h", span=200.0,
                           criticality=2.0, description="Feed flow")
    assert lic.process_type == "integrating" and lic.criticality == 1.0 and lic.mv_tag is None
    assert fic.tags == {"pv": "FIC101.PV", "op": "FIC101.OP", "sp": "FIC101.SP"}


def test_row_without_pv_tag_is_kept_with_an_issue():
    loops, problems = read_loops_csv(DATA / "loops.csv")
    tic = next(l for l in loops if l.loop == "TIC300")
    assert tic.issues == ("no PV tag in loops.csv",)
    assert not tic.usable and math.isnan(tic.span)
    assert any("line 4 (loop TIC300)" in p and "no PV tag in loops.csv" in p for p in problems)


def test_invalid_process_type_names_the_loop():
    loops, problems = read_loops_csv(DATA / "loops.csv")
    pic = next(l for l in loops if l.loop == "PIC400")
    assert pic.process_type == "unknown"
    assert any("(loop PIC400)" in p and "invalid process_type 'sticky'" in p for p in problems)


def test_a_level_or_a_flow_named_by_its_kind_is_read_as_its_process_type(tmp_path):
    path = write(tmp_path, "loop,pv_tag,op_tag,process_type\n"
                           "LIC1,L.PV,L.OP,Level\nFIC1,F.PV,F.OP, flow\n"
                           "FIC2,G.PV,G.OP,non_integrating\nPIC1,P.PV,P.OP,pressure\n"
                           "TIC1,T.PV,T.OP,\n")
    loops, problems = read_loops_csv(path)
    assert [l.process_type for l in loops] == ["integrating", "self-regulating",
                                               "self-regulating", "unknown", "unknown"]
    # a pressure may integrate or settle: the data decide, and the file is told
    assert problems == [p for p in problems if "(loop PIC1)" in p] and len(problems) == 1
    assert "invalid process_type 'pressure'" in problems[0] and "level or flow" in problems[0]


def test_the_sampling_of_an_export_is_read_in_the_words_historians_use(tmp_path):
    path = write(tmp_path, "loop,pv_tag,op_tag,sampling\n"
                           "A,A.PV,A.OP,\nB,B.PV,B.OP,Average\nC,C.PV,C.OP,time weighted\n"
                           "D,D.PV,D.OP,interpolated\nE,E.PV,E.OP,hourly\n")
    loops, problems = read_loops_csv(path)
    assert [l.sampling for l in loops] == ["point", "average", "average", "point", "point"]
    assert len(problems) == 1 and "(loop E)" in problems[0]
    assert "invalid sampling 'hourly'" in problems[0] and "point or average" in problems[0]
    assert loops[4].issues == ("invalid sampling 'hourly' (expected point or average); "
                               "using 'point'",)


def test_duplicate_loop_name_keeps_the_first_and_reports():
    loops, problems = read_loops_csv(DATA / "loops.csv")
    assert [l.loop for l in loops] == ["FIC101", "LIC200", "TIC300", "PIC400"]
    assert next(l for l in loops if l.loop == "FIC101").pv_tag == "FIC101.PV"
    assert any("line 6 (loop FIC101): duplicate loop name (first on line 2)" in p
               for p in problems)
    assert len(problems) == 3


def test_unknown_columns_are_a_one_line_error(tmp_path):
    path = write(tmp_path, "loop,pv_tag,op_tag,owner,color\nA,a,b,me,red\n")
    with pytest.raises(RegistryError) as err:
        read_loops_csv(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and "['owner', 'color']" in msg


@pytest.mark.parametrize("text, match", [
    ("", "empty loop registry"),
    ("loop,op_tag\nA,a\n", r"missing required columns \['pv_tag'\]"),
    ("loop,pv,pv_tag,op\nA,a,a,b\n", r"columns \['pv_tag'\] given more than once"),
])
def test_unusable_headers_are_errors(tmp_path, text, match):
    with pytest.raises(RegistryError, match=match):
        read_loops_csv(write(tmp_path, text))


def test_missing_file_is_an_error(tmp_path):
    with pytest.raises(RegistryError, match="nope.csv: cannot read loop registry"):
        read_loops_csv(tmp_path / "nope.csv")


def test_header_aliases_and_blank_lines(tmp_path):
    path = write(tmp_path, "Loop,PV,OP,Mode,Process_Type,Span\n\nA,a.pv,a.op,a.mode,"
                           "Self Regulating,5\n")
    loops, problems = read_loops_csv(path)
    assert problems == []
    assert loops == [LoopSpec("A", pv_tag="a.pv", op_tag="a.op", mode_tag="a.mode",
                              process_type="self-regulating", span=5.0)]


def test_bad_numbers_and_ragged_rows(tmp_path):
    path = write(tmp_path, "loop,pv_tag,op_tag,span,criticality\n"
                           "A,a,b,-3,x\n"
                           "B,c\n"
                           "C,d,e,1,1,extra\n"
                           ",f,g,,\n")
    loops, problems = read_loops_csv(path)
    a, b = loops
    assert math.isnan(a.span) and a.criticality == 1.0 and len(a.issues) == 2
    assert b.op_tag is None and b.issues == ("no OP tag in loops.csv",)
    assert any("line 3 (loop B): 2 fields" in p for p in problems)
    assert any("line 4: 6 fields" in p and "row skipped" in p for p in problems)
    assert any("line 5: no loop name" in p for p in problems)


def test_a_registry_tag_absent_from_the_exports_is_detectable(tmp_path):
    loops, _ = read_loops_csv(DATA / "loops.csv")
    with Store(tmp_path / "s.duckdb") as store:
        ingest_exports(store, [DATA / "wide.csv"])
        store.replace_loops(loops)
        missing = {l.loop: store.missing_tags(l) for l in store.loops()}
    assert missing["FIC101"] == {"sp": "FIC101.SP"}
    assert missing["LIC200"] == {"op": "LIC200.OP"}
    assert missing["TIC300"] == {"op": "TIC300.OP"}  # and no PV tag at all (an issue)


@pytest.mark.parametrize("module", ["valvediag.io.exports", "valvediag.store.ingest", "valvediag.store.database",
                                    "valvediag.io.registry",
                                    "valvediag.analysis.align", "valvediag.analysis.quality"])
def test_public_functions_document_their_parameters(module):
    """Like python-control: every public callable names each parameter in its docstring."""
    import dataclasses
    import importlib
    import inspect

    mod = importlib.import_module(module)
    missing = {}
    for name in mod.__all__:
        obj = getattr(mod, name)
        if inspect.isclass(obj) and obj.__module__ == module:
            targets = [(f"{name}.{m}", f) for m, f in vars(obj).items()
                       if inspect.isfunction(f) and not m.startswith("_")]
            if not dataclasses.is_dataclass(obj) and not issubclass(obj, Exception):
                targets.append((name, obj))
        elif inspect.isfunction(obj):
            targets = [(name, obj)]
        else:
            continue
        for label, f in targets:
            doc = inspect.getdoc(f) or ""
            params = [p for p in inspect.signature(f).parameters if p not in ("self", "cls")]
            lost = [p for p in params if p not in doc]
            if not doc or lost:
                missing[label] = lost or "no docstring"
    assert missing == {}


def test_a_description_of_200_kb_keeps_its_loop_shortened_with_a_problem(tmp_path):
    # the csv module's default field limit (128 KiB) used to drop the row
    path = write(tmp_path, "loop,pv_tag,op_tag,description\n"
                           f"FIC1,FIC1.PV,FIC1.OP,{'x' * 200_000}\nFIC2,FIC2.PV,FIC2.OP,short\n")
    loops, problems = read_loops_csv(path)
    assert [lp.loop for lp in loops] == ["FIC1", "FIC2"]
    assert len(loops[0].description) == 2000 and loops[1].description == "short"
    assert problems == [f"{path} line 2 (loop FIC1): description of 200,000 characters "
                        f"shortened to 2,000"]
