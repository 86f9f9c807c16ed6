"""``sapga bag reindex BAG``: complete a killed or damaged recording, losing nothing intact.

A recorder killed with SIGKILL leaves storage files without summary and footer (only stream
readers read them) and no ``metadata.yaml``; a flipped bit on disk spoils one chunk.
``reindex``:

1. reads each storage file record by record (``salvage.py``): a damaged chunk is skipped,
   every other chunk's messages are kept, and the loss is counted per topic from the message
   indexes;
2. rewrites a file that lacks its footer or holds damage with the ``mcap`` library's
   ``Writer`` into a new temporary file of the bag directory (created exclusively, never
   through a link): header, schemas, channels, then every intact message, attachment and
   metadata record in file order (an attachment that does not match its CRC is lost, and
   named), every private record byte for byte, chunk, attachment and metadata indexes,
   summary and footer;
3. reads the new file back (random access, every message, attachment and metadata record)
   and only then renames it over the original; a damaged original is kept beside it as
   ``<file>.damaged`` (a hard link: no copy), so nothing that was on disk is ever gone.
   A file with no message or attachment left to read is left as it is (nothing would be
   gained);
4. writes ``metadata.yaml`` from what the files hold (topics, QoS, counts, times), keeping
   the ``custom_data`` of the last ``rosbag2`` record.

A single ``.mcap`` file is repaired in place; a complete, intact file is left as it is.
Symbolic links (the bag, a storage file) are refused, never followed.
"""
from __future__ import annotations

import os
import stat
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from sapga_ros.errors import McapError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.io.bounded import NotRegularFile, load_yaml
from sapga_ros.recording.chunks import Budget
from sapga_ros.recording.metadata import (METADATA_FILE, RECORD_NAME, BagMetadata, FileInfo,
                                          TopicInfo)
from sapga_ros.recording.held import Survey, recount, survey
from sapga_ros.recording.reader import Recording, bag_files, open_storage
from sapga_ros.recording.salvage import CUT_SHORT, Damage, Private, Scan, records, scan

_COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                '': CompressionType.NONE}


@dataclass
class FileRepair:
    """What ``repair_file`` did to one storage file."""

    path: Path
    action: str                     # 'intact', 'repaired' or 'kept' (nothing to gain)
    messages: int                   # messages the file holds now (readable)
    damage: list[Damage] = field(default_factory=list)
    lost: dict[str, int] = field(default_factory=dict)     # topic -> messages lost
    counted: bool = True            # every damaged chunk's loss could be counted
    kept_as: Path | None = None     # the damaged original, kept beside the file
    attachments: int = 0            # attachment records the file holds now
    metadata: int = 0               # metadata records the file holds now
    private: int = 0                # private records (opcode 0x80 and above) kept
    lost_records: list[str] = field(default_factory=list)   # "attachment 'name'", ...

    @property
    def loses(self) -> bool:
        """Whether damage cost (or may have cost) data, or the file could not be repaired."""
        return bool(self.lost or self.lost_records or not self.counted
                    or self.action == 'kept')

    def report(self) -> str:
        """One line on what was found and done."""
        regions = [d for d in self.damage if d.why != CUT_SHORT]
        cut = [d for d in self.damage if d.why == CUT_SHORT]
        parts = []
        if regions:
            d = regions[0]
            more = f' and {len(regions) - 1} more' if len(regions) > 1 else ''
            lost = ', '.join(f'{t} {n}' for t, n in sorted(self.lost.items()))
            count = (f'{sum(self.lost.values())} messages lost' if self.counted else
                     f'{sum(self.lost.values())} messages known lost, perhaps more')
            parts.append(f'damaged bytes {d.start}-{d.end} ({d.why}){more}: {count}'
                         f'{f" ({lost})" if lost else ""}')
        elif self.lost:
            lost = ', '.join(f'{t} {n}' for t, n in sorted(self.lost.items()))
            parts.append(f'{sum(self.lost.values())} messages of undefined channels lost '
                         f'({lost})')
        if self.lost_records:
            parts.append(f'lost {", ".join(self.lost_records)}')
        if cut:
            parts.append(f'the last {cut[0].end - cut[0].start} bytes are an unfinished '
                         'record (the writer was stopped)')
        if self.kept_as:
            parts.append(f'the damaged original is kept as {self.kept_as.name}')
        if self.action == 'repaired' and not self.damage and not self.lost:
            parts.append('its summary or indexes did not match its messages')
        what = {'intact': 'complete and intact', 'repaired': 'rewritten complete',
                'kept': 'left unchanged: nothing readable to keep'}[self.action]
        kept = ''.join(f', {n} {noun}{"" if n == 1 else "s"}' for n, noun in (
            (self.attachments, 'attachment'), (self.metadata, 'metadata record'),
            (self.private, 'private record')) if n and self.action != 'kept')
        return f'{self.path}: {what}, {self.messages} messages{kept}' + ''.join(
            f'; {p}' for p in parts)


