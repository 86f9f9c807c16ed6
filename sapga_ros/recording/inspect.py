"""``sapga inspect``'s summary of a recording (a bag directory or one MCAP file).

Reads with ``reader.py`` and the ``mcap_ros2`` decoder (no ROS graph) and reports the
topics and message counts and, per episode (``episodes.py``), the return, delta*,
steps to the goal (or that it was not reached) and how often each action was commanded.
The numbers the simulator put in the end event (return, step, delta_star) are reported; the
same quantities recomputed from the recorded rewards and states are reported beside them
(``return_from_rewards``, ``delta_star_from_states``).  The problem is the one named in the
bag's metadata (or the JointState ``frame_id``).  A recording cut short by a hard kill is
summarised as far as it can be read (``complete`` false, ``error`` says where it ends).

``inspect_path`` streams: a first pass counts the messages and finds the metadata (a single
file's ``sapga`` record is written last), a second decodes the episode topics and cuts them
(``cutter.py``), one episode summarised as soon as it is complete; no pass keeps the
messages, so the memory is that of a chunk and of the longest episode, whatever the count.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from sapga_ros.errors import ConfigError, McapError
from sapga_ros.recording.chunks import BUDGET_FLOOR, BUDGET_RATIO
from sapga_ros.recording.cutter import Cutter
from sapga_ros.recording.episodes import EPISODE_ROLES, Episode, episode_summary, finite, \
    topic_roles
from sapga_ros.recording.events import ROLE_TYPES, parse_event
from sapga_ros.recording.reader import (Decoder, RecordedMessage, Recording, Sink,
                                        read_recording, schema_type)
from sapga_ros.recording.robot import RobotLayout
from sapga_ros.recording.schemas import cdr_string

EPISODE_MESSAGE_BYTES = 1 << 20     # [bytes] of CDR: a robot's JointState takes some 100s
Replay = Callable[[Sink], None]      # pushes every message of the recording, in file order


def _load_problem(name: str | None) -> tuple[Any, str | None]:
    if not name:
        return None, 'no problem named in the file'
    from sim_nodes.problem import load_problem
    try:
        return load_problem(name), None
    except ConfigError as exc:
        return None, str(exc)


@dataclass
class Scan:
    """What the first pass keeps: counts, times, each topic's first message."""

    count: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    first: dict[str, tuple[int, RecordedMessage]] = field(default_factory=dict)
    start: int | None = None
    end: int | None = None

    def add(self, m: RecordedMessage) -> None:
        if m.topic not in self.first:
            self.first[m.topic] = (self.count, m)
        self.counts[m.topic] = self.counts.get(m.topic, 0) + 1
        self.count += 1
        self.start = m.log_time if self.start is None else min(self.start, m.log_time)
        self.end = m.log_time if self.end is None else max(self.end, m.log_time)


def _robot(scan: Scan, roles: dict[str, str], problem: Any) -> RobotLayout | None:
    """The MuJoCo robot's layout when the recording was made on it: its first episode event
    names engine mujoco, or (a simulator that does not name its engine) it holds a robot's
    effort array; None otherwise, or for a problem without a MuJoCo robot."""
    events = [t for t, r in roles.items() if r == 'event' and t in scan.first]
    ev = parse_event(cdr_string(scan.first[events[0]][1].data)) if events else None
    engine = ev.get('engine') if ev is not None else None
    if engine is None:
        engine = 'mujoco' if 'effort' in roles.values() else 'kernel'
    return RobotLayout.of(problem) if engine == 'mujoco' else None


def _problem_name(rec: Recording, scan: Scan) -> str | None:
    """The problem named in the metadata, else the first JointState's frame_id."""
    name = rec.metadata.get('problem')
    if name:
        return name
    states = [scan.first[t] for t, info in rec.topics.items()
              if t in scan.first and schema_type(info) == ROLE_TYPES['state']]
    if not states:
        return None
    i, m = min(states, key=lambda x: x[0])
    decoded = Decoder(rec.topics)(i, m)
    return (decoded.value.header.frame_id or None) if decoded is not None else None


