"""Cutting a recording's messages into episodes one message at a time, in bounded memory.

``Cutter.feed`` takes decoded messages in file order and hands each episode to ``done`` once
nothing more can join it, so a reader holds the two or three newest episodes, never the whole
recording: a bag of millions of messages is summarised in the memory of its longest episode.
Messages are taken in receive order (``log_time``, then file order) through a window of
``WINDOW`` messages, as a recorder writes them (a file whose messages are further out of order
than that is cut in the order the window gives).  A recorder that falls behind takes an
episode's few events from their queue long before the values queued beside them, so receive
times alone would end an episode before most of its values: states go to their episode by sim
time (their stamps against the events' ``time``), stamped commands by the state they answer,
and values without a stamp (rewards, commands, effort arrays, exemplar indices) by their
publish time against the publish times of the start and end events (``Episode.sent_within``).
Commands without a stamp go with the states in order when there is one per state
(``Episode.settled``: the answer to the final state is dropped).

What the open episodes keep is bounded in bytes: each state or value costs about what it
takes (``KEPT_STATE``, ``KEPT_VALUE``); past ``limit`` bytes the cutter takes no more messages
and ``overflow`` says where it stopped (one line), the episodes so far are still reported.
``build_episodes`` cuts a list of messages at once (the same rules).
"""
from __future__ import annotations

import dataclasses
import heapq
from typing import Any, Callable

from sapga_ros.recording.episodes import (EPISODE_ROLES, Episode, event_ns, finite,
                                          stamp_ns, stamped_command, state_vector)
from sapga_ros.recording.events import EPISODE_END_EVENTS, event_episode, parse_event
from sapga_ros.recording.reader import DecodedMessage
from sapga_ros.recording.robot import RobotLayout

WINDOW = 4096               # messages reordered by receive time before they are cut
KEPT_STATE = 400            # [bytes] a kept state: its stamp, vector and dict entry, about
KEPT_VALUE = 100            # [bytes] a kept reward, command or exemplar index, about


def sent_ns(m: DecodedMessage) -> int:
    """When a message was sent: its publish time, or where a writer left that 0 (unknown),
    its receive time."""
    return m.publish_time if m.publish_time > 0 else m.log_time


