"""Reading a recording: a rosbag2 bag directory or one MCAP file, tolerant and bounded.

``read_recording(path)`` takes a bag directory (its ``metadata.yaml`` lists the storage files;
without one, as after a killed recorder, the ``*.mcap`` files in split order) or a single
``.mcap`` file, and returns every message it can read, in file order, with what stopped it:
a file cut short (hard kill, full disk, partial copy) yields every message of its complete
chunks with ``complete=False`` and an ``error`` naming the file and the byte where it ends;
a chunk whose contents are damaged (its record whole) is skipped, and the reading goes on.
Decompression is bounded (``chunks.py``); only regular files are opened.  McapError (one
line) when nothing at all can be read.

``read_recording(path, sink)`` streams instead: each message goes to ``sink`` as it is read
and none is kept, so a recording of any number of messages is read in the memory of one
chunk (``MAX_CHUNK_BYTES``, the limit the writer keeps to): whatever the writer wrote is
read, however well it compresses, and a bomb costs no more memory than one chunk.  Reading
that keeps the messages stays within ``Budget`` (a multiple of the file size): a bag beyond
it is read by streaming.  ``Decoder`` decodes them one at a time (``decode_messages`` a
whole list), within ``max_bytes`` a message if given.  The module stays over 300 lines so that
reading, streaming and decoding share one definition of a message.
"""
from __future__ import annotations

import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any, BinaryIO, Callable, Collection, NamedTuple

from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.records import (AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Header,
                          Message, MessageIndex, Metadata, MetadataIndex, Schema, Statistics,
                          SummaryOffset)
from mcap.stream_reader import StreamReader

from sapga_ros.errors import McapError
from sapga_ros.io.bounded import open_regular
from sapga_ros.recording.chunks import Budget, BudgetExceeded, chunk_records
from sapga_ros.recording.metadata import METADATA_FILE, read_bag_metadata
from sapga_ros.recording.schemas import full_type_name
from sapga_ros.recording.writer import SAPGA_RECORD

MCAP_MAGIC = b'\x89MCAP0\r\n'
_ELSEWHERE = (ChunkIndex, AttachmentIndex, Statistics, MetadataIndex, SummaryOffset, Footer)
_SPLIT_INDEX = re.compile(r'_(\d+)\.mcap$')


class RecordedMessage(NamedTuple):
    topic: str
    log_time: int           # [ns] receive time
    publish_time: int       # [ns]
    data: bytes             # CDR, as received


@dataclass(frozen=True)
class TopicRecord:
    """A recorded topic: its channel and schema."""

    name: str
    type: str               # schema name, e.g. 'sensor_msgs/msg/JointState'
    message_encoding: str
    schema: Schema | None
    metadata: dict[str, str]


@dataclass
class FileRecording:
    """What was read of one storage file."""

    path: str
    size: int = 0
    profile: str = ''
    library: str = ''
    complete: bool = False          # the footer was read: the writer finished the file
    error: str | None = None        # what stopped the reading early, if anything
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    message_count: int = 0


@dataclass
class Recording:
    """Everything readable from a bag directory or a file, in file order."""

    path: str
    files: list[FileRecording] = field(default_factory=list)
    topics: dict[str, TopicRecord] = field(default_factory=dict)
    messages: list[RecordedMessage] = field(default_factory=list)
    bag_metadata: dict[str, Any] | None = None      # metadata.yaml, for a bag directory
    problems: list[str] = field(default_factory=list)   # bag-level: missing files, no yaml

    @property
    def is_bag(self) -> bool:
        return Path(self.path).is_dir()

    @property
    def size(self) -> int:
        return sum(f.size for f in self.files)

    @property
    def complete(self) -> bool:
        """Every file finished (footer) and read without damage, the bag's metadata sound."""
        return not self.problems and all(f.complete and not f.error for f in self.files)

    @property
    def error(self) -> str | None:
        """The first thing that went wrong, or None."""
        return next(iter(self.problems + [f.error for f in self.files if f.error]), None)

    @property
    def metadata(self) -> dict[str, str]:
        """The ``sapga`` entries: metadata.yaml's custom_data, else the files' records."""
        custom = (self.bag_metadata or {}).get('custom_data')
        if isinstance(custom, dict) and custom:
            return {str(k): str(v) for k, v in custom.items()}
        merged: dict[str, str] = {}
        for f in self.files:
            merged.update(f.metadata.get(SAPGA_RECORD, {}))
        return merged

    def topic_counts(self) -> dict[str, int]:
        counts = {name: 0 for name in self.topics}
        for m in self.messages:
            counts[m.topic] += 1
        return counts


