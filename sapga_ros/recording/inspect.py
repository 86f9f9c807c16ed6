"""``sapga inspect FILE.mcap [--json] [--plot OUT.png] [--episode N]``: summarise a recording.

Reads the file with the ``mcap`` library and the ``mcap_ros2`` decoder (no ROS graph) and
reports its topics and message counts and, per episode, the return, delta* (SPEC 2), steps to
the goal (or that it was not reached) and how often each action was commanded.  ``--plot``
draws one episode like the paper's Figures 6 and 7: angles, velocities and the command over
time, and a stroboscopic picture of the pendulum (acrobot: two links from the shoulder;
PDIP: the cart and its two poles).

Episodes are cut at ``episode_event`` messages (docs/ros_interface.md), all topics ordered by
receive time: an episode runs from its ``start`` event to its ``goal`` / ``step_limit`` /
``reset`` event; messages after that end and before the next start belong to no episode.
The numbers the simulator put in the end event (return, step, delta_star) are reported; the
same quantities recomputed from the recorded rewards and states are reported beside them
(``return_from_rewards``, ``delta_star_from_states``).  The state layout (which JointState
joint and field is which state coordinate) comes from ``msg_configs/<problem>.yaml``, the
problem being named in the file's ``sapga`` metadata (or the JointState ``frame_id``).

A file cut short by a hard kill is summarised as far as it can be read, with a warning; a
file that cannot be read at all gives a one-line error and exit status 1.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sapga_ros.errors import ConfigError, McapError, SapgaError
from sapga_ros.recording.mcap_io import (DEFAULT_ROLE_TOPICS, ROLE_TYPES, DecodedMessage,
                                         Recording, decode_messages, full_type_name, parse_event,
                                         read_recording)

END_EVENTS = ('goal', 'step_limit', 'reset')


@dataclass
class Episode:
    """What the recording holds of one episode."""

    number: int | None
    start_ns: int | None = None     # sim time of its first state (the start event's 'time')
    end_ns: int | None = None       # sim time of its last state (the end event's 'time')
    end: str = 'incomplete'         # goal | step_limit | reset | incomplete
    end_event: dict[str, Any] | None = None
    rewards: list[float] = field(default_factory=list)
    states: dict[int, np.ndarray | None] = field(default_factory=dict)  # stamp [ns] -> state
    commands: list[tuple[int | None, float]] = field(default_factory=list)  # (state stamp, u)
    exemplars: list[int] = field(default_factory=list)
    latest: int | None = None       # stamp of the latest state heard so far

    @property
    def closed(self) -> bool:
        return self.end != 'incomplete'

    def owns(self, stamp: int) -> bool:
        """Whether a state stamped ``stamp`` lies within this episode's sim-time span."""
        if self.closed and self.end_ns is None:
            return False
        return ((self.start_ns is None or stamp >= self.start_ns)
                and (self.end_ns is None or stamp <= self.end_ns))

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


