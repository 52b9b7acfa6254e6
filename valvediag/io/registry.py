"""
The loop registry: ``loops.csv``, one row per control loop.

Columns (header names are case-insensitive; aliases in brackets)::

    loop (name, loop_name)          required, unique
    pv_tag (pv)                     required column; an empty cell is a problem
    op_tag (op)                     required column; an empty cell is a problem
    sp_tag (sp), mv_tag (mv), mode_tag (mode)     optional
    process_type                    integrating | self-regulating | unknown
                                    (level: integrating; flow: self-regulating)
    unit, span, criticality, description          optional
    sampling                        point | average: what each PV sample is
                                    (default point)

:func:`read_loops_csv` never drops a loop silently. A loop without a PV (or OP)
tag is returned with an ``issues`` entry (``"no PV tag in loops.csv"``) so the
scan can give it ``insufficient-data`` with that reason; every problem is also
listed, one line each, naming the file, the line and the loop.

Notes
-----
* ``mode_tag`` is an extension of the documented column list: the quality screen
  reports manual-mode time when a loop has one.
* ``span`` is the PV span in engineering units [PV unit]. Empty means "derive
  from the data later" (NaN). It must be positive when given.
* ``criticality`` is a dimensionless weight >= 0 for ranking (default 1.0).
* ``sampling`` says what the export's PV samples are: ``point``, the PV's
  value at the time stamp (a snapshot, interpolated or recorded export; the
  default), or ``average``, its mean over the sample time (a historian's
  average or time-weighted average export). An average rounds a sharp turn
  over one sample, which the Backlash Index would read as a dead band; the
  data cannot tell the two kinds apart, so the registry says which
  (:data:`SAMPLING_ALIASES` lists the other words read).
* A row with more fields than the header is skipped (its fields cannot be
  attributed to columns) and reported. A row whose loop name repeats an
  earlier one is skipped and reported; the first row wins.
"""
from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

from ..plain import printable

__all__ = ["LoopSpec", "RegistryError", "read_loops_csv", "PROCESS_TYPES",
           "PROCESS_TYPE_ALIASES", "ROLES", "SAMPLINGS", "SAMPLING_ALIASES"]

PROCESS_TYPES = ("integrating", "self-regulating", "unknown")
#: Process types written as the loop's kind, read as the type they name: a
#: liquid level integrates the difference of its flows, a flow through a
#: valve settles. Pressure and temperature are either (a gas volume's
#: pressure integrates, a liquid line's settles): those stay ``unknown``
#: and the data's tests decide.
PROCESS_TYPE_ALIASES = {"level": "integrating", "integrator": "integrating",
                        "flow": "self-regulating", "self-regulated": "self-regulating",
                        "selfregulating": "self-regulating",
                        "non-integrating": "self-regulating", "": "unknown"}
#: What an export's PV samples are: the value at the time stamp, or the mean
#: over the sample time.
SAMPLINGS = ("point", "average")
#: Other words for them, as historians' export dialogs name them.
SAMPLING_ALIASES = {"": "point", "snapshot": "point", "sampled": "point",
                    "interpolated": "point", "recorded": "point", "raw": "point",
                    "averaged": "average", "mean": "average", "time-weighted": "average",
                    "time-weighted-average": "average", "twa": "average"}
#: Signal roles of a loop, in the order ``LoopSpec.tags`` lists them.
ROLES = ("pv", "op", "sp", "mv", "mode")
#: Longest description kept [characters]; a longer one is shortened, with a problem line.
DESCRIPTION_MAX = 2000

_COLUMNS = {
    "loop": ("loop", "name", "loop_name"),
    "pv_tag": ("pv_tag", "pv"),
    "op_tag": ("op_tag", "op"),
    "sp_tag": ("sp_tag", "sp"),
    "mv_tag": ("mv_tag", "mv"),
    "mode_tag": ("mode_tag", "mode"),
    "process_type": ("process_type",),
    "unit": ("unit",),
    "span": ("span",),
    "criticality": ("criticality",),
    "description": ("description",),
    "sampling": ("sampling",),
}
_REQUIRED = ("loop", "pv_tag", "op_tag")


class RegistryError(ValueError):
    """loops.csv cannot be read at all. The message is one line naming the file."""


