"""The simulator node's parameters: one table (``sim_parameters``) for their declaration
with ranges (``params.py``), their checks, the executables' ``--help`` and the frozen
``SimSettings``.

``ros2 run sapga_ros sim_node --help`` prints the table (name, type, default, range or
choices, description) from ``sim_parameters``; the same ``Param`` rows
(``sim_nodes/params.py``) declare the parameters. In short: ``problem`` (read-only;
``<model>_sim``: the model's own, ``sim_node``: acrobot), ``mode`` (``realtime``: one MDP
step per tick of wall time / ``real_time_factor``, zero-order hold on the latest command;
``lockstep``: one MDP step per command answering the current state), ``real_time_factor``,
``delta`` and ``n_step`` (default: the problem's ``episode.delta`` / ``episode.n_step``),
``auto_reset``, ``max_episodes`` (the reset service still starts episodes beyond it),
``republish_period`` (lockstep: the waiting state again, same stamp), ``publish_clock``
(false for all but one of several simulators in one domain), ``markers``, ``qos_profile``
(read-only; ``sensor_data``: best effort, depth 5, for realtime runs), ``executor``
(read-only; ``executors.py``), ``wait_for_policy``
and ``policy_timeout`` (realtime: the first tick waits for a command answering the first
state, which is re-published meanwhile; exit 1 after the timeout), ``disturbance`` and
``disturbance_seed`` (read-only; the plant is disturbed as the episode engine disturbs it,
``sim_nodes.disturbance.Plant``), and the recorder gate's
``wait_for_recorder`` and ``recorder_timeout`` (``recorder_gate.py``), ``engine``
(read-only; ``kernel`` or ``mujoco``) and ``effort_topic`` (``mujoco_engine.py``).
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from rclpy.node import Node

from sim_nodes.params import DELTA, N_STEP, Param
from sim_nodes.problem import Problem
from sim_nodes.ros.common import QOS_PROFILES
from sim_nodes.ros.executors import DEFAULT_EXECUTOR, EXECUTORS
from sim_nodes.problem_checks import EFFORT_TOPIC
from sim_nodes.ros.mujoco_engine import ENGINES
from sim_nodes.ros.params import check, declare
from sim_nodes.ros.recorder_gate import gate_parameters

MODES = ('realtime', 'lockstep')
MAX_COUNT = 10 ** 9         # max_episodes: at most this many


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


def sim_parameters(default_problem: str) -> list[Param]:
    """The simulator's parameters (``delta``, ``n_step``: the problem's by default)."""
    return [
        Param('problem', default_problem, 'problem name: msg_configs/<problem>.yaml',
              read_only=True),
        Param('mode', 'realtime', 'realtime: one MDP step per tick of wall time / '
              'real_time_factor; lockstep: one per command answering the current state',
              choices=MODES),
        Param('real_time_factor', 1.0, 'sim time / wall time in realtime mode', 1e-3, 1e4),
        DELTA,
        N_STEP,
        Param('auto_reset', True, 'start a new episode after one ends'),
        Param('max_episodes', 0, 'auto_reset starts no episode beyond this many (0 = '
              'unlimited)', 0, MAX_COUNT),
        Param('republish_period', 0.2, 'lockstep: re-publish the waiting state this often '
              '(0 = never)', 0.0, 3600.0, unit='s'),
        Param('publish_clock', True, 'publish /clock (one simulator per domain should)'),
        Param('markers', True, 'publish the pendulum as visualization_msgs/MarkerArray'),
        Param('qos_profile', 'reliable', 'reliable (the problem ros.qos) | sensor_data (best '
              'effort)', choices=QOS_PROFILES, read_only=True),
        Param('executor', DEFAULT_EXECUTOR, 'events: rclpy EventsExecutor (faster); single: '
              'SingleThreadedExecutor', choices=EXECUTORS, read_only=True),
        Param('wait_for_policy', True, 'realtime: step only once a command answered the first '
              'state (re-published meanwhile); false: step at once', read_only=True),
        Param('policy_timeout', 60.0, 'how long realtime waits for that answer (longer: the '
              'node stops, exit 1)', 1e-3, 86400.0, read_only=True, unit='s'),
        Param('disturbance', 'none', 'disturbance profile of the plant (a name in '
              'msg_configs/disturbances or a .yaml file): noise on the published state, '
              'latency, gain, model error, pushes; none: the model', read_only=True),
        Param('disturbance_seed', 0, 'seed of the disturbances: episode k is drawn as the '
              'evaluation\'s episode k - 1 of this seed', 0, MAX_COUNT, read_only=True),
        *gate_parameters(), *engine_parameters()]


def engine_parameters() -> list[Param]:
    """The physics engine: the compiled kernel, or MuJoCo (``mujoco_engine.py``)."""
    return [Param('engine', 'kernel', 'kernel: the compiled model, as the evaluator; mujoco: '
                  'the MuJoCo robot (its own joint names and angle zero)', choices=ENGINES,
                  read_only=True),
            Param('effort_topic', EFFORT_TOPIC, 'engine mujoco: the std_msgs/Float64MultiArray '
                  'effort command (one value per actuator)', read_only=True)]


_CHECKED = sim_parameters('acrobot')    # ranges and choices do not depend on the problem


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None."""
    return check(_CHECKED, name, value)


def declare_settings(node: Node, problem: Problem) -> str:
    """Declare the simulator's parameters but ``problem`` (declared first, to read it) and
    the recorder gate's; return the (read-only) qos_profile."""
    gate = {p.name for p in gate_parameters() + engine_parameters()}
    table = [p for p in sim_parameters(problem.name) if p.name != 'problem' and
             p.name not in gate]
    return declare(node, table, problem)['qos_profile']


def read_settings(node: Node) -> SimSettings:
    """The node's current settings (each checked when it was set)."""
    return SimSettings(**{f.name: node.get_parameter(f.name).value
                          for f in fields(SimSettings)})
