"""Messages a subscription never handled, counted and reported (floods are not silent).

A keep-last subscription whose messages arrive faster than its node handles them drops the
oldest of its queue without telling anyone, and a best-effort one loses what the network
loses.  Either way the publisher's sequence numbers (``publication_sequence_number`` of the
message info rclpy passes to a two-argument callback) have a gap.  ``DropCounter.seen`` of
each message's info counts the gaps and logs a throttled warning with the count so far.
Gaps are counted while the topic has one publisher (each numbers its own messages: two
interleave), and a publisher that starts again (smaller numbers) starts a new count base.
"""
from __future__ import annotations

from typing import Any, Callable

THROTTLE_S = 2.0    # [s] between repeats of the warning


class DropCounter:
    """Counts the messages of one subscription that were published but never handled."""

    def __init__(self, logger: Any, topic: str, publishers: Callable[[], int],
                 depth: int) -> None:
        self._logger = logger
        self._topic = topic
        self._publishers = publishers       # the subscription's matched publisher count
        self._depth = depth
        self._last: int | None = None
        self.count = 0                      # messages dropped so far

    def seen(self, info: Any) -> int:
        """Account for one handled message (its rclpy message info); the messages skipped."""
        seq = info.get('publication_sequence_number') if isinstance(info, dict) else None
        if not isinstance(seq, int):
            return 0                        # this RMW does not number messages
        last, self._last = self._last, seq
        if last is None or seq <= last + 1 or self._publishers() != 1:
            return 0
        skipped = seq - last - 1
        self.count += skipped
        self._logger.warning(
            f'{self._topic}: {self.count} messages dropped so far ({skipped} just now): they '
            f'arrive faster than this node handles them (queue depth {self._depth}) or the '
            'network loses them', throttle_duration_sec=THROTTLE_S)
        return skipped
