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
user-space buffering, ``storage.py``); ``flush`` closes the chunk in progress.  A writer
killed with SIGKILL leaves files without summary and footer that stream readers read up to
the last complete chunk, and no ``metadata.yaml``: ``sapga bag reindex`` (``repair.py``)
completes them.

A write that fails (a full disk) is never silent: ``write`` raises McapError for that
message and every later one until a new storage file can be written (tried every
``RETRY_S``); ``close`` then counts in ``metadata.yaml`` what the files hold, marks the bag
``incomplete`` in its ``custom_data`` and raises McapError.
"""
from __future__ import annotations

import os
import stat
import time
from pathlib import Path
from typing import Any, Mapping

from sapga_ros.errors import McapError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.recording.chunks import MAX_CHUNK_SIZE
from sapga_ros.recording.held import recount
from sapga_ros.recording.metadata import (METADATA_FILE, RECORD_NAME, BagMetadata, FileInfo,
                                          TopicInfo, storage_file_name)
from sapga_ros.recording.storage import COMPRESSIONS, StorageFile

SAPGA_RECORD = 'sapga'
RETRY_S = 1.0                           # [s] between tries of a new file after a failure
DEFAULT_CHUNK_SIZE = 64 * 1024          # [bytes] uncompressed chunk


def check_options(chunk_size: Any, compression: Any) -> None:
    """McapError unless chunk_size is a positive int within the readers' chunk limit and
    compression is known."""
    if compression not in COMPRESSIONS:
        raise McapError(f'compression {compression!r}: expected one of '
                        f'{", ".join(COMPRESSIONS)}')
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise McapError(f'chunk_size {chunk_size!r}: expected a positive number of bytes')
    if chunk_size > MAX_CHUNK_SIZE:
        raise McapError(f'chunk_size {chunk_size}: more than {MAX_CHUNK_SIZE} bytes '
                        f'({MAX_CHUNK_SIZE >> 20} MiB), the largest chunk every reader of '
                        'the bag accepts')


def _not_a_directory(path: Path) -> str:
    """What is at ``path`` instead of a directory."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return 'not a directory (a part of the path is a file)'
    return ('a device, not a directory' if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else 'a FIFO, not a directory' if stat.S_ISFIFO(mode)
            else 'a file, not a directory')


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
        except (FileExistsError, NotADirectoryError) as exc:
            raise McapError(f'{self.path.parent}: {_not_a_directory(self.path.parent)}; the '
                            'bag directory cannot be made in it') from exc
        except OSError as exc:
            raise McapError(f'{self.path.parent}: cannot create the output directory '
                            f'({exc.strerror or exc})') from exc
        try:
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
        self.failure: str | None = None     # the first write that failed
        self.offered = 0                    # messages given to write()
        self._retry_at = 0.0
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

    def _failed(self, exc: McapError) -> None:
        """A write failed: leave the file as it is (reindex completes it) and try a new
        storage file, at most every ``RETRY_S``, once the disk takes data again."""
        self.failure = self.failure or str(exc)
        if self.file is not None:
            file, self.file = self.file, None
            file.close()
        self._retry_at = time.monotonic() + RETRY_S

    def _writable(self) -> StorageFile:
        """The open storage file; McapError while writes fail."""
        if self.file is None and time.monotonic() >= self._retry_at:
            try:
                self.new_file(self.file_metadata)
            except McapError as exc:
                self._failed(exc)
        if self.file is None:
            raise McapError(f'{self.path}: not recording since a write failed '
                            f'({self.failure})')
        return self.file

    def new_file(self, extra: Mapping[str, str] | None = None) -> Path:
        """Finish the open storage file, if any, and open the next one (a split)."""
        if self.closed:
            raise McapError(f'{self.path}: the bag is closed')
        self._finish_file()
        name = storage_file_name(self.path, len(self.metadata.files))
        self.file_metadata = {str(k): str(v) for k, v in (extra or {}).items()}
        try:
            self.file = StorageFile(self.path / name, self._chunk_size, self._compression)
            self.metadata.files.append(FileInfo(name))
            self.file.add_metadata(RECORD_NAME, {'serialized_metadata':
                                                 self.metadata.serialized()})
            self.file.add_metadata(SAPGA_RECORD, {**self._common_metadata,
                                                  **self.file_metadata})
            for topic in self.metadata.topics.values():
                self.file.add_topic(topic)
        except McapError as exc:
            self._failed(exc)
            raise
        return self.path / name

    def add_topic(self, topic: TopicInfo) -> None:
        """Register a topic (its QoS and hash are fixed from now on for every file); a write
        failure is kept for the next ``write`` to report."""
        if topic.name not in self.metadata.topics:
            self.metadata.topics[topic.name] = topic
            if self.file is not None:
                try:
                    self.file.add_topic(topic)
                except McapError as exc:
                    self._failed(exc)

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
        """Append one serialized message, unchanged, to the open storage file."""
        if self.closed:
            raise McapError(f'{self.path}: write after close')
        self.offered += 1
        file = self._writable()
        try:
            file.write(topic, data, log_time, publish_time)
        except McapError as exc:
            if file.broken:
                self._failed(exc)
            raise
        self.metadata.add_message(topic, int(log_time))

    @property
    def file_message_count(self) -> int:
        """Messages in the open storage file."""
        return self.metadata.files[-1].message_count

    def flush(self) -> None:
        """Close the chunk in progress; McapError if that write fails."""
        if self.file is not None:
            try:
                self.file.flush()
            except McapError as exc:
                self._failed(exc)
                raise

    def close(self) -> None:
        """Finish the open file and write ``metadata.yaml`` (idempotent).

        After a failed write, ``metadata.yaml`` counts what the files hold, its
        ``custom_data`` says ``incomplete`` and why, and McapError says so."""
        if self.closed:
            return
        self.closed = True
        try:
            self._finish_file()
        except McapError as exc:
            self._failed(exc)
        if self.failure:
            held = recount(self.metadata, self.path)
            self.metadata.custom_data['incomplete'] = (
                f'{self.failure}; {held} of {self.offered} messages written')
        try:
            write_atomic(self.path / METADATA_FILE, self.metadata.yaml_text())
        except OSError as exc:
            raise McapError(f'{self.path / METADATA_FILE}: cannot write '
                            f'({exc.strerror or exc})') from exc
        if self.failure:
            raise McapError(f'{self.path}: incomplete: {self.metadata.custom_data["incomplete"]}')

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
