"""What a bag's storage files hold, counted from the files themselves, one chunk at a time.

After a write failed (a full disk), what a writer was given is not what is on disk: a chunk
that could not be written took its messages with it; after reindex, the files are all there
is.  ``survey`` reads one storage file as ``salvage.py`` does (intact records only, streamed:
nothing is kept but counts) and says per topic how many messages it holds, their first and
last receive times, each topic's channel and schema name, and its metadata records;
``recount`` sets a ``BagMetadata``'s counts and times from the surveys of its files.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Channel, Message, Metadata

from sapga_ros.errors import McapError
from sapga_ros.io.bounded import open_regular
from sapga_ros.recording.chunks import Budget
from sapga_ros.recording.metadata import NO_TIME, BagMetadata
from sapga_ros.recording.salvage import records, scan


@dataclass
class Survey:
    """What one storage file holds readable."""

    counts: dict[str, int] = field(default_factory=dict)        # topic -> messages
    first: int = NO_TIME        # [ns] earliest receive time
    last: int = 0
    topics: dict[str, tuple[Channel, str]] = field(default_factory=dict)  # channel, type
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)   # last of each name


def survey(path: Path) -> Survey:
    """The survey of one storage file (no file, or nothing readable: an empty one)."""
    out = Survey()
    try:
        f = open_regular(path)
    except OSError:
        return out
    with f:
        try:
            found = scan(f, str(path), Budget.streaming())
            for cid, channel in sorted(found.channels.items()):
                schema = found.schemas.get(channel.schema_id)
                out.topics.setdefault(channel.topic, (channel, schema.name if schema else ''))
            for r in records(f, found, Budget.streaming()):
                if isinstance(r, Message):
                    topic = found.channels[r.channel_id].topic
                    out.counts[topic] = out.counts.get(topic, 0) + 1
                    out.first, out.last = min(out.first, r.log_time), max(out.last, r.log_time)
                elif isinstance(r, Metadata):
                    out.metadata[r.name] = dict(r.metadata)
        except McapError:
            pass        # what was counted before it is what the file holds
    return out


def recount(meta: BagMetadata, bag: Path, surveys: list[Survey] | None = None) -> int:
    """Set ``meta``'s message counts and times from its files in ``bag`` (or their
    ``surveys``, in the same order); the total."""
    for topic in meta.topics.values():
        topic.message_count = 0
    for k, info in enumerate(meta.files):
        found = surveys[k] if surveys is not None else survey(bag / info.path)
        info.starting_time, info.end_time = found.first, found.last
        info.message_count = sum(found.counts.values())
        for name, n in found.counts.items():
            if name in meta.topics:
                meta.topics[name].message_count += n
    return sum(info.message_count for info in meta.files)
