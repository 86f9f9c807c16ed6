"""Message types of a recording: names, complete ``ros2msg`` definitions, type hashes, times.

No rclpy here: definitions come from the installed share directories
(``<prefix>/share/<pkg>/msg/<Type>.msg`` and the ``.json`` type descriptions beside them),
the same files rosbag2 reads through ``rosidl``.

- ``message_definition``: the type's ``.msg`` text, then every dependency (depth first,
  each package's dependencies in sorted order, each type once) as a line of 80 ``=``, a line
  ``MSG: pkg/Type`` and that type's ``.msg`` text: rosbag2's concatenated ``ros2msg`` form;
- ``type_hash``: the RIHS01 hash (``topic_type_hash`` / ``type_description_hash``);
- ``publish_time_ns``: MCAP ``publish_time`` = ``header.stamp`` when the type starts with a
  ``std_msgs/Header``, else the publisher's source timestamp, else the receive time.
"""
from __future__ import annotations

import json
import os
import re
import struct
import sys
from functools import lru_cache
from pathlib import Path

from sapga_ros.errors import McapError

SEPARATOR = '=' * 80
PRIMITIVE_TYPES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'))
_NAME = r'[A-Za-z][A-Za-z0-9_]*'
_TYPE_RE = re.compile(rf'^({_NAME})/(?:({_NAME})/)?({_NAME})$')
MAX_DEFINITION_DEPTH = 50


def split_type(type_name: str) -> tuple[str, str, str]:
    """('pkg', 'msg', 'Type') of 'pkg/msg/Type' or 'pkg/Type'; McapError if malformed."""
    m = _TYPE_RE.match(type_name)
    if not m:
        raise McapError(f'message type {type_name!r}: expected pkg/msg/Type')
    pkg, ns, name = m.groups()
    return pkg, ns or 'msg', name


def full_type_name(type_name: str) -> str:
    """The canonical 'pkg/msg/Type' spelling (schema names, as rosbag2 writes them)."""
    return '/'.join(split_type(type_name))


def share_dirs() -> list[Path]:
    """Share directories searched for .msg files: $AMENT_PREFIX_PATH, then this prefix."""
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    seen: list[Path] = []
    for prefix in prefixes:
        share = Path(prefix) / 'share'
        if share not in seen:
            seen.append(share)
    return seen


def _interface_file(type_name: str, suffix: str) -> Path | None:
    pkg, ns, name = split_type(type_name)
    for share in share_dirs():
        path = share / pkg / ns / f'{name}{suffix}'
        if path.is_file():
            return path
    return None


@lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    path = _interface_file(type_name, '.msg')
    if path is None:
        where = ', '.join(str(s) for s in share_dirs())
        raise McapError(f'message type {type_name!r}: no .msg definition found under {where}')
    try:
        return path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as exc:
        raise McapError(f'{path}: cannot read the message definition ({exc})') from exc


def msg_dependencies(text: str, package: str) -> list[str]:
    """Non-primitive field types of a .msg text as 'pkg/Type', sorted, each once."""
    deps = set()
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        token = line.split()[0]
        base = re.sub(r'\[[^\]]*\]$', '', token).split('<=', 1)[0]
        if base in PRIMITIVE_TYPES or '=' in base:
            continue
        if '/' not in base:
            base = f'{package}/{base}'
        pkg, _, name = split_type(base)
        deps.add(f'{pkg}/{name}')
    return sorted(deps)


@lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """The complete ``ros2msg`` definition of a type, in rosbag2's concatenated form."""
    seen: set[str] = set()

    def append_recursive(name: str, depth: int) -> str:
        if depth <= 0:
            raise McapError(f'message type {type_name!r}: definition nests too deeply')
        text = _msg_text(name)
        result = text
        for dep in msg_dependencies(text, split_type(name)[0]):
            if dep not in seen:
                seen.add(dep)
                result += f'\n{SEPARATOR}\nMSG: {dep}\n' + append_recursive(dep, depth - 1)
        return result

    return append_recursive(full_type_name(type_name), MAX_DEFINITION_DEPTH)


@lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """The type's RIHS01 hash from its installed type description (.json), or ''."""
    path = _interface_file(type_name, '.json')
    if path is None:
        return ''
    try:
        doc = json.loads(path.read_text(encoding='utf-8'))
        for entry in doc.get('type_hashes', []):
            if entry.get('type_name') == full_type_name(type_name):
                return str(entry.get('hash_string', ''))
    except (OSError, ValueError, AttributeError, RecursionError):
        pass
    return ''


@lru_cache(maxsize=None)
def has_header(type_name: str) -> bool:
    """Whether the type's first field is a std_msgs/Header (its stamp is the publish time)."""
    for line in _msg_text(full_type_name(type_name)).splitlines():
        line = line.split('#', 1)[0].strip()
        if line:
            return line.split()[0] in ('std_msgs/Header', 'std_msgs/msg/Header')
    return False


def header_stamp_ns(data: bytes) -> int | None:
    """header.stamp [ns] of a CDR message whose first field is a std_msgs/Header."""
    if len(data) < 12:
        return None
    order = '<' if data[1] & 1 else '>'      # encapsulation kind: odd = little endian
    sec, nanosec = struct.unpack_from(order + 'iI', data, 4)
    ns = sec * 1_000_000_000 + nanosec
    return ns if ns >= 0 else None


def cdr_string(data: bytes) -> str | None:
    """The value of a CDR std_msgs/String (one string field), or None if malformed."""
    if len(data) < 8:
        return None
    order = '<' if data[1] & 1 else '>'
    (length,) = struct.unpack_from(order + 'I', data, 4)
    if length < 1 or 8 + length > len(data):
        return None
    try:
        return data[8:8 + length - 1].decode('utf-8')
    except UnicodeDecodeError:
        return None


def first_marker(data: bytes) -> tuple[str, int] | None:
    """(ns, header.stamp [ns]) of the first marker of a CDR visualization_msgs/MarkerArray,
    or None if it has none or is malformed."""
    if len(data) < 24:
        return None
    order = '<' if data[1] & 1 else '>'
    count, sec, nanosec, frame_len = struct.unpack_from(order + 'IiII', data, 4)
    at = 20 + frame_len                         # after header.frame_id
    at += -(at - 4) % 4                         # CDR alignment of ns's length (from byte 4)
    if count < 1 or sec < 0 or at + 4 > len(data):
        return None
    (ns_len,) = struct.unpack_from(order + 'I', data, at)
    if ns_len < 1 or at + 4 + ns_len > len(data):
        return None
    try:
        ns = data[at + 4:at + 3 + ns_len].decode('utf-8')
    except UnicodeDecodeError:
        return None
    return ns, sec * 1_000_000_000 + nanosec


def publish_time_ns(type_name: str, data: bytes, source_ns: int | None, receive_ns: int) -> int:
    """MCAP publish_time: header.stamp if the type has one, else source time, else receive."""
    try:
        if has_header(type_name):
            stamp = header_stamp_ns(data)
            if stamp is not None:
                return stamp
    except McapError:
        pass
    return source_ns if source_ns else receive_ns
