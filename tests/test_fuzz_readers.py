"""Property-based fuzz tests of the readers (hypothesis).

The requirement: on random and malformed CSV and Parquet, the result is never a
traceback. It is always a clear one-line error that names the file, or rows that
are stored or quarantined. No good row is ever lost.

The readers under test are :func:`valvediag.io.exports.parse_export` /
:func:`~valvediag.io.exports.read_export` / :func:`~valvediag.store.ingest.ingest_exports`,
:func:`valvediag.io.registry.read_loops_csv` and
:func:`valvediag.io.loopfile.read_loop_csv`. The generators build each file beside
an *oracle*: what the module docstrings say must happen to every line (or cell)
of it. The oracle is written from the documented contract, not from the code:

* a good long row is stored with its exact value and UTC time stamp (microsecond
  resolution, finer digits truncated). Or it is an exact duplicate of an earlier
  sample with the same (tag, ts) and is counted. Or it repeats an earlier
  (tag, ts) with a different value or status and is quarantined. In every case
  the first sample in file order wins;
* ``NaN``/``inf`` and known state texts are samples with ``value = NULL`` and
  the text in ``status``; any other non-numeric text is quarantined;
* every malformed line is quarantined with its line number and its raw text;
* in a wide file an empty cell (or null/NaN in a numeric Parquet column) is "no
  sample", and every other cell is one sample or one quarantine row.

Each hypothesis example writes its files (and its DuckDB store) into its own
``tempfile.TemporaryDirectory`` inside the test body, so no function-scoped
fixture is shared between examples. Example counts are modest: the whole file
runs in about 20-30 s on two busy cores.
"""
from __future__ import annotations

import collections
import datetime as dt
import functools
import os
import struct
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import hypothesis.strategies as st
import polars as pl
from hypothesis import HealthCheck, example, given, settings

# The exact header aliases the layout detection reserves. A random wide tag name
# that normalises to one of them is (correctly) a layout error, so the wide
# generators avoid them; they are private, so import rather than copy them.
from valvediag.io.exports import (
    _CONFIDENCE_NAMES,
    _STATUS_NAMES,
    _TAG_NAMES,
    _TIME_NAMES,
    _VALUE_NAMES,
    DIGITAL_STATES,
    DUPLICATE_REASON,
    QUARANTINE_SCHEMA,
    SAMPLE_SCHEMA,
    ExportError,
    parse_export,
    read_export,
)
from valvediag.io.loopfile import LoopFileError, read_loop_csv
from valvediag.io.registry import RegistryError, read_loops_csv
from valvediag.store.database import Store
from valvediag.store.ingest import ingest_exports

RESERVED = frozenset(_TIME_NAMES + _TAG_NAMES + _VALUE_NAMES + _STATUS_NAMES + _CONFIDENCE_NAMES)
BOM = "\ufeff"
EPOCH0 = dt.datetime(1970, 1, 1)
MAX_US = 4102444800 * 10**6            # 2100-01-01T00:00:00Z [us]
POOL_US = [1704067200 * 10**6 + k * 10**6 for k in range(4)]   # for key collisions
# deadline=None and no "too slow"/"too large" health checks: another process keeps the
# two cores busy, and timings must not make the properties flaky.
FUZZ = dict(deadline=None, suppress_health_check=[
    HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])


# --------------------------------------------------------------------------
# helpers: "no traceback" and "one clear line"
# --------------------------------------------------------------------------
def call_reader(fn, path, allowed, **kwargs):
    """Call ``fn(path, **kwargs)``; return ``(result, None)`` or ``(None, error)``.

    An exception of a type in ``allowed`` is returned. Any other exception,
    including a Rust panic surfacing as ``pyo3_runtime.PanicException`` (a
    ``BaseException``) or ``_csv.Error``, fails the property.
    """
    try:
        return fn(path, **kwargs), None
    except allowed as exc:
        return None, exc
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:  # noqa: BLE001 - that is the property under test
        first = (str(exc).strip().splitlines() or [""])[0][:300]
        names = [Path(p).name for p in ([path] if isinstance(path, (str, os.PathLike))
                                        else path)]
        wanted = "/".join(a.__name__ for a in allowed) or "no exception"
        raise AssertionError(
            f"{fn.__name__}({', '.join(map(repr, names))}) raised {type(exc).__module__}."
            f"{type(exc).__qualname__} instead of {wanted}: {first}") from exc


def assert_one_line_naming(exc: BaseException | str, path) -> None:
    """The error message is non-empty, one line, and names the file."""
    msg = str(exc)
    assert msg.strip(), f"empty error message ({type(exc).__name__})"
    assert len(msg.splitlines()) == 1 and "\n" not in msg and "\r" not in msg, \
        f"multi-line message: {msg!r}"
    assert str(path) in msg, f"message does not name {path}: {msg!r}"


def strip_like_reader(texts: list[str]) -> list[str]:
    """Whitespace-strip as the readers do (Rust/Unicode ``White_Space``)."""
    return pl.Series(texts, dtype=pl.String).str.strip_chars().to_list()


def physical_lines(data: bytes) -> list[str]:
    """The file's physical lines (1-based list index + 1), as the documented reader sees them.

    A UTF-8 BOM is dropped, non-UTF-8 is Latin-1, 0x1F becomes U+241F, lines
    end at ``\\n`` (a ``\\r`` before it belongs to the line ending).
    """
    if data.startswith(BOM.encode()):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    text = text.replace("\x1f", "\u241f")
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return [ln[:-1] if ln.endswith("\r") else ln for ln in lines]


def ts_us(samples: pl.DataFrame) -> pl.DataFrame:
    """Samples with ``ts`` as integer microseconds since the epoch (no Python datetimes)."""
    return samples.with_columns(pl.col("ts").dt.epoch("us"))


def check_frames(parsed, path: str) -> None:
    """Schema, uniqueness and provenance checks that hold for every parse."""
    assert parsed.samples.schema == pl.Schema(SAMPLE_SCHEMA)
    assert parsed.quarantine.schema == pl.Schema(QUARANTINE_SCHEMA)
    assert parsed.samples.select("tag", "ts").is_duplicated().sum() == 0, "stored keys not unique"
    assert parsed.samples.null_count().select("tag", "ts", "source_file", "source_line").row(0) \
        == (0, 0, 0, 0)
    # value IS NULL means exactly "this sample is bad": a stored value is finite
    values = parsed.samples["value"].drop_nulls()
    assert values.is_finite().all(), \
        f"non-finite value stored as a good sample: {values.filter(~values.is_finite()).to_list()}"
    assert set(parsed.samples["source_file"].unique()) <= {path}
    assert set(parsed.quarantine["source_file"].unique()) <= {path}
    assert parsed.quarantine["reason"].null_count() == 0
    for reason in parsed.quarantine["reason"]:
        assert len(reason.splitlines()) == 1, f"multi-line reason {reason!r}"


# --------------------------------------------------------------------------
# the oracle: first sample of a (tag, ts) wins
# --------------------------------------------------------------------------
@dataclass
class Expect:
    """What must happen to a file. Keys of ``stored`` are (line, tag)."""

    stored: dict = field(default_factory=dict)      # (line, tag) -> (ts_us, value, status)
    dup_lines: list = field(default_factory=list)   # exact duplicates (counted, not stored)
    quarantine: collections.Counter = field(default_factory=collections.Counter)  # line -> rows
    raw: dict = field(default_factory=dict)         # line -> raw text (malformed/bad lines)
    conflicts: set = field(default_factory=set)     # (line, tag) quarantined as conflicts
    cells: list = field(default_factory=list)       # (line, tag) of quarantined wide cells
    _first: dict = field(default_factory=dict)

    def good(self, line, tag, us, value, status):
        key = (tag, us)
        if key not in self._first:
            self._first[key] = (value, status)
            self.stored[(line, tag)] = (us, value, status)
        elif self._first[key] == (value, status):
            self.dup_lines.append(line)
        else:
            self.quarantine[line] += 1
            self.conflicts.add((line, tag))

    def bad(self, line, raw=None, tag=None):
        self.quarantine[line] += 1
        if raw is not None:
            self.raw[line] = raw
        if tag is not None:
            self.cells.append((line, tag))