def refuse_link(path: Path) -> None:
    """McapError if ``path`` is a symbolic link (reindex never follows one)."""
    if path.is_symlink():
        raise McapError(f'{path}: a symbolic link; reindex works on the bag itself, never '
                        'through a link')


def _write(out_f: Any, f: Any, found: Scan) -> tuple[int, int, int]:
    """Write the intact records of ``found`` as a complete MCAP file; the messages,
    attachments and metadata records written.  A private record goes straight to
    ``out_f``: the ``Writer`` has written every record it was given (it holds back only
    the messages of the open chunk), so ``out_f`` is at a record boundary."""
    header = found.header or Header(profile='ros2', library='')
    writer = Writer(out_f, compression=_COMPRESSION.get(found.compression,
                                                        CompressionType.ZSTD))
    writer.start(profile=header.profile, library=header.library)
    schemas = {sid: writer.register_schema(s.name, s.encoding, s.data)
               for sid, s in sorted(found.schemas.items())}
    channels = {cid: writer.register_channel(c.topic, c.message_encoding,
                                             schemas.get(c.schema_id, 0), dict(c.metadata))
                for cid, c in sorted(found.channels.items())}
    count = attachments = metadata = 0
    for r in records(f, found, Budget.streaming()):
        if isinstance(r, Message) and r.channel_id in channels:
            writer.add_message(channels[r.channel_id], r.log_time, r.data, r.publish_time,
                               r.sequence)
            count += 1
        elif isinstance(r, Metadata):
            writer.add_metadata(r.name, dict(r.metadata))
            metadata += 1
        elif isinstance(r, Attachment):
            writer.add_attachment(r.create_time, r.log_time, r.name, r.media_type, r.data)
            attachments += 1
        elif isinstance(r, Private):
            out_f.write(r.raw)
        elif not isinstance(r, (Header, Schema, Channel, Message)):
            raise McapError(f'{found.path}: unexpected record {type(r).__name__}')
    writer.finish()
    return count, attachments, metadata


def _verify(tmp: str, counts: tuple[int, int, int], path: Path) -> None:
    """McapError unless ``tmp`` reads back complete, at random access, with ``counts``
    messages, attachments and metadata records, each found through the summary."""
    with open(tmp, 'rb') as f:
        reader = make_reader(f)
        if reader.get_summary() is None:
            raise McapError(f'{path}: the rewritten copy has no summary; left unchanged')
        back = (sum(1 for _ in reader.iter_messages(log_time_order=False)),
                sum(1 for _ in reader.iter_attachments()),
                sum(1 for _ in reader.iter_metadata()))
    if back != counts:
        raise McapError(f'{path}: the rewritten copy reads back {back[0]} of {counts[0]} '
                        f'messages, {back[1]} of {counts[1]} attachments and {back[2]} of '
                        f'{counts[2]} metadata records; left unchanged')


def _indexed(f: Any, found: Scan) -> bool:
    """Whether a random-access reader finds every message through the file's summary."""
    f.seek(0)
    try:
        reader = make_reader(f)
        counts: dict[int, int] = {}
        for _, channel, _ in reader.iter_messages(log_time_order=False):
            counts[channel.id] = counts.get(channel.id, 0) + 1
        stats = reader.get_summary().statistics
    except Exception:  # noqa: BLE001 - any failure means a damaged summary or index
        return False
    return (counts == found.per_channel and stats is not None
            and dict(stats.channel_message_counts) == counts)


def _keep_original(path: Path) -> Path:
    """Link the damaged original as ``<name>.damaged`` (or ``.damaged-N``)."""
    for k in range(1000):
        aside = path.with_name(f'{path.name}.damaged' + (f'-{k}' if k else ''))
        try:
            os.link(path, aside, follow_symlinks=False)
            return aside
        except FileExistsError:
            continue
    raise McapError(f'{path}: no free name to keep the damaged original; left unchanged')


