"""Writing rosbag2 bags with MCAP storage, as rosbag2's MCAP storage plugin writes them.

``BagWriter`` makes one bag directory (never an existing one) of storage files
``<bag>_0.mcap``, ``<bag>_1.mcap``, ... (``new_file`` splits, as rosbag2's
``SequentialWriter::split_bagfile``) and ``metadata.yaml`` when it closes.  Each storage file is
written by the ``mcap`` library's ``Writer``, with what the plugin writes:

- Header profile ``ros2``; a Metadata record ``rosbag2`` (``serialized_metadata``: the bag's
  ``BagMetadata`` so far) when the file opens and again before it closes;
- one Schema per message type (``pkg/msg/Type``, encoding ``ros2msg``, the complete
  definition) and one Channel per topic (message encoding ``cdr``, metadata
  ``offered_qos_profiles`` and ``topic_type_hash``), in every file;
- Messages with ``log_time`` = receive time and ``publish_time`` = send time, sequence 0;
- chunks (zstd by default) with CRCs, message indexes, summary and footer.

Besides, a Metadata record ``sapga`` (problem, topic roles, episode) makes a single file
self-describing for ``sapga inspect``.

Crash safety: every byte the MCAP writer emits goes to the operating system at once (no
user-space buffering); ``flush`` closes the chunk in progress.  A writer killed with SIGKILL
leaves files without summary and footer that stream readers read up to the last complete
chunk, and no ``metadata.yaml``: ``sapga bag reindex`` (``repair.py``) completes them.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import IO, Any, Mapping

from mcap.writer import CompressionType, Writer

from sapga_ros import __version__
from sapga_ros.errors import McapError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.recording.metadata import (METADATA_FILE, RECORD_NAME, BagMetadata, FileInfo,
                                          TopicInfo, qos_yaml, storage_file_name)
from sapga_ros.recording.schemas import message_definition

PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
SAPGA_RECORD = 'sapga'
LIBRARY = f'sapga_ros {__version__}'
DEFAULT_CHUNK_SIZE = 64 * 1024          # [bytes] uncompressed chunk
COMPRESSIONS = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}


def check_options(chunk_size: Any, compression: Any) -> None:
    """McapError unless chunk_size is a positive int and compression is known."""
    if compression not in COMPRESSIONS:
        raise McapError(f'compression {compression!r}: expected one of '
                        f'{", ".join(COMPRESSIONS)}')
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise McapError(f'chunk_size {chunk_size!r}: expected a positive number of bytes')


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


class StorageFile:
    """One MCAP storage file of a bag."""

    def __init__(self, path: Path, chunk_size: int, compression: str) -> None:
        self.path = path
        try:
            self._file = open(path, 'xb')
        except OSError as exc:
            raise McapError(f'{path}: cannot create ({exc.strerror or exc})') from exc
        self._writer = Writer(_WriteThrough(self._file), chunk_size=chunk_size,
                              compression=COMPRESSIONS[compression])
        self._schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.unflushed = 0
        self._do(self._writer.start, profile=PROFILE, library=LIBRARY)

    def _do(self, action: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return action(*args, **kwargs)
        except OSError as exc:
            raise McapError(f'{self.path}: write failed ({exc.strerror or exc})') from exc

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
        self.channels[topic.name] = self._do(
            self._writer.register_channel, topic=topic.name,
            message_encoding=topic.serialization_format, schema_id=schema_id,
            metadata={'offered_qos_profiles': qos_yaml(topic.offered_qos_profiles),
                      'topic_type_hash': topic.type_description_hash})

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
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
        """Summary and footer, then close the file."""
        try:
            self._do(self._writer.finish)
        finally:
            self._file.close()


class BagWriter:
    """A rosbag2 bag directory with MCAP storage; a context manager that closes it.

    ``custom_data`` goes to ``metadata.yaml``; ``file_metadata`` (and the mapping given to
    ``new_file``) to each storage file's ``sapga`` record.
    """

    def __init__(self, directory: str | os.PathLike, *, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str = 'zstd', custom_data: Mapping[str, str] | None = None,
                 file_metadata: Mapping[str, str] | None = None) -> None:
        check_options(chunk_size, compression)
        self.path = Path(directory)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.mkdir()
        except FileExistsError as exc:
            raise McapError(f'{self.path}: exists already; a bag is never overwritten') from exc
        except OSError as exc:
            raise McapError(f'{self.path}: cannot create the bag directory '
                            f'({exc.strerror or exc})') from exc
        self._chunk_size = chunk_size
        self._compression = compression
        self._common_metadata = {str(k): str(v) for k, v in (file_metadata or {}).items()}
        self.metadata = BagMetadata(custom_data={str(k): str(v)
                                                 for k, v in (custom_data or {}).items()})
        self.file: StorageFile | None = None
        self.file_metadata: dict[str, str] = {}     # the open file's own sapga entries
        self.closed = False
        self.new_file()

    @property
    def paths(self) -> list[Path]:
        """The storage files so far."""
        return [self.path / f.path for f in self.metadata.files]

    @property
    def message_count(self) -> int:
        return sum(f.message_count for f in self.metadata.files)

    def _finish_file(self) -> None:
        if self.file is not None:
            file, self.file = self.file, None
            try:
                file.add_metadata(SAPGA_RECORD, {**self._common_metadata, **self.file_metadata})
                file.add_metadata(RECORD_NAME, {'serialized_metadata':
                                                self.metadata.serialized()})
            finally:
                file.close()

    def new_file(self, extra: Mapping[str, str] | None = None) -> Path:
        """Finish the open storage file, if any, and open the next one (a split)."""
        if self.closed:
            raise McapError(f'{self.path}: the bag is closed')
        self._finish_file()
        name = storage_file_name(self.path, len(self.metadata.files))
        self.file = StorageFile(self.path / name, self._chunk_size, self._compression)
        self.metadata.files.append(FileInfo(name))
        self.file_metadata = {str(k): str(v) for k, v in (extra or {}).items()}
        self.file.add_metadata(RECORD_NAME, {'serialized_metadata': self.metadata.serialized()})
        self.file.add_metadata(SAPGA_RECORD, {**self._common_metadata, **self.file_metadata})
        for topic in self.metadata.topics.values():
            self.file.add_topic(topic)
        return self.file.path

    def add_topic(self, topic: TopicInfo) -> None:
        """Register a topic (its QoS and hash are fixed from now on for every file)."""
        if topic.name not in self.metadata.topics:
            self.metadata.topics[topic.name] = topic
            self.file.add_topic(topic)

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
        """Append one serialized message, unchanged, to the open storage file."""
        if self.closed:
            raise McapError(f'{self.path}: write after close')
        self.file.write(topic, data, log_time, publish_time)
        self.metadata.add_message(topic, int(log_time))

    @property
    def file_message_count(self) -> int:
        """Messages in the open storage file."""
        return self.metadata.files[-1].message_count

    def flush(self) -> None:
        if self.file is not None:
            self.file.flush()

    def close(self) -> None:
        """Finish the open file and write ``metadata.yaml`` (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._finish_file()
        finally:
            try:
                write_atomic(self.path / METADATA_FILE, self.metadata.yaml_text())
            except OSError as exc:
                raise McapError(f'{self.path / METADATA_FILE}: cannot write '
                                f'({exc.strerror or exc})') from exc

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
