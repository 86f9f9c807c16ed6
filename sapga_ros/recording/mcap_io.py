"""MCAP recording of ROS 2 topics (SPEC 4, the Recorder): writer, file rotation and reader.

Files follow the MCAP ``ros2`` profile exactly as rosbag2's MCAP storage plugin writes them,
so Foxglove, ``ros2 bag info`` and any MCAP reader open them:

- one Schema per message type, named ``pkg/msg/Type``, encoding ``ros2msg``, holding the
  *complete* message definition: the type's ``.msg`` text, then every dependency (depth
  first, each package's dependencies in sorted order, each type once) as a line of 80 ``=``,
  a line ``MSG: pkg/Type`` and that type's ``.msg`` text.  Definitions come from the
  installed share directories, ``<prefix>/share/<pkg>/msg/<Type>.msg``;
- one Channel per topic (resolved name), message encoding ``cdr``, metadata
  ``offered_qos_profiles`` (rosbag2's YAML, policy names as in Jazzy) and ``topic_type_hash``;
- Message records carry the CDR bytes exactly as received; ``log_time`` is the receive time
  [ns], ``publish_time`` the ``header.stamp`` when the type starts with a ``std_msgs/Header``,
  else the publisher's source timestamp, else the receive time;
- a Metadata record ``sapga`` names the problem, goal delta and topic roles, so that
  ``sapga inspect`` can read the state layout from ``msg_configs/<problem>.yaml``.

Crash safety: data is written in compressed chunks of at most ``chunk_size`` bytes; each
chunk goes to the operating system as soon as it is complete (no user-space buffering), and
``flush()`` closes the chunk in progress.  A recorder killed with SIGKILL leaves a file
without summary and footer that ``read_recording`` (and any streaming MCAP reader) reads up
to the last complete chunk.  Files are opened with exclusive creation: nothing is overwritten.

No rclpy here: the node (``sapga_ros.nodes.recorder_node``) hands over bytes and times.
"""
from __future__ import annotations

import json
import os
import re
import struct
import sys
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from mcap.writer import CompressionType, Writer

from sapga_ros import __version__
from sapga_ros.errors import McapError

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
SEPARATOR = '=' * 80
METADATA_NAME = 'sapga'
MCAP_MAGIC = b'\x89MCAP0\r\n'
DEFAULT_CHUNK_SIZE = 64 * 1024          # [bytes] uncompressed; the most a hard kill can lose
SPLITS = ('run', 'episode')
COMPRESSIONS = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}
EPISODE_END_EVENTS = ('goal', 'step_limit', 'reset')

# Message type of each role in msg_configs/<problem>.yaml `ros.topics` (docs/ros_interface.md)
ROLE_TYPES = {
    'state': 'sensor_msgs/msg/JointState',
    'command': 'std_msgs/msg/Float64',
    'reward': 'std_msgs/msg/Float64',
    'event': 'std_msgs/msg/String',
    'exemplar': 'std_msgs/msg/Int32',
}
DEFAULT_ROLE_TOPICS = {'state': 'joint_states', 'command': 'command', 'reward': 'reward',
                       'event': 'episode_event', 'exemplar': 'exemplar_index'}
