"""Episodes of a recording: its messages cut at ``episode_event`` messages.

Episodes are cut at ``episode_event`` messages (docs/ros_interface.md), all topics ordered by
receive time: an episode runs from its ``start`` event to its ``goal`` / ``step_limit`` /
``reset`` event; messages after that end and before the next start belong to no episode.
States also carry their sim time, and events the sim time of their state, so a state that
arrives just after its episode's end event still goes to its episode.  The state layout
(which JointState joint and field is which coordinate) comes from the problem.  Commands come
from ``command_stamped`` (each names the state it answers: its stamp) and from the hand-use
``command`` (held from the latest state heard), or from a robot's effort arrays (``robot.py``);
markers belong to no episode's numbers.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sapga_ros.errors import DataFileError
from sapga_ros.io.jsonfile import strict_loads
from sapga_ros.recording.events import MAX_EVENT_CHARS, ROLE_TYPES
from sim_nodes.problem_checks import DEFAULT_TOPICS
from sapga_ros.recording.reader import Recording, schema_type
from sapga_ros.recording.robot import effort_topic


@dataclass
class Episode:
    """What the recording holds of one episode."""

    number: int | None
    start_ns: int | None = None     # sim time of its first state (the start event's 'time')
    end_ns: int | None = None       # sim time of its last state (the end event's 'time')
    end: str = 'incomplete'         # goal | step_limit | end_stop | reset | incomplete
    end_event: dict[str, Any] | None = None
    rewards: list[float] = field(default_factory=list)
    states: dict[int, np.ndarray | None] = field(default_factory=dict)  # stamp [ns] -> state
    commands: list[tuple[int | None, float]] = field(default_factory=list)  # (state stamp, u)
    held: list[tuple[int | None, float]] = field(default_factory=list)  # unstamped, as heard
    exemplars: list[int] = field(default_factory=list)
    latest: int | None = None       # stamp of the latest state heard so far
    start_sent: int | None = None   # publish times [ns] of its start and end events
    end_sent: int | None = None
    kept: int = 0                   # [bytes] what its states and values take, about

    @property
    def closed(self) -> bool:
        return self.end != 'incomplete'

    def owns(self, stamp: int) -> bool:
        """Whether a state stamped ``stamp`` lies within this episode's sim-time span."""
        if self.closed and self.end_ns is None:
            return False
        return ((self.start_ns is None or stamp >= self.start_ns)
                and (self.end_ns is None or stamp <= self.end_ns))

    def settled(self) -> Episode:
        """This episode once nothing more joins it, its commands without a stamp (``held``:
        ``command``, effort arrays) among ``commands``.  Each was heard after the latest
        state the reader had then taken (its stamp), but a recorder that falls behind takes
        its queues unevenly; so when they are one per state (an answer to every state, as in
        lockstep), the k-th goes with the k-th state, and the answer to the final state,
        which stepped nothing, is dropped.  Otherwise (a command lost, or realtime) each
        keeps the latest state heard before it, and all count."""
        stamps = sorted(self.states)
        if len(stamps) and len(self.held) in (len(stamps) - 1, len(stamps)):
            held = [(t, v) for t, (_, v) in zip(stamps[:-1], self.held)]
        else:       # not one per state: each at the latest state heard before it
            held = self.held
        if held:
            self.commands = sorted(self.commands + held,
                                   key=lambda c: -1 if c[0] is None else c[0])
        self.held = []
        return self

    def sent_within(self, sent: int) -> bool:
        """Whether a value without a stamp (reward, command, exemplar index) published at
        ``sent`` was published between this episode's start and end events (the publishers'
        clock: a recorder that falls behind receives the values of an episode after its end
        event, though never before their publishers sent them)."""
        if self.start_sent is None and self.end_sent is None:
            return not self.closed
        return ((self.start_sent is None or sent >= self.start_sent)
                and (self.end_sent is None or sent <= self.end_sent))

    def add_state(self, stamp: int, s: np.ndarray | None) -> None:
        if stamp not in self.states:        # lockstep re-publishes repeat a stamp
            self.states[stamp] = s
            self.latest = stamp if self.latest is None else max(self.latest, stamp)

    def trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps [ns], states) of the states with a known layout, in sim-time order."""
        stamps = sorted(t for t, s in self.states.items() if s is not None)
        if not stamps:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 0))
        return np.array(stamps, dtype=np.int64), np.vstack([self.states[t] for t in stamps])


def finite(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _json_number(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


# the roles an episode is made of (markers are for viewers); effort: a robot's effort array
EPISODE_ROLES = ('state', 'command', 'command_stamped', 'reward', 'event', 'exemplar',
                 'effort')


def topic_roles(rec: Recording, problem: Any) -> dict[str, str]:
    """topic -> role (state, command, reward, event, exemplar; effort: the one effort-array
    topic a robot takes, ``robot.effort_topic``) of the recorded topics."""
    types = {name: schema_type(t) for name, t in rec.topics.items()}
    effort = effort_topic(types)
    roles: dict[str, str] = {effort: 'effort'} if effort is not None else {}
    try:
        meta_topics = strict_loads(rec.metadata.get('topics', '{}')[:MAX_EVENT_CHARS], 'topics')
    except (DataFileError, TypeError):
        meta_topics = {}
    if isinstance(meta_topics, dict):
        for role, topic in meta_topics.items():
            if role in ROLE_TYPES and types.get(topic) == ROLE_TYPES[role]:
                roles[topic] = role
    if len(roles) > (effort is not None):
        return roles
    names = dict(DEFAULT_TOPICS)
    if problem is not None and isinstance(problem.ros.get('topics'), dict):
        names.update(problem.ros['topics'])
    for topic, type_name in types.items():
        base = topic.rstrip('/').rsplit('/', 1)[-1]
        for role, name in names.items():
            if base == str(name).rsplit('/', 1)[-1] and type_name == ROLE_TYPES[role]:
                roles[topic] = role
    return roles


def state_vector(msg: Any, problem: Any) -> np.ndarray | None:
    """The problem's state vector from a JointState, or None if a coordinate is missing."""
    names = list(msg.name)
    out = np.empty(problem.dim)
    for i, c in enumerate(problem.state):
        if c.joint not in names:
            return None
        values = msg.position if c.field == 'position' else msg.velocity
        j = names.index(c.joint)
        if j >= len(values):
            return None
        out[i] = float(values[j])
    return out if np.all(np.isfinite(out)) else None


