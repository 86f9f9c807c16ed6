"""``sapga bag reindex BAG``: make a killed recording complete, as ``ros2 bag reindex`` does.

A recorder killed with SIGKILL leaves storage files without summary and footer (only stream
readers read them) and no ``metadata.yaml``.  ``reindex``:

1. rewrites each incomplete storage file with the ``mcap`` library's ``Writer``: every
   record read before the damage (header, schemas, channels, messages with their times,
   metadata records), in order, then chunk indexes, summary and footer, so random-access
   readers (``mcap``'s ``make_reader``, rosbag2, rosbags) open it; the new file replaces the
   old one atomically only after it reads back with the same messages;
2. writes ``metadata.yaml`` from what the files hold (topics, QoS, counts, times), keeping
   the ``custom_data`` of the last ``rosbag2`` record.

A single ``.mcap`` file is repaired in place; a complete file is left as it is.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import yaml
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from sapga_ros.errors import McapError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.bounded import load_yaml, open_regular
from sapga_ros.recording.chunks import Budget, chunk_records
from sapga_ros.recording.metadata import (METADATA_FILE, RECORD_NAME, BagMetadata, FileInfo,
                                          TopicInfo)
from sapga_ros.recording.reader import FileRecording, Recording, read_file, bag_files

_COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                '': CompressionType.NONE}


@dataclass
class ReindexResult:
    """What ``reindex`` did."""

    path: Path
    repaired: list[Path] = field(default_factory=list)      # files rewritten
    messages: int = 0
    metadata_written: bool = False


def _raw_records(path: Path) -> Iterator[Any]:
    """Every record of an MCAP file up to the first damage, chunks unopened."""
    with open_regular(path) as f:
        reader = StreamReader(f, emit_chunks=True,
                              record_size_limit=max(os.fstat(f.fileno()).st_size, 1))
        try:
            yield from reader.records
        except Exception:  # noqa: BLE001 - the damaged tail: stop where it starts
            return


def _records(path: Path, budget: Budget) -> Iterator[Any]:
    """Every record of an MCAP file up to the first damage, chunks opened (bounded)."""
    try:
        for record in _raw_records(path):
            if isinstance(record, Chunk):
                yield from chunk_records(record, budget, str(path))
            else:
                yield record
    except McapError:       # a chunk that does not open: the damage starts there
        return


def _first_compression(path: Path) -> str:
    """The compression of the file's first chunk ('zstd' if it has none)."""
    return next((r.compression for r in _raw_records(path) if isinstance(r, Chunk)), 'zstd')


def _rewrite(path: Path, out_f: Any, budget: Budget) -> int:
    """Write the readable records of ``path`` as a complete MCAP file; the message count."""
    records = _records(path, budget)
    header = next(records, None)
    if not isinstance(header, Header):
        raise McapError(f'{path}: no MCAP header record: nothing to repair')
    writer = Writer(out_f, compression=_COMPRESSION.get(_first_compression(path),
                                                        CompressionType.ZSTD))
    writer.start(profile=header.profile, library=header.library)
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    count = sum(_copy(writer, r, schemas, channels) for r in records)
    writer.finish()
    return count


def _copy(writer: Writer, r: Any, schemas: dict[int, int], channels: dict[int, int]) -> int:
    if isinstance(r, Schema) and r.id not in schemas:
        schemas[r.id] = writer.register_schema(r.name, r.encoding, r.data)
    elif isinstance(r, Channel) and r.id not in channels:
        channels[r.id] = writer.register_channel(r.topic, r.message_encoding,
                                                 schemas.get(r.schema_id, 0), dict(r.metadata))
    elif isinstance(r, Message) and r.channel_id in channels:
        writer.add_message(channels[r.channel_id], r.log_time, r.data, r.publish_time,
                           r.sequence)
        return 1
    elif isinstance(r, Metadata):
        writer.add_metadata(r.name, dict(r.metadata))
    return 0


def repair_file(path: str | os.PathLike) -> int:
    """Rewrite an incomplete MCAP file complete, in place; the messages it holds."""
    path = Path(path)
    budget = Budget(path.stat().st_size)
    tmp = path.with_name(f'.{path.name}.reindex')
    try:
        with open(tmp, 'wb') as out_f:
            count = _rewrite(path, out_f, budget)
            out_f.flush()
            os.fsync(out_f.fileno())
        with open(tmp, 'rb') as f:      # read back at random access before replacing
            back = sum(1 for _ in make_reader(f).iter_messages(log_time_order=False))
        if back != count:
            raise McapError(f'{path}: the rewritten file reads back {back} of {count} '
                            'messages; left unchanged')
        os.replace(tmp, path)
    except OSError as exc:
        raise McapError(f'{path}: cannot rewrite ({exc.strerror or exc})') from exc
    finally:
        tmp.unlink(missing_ok=True)
    return count


def _topic(info: Any) -> TopicInfo:
    try:
        qos = load_yaml(info.metadata.get('offered_qos_profiles', '') or '[]')
    except yaml.YAMLError:
        qos = []
    return TopicInfo(info.name, info.type, qos if isinstance(qos, list) else [],
                     info.metadata.get('topic_type_hash', ''), info.message_encoding)


def _custom_data(files: list[FileRecording]) -> dict[str, str]:
    for f in reversed(files):
        text = f.metadata.get(RECORD_NAME, {}).get('serialized_metadata', '')
        try:
            custom = (load_yaml(text) or {}).get('custom_data')
        except (yaml.YAMLError, AttributeError):
            custom = None
        if isinstance(custom, dict):
            return {str(k): str(v) for k, v in custom.items()}
    return {}


def reindex(path: str | os.PathLike) -> ReindexResult:
    """Repair the incomplete files of a bag directory (or one file) and write metadata.yaml."""
    path = Path(path)
    result = ReindexResult(path)
    probe = Recording(path=str(path))
    files = bag_files(path, probe) if path.is_dir() else [path]
    for file in files:
        rec = Recording(path=str(file))
        if not read_file(file, rec, Budget(file.stat().st_size)).complete:
            result.messages += repair_file(file)
            result.repaired.append(file)
    if not path.is_dir():
        return result
    meta, read = BagMetadata(), []
    for file in files:
        rec = Recording(path=str(file))
        read.append(read_file(file, rec, Budget(file.stat().st_size)))
        meta.files.append(FileInfo(file.name))
        for name, info in rec.topics.items():
            meta.topics.setdefault(name, _topic(info))
        for m in rec.messages:
            meta.add_message(m.topic, m.log_time)
    meta.custom_data = _custom_data(read)
    write_atomic(path / METADATA_FILE, meta.yaml_text())
    result.metadata_written = True
    result.messages = meta.to_dict()['message_count']
    return result
