"""JSON files read as hostile input and written as strict JSON.

``read_json`` reads a regular file of at most ``max_bytes`` bytes holding at most
``max_values`` JSON values (counted on the bytes before parsing, so the parsed document
costs a bounded multiple of the file: a flat list of a million empty lists would otherwise
take thirty times its bytes), refuses the non-standard constants ``NaN``, ``Infinity`` and
``-Infinity``, and turns every failure into one ``DataFileError`` line naming the file.

``strict_loads`` is the one parser under both: a bare ``NaN`` or ``Infinity`` anywhere is
refused with one line naming the field that holds it (``runs[3].best_value: bare NaN ...``).

``dumps`` writes strict JSON: a non-finite float becomes ``null`` (no bare ``NaN`` in any
file); ``write_json`` writes it atomically (``sapga_ros.io.atomic``).  A format that must
keep inf apart from NaN (a checkpoint's counters) writes it tagged instead:
``tagged_dumps`` writes ``{"$nonfinite": "inf"}`` (or ``"-inf"``, ``"nan"``) and
``strict_loads(..., tagged=True)`` reads it back as the float.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Callable

from sapga_ros.errors import DataFileError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.bounded import TooLarge, read_bounded

MAX_VALUES = 1_000_000     # JSON values in one file, by default


TAG = '$nonfinite'
_TAGGED = {'inf': math.inf, '-inf': -math.inf, 'nan': math.nan}


class _Bare:
    """A bare non-standard constant met while parsing (refused once the field is known)."""

    def __init__(self, name: str) -> None:
        self.name = name


def bare_field(doc: Any) -> tuple[str, str] | None:
    """(field path, constant) of the first ``_Bare`` in ``doc`` (walked without recursion)."""
    stack: list[tuple[str, Any]] = [('', doc)]
    while stack:
        where, value = stack.pop()
        if isinstance(value, _Bare):
            return where or '(document)', value.name
        if isinstance(value, dict):
            stack.extend((f'{where}.{k}' if where else str(k), v)
                         for k, v in reversed(value.items()))
        elif isinstance(value, list):
            stack.extend((f'{where}[{i}]', v) for i, v in reversed(list(enumerate(value))))
    return None


def _untag(obj: dict) -> Any:
    if len(obj) == 1 and obj.get(TAG) in _TAGGED:
        return _TAGGED[obj[TAG]]
    return obj


def unique_object(pairs: list[tuple[str, Any]]) -> dict:
    """A JSON object's dict, refusing a key given twice (``json``'s ``object_pairs_hook``):
    readers that keep the first or the last of them would read different documents."""
    doc = dict(pairs)
    if len(doc) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise ValueError(f'key {key[:60]!r} given twice')
            seen.add(key)
    return doc


def strict_loads(data: bytes | str, where: str, error: type[Exception] = DataFileError,
                 tagged: bool = False, legacy: bool = False) -> Any:
    """The JSON document of ``data``; ``error`` (one line naming ``where`` and the field) if
    it holds a bare NaN/Infinity or is not JSON.  ``tagged``: read tagged non-finite floats;
    ``legacy``: also read bare NaN/Infinity as floats (what earlier versions of a format
    wrote; the caller checks every field)."""
    seen: list[str] = []

    def bare(name: str) -> Any:
        if legacy:
            return float(name)
        seen.append(name)
        return _Bare(name)
    try:
        doc = json.loads(data, parse_constant=bare, object_pairs_hook=(
            (lambda pairs: _untag(unique_object(pairs))) if tagged else unique_object))
    except RecursionError:
        raise error(f'{where}: nested too deeply') from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise error(f'{where}: not valid JSON ({str(exc)[:100]})') from None
    if seen:
        path, name = bare_field(doc) or ('(a key)', seen[0])
        raise error(f'{where}: not valid JSON (field {path[:100]}: bare {name}, a '
                    'non-finite number)')
    return doc


def value_count(data: bytes) -> int:
    """An upper bound of the number of JSON values ``data`` can hold."""
    return sum(data.count(c) for c in (b'[', b'{', b',', b':')) + 1


def parse_json(data: bytes, where: str, max_values: int = MAX_VALUES) -> Any:
    """The strict JSON document of ``data`` (see the module doc); DataFileError if not."""
    if value_count(data) > max_values:
        raise DataFileError(f'{where}: more than {max_values} JSON values')
    return strict_loads(data, where)


def read_json(path: str | os.PathLike, max_bytes: int, max_values: int = MAX_VALUES) -> Any:
    """The strict JSON document in regular file ``path`` (bounded; see the module doc)."""
    try:
        data = read_bounded(path, max_bytes)
    except TooLarge:
        raise DataFileError(f'{path}: larger than {max_bytes} bytes') from None
    except OSError as exc:
        raise DataFileError(f'{path}: cannot read ({exc.strerror or exc})') from None
    return parse_json(data, str(path), max_values)


def _map_nonfinite(obj: Any, change: Callable[[float], Any]) -> Any:
    """``obj`` with every non-finite float (nested in dicts, lists, tuples) as ``change(x)``."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else change(obj)
    if isinstance(obj, dict):
        return {k: _map_nonfinite(v, change) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_map_nonfinite(v, change) for v in obj]
    return obj


def finite(obj: Any) -> Any:
    """``obj`` with every non-finite float (nested in dicts, lists, tuples) as None."""
    return _map_nonfinite(obj, lambda x: None)


def dumps(obj: Any, **kwargs: Any) -> str:
    """Strict JSON text of ``obj``: non-finite floats written as null."""
    return json.dumps(finite(obj), allow_nan=False, **kwargs)


def tag_nonfinite(obj: Any) -> Any:
    """``obj`` with every non-finite float as ``{TAG: 'inf' | '-inf' | 'nan'}``."""
    return _map_nonfinite(obj, lambda x: {TAG: 'nan' if math.isnan(x) else
                                          ('inf' if x > 0 else '-inf')})


def tagged_dumps(obj: Any, **kwargs: Any) -> str:
    """Strict JSON text of ``obj``, its non-finite floats tagged (see the module doc)."""
    return json.dumps(tag_nonfinite(obj), allow_nan=False, **kwargs)


def write_json(path: str | os.PathLike, obj: Any, **kwargs: Any) -> Path:
    """Write ``obj`` as strict JSON to ``path`` atomically."""
    return write_atomic(path, dumps(obj, **kwargs))