PRIMITIVE_TYPES = frozenset((
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'))
_NAME = r'[A-Za-z][A-Za-z0-9_]*'
_TYPE_RE = re.compile(rf'^({_NAME})/(?:({_NAME})/)?({_NAME})$')
_RMW_INFINITE_NS = (1 << 63) - 1        # RMW_DURATION_INFINITE


# --------------------------------------------------------------------------------------------
# Message definitions, type hashes, QoS metadata
# --------------------------------------------------------------------------------------------

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

    return append_recursive(full_type_name(type_name), 50)


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
    except (OSError, ValueError, AttributeError):
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


def _duration_yaml(ns: int) -> str:
    ns = min(max(int(ns), 0), _RMW_INFINITE_NS)
    return f'\n    sec: {ns // 1_000_000_000}\n    nsec: {ns % 1_000_000_000}'


def qos_profiles_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """``offered_qos_profiles`` in rosbag2's YAML (Jazzy, metadata version 9).

    Each profile maps history / reliability / durability / liveliness to a policy name
    ('keep_last', 'reliable', 'volatile', 'automatic', ...), depth to an int, deadline /
    lifespan / liveliness_lease_duration to nanoseconds (absent: infinite).
    """
    items = []
    for p in profiles:
        lines = [f'- history: {p.get("history", "keep_last")}',
                 f'  depth: {int(p.get("depth", 10))}',
                 f'  reliability: {p.get("reliability", "reliable")}',
                 f'  durability: {p.get("durability", "volatile")}',
                 '  deadline:' + _duration_yaml(p.get('deadline', _RMW_INFINITE_NS)),
                 '  lifespan:' + _duration_yaml(p.get('lifespan', _RMW_INFINITE_NS)),
                 f'  liveliness: {p.get("liveliness", "automatic")}',
                 '  liveliness_lease_duration:'
                 + _duration_yaml(p.get('liveliness_lease_duration', _RMW_INFINITE_NS)),
                 '  avoid_ros_namespace_conventions: '
                 + ('true' if p.get('avoid_ros_namespace_conventions') else 'false')]
        items.append('\n'.join(lines))
    return '\n'.join(items)


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ChannelInfo:
    """What a channel record says about one topic."""

    topic: str                  # resolved topic name, e.g. '/joint_states'
    type_name: str              # 'pkg/msg/Type'
    offered_qos_profiles: str   # rosbag2 YAML (qos_profiles_yaml)

    def metadata(self) -> dict[str, str]:
        meta = {'offered_qos_profiles': self.offered_qos_profiles}
        digest = type_hash(self.type_name)
        if digest:
            meta['topic_type_hash'] = digest
        return meta


class _WriteThrough:
    """A file whose every write reaches the operating system at once (survives SIGKILL)."""

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f

    def write(self, data: bytes) -> int:
        n = self._f.write(data)
        self._f.flush()
        return n

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        self._f.flush()


def create_exclusive(directory: str | os.PathLike, stem: str) -> tuple[Path, IO[bytes]]:
    """Open a new ``<stem>.mcap`` (or ``<stem>_<k>.mcap``) for writing; never overwrites."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise McapError(f'{directory}: cannot create output directory ({exc.strerror})') from exc
    for k in range(10000):
        path = directory / (f'{stem}.mcap' if k == 0 else f'{stem}_{k}.mcap')
        try:
            return path, open(path, 'xb')
        except FileExistsError:
            continue
        except OSError as exc:
            raise McapError(f'{path}: cannot create ({exc.strerror})') from exc
    raise McapError(f'{directory}: no free file name for {stem}.mcap')


def check_options(chunk_size: int, compression: str) -> None:
    """McapError unless chunk_size is a positive int and compression is known."""
    if compression not in COMPRESSIONS:
        raise McapError(f'compression {compression!r}: expected one of '
                        f'{", ".join(COMPRESSIONS)}')
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise McapError(f'chunk_size {chunk_size!r}: expected a positive number of bytes')


class McapRecordingWriter:
    """One MCAP file of ROS 2 messages; a context manager that finishes the file on exit."""

    def __init__(self, path: Path, f: IO[bytes], *, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str = 'zstd',
                 metadata: Mapping[str, Mapping[str, str]] | None = None) -> None:
        check_options(chunk_size, compression)
        self.path = Path(path)
        self._file = f
        self._writer = Writer(_WriteThrough(f), chunk_size=chunk_size,
                              compression=COMPRESSIONS[compression])
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self.message_count = 0
        self.unflushed = 0
        self.closed = False
        self._writer.start(profile=PROFILE, library=f'sapga_ros {__version__}')
        for name, data in (metadata or {}).items():
            self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    @classmethod
    def create(cls, directory: str | os.PathLike, stem: str,
               **kwargs: Any) -> McapRecordingWriter:
        """A writer on a new file in ``directory`` named after ``stem``."""
        path, f = create_exclusive(directory, stem)
        try:
            return cls(path, f, **kwargs)
        except BaseException:
            f.close()
            raise

    def _channel_id(self, info: ChannelInfo) -> int:
        channel_id = self._channels.get(info.topic)
        if channel_id is not None:
            return channel_id
        type_name = full_type_name(info.type_name)
        schema_id = self._schemas.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING,
                data=message_definition(type_name).encode('utf-8'))
            self._schemas[type_name] = schema_id
        channel_id = self._writer.register_channel(
            topic=info.topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id,
            metadata=info.metadata())
        self._channels[info.topic] = channel_id
        return channel_id

    def write(self, info: ChannelInfo, data: bytes, log_time: int, publish_time: int) -> None:
        """Append one serialized message, unchanged."""
        if self.closed:
            raise McapError(f'{self.path}: write after close')
        channel_id = self._channel_id(info)
        seq = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = (seq + 1) & 0xFFFFFFFF
        try:
            self._writer.add_message(channel_id=channel_id, log_time=int(log_time),
                                     data=bytes(data), publish_time=int(publish_time),
                                     sequence=seq)
        except OSError as exc:
            raise McapError(f'{self.path}: write failed ({exc.strerror or exc})') from exc
        self.message_count += 1
        self.unflushed += 1

    def flush(self) -> None:
        """Close the chunk in progress and hand everything to the operating system."""
        if not self.closed and self.unflushed:
            try:
                self._writer.flush()
            except OSError as exc:
                raise McapError(f'{self.path}: write failed ({exc.strerror or exc})') from exc
            self.unflushed = 0

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        except OSError as exc:
            raise McapError(f'{self.path}: cannot finish the file ({exc.strerror or exc}); '
                            'it is readable up to its last complete chunk') from exc
        finally:
            self._file.close()

    def __enter__(self) -> McapRecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def utc_stamp() -> str:
    """A file-name-safe UTC time, e.g. '20250101-120000'."""
    return datetime.now(timezone.utc).strftime('%Y%m%d-%H%M%S')


class RecordingSession:
    """Routes messages to MCAP files: one file per run, or one per episode.

    ``split='run'``: one file, opened at the first message; episode events stay inside.
    ``split='episode'``: a new file at every episode ``start`` event (the event is its first
    message); messages before the first start go to ``<stem>_prelude.mcap``.  Either way
    each episode end event (goal / step_limit / reset) flushes the chunk in progress, so a
    finished episode is on disk whatever happens next.
    """

    def __init__(self, output_dir: str | os.PathLike, stem: str, *, split: str = 'run',
                 event_topic: str | None = None, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str = 'zstd', metadata: Mapping[str, str] | None = None) -> None:
        if split not in SPLITS:
            raise McapError(f'split {split!r}: expected one of {", ".join(SPLITS)}')
        check_options(chunk_size, compression)
        self.output_dir = Path(output_dir)
        try:                        # fail now, not at the first message
            self.output_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise McapError(f'{self.output_dir}: cannot create the output directory '
                            f'({exc.strerror})') from exc
        if not os.access(self.output_dir, os.W_OK | os.X_OK):
            raise McapError(f'{self.output_dir}: output directory is not writable')
        self.stem = stem
        self.split = split
        self.event_topic = event_topic
        self._chunk_size = chunk_size
        self._compression = compression
        self._metadata = dict(metadata or {})
        self.writer: McapRecordingWriter | None = None
        self.paths: list[Path] = []
        self.message_count = 0

    def _open(self, episode: Any = None) -> McapRecordingWriter:
        meta = dict(self._metadata, split=self.split, created=datetime.now(timezone.utc)
                    .isoformat(timespec='seconds'))
        stem = self.stem
        if self.split == 'episode':
            if isinstance(episode, int) and not isinstance(episode, bool) and episode >= 0:
                stem = f'{self.stem}_ep{episode:04d}'
                meta['episode'] = str(episode)
            else:
                stem = f'{self.stem}_prelude'
        writer = McapRecordingWriter.create(
            self.output_dir, stem, chunk_size=self._chunk_size, compression=self._compression,
            metadata={METADATA_NAME: meta})
        self.paths.append(writer.path)
        return writer

    def write(self, info: ChannelInfo, data: bytes, log_time: int, publish_time: int) -> None:
        """Record one message; rotate or flush the file on episode events."""
        event = None
        if info.topic == self.event_topic:
            event = parse_event(cdr_string(data))
        if (self.split == 'episode' and event is not None and event.get('event') == 'start'
                and self.writer is not None):
            self.writer.close()
            self.writer = None
        if self.writer is None:
            self.writer = self._open(event.get('episode') if event else None)
        self.writer.write(info, data, log_time, publish_time)
        self.message_count += 1
        if event is not None and event.get('event') in EPISODE_END_EVENTS:
            self.writer.flush()

    def flush(self) -> None:
        if self.writer is not None:
            self.writer.flush()

    def close(self) -> None:
        """Finish the open file, if any (idempotent)."""
        if self.writer is not None:
            writer, self.writer = self.writer, None
            writer.close()


def parse_event(text: str | None) -> dict[str, Any] | None:
    """An episode_event JSON object, or None if it is not one."""
    if text is None:
        return None
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):  # malformed or hostile: not an event
        return None
    return doc if isinstance(doc, dict) else None


# --------------------------------------------------------------------------------------------
# Reading (tolerant of a truncated tail)
# --------------------------------------------------------------------------------------------

@dataclass
class Recording:
    """Everything readable from one MCAP file, in file order."""

    path: str
    size: int = 0
    profile: str = ''
    library: str = ''
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = False          # the footer was read: the writer finished the file
    error: str | None = None        # what stopped the reading early, if anything

    def topic_counts(self) -> dict[int, int]:
        counts = {cid: 0 for cid in self.channels}
        for m in self.messages:
            counts[m.channel_id] = counts.get(m.channel_id, 0) + 1
        return counts


def read_recording(path: str | os.PathLike) -> Recording:
    """Read an MCAP file record by record, keeping everything before any damage.

    A file cut short (hard kill, full disk, partial copy) yields every message of its
    complete chunks with ``complete=False`` and ``error`` saying where it ends.  McapError
    (one line, naming the file) when not even the MCAP header can be read.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        f = open(p, 'rb')
    except FileNotFoundError as exc:
        raise McapError(f'{p}: no such file') from exc
    except OSError as exc:
        raise McapError(f'{p}: cannot read ({exc.strerror})') from exc
    with f:
        head = f.read(len(MCAP_MAGIC))
        if not head:
            raise McapError(f'{p}: empty file, not an MCAP recording')
        if head != MCAP_MAGIC[:len(head)] or len(head) < len(MCAP_MAGIC):
            raise McapError(f'{p}: not an MCAP file (bad magic bytes at the start)')
        f.seek(0)
        rec = Recording(path=str(p), size=size)
        good = len(MCAP_MAGIC)      # end of the last record read intact [bytes]
        reader = StreamReader(f, validate_crcs=True, record_size_limit=max(size, 1))
        try:
            for record in reader.records:
                _take(rec, record)
                good = f.tell()
        except CRCValidationError:
            rec.error = f'{p}: corrupt chunk after byte {good} of {size} (CRC mismatch)'
        except (EndOfFile, InvalidMagic, struct.error) as exc:
            if rec.complete:
                rec.error = f'{p}: damaged closing magic bytes after the footer ({exc})'
            else:
                rec.error = (f'{p}: truncated after byte {good} of {size}: no footer (the '
                             'writer did not finish; was the recorder killed?)')
        except Exception as exc:  # noqa: BLE001 - any parse failure means damaged data
            rec.error = f'{p}: corrupt data after byte {good} of {size} ({exc})'
        if not rec.profile and not rec.library and not any((rec.channels, rec.messages)):
            if rec.error is None:
                rec.error = f'{p}: no MCAP header record'
            raise McapError(rec.error)
    return rec


def _take(rec: Recording, record: object) -> None:
    if isinstance(record, Message):
        if record.channel_id in rec.channels:
            rec.messages.append(record)
    elif isinstance(record, Header):
        rec.profile, rec.library = record.profile, record.library
    elif isinstance(record, Schema):
        rec.schemas.setdefault(record.id, record)
    elif isinstance(record, Channel):
        rec.channels.setdefault(record.id, record)
    elif isinstance(record, Metadata):
        rec.metadata[record.name] = dict(record.metadata)
    elif isinstance(record, Footer):
        rec.complete = True


@dataclass(frozen=True)
class DecodedMessage:
    """One message with its channel and decoded value (attribute access, like rclpy)."""

    topic: str
    type_name: str
    log_time: int
    publish_time: int
    index: int              # position in the file
    value: Any


def decode_messages(rec: Recording, topics: Collection[str] | None = None,
                    ) -> tuple[list[DecodedMessage], dict[str, str]]:
    """Decode the ros2msg/cdr messages (of ``topics``, default all).

    Returns (messages, {topic: what failed}): a broken schema or message spoils its topic only.
    """
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    decoders: dict[int, Any] = {}
    failed: dict[str, str] = {}
    out: list[DecodedMessage] = []
    for i, msg in enumerate(rec.messages):
        channel = rec.channels[msg.channel_id]
        if channel.topic in failed or (topics is not None and channel.topic not in topics):
            continue
        schema = rec.schemas.get(channel.schema_id)
        if msg.channel_id not in decoders:
            try:
                decoders[msg.channel_id] = factory.decoder_for(channel.message_encoding, schema)
            except Exception as exc:  # noqa: BLE001 - a broken schema spoils one topic only
                decoders[msg.channel_id] = None
                failed[channel.topic] = f'schema {schema.name if schema else "?"}: {exc}'
                continue
            if decoders[msg.channel_id] is None:
                failed[channel.topic] = (f'no ros2msg/cdr decoder (message encoding '
                                         f'{channel.message_encoding!r})')
                continue
        try:
            value = decoders[msg.channel_id](msg.data)
        except Exception as exc:  # noqa: BLE001 - one malformed message spoils one topic only
            failed[channel.topic] = f'message {i} does not decode ({exc})'
            continue
        out.append(DecodedMessage(topic=channel.topic, type_name=schema.name if schema else '',
                                  log_time=msg.log_time, publish_time=msg.publish_time,
                                  index=i, value=value))
    return out, failed
