"""A recorded run: messages in, one rosbag2 bag out, split per run or per episode.

``split='run'``: one storage file, episode events inside it.  ``split='episode'``: a new
storage file of the same bag at every episode ``start`` event (the event is its first
message; its ``sapga`` record names the episode), as rosbag2 splits a bag.  Either way each
episode end event (goal / step_limit / reset) flushes the chunk in progress, so a finished
episode is on disk whatever happens next.  The bag directory is ``<output_dir>/<name>``.
"""
from __future__ import annotations

import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Mapping

from sapga_ros.errors import McapError
from sapga_ros.recording.events import EPISODE_END_EVENTS, event_episode, parse_event
from sapga_ros.recording.metadata import TopicInfo
from sapga_ros.recording.schemas import cdr_string
from sapga_ros.recording.writer import DEFAULT_CHUNK_SIZE, BagWriter, check_options

SPLITS = ('run', 'episode')


def utc_stamp() -> str:
    """A file-name-safe UTC time, e.g. '20250101-120000'."""
    return datetime.now(timezone.utc).strftime('%Y%m%d-%H%M%S')


def free_bag_path(output_dir: str | os.PathLike, name: str) -> Path:
    """``<output_dir>/<name>``, or ``<name>-1``, ``<name>-2``... if taken: never overwrites."""
    output_dir = Path(output_dir)
    for k in range(10000):
        path = output_dir / (name if k == 0 else f'{name}-{k}')
        if not os.path.lexists(path):
            return path
    raise McapError(f'{output_dir}: no free bag name for {name}')


class RecordingSession:
    """Routes messages to a ``BagWriter``; splits and flushes on episode events."""

    def __init__(self, bag: str | os.PathLike, *, split: str = 'run',
                 event_topic: str | None = None, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 compression: str = 'zstd', metadata: Mapping[str, str] | None = None) -> None:
        if split not in SPLITS:
            raise McapError(f'split {split!r}: expected one of {", ".join(SPLITS)}')
        check_options(chunk_size, compression)
        meta = {str(k): str(v) for k, v in (metadata or {}).items()}
        meta.update(split=split, created=datetime.now(timezone.utc).isoformat(
            timespec='seconds'))
        self.split = split
        self.event_topic = event_topic
        self.bag = BagWriter(bag, chunk_size=chunk_size, compression=compression,
                             custom_data=meta, file_metadata=meta)

    @property
    def path(self) -> Path:
        return self.bag.path

    @property
    def message_count(self) -> int:
        return self.bag.message_count

    def add_topic(self, topic: TopicInfo) -> None:
        self.bag.add_topic(topic)

    def write(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
        """Record one message of a registered topic; split or flush on episode events."""
        event = parse_event(cdr_string(data)) if topic == self.event_topic else None
        kind = event.get('event') if event else None
        if self.split == 'episode' and kind == 'start' and self.bag.file_message_count:
            number = event_episode(event)
            self.bag.new_file({} if number is None else {'episode': str(number)})
        elif self.split == 'episode' and kind == 'start' and event_episode(event) is not None:
            self.bag.file_metadata['episode'] = str(event_episode(event))
        self.bag.write(topic, data, log_time, publish_time)
        if kind in EPISODE_END_EVENTS:
            self.bag.flush()

    def flush(self) -> None:
        self.bag.flush()

    def close(self) -> None:
        self.bag.close()
