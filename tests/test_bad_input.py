"""Bad input, as a table: each input and the one-line outcome a user gets.

Single-loop files (``valvediag bi``) and historian exports (the scan's
ingest). Every message is one line and names the file; where a line of the
file is at fault, the message names it too. The scan-level cases (a missing
export path, an unwritable output directory, a night that stored nothing, a
partial night) are in ``tests/test_scan.py`` and ``tests/test_flow_local.py``.
"""
from __future__ import annotations

import gzip
import zipfile

import pytest

from valvediag.io.exports import ExportError, parse_export
from valvediag.io.loopfile import LoopFileError, read_loop_csv

GOOD_ROWS = "".join(f"{k},{k % 7},{k % 5}\n" for k in range(30))


def _gzip(path, text):
    path.write_bytes(gzip.compress(text.encode()))


def _zip(path, text):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("export.csv", text)


def _one_line_error(reader, error, path, content, words):
    """Write ``content`` (text, a writer, or None for no file) to ``path``; ``reader``
    must raise ``error``, one line naming the file and holding each of ``words``."""
    if callable(content):
        content(path)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(error) as err:
        reader(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg, msg
    for w in words:
        assert w.lower() in msg.lower(), (w, msg)


# (case, file name, content (text, or a writer), words the one-line error holds)
LOOP_FILES = [
    ("missing file", "absent.csv", None, ["no such file"]),
    ("empty file", "empty.csv", "", ["the file is empty"]),
    ("header only", "header.csv", "timestamp,pv,op\n", ["a header but no rows"]),
    ("missing columns", "cols.csv", "when,what\n1,2\n", ["missing column(s) timestamp, pv, op",
                                                         "columns: when, what"]),
    ("ragged row", "ragged.csv", "timestamp,pv,op\n0,1,2\n1,1,2,3\n2,1,2\n",
     ["line 3 has 4 fields, the header 3"]),
    ("text in the time column", "text_ts.csv", "timestamp,pv,op\n0,1,2\nsoon,1,2\n",
     ["line 3", "'soon' is not a number of seconds like the others"]),
    ("naive and offset time stamps mixed", "mixed.csv",
     "timestamp,pv,op\n2026-11-01T00:00:00,1,2\n2026-11-01T00:00:01+00:00,1,2\n",
     ["line 3", "written differently from line 2", "with and without a UTC offset"]),
    ("empty time stamp", "empty_ts.csv", "timestamp,pv,op\n0,1,2\n,1,2\n2,1,2\n",
     ["line 3: empty timestamp"]),
    ("time running backwards", "backwards.csv", "timestamp,pv,op\n0,1,2\n5,1,2\n3,1,2\n",
     ["line"]),
]


@pytest.mark.parametrize("case, name, content, words", LOOP_FILES,
                         ids=[c[0] for c in LOOP_FILES])
def test_single_loop_file_errors_are_one_line_naming_file_and_line(tmp_path, case, name,
                                                                   content, words):
    _one_line_error(read_loop_csv, LoopFileError, tmp_path / name, content, words)


def test_a_good_single_loop_file_reads():
    # the table's control: the same layout without the fault reads
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "good.csv"
        p.write_text("timestamp,pv,op\n" + GOOD_ROWS)
        rec, _ = read_loop_csv(p)
    assert rec.pv.size == 30


LONG = "tag,timestamp,value,status\nFIC1.PV,2026-11-01T00:00:00Z,1.5,\n"
EXPORTS = [
    ("missing file", "absent.csv", None, ["no such file"]),
    ("empty file", "empty.csv", "", ["empty"]),
    ("unknown columns", "cols.csv", "foo,bar,baz\n1,2,3\n", ["foo", "bar"]),
    ("gzip-compressed CSV", "export.csv.gz", lambda p: _gzip(p, LONG),
     ["gzip-compressed", "gunzip it"]),
    ("zip archive", "export.zip", lambda p: _zip(p, LONG), ["a zip archive", "unzip it"]),
    # bytes the CSV reader takes for a zlib stream's start (found by the fuzz test)
    ("bytes that begin like a zlib stream", "export.csv",
     lambda p: p.write_bytes(b"x\x01\x02\x01"), ["not a text export"]),
    ("not Parquet", "export.parquet", "tag,timestamp\n", ["parquet"]),
    ("naive time stamps without a time zone", "naive.csv",
     "tag,timestamp,value\nFIC1.PV,2026-11-01 00:00:00,1.5\nFIC1.PV,2026-11-01 00:00:05,1.6\n",
     ["time zone"]),
]


@pytest.mark.parametrize("case, name, content, words", EXPORTS, ids=[c[0] for c in EXPORTS])
def test_export_errors_are_one_line_naming_the_file(tmp_path, case, name, content, words):
    _one_line_error(parse_export, ExportError, tmp_path / name, content, words)


def test_the_same_export_uncompressed_parses(tmp_path):
    # the table's control for the archives: the text they hold is a good export
    path = tmp_path / "export.csv"
    path.write_text(LONG)
    assert parse_export(path).samples.height == 1


# ------------------------------------------------------------------ through a whole scan
# Each case changes a small synthetic plant (its exports, its registry or the output path),
# runs the scan and checks how the run ends: the status in the store, the exception or the
# summary, and the words that name the problem. Nothing may be duplicated.

def _garbled(d):
    (d / "exports" / "garbled.csv").write_text("foo,bar\n1,2\n")


def _only_garbled(d):
    for p in (d / "exports").iterdir():
        p.unlink()
    _garbled(d)


def _naive_rows(d):
    # naive time stamps among offset ones and no time zone: a setting fixes it
    (d / "exports" / "naive.csv").write_text(
        "tag,timestamp,value\nXX.PV,2026-11-01T00:00:00Z,1\nXX.PV,2026-11-01 00:00:05,2\n"
        "XX.PV,2026-11-01 00:00:10,3\n")


def _decimal_commas(d):
    (d / "exports" / "commas.csv").write_text("tag,timestamp,value\n" + "".join(
        f'XX.PV,2026-11-01T00:{i // 60:02d}:{i % 60:02d}Z,"{i},5"\n' for i in range(40)))


def _text_values(d):
    (d / "exports" / "text.csv").write_text("tag,timestamp,value\n" + "".join(
        f"XX.PV,2026-11-01T00:{i // 60:02d}:{i % 60:02d}Z,v{i}?\n" for i in range(40)))


def _gzipped(d):
    src = sorted((d / "exports").iterdir())[0]
    _gzip(d / "exports" / "more.csv.gz", src.read_text())


def _single_sample_tag(d):
    (d / "exports" / "single.csv").write_text(
        "tag,timestamp,value\nXIC9.PV,2026-11-01T01:00:00Z,3.0\n"
        "XIC9.OP,2026-11-01T00:00:00Z,40\nXIC9.OP,2026-11-01T01:00:00Z,41\n")
    with open(d / "loops.csv", "a") as fh:
        fh.write("XIC9,XIC9.PV,XIC9.OP,,,self-regulating,%,100,1,one PV sample\n")


def _edit_tag_rows(d, tag, edit):
    """Rewrite the value cell of ``tag``'s rows: ``edit(k, row)`` -> row (k counts them)."""
    path = next((d / "exports").glob("*.csv"))
    lines, k = path.read_text().splitlines(), 0
    for i, line in enumerate(lines):
        if line.startswith(tag + ","):
            lines[i], k = edit(k, line.split(",")), k + 1
    path.write_text("\n".join(lines) + "\n")


def _placeholder(d):
    # one -9999 in the middle of the sticky loop's PV
    _edit_tag_rows(d, "LIC102.PV", lambda k, f: ",".join(
        f[:2] + ["-9999"] + f[3:]) if k == 250 else ",".join(f))


def _scattered_bad_states(d):
    # every 20th PV sample of the sticky loop a 'Bad Input' state (5 %)
    _edit_tag_rows(d, "LIC102.PV", lambda k, f: ",".join(
        f[:2] + ["Bad Input"] + f[3:]) if k % 20 == 7 else ",".join(f))


def _formula_description(d):
    text = (d / "loops.csv").read_text().replace("Reflux drum D-169 level",
                                                 "=HYPERLINK(\"http://x\")")
    (d / "loops.csv").write_text(text)


def _missing_export_path(d):
    (d / "exports_moved").mkdir()           # the share that is not mounted


def _out_is_a_file(d):
    (d / "out_file").write_text("a file where the output directory should go")


def _huge_description(d):
    with open(d / "loops.csv", "a") as fh:
        fh.write(f"XIC8,XIC8.PV,XIC8.OP,,,self-regulating,%,100,1,{'x' * 200_000}\n")


# (case, change, expected: 'complete' | 'partial' | an exception type, words in the
#  note or message, (loop, verdict, words in its reason) or None)
SCANS = [
    ("one unreadable export", _garbled, "partial", ["garbled.csv"], None),
    ("every export unreadable", _only_garbled, "NothingStoredError",
     ["no export reached the store", "garbled.csv"], None),
    ("naive time stamps without a time zone", _naive_rows, "partial",
     ["naive.csv", "a cause a setting fixes", "no UTC offset"], None),
    ("quoted decimal commas (read as decimals)", _decimal_commas, "complete", [], None),
    ("text in every value of a file", _text_values, "partial",
     ["text.csv", "all 40 rows were quarantined", "'v0?'"], None),
    ("a gzip-compressed export", _gzipped, "partial",
     ["more.csv.gz", "gzip-compressed"], None),
    ("a PV tag with a single sample", _single_sample_tag, "complete", [],
     ("XIC9", "insufficient-data", "has a single valid sample")),
    ("a description of 200 kB", _huge_description, "complete", [],
     ("XIC8", "insufficient-data", "not found in the exports")),
    ("one placeholder sample in a sticky valve's PV", _placeholder, "complete", [],
     ("LIC102", "stiction", "")),
    ("5 % scattered bad states in a sticky valve's PV", _scattered_bad_states, "complete",
     [], ("LIC102", "stiction", "")),
    ("a description that a spreadsheet would run", _formula_description, "complete", [],
     ("LIC102", "stiction", "")),
    ("an export path that does not exist", _missing_export_path, "FileNotFoundError",
     ["no such file or directory"], None),
    ("an output path that is a file", _out_is_a_file, "OSError",
     ["cannot write the outputs here"], None),
    ("the disk fills up during the ingest", None, "NothingStoredError",
     ["no export reached the store", "No space left on device"], None),
]


@pytest.fixture(scope="module")
def small_plant(tmp_path_factory):
    from valvediag.synth.plant import synth_plant

    base = tmp_path_factory.mktemp("bad_input_plant")
    synth_plant(3, 0.03, 5.0, base, seed=1)
    return base


@pytest.mark.system
@pytest.mark.parametrize("case, change, expect, words, loop", SCANS,
                         ids=[c[0] for c in SCANS])
def test_bad_input_through_a_scan(small_plant, tmp_path, monkeypatch, case, change, expect,
                                  words, loop):
    import shutil

    from valvediag.scan import run as scan_run
    from valvediag.store.database import Store

    d = tmp_path / "plant"
    shutil.copytree(small_plant, d)
    db, out, exports = tmp_path / "s.duckdb", tmp_path / "out", d / "exports"
    if change is None:                          # a full disk under the store
        import duckdb

        from valvediag.store.database import Store as _Store

        def full(*args, **kwargs):
            raise duckdb.IOException('Could not write file "s.duckdb.wal": No space left on '
                                     'device')
        monkeypatch.setattr(_Store, "insert_new_samples", full)
    else:
        change(d)
    if change is _missing_export_path:
        exports = [d / "exports", d / "share" / "exports"]
    if change is _out_is_a_file:
        out = d / "out_file" / "out"
    if expect in ("complete", "partial"):
        summary = scan_run.run_scan(exports, d / "loops.csv", db, out)
        assert summary.status == expect, (summary.status, summary.status_note)
        text = summary.status_note
        if loop is not None:
            name, verdict, why = loop
            r = next(r for r in summary.results if r.loop == name)
            assert r.verdict == verdict and why in r.reason, (r.verdict, r.reason)
        assert (out / "verdicts.json").exists()
    else:
        exc = {"FileNotFoundError": FileNotFoundError, "OSError": OSError,
               "NothingStoredError": scan_run.NothingStoredError}[expect]
        with pytest.raises(exc) as err:
            scan_run.run_scan(exports, d / "loops.csv", db, out)
        text = str(err.value)
        assert not (out / "verdicts.json").exists()
    assert "\n" not in text
    for w in words:
        assert w in text, (w, text)
    if change is _decimal_commas:
        with Store(db, read_only=True) as s:
            got = s.fetch_tag("XX.PV")["value"].to_list()
        assert got == [i + 0.5 for i in range(40)]
    if change is _formula_description:
        import csv

        with open(out / "work_orders.csv", newline="", encoding="utf-8") as fh:
            row = next(r for r in csv.DictReader(fh) if r["loop"] == "LIC102")
        assert row["description"] == "'=HYPERLINK(\"http://x\")"
    if not db.exists():                 # stopped before the store was made
        return
    with Store(db, read_only=True) as s:
        runs = s.runs()["status"].to_list()
        assert s.duplicate_keys() == 0
    if expect in ("complete", "partial"):
        assert runs == [expect]
    elif expect == "NothingStoredError":
        assert runs == ["failed"]
    else:                               # stopped before the run was planned
        assert runs == []