def actual_stored(samples: pl.DataFrame) -> dict:
    s = ts_us(samples)
    return {(r["source_line"], r["tag"]): (r["ts"], r["value"], r["status"])
            for r in s.iter_rows(named=True)}


def check_against(parsed, exp: Expect) -> None:
    """Compare a parse with the oracle: nothing lost, nothing invented."""
    got = actual_stored(parsed.samples)
    missing = {k: v for k, v in exp.stored.items() if got.get(k) != v}
    extra = {k: v for k, v in got.items() if k not in exp.stored}
    assert not missing and not extra, (
        f"good samples lost or altered: expected {missing}, got "
        f"{ {k: got.get(k) for k in missing} }; unexpected samples {extra}")
    q = collections.Counter(parsed.quarantine["line"].to_list())
    assert q == exp.quarantine, f"quarantined lines {dict(q)} != expected {dict(exp.quarantine)}"
    raw = dict(zip(parsed.quarantine["line"], parsed.quarantine["raw"]))
    for line, text in exp.raw.items():
        assert raw[line] == text, f"line {line}: raw {raw[line]!r} != {text!r}"
    reasons = collections.defaultdict(list)
    for line, reason in zip(parsed.quarantine["line"], parsed.quarantine["reason"]):
        reasons[line].append(reason)
    for line, tag in exp.conflicts:
        assert any(r.startswith(DUPLICATE_REASON) for r in reasons[line]), \
            f"line {line} (tag {tag}) should be a conflicting duplicate: {reasons[line]}"
    for line, tag in exp.cells:
        assert any(tag in r for r in reasons[line]), \
            f"line {line}: no quarantine reason names tag {tag!r}: {reasons[line]}"
    assert parsed.duplicates_dropped == len(exp.dup_lines), \
        f"duplicates_dropped {parsed.duplicates_dropped} != {len(exp.dup_lines)} " \
        f"(lines {exp.dup_lines})"
    stored_lines = {line for line, _ in got}
    if parsed.shape == "long":
        both = stored_lines & set(q)
        assert not both, f"lines both stored and quarantined: {sorted(both)}"


# --------------------------------------------------------------------------
# strategies: time stamps, values, tags
# --------------------------------------------------------------------------
instants = st.one_of(st.sampled_from(POOL_US), st.integers(0, MAX_US - 1))
offsets = st.one_of(st.just(0), st.sampled_from([60, -300, 330, 345, 840, -720]),
                    st.integers(-14 * 60, 14 * 60))


@st.composite
def time_text(draw, us: int) -> str:
    """A documented rendering of the instant ``us``: ISO 8601 with an offset, or epoch s."""
    style = draw(st.sampled_from(["iso", "iso", "iso_space", "minutes", "epoch"]))
    micro = us % 10**6
    if style == "epoch":
        sec = us // 10**6
        if micro == 0 and draw(st.booleans()):
            return str(sec)
        frac = f"{micro:06d}"
        return f"{sec}.{frac.rstrip('0') if draw(st.booleans()) else frac}".rstrip(".")
    off = draw(offsets)
    local = EPOCH0 + dt.timedelta(microseconds=us + off * 60 * 10**6)
    sign, a = ("-" if off < 0 else "+"), abs(off)
    forms = [f"{sign}{a // 60:02d}:{a % 60:02d}", f"{sign}{a // 60:02d}{a % 60:02d}"]
    if a % 60 == 0:
        forms.append(f"{sign}{a // 60:02d}")
    if off == 0:
        forms.append("Z")
    zone = draw(st.sampled_from(forms))
    if style == "minutes" and local.second == 0 and micro == 0:
        return f"{local:%Y-%m-%dT%H:%M}{zone}"
    if micro == 0:
        frac = draw(st.sampled_from(["", ".0", ".000000"]))
    else:
        digits = f"{micro:06d}"
        frac = "." + draw(st.sampled_from([digits, digits.rstrip("0"),
                                           digits + str(draw(st.integers(0, 999))).zfill(3)]))
    sep = " " if style == "iso_space" else "T"
    return f"{local:%Y-%m-%d}{sep}{local:%H:%M:%S}{frac}{zone}"


STATE_TEXTS = ["I/O Timeout", "Bad Input", "Shutdown", "No Data", "Calc Failed", "Comm Fail",
               "Scan Off", "Over Range", "MAN", "AUTO", "CAS", "ON", "OFF", "Bad"]
NONFINITE = ["inf", "-inf", "+inf", "Infinity", "-Infinity", "NaN", "nan", "1e400", "-1e999"]
FLAGS = ["Questionable", "Substituted", "Annotated", "Good", ""]
BAD_TS = ["not a time", "2024-13-01T00:00:00Z", "2024-02-30T00:00:00+01:00",
          "2024-01-01T24:30:00Z", "17040672xx", "1704067200000", "99999999999999",
          "1704067200000000",
          "2024-01-01", "2024-01-01 00:00:00", "2024-01-01T00:00:00", "inf", "NaN", "1e5",
          "2024-01-01T00:00:00+99:99", "12:00:00Z", "--", "", "   "]
BAD_VALUES = ["12abc", "#VALUE!", "--", "1_000", "0x10", "1.2.3", "Bad Inputs", "?", "1d5",
              "\u00bd", "\u0661\u0662", "1,5"]
AWKWARD_TAGS = ["line", "raw", "kind", "utc", "naive", "ts_reason", "v", "f0", "f1", "state",
                "reason", "time_col", "_f", "_n", "source_line", "value_text", "num", "t"]

letters = st.text(alphabet=st.characters(categories=("Lu", "Ll")), min_size=1, max_size=8)


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


junk_words = letters.filter(lambda t: not _is_float(t)
                            and " ".join(t.lower().split()) not in DIGITAL_STATES)
bad_ts_text = st.one_of(st.sampled_from(BAD_TS), letters)
bad_value_text = st.one_of(st.sampled_from(BAD_VALUES), junk_words)


def bad_value_for(sep: str):
    """Non-numeric value texts. With ``;``/tab a decimal comma is a number, so "1,5" is
    not; with ``,`` a quoted "1,5" is a decimal comma where the column has no decimal
    point, so the comma case is "1,234", which could be a thousands separator and is
    always quarantined."""
    return bad_value_text.map(lambda v: v if v != "1,5" else "1,234" if sep == "," else
                              f"1{sep}5")


tag_chars = st.characters(categories=("L", "N"), include_characters=".-_/:#\u00b0\u00b5,;'\"")
random_tag = st.text(alphabet=tag_chars, min_size=1, max_size=10)
tags = st.one_of(st.sampled_from(["A", "B", "FIC101.PV", "T\u00b0C"]), random_tag,
                 st.builds(lambda a, b: f"{a} {b}", random_tag, random_tag))


@st.composite
def value_text(draw, sep: str):
    """A good value rendering and its oracle ``(text, value, state)``."""
    kind = draw(st.sampled_from(["num", "num", "int", "state", "nonfinite"]))
    if kind == "num":
        x = draw(st.floats(allow_nan=False, allow_infinity=False))
        text = draw(st.sampled_from([repr(x), f"{x:.17g}", f"{x:.17e}"]))
        if not text.startswith("-") and draw(st.booleans()):
            text = "+" + text
        if sep != "," and "." in text and draw(st.booleans()):
            text = text.replace(".", ",")          # decimal comma with ; or tab
        return text, float(text.replace(",", ".")), None
    if kind == "int":
        n = draw(st.integers(-10**25, 10**25))
        return str(n), float(n), None
    if kind == "nonfinite":
        text = draw(st.sampled_from(NONFINITE))
        return text, None, text
    text = draw(st.sampled_from([str, str.lower, str.upper]))(draw(st.sampled_from(STATE_TEXTS)))
    return text, None, text


