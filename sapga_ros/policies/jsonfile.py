"""Strict JSON for policy files of every kind: bounded reading, no NaN or Infinity, numbers
checked finite, short excerpts of hostile values in one-line ``PolicyFileError`` messages."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from sapga_ros.errors import PolicyFileError
from sapga_ros.io.bounded import TooLarge, read_bounded
from sapga_ros.io.jsonfile import unique_object

MAX_POLICY_BYTES = 64 * 1024 * 1024  # a Q-learning export of 20^4 tiles is ~15 MB
LIMIT = f'{MAX_POLICY_BYTES // (1024 * 1024)} MB limit'


def reject_constant(name: str) -> float:
    """NaN/Infinity literals parse to floats; validation then names the field holding one."""
    return float(name)


def excerpt(value: Any, limit: int = 60) -> str:
    """A short repr of a (possibly huge, hostile) value for an error message."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + '...'


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no inf or NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def check_finite_tree(value: Any, where: str, depth: int = 0) -> None:
    """Every number inside ``value`` (free-form meta) is finite."""
    if depth > 50:
        raise PolicyFileError(f'{where}: nested too deeply')
    if isinstance(value, float) and not math.isfinite(value):
        raise PolicyFileError(f'{where}: not a finite number ({json.dumps(value)})')
    if isinstance(value, dict):
        for k, v in value.items():
            check_finite_tree(v, f'{where}.{k}', depth + 1)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            check_finite_tree(v, f'{where}[{i}]', depth + 1)


def finite(value: Any, where: str) -> float:
    """``value`` as a float if it is a finite JSON number (not a boolean); else the error."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PolicyFileError(f'{where}: expected a number, got {excerpt(value, 40)}')
    try:
        number = float(value)
    except OverflowError:
        raise PolicyFileError(f'{where}: number too large ({excerpt(value, 40)})') from None
    if not math.isfinite(number):
        raise PolicyFileError(f'{where}: not a finite number ({json.dumps(number)})')
    return number


def meta_of(doc: dict, source: str) -> dict:
    """The free-form ``meta`` object of a document ({} if absent), every number finite."""
    meta = doc.get('meta', {})
    if not isinstance(meta, dict):
        raise PolicyFileError(f'{source}: meta: expected an object')
    check_finite_tree(meta, f'{source}: meta')
    return meta


def read_policy_bytes(path: str | os.PathLike) -> bytes:
    """The bytes of a policy file, its size checked before it is read."""
    try:
        return read_bounded(Path(path), MAX_POLICY_BYTES)
    except TooLarge:
        raise PolicyFileError(f'{path}: larger than the {LIMIT}') from None
    except OSError as exc:
        raise PolicyFileError(f'{path}: cannot read ({exc.strerror or exc})') from exc


def read_policy_text(path: str | os.PathLike) -> str:
    """The text of a policy file (its bytes freed once decoded)."""
    return as_text(read_policy_bytes(path), str(path))


def as_text(data: str | bytes, source: str) -> str:
    """Policy file contents as text: at most the size limit, UTF-8."""
    if len(data) > MAX_POLICY_BYTES:
        raise PolicyFileError(f'{source}: {len(data)} bytes, larger than the {LIMIT}')
    if isinstance(data, str):
        return data
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise PolicyFileError(f'{source}: not UTF-8 text (byte {exc.start})') from exc


def parse_json(data: str | bytes, source: str) -> Any:
    """Parse a JSON document refusing NaN/Infinity and oversized input."""
    text = as_text(data, source)
    try:
        return json.loads(text, parse_constant=reject_constant, object_pairs_hook=unique_object)
    except json.JSONDecodeError as exc:
        raise PolicyFileError(f'{source}: malformed JSON ({exc.msg}, line {exc.lineno} '
                              f'column {exc.colno})') from exc
    except RecursionError as exc:
        raise PolicyFileError(f'{source}: JSON nested too deeply') from exc
    except ValueError as exc:
        raise PolicyFileError(f'{source}: {exc}') from exc
