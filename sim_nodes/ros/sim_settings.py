"""The simulator node's parameters: declaration, validation and the frozen ``SimSettings``.

==================  ========  ==============  ===============================================
name                type      default         meaning
==================  ========  ==============  ===============================================
problem             string    per executable  msg_configs/<problem>.yaml; ``<model>_sim``: the
                                              model's own, ``sim_node``: acrobot (read-only)
mode                string    realtime        ``realtime``: one MDP step per tick of wall time /
                                              real_time_factor, zero-order hold on the latest
                                              command; ``lockstep``: one MDP step per command
                                              answering the current state
real_time_factor    double    1.0             > 0; sim time / wall time in realtime mode
delta               double    episode.delta   goal difficulty: the episode ends in S_delta
n_step              integer   episode.n_step  the episode ends after this many MDP steps
auto_reset          bool      true            start a new episode after one ends
max_episodes        integer   0               auto_reset starts no episode beyond this many
                                              (0 = unlimited); the reset service still does
republish_period    double    0.2             [s] lockstep: re-publish the waiting state
                                              (same stamp) this often; 0 = never
publish_clock       bool      true            publish /clock (false for all but one of several
                                              simulators in one domain)
markers             bool      true            publish the pendulum as a MarkerArray
qos_profile         string    reliable        ``reliable``: the problem's ``ros.qos``;
                                              ``sensor_data``: best effort, depth 5 (realtime
                                              runs; read-only)
wait_for_recorder   string    ''              the first episode starts once this recorder
                                              node is ready (recorder_gate.py); '' = at once
recorder_timeout    double    60.0            [s] waiting longer stops the node (exit 1)
==================  ========  ==============  ===============================================
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from sim_nodes.errors import ConfigError
from sim_nodes.problem import Problem
from sim_nodes.ros.common import QOS_PROFILES

MODES = ('realtime', 'lockstep')


@dataclass(frozen=True)
class SimSettings:
    """The node's changeable parameters (see the module docstring)."""

    mode: str
    real_time_factor: float
    delta: float
    n_step: int
    auto_reset: bool
    max_episodes: int
    republish_period: float
    publish_clock: bool
    markers: bool


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None."""
    if name == 'mode' and value not in MODES:
        return f'mode: expected one of {", ".join(MODES)}, got {value!r}'
    if name == 'real_time_factor' and not (math.isfinite(value) and 1e-3 <= value <= 1e4):
        return f'real_time_factor: expected a number in [0.001, 10000], got {value}'
    if name == 'delta' and not (math.isfinite(value) and value >= 0):
        return f'delta: expected a finite number >= 0, got {value}'
    if name == 'n_step' and value < 1:
        return f'n_step: expected an integer >= 1, got {value}'
    if name == 'max_episodes' and value < 0:
        return f'max_episodes: expected an integer >= 0 (0 = unlimited), got {value}'
    if name == 'republish_period' and not (math.isfinite(value) and 0 <= value <= 3600):
        return f'republish_period: expected seconds in [0, 3600], got {value}'
    if name == 'qos_profile' and value not in QOS_PROFILES:
        return f'qos_profile: expected one of {", ".join(QOS_PROFILES)}, got {value!r}'
    return None


def declare_settings(node: Node, problem: Problem) -> str:
    """Declare the simulator's parameters on ``node``; return the (read-only) qos_profile."""
    for name, default, text in (
            ('mode', 'realtime', 'realtime | lockstep'),
            ('real_time_factor', 1.0, 'sim time / wall time in realtime mode (> 0)'),
            ('delta', problem.default_delta, 'goal difficulty: the episode ends in S_delta'),
            ('n_step', problem.n_step, 'MDP steps per episode at most'),
            ('auto_reset', True, 'start a new episode after one ends'),
            ('max_episodes', 0, 'auto_reset starts no episode beyond this many (0 = unlimited)'),
            ('republish_period', 0.2,
             '[s] lockstep: re-publish the waiting state this often (0 = never)'),
            ('publish_clock', True, 'publish /clock (one simulator per domain should)'),
            ('markers', True, 'publish the pendulum as visualization_msgs/MarkerArray')):
        node.declare_parameter(name, default, ParameterDescriptor(description=text))
    qos = node.declare_parameter('qos_profile', 'reliable', ParameterDescriptor(
        description='reliable (the problem ros.qos) | sensor_data (best effort)',
        read_only=True)).value
    reason = check_setting('qos_profile', qos)
    if reason:
        raise ConfigError(f'{node.get_name()}: parameter {reason}')
    return qos


def read_settings(node: Node) -> SimSettings:
    """The node's current settings; ``ConfigError`` naming a value that is not acceptable."""
    values = {f.name: node.get_parameter(f.name).value for f in fields(SimSettings)}
    for key, value in values.items():
        reason = check_setting(key, value)
        if reason:
            raise ConfigError(f'{node.get_name()}: parameter {reason}')
    return SimSettings(**values)