def repair_file(path: str | os.PathLike) -> FileRepair:
    """Rewrite an incomplete or damaged MCAP file complete, in place; what was done."""
    path = Path(path)
    refuse_link(path)
    with open_storage(path) as f:
        found = scan(f, str(path), Budget.streaming())
        lost, counted = found.lost()
        result = FileRepair(path, 'intact', found.kept, found.damage, lost, counted,
                            attachments=found.attachments, metadata=found.metadata,
                            lost_records=list(found.lost_records.values()),
                            private=len(found.skipped))
        if found.header is None and not (found.kept or found.attachments or found.metadata):
            raise McapError(f'{path}: no MCAP record can be read: not an MCAP file, or '
                            'nothing left of one')
        if found.footer and not found.damage and not found.orphans and _indexed(f, found):
            return result
        if not (found.kept or found.attachments) and found.damage:
            result.action = 'kept'
            return result
        result.action = 'repaired'
        _rewrite(path, f, found, result)
    return result


def _rewrite(path: Path, f: Any, found: Scan, result: FileRepair) -> None:
    """Write the copy beside ``path``, verify it, keep a damaged original, rename."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.reindex.', dir=path.parent)
    except OSError as exc:
        raise McapError(f'{path.parent}: cannot create a file ({exc.strerror or exc}); '
                        'left unchanged') from exc
    try:
        os.fchmod(fd, stat.S_IMODE(os.fstat(f.fileno()).st_mode))
        with os.fdopen(fd, 'wb') as out_f:
            counts = _write(out_f, f, found)
            out_f.flush()
            os.fsync(out_f.fileno())
        _verify(tmp, counts, path)
        if any(d.why != CUT_SHORT for d in found.damage):
            result.kept_as = _keep_original(path)
        os.replace(tmp, path)
        result.messages, result.attachments, result.metadata = counts
    except OSError as exc:
        raise McapError(f'{path}: cannot rewrite ({exc.strerror or exc}); left '
                        'unchanged') from exc
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


def _topic(name: str, channel: Channel, type_name: str) -> TopicInfo:
    try:
        qos = load_yaml(channel.metadata.get('offered_qos_profiles', '') or '[]')
    except yaml.YAMLError:
        qos = []
    return TopicInfo(name, type_name, qos if isinstance(qos, list) else [],
                     channel.metadata.get('topic_type_hash', ''), channel.message_encoding)


def _custom_data(surveys: list[Survey]) -> dict[str, str]:
    for s in reversed(surveys):
        text = s.metadata.get(RECORD_NAME, {}).get('serialized_metadata', '')
        try:
            custom = (load_yaml(text) or {}).get('custom_data')
        except (yaml.YAMLError, AttributeError):
            custom = None
        if isinstance(custom, dict):
            return {str(k): str(v) for k, v in custom.items()}
    return {}


@dataclass
class ReindexResult:
    """What ``reindex`` did."""

    path: Path
    files: list[FileRepair] = field(default_factory=list)
    messages: int = 0
    metadata_written: bool = False

    @property
    def repaired(self) -> list[Path]:
        """The files rewritten."""
        return [r.path for r in self.files if r.action == 'repaired']

    @property
    def lost(self) -> bool:
        """Whether damage cost (or may have cost) data, or a file could not be repaired."""
        return any(r.loses for r in self.files)


def reindex(path: str | os.PathLike) -> ReindexResult:
    """Repair the incomplete or damaged files of a bag directory (or one file) and write
    metadata.yaml from what they hold."""
    path = Path(path)
    refuse_link(path)
    result = ReindexResult(path)
    probe = Recording(path=str(path))
    files = bag_files(path, probe) if path.is_dir() else [path]
    for file in files:
        result.files.append(repair_file(file))
    result.messages = sum(r.messages for r in result.files)
    if not path.is_dir():
        return result
    meta, surveys = BagMetadata(), [survey(file) for file in files]
    for file, found in zip(files, surveys):
        meta.files.append(FileInfo(file.name))
        for name, (channel, type_name) in found.topics.items():
            meta.topics.setdefault(name, _topic(name, channel, type_name))
    recount(meta, path, surveys)
    meta.custom_data = _custom_data(surveys)
    try:
        write_atomic(path / METADATA_FILE, meta.yaml_text())
    except (NotRegularFile, OSError) as exc:
        raise McapError(f'{path / METADATA_FILE}: cannot write ({exc.strerror or exc})'
                        ) from exc
    result.metadata_written = True
    result.messages = meta.to_dict()['message_count']
    return result
