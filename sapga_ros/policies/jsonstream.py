"""A policy document read field by field, in memory a small multiple of its text.

``json.loads`` of a hostile document takes ~24 times its size (an empty list is 56 bytes of
Python for 3 bytes of text), so a policy file is not parsed whole.  ``read_document`` walks
the top-level object itself: every field but the *bulk* ones (``exemplars``, a Q-table's
``q``) is decoded alone, refused when its text is longer than ``MAX_FIELD_CHARS``; a bulk
field (an array or object of many small items) is left in the text and its items are decoded
one at a time by ``Bulk.items()``, each refused when longer than ``MAX_ITEM_CHARS``, so a
reader keeps only what it converts (the exemplar reader: packed arrays of numbers).  The
fields are read in one pass when those a reader needs first come before the bulk field (as
the package writes them); otherwise ``Document.complete()`` reads past it first.  The
document's syntax is checked all through, as ``json.loads`` would, with the same one-line
messages (malformed JSON with line and column, nesting too deep, NaN/Infinity parsed to
floats that the readers then refuse by name).
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any, Iterator

from sapga_ros.errors import PolicyFileError
from sapga_ros.io.jsonfile import unique_object
from sapga_ros.policies.jsonfile import reject_constant

MAX_FIELD_CHARS = 1024 * 1024   # a field other than the bulk (meta, ...), as text
MAX_ITEM_CHARS = 64 * 1024      # an item of a bulk field (an exemplar, a Q-table row)
MAX_FIELDS = 1000               # fields of the top-level object
MAX_ITEMS = 2_000_000           # items of a bulk field (64 MB hold ~1 M short exemplars)
_DECODER = json.JSONDecoder(parse_constant=reject_constant, object_pairs_hook=unique_object)
_WS = re.compile(r'[ \t\n\r]*')
_SPACE = (' ', '\t', '\n', '\r')
_CLOSE = {'{': '}', '[': ']'}


def malformed(text: str, pos: int, msg: str, source: str) -> PolicyFileError:
    """The error of a syntax error at ``pos``, with its line and column."""
    err = json.JSONDecodeError(msg, text, pos)
    return PolicyFileError(f'{source}: malformed JSON ({err.msg}, line {err.lineno} column '
                           f'{err.colno})')


def _ws(text: str, pos: int) -> int:
    return _WS.match(text, pos).end()


def _expect(text: str, pos: int, chars: str, msg: str, source: str) -> str:
    if pos >= len(text) or text[pos] not in chars:
        raise malformed(text, pos, msg, source)
    return text[pos]


def _decode(text: str, pos: int, stop: int, where: str, source: str) -> Any:
    """The value of ``text[pos:stop]``, which must be exactly one JSON value."""
    try:
        value, end = _DECODER.raw_decode(text[pos:stop])
    except json.JSONDecodeError as exc:
        raise malformed(text, pos + exc.pos, exc.msg, source) from None
    except RecursionError:
        raise PolicyFileError(f'{where}: JSON nested too deeply') from None
    except ValueError as exc:     # an integer of more digits than Python converts
        raise PolicyFileError(f'{where}: {exc}'[:300]) from None
    if end != stop - pos:
        raise malformed(text, pos + end, 'Expecting \',\' delimiter', source)
    return value


def value_at(text: str, pos: int, limit: int, where: str, source: str) -> tuple[Any, int]:
    """(value, end) of the JSON value at ``pos`` (no whitespace before it), its text at most
    ``limit`` characters; only that much is ever decoded."""
    if pos >= len(text):
        raise malformed(text, pos, 'Expecting value', source)
    close = _CLOSE.get(text[pos])
    if close is None:                              # a scalar: its own size bounds it
        try:
            value, end = _DECODER.raw_decode(text, pos)
        except json.JSONDecodeError as exc:
            raise malformed(text, exc.pos, exc.msg, source) from None
        except ValueError as exc:
            raise PolicyFileError(f'{where}: {exc}'[:300]) from None
        if isinstance(value, str) and end - pos > limit:
            raise PolicyFileError(f'{where}: longer than {limit} characters')
        return value, end
    if limit <= MAX_ITEM_CHARS:
        value, end = _flat(text, pos)
        if end >= 0:
            return value, end
    stop = min(len(text), pos + limit)             # nested or broken: decode what may be it
    try:
        value, end = _DECODER.raw_decode(text[pos:stop])
    except json.JSONDecodeError as exc:
        if stop < len(text) and (exc.pos >= stop - pos - 1 or     # cut short by the bound
                                 exc.msg.startswith('Unterminated string')):
            raise PolicyFileError(f'{where}: longer than {limit} characters') from None
        raise malformed(text, pos + exc.pos, exc.msg, source) from None
    except RecursionError:
        raise PolicyFileError(f'{where}: JSON nested too deeply') from None
    except ValueError as exc:
        raise PolicyFileError(f'{where}: {exc}'[:300]) from None
    return value, pos + end


@dataclass
class Bulk:
    """A bulk field left in the text: an array or object (``kind``), or any other value
    (``value``), its items decoded one at a time by ``items()``."""

    text: str
    start: int
    where: str
    source: str
    kind: str = 'other'                  # 'array', 'object' or 'other'
    value: Any = None                    # the decoded value of kind 'other'
    end: int = field(default=0)

    def items(self) -> Iterator[tuple[Any, Any]]:
        """(index, item) of an array or (key, item) of an object, in order (at most
        ``MAX_ITEMS``; an object's key given twice is refused)."""
        text, source = self.text, self.source
        array = self.kind == 'array'
        closing = ']' if array else '}'
        pos = _ws(text, self.start + 1)
        if text.startswith(closing, pos):
            self.end = pos + 1
            return
        self.end = 0
        index = 0
        seen: set[str] = set()
        while True:
            if array:
                key = index
            else:
                key, pos = _key(text, pos, source)
                if key in seen:               # as ``unique_object`` for a whole document
                    raise PolicyFileError(f'{self.where}: key {key[:60]!r} given twice')
                seen.add(key)
            item, pos = _flat(text, pos)           # the common case, fast
            if pos < 0:
                item, pos = value_at(text, -pos, MAX_ITEM_CHARS, f'{self.where}[{key}]',
                                     source)
            yield key, item
            index += 1
            if index > MAX_ITEMS:
                raise PolicyFileError(f'{self.where}: more than {MAX_ITEMS} items')
            if text[pos:pos + 1] not in (',', closing):
                pos = _ws(text, pos)
            sep = _expect(text, pos, ',' + closing, 'Expecting \',\' delimiter', source)
            pos += 1
            if text[pos:pos + 1] in _SPACE:
                pos = _ws(text, pos)
            if sep != ',':
                self.end = pos
                return


def _flat(text: str, pos: int) -> tuple[Any, int]:
    """(item, end) of a flat object or array at ``pos`` (ending at its first closing
    bracket, at most ``MAX_ITEM_CHARS`` long); (None, -pos) if it is not one."""
    close = _CLOSE.get(text[pos:pos + 1])
    if close is not None:
        first = text.find(close, pos, pos + MAX_ITEM_CHARS)
        if first >= 0:
            try:
                value, end = _DECODER.raw_decode(text[pos:first + 1])
                if end == first + 1 - pos:
                    return value, first + 1
            except (ValueError, RecursionError):
                pass
    return None, -pos


def _key(text: str, pos: int, source: str) -> tuple[str, int]:
    """(key, position of its value) of the ``"key": `` at ``pos``."""
    _expect(text, pos, '"', 'Expecting property name enclosed in double quotes', source)
    try:
        key, pos = json.decoder.scanstring(text, pos + 1)
    except json.JSONDecodeError as exc:
        raise malformed(text, exc.pos, exc.msg, source) from None
    pos = _ws(text, pos)
    _expect(text, pos, ':', 'Expecting \':\' delimiter', source)
    return key, _ws(text, pos + 1)


class Document(dict):
    """A policy document's top-level fields (field -> value; a bulk field -> ``Bulk``), read
    up to the first bulk field; ``complete()`` reads on past it, to the end."""

    def __init__(self, text: str, source: str, bulk: frozenset[str] | set[str]) -> None:
        super().__init__()
        self.text, self.source, self.bulk = text, source, bulk
        self._pending: Bulk | None = None

    def complete(self) -> Document:
        """Read the fields after the bulk field (its items are skipped, checked, unless
        they were read already) and the rest of the text."""
        while self._pending is not None:
            part, self._pending = self._pending, None
            if not part.end:
                for _ in part.items():
                    pass
            self._fields(part.end, after_value=True)
        return self

    def _fields(self, pos: int, after_value: bool) -> None:
        """Read fields from ``pos`` until a bulk field or the end of the object."""
        text, source = self.text, self.source
        while True:
            if after_value:
                pos = _ws(text, pos)
                sep = _expect(text, pos, ',}', 'Expecting \',\' delimiter', source)
                pos = _ws(text, pos + 1)
                if sep == '}':
                    break
            key, pos = _key(text, pos, source)
            where = f'{source}: {key[:60]}'
            if key in self:
                raise PolicyFileError(f'{where}: given twice')
            if key in self.bulk and text.startswith(('[', '{'), pos):
                self[key] = self._pending = Bulk(text, pos, where, source,
                                                 'array' if text[pos] == '[' else 'object')
                return                     # read on by complete(), once its items are read
            self[key], pos = value_at(text, pos, MAX_FIELD_CHARS, where, source)
            if len(self) > MAX_FIELDS:
                raise PolicyFileError(f'{source}: more than {MAX_FIELDS} fields')
            after_value = True
        pos = _ws(text, pos)
        if pos != len(text):
            raise malformed(text, pos, 'Extra data', source)


def read_document(text: str, source: str, bulk: frozenset[str] | set[str] = frozenset()
                  ) -> Document:
    """The top-level object of ``text`` as a ``Document`` (see the module), read up to the
    first of the ``bulk`` fields that holds an array or object."""
    pos = _ws(text, 0)
    if not text.startswith('{', pos):
        if pos < len(text) and len(text) <= MAX_FIELD_CHARS:
            _decode(text, pos, len(text.rstrip(' \t\n\r')), f'{source}: document', source)
        elif pos >= len(text):
            raise malformed(text, pos, 'Expecting value', source)
        raise PolicyFileError(f'{source}: expected a JSON object at the top level')
    doc = Document(text, source, bulk)
    pos = _ws(text, pos + 1)
    if text.startswith('}', pos):
        doc._fields(pos, after_value=True)
    else:
        doc._fields(pos, after_value=False)
    return doc


def complete(doc: dict) -> dict:
    """``doc`` with every field read (a parsed dict is complete already)."""
    return doc.complete() if isinstance(doc, Document) else doc


def require(doc: Any, names: tuple[str, ...], source: str) -> dict:
    """``doc``, an object with every field of ``names`` (read past its bulk field if some
    come after it); else the error naming what is missing."""
    if not isinstance(doc, dict):
        raise PolicyFileError(f'{source}: expected a JSON object at the top level')
    if any(name not in doc for name in names):
        complete(doc)
    for name in names:
        if name not in doc:
            raise PolicyFileError(f'{source}: missing field {name!r}')
    return doc
