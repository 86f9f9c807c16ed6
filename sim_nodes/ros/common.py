"""Helpers shared by the ROS 2 nodes (the topic contract is docs/ros_interface.md).

Everything a node needs from a problem's ``ros:`` section, in one place:

* ``topic_names(problem)``: the topic names of ``ros.topics`` (relative, so ``__ns``
  remapping namespaces them), with the contract's defaults;
* ``qos_profile(problem)``: the ``ros.qos`` profile of the state and command topics;
  ``topic_qos(problem, name)``: that one (``reliable``) or ``sensor_data`` (best effort, as
  rclpy's ``qos_profile_sensor_data``), the nodes' ``qos_profile`` parameter;
* ``EVENT_QOS``, ``CLOCK_QOS``: the profiles of ``episode_event`` and ``/clock``;
* ``QUIET_PUBLISHER``: ``event_callbacks`` for publishers on the per-step path;
* ``JointStateLayout``: the state vector <-> ``sensor_msgs/JointState`` per the ``state:``
  layout (``joint``, ``field``); ``from_msg`` checks names, lengths and finiteness and
  raises ``MessageError`` naming what is wrong;
* ``stamp_ns``/``set_stamp``/``steady_clock``/``THROTTLE_S``: time helpers;
* ``run_node``, ``spin_guarded``, ``NodeExit``, ``one_line``: from ``runner.py`` (the body
  of every executable's ``main()``: --help, ROS arguments, spin, exit codes).
"""
from __future__ import annotations

import array
import math
from typing import Any, Sequence

import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from sensor_msgs.msg import JointState

from sim_nodes.errors import ConfigError, SapgaError
from sim_nodes.problem import Problem
from sim_nodes.problem_checks import DEFAULT_TOPICS
from sim_nodes.ros.runner import NodeExit, one_line, run_node, spin_guarded  # noqa: F401