class Picker:
    """The episode to plot, chosen as episodes go by: number ``number`` (the first of it
    with 2 or more states), else the one of the highest return (the first of equals)."""

    def __init__(self, number: int | None) -> None:
        self.number = number
        self.best: tuple[Episode, dict] | None = None
        self._key: tuple = ()

    def offer(self, ep: Episode, summary: dict) -> None:
        if len(ep.trajectory()[0]) < 2:
            return
        if self.number is not None:
            if ep.number == self.number and self.best is None:
                self.best = ep, summary
            return
        key = (summary['return'] is not None, summary['return'] or 0.0)
        if self.best is None or key > self._key:
            self.best, self._key = (ep, summary), key

    def chosen(self) -> tuple[Episode, dict]:
        if self.best is None:
            raise McapError(f'episode {self.number}: not in the recording, or fewer than 2 '
                            'states' if self.number is not None else
                            'nothing to plot: no episode with 2 or more states')
        return self.best


def summarize(rec: Recording, scan: Scan | None = None, replay: Replay | None = None,
              picker: Picker | None = None) -> tuple[dict[str, Any], list[Episode], Any]:
    """The summary dict of a recording, its episodes and its problem (None if unknown).

    ``rec`` holds the messages, or ``scan`` counts them and ``replay`` pushes them again;
    then no episode is kept (the list is empty) but the one ``picker`` chooses."""
    if scan is None:
        scan = Scan()
        for m in rec.messages:
            scan.add(m)
    if replay is None:
        replay = lambda sink: [sink(m) for m in rec.messages]  # noqa: E731
    kept: list[Episode] = []
    meta = rec.metadata
    problem_name = _problem_name(rec, scan)
    problem, problem_error = _load_problem(problem_name)
    roles = topic_roles(rec, problem)
    goal_delta = finite(meta.get('delta'))
    if problem is not None:
        goal_delta = problem.resolve('delta', goal_delta)
    summaries: list[dict] = []

    def done(ep: Episode) -> None:
        summaries.append(episode_summary(ep, problem, goal_delta))
        if picker is not None:
            picker.offer(ep, summaries[-1])
        if rec.messages:            # held in memory: the caller may want them all
            kept.append(ep)
    robot = _robot(scan, roles, problem)
    cutter = Cutter(roles, problem, done, limit=BUDGET_FLOOR + BUDGET_RATIO * rec.size,
                    robot=robot)
    decode = Decoder(rec.topics, [t for t, r in roles.items() if r in EPISODE_ROLES],
                     max_bytes=EPISODE_MESSAGE_BYTES)
    index = [0]

    def sink(m: RecordedMessage) -> None:
        i = index[0]
        index[0] += 1
        if i < scan.count and (d := decode(i, m)) is not None:
            cutter.feed(d)
    replay(sink)
    cutter.close()
    summary = {
        'file': rec.path, 'bag': rec.is_bag, 'bytes': rec.size,
        'complete': rec.complete and not cutter.overflow,
        'error': rec.error or cutter.overflow,
        'profile': rec.files[0].profile if rec.files else '',
        'library': rec.files[0].library if rec.files else '',
        'storage_files': [{'path': f.path, 'bytes': f.size, 'messages': f.message_count,
                           'complete': f.complete, 'error': f.error} for f in rec.files],
        'problem': problem_name, 'problem_error': problem_error,
        'robot_joints': robot is not None,
        'goal_delta': goal_delta,
        'message_count': scan.count,
        'start_time_ns': scan.start, 'end_time_ns': scan.end,
        'duration_s': (scan.end - scan.start) * 1e-9 if scan.count else 0.0,
        'topics': [{'topic': name, 'type': t.type, 'count': scan.counts.get(name, 0),
                    'role': roles.get(name), 'message_encoding': t.message_encoding,
                    'schema_encoding': t.schema.encoding if t.schema else ''}
                   for name, t in rec.topics.items()],
        'undecodable_topics': decode.failed,
        'malformed_events': cutter.bad_events,
        'episodes': summaries,
        'metadata': meta,
    }
    summary['episodes_reaching_goal'] = sum(e['reached_goal'] for e in summaries)
    returns = [e['return'] for e in summaries if e['return'] is not None]
    summary['best_return'] = max(returns) if returns else None
    return summary, kept, problem


