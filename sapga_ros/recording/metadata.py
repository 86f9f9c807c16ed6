"""rosbag2 bag metadata (version 9, ROS 2 Jazzy): ``metadata.yaml`` and the ``rosbag2`` record.

The layout and the YAML follow rosbag2's ``rosbag2_storage`` (``BagMetadata``, yaml.hpp,
qos.cpp) exactly:

- a bag is a directory ``<bag>/`` holding ``metadata.yaml`` and the storage files
  ``<bag>_0.mcap``, ``<bag>_1.mcap``, ... (one per split, named as rosbag2's
  ``SequentialWriter::format_storage_uri`` names them);
- ``metadata.yaml`` = ``{rosbag2_bagfile_information: <BagMetadata>}``; the same
  ``BagMetadata`` (without the wrapper) is the ``serialized_metadata`` of each MCAP file's
  ``rosbag2`` Metadata record, as the MCAP storage plugin's ``update_metadata`` writes it;
- ``offered_qos_profiles`` (version 9): a list of profiles with policy *names*
  (``keep_last``, ``reliable``, ``transient_local``, ``automatic``) and durations as
  ``{sec, nsec}``; in an MCAP channel's metadata the same list as a YAML string.

``read_bag_metadata`` reads a ``metadata.yaml`` bounded in size (1 MiB), nesting and number
of storage files, without YAML aliases, and refuses a file listed twice (a bag would count
its messages twice).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any, Mapping, Sequence

import yaml

from sapga_ros.errors import McapError
from sapga_ros.io.bounded import load_yaml, read_bounded

VERSION = 9                                 # rosbag2 metadata version of ROS 2 Jazzy
STORAGE_ID = 'mcap'
ROS_DISTRO = 'jazzy'
METADATA_FILE = 'metadata.yaml'
RECORD_NAME = 'rosbag2'                     # the MCAP Metadata record rosbag2 writes
RMW_DURATION_INFINITE = (1 << 63) - 1       # [ns]
NO_TIME = (1 << 63) - 1                     # rosbag2's starting_time before any message
MAX_METADATA_BYTES = 1 << 20            # some 5000 storage files
MAX_STORAGE_FILES = 10000


def storage_file_name(bag: str | os.PathLike, index: int) -> str:
    """rosbag2's name of storage file ``index`` of bag directory ``bag``: ``<bag>_<i>.mcap``."""
    return f'{Path(bag).name}_{index}.mcap'


def _duration(ns: Any) -> dict[str, int]:
    ns = min(max(int(ns), 0), RMW_DURATION_INFINITE)
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def qos_profile(**p: Any) -> dict[str, Any]:
    """One offered QoS profile in rosbag2's version-9 form (absent durations: infinite).

    Keys: history, depth, reliability, durability, deadline, lifespan, liveliness,
    liveliness_lease_duration (nanoseconds), avoid_ros_namespace_conventions.
    """
    return {
        'history': str(p.get('history', 'keep_last')),
        'depth': int(p.get('depth', 10)),
        'reliability': str(p.get('reliability', 'reliable')),
        'durability': str(p.get('durability', 'volatile')),
        'deadline': _duration(p.get('deadline', RMW_DURATION_INFINITE)),
        'lifespan': _duration(p.get('lifespan', RMW_DURATION_INFINITE)),
        'liveliness': str(p.get('liveliness', 'automatic')),
        'liveliness_lease_duration': _duration(
            p.get('liveliness_lease_duration', RMW_DURATION_INFINITE)),
        'avoid_ros_namespace_conventions': bool(p.get('avoid_ros_namespace_conventions')),
    }


def qos_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """``offered_qos_profiles`` of an MCAP channel: the profile list as a YAML string."""
    return yaml.safe_dump([dict(p) for p in profiles], sort_keys=False,
                          default_flow_style=False)


