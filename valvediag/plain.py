"""
Plain values: what results become in JSON, in one-line messages and as time
stamps. Every module that writes JSON, reports an error in one line or takes a
time from its caller uses these, so the rules are the same everywhere.
"""
from __future__ import annotations

import dataclasses
import datetime as dt
import math
import os
from collections.abc import Mapping
from pathlib import Path

__all__ = ["to_plain", "finite_or_none", "one_line", "first_line", "printable", "aware_utc",
           "spreadsheet_safe"]


def to_plain(obj):
    """A value made of plain JSON types.

    Parameters
    ----------
    obj : object
        Nested mappings, sequences, dataclasses (their ``to_json()`` when they
        have one), numpy arrays and scalars, floats, datetimes, paths.

    Returns
    -------
    object
        Dicts with string keys, lists, str, int, float, bool or None:
        NaN and infinities become None, datetimes and dates ISO 8601 text,
        paths their text.

    Examples
    --------
    >>> import numpy as np
    >>> to_plain({"bi": np.float64("nan"), "cycles": np.int64(3), "t": (1.5, float("inf"))})
    {'bi': None, 'cycles': 3, 't': [1.5, None]}
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = obj.to_json() if hasattr(obj, "to_json") else dataclasses.asdict(obj)
    if isinstance(obj, Mapping):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_plain(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):   # numpy
        return to_plain(obj.tolist())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (dt.datetime, dt.date)):
        return obj.isoformat()
    if isinstance(obj, Path):
        return os.fspath(obj)
    return obj


def finite_or_none(x, digits: int | None = None):
    """A number as a float (rounded to ``digits`` decimals), or None when missing.

    Parameters
    ----------
    x : number, str, bool or None
        Text and booleans pass unchanged.
    digits : int, optional
        Decimals kept.

    Returns
    -------
    float, str, bool or None
        None for None, NaN and infinities.

    Examples
    --------
    >>> finite_or_none(2.0 / 3.0, 3), finite_or_none(float("nan")), finite_or_none("kano")
    (0.667, None, 'kano')
    """
    if x is None or isinstance(x, (str, bool)):
        return x
    x = float(x)
    if not math.isfinite(x):
        return None
    return round(x, digits) if digits is not None else x


def one_line(exc: BaseException | str) -> str:
    """An error as one line: its text with every run of white space (line breaks
    included) made one blank; the exception's type when it has no text.

    Parameters
    ----------
    exc : BaseException or str

    Returns
    -------
    str

    Examples
    --------
    >>> one_line(RuntimeError("disk full\\nwhile writing report.html"))
    'disk full while writing report.html'
    """
    text = " ".join(str(exc).split())
    return text or (type(exc).__name__ if isinstance(exc, BaseException) else "")


def first_line(exc: BaseException) -> str:
    """The first line of an error's text (libraries append details on later lines),
    its blanks collapsed; the exception's type when it has no text.

    Parameters
    ----------
    exc : BaseException

    Returns
    -------
    str
    """
    text = str(exc).strip()
    return " ".join(text.splitlines()[0].split()) if text else type(exc).__name__


def printable(text: str) -> str:
    """Text fit for a one-line message: every character that is not printable (line
    breaks of any kind, including ``\\x85`` and ``\\u2028``, form feeds and other
    controls) shown escaped, e.g. ``\\x0c``.

    Parameters
    ----------
    text : str

    Returns
    -------
    str

    Examples
    --------
    >>> printable("a\\x85b")
    'a\\\\x85b'
    """
    text = str(text)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                   for c in text)


def aware_utc(value: dt.datetime | None, what: str) -> dt.datetime | None:
    """A time zone aware time, in UTC; a naive one is refused, not guessed.

    Parameters
    ----------
    value : datetime.datetime or None
    what : str
        Name of the argument, for the message.

    Returns
    -------
    datetime.datetime or None

    Raises
    ------
    TypeError
        Not a datetime.
    ValueError
        A naive datetime.
    """
    if value is None:
        return None
    if not isinstance(value, dt.datetime):
        raise TypeError(f"{what} must be a datetime, not {type(value).__name__}")
    if value.tzinfo is None or value.utcoffset() is None:
        raise ValueError(f"{what} {value.isoformat()} has no time zone; give an aware datetime "
                         f"(e.g. tzinfo=datetime.timezone.utc)")
    return value.astimezone(dt.timezone.utc)


#: First characters that make a spreadsheet read a cell as a formula.
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def spreadsheet_safe(text) -> str:
    """A CSV cell that a spreadsheet shows as text, never runs as a formula.

    Parameters
    ----------
    text : object
        The cell's value (taken as ``str``).

    Returns
    -------
    str
        The text, with a leading apostrophe when it starts with ``=``, ``+``,
        ``-``, ``@``, a tab or a carriage return (the OWASP advice against CSV
        injection). Spreadsheets hide the apostrophe.

    Examples
    --------
    >>> spreadsheet_safe('=HYPERLINK("http://x")')
    '\'=HYPERLINK("http://x")'
    >>> spreadsheet_safe("Drum level")
    'Drum level'
    """
    text = str(text)
    return "'" + text if text.startswith(FORMULA_STARTS) else text