def open_storage(path: Path) -> BinaryIO:
    """A storage file opened for reading if it is a regular file; McapError (one line)."""
    try:
        return open_regular(path)
    except FileNotFoundError as exc:
        raise McapError(f'{path}: no such file') from exc
    except OSError as exc:
        raise McapError(f'{path}: cannot read ({exc.strerror or exc})') from exc


Sink = Callable[[RecordedMessage], None]


def read_file(path: Path, rec: Recording, budget: Budget, sink: Sink | None = None
              ) -> FileRecording:
    """Append the topics and messages of one MCAP file to ``rec`` (the messages to ``sink``
    instead, if given)."""
    take = sink or rec.messages.append
    with open_storage(path) as f:
        size = os.fstat(f.fileno()).st_size
        head = f.read(len(MCAP_MAGIC))
        if not head:
            raise McapError(f'{path}: empty file, not an MCAP recording')
        if head != MCAP_MAGIC:
            raise McapError(f'{path}: not an MCAP file (bad magic bytes at the start)')
        f.seek(0)
        out = FileRecording(path=str(path), size=size)
        channels: dict[int, str] = {}      # channel id -> topic, this file's
        schemas: dict[int, Schema] = {}
        good = len(MCAP_MAGIC)              # end of the last record read intact [bytes]
        reader = StreamReader(f, emit_chunks=True, record_size_limit=max(size, 1))
        after_chunk, data = False, True     # the last record a chunk; before DataEnd
        try:
            for record in reader.records:
                if data and (isinstance(record, _ELSEWHERE) or (
                        isinstance(record, MessageIndex) and not (
                            after_chunk and f.tell() - good == 15 + 16 * len(record.records)))):
                    out.error = out.error or (
                        f'{path}: byte {good}: {type(record).__name__} record where a chunk '
                        'was expected (a damaged record opcode?); that chunk\'s messages are '
                        'lost here (`sapga bag reindex` recovers or counts them)')
                after_chunk = isinstance(record, (Chunk, MessageIndex))
                data = data and not isinstance(record, DataEnd)
                try:
                    records = (chunk_records(record, budget, f'{path}: byte {good}')
                               if isinstance(record, Chunk) else [record])
                except BudgetExceeded as exc:     # keep what fits, then stop
                    for r in exc.records:
                        _take(r, rec, out, channels, schemas, take)
                    raise
                except McapError as exc:    # this chunk only: the next record is whole
                    out.error = out.error or (f'{exc}; its messages are skipped (`sapga bag '
                                              'reindex` keeps every other chunk)')
                    records = []
                for r in records:
                    _take(r, rec, out, channels, schemas, take)
                good = f.tell()
        except (EndOfFile, InvalidMagic, struct.error) as exc:
            if out.complete:
                end = f'{path}: damaged closing magic bytes after the footer ({exc})'
            else:
                end = (f'{path}: truncated after byte {good} of {size}: no footer (the '
                       'writer did not finish; was the recorder killed?)')
            out.error = f'{out.error}; {end}' if out.error else end
        except McapError as exc:
            out.error = f'{out.error}; {exc}' if out.error else str(exc)
        except Exception as exc:  # noqa: BLE001 - any parse failure means damaged data
            end = f'{path}: corrupt data after byte {good} of {size} ({exc})'[:300]
            out.error = f'{out.error}; {end}' if out.error else end
        if not out.profile and not out.library and not channels and not out.message_count:
            raise McapError(out.error or f'{path}: no MCAP header record')
    return out


def _take(r: object, rec: Recording, out: FileRecording, channels: dict[int, str],
          schemas: dict[int, Schema], take: Sink) -> None:
    if isinstance(r, Message):
        topic = channels.get(r.channel_id)
        if topic is not None:
            take(RecordedMessage(topic, r.log_time, r.publish_time, r.data))
            out.message_count += 1
    elif isinstance(r, Schema):
        schemas.setdefault(r.id, r)
    elif isinstance(r, Channel) and r.id not in channels:
        schema = schemas.get(r.schema_id)
        known = rec.topics.get(r.topic)
        if known is None:
            rec.topics[r.topic] = TopicRecord(r.topic, schema.name if schema else '',
                                              r.message_encoding, schema, dict(r.metadata))
        elif known.type != (schema.name if schema else ''):
            out.error = out.error or (f'{out.path}: topic {r.topic} changes type; its '
                                      'messages here are skipped')
            return
        channels[r.id] = r.topic
    elif isinstance(r, Header):
        out.profile, out.library = r.profile, r.library
    elif isinstance(r, Metadata):
        out.metadata[r.name] = dict(r.metadata)
    elif isinstance(r, Footer):
        out.complete = True


def split_index(path: Path) -> int:
    """The split number of ``<bag>_<i>.mcap`` (files without one sort first)."""
    m = _SPLIT_INDEX.search(path.name)
    return int(m.group(1)) if m else -1