@dataclass
class TopicInfo:
    """One topic of a bag (``topics_with_message_count``)."""

    name: str                               # resolved, e.g. '/joint_states'
    type: str                               # 'pkg/msg/Type'
    offered_qos_profiles: list[dict[str, Any]]
    type_description_hash: str = ''
    serialization_format: str = 'cdr'
    message_count: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {'topic_metadata': {
            'name': self.name, 'type': self.type,
            'serialization_format': self.serialization_format,
            'offered_qos_profiles': self.offered_qos_profiles,
            'type_description_hash': self.type_description_hash},
            'message_count': self.message_count}


@dataclass
class FileInfo:
    """One storage file of a bag (``files``)."""

    path: str                               # relative to the bag directory
    starting_time: int = NO_TIME            # [ns] earliest receive time
    end_time: int = 0
    message_count: int = 0

    def add(self, t: int) -> None:
        self.starting_time = min(self.starting_time, t)
        self.end_time = max(self.end_time, t)
        self.message_count += 1

    @property
    def duration(self) -> int:
        return max(0, self.end_time - self.starting_time) if self.message_count else 0

    def to_dict(self) -> dict[str, Any]:
        return {'path': self.path,
                'starting_time': {'nanoseconds_since_epoch': self.starting_time},
                'duration': {'nanoseconds': self.duration},
                'message_count': self.message_count}


@dataclass
class BagMetadata:
    """rosbag2's ``BagMetadata``, kept up to date message by message."""

    files: list[FileInfo] = field(default_factory=list)
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    custom_data: dict[str, str] = field(default_factory=dict)

    def add_message(self, topic: str, t: int) -> None:
        """Count one message on ``topic`` received at ``t`` [ns] in the last file."""
        self.topics[topic].message_count += 1
        self.files[-1].add(t)

    def to_dict(self) -> dict[str, Any]:
        """The ``BagMetadata`` mapping, keys in rosbag2's order."""
        counted = [f for f in self.files if f.message_count]
        start = min((f.starting_time for f in counted), default=NO_TIME)
        end = max((f.end_time for f in counted), default=0)
        return {
            'version': VERSION,
            'storage_identifier': STORAGE_ID,
            'duration': {'nanoseconds': max(0, end - start) if counted else 0},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': sum(f.message_count for f in self.files),
            'topics_with_message_count': [t.to_dict() for t in self.topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [f.path for f in self.files],
            'files': [f.to_dict() for f in self.files],
            'custom_data': dict(self.custom_data) or None,
            'ros_distro': ROS_DISTRO,
        }

    def serialized(self) -> str:
        """The ``serialized_metadata`` of the ``rosbag2`` MCAP record."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=False)

    def yaml_text(self) -> str:
        """The text of ``metadata.yaml``."""
        return yaml.safe_dump({'rosbag2_bagfile_information': self.to_dict()},
                              sort_keys=False, default_flow_style=False)


def read_bag_metadata(bag: str | os.PathLike) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of ``<bag>/metadata.yaml``.

    McapError (one line) if it is missing, not a regular file, too large, not YAML, or lacks
    ``relative_file_paths`` (a list of file names).
    """
    path = Path(bag) / METADATA_FILE
    try:
        doc = load_yaml(read_bounded(path, MAX_METADATA_BYTES).decode('utf-8'))
    except FileNotFoundError as exc:
        raise McapError(f'{path}: no such file') from exc
    except OSError as exc:
        raise McapError(f'{path}: cannot read ({exc.strerror or exc})') from exc
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        raise McapError(f'{path}: not YAML ({" ".join(str(exc).split())[:120]})') from exc
    info = doc.get('rosbag2_bagfile_information') if isinstance(doc, dict) else None
    files = info.get('relative_file_paths') if isinstance(info, dict) else None
    if not isinstance(files, list) or not all(isinstance(p, str) and p for p in files):
        raise McapError(f'{path}: no rosbag2_bagfile_information.relative_file_paths list')
    if len(files) > MAX_STORAGE_FILES:
        raise McapError(f'{path}: relative_file_paths lists {len(files)} files, more than '
                        f'{MAX_STORAGE_FILES}')
    seen: set[str] = set()
    for name in files:
        if PurePath(name).name in seen:
            raise McapError(f'{path}: relative_file_paths lists {PurePath(name).name[:80]!r} '
                            'twice')
        seen.add(PurePath(name).name)
    return info
