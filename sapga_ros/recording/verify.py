"""Is a recording of finished episodes whole?  What the launcher checks before it reports.

For episodes that ran from their ``start`` to their end event (the simulator's end events
say how many steps each took), a whole recording holds, on the topics of their roles:

- exactly one ``start`` and one end event per episode;
- one reward per step;
- every state: the distinct ``header.stamp`` values number the steps plus one initial state
  per episode (lockstep re-publishes repeat a stamp and count once);
- in lockstep, a command for every step and every restart (the command answering an
  episode's final state starts the next one), on ``command_stamped`` or the hand-use
  ``command``, and the exemplar index of every such answer; realtime steps hold the last
  command;
- when ``topics`` names the markers role and the recording has the simulator's scenes on it
  (markers other than the ``exemplar`` ghost: a simulator drawing its model), the scene of
  every state (distinct ``header.stamp`` of each array's first marker); in lockstep, when it
  has the policy node's ``exemplar`` ghosts, the ghost of every answer.  A recording without
  them (the model has no drawing, ``markers`` off) is not asked for them.

Markers are checked like the rest: the launcher stops the recorder once this check passes on
the bag on disk, and the recorder takes the markers last (two publishers: twice the
messages of a state topic), so a check without them let it stop with the run's last
markers still in its queue.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

from sapga_ros.recording.events import EPISODE_END_EVENTS, parse_event
from sapga_ros.recording.reader import Recording
from sapga_ros.recording.schemas import cdr_string, first_marker, header_stamp_ns

GHOST_NS = 'exemplar'      # the policy node's markers (sim_nodes/ros/markers.py)


def recording_gaps(rec: Recording, topics: Mapping[str, str],
                   ends: Sequence[Mapping[str, Any]], lockstep: bool = True) -> list[str]:
    """What ``rec`` lacks of the episodes that ended with ``ends``; [] when whole.

    ``topics`` maps the roles state, reward, event, command and / or command_stamped (and
    optionally exemplar, markers and effort, the effort array a robot takes) to resolved
    topic names.
    """
    steps = sum(int(e.get('step') or 0) for e in ends)
    n = len(ends)
    by_topic: dict[str, list[bytes]] = {}
    for m in rec.messages:
        by_topic.setdefault(m.topic, []).append(m.data)
    kinds = [(parse_event(cdr_string(d)) or {}).get('event')
             for d in by_topic.get(topics['event'], [])]
    have = {
        'start events': (kinds.count('start'), n),
        'end events': (sum(k in EPISODE_END_EVENTS for k in kinds), n),
        'rewards': (len(by_topic.get(topics['reward'], [])), steps),
        'states': (len({header_stamp_ns(d) for d in by_topic.get(topics['state'], [])}),
                   steps + n),
    }
    if lockstep:
        commands = sum(len(by_topic.get(topics[role], []))
                       for role in ('command', 'command_stamped', 'effort') if role in topics)
        have['commands'] = (commands, steps + n - 1)
        if 'exemplar' in topics:    # the policy node names the exemplar of every answer
            have['exemplar indices'] = (len(by_topic.get(topics['exemplar'], [])),
                                        steps + n - 1)
    if 'markers' in topics:
        drawn = [first_marker(d) for d in by_topic.get(topics['markers'], [])]
        scenes = {m[1] for m in drawn if m is not None and m[0] != GHOST_NS}
        ghosts = {m[1] for m in drawn if m is not None and m[0] == GHOST_NS}
        if scenes:
            have['state markers'] = (len(scenes), steps + n)
        if ghosts and lockstep:
            have['exemplar markers'] = (len(ghosts), steps + n - 1)
    return [f'{got} of {want} {what}' for what, (got, want) in have.items() if got < want]
