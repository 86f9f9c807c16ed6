"""JSON files read as hostile input and written as strict JSON.

``read_json`` reads a regular file of at most ``max_bytes`` bytes holding at most
``max_values`` JSON values (counted on the bytes before parsing, so the parsed document
costs a bounded multiple of the file: a flat list of a million empty lists would otherwise
take thirty times its bytes), refuses the non-standard constants ``NaN``, ``Infinity`` and
``-Infinity``, and turns every failure into one ``DataFileError`` line naming the file.

``dumps`` writes strict JSON: a non-finite float becomes ``null`` (no bare ``NaN`` in any
file); ``write_json`` writes it atomically (``sapga_ros.io.atomic``).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from sapga_ros.errors import DataFileError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.bounded import TooLarge, read_bounded

MAX_VALUES = 1_000_000     # JSON values in one file, by default


def _constant(name: str) -> Any:
    raise ValueError(f'{name} is not JSON (a non-finite number)')


def value_count(data: bytes) -> int:
    """An upper bound of the number of JSON values ``data`` can hold."""
    return sum(data.count(c) for c in (b'[', b'{', b',', b':')) + 1


def parse_json(data: bytes, where: str, max_values: int = MAX_VALUES) -> Any:
    """The strict JSON document of ``data`` (see the module doc); DataFileError if not."""
    if value_count(data) > max_values:
        raise DataFileError(f'{where}: more than {max_values} JSON values')
    try:
        return json.loads(data, parse_constant=_constant)
    except RecursionError:
        raise DataFileError(f'{where}: nested too deeply') from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise DataFileError(f'{where}: not valid JSON ({str(exc)[:100]})') from None


def read_json(path: str | os.PathLike, max_bytes: int, max_values: int = MAX_VALUES) -> Any:
    """The strict JSON document in regular file ``path`` (bounded; see the module doc)."""
    try:
        data = read_bounded(path, max_bytes)
    except TooLarge:
        raise DataFileError(f'{path}: larger than {max_bytes} bytes') from None
    except OSError as exc:
        raise DataFileError(f'{path}: cannot read ({exc.strerror or exc})') from None
    return parse_json(data, str(path), max_values)


def finite(obj: Any) -> Any:
    """``obj`` with every non-finite float (nested in dicts, lists, tuples) as None."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    return obj


def dumps(obj: Any, **kwargs: Any) -> str:
    """Strict JSON text of ``obj``: non-finite floats written as null."""
    return json.dumps(finite(obj), allow_nan=False, **kwargs)


def write_json(path: str | os.PathLike, obj: Any, **kwargs: Any) -> Path:
    """Write ``obj`` as strict JSON to ``path`` atomically."""
    return write_atomic(path, dumps(obj, **kwargs))
