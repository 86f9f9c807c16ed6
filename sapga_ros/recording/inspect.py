"""``sapga inspect``'s summary of a recording (a bag directory or one MCAP file).

Reads with ``reader.py`` and the ``mcap_ros2`` decoder (no ROS graph) and reports the
topics and message counts and, per episode (``episodes.py``), the return, delta*,
steps to the goal (or that it was not reached) and how often each action was commanded.
The numbers the simulator put in the end event (return, step, delta_star) are reported; the
same quantities recomputed from the recorded rewards and states are reported beside them
(``return_from_rewards``, ``delta_star_from_states``).  The problem is the one named in the
bag's metadata (or the JointState ``frame_id``).  A recording cut short by a hard kill is
summarised as far as it can be read (``complete`` false, ``error`` says where it ends).
"""
from __future__ import annotations

from typing import Any

from sapga_ros.errors import ConfigError, McapError
from sapga_ros.recording.episodes import (EPISODE_ROLES, Episode, finite, build_episodes,
                                          episode_summary, topic_roles)
from sapga_ros.recording.events import ROLE_TYPES
from sapga_ros.recording.reader import Recording, decode_messages, schema_type


def _load_problem(name: str | None) -> tuple[Any, str | None]:
    if not name:
        return None, 'no problem named in the file'
    from sim_nodes.problem import load_problem
    try:
        return load_problem(name), None
    except ConfigError as exc:
        return None, str(exc)


def _problem_name(rec: Recording) -> str | None:
    """The problem named in the metadata, else the first JointState's frame_id."""
    name = rec.metadata.get('problem')
    if name:
        return name
    states = {t for t, info in rec.topics.items() if schema_type(info) == ROLE_TYPES['state']}
    first = [m for m in rec.messages if m.topic in states][:1]
    view = Recording(path=rec.path, topics=rec.topics, messages=first)
    for m in decode_messages(view, states)[0]:
        return m.value.header.frame_id or None
    return None


def summarize(rec: Recording) -> tuple[dict[str, Any], list[Episode], Any]:
    """The summary dict of a recording, its episodes and its problem (None if unknown)."""
    meta = rec.metadata
    problem_name = _problem_name(rec)
    problem, problem_error = _load_problem(problem_name)
    roles = topic_roles(rec, problem)
    messages, failed = decode_messages(rec, [t for t, r in roles.items() if r in EPISODE_ROLES])
    episodes, bad_events = build_episodes(messages, roles, problem)
    goal_delta = finite(meta.get('delta'))
    if problem is not None:
        goal_delta = problem.resolve('delta', goal_delta)
    counts = rec.topic_counts()
    topics = [{'topic': name, 'type': t.type, 'count': counts[name], 'role': roles.get(name),
               'message_encoding': t.message_encoding,
               'schema_encoding': t.schema.encoding if t.schema else ''}
              for name, t in rec.topics.items()]
    times = [m.log_time for m in rec.messages]
    first = rec.files[0] if rec.files else None
    summary = {
        'file': rec.path, 'bag': rec.is_bag, 'bytes': rec.size, 'complete': rec.complete,
        'error': rec.error, 'profile': first.profile if first else '',
        'library': first.library if first else '',
        'storage_files': [{'path': f.path, 'bytes': f.size, 'messages': f.message_count,
                           'complete': f.complete, 'error': f.error} for f in rec.files],
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
        'metadata': meta,
    }
    eps = summary['episodes']
    summary['episodes_reaching_goal'] = sum(e['reached_goal'] for e in eps)
    returns = [e['return'] for e in eps if e['return'] is not None]
    summary['best_return'] = max(returns) if returns else None
    return summary, episodes, problem


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


def pick_episode(episodes: list[Episode], summaries: list[dict], number: int | None) -> int:
    """Index of episode ``number``, else of the best-return episode, with 2 or more states."""
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