@dataclass(frozen=True)
class LoopSpec:
    """One control loop of the registry.

    Attributes
    ----------
    loop : str
        Loop name, unique in the registry.
    pv_tag, op_tag, sp_tag, mv_tag, mode_tag : str or None
        Historian tags of the process variable, controller output, set point,
        measured valve position and controller mode.
    process_type : str
        ``integrating``, ``self-regulating`` or ``unknown`` (``level`` and
        ``flow`` in the file are read as the first two,
        :data:`PROCESS_TYPE_ALIASES`).
    unit : str or None
        Engineering unit of the PV.
    span : float
        PV span [PV unit]; NaN when not given.
    criticality : float
        Ranking weight [-], default 1.0.
    description : str
        Free text.
    sampling : str
        ``point`` or ``average``: whether each PV sample of the exports is
        the value at its time stamp or the mean over the sample time.
    issues : tuple of str
        Problems that limit what the scan can do for this loop, e.g.
        ``"no PV tag in loops.csv"``. Empty when the row is fine.
    """

    loop: str
    pv_tag: str | None = None
    op_tag: str | None = None
    sp_tag: str | None = None
    mv_tag: str | None = None
    mode_tag: str | None = None
    process_type: str = "unknown"
    unit: str | None = None
    span: float = math.nan
    criticality: float = 1.0
    description: str = ""
    sampling: str = "point"
    issues: tuple[str, ...] = ()

    @property
    def tags(self) -> dict[str, str]:
        """Role (``pv``, ``op``, ``sp``, ``mv``, ``mode``) -> tag, for the roles set."""
        out = {}
        for role in ROLES:
            tag = getattr(self, f"{role}_tag")
            if tag:
                out[role] = tag
        return out

    @property
    def usable(self) -> bool:
        """True when the loop has both a PV and an OP tag."""
        return bool(self.pv_tag and self.op_tag)


def _read_text(path: str) -> str:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise RegistryError(f"{path}: cannot read loop registry ({exc.strerror})") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return text.replace("\r\n", "\n").replace("\r", "\n")   # old Mac line ends too


def _rows(reader, path: str, problems: list[str]):
    """``(first line, fields)`` of each record; a record the csv module refuses is a problem."""
    while True:
        start = reader.line_num + 1
        try:
            fields = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            problems.append(f"{path} line {start}: unreadable row ({exc}); row skipped")
            continue
        yield start, fields


def _shown(name: str) -> str:
    """A loop name fit for a one-line message (line breaks and controls escaped)."""
    return printable(name)


def _map_header(header: list[str], path: str) -> list[str]:
    lookup = {alias: col for col, aliases in _COLUMNS.items() for alias in aliases}
    found = ", ".join(repr(h) for h in header)
    names = [h.strip().lower().replace(" ", "_") for h in header]
    unknown = [h for h, n in zip(header, names) if n not in lookup]
    if unknown:
        raise RegistryError(f"{path}: unknown columns {unknown} (expected "
                            f"{','.join(_COLUMNS)}); columns found: {found}")
    mapped = [lookup[n] for n in names]
    dupes = sorted({m for m in mapped if mapped.count(m) > 1})
    if dupes:
        raise RegistryError(f"{path}: columns {dupes} given more than once; columns found: {found}")
    missing = [c for c in _REQUIRED if c not in mapped]
    if missing:
        raise RegistryError(f"{path}: missing required columns {missing}; columns found: {found}")
    return mapped


def _number(text: str, default: float) -> tuple[float, bool]:
    if not text:
        return default, True
    try:
        x = float(text)
    except ValueError:
        return default, False
    return x, math.isfinite(x)


def _named(text: str, aliases: dict[str, str]) -> str:
    """A word of the file in its canonical spelling: lower case, words joined
    by hyphens, an alias read as the word it stands for."""
    word = text.strip().lower().replace("_", "-").replace(" ", "-")
    return aliases.get(word, word)


