"""Topic roles of a sapga_ros recording and the ``episode_event`` messages that cut it.

Roles and their types follow docs/ros_interface.md; ``msg_configs/<problem>.yaml``
``ros.topics`` names the topics.  ``parse_event`` is the one parser of episode events for
every reader (recorder, launcher, inspect): bounded in size and nesting, it returns None for
anything that is not a JSON object, whatever the input.
"""
from __future__ import annotations

import json
from typing import Any

# Message type of each role in msg_configs/<problem>.yaml `ros.topics`
ROLE_TYPES = {
    'state': 'sensor_msgs/msg/JointState',
    'command': 'std_msgs/msg/Float64',
    'reward': 'std_msgs/msg/Float64',
    'event': 'std_msgs/msg/String',
    'exemplar': 'std_msgs/msg/Int32',
    'command_stamped': 'sensor_msgs/msg/JointState',
    'markers': 'visualization_msgs/msg/MarkerArray',
}
# Roles a run may leave without a publisher: the hand-use Float64 command (the policy node
# answers on command_stamped).  A recorder is ready without one; one that appears is recorded.
OPTIONAL_ROLES = ('command',)
# Publishers of a role in a run: both the simulator (the scene) and the policy node (the
# exemplar ghost) draw on markers.  One subscription history holds every publisher's
# messages, so a recorder keeps that many times its depth (``recorder_qos.role_qos``).
ROLE_PUBLISHERS = {'markers': 2}
EPISODE_END_EVENTS = ('goal', 'step_limit', 'end_stop', 'reset')
MAX_EVENT_CHARS = 65536     # an episode event is a few hundred characters


def _bare(name: str) -> float:
    raise ValueError(f'bare {name}')   # strict JSON: a non-finite number is null


def parse_event(text: Any) -> dict[str, Any] | None:
    """An episode_event JSON object, or None if ``text`` is not one (or is too large)."""
    if not isinstance(text, str) or len(text) > MAX_EVENT_CHARS:
        return None
    try:
        doc = json.loads(text, parse_constant=_bare)
    except (ValueError, RecursionError):  # malformed or hostile (deep nesting): not an event
        return None
    return doc if isinstance(doc, dict) else None


def event_episode(event: dict[str, Any] | None) -> int | None:
    """The event's episode number if it is a non-negative int (bool excluded), else None."""
    number = (event or {}).get('episode')
    if isinstance(number, int) and not isinstance(number, bool) and number >= 0:
        return number
    return None