def render(fields: list[str], sep: str, quote_all: bool = False, quote: list | None = None) -> str:
    """Join fields as CSV, quoting those that need it (and some that do not)."""
    out = []
    for i, f in enumerate(fields):
        must = sep in f or '"' in f
        if must or quote_all or (quote and quote[i % len(quote)]):
            out.append('"' + f.replace('"', '""') + '"')
        else:
            out.append(f)
    return sep.join(out)


# --------------------------------------------------------------------------
# long CSV files with an oracle
# --------------------------------------------------------------------------
LONG_ALIASES = {"tag": ["tag", "Tag", "TAGNAME", "tag_name", "Point"],
                "time": ["timestamp", "Time", "TS", "DateTime"],
                "value": ["value", "Value", "VAL"],
                "status": ["status", "Quality", "FLAG"]}


@dataclass
class CsvCase:
    data: bytes
    exp: Expect
    body_lines: int      # non-blank lines after the header
    note: str = ""


@st.composite
def long_csv(draw, max_rows: int = 25, few_keys: bool = False) -> CsvCase:
    """A long CSV of good, malformed, blank and duplicate lines, with its oracle.

    ``few_keys`` draws tags, instants and values from two or three values each, so
    that the same (tag, ts) recurs often, with the same or another value (exact
    duplicates and conflicts, also across the slices of an ingest).
    """
    tag_st = st.sampled_from(["A", "B"]) if few_keys else tags
    us_st = st.sampled_from(POOL_US[:2]) if few_keys else instants
    value_st = (st.sampled_from([("1", 1.0, None), ("2", 2.0, None),
                                 ("Bad Input", None, "Bad Input")])
                if few_keys else None)
    sep = draw(st.sampled_from([",", ",", ";", "\t"]))
    with_status = draw(st.booleans())
    roles = ["tag", "time", "value"] + (["status"] if with_status else [])
    order = draw(st.permutations(roles))
    header = [draw(st.sampled_from(LONG_ALIASES[r])) for r in order]
    eol_mode = draw(st.sampled_from(["\n", "\r\n", "mixed"]))
    lines: list[str] = [render(header, sep, quote_all=draw(st.booleans()))]
    lead = draw(st.integers(0, 1))
    lines = [""] * lead + lines
    exp = Expect()
    goods: list[tuple] = []          # (tag, us, value, state, flag) of good lines so far
    n_body = 0
    kinds = draw(st.lists(st.sampled_from(
        ["good"] * 6 + ["dup_same", "dup_diff", "bad_ts", "bad_value", "empty_value", "empty_tag",
                        "missing", "extra", "open_quote", "junk", "blank"]),
        min_size=0, max_size=max_rows))
    for kind in ["good"] + kinds:     # first line good: never an all-naive file
        line_no = len(lines) + 1
        if kind in ("dup_same", "dup_diff") and not goods:
            kind = "good"
        if kind == "blank":
            lines.append(draw(st.sampled_from(["", " ", "   "])))
            continue
        n_body += 1
        if kind == "junk":
            text = draw(st.text(alphabet=st.characters(
                categories=("L", "N", "P"), exclude_characters=',;"\x1f'), min_size=1, max_size=20))
            lines.append(text)
            exp.bad(line_no, text)
            continue
        if kind.startswith("dup"):
            tag, us, value, state, flag = draw(st.sampled_from(goods))
            if kind == "dup_same":
                vtext = state if state is not None else draw(st.sampled_from(
                    [repr(value), f"{value:.17e}", f"{value:.17g}"]))
            else:
                vtext, value, state = draw(value_st if few_keys else value_text(sep))
        else:
            tag = draw(tag_st)
            us = draw(us_st)
            vtext, value, state = draw(value_st if few_keys else value_text(sep))
            flag = draw(st.sampled_from(FLAGS)) if with_status else ""
        ttext = draw(time_text(us))
        pad = draw(st.sampled_from(["", " "]))
        fields = {"tag": pad + tag + pad, "time": ttext, "value": pad + vtext + pad,
                  "status": flag}
        good = kind in ("good", "dup_same", "dup_diff")
        if kind == "bad_ts":
            fields["time"] = draw(bad_ts_text)
        elif kind == "bad_value":
            fields["value"] = draw(bad_value_for(sep))
        elif kind == "empty_value":
            fields["value"] = draw(st.sampled_from(["", " "]))
        elif kind == "empty_tag":
            fields["tag"] = draw(st.sampled_from(["", "  "]))
        row = [fields[r] for r in order]
        if kind == "missing":
            del row[draw(st.integers(0, len(row) - 1))]
        elif kind == "extra":
            row.insert(draw(st.integers(0, len(row))), draw(st.sampled_from(["", "x", "1"])))
        if kind == "open_quote":
            text = '"' + sep.join(f.replace('"', "'").replace(sep, " ") for f in row)
        else:
            text = render(row, sep, quote=draw(st.lists(st.booleans(), min_size=1, max_size=4)))
        lines.append(text)
        if good:
            status = "; ".join(s for s in (state, flag.strip()) if s) or None
            exp.good(line_no, tag.strip(), us, value, status)
            goods.append((tag, us, value, state, flag))
        else:
            exp.bad(line_no, text)
    eols = [draw(st.sampled_from(["\n", "\r\n"])) if eol_mode == "mixed" else eol_mode
            for _ in lines]
    text = "".join(ln + e for ln, e in zip(lines, eols))
    if not draw(st.booleans()):
        text = text[:-len(eols[-1])]                # no final line break
    if draw(st.booleans()):
        text = BOM + text
    return CsvCase(text.encode("utf-8"), exp, n_body, f"sep={sep!r}")


def csv_case(text: str, rows: list[tuple]) -> CsvCase:
    """An explicit CSV case: ``rows`` are ``("good", line, tag, us, value, status)``,
    ``("bad", line, raw)`` or ``("cell", line)`` (one quarantined wide cell)."""
    exp = Expect()
    for r in rows:
        if r[0] == "good":
            exp.good(*r[1:])
        elif r[0] == "bad":
            exp.bad(r[1], r[2])
        else:
            exp.bad(r[1])
    return CsvCase(text.encode(), exp, len(rows))


T0 = 1704067200 * 10**6          # 2024-01-01T00:00:00Z [us]


# --------------------------------------------------------------------------
# 1. arbitrary bytes and text
# --------------------------------------------------------------------------
TOKENS = [",", ",", ";", "\t", '"', "\r", "\n", "\n", "\r\n", " ", "A", "B", "x", "\u00b0",
          BOM, "\x00", "\x1f", "\x85", "\u2028", "1", "-", ".", "e", "5", ":",
          "2024-01-01T00:00:00Z", "2024-01-01 00:00:00", "1704067200", "1e400", "NaN", "inf",
          "Bad Input", "I/O Timeout", "\u00e9", "\U0001f600"]
HEADERS = ["tag,timestamp,value", "tag;timestamp;value;status", "timestamp,A,B", "Time\tT1",
           "tagname,time,val,quality", "tag,timestamp,value,confidence", "ts,line,raw", ""]
token_text = st.lists(st.sampled_from(TOKENS), max_size=40).map("".join)
structured_text = st.builds(lambda h, body: h + "\n" + body, st.sampled_from(HEADERS),
                            token_text)
