"""Reading a recording made on the MuJoCo robot (``engine:=mujoco``): its joint states in the
robot's own names and convention, its commands as ``std_msgs/Float64MultiArray`` effort
arrays.

``RobotLayout.of(problem)`` is the robot of ``sim_nodes.mujoco_plant`` for the problem (None
for a model without one): ``state(msg)`` reads a ``JointState`` that names the robot's joints
as the problem's state (coordinate = offset + direction * the robot's, angles wrapped to
[0, 2pi)), ``action(data)`` an effort array of the robot's one actuator as the problem's
action (direction * the effort).  A message that does not fit reads None.

The effort topic is the one ros2control's forward command controllers use, ``<controller>/
commands`` (``EFFORT_TYPE``); a recording with exactly one such topic has its commands there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from sim_nodes.errors import ConfigError
from sim_nodes.mujoco_plant import coordinates, mapping
from sim_nodes.problem import Problem

EFFORT_TYPE = 'std_msgs/msg/Float64MultiArray'
EFFORT_BASE = 'commands'        # the last part of a forward command controller's topic
TWO_PI = 2.0 * math.pi


def effort_topic(types: dict[str, str]) -> str | None:
    """The one recorded effort-array topic (``.../commands``) of topic -> type, or None."""
    found = [t for t, ty in types.items()
             if ty == EFFORT_TYPE and t.rstrip('/').rsplit('/', 1)[-1] == EFFORT_BASE]
    return found[0] if len(found) == 1 else None


@dataclass(frozen=True)
class RobotLayout:
    """The problem's state and action on the MuJoCo robot (module doc)."""

    joints: tuple[str, ...]         # the robot's joint of each state coordinate
    offsets: np.ndarray             # per coordinate (velocities: 0)
    directions: np.ndarray
    velocity: tuple[bool, ...]      # per coordinate: read from the velocities
    angle: np.ndarray               # per coordinate: wrapped to [0, 2pi) (bool)
    actuator_direction: float

    @classmethod
    def of(cls, problem: Problem | None) -> RobotLayout | None:
        if problem is None:
            return None
        try:
            joints, offsets, directions, angle, velocity = zip(*coordinates(problem))
        except ConfigError:
            return None
        return cls(joints, np.array(offsets), np.array(directions), velocity,
                   np.array(angle, dtype=np.bool_),
                   mapping(problem)[problem.actuator_joint].direction)

    def state(self, msg: Any) -> np.ndarray | None:
        """The problem state of a robot ``JointState``; None when it does not fit."""
        names = list(msg.name)
        raw = np.empty(len(self.joints))
        for d, (joint, vel) in enumerate(zip(self.joints, self.velocity)):
            values = msg.velocity if vel else msg.position
            if joint not in names or len(values) != len(names):
                return None
            raw[d] = values[names.index(joint)]
        s = self.offsets + self.directions * raw
        s[self.angle] %= TWO_PI
        return s if np.all(np.isfinite(s)) else None

    def action(self, data: Sequence[float]) -> float | None:
        """The problem's action of an effort array (the robot has one actuator); None when
        it holds another number of values or a value that is not finite."""
        if len(data) != 1 or not math.isfinite(data[0]):
            return None
        return self.actuator_direction * float(data[0]) + 0.0
