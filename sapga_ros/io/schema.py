"""Schema checks for parsed JSON documents: every reader of the package's data files takes
its fields through these, so a field of the wrong type, shape, length or range is refused
with one ``DataFileError`` line naming the file and the field (``where``), never a
traceback further on.

Numbers are ints or floats (never bools), finite unless ``null`` is allowed, in which case
JSON ``null`` reads as nan (how the package writes a non-finite float).
"""
from __future__ import annotations

import math
import re
from typing import Any

from sapga_ros.errors import DataFileError

MAX_TEXT = 1000            # characters of a text field, by default


def _shown(value: Any) -> str:
    text = repr(value) if not isinstance(value, (dict, list)) else type(value).__name__
    return text[:40]


def fail(where: str, expected: str, value: Any) -> DataFileError:
    """The error of a field ``where`` that is not ``expected``."""
    return DataFileError(f'{where}: expected {expected}, got {_shown(value)}')


def mapping(value: Any, where: str) -> dict:
    """``value`` if it is a JSON object."""
    if not isinstance(value, dict):
        raise fail(where, 'an object', value)
    return value


def field(doc: dict, key: str, where: str) -> Any:
    """``doc[key]``; DataFileError naming ``where.key`` if it is missing."""
    if key not in doc:
        raise DataFileError(f'{where}: missing field {key!r}')
    return doc[key]


def number(value: Any, where: str, low: float = -math.inf, high: float = math.inf,
           null: bool = False) -> float:
    """A number in [low, high]; with ``null``, None reads as nan."""
    if value is None and null:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise fail(where, 'a number' + (' or null' if null else ''), value)
    try:
        x = float(value)
    except OverflowError:
        raise fail(where, 'a number of float range', value) from None
    if not (math.isfinite(x) and low <= x <= high):
        raise fail(where, f'a finite number in [{low}, {high}]', value)
    return x


def integer(value: Any, where: str, low: int, high: int) -> int:
    """A whole number in [low, high] (JSON integers only)."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise fail(where, f'a whole number in [{low}, {high}]', value)
    return value


def boolean(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise fail(where, 'true or false', value)
    return value


def text(value: Any, where: str, max_len: int = MAX_TEXT, pattern: str | None = None) -> str:
    """A string of at most ``max_len`` characters (matching ``pattern`` if given)."""
    if not isinstance(value, str) or len(value) > max_len or \
            (pattern is not None and not re.fullmatch(pattern, value)):
        shape = f' matching {pattern}' if pattern else ''
        raise fail(where, f'a text of at most {max_len} characters{shape}', value)
    return value


def sequence(value: Any, where: str, max_len: int, length: int | None = None,
             min_len: int = 0) -> list:
    """A JSON list of ``length`` items (or ``min_len`` to ``max_len``)."""
    if not isinstance(value, list):
        raise fail(where, 'a list', value)
    if length is not None and len(value) != length:
        raise DataFileError(f'{where}: expected {length} items, got {len(value)}')
    if not min_len <= len(value) <= max_len:
        raise DataFileError(f'{where}: expected {min_len} to {max_len} items, '
                            f'got {len(value)}')
    return value


def numbers(value: Any, where: str, max_len: int, length: int | None = None,
            null: bool = False, min_len: int = 0, low: float = -math.inf,
            high: float = math.inf) -> list[float]:
    """A list of numbers (see ``number``) of ``length`` items (or up to ``max_len``)."""
    items = sequence(value, where, max_len, length, min_len)
    return [number(v, f'{where}[{i}]', low, high, null) for i, v in enumerate(items)]


def integers(value: Any, where: str, max_len: int, low: int, high: int,
             length: int | None = None, min_len: int = 0) -> list[int]:
    items = sequence(value, where, max_len, length, min_len)
    return [integer(v, f'{where}[{i}]', low, high) for i, v in enumerate(items)]