encodings = st.sampled_from(["utf-8", "utf-8", "utf-8-sig", "utf-16", "latin-1"])
arbitrary_files = st.one_of(
    st.binary(max_size=300),
    st.builds(lambda t, enc: t.encode(enc, errors="replace"), st.text(max_size=200), encodings),
    st.builds(lambda t, enc: t.encode(enc, errors="replace"), structured_text, encodings),
)

CR_ONLY = b"tag,timestamp,value\rA,2024-01-01T00:00:00Z,1\r"
CR_IN_QUOTED_LINE = b'tag,timestamp,value\nA\rB,"2024-01-01T00:00:00Z",1\n'
HUGE_QUOTED_FIELD = (b'tag,timestamp,value\n"' + b"x" * 140_000
                     + b'",2024-01-01T00:00:00Z,1\nA,2024-01-01T00:00:00Z,1\n')
WIDE_TAG_NAMED_RAW = b"timestamp,raw\n2024-01-01T00:00:00Z,1\n"
MICROSECOND_EPOCH = b"tag,timestamp,value\nA,1704067200000000,1\n"
ONLY_NBSP = "\u00a0\n".encode()


@settings(max_examples=120, **FUZZ)
@given(data=arbitrary_files)
@example(data=CR_ONLY)
@example(data=CR_IN_QUOTED_LINE)
@example(data=HUGE_QUOTED_FIELD)
@example(data=WIDE_TAG_NAMED_RAW)
@example(data=MICROSECOND_EPOCH)
@example(data=ONLY_NBSP)
def test_arbitrary_bytes_give_a_one_line_error_or_an_accounted_parse(data):
    """Any bytes in a ``.csv`` file: ``ExportError`` with one line naming the file, or a
    parse whose samples and quarantine have the documented schema and whose long rows
    account for every non-blank body line (stored, quarantined with its raw text, or
    counted duplicate), never both stored and quarantined."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "export.csv")
        Path(path).write_bytes(data)
        parsed, err = call_reader(parse_export, path, (ExportError,))
        if err is not None:
            assert_one_line_naming(err, path)
            return
        check_frames(parsed, path)
        lines = physical_lines(data)
        blank = [s == "" for s in strip_like_reader(lines)] if lines else []
        nonblank = [i + 1 for i, b in enumerate(blank) if not b]
        body = set(nonblank[1:])
        stored = set(parsed.samples["source_line"])
        quarantined = set(parsed.quarantine["line"])
        assert stored | quarantined <= body, \
            f"line numbers outside the file's body: {sorted((stored | quarantined) - body)}"
        for line, raw in zip(parsed.quarantine["line"], parsed.quarantine["raw"]):
            assert raw is not None and raw.rstrip("\r") == lines[line - 1].rstrip("\r"), \
                f"line {line}: raw {raw!r} != {lines[line - 1]!r}"
        if parsed.shape == "long":
            assert not stored & quarantined
            assert len(stored) + len(quarantined) + parsed.duplicates_dropped == len(body), \
                "a long body line was neither stored, quarantined nor counted"


# --------------------------------------------------------------------------
# 2. long CSV: good rows mixed with malformed ones
# --------------------------------------------------------------------------
@settings(max_examples=80, **FUZZ)
@given(case=long_csv())
# a quoted line before an unquoted one with the same key: the first line must win
@example(case=csv_case('tag,timestamp,value\n"A",2024-01-01T00:00:00Z,1\n'
                       'A,2024-01-01T00:00:00Z,2\n',
                       [("good", 2, "A", T0, 1.0, None), ("good", 3, "A", T0, 2.0, None)]))
# the documented "+01" offset after fractional seconds
@example(case=csv_case("tag,timestamp,value\nA,2024-01-01T01:00:00.5+01,1\n",
                       [("good", 2, "A", T0 + 500_000, 1.0, None)]))
# an epoch in microseconds is quarantined, not a traceback
@example(case=csv_case("tag,timestamp,value\nA,2024-01-01T00:00:00Z,1\nA,1704067200000000,2\n",
                       [("good", 2, "A", T0, 1.0, None),
                        ("bad", 3, "A,1704067200000000,2")]))
def test_long_csv_every_good_row_is_stored_exactly_or_counted_and_every_bad_line_quarantined(
        case):
    """Long CSV with random good rows, malformed rows, blank lines, BOM, CRLF, quoting,
    separators and duplicate keys. Every good row is stored with its exact value, status
    and UTC time stamp, or counted as an exact duplicate; a same-key row with a different
    value is quarantined as such; every other non-blank line is quarantined with its line
    number and raw text; no line is both stored and quarantined; keys are unique."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "long.csv")
        Path(path).write_bytes(case.data)
        parsed, err = call_reader(parse_export, path, (ExportError,))
        assert err is None, f"{case.note}: unexpected whole-file error: {err}"
        assert parsed.shape == "long"
        check_frames(parsed, path)
        check_against(parsed, case.exp)
        assert (parsed.samples.height + len(set(parsed.quarantine["line"]))
                + parsed.duplicates_dropped) == case.body_lines
        # read_export is the same parse, as a (samples, quarantine) pair
        samples, quarantine = read_export(path)
        assert samples.equals(parsed.samples) and quarantine.equals(parsed.quarantine)


# --------------------------------------------------------------------------
# 3. wide CSV
# --------------------------------------------------------------------------
def _norm(name: str) -> str:
    return name.strip().strip('"').strip().lower()


wide_tag_names = st.one_of(tags, st.sampled_from(AWKWARD_TAGS)).filter(
    lambda t: t.strip() == t and _norm(t) and _norm(t) not in RESERVED and not t.startswith('"')
    and not t.endswith('"'))


@st.composite
def wide_csv(draw, max_rows: int = 12) -> CsvCase:
    """A wide CSV (``timestamp,TAG1,...``) with random cells, and its oracle."""
    sep = draw(st.sampled_from([",", ",", ";", "\t"]))
    names = draw(st.lists(wide_tag_names, min_size=1, max_size=4, unique_by=_norm))
    time_name = draw(st.sampled_from(["timestamp", "Time", "TS", "datetime"]))
    pos = draw(st.integers(0, len(names)))
    header = names[:pos] + [time_name] + names[pos:]
    lines = [render(header, sep, quote_all=draw(st.booleans()))]
    exp = Expect()
    cells = 0
    kinds = draw(st.lists(st.sampled_from(["good"] * 6 + ["bad_ts", "malformed", "blank"]),
                          max_size=max_rows))
    for kind in ["good"] + kinds:
        line_no = len(lines) + 1
        if kind == "blank":
            lines.append(draw(st.sampled_from(["", "  "])))
            continue
        us = draw(instants)
        ttext = draw(time_text(us)) if kind != "bad_ts" else draw(bad_ts_text)
        row, planned = [], []
        for tag in names:
            ckind = draw(st.sampled_from(["num", "num", "state", "empty", "junk"]))
            if ckind == "num":
                text, value, state = draw(value_text(sep))
            elif ckind == "state":
                text = draw(st.sampled_from(STATE_TEXTS + NONFINITE))
                value, state = None, text
            elif ckind == "empty":
                text, value, state = draw(st.sampled_from(["", " "])), None, None
            else:
                text, value, state = draw(bad_value_for(sep)), None, None
            row.append(text)
            planned.append((tag, ckind, value, state))
        row.insert(pos, ttext)
        if kind == "malformed":
            if draw(st.booleans()) or len(row) > 2:
                del row[draw(st.integers(0, len(row) - 1))]
            else:
                row.append("1")
        text = render(row, sep, quote=draw(st.lists(st.booleans(), min_size=1, max_size=4)))
        lines.append(text)
        if strip_like_reader([text])[0] == "":
            continue          # blank time stamp and blank cells (tab separated): a blank line
        if kind in ("malformed", "bad_ts"):
            exp.bad(line_no, text)
            continue
        for tag, ckind, value, state in planned:
            if ckind == "empty":
                continue
            cells += 1
            if ckind == "junk":
                exp.bad(line_no, tag=tag.strip())
            else:
                exp.good(line_no, tag.strip(), us, value, state)
    text = "\n".join(lines) + "\n"
    return CsvCase(text.encode("utf-8"), exp, cells, f"sep={sep!r} header={header!r}")


