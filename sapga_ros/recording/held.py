"""What a bag's storage files hold, counted from the files themselves.

After a write failed (a full disk), what a writer was given is not what is on disk: a chunk
that could not be written took its messages with it.  ``recount`` sets a ``BagMetadata``'s
counts and times from the messages each storage file holds readable (``salvage.py``), one
chunk in memory at a time.
"""
from __future__ import annotations

from pathlib import Path

from mcap.records import Message

from sapga_ros.errors import McapError
from sapga_ros.io.bounded import open_regular
from sapga_ros.recording.chunks import Budget
from sapga_ros.recording.metadata import NO_TIME, BagMetadata
from sapga_ros.recording.salvage import records, scan


def held(path: Path) -> tuple[dict[str, int], int, int]:
    """Readable messages per topic of one storage file, and their first and last receive
    times [ns] (no file, or nothing readable: nothing)."""
    counts: dict[str, int] = {}
    first, last = NO_TIME, 0
    try:
        f = open_regular(path)
    except OSError:
        return counts, first, last
    with f:
        try:
            found = scan(f, str(path), Budget.streaming())
            for r in records(f, found, Budget.streaming()):
                if isinstance(r, Message):
                    topic = found.channels[r.channel_id].topic
                    counts[topic] = counts.get(topic, 0) + 1
                    first, last = min(first, r.log_time), max(last, r.log_time)
        except McapError:
            pass        # what was counted before it is what the file holds
    return counts, first, last


def recount(meta: BagMetadata, bag: Path) -> int:
    """Set ``meta``'s message counts and times from its files in ``bag``; the total."""
    for topic in meta.topics.values():
        topic.message_count = 0
    for info in meta.files:
        counts, info.starting_time, info.end_time = held(bag / info.path)
        info.message_count = sum(counts.values())
        for name, n in counts.items():
            if name in meta.topics:
                meta.topics[name].message_count += n
    return sum(info.message_count for info in meta.files)