def event_ns(ev: dict[str, Any]) -> int | None:
    t = finite(ev.get('time'))
    t = None if t is None else finite(t * 1e9)      # 1e300 s: no time
    return None if t is None else int(round(t))


def stamp_ns(msg: Any) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def stamped_command(msg: Any, problem: Any) -> tuple[int, float | None]:
    """(answered state's stamp [ns], value) of a ``command_stamped`` JointState: the effort of
    the problem's actuator joint (the only effort when the problem is unknown); value None
    when there is none or it is not finite."""
    names, effort = list(msg.name), list(msg.effort)
    joint = problem.actuator_joint if problem is not None else None
    if joint in names and names.index(joint) < len(effort):
        value = effort[names.index(joint)]
    else:
        value = effort[0] if joint is None and len(effort) == 1 else None
    return stamp_ns(msg), finite(value)


def episode_summary(ep: Episode, problem: Any, goal_delta: float | None) -> dict[str, Any]:
    """One episode as a JSON-ready dict."""
    ev = ep.end_event or {}
    ret_rewards = float(np.sum(ep.rewards)) if ep.rewards else None
    delta_states = None
    _, states = ep.trajectory()
    if problem is not None and len(states):
        from sim_nodes.goal import delta_of
        delta_states = min(delta_of(problem, s) for s in states)
    steps = ev.get('step') if isinstance(ev.get('step'), int) else None
    if steps is None and ep.rewards:
        steps = len(ep.rewards)
    ret = finite(ev.get('return'))
    ret = ret if ret is not None else ret_rewards
    delta_star = finite(ev.get('delta_star'))    # absent from the event: from the states
    if delta_star is None and 'delta_star' not in ev:
        delta_star = delta_states
    gd = finite(ev.get('goal_delta'))             # 0 is a goal delta, not "none given"
    gd = goal_delta if gd is None else gd
    actions = Counter(v for _, v in ep.commands)
    return {
        'episode': ep.number, 'end': ep.end, 'steps': steps,
        'return': _json_number(ret),
        'delta_star': _json_number(delta_star), 'goal_delta': _json_number(gd),
        'reached_goal': ep.end == 'goal',
        'steps_to_goal': steps if ep.end == 'goal' else None,
        'achieved': bool(delta_star is not None and gd is not None and delta_star <= gd),
        'actions': {_action_key(v): n for v, n in sorted(actions.items())},
        'exemplars_used': len(set(ep.exemplars)),
        'messages': {'states': len(ep.states), 'rewards': len(ep.rewards),
                     'commands': len(ep.commands)},
        'final_delta': _json_number(finite(ev.get('delta'))),
        'late_commands': ev.get('late_commands') if isinstance(ev.get('late_commands'), int)
        and not isinstance(ev.get('late_commands'), bool) else None,
        'return_from_rewards': _json_number(ret_rewards),
        'delta_star_from_states': _json_number(delta_states),
        **(_event_hold(ev) or _hold(ep, problem, states, gd)),
    }


def _event_hold(ev: dict) -> dict[str, Any] | None:
    """The hold measures the simulator put in the end event (computed on the true state:
    the recorded states carry any sensor noise, and a robot's own joint convention), or None
    when the event lacks them or they are not what the simulator writes."""
    first, fraction, contacts = (ev.get(k) for k in ('first_entry_step', 'hold_fraction',
                                                     'rail_contacts'))

    def count(x: Any) -> bool:
        return isinstance(x, int) and not isinstance(x, bool) and x >= 0

    if not (first is None or count(first)) or not count(contacts) or isinstance(
            fraction, bool) or not isinstance(fraction, (int, float)) or not (
            0.0 <= fraction <= 1.0):          # NaN fails the comparison
        return None
    return {'first_entry_step': first, 'hold_fraction': float(fraction),
            'rail_contacts': contacts}


def _hold(ep: Episode, problem: Any, states: np.ndarray, gd: float | None) -> dict[str, Any]:
    """The hold measures from the recorded states and rewards (None without a layout): for
    recordings whose end events do not carry them."""
    if problem is None or gd is None or not len(states):
        return {'first_entry_step': None, 'hold_fraction': None, 'rail_contacts': None}
    from sim_nodes.goal import trace_hold
    return trace_hold(problem, states, ep.rewards, gd)


def _action_key(v: float) -> str:
    return f'{v:g}'