def _finite(value: Any) -> float | None:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _json_number(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _load_problem(name: str | None) -> tuple[Any, str | None]:
    if not name:
        return None, 'no problem named in the file'
    from sim_nodes.problem import load_problem
    try:
        return load_problem(name), None
    except ConfigError as exc:
        return None, str(exc)


def schema_type(rec: Recording, channel_id: int) -> str:
    """The channel's message type as 'pkg/msg/Type' ('' without a schema)."""
    schema = rec.schemas.get(rec.channels[channel_id].schema_id)
    if schema is None:
        return ''
    try:
        return full_type_name(schema.name)
    except McapError:
        return schema.name


def topic_roles(rec: Recording, problem: Any) -> dict[str, str]:
    """topic → role (state, command, reward, event, exemplar) of the recorded channels."""
    types = {c.topic: schema_type(rec, c.id) for c in rec.channels.values()}
    roles: dict[str, str] = {}
    try:
        meta_topics = json.loads(rec.metadata.get('sapga', {}).get('topics', '{}'))
    except ValueError:
        meta_topics = {}
    if isinstance(meta_topics, dict):
        for role, topic in meta_topics.items():
            if role in ROLE_TYPES and types.get(topic) == ROLE_TYPES[role]:
                roles[topic] = role
    if roles:
        return roles
    names = dict(DEFAULT_ROLE_TOPICS)
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


def _event_ns(ev: dict[str, Any]) -> int | None:
    t = _finite(ev.get('time'))
    return None if t is None else int(round(t * 1e9))


def _stamp_ns(msg: Any) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def build_episodes(messages: list[DecodedMessage], roles: dict[str, str],
                   problem: Any) -> tuple[list[Episode], int]:
    """Cut the messages into episodes; returns (episodes, malformed events).

    Messages are taken in receive order.  States also carry their sim time, and events the
    sim time of their state ('time'), so a state that arrives just after its episode's end
    event (or just before the next start event) still goes to the episode it belongs to.
    """
    timeline = sorted((m for m in messages if m.topic in roles),
                      key=lambda m: (m.log_time, m.index))
    episodes: list[Episode] = []
    orphans: list[tuple[int, np.ndarray | None]] = []   # states heard between episodes
    bad_events = 0

    def current() -> Episode | None:
        return episodes[-1] if episodes else None

    def open_episode() -> Episode:
        ep = current()
        if ep is None:          # the recording began inside an episode
            ep = Episode(None)
            episodes.append(ep)
        return ep

    for m in timeline:
        role = roles[m.topic]
        if role == 'event':
            ev = parse_event(getattr(m.value, 'data', None))
            if ev is None:
                bad_events += 1
                continue
            kind = ev.get('event')
            number = ev.get('episode') if isinstance(ev.get('episode'), int) else None
            if kind == 'start':
                ep = Episode(number, start_ns=_event_ns(ev))
                episodes.append(ep)
                for stamp, s in orphans:
                    if ep.owns(stamp):
                        ep.add_state(stamp, s)
                orphans.clear()
            elif kind in END_EVENTS and not open_episode().closed:
                ep = open_episode()
                ep.number = number if ep.number is None else ep.number
                ep.end, ep.end_event, ep.end_ns = kind, ev, _event_ns(ev)
            continue
        if role == 'state':
            stamp = _stamp_ns(m.value)
            s = state_vector(m.value, problem) if problem is not None else None
            home = next((ep for ep in reversed(episodes[-2:]) if ep.owns(stamp)), None)
            if home is not None:
                home.add_state(stamp, s)
            elif not episodes:
                open_episode().add_state(stamp, s)
            elif episodes[-1].closed:
                orphans.append((stamp, s))
            continue
        ep = open_episode()
        if ep.closed:
            continue            # between episodes: belongs to none
        value = _finite(m.value.data)
        if value is None:
            continue
        if role == 'reward':
            ep.rewards.append(value)
        elif role == 'command':     # held from the latest state on (zero-order hold)
            ep.commands.append((ep.latest, value + 0.0))
        elif role == 'exemplar':
            ep.exemplars.append(int(value))
    return episodes, bad_events


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
    ret = _finite(ev.get('return'))
    ret = ret if ret is not None else ret_rewards
    delta_star = _finite(ev.get('delta_star'))    # absent from the event: from the states
    if delta_star is None and 'delta_star' not in ev:
        delta_star = delta_states
    gd = _finite(ev.get('goal_delta')) or goal_delta
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
        'final_delta': _json_number(_finite(ev.get('delta'))),
        'return_from_rewards': _json_number(ret_rewards),
        'delta_star_from_states': _json_number(delta_states),
    }


def _action_key(v: float) -> str:
    return f'{v:g}'


def _first_messages(rec: Recording, topics: set[str]) -> Recording:
    """A view of ``rec`` holding only the first message on any of ``topics``."""
    first = [m for m in rec.messages if rec.channels[m.channel_id].topic in topics][:1]
    return Recording(path=rec.path, schemas=rec.schemas, channels=rec.channels, messages=first)