@settings(max_examples=50, **FUZZ)
@given(case=wide_csv())
@example(case=csv_case(WIDE_TAG_NAMED_RAW.decode(), [("good", 2, "raw", T0, 1.0, None)]))
def test_wide_csv_every_cell_is_a_sample_a_quarantine_row_or_an_empty_cell(case):
    """Wide CSV with random tag columns and random cells: every numeric cell is stored
    with its value, every state/NaN/inf text is stored with ``value = NULL`` and the text
    as status, every other non-empty cell is a quarantine row naming its tag, empty
    cells are no sample, and bad time stamps or field counts quarantine the whole line.
    Counting cells, nothing is lost."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "wide.csv")
        Path(path).write_bytes(case.data)
        parsed, err = call_reader(parse_export, path, (ExportError,))
        assert err is None, f"{case.note}: unexpected whole-file error: {err}"
        assert parsed.shape == "wide"
        check_frames(parsed, path)
        check_against(parsed, case.exp)


# --------------------------------------------------------------------------
# 4. Parquet: long and wide, random dtypes
# --------------------------------------------------------------------------
TZ_FIXED = "Etc/GMT-2"          # UTC+02:00 all year: naive local times are unambiguous
TIME_KINDS = ["str", "dt_utc", "dt_tz", "dt_naive", "date", "int", "float"]


@dataclass
class ParquetCase:
    frame: pl.DataFrame
    exp: Expect | None          # None: a whole-file error is expected
    timezone: str | None
    rows: int


NAIVE_BAD_TS = {"2024-01-01 00:00:00", "2024-01-01T00:00:00"}
SHIFT_US = 2 * 3600 * 10**6     # TZ_FIXED is 2 h ahead of UTC


@st.composite
def time_column(draw, n: int, name: str):
    """A time column of ``n`` rows and its oracle.

    Returns ``(series, expect, timezone, whole_file_error)`` where ``expect``
    holds the UTC instant [us] of each row, or None when the row's time stamp is
    bad (quarantined).
    """
    kind = draw(st.sampled_from(TIME_KINDS))
    expect: list = []
    if kind == "str":
        vals = []
        for _ in range(n):
            if draw(st.integers(0, 5)) == 0:
                vals.append(draw(st.one_of(st.none(), bad_ts_text)))
                expect.append(None)
            else:
                us = draw(instants)
                vals.append(draw(time_text(us)))
                expect.append(us)
        # naive texts are bad rows here (no time zone); naive texts alone are a file error
        all_naive = (all(e is None for e in expect)
                     and any(v in NAIVE_BAD_TS for v in vals))
        return pl.Series(name, vals, dtype=pl.String), expect, None, all_naive
    if kind in ("int", "float"):
        vals = []
        for _ in range(n):
            roll = draw(st.integers(0, 6))
            if roll == 0:
                vals.append(None)
                expect.append(None)
            elif roll == 1:       # milliseconds, or not a number: quarantined
                bad = draw(st.sampled_from([1e11, -2e11, 1704067200000.0] + (
                    [float("nan"), float("inf")] if kind == "float" else [])))
                vals.append(bad if kind == "float" else int(bad))
                expect.append(None)
            else:
                us = draw(instants)
                if kind == "int":
                    us -= us % 10**6
                    vals.append(us // 10**6)
                else:
                    vals.append(us / 1e6)
                expect.append(us)
        dtype = pl.Int64 if kind == "int" else pl.Float64
        return pl.Series(name, vals, dtype=dtype), expect, None, False
    # Date / Datetime; naive ones are local times in TZ_FIXED when a zone is given
    tz = draw(st.sampled_from([None, TZ_FIXED]))
    unit = draw(st.sampled_from(["ms", "us", "ns"]))
    naive = kind in ("dt_naive", "date")
    raw = []
    for _ in range(n):
        if draw(st.integers(0, 6)) == 0:
            raw.append(None)
            expect.append(None)
            continue
        us = draw(instants)
        if kind == "date":
            day = us // (86400 * 10**6)
            raw.append(day)
            expect.append(day * 86400 * 10**6 - SHIFT_US)
            continue
        if unit == "ms":
            us -= us % 1000
        sub = draw(st.integers(0, 999)) if unit == "ns" else 0   # truncated to us
        wall = us + SHIFT_US if naive else us
        raw.append({"ms": wall // 1000, "us": wall, "ns": wall * 1000 + sub}[unit])
        expect.append(us)
    if kind == "date":
        s = pl.Series(name, raw, dtype=pl.Int32).cast(pl.Date)
    elif naive:
        s = pl.Series(name, raw, dtype=pl.Int64).cast(pl.Datetime(unit))
    else:
        zone = "UTC" if kind == "dt_utc" else draw(st.sampled_from(
            ["Europe/Berlin", "America/New_York", "Asia/Kolkata", "Pacific/Chatham"]))
        s = pl.Series(name, raw, dtype=pl.Int64).cast(pl.Datetime(unit, "UTC"))
        s = s.dt.convert_time_zone(zone)
    whole_error = naive and tz is None and any(e is not None for e in expect)
    return s, expect, tz, whole_error


@st.composite
def text_cell(draw):
    """A text value cell: ``(text, kind, value, state)``; kind good/bad/empty."""
    roll = draw(st.integers(0, 9))
    if roll <= 4:
        text, value, state = draw(value_text(","))
        return text, "good", value, state
    if roll == 5:
        t = draw(st.sampled_from(STATE_TEXTS))
        return t, "good", None, t
    if roll == 6:
        return draw(bad_value_text), "bad", None, None
    return draw(st.sampled_from([None, "", "  "])), "empty", None, None


@st.composite
def parquet_long(draw) -> ParquetCase:
    """A long Parquet export with random column dtypes, and its oracle."""
    n = draw(st.integers(0, 12))
    names = {"tag": draw(st.sampled_from(["tag", "TagName", "point"])),
             "time": draw(st.sampled_from(["timestamp", "ts", "Time"])),
             "value": draw(st.sampled_from(["value", "val"]))}
    tseries, tus, tz, whole_error = draw(time_column(n, names["time"]))
    tag_vals, tag_ok = [], []
    for _ in range(n):
        if draw(st.integers(0, 7)) == 0:
            tag_vals.append(draw(st.sampled_from([None, "", "  "])))
            tag_ok.append(False)
        else:
            tag_vals.append(draw(tags))
            tag_ok.append(True)
    tag_dtype = draw(st.sampled_from([pl.String, pl.Categorical]))
    vkind = draw(st.sampled_from(["f64", "f32", "i64", "i32", "str"]))
    vals, vinfo = [], []
    for _ in range(n):
        if vkind == "str":
            text, k, value, state = draw(text_cell())
            vals.append(text)
            vinfo.append((k, value, state))
            continue
        if draw(st.integers(0, 7)) == 0:
            vals.append(None)
            vinfo.append(("empty", None, None))
        elif vkind in ("f64", "f32") and draw(st.integers(0, 5)) == 0:
            x = draw(st.sampled_from([float("nan"), float("inf"), float("-inf")]))
            vals.append(x)
            vinfo.append(("nonfinite", None, x))
        elif vkind in ("f64", "f32"):
            x = draw(st.floats(allow_nan=False, allow_infinity=False,
                               width=64 if vkind == "f64" else 32))
            vals.append(x)
            vinfo.append(("good", float(x), None))
        else:
            bits = 63 if vkind == "i64" else 31
            x = draw(st.integers(-2**bits, 2**bits - 1))
            vals.append(x)
            vinfo.append(("good", float(x), None))
    vdtype = {"f64": pl.Float64, "f32": pl.Float32, "i64": pl.Int64, "i32": pl.Int32,
              "str": pl.String}[vkind]
    columns = {names["tag"]: pl.Series(names["tag"], tag_vals, dtype=pl.String).cast(tag_dtype),
               names["time"]: tseries,
               names["value"]: pl.Series(names["value"], vals, dtype=vdtype)}
    skind = draw(st.sampled_from([None, "status", "confidence"]))
    flags: list = [None] * n
    if skind == "status":
        flags = [draw(st.sampled_from(FLAGS + [None])) for _ in range(n)]
        columns["status"] = pl.Series("status", flags, dtype=pl.String)
    elif skind == "confidence":
        flags = [draw(st.sampled_from([None, -1, 0, 50, 100])) for _ in range(n)]
        columns["confidence"] = pl.Series("confidence", flags, dtype=pl.Int64)
    order = draw(st.permutations(list(columns)))
    frame = pl.DataFrame([columns[c] for c in order])
    if whole_error:
        return ParquetCase(frame, None, tz, n)
    exp = Expect()
    for i in range(n):
        line = i + 2
        kind, value, state = vinfo[i]
        if kind == "nonfinite":                      # a float NaN/inf: kept as its text
            state = "NaN" if state != state else ("inf" if state > 0 else "-inf")
        flag = flags[i]
        if skind == "confidence" and flag == -1:     # PHD: -1 means no data, value NULL
            value = None
            if kind in ("bad", "empty"):
                kind, state = "good", None
        if skind == "confidence" and flag is not None:
            flag = f"confidence {flag}"
        elif flag is not None:
            flag = flag.strip() or None
        if not tag_ok[i] or tus[i] is None or kind in ("bad", "empty"):
            exp.bad(line)
            continue
        status = "; ".join(x for x in (state, flag) if x) or None
        exp.good(line, tag_vals[i].strip(), tus[i], value, status)
    return ParquetCase(frame, exp, tz, n)


def _wide_cell(draw, dtype):
    """A wide cell: ``(python value, kind, value, state)``; kind good/bad/none."""
    if dtype == pl.String:
        text, k, value, state = draw(text_cell())
        return text, ("none" if k == "empty" else k), value, state
    if draw(st.integers(0, 6)) == 0:
        return None, "none", None, None
    if dtype in (pl.Float64, pl.Float32):
        roll = draw(st.integers(0, 7))
        if roll == 0:
            return float("nan"), "none", None, None      # NaN in a numeric column: no sample
        if roll == 1:
            x = draw(st.sampled_from([float("inf"), float("-inf")]))
            return x, "good", None, "inf" if x > 0 else "-inf"   # a bad sample, value NULL
        x = draw(st.floats(allow_nan=False, allow_infinity=False,
                           width=64 if dtype == pl.Float64 else 32))
        return x, "good", float(x), None
    x = draw(st.integers(-2**31, 2**31 - 1))
    return x, "good", float(x), None


@st.composite
def parquet_wide(draw) -> ParquetCase:
    """A wide Parquet export with random tag columns of random dtypes, and its oracle."""
    n = draw(st.integers(0, 10))
    time_name = draw(st.sampled_from(["timestamp", "ts", "Time"]))
    names = draw(st.lists(wide_tag_names, min_size=1, max_size=3, unique_by=_norm))
    tseries, tus, tz, whole_error = draw(time_column(n, time_name))
    cols = [tseries]
    planned = []
    for name in names:
        dtype = draw(st.sampled_from([pl.Float64, pl.Float32, pl.Int64, pl.String]))
        cells = [_wide_cell(draw, dtype) for _ in range(n)]
        cols.append(pl.Series(name, [c[0] for c in cells], dtype=dtype))
        planned.append((name, cells))
    order = draw(st.permutations(range(len(cols))))
    frame = pl.DataFrame([cols[i] for i in order])
    if whole_error:
        return ParquetCase(frame, None, tz, n)
    exp = Expect()
    for i in range(n):
        line = i + 2
        if tus[i] is None:
            exp.bad(line)
            continue
        for name, cells in planned:
            _, kind, value, state = cells[i]
            if kind == "bad":
                exp.bad(line, tag=name.strip())
            elif kind == "good":
                exp.good(line, name.strip(), tus[i], value, state)
    return ParquetCase(frame, exp, tz, n)


def _expect(rows: list[tuple]) -> Expect:
    return csv_case("", rows).exp


def _run_parquet_case(case: ParquetCase, shape: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"{shape}.parquet")
        case.frame.write_parquet(path)
        parsed, err = call_reader(parse_export, path, (ExportError,), timezone=case.timezone)
        if case.exp is None:
            assert err is not None, "naive time stamps without a time zone must be an error"
            assert_one_line_naming(err, path)
            return
        assert err is None, f"unexpected whole-file error: {err}\n{case.frame}"
        assert parsed.shape == shape
        check_frames(parsed, path)
        check_against(parsed, case.exp)
        assert parsed.quarantine["raw"].null_count() == 0
        lines = set(parsed.quarantine["line"]) | set(parsed.samples["source_line"])
        assert lines <= set(range(2, case.rows + 2))


@settings(max_examples=70, **FUZZ)
@given(case=parquet_long())
def test_parquet_long_random_dtypes_every_row_stored_counted_or_quarantined(case):
    """Long Parquet with random dtypes (text/datetime with and without a zone/date/int and
    float epoch time; float/int/text values with states, NaN, inf and nulls; status or
    PHD confidence): every row is stored exactly, counted as an exact duplicate, or
    quarantined with its line (row + 2) and raw text; naive times without a zone are a
    one-line error naming the file."""
    _run_parquet_case(case, "long")


@settings(max_examples=60, **FUZZ)
@given(case=parquet_wide())
# inf in a numeric column is a bad sample (value NULL), not a stored value of inf
@example(case=ParquetCase(pl.DataFrame({"timestamp": [T0 // 10**6], "T1": [float("inf")]}),
                          _expect([("good", 2, "T1", T0, None, "inf")]), None, 1))
# a tag column whose name the reader uses internally
@example(case=ParquetCase(pl.DataFrame({"timestamp": [T0 // 10**6], "line": [1.0]}),
                          _expect([("good", 2, "line", T0, 1.0, None)]), None, 1))
def test_parquet_wide_random_dtypes_every_cell_accounted(case):
    """Wide Parquet with random tag columns (float, int, text): finite numbers are stored,
    ``inf`` and state texts are bad samples (``value = NULL``, text in status), null/NaN
    in a numeric column and empty text are no sample, other text is quarantined."""
    _run_parquet_case(case, "wide")


EXOTIC = {
    "bool": (pl.Boolean, [True, False, None]),
    "list": (pl.List(pl.Int64), [[1], [2, 3], None]),
    "array": (pl.Array(pl.Float64, 2), [[1.0, 2.0], [3.0, 4.0], None]),
    "struct": (pl.Struct({"x": pl.Int64}), [{"x": 1}, {"x": 2}, None]),
    "duration": (pl.Duration("us"), [dt.timedelta(seconds=1), dt.timedelta(0), None]),
    "binary": (pl.Binary, [b"1", b"Bad Input", None]),
    "date": (pl.Date, [dt.date(2024, 1, 1), dt.date(2024, 1, 2), None]),
    "time": (pl.Time, [dt.time(1), dt.time(2), None]),
    "decimal": (pl.Decimal(10, 3), [1, 2, None]),
    "categorical": (pl.Categorical, ["1", "Shutdown", None]),
    "null": (pl.Null, [None, None, None]),
    "uint64": (pl.UInt64, [2**64 - 1, 0, None]),
    "int8": (pl.Int8, [-128, 127, None]),
}


@settings(max_examples=100, **FUZZ)
@given(shape=st.sampled_from(["long", "wide"]), where=st.sampled_from(["value", "time", "tag"]),
       dtype=st.sampled_from(sorted(EXOTIC)))
@example(shape="wide", where="value", dtype="list")
@example(shape="wide", where="value", dtype="duration")
@example(shape="long", where="value", dtype="list")
def test_parquet_exotic_dtypes_give_a_clear_error_or_accounted_rows(shape, where, dtype):
    """Parquet columns of unusual dtypes (bool, list, array, struct, duration, binary,
    date, time, decimal, categorical, null, uint64, int8) as value, time or tag column:
    a one-line ``ExportError`` naming the file, or a parse in which each of the three
    rows is stored, quarantined or counted (long) and every line number is a real row."""
    ts = pl.Series([dt.datetime(2024, 1, 1, 0, 0, s, tzinfo=dt.timezone.utc) for s in range(3)])
    odd_dtype, odd_values = EXOTIC[dtype]
    odd = pl.Series(odd_values, dtype=odd_dtype)
    if shape == "long":
        cols = {"tag": pl.Series(["A", "B", "A"]), "timestamp": ts,
                "value": pl.Series([1.0, 2.0, 3.0])}
    else:
        cols = {"timestamp": ts, "T1": pl.Series([1.0, 2.0, 3.0])}
        where = "value" if where == "tag" else where
    target = {"value": "value" if shape == "long" else "T1", "time": "timestamp",
              "tag": "tag"}[where]
    cols[target] = odd
    frame = pl.DataFrame([s.alias(k) for k, s in cols.items()])
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "odd.parquet")
        frame.write_parquet(path)
        parsed, err = call_reader(parse_export, path, (ExportError,))
        if err is not None:
            assert_one_line_naming(err, path)
            return
        check_frames(parsed, path)
        stored = set(parsed.samples["source_line"])
        quarantined = set(parsed.quarantine["line"])
        assert stored | quarantined <= {2, 3, 4}
        if parsed.shape == "long":
            assert not stored & quarantined
            assert len(stored) + len(quarantined) + parsed.duplicates_dropped == 3


@functools.lru_cache(maxsize=None)
def _parquet_base(shape: str) -> bytes:
    t = [dt.datetime(2024, 1, 1, 0, 0, s, tzinfo=dt.timezone.utc) for s in range(5)]
    if shape == "long":
        frame = pl.DataFrame({"tag": ["A", "B", "A", "B", "A"], "ts": t,
                              "value": ["1", "Bad Input", "x", None, "2.5"]})
    else:
        frame = pl.DataFrame({"timestamp": t, "T1": [1.0, None, 3.0, float("nan"), 5.0],
                              "T2": ["1", "Shutdown", None, "x", "2"]})
    with tempfile.TemporaryDirectory() as tmp:
        frame.write_parquet(os.path.join(tmp, "b.parquet"))
        return Path(tmp, "b.parquet").read_bytes()


mutations = st.one_of(
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("set"), st.lists(st.tuples(st.floats(0, 1, exclude_max=True),
                                                 st.integers(0, 255)), min_size=1, max_size=4)),
    st.tuples(st.just("splice"), st.floats(0, 1, exclude_max=True), st.integers(0, 16),
              st.binary(max_size=16)),
    st.tuples(st.just("footer"), st.integers(-2**31, 2**31 - 1)),
)


def _mutate(data: bytes, mutation) -> bytes:
    b = bytearray(data)
    if mutation[0] == "truncate":
        return bytes(b[:int(mutation[1] * len(b))])
    if mutation[0] == "set":
        for where, byte in mutation[1]:
            b[int(where * len(b))] = byte
        return bytes(b)
    if mutation[0] == "splice":
        i = int(mutation[1] * len(b))
        b[i:i + mutation[2]] = mutation[3]
        return bytes(b)
    b[-8:-4] = struct.pack("<i", mutation[1])     # the footer length
    return bytes(b)


PANIC_MUTATION = ("set", [(673.5 / 1206, 125)])


@settings(max_examples=80, **FUZZ)
@given(shape=st.sampled_from(["long", "wide"]), mutation=mutations)
# one byte of the footer of the 5-row long base file changed (polars 2.1.0 writes it the
# same way every time): pl.read_parquet panics, pyo3_runtime.PanicException
@example(shape="long", mutation=PANIC_MUTATION)
def test_corrupted_parquet_gives_a_one_line_error_or_a_consistent_parse(shape, mutation):
    """Truncated, bit-flipped and spliced Parquet files: a one-line ``ExportError``
    naming the file, or (when the damage leaves a readable file) a parse with the
    documented schema, unique keys and no line both stored and quarantined."""
    data = _mutate(_parquet_base(shape), mutation)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "corrupt.parquet")
        Path(path).write_bytes(data)
        parsed, err = call_reader(parse_export, path, (ExportError,))
        if err is not None:
            assert_one_line_naming(err, path)
            return
        check_frames(parsed, path)
        if parsed.shape == "long":
            assert not set(parsed.samples["source_line"]) & set(parsed.quarantine["line"])


@settings(max_examples=12, **FUZZ)
@given(data=arbitrary_files, suffix=st.sampled_from([".csv", ".csv", ".parquet"]))
@example(data=CR_ONLY, suffix=".csv")
@example(data=ONLY_NBSP, suffix=".csv")
@example(data=MICROSECOND_EPOCH, suffix=".csv")
@example(data=_mutate(_parquet_base("long"), PANIC_MUTATION), suffix=".parquet")
def test_ingest_exports_never_raises_and_a_bad_file_does_not_stop_the_batch(data, suffix):
    """``ingest_exports`` over [good export, random file, good export] never raises: the
    random file is ingested or gets one one-line error naming it, and both good exports
    are stored in full (the nightly job goes on past a bad file)."""
    good = "tag,timestamp,value\n" + "".join(
        f"{{tag}},2024-01-01T00:00:0{s}Z,{s}\n" for s in range(3))
    with tempfile.TemporaryDirectory() as tmp:
        first, last = os.path.join(tmp, "a.csv"), os.path.join(tmp, "z.csv")
        Path(first).write_text(good.format(tag="GOOD.FIRST"))
        Path(last).write_text(good.format(tag="GOOD.LAST"))
        odd = os.path.join(tmp, "m_export" + suffix)
        Path(odd).write_bytes(data)
        with Store(os.path.join(tmp, "plant.duckdb")) as store:
            def ingest_exports_into_store(paths):
                return ingest_exports(store, paths)
            report, _ = call_reader(ingest_exports_into_store, [first, odd, last], ())
            for e in report.errors:
                assert_one_line_naming(e, odd)
            assert len(report.errors) <= 1
            for tag in ("GOOD.FIRST", "GOOD.LAST"):
                assert store.fetch_tag(tag)["value"].to_list() == [0.0, 1.0, 2.0]
            assert store.duplicate_keys() == 0


# --------------------------------------------------------------------------
# 5. loops.csv and single-loop CSV
# --------------------------------------------------------------------------
LOOPS_TOKENS = [",", ",", '"', "\r", "\n", "\n", "\r\n", " ", "FIC101", "FIC101.PV", "x",
                "integrating", "self-regulating", "sticky", "1", "-1", "0", "nan", "inf",
                "\x00", BOM, "\u00e9", ";", "\t"]
LOOPS_HEADERS = ["loop,pv_tag,op_tag", "loop,pv_tag,op_tag,sp_tag,process_type,span,criticality",
                 "name,pv,op,mode,unit,description", "loop,pv_tag", "loop,loop,pv_tag,op_tag", ""]
loops_text = st.one_of(
    st.builds(lambda h, body: h + "\n" + body, st.sampled_from(LOOPS_HEADERS),
              st.lists(st.sampled_from(LOOPS_TOKENS), max_size=40).map("".join)),
    st.text(max_size=120),
)


@settings(max_examples=80, **FUZZ)
@given(text=loops_text, enc=encodings)
@example(text="loop,pv_tag,op_tag\rA,a,b\r", enc="utf-8")
@example(text='loop,pv_tag,op_tag\n"' + "x" * 140_000 + '",a,b\n', enc="utf-8")
# a quoted loop name holding a line break: each problem must still be one line
@example(text='loop,pv_tag,op_tag\n"A\nB",a,\n', enc="utf-8")
def test_read_loops_csv_random_text_only_registry_error(text, enc):
    """Random and malformed ``loops.csv``: ``RegistryError`` with one line naming the
    file, or loops with unique names and one-line problems naming the file."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "loops.csv")
        Path(path).write_bytes(text.encode(enc, errors="replace"))
        result, err = call_reader(read_loops_csv, path, (RegistryError,))
        if err is not None:
            assert_one_line_naming(err, path)
            return
        loops, problems = result
        names = [lp.loop for lp in loops]
        assert len(names) == len(set(names)) and all(names)
        for p in problems:
            assert len(p.splitlines()) == 1 and p.startswith(path), p


