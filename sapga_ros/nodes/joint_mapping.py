"""Driving a robot that is not ours: its ``JointState`` read as the problem's state, the
problem's action written as its effort (no rclpy here: plain message fields).

``JointMapping.of(problem, values)`` checks the policy node's mapping parameters
(``policy_params.py``): ``robot_joints`` (the robot's joint for each of the problem's
``ros.joints``; [] = the same names), ``joint_offsets`` and ``joint_directions`` (per
problem joint; [] = 0 and +1): a problem coordinate is ``offset + direction * robot
position``, its velocity ``direction * robot velocity``, and the robot's effort is
``direction * action`` of the actuated joint; ``velocity_source`` (``auto``: the message's
velocities, finite differences of positions when it has none; ``message``; ``difference``);
``command_output`` (``stamped`` | ``effort_array``), ``effort_size`` and ``effort_index``.
A mapping that does not fit is a ``ConfigError`` of one line naming the parameter.

``RobotState(mapping)`` reads messages (``read``), ``MessageError`` for one that does not fit
(a mapped joint missing, lengths that differ from ``name``'s, a non-finite coordinate).  A
finite-difference velocity is the change of the (mapped) position since the previous
message over the change of stamps (angles on the circle); the first message, or one whose
stamp is not later, reads velocity 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim_nodes.errors import ConfigError
from sim_nodes.problem import Problem
from sim_nodes.ros.common import MessageError, stamp_ns

VELOCITY_SOURCES = ('auto', 'message', 'difference')
COMMAND_OUTPUTS = ('stamped', 'effort_array')
TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class JointMapping:
    """The robot's joints for a problem (module docstring)."""

    problem: Problem
    robot_joints: tuple[str, ...]      # per problem joint (ros.joints order)
    offsets: tuple[float, ...]
    directions: tuple[float, ...]
    velocity_source: str = 'auto'
    command_output: str = 'stamped'
    effort_size: int = 1
    effort_index: int = 0

    @classmethod
    def of(cls, problem: Problem, values: dict[str, Any]) -> JointMapping:
        """The mapping of the policy node's parameter ``values``, checked."""
        joints = problem.joints
        n = len(joints)

        def per_joint(name: str, default: Any) -> tuple:
            given = list(values.get(name) or [])
            if not given:
                return (default,) * n if default is not None else tuple(joints)
            if len(given) != n:
                raise ConfigError(f'{name}: expected {n} values, one per joint of problem '
                                  f'{problem.name} ({", ".join(joints)}), got {len(given)}')
            return tuple(given)
        robot = per_joint('robot_joints', None)
        if any(not j for j in robot):
            raise ConfigError(f'robot_joints: an empty joint name in {list(robot)}')
        directions = per_joint('joint_directions', 1.0)
        bad = [d for d in directions if d not in (1.0, -1.0)]
        if bad:
            raise ConfigError(f'joint_directions: expected 1 or -1 for each joint, got {bad[0]}')
        mapping = cls(problem, robot, tuple(map(float, per_joint('joint_offsets', 0.0))),
                      tuple(map(float, directions)),
                      values.get('velocity_source', 'auto'),
                      values.get('command_output', 'stamped'),
                      int(values.get('effort_size', 1)), int(values.get('effort_index', 0)))
        if mapping.effort_index >= mapping.effort_size:
            raise ConfigError(f'effort_index: expected an index below effort_size '
                              f'{mapping.effort_size}, got {mapping.effort_index}')
        return mapping

    @property
    def actuated(self) -> int:
        """The index of the actuator joint in the problem's joints."""
        return self.problem.joints.index(self.problem.actuator_joint)

    @property
    def identity(self) -> bool:
        """The problem's own joints and conventions (today's topic contract)."""
        return (self.robot_joints == tuple(self.problem.joints)
                and not any(self.offsets) and all(d == 1.0 for d in self.directions)
                and self.velocity_source != 'difference')

    def effort(self, action: float) -> float:
        """The robot effort of the problem's action on the actuated joint."""
        return self.directions[self.actuated] * action

    def describe(self) -> str:
        """One line: problem joint <- offset + direction * robot joint, ..."""
        parts = [f'{j} = {o:g} {"+" if d > 0 else "-"} robot {r}' for j, r, o, d in
                 zip(self.problem.joints, self.robot_joints, self.offsets, self.directions)]
        return ', '.join(parts) + f'; velocities: {self.velocity_source}'