def inspect_path(path: str, picker: Picker | None = None
                 ) -> tuple[dict[str, Any], Recording, Any]:
    """(summary, recording without its messages, problem) of the recording at ``path``,
    streamed in two passes (see the module doc); McapError if nothing can be read."""
    scan = Scan()
    rec = read_recording(path, sink=scan.add)
    summary, _, problem = summarize(rec, scan, lambda sink: read_recording(path, sink=sink),
                                    picker)
    return summary, rec, problem


def fmt(x: Any, spec: str) -> str:
    return '-' if x is None else format(x, spec)


def format_summary(s: dict[str, Any]) -> str:
    """The summary as text for a terminal."""
    state = 'complete' if s['complete'] else 'INCOMPLETE'
    kind = f'rosbag2 bag, {len(s["storage_files"])} storage file(s)' if s['bag'] else 'file'
    lines = [f'{"bag:" if s["bag"] else "file:":<11}{s["file"]} ({kind}, {s["bytes"]} bytes, '
             f'{state})',
             f'profile:   {s["profile"] or "-"}   library: {s["library"] or "-"}',
             f'problem:   {s["problem"] or "unknown"}   goal delta: {fmt(s["goal_delta"], "g")}',
             f'messages:  {s["message_count"]} over {s["duration_s"]:.2f} s']
    if s['problem_error']:
        lines.append(f'note:      {s["problem_error"]}')
    if s.get('robot_joints'):
        lines.append('states:    the MuJoCo robot\'s joints, read in the problem\'s convention; '
                     'commands: its effort arrays')
    lines.append('topics:')
    width = max([len(t['topic']) for t in s['topics']] + [5])
    type_width = max([len(t['type']) for t in s['topics']] + [28])
    for t in s['topics']:
        lines.append(f'  {t["topic"]:<{width}}  {t["type"]:<{type_width}} {t["count"]:>8}')
    for topic, why in s['undecodable_topics'].items():
        lines.append(f'  {topic}: not decoded ({why})')
    if s['malformed_events']:
        lines.append(f'  {s["malformed_events"]} episode_event messages are not JSON objects')
    lines.append(f'episodes:  {len(s["episodes"])} ({s["episodes_reaching_goal"]} reached the '
                 'goal)')
    if s['episodes']:
        lines.append(f'  {"#":>4} {"end":<10} {"steps":>6} {"return":>10} {"delta*":>9} '
                     f'{"to goal":>11} {"1st in":>6} {"hold":>6} {"rail":>4}  actions')
        for e in s['episodes']:
            actions = ' '.join(f'{k}:{n}' for k, n in e['actions'].items()) or '-'
            to_goal = e['steps_to_goal'] if e['reached_goal'] else 'not reached'
            lines.append(f'  {fmt(e["episode"], "d"):>4} {e["end"]:<10} '
                         f'{fmt(e["steps"], "d"):>6} {fmt(e["return"], ".2f"):>10} '
                         f'{fmt(e["delta_star"], ".4f"):>9} {to_goal!s:>11} '
                         f'{fmt(e["first_entry_step"], "d"):>6} '
                         f'{fmt(e["hold_fraction"], ".4f"):>6} {fmt(e["rail_contacts"], "d"):>4}'
                         f'  {actions}')
    return '\n'.join(lines)