THROTTLE_S = 2.0  # [s] between repeats of a warning about bad input
QOS_PROFILES = ('reliable', 'sensor_data')     # values of the nodes' qos_profile parameter
# Late joiners (recorders, tests) get the last episode events; volatile readers still match.
EVENT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Reliable keep-last-1 matches both reliable and best-effort /clock readers (rclpy's).
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
# rclpy gives every publisher two default QoS-event handlers (incompatible QoS / type), and
# the Python executor rebuilds its wait set with each of them on every spin: about 20 % of
# the lockstep loop.  Publishers of per-step topics go without; the subscriptions keep
# theirs, so an incompatible pairing is still reported, by the reading node.
QUIET_PUBLISHER = PublisherEventCallbacks(use_default_callbacks=False)

_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'volatile': DurabilityPolicy.VOLATILE,
               'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}
_HISTORY = {'keep_last': HistoryPolicy.KEEP_LAST, 'keep_all': HistoryPolicy.KEEP_ALL}


class MessageError(SapgaError):
    """A received message fails validation (wrong names, sizes, non-finite values)."""


def topic_names(problem: Problem) -> dict[str, str]:
    """``ros.topics`` of the problem over the contract's defaults (keys as DEFAULT_TOPICS)."""
    given = problem.ros.get('topics') or {}
    if not isinstance(given, dict):
        raise ConfigError(f'{problem.source}: ros.topics: expected a mapping')
    names = dict(DEFAULT_TOPICS)
    for key, value in given.items():
        if not isinstance(value, str) or not value:
            raise ConfigError(f'{problem.source}: ros.topics.{key}: expected a topic name, '
                              f'got {value!r}')
        names[str(key)] = value
    return names


def check_topic_types(node: Node, uses: Sequence[tuple[str, str, type]]) -> None:
    """Refuse, before a node makes its publishers and subscriptions, two of its topics
    (what, name, message type) that resolve, with its namespace and remappings, to one name
    with different types (rcl refuses the second, and a refused subscription reports a
    misleading 'invalid allocator')."""
    seen: dict[str, tuple[str, type]] = {}
    for what, name, msg_type in uses:
        resolved = node.resolve_topic_name(name)
        other = seen.setdefault(resolved, (what, msg_type))
        if other[1] is not msg_type:
            raise ConfigError(f'{other[0]} ({other[1].__name__}) and {what} '
                              f'({msg_type.__name__}) are both the topic {resolved}: check '
                              'ros.topics, the topic parameters and --ros-args -r remappings')


def _choice(cfg: dict, key: str, table: dict, default: str, source: str) -> Any:
    value = cfg.get(key, default)
    if value not in table:
        raise ConfigError(f'{source}: ros.qos.{key}: expected one of {", ".join(table)}, '
                          f'got {value!r}')
    return table[value]


def qos_profile(problem: Problem) -> QoSProfile:
    """The QoS of ``ros.qos`` (reliability, durability, history, depth) for state/command."""
    cfg = problem.ros.get('qos') or {}
    if not isinstance(cfg, dict):
        raise ConfigError(f'{problem.source}: ros.qos: expected a mapping')
    depth = cfg.get('depth', 10)
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
        raise ConfigError(f'{problem.source}: ros.qos.depth: expected an integer >= 1, '
                          f'got {depth!r}')
    return QoSProfile(
        depth=depth,
        reliability=_choice(cfg, 'reliability', _RELIABILITY, 'reliable', problem.source),
        durability=_choice(cfg, 'durability', _DURABILITY, 'volatile', problem.source),
        history=_choice(cfg, 'history', _HISTORY, 'keep_last', problem.source))


def topic_qos(problem: Problem, profile: str) -> QoSProfile:
    """The QoS of the per-step topics under the nodes' ``qos_profile`` parameter:
    ``reliable``, the problem's ``ros.qos``; ``sensor_data``, best effort keep-last 5."""
    if profile == 'sensor_data':
        return qos_profile_sensor_data
    if profile == 'reliable':
        return qos_profile(problem)
    raise ConfigError(f'qos_profile: expected one of {", ".join(QOS_PROFILES)}, '
                      f'got {profile!r}')


def stamp_ns(msg: Any) -> int:
    """A message header's stamp in integer nanoseconds."""
    stamp = msg.header.stamp
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def set_stamp(header: Any, ns: int) -> None:
    """Set a message header's stamp to ``ns`` nanoseconds."""
    header.stamp.sec, header.stamp.nanosec = divmod(ns, 1_000_000_000)


def steady_clock() -> Clock:
    """A steady clock for timers that must run whatever ``use_sim_time`` says."""
    return Clock(clock_type=ClockType.STEADY_TIME)


class JointStateLayout:
    """The state vector of a problem carried in ``sensor_msgs/JointState``.

    ``name`` = ``ros.joints``; each state coordinate sits in ``position`` or ``velocity`` of
    its joint (the YAML ``state:`` layout); ``effort`` is the actuator's torque/force on
    ``actuator.joint``, 0 elsewhere.  Joints that carry no coordinate read 0.
    """

    def __init__(self, problem: Problem) -> None:
        joints = tuple(problem.joints)
        where = f'{problem.source}: ros.joints'
        if not joints or not all(isinstance(j, str) and j for j in joints):
            raise ConfigError(f'{where}: expected a list of joint names')
        if len(set(joints)) != len(joints):
            raise ConfigError(f'{where}: duplicate joint names {list(joints)}')
        index = {j: i for i, j in enumerate(joints)}
        self.problem = problem
        self.joints = joints
        self.frame_id = str(problem.ros.get('frame_id', problem.name))
        self.dim = problem.dim
        # (state index, joint index) pairs per field
        self.position = tuple((d, index[c.joint]) for d, c in enumerate(problem.state)
                              if c.field == 'position' and c.joint in index)
        self.velocity = tuple((d, index[c.joint]) for d, c in enumerate(problem.state)
                              if c.field == 'velocity' and c.joint in index)
        missing = [c.joint for c in problem.state if c.joint not in index]
        if missing:
            raise ConfigError(f'{where}: joints {missing} of the state layout are not listed')
        if problem.actuator_joint not in index:
            raise ConfigError(f'{problem.source}: actuator.joint: {problem.actuator_joint!r} '
                              f'is not one of ros.joints {list(joints)}')
        self.actuator = index[problem.actuator_joint]
        self._joint_list = list(joints)

    def new_msg(self) -> JointState:
        """An empty JointState with this layout's names and frame."""
        msg = JointState()
        msg.name = list(self.joints)
        msg.header.frame_id = self.frame_id
        return msg

    def fill(self, msg: JointState, s: np.ndarray, effort: float, stamp: int) -> JointState:
        """Write state ``s``, actuator ``effort`` and ``stamp`` [ns] into ``msg``; return it."""
        n = len(self.joints)
        pos = [0.0] * n
        vel = [0.0] * n
        eff = [0.0] * n
        for d, j in self.position:
            pos[j] = float(s[d])
        for d, j in self.velocity:
            vel[j] = float(s[d])
        eff[self.actuator] = float(effort)
        set_stamp(msg.header, stamp)
        msg.position = array.array('d', pos)  # array.array skips rosidl's per-item checks
        msg.velocity = array.array('d', vel)
        msg.effort = array.array('d', eff)
        return msg

    def to_msg(self, s: np.ndarray, effort: float = 0.0, stamp: int = 0) -> JointState:
        """A new JointState carrying state ``s`` (see ``fill``)."""
        return self.fill(self.new_msg(), s, effort, stamp)

    def from_msg(self, msg: JointState, out: np.ndarray | None = None) -> np.ndarray:
        """The state vector of ``msg`` (joints in any order; extra joints ignored).

        Raises ``MessageError`` for missing or duplicate joints, position / velocity arrays
        whose length differs from ``name``'s, or a non-finite state coordinate.
        """
        names = msg.name
        n = len(names)
        pos, vel = msg.position, msg.velocity
        if len(pos) != n or len(vel) != n:
            raise MessageError(f'JointState has {n} names but {len(pos)} positions and '
                               f'{len(vel)} velocities')
        if names == self._joint_list:
            where = range(len(self.joints))
        else:
            index = {name: i for i, name in enumerate(names)}
            if len(index) != n:
                raise MessageError(f'JointState has duplicate joint names {list(names)}'[:200])
            missing = [j for j in self.joints if j not in index]
            if missing:
                raise MessageError(f'JointState lacks joints {missing} (got {list(names)})'[:200])
            where = [index[j] for j in self.joints]
        s = np.empty(self.dim) if out is None else out
        for d, j in self.position:
            s[d] = pos[where[j]]
        for d, j in self.velocity:
            s[d] = vel[where[j]]
        for d in range(self.dim):
            if not math.isfinite(s[d]):
                raise MessageError(f'JointState: {self.problem.state_names[d]} is not finite '
                                   f'({s[d]})')
        return s