class RobotState:
    """Reads a robot's ``JointState`` as the problem's state (module docstring)."""

    def __init__(self, mapping: JointMapping) -> None:
        p = mapping.problem
        self.mapping = mapping
        self.dim = p.dim
        joint = {j: k for k, j in enumerate(p.joints)}
        # per coordinate: (problem joint index, is velocity, is angle)
        self._coords = [(joint[c.joint], c.field == 'velocity', c.angle) for c in p.state]
        position_of = {joint[c.joint]: d for d, c in enumerate(p.state)
                       if c.field == 'position'}
        # per velocity coordinate: the position coordinate it is the derivative of
        self._derivative = {d: position_of.get(j) for d, (j, vel, _) in enumerate(self._coords)
                            if vel}
        lacking = [p.state[d].name for d, k in self._derivative.items() if k is None]
        if lacking and mapping.velocity_source != 'message':
            raise ConfigError(f'velocity_source: {mapping.velocity_source} needs a position '
                              f'of the joint of {lacking[0]}')
        self._names: list[str] = []
        self._where: list[int] = []
        self._last: tuple[int, np.ndarray] | None = None     # (stamp, state) for differences
        self._before: tuple[int, np.ndarray] | None = None   # and the one before it
        self.estimated = 0              # states whose velocities were estimated

    def _index(self, names: list[str]) -> list[int]:
        if names == self._names:
            return self._where
        index = {name: i for i, name in enumerate(names)}
        if len(index) != len(names):
            raise MessageError(f'JointState has duplicate joint names {names}'[:200])
        missing = [j for j in self.mapping.robot_joints if j not in index]
        if missing:
            raise MessageError(f'JointState lacks joints {sorted(set(missing))} that '
                               f'robot_joints maps (got {names})'[:200])
        self._names = names
        self._where = [index[j] for j in self.mapping.robot_joints]
        return self._where

    def read(self, msg: Any, out: np.ndarray | None = None) -> np.ndarray:
        """The problem state of ``msg``; ``MessageError`` for a message that does not fit."""
        names = list(msg.name)
        n = len(names)
        pos, vel = msg.position, msg.velocity
        if len(pos) != n or len(vel) not in (0, n):
            raise MessageError(f'JointState has {n} names but {len(pos)} positions and '
                               f'{len(vel)} velocities')
        source = self.mapping.velocity_source
        if source == 'message' and not len(vel):
            raise MessageError('JointState has no velocities (velocity_source: message)')
        where = self._index(names)
        m = self.mapping
        s = np.empty(self.dim) if out is None else out
        measured = source == 'message' or (source == 'auto' and len(vel))
        for d, (j, is_vel, _) in enumerate(self._coords):
            if not is_vel:
                s[d] = m.offsets[j] + m.directions[j] * pos[where[j]]
            elif measured:
                s[d] = m.directions[j] * vel[where[j]]
        for d in range(self.dim):
            if not is_finite(s[d], d, self._coords, measured):
                raise MessageError(f'JointState: {m.problem.state_names[d]} is not finite '
                                   f'({s[d]})')
        if not measured:
            self._differences(s, stamp_ns(msg))
        return s

    def _differences(self, s: np.ndarray, stamp: int) -> None:
        """Velocities of the quadratic through the last three positions at ``stamp`` (the
        second-order backward difference; first order after one message, 0 on the first
        or when the stamps do not increase)."""
        last, before = self._last, self._before
        self.estimated += 1
        h2 = (stamp - last[0]) * 1e-9 if last is not None else 0.0
        h1 = (last[0] - before[0]) * 1e-9 if before is not None else 0.0
        if h2 <= 0.0:
            before = last = None
        self._before, self._last = last, (stamp, s.copy())
        for d, k in self._derivative.items():
            if last is None:
                s[d] = 0.0
                continue
            slope2 = self._change(s[k], last[1][k], k) / h2
            if h1 > 0.0 and before is not None:
                slope1 = self._change(last[1][k], before[1][k], k) / h1
                s[d] = slope2 + (slope2 - slope1) * h2 / (h1 + h2)
            else:
                s[d] = slope2
        self._last[1][:] = s

    def _change(self, x: float, x_before: float, k: int) -> float:
        change = x - x_before
        return math.remainder(change, TWO_PI) if self._coords[k][2] else change


def is_finite(x: float, d: int, coords: list, measured: bool) -> bool:
    """Coordinate ``d`` is finite, or a velocity still to be estimated."""
    return math.isfinite(x) or (coords[d][1] and not measured)
