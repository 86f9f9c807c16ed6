"""One MCAP storage file of a bag, written as rosbag2's MCAP storage plugin writes it.

Every byte the ``mcap`` library's ``Writer`` emits goes to the operating system at once
(an unbuffered file: survives SIGKILL); ``flush`` closes the chunk in progress.  A write
that fails (a full disk) marks the file broken: it takes nothing more, is closed without
summary and footer, and keeps every whole record that reached the disk for ``sapga bag
reindex`` (the part of a record the failed write left is cut off, so that the file ends on a
record boundary and streaming readers read it to its end).

Each channel and its schema are also written outside the chunks, as a Metadata record
``sapga_channel`` (``chunks.channel_record``): the chunk that defines a channel may be the
one a flipped bit spoils, and without its definition no later message of the channel could
be kept; readers that do not know the record skip it.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import IO, Any, Mapping

from mcap.records import Channel, Schema
from mcap.writer import CompressionType, Writer

from sapga_ros import __version__
from sapga_ros.errors import McapError
from sapga_ros.recording.chunks import MAX_MESSAGE_BYTES, CHANNEL_RECORD, channel_record
from sapga_ros.recording.metadata import TopicInfo, qos_yaml
from sapga_ros.recording.schemas import message_definition

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
LIBRARY = f'sapga_ros {__version__}'
COMPRESSIONS = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}


class _WriteThrough:
    """An unbuffered file: every write reaches the operating system at once (survives
    SIGKILL), and a failed write leaves nothing behind to be written again later."""

    def __init__(self, f: IO[bytes]) -> None:
        self._f = f

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            view = view[self._f.write(view):]
        return len(data)

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        pass


class StorageFile:
    """One MCAP storage file of a bag."""

    def __init__(self, path: Path, chunk_size: int, compression: str) -> None:
        self.path = path
        try:
            self._file = open(path, 'xb', buffering=0)
        except OSError as exc:
            raise McapError(f'{path}: cannot create ({exc.strerror or exc})') from exc
        self._writer = Writer(_WriteThrough(self._file), chunk_size=chunk_size,
                              compression=COMPRESSIONS[compression])
        self._schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.unflushed = 0
        self.broken = False         # a write failed: the file takes nothing more
        try:
            self._do(self._writer.start, profile=PROFILE, library=LIBRARY)
        except McapError:
            self._file.close()
            path.unlink(missing_ok=True)       # ours, and holds not even a header
            raise

    def _do(self, action: Any, *args: Any, **kwargs: Any) -> Any:
        if self.broken:
            raise McapError(f'{self.path}: an earlier write failed')
        end = self._file.tell()             # the end of the last whole record
        try:
            return action(*args, **kwargs)
        except OSError as exc:
            self.broken = True
            self._cut(end)
            raise McapError(f'{self.path}: write failed ({exc.strerror or exc})') from exc

    def _cut(self, end: int) -> None:
        """Drop what a failed write left after ``end``: part of a record, which no reader
        could parse (cutting a file frees space, so it works on a full disk)."""
        try:
            os.ftruncate(self._file.fileno(), end)
        except OSError:
            pass                            # the reindex of the bag still ends there

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        self._do(self._writer.add_metadata, name, {str(k): str(v) for k, v in data.items()})

    def add_topic(self, topic: TopicInfo) -> None:
        """The topic's schema (once per type) and channel, as the plugin's create_topic."""
        if topic.name in self.channels:
            return
        schema_id = self._schemas.get(topic.type)
        if schema_id is None:
            schema_id = self._do(self._writer.register_schema, name=topic.type,
                                 encoding=SCHEMA_ENCODING,
                                 data=message_definition(topic.type).encode('utf-8'))
            self._schemas[topic.type] = schema_id
        metadata = {'offered_qos_profiles': qos_yaml(topic.offered_qos_profiles),
                    'topic_type_hash': topic.type_description_hash}
        channel_id = self._do(self._writer.register_channel, topic=topic.name,
                              message_encoding=topic.serialization_format,
                              schema_id=schema_id, metadata=metadata)
        self.channels[topic.name] = channel_id
        self._do(self._writer.add_metadata, CHANNEL_RECORD, channel_record(
            Channel(id=channel_id, topic=topic.name, schema_id=schema_id, metadata=metadata,
                    message_encoding=topic.serialization_format),
            Schema(id=schema_id, name=topic.type, encoding=SCHEMA_ENCODING,
                   data=message_definition(topic.type).encode('utf-8'))))

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
        if len(data) > MAX_MESSAGE_BYTES:
            raise McapError(f'{self.path}: a message of {len(data)} bytes on {topic}: more '
                            f'than {MAX_MESSAGE_BYTES >> 20} MiB, the largest a chunk every '
                            'reader accepts can hold; not recorded')
        self._do(self._writer.add_message, channel_id=self.channels[topic],
                 log_time=int(log_time), data=bytes(data), publish_time=int(publish_time),
                 sequence=0)
        self.unflushed += 1

    def flush(self) -> None:
        """Close the chunk in progress; everything written so far is on the OS's side."""
        if self.unflushed:
            self._do(self._writer.flush)
            self.unflushed = 0

    def close(self) -> None:
        """Summary and footer (unless a write failed), then close the file."""
        try:
            if not self.broken:
                self._do(self._writer.finish)
        finally:
            self._file.close()