# Time stamps are small numbers, a few extreme ones, or whole seconds within one minute,
# so that no combination asks read_loop_csv for a grid of 1e8..1e10 points, which would
# really be allocated. The extremes (1e15, 1e-300) ask for absurd sizes that numpy
# refuses at once.
LOOP_TS = ["0", "1", "2", "3", "10", "0.5", "-1", "inf", "nan", "1e15", "1e-300", "x", "",
           "2026-11-01T00:00:00Z", "2026-11-01T00:00:05+00:00", "2026-11-01T00:00:30Z",
           "I/O Timeout"]
LOOP_VALUES = ["1", "2.5", "-3", "", "Bad Input", "nan", "inf", "1e308", "x"]


@st.composite
def loop_csv_text(draw) -> str:
    header = draw(st.sampled_from(["timestamp,pv,op", "time,pv,op,sp,mv", "ts,PV,OP,SP",
                                   "timestamp,pv", "timestamp,pv,op,pv", "", "date,co,pv"]))
    rows = draw(st.lists(st.lists(st.one_of(st.sampled_from(LOOP_TS), st.sampled_from(LOOP_VALUES)),
                                  min_size=1, max_size=5), max_size=8))
    rows = [[draw(st.sampled_from(LOOP_TS))] + r[1:] for r in rows]
    body = "\n".join(",".join(r) for r in rows)
    noise = draw(st.lists(st.sampled_from(LOOPS_TOKENS), max_size=3).map("".join))
    return header + "\n" + body + "\n" + noise