def summarize(rec: Recording) -> tuple[dict[str, Any], list[Episode], Any]:
    """The summary dict of a recording, its episodes and its problem (None if unknown)."""
    meta = rec.metadata.get('sapga', {})
    problem_name = meta.get('problem')
    if not problem_name:        # fall back on the JointState frame_id
        states = {c.topic for c in rec.channels.values()
                  if schema_type(rec, c.id) == ROLE_TYPES['state']}
        for m in decode_messages(_first_messages(rec, states), states)[0][:1]:
            problem_name = m.value.header.frame_id or None
    problem, problem_error = _load_problem(problem_name)
    roles = topic_roles(rec, problem)
    messages, failed = decode_messages(rec, roles)
    episodes, bad_events = build_episodes(messages, roles, problem)
    goal_delta = _finite(meta.get('delta'))
    if goal_delta is None and problem is not None:
        goal_delta = problem.default_delta
    counts = rec.topic_counts()
    topics = []
    for cid, c in sorted(rec.channels.items()):
        schema = rec.schemas.get(c.schema_id)
        topics.append({'topic': c.topic, 'type': schema.name if schema else '',
                       'count': counts.get(cid, 0), 'role': roles.get(c.topic),
                       'message_encoding': c.message_encoding,
                       'schema_encoding': schema.encoding if schema else ''})
    times = [m.log_time for m in rec.messages]
    summary = {
        'file': rec.path, 'bytes': rec.size, 'complete': rec.complete, 'error': rec.error,
        'profile': rec.profile, 'library': rec.library,
        'problem': problem_name, 'problem_error': problem_error,
        'goal_delta': goal_delta,
        'message_count': len(rec.messages),
        'start_time_ns': min(times) if times else None,
        'end_time_ns': max(times) if times else None,
        'duration_s': (max(times) - min(times)) * 1e-9 if times else 0.0,
        'topics': topics,
        'undecodable_topics': failed,
        'malformed_events': bad_events,
        'episodes': [episode_summary(ep, problem, goal_delta) for ep in episodes],
        'metadata': rec.metadata,
    }
    eps = summary['episodes']
    summary['episodes_reaching_goal'] = sum(e['reached_goal'] for e in eps)
    returns = [e['return'] for e in eps if e['return'] is not None]
    summary['best_return'] = max(returns) if returns else None
    return summary, episodes, problem


def _fmt(x: Any, spec: str) -> str:
    return '-' if x is None else format(x, spec)


def format_summary(s: dict[str, Any]) -> str:
    """The summary as text for a terminal."""
    state = 'complete' if s['complete'] else 'INCOMPLETE'
    lines = [f'file:      {s["file"]} ({s["bytes"]} bytes, {state})',
             f'profile:   {s["profile"] or "-"}   library: {s["library"] or "-"}',
             f'problem:   {s["problem"] or "unknown"}   goal delta: {_fmt(s["goal_delta"], "g")}',
             f'messages:  {s["message_count"]} over {s["duration_s"]:.2f} s']
    if s['problem_error']:
        lines.append(f'note:      {s["problem_error"]}')
    lines.append('topics:')
    width = max([len(t['topic']) for t in s['topics']] + [5])
    for t in s['topics']:
        lines.append(f'  {t["topic"]:<{width}}  {t["type"]:<28} {t["count"]:>8}')
    for topic, why in s['undecodable_topics'].items():
        lines.append(f'  {topic}: not decoded ({why})')
    if s['malformed_events']:
        lines.append(f'  {s["malformed_events"]} episode_event messages are not JSON objects')
    lines.append(f'episodes:  {len(s["episodes"])} ({s["episodes_reaching_goal"]} reached the '
                 'goal)')
    if s['episodes']:
        lines.append(f'  {"#":>4} {"end":<10} {"steps":>6} {"return":>10} {"delta*":>9} '
                     f'{"to goal":>11}  actions')
        for e in s['episodes']:
            actions = ' '.join(f'{k}:{n}' for k, n in e['actions'].items()) or '-'
            to_goal = e['steps_to_goal'] if e['reached_goal'] else 'not reached'
            lines.append(f'  {_fmt(e["episode"], "d"):>4} {e["end"]:<10} '
                         f'{_fmt(e["steps"], "d"):>6} {_fmt(e["return"], ".2f"):>10} '
                         f'{_fmt(e["delta_star"], ".4f"):>9} {to_goal!s:>11}  {actions}')
    return '\n'.join(lines)