def bag_files(bag: Path, rec: Recording) -> list[Path]:
    """The storage files of a bag: metadata.yaml's list, else the ``*.mcap`` files."""
    try:
        meta = read_bag_metadata(bag)
    except McapError as exc:
        rec.problems.append(f'{exc}: reading the .mcap files of the directory (a killed '
                            f'recording? `sapga bag reindex {bag}` completes it)'
                            if not (bag / METADATA_FILE).exists() else str(exc))
        files = sorted((p for p in bag.glob('*.mcap') if p.is_file()),
                       key=lambda p: (split_index(p), p.name))
        if not files:
            raise McapError(f'{bag}: neither {METADATA_FILE} nor .mcap files: not a bag')
        return files
    rec.bag_metadata = meta
    custom = meta.get('custom_data')
    if isinstance(custom, dict) and custom.get('incomplete'):
        rec.problems.append(f'{bag}: the recorder marked the bag incomplete '
                            f'({str(custom["incomplete"])[:300]})')
    return [bag / PurePath(name).name for name in meta['relative_file_paths']]


def read_recording(path: str | os.PathLike, sink: Sink | None = None) -> Recording:
    """Read a bag directory or an MCAP file, keeping everything before any damage (the
    messages go to ``sink`` instead, if given: see the module doc)."""
    p = Path(path)
    rec = Recording(path=str(p))
    files = bag_files(p, rec) if p.is_dir() else [p]
    budget = (Budget(sum(f.stat().st_size for f in files if f.is_file())) if sink is None
              else Budget.streaming())
    for file in files:
        try:
            rec.files.append(read_file(file, rec, budget, sink))
        except McapError as exc:
            if not p.is_dir():
                raise
            rec.problems.append(str(exc))
    if p.is_dir() and not rec.files:
        raise McapError(rec.problems[-1] if rec.problems else f'{p}: no readable file')
    return rec


@dataclass(frozen=True)
class DecodedMessage:
    """One message with its topic and decoded value (attribute access, like rclpy)."""

    topic: str
    type_name: str
    log_time: int
    publish_time: int
    index: int              # position in the recording
    value: Any


def schema_type(topic: TopicRecord) -> str:
    """The topic's message type as 'pkg/msg/Type' ('' without a schema)."""
    try:
        return full_type_name(topic.type)
    except McapError:
        return topic.type


class Decoder:
    """Decodes the ros2msg/cdr messages of ``topics`` (default all) one at a time; a broken
    schema or message spoils its topic only (``failed``: {topic: what failed})."""

    def __init__(self, known: dict[str, TopicRecord], topics: Collection[str] | None = None,
                 max_bytes: int | None = None) -> None:
        from mcap_ros2.decoder import DecoderFactory

        self.known, self.topics = known, topics
        self.max_bytes = max_bytes      # a larger message spoils its topic, undecoded
        self.factory = DecoderFactory()
        self.decoders: dict[str, Any] = {}
        self.failed: dict[str, str] = {}

    def __call__(self, i: int, msg: RecordedMessage) -> DecodedMessage | None:
        """Message ``i`` decoded, or None (another topic, or its topic failed)."""
        if msg.topic in self.failed or (self.topics is not None and msg.topic not in self.topics):
            return None
        info = self.known[msg.topic]
        if msg.topic not in self.decoders:
            try:
                self.decoders[msg.topic] = self.factory.decoder_for(info.message_encoding,
                                                                    info.schema)
            except Exception as exc:  # noqa: BLE001 - a broken schema spoils one topic only
                self.failed[msg.topic] = f'schema {info.type}: {exc}'[:200]
                return None
            if self.decoders[msg.topic] is None:
                self.failed[msg.topic] = (f'no ros2msg/cdr decoder (message encoding '
                                          f'{info.message_encoding!r})')
                return None
        if self.max_bytes is not None and len(msg.data) > self.max_bytes:
            self.failed[msg.topic] = (f'message {i} holds {len(msg.data)} bytes, more than '
                                      f'the {self.max_bytes} decoded of one message')
            return None
        try:
            value = self.decoders[msg.topic](msg.data)
        except Exception as exc:  # noqa: BLE001 - one malformed message spoils one topic only
            self.failed[msg.topic] = f'message {i} does not decode ({exc})'[:200]
            return None
        return DecodedMessage(msg.topic, info.type, msg.log_time, msg.publish_time, i, value)


def decode_messages(rec: Recording, topics: Collection[str] | None = None,
                    ) -> tuple[list[DecodedMessage], dict[str, str]]:
    """Decode the ros2msg/cdr messages (of ``topics``, default all).

    Returns (messages, {topic: what failed}): a broken schema or message spoils its topic only.
    """
    decode = Decoder(rec.topics, topics)
    out = [d for i, msg in enumerate(rec.messages) if (d := decode(i, msg)) is not None]
    return out, decode.failed