def _row_to_spec(row: dict[str, str], where: str) -> tuple[LoopSpec, list[str]]:
    """Build a LoopSpec; return it with the problems found (each naming ``where``)."""
    issues, problems = [], []

    def note(issue: str) -> None:
        issues.append(issue)
        problems.append(f"{where}: {issue}")

    tags = {role: (row.get(f"{role}_tag") or None) for role in ROLES}
    if not tags["pv"]:
        note("no PV tag in loops.csv")
    if not tags["op"]:
        note("no OP tag in loops.csv")
    if tags["pv"] and tags["pv"] == tags["op"]:
        note(f"PV and OP are the same tag {tags['pv']!r}")

    raw_type = row.get("process_type", "")
    ptype = _named(raw_type, PROCESS_TYPE_ALIASES)
    if ptype not in PROCESS_TYPES:
        note(f"invalid process_type {raw_type!r} (expected one of {', '.join(PROCESS_TYPES)}, "
             f"or level or flow); using 'unknown'")
        ptype = "unknown"

    span, ok = _number(row.get("span", ""), math.nan)
    if not ok or span <= 0:
        note(f"invalid span {row.get('span')!r} (must be a positive number); derived from data")
        span = math.nan
    crit, ok = _number(row.get("criticality", ""), 1.0)
    if not ok or crit < 0:
        note(f"invalid criticality {row.get('criticality')!r} (must be >= 0); using 1.0")
        crit = 1.0

    raw_sampling = row.get("sampling", "")
    sampling = _named(raw_sampling, SAMPLING_ALIASES)
    if sampling not in SAMPLINGS:
        note(f"invalid sampling {raw_sampling!r} (expected point or average); using 'point'")
        sampling = "point"

    description = row.get("description", "")
    if len(description) > DESCRIPTION_MAX:
        note(f"description of {len(description):,} characters shortened to "
             f"{DESCRIPTION_MAX:,}")
        description = description[:DESCRIPTION_MAX - 1] + "\u2026"
    spec = LoopSpec(loop=row["loop"], pv_tag=tags["pv"], op_tag=tags["op"], sp_tag=tags["sp"],
                    mv_tag=tags["mv"], mode_tag=tags["mode"], process_type=ptype,
                    unit=row.get("unit") or None, span=span, criticality=crit,
                    description=description, sampling=sampling, issues=tuple(issues))
    return spec, problems


def read_loops_csv(path: str | os.PathLike) -> tuple[list[LoopSpec], list[str]]:
    """Read and validate a ``loops.csv`` registry.

    Parameters
    ----------
    path : str or path-like
        The registry file (comma separated, header row).

    Returns
    -------
    loops : list of LoopSpec
        One per distinct loop name, in file order. Loops with problems are
        included; their ``issues`` say what is wrong.
    problems : list of str
        One line per problem: ``"<file> line <n> (loop <name>): <what>"``.

    Raises
    ------
    RegistryError
        The file is missing or empty, or its header has unknown, repeated or
        missing required columns. One line naming the file and the columns.
    """
    path = os.fspath(path)
    text = _read_text(path)
    # a field may be as long as the file (a long description); the csv module's
    # default limit (128 KiB) would drop its row
    if csv.field_size_limit() < len(text):
        csv.field_size_limit(len(text))
    reader = csv.reader(io.StringIO(text))
    try:
        header = next((r for r in reader if any(c.strip() for c in r)), None)
    except csv.Error as exc:
        raise RegistryError(f"{path}: unreadable header ({exc})") from None
    if header is None:
        raise RegistryError(f"{path}: empty loop registry (no header)")
    columns = _map_header(header, path)

    loops: list[LoopSpec] = []
    problems: list[str] = []
    first_line: dict[str, int] = {}
    for line, fields in _rows(reader, path, problems):
        if not any(f.strip() for f in fields):
            continue
        if len(fields) > len(columns):
            problems.append(f"{path} line {line}: {len(fields)} fields but the header has "
                            f"{len(columns)}; row skipped")
            continue
        row = {c: f.strip() for c, f in zip(columns, fields)}
        name = row.get("loop", "")
        if not name:
            problems.append(f"{path} line {line}: no loop name; row skipped")
            continue
        where = f"{path} line {line} (loop {_shown(name)})"
        if len(fields) < len(columns):
            problems.append(f"{where}: {len(fields)} fields but the header has {len(columns)}; "
                            f"missing fields taken as empty")
        if name in first_line:
            problems.append(f"{where}: duplicate loop name (first on line {first_line[name]}); "
                            f"row skipped")
            continue
        first_line[name] = line
        spec, row_problems = _row_to_spec(row, where)
        loops.append(spec)
        problems.extend(row_problems)
    return loops, problems