class Cutter:
    """Episodes of the messages fed to it (see the module doc)."""

    def __init__(self, roles: dict[str, str], problem: Any, done: Callable[[Episode], None],
                 limit: float = float('inf'), window: int = WINDOW,
                 robot: RobotLayout | None = None) -> None:
        self.roles, self.problem, self.done = roles, problem, done
        self.robot = robot              # the states are a robot's, in its convention
        self.limit, self.window = limit, window
        self.kept = 0                   # [bytes] kept by the open episodes
        self.bad_events = 0
        self.overflow: str | None = None
        self._heap: list[tuple[int, int, DecodedMessage]] = []
        self._open: list[Episode] = []      # the newest episodes (at most three)
        self._orphans: list[tuple[int, Any]] = []   # states heard between episodes

    def feed(self, m: DecodedMessage) -> None:
        if self.roles.get(m.topic) not in EPISODE_ROLES or self.overflow:
            return
        m = dataclasses.replace(m, value=self._reduce(m))
        heapq.heappush(self._heap, (m.log_time, m.index, m))
        if len(self._heap) > self.window:
            self._take(heapq.heappop(self._heap)[2])

    def close(self) -> None:
        """Cut what is left and hand every open episode to ``done``."""
        while self._heap and not self.overflow:
            self._take(heapq.heappop(self._heap)[2])
        self._heap.clear()
        for ep in self._open:
            self.done(ep.settled())
        self._open.clear()

    def _current(self) -> Episode:
        """The newest episode (one of unknown number if the recording began inside it)."""
        if not self._open:
            self._open.append(Episode(None))
        return self._open[-1]

    def _keep(self, ep: Episode, cost: int, m: DecodedMessage) -> None:
        ep.kept += cost
        self.kept += cost
        if self.kept > self.limit:
            self.overflow = (f'message {m.index} ({m.topic}): the episodes read would take '
                             f'more than {int(self.limit)} bytes in memory; the rest is not '
                             'summarised')

    def _start(self, ep: Episode) -> None:
        self._open.append(ep)
        while len(self._open) > 2:      # states find their episode among the newest two
            old = self._open.pop(0)
            self.kept -= old.kept
            self.done(old.settled())

    def _reduce(self, m: DecodedMessage) -> Any:
        """What the cutting needs of a decoded message, taken before the message waits in
        the window: a few numbers (an event's fields), never the decoded message, whose
        strings and lists can take many times the bytes of its CDR."""
        role, v = self.roles[m.topic], m.value
        if role == 'event':
            return parse_event(getattr(v, 'data', None))
        if role == 'state':
            return stamp_ns(v), (self.robot.state(v) if self.robot is not None else
                                 state_vector(v, self.problem) if self.problem is not None
                                 else None)
        if role == 'command_stamped':
            return stamped_command(v, self.problem)
        if role == 'effort':        # a robot's effort array, held like ``command``
            return self.robot.action(v.data) if self.robot is not None else None
        return finite(v.data)

    def _take(self, m: DecodedMessage) -> None:
        """Cut one message, reduced (``_reduce``), in receive order."""
        role = self.roles[m.topic]
        if role == 'event':
            self._event(m)
            return
        if role == 'state':
            stamp, s = m.value
            home = next((ep for ep in reversed(self._open[-2:]) if ep.owns(stamp)), None)
            if home is None and not self._open:
                home = self._current()
            if home is not None:
                if stamp not in home.states:
                    self._keep(home, KEPT_STATE, m)
                home.add_state(stamp, s)
            elif self._open[-1].closed:
                self._orphans.append((stamp, s))
                self._keep(self._open[-1], KEPT_STATE, m)
            return
        if role == 'command_stamped':
            stamp, value = m.value
            ep = self._home(lambda e: e.owns(stamp) and (e.end_ns is None or stamp < e.end_ns))
            if ep is not None and value is not None:
                ep.commands.append((stamp, value + 0.0))
                self._keep(ep, KEPT_VALUE, m)
            return
        ep = self._home(lambda e: e.sent_within(sent_ns(m)))
        value = m.value
        if ep is None or value is None:
            return              # between episodes, or answering a final state: none's
        if role == 'reward':
            ep.rewards.append(value)
        elif role in ('command', 'effort'):     # held from the latest state on
            ep.held.append((ep.latest, value + 0.0))
        elif role == 'exemplar':
            ep.exemplars.append(int(value))
        self._keep(ep, KEPT_VALUE, m)

    def _home(self, owns: Callable[[Episode], bool]) -> Episode | None:
        """The episode a value goes to: the newer of the two newest that ``owns`` it, else
        the newest while it is open and began without a start event (a recording begun
        inside it), else none (a value of no episode, or of one no longer held)."""
        home = next((ep for ep in reversed(self._open[-2:]) if owns(ep)), None)
        current = self._current()
        if home is None and not current.closed and current.start_sent is None:
            home = current
        return home

    def _event(self, m: DecodedMessage) -> None:
        ev = m.value
        if ev is None:
            self.bad_events += 1
            return
        kind = ev.get('event')
        number = event_episode(ev)
        if kind == 'start':
            ep = Episode(number, start_ns=event_ns(ev), start_sent=sent_ns(m))
            self._start(ep)
            for stamp, s in self._orphans:
                if ep.owns(stamp):
                    ep.add_state(stamp, s)
            self._orphans.clear()
        elif kind in EPISODE_END_EVENTS and not self._current().closed:
            ep = self._current()
            ep.number = number if ep.number is None else ep.number
            ep.end, ep.end_event, ep.end_ns = kind, ev, event_ns(ev)
            ep.end_sent = sent_ns(m)
            if ep.end_ns is not None:   # an answer to the final state steps nothing in it
                ep.commands = [c for c in ep.commands if c[0] is None or c[0] < ep.end_ns]


def build_episodes(messages: list[DecodedMessage], roles: dict[str, str],
                   problem: Any, robot: RobotLayout | None = None
                   ) -> tuple[list[Episode], int]:
    """Cut the messages into episodes; returns (episodes, malformed events).

    Messages are taken in receive order.  States also carry their sim time, and events the
    sim time of their state ('time'), so a state that arrives just after its episode's end
    event (or just before the next start event) still goes to the episode it belongs to.
    """
    episodes: list[Episode] = []
    cutter = Cutter(roles, problem, episodes.append, window=len(messages) + 1, robot=robot)
    for m in messages:
        cutter.feed(m)
    cutter.close()
    return episodes, cutter.bad_events