def _pick_episode(episodes: list[Episode], summaries: list[dict], number: int | None) -> int:
    candidates = [i for i, ep in enumerate(episodes) if len(ep.trajectory()[0]) >= 2]
    if number is not None:
        for i in candidates:
            if episodes[i].number == number:
                return i
        raise McapError(f'episode {number}: not in the recording, or fewer than 2 states')
    if not candidates:
        raise McapError('nothing to plot: no episode with 2 or more states')
    return max(candidates, key=lambda i: (summaries[i]['return'] is not None,
                                          summaries[i]['return'] or 0.0, -i))


def plot_episode(ep: Episode, problem: Any, out_path: str, title: str) -> None:
    """Angles, velocities, command over time and a stroboscopic picture, to a PNG file."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    stamps, x = ep.trajectory()
    t = (stamps - stamps[0]) * 1e-9
    coords = list(problem.state)
    groups = [('angle [rad]', [i for i, c in enumerate(coords) if c.angle]),
              ('position [m]', [i for i, c in enumerate(coords)
                                if not c.angle and c.field == 'position']),
              ('velocity', [i for i, c in enumerate(coords) if c.field == 'velocity'])]
    groups = [g for g in groups if g[1]]
    rows = len(groups) + 1
    fig = plt.figure(figsize=(12, 2.2 * rows + 0.6))
    grid = fig.add_gridspec(rows, 2, width_ratios=[1.6, 1.0])
    ax = None
    for r, (label, idx) in enumerate(groups):
        ax = fig.add_subplot(grid[r, 0], sharex=ax)
        for i in idx:
            ax.plot(t, x[:, i], label=f'{coords[i].name} [{coords[i].unit}]')
        ax.set_ylabel(label)
        ax.legend(loc='upper right', fontsize='small')
        ax.grid(alpha=0.3)
    ax = fig.add_subplot(grid[rows - 1, 0], sharex=ax)
    if ep.commands:
        ct = [((stamp if stamp is not None else stamps[0]) - stamps[0]) * 1e-9
              for stamp, _ in ep.commands]
        ax.step(ct, [u for _, u in ep.commands], where='post', color='k')
    ax.set_ylabel('command')
    ax.set_xlabel('time [s]')
    ax.grid(alpha=0.3)
    strobe = fig.add_subplot(grid[:, 1])
    _draw_strobe(strobe, problem, x)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out_path, dpi=100)
    plt.close(fig)


def _draw_strobe(ax: Any, problem: Any, x: np.ndarray) -> None:
    from matplotlib import colormaps
    from matplotlib.patches import Rectangle

    names = list(problem.state_names)
    ph = problem.physics
    frames = np.unique(np.linspace(0, len(x) - 1, min(len(x), 30)).astype(int))
    cmap = colormaps['viridis']
    for k, i in enumerate(frames):
        color = cmap(k / max(len(frames) - 1, 1))
        alpha = 0.25 + 0.75 * k / max(len(frames) - 1, 1)
        s = dict(zip(names, x[i]))
        if problem.model == 'acrobot':
            l1, l2 = ph.get('l1', 1.0), ph.get('l2', ph.get('l1', 1.0))
            th1, th2 = s['theta1'], s['theta1'] + s['theta2']
            px = [0.0, l1 * math.cos(th1), l1 * math.cos(th1) + l2 * math.cos(th2)]
            py = [0.0, l1 * math.sin(th1), l1 * math.sin(th1) + l2 * math.sin(th2)]
            ax.plot(px, py, '-o', color=color, alpha=alpha, lw=2, ms=3)
        elif problem.model == 'pdip':
            cx = s.get('x', 0.0)
            ax.add_patch(Rectangle((cx - 0.2, -0.1), 0.4, 0.2, fill=False, color=color,
                                   alpha=alpha))
            for pole, length, lw in (('theta1', ph.get('l1', 1.0), 2.5),
                                     ('theta2', ph.get('l2', 0.5), 1.2)):
                if pole in s:
                    ax.plot([cx, cx + length * math.cos(s[pole])],
                            [0.0, length * math.sin(s[pole])], '-', color=color,
                            alpha=alpha, lw=lw)
        else:
            ax.text(0.5, 0.5, f'no picture for model {problem.model!r}',
                    transform=ax.transAxes, ha='center')
            return
    if problem.model == 'pdip':
        xm = ph.get('x_max', 2.5)
        ax.plot([-xm, xm], [0, 0], color='0.5', lw=1)
    ax.set_aspect('equal')
    ax.set_title(f'{len(frames)} frames, purple (start) to yellow (end)', fontsize='small')
    ax.grid(alpha=0.3)


def run_inspect(path: str, json_out: bool = False, plot: str | None = None,
                episode: int | None = None) -> int:
    """Print the summary of one recording (text or one JSON object); 0 on success.

    A truncated file is summarised as far as it can be read, with a warning on stderr; an
    unreadable one prints a one-line error on stderr and returns 1.
    """
    try:
        rec = read_recording(path)
        try:
            summary, episodes, problem = summarize(rec)
        except Exception as exc:  # noqa: BLE001 - no file content may crash the CLI
            raise McapError(f'{path}: messages do not match their roles '
                            f'({type(exc).__name__}: {exc})') from exc
        if rec.error:
            print(f'warning: {rec.error}; summarising the {len(rec.messages)} messages read',
                  file=sys.stderr)
        if plot:
            if problem is None:
                raise McapError(f'{path}: cannot plot: {summary["problem_error"]}')
            i = _pick_episode(episodes, summary['episodes'], episode)
            ep = summary['episodes'][i]
            title = (f'{problem.name}: episode {_fmt(ep["episode"], "d")}, {ep["end"]}, '
                     f'return {_fmt(ep["return"], ".2f")}, delta* '
                     f'{_fmt(ep["delta_star"], ".4f")}')
            try:
                plot_episode(episodes[i], problem, plot, title)
            except OSError as exc:
                raise McapError(f'{plot}: cannot write the plot ({exc.strerror})') from exc
            summary['plot'] = {'file': plot, 'episode': ep['episode']}
    except SapgaError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    if json_out:
        print(json.dumps(summary, allow_nan=False, default=str))
    else:
        print(format_summary(summary))
        if plot:
            print(f'plot:      {plot} (episode {_fmt(summary["plot"]["episode"], "d")})')
    return 0


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """The ``sapga inspect`` arguments (added to ``parser`` if one is given)."""
    parser = parser or argparse.ArgumentParser(
        prog='sapga inspect', description='Summarise an MCAP recording of sapga_ros topics.')
    parser.add_argument('file', help='the .mcap recording')
    parser.add_argument('--json', action='store_true', help='print one JSON object')
    parser.add_argument('--plot', metavar='OUT.png', help='plot one episode to a PNG file')
    parser.add_argument('--episode', type=int, metavar='N',
                        help='episode to plot (default: the one with the highest return)')
    return parser


def inspect_main(argv: list[str] | None = None) -> int:
    """Entry point of ``sapga inspect``."""
    args = build_parser().parse_args(argv)
    return run_inspect(args.file, json_out=args.json, plot=args.plot, episode=args.episode)


if __name__ == '__main__':
    raise SystemExit(inspect_main())