@settings(max_examples=80, **FUZZ)
@given(text=st.one_of(loop_csv_text(), st.text(max_size=80)))
@example(text="timestamp,pv,op\n0,1,2\n1,2,3\ninf,3,4\n")
@example(text="timestamp,pv,op\n0,1,2\n1,2,3\n2,2,3\n1e15,3,4\n")
@example(text="\x0c\n0")     # a form feed for a header: escaped in the one-line message
def test_read_loop_csv_random_text_only_loopfile_error(text):
    """Random and malformed single-loop CSV: ``LoopFileError`` with one line naming the
    file, or a record on a uniform, increasing grid with arrays of the grid's length."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "loop.csv")
        Path(path).write_bytes(text.encode("utf-8", errors="replace"))
        result, err = call_reader(read_loop_csv, path, (LoopFileError,))
        if err is not None:
            assert_one_line_naming(err, path)
            return
        rec, meta = result
        assert rec.t.size >= 2 and rec.t[0] == 0
        assert rec.sample_time > 0
        for arr in (rec.pv, rec.op, rec.sp, rec.mv):
            assert arr is None or arr.shape == rec.t.shape
        assert meta["file"] == path


# --------------------------------------------------------------------------
# 6. round trip through ingest_exports into DuckDB
# --------------------------------------------------------------------------
@settings(max_examples=8, **FUZZ)
@given(case=st.one_of(long_csv(max_rows=15), long_csv(max_rows=12, few_keys=True),
                      wide_csv(max_rows=8)),
       chunk_rows=st.sampled_from([None, 1, 2, 3, 5]))
# slices [2,3] and [4,5]: line 5 repeats line 4, which conflicts with the stored line 2;
# line 5 must be quarantined as a conflict, as in a whole-file parse, not counted as an
# exact duplicate of the (quarantined) line 4
@example(case=csv_case("tag,timestamp,value\nA,2024-01-01T00:00:00Z,1\nB,2024-01-01T00:00:00Z,5\n"
                       "A,2024-01-01T00:00:00Z,2\nA,2024-01-01T00:00:00Z,2\n",
                       [("good", 2, "A", T0, 1.0, None), ("good", 3, "B", T0, 5.0, None),
                        ("good", 4, "A", T0, 2.0, None), ("good", 5, "A", T0, 2.0, None)]),
         chunk_rows=2)
def test_ingest_round_trip_accounts_for_every_line_and_reingest_changes_nothing(
        case, chunk_rows):
    """Ingest a random export (long or wide, in slices of ``chunk_rows``) into a real
    DuckDB store: the stored samples are exactly the oracle's good samples, every line
    is in samples, in quarantine or counted duplicate, and ingesting the same file again
    (skipped by hash, then forced) changes no row count and stores no key twice.
    Finally, the slice size changes nothing: stored, quarantined and counted lines are
    those of a whole-file parse."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "export.csv")
        Path(path).write_bytes(case.data)
        with Store(os.path.join(tmp, "plant.duckdb")) as store:
            first = ingest_exports(store, [path], chunk_rows=chunk_rows)
            assert first.ok, first.errors
            counts = store.counts()
            samples = store.con.sql(
                "SELECT tag, ts, value, status, source_file, source_line FROM samples").pl()
            quarantine = store.quarantine()
            # samples: exactly the oracle's good, first-seen samples
            got = actual_stored(samples.with_columns(pl.col("ts").cast(pl.Datetime("us", "UTC"))))
            assert got == case.exp.stored, "stored samples differ from the good rows"
            assert store.duplicate_keys() == 0
            assert set(samples["source_file"]) <= {path}
            # every line accounted: distinct (line, reason) quarantine rows + samples + dups
            assert (counts["samples"] + counts["quarantine"] + first.rows_skipped_duplicate
                    == len(case.exp.stored) + sum(case.exp.quarantine.values())
                    + len(case.exp.dup_lines)), "a sample or line is unaccounted for"
            assert first.rows_inserted == counts["samples"]
            for force in (False, True):
                again = ingest_exports(store, [path], chunk_rows=chunk_rows, force=force)
                assert again.ok and again.rows_inserted == 0
                assert store.counts()["samples"] == counts["samples"]
                assert store.counts()["quarantine"] == counts["quarantine"]
                assert store.duplicate_keys() == 0
            # slicing must not change which lines are quarantined or counted
            whole = parse_export(path)
            assert collections.Counter(quarantine["line"].to_list()) == collections.Counter(
                whole.quarantine["line"].to_list()), \
                f"chunk_rows={chunk_rows}: quarantined lines differ from a whole-file parse"
            assert first.rows_skipped_duplicate == whole.duplicates_dropped
