"""Messages a subscription never handled, counted and reported (floods are not silent).

A keep-last subscription whose messages arrive faster than its node handles them drops the
oldest of its queue without telling anyone, and a best-effort one loses what the network
loses.  Either way the publisher's sequence numbers (``publication_sequence_number`` of the
message info rclpy passes to a two-argument callback) have a gap.  ``DropCounter.seen`` of
each message's info counts the gaps and logs a throttled warning with the count so far.

Every publisher numbers its own messages from 1, so the count is kept per publisher.  rclpy
does not pass the publisher's GID to a callback, so the counter tells publishers apart by
their numbering: it keeps one stream (the last number seen) per publisher, and a message
continues the stream whose last number is the closest below its own.  A message that
continues no stream exactly is a gap only when it cannot be a publisher the counter has not
seen yet: a topic with more matched publishers than streams, or a number below every
stream's, starts a new stream instead.  The streams of publishers that left stay (at most
``MAX_STREAMS``, the least recently used forgotten first): a stale stream can only take a gap
for itself, so the count errs low, never high.  So a hand ``ros2 topic pub`` between a
policy node's commands counts nothing, and a real gap in either is counted.
"""
from __future__ import annotations

from typing import Any, Callable

THROTTLE_S = 2.0    # [s] between repeats of the warning
MAX_STREAMS = 64    # publishers told apart at most (then the oldest streams are forgotten)


class DropCounter:
    """Counts the messages of one subscription that were published but never handled."""

    def __init__(self, logger: Any, topic: str, publishers: Callable[[], int],
                 depth: int) -> None:
        self._logger = logger
        self._topic = topic
        self._publishers = publishers       # the subscription's matched publisher count
        self._depth = depth
        self._streams: list[int] = []       # last number of each publisher, most recent last
        self.count = 0                      # messages dropped so far

    def seen(self, info: Any) -> int:
        """Account for one handled message (its rclpy message info); the messages skipped."""
        seq = info.get('publication_sequence_number') if isinstance(info, dict) else None
        if not isinstance(seq, int):
            return 0                        # this RMW does not number messages
        streams = self._streams
        if streams and streams[-1] == seq - 1:      # the usual case: the same publisher
            streams[-1] = seq
            return 0
        return self._irregular(seq)

    def _irregular(self, seq: int) -> int:
        """A message that does not continue the most recent stream."""
        streams = self._streams
        below = [k for k, last in enumerate(streams) if last < seq]
        k = max(below, key=lambda i: streams[i]) if below else None
        publishers = self._publishers()
        skipped = 0
        if k is not None and streams[k] == seq - 1:
            streams.pop(k)                  # another known publisher, in order
        elif k is None or len(streams) < publishers:
            pass                            # a publisher not seen before: a new stream
        else:
            skipped = seq - streams.pop(k) - 1
        streams.append(seq)
        del streams[:-MAX_STREAMS]
        if skipped:
            self.count += skipped
            self._logger.warning(
                f'{self._topic}: {self.count} messages dropped so far ({skipped} just now): '
                f'they arrive faster than this node handles them (queue depth {self._depth}) '
                'or the network loses them', throttle_duration_sec=THROTTLE_S)
        return skipped
