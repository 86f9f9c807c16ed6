"""The policy node's parameters: one table for their declaration with ranges, their checks
and ``policy_node --help`` (``sim_nodes/params.py``).

================  ========  ============  ================================================
name              type      default       meaning
================  ========  ============  ================================================
problem           string    acrobot       msg_configs/<problem>.yaml (read-only)
policy_file       string    ''            a policy JSON file, loaded at start (a bad one:
                                          exit 2); setting it loads that file or is refused
trainer_service   string    trainer_node/ the trainer's std_srvs/Trigger (read-only)
                            get_policy
load_timeout      double    5.0           [s] wait for the trainer's answer at most
delay             integer   0             run every plain exemplar policy as designed for
                                          this many MDP steps of actuation delay (its
                                          selector acts on the predicted state; read-only)
markers           bool      true          publish the exemplar ghost on ``markers``
qos_profile       string    reliable      ``reliable`` (the problem's ``ros.qos``) |
                                          ``sensor_data`` (best effort; read-only)
executor          string    events        ``events`` (rclpy's EventsExecutor) | ``single``
                                          (``SingleThreadedExecutor``; read-only)
robot_joints      string[]  []            the robot's joint per problem joint ([]: same)
joint_offsets     double[]  []            per problem joint: coordinate = offset +
joint_directions  double[]  []            direction (1 or -1) * robot position
velocity_source   string    auto          auto | message | difference (finite
                                          differences of positions)
command_output    string    stamped       stamped (``command_stamped``) | effort_array
                                          (``std_msgs/Float64MultiArray``, effort_topic)
effort_topic      string    see --help    effort_controller/commands
effort_size       integer   1             values in the effort array (robot actuators)
effort_index      integer   0             the actuated joint's index in it
================  ========  ============  ================================================

(``policy_node --help`` prints the ranges too.)  The mapping and output parameters are
read-only; ``joint_mapping.py`` checks them together.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

from sapga_ros.nodes.joint_mapping import COMMAND_OUTPUTS, VELOCITY_SOURCES
from sapga_ros.policies.controller_row import MAX_DELAY
from sapga_ros.evaluation.replan_settings import ReplanSettings
from sim_nodes.params import Param, declared
from sim_nodes.ros.common import QOS_PROFILES
from sim_nodes.ros.executors import DEFAULT_EXECUTOR, EXECUTORS
from sim_nodes.ros.params import check

PARAMETERS = (
    Param('problem', 'acrobot', 'msg_configs/<problem>.yaml', read_only=True),
    Param('policy_file', '', 'policy JSON file loaded at start (a bad one: exit 2); setting '
          "it loads that file ('' = none)"),
    Param('trainer_service', 'trainer_node/get_policy', "the trainer's std_srvs/Trigger that "
          'load_policy calls', read_only=True),
    Param('load_timeout', 5.0, 'how long load_policy waits for the trainer', 1e-3, 86400.0,
          unit='s'),
    Param('delay', 0, 'run every plain exemplar policy as designed for N MDP steps of '
          'actuation delay: its selector acts on the state predicted that far ahead from the '
          'commands in flight (nominal model); 0: as each policy file says', 0, MAX_DELAY,
          read_only=True),
    Param('markers', True, 'publish the exemplar in use as a ghost on markers'),
    Param('qos_profile', 'reliable', 'reliable (the problem ros.qos) | sensor_data (best '
          'effort)', choices=QOS_PROFILES, read_only=True),
    Param('executor', DEFAULT_EXECUTOR, 'events: rclpy EventsExecutor (faster); single: '
          'SingleThreadedExecutor', choices=EXECUTORS, read_only=True),
)
# driving a robot that is not ours (joint_mapping.py); all read-only
MAPPING_PARAMETERS = (
    Param('robot_joints', [], "the robot's joint name for each of the problem's ros.joints "
          '([] = the same names)', read_only=True),
    Param('joint_offsets', [], 'per problem joint: coordinate = offset + direction * robot '
          'position ([] = 0)', item=float, read_only=True),
    Param('joint_directions', [], 'per problem joint: 1 or -1 (also the sign of the effort; '
          '[] = 1)', item=float, read_only=True),
    Param('velocity_source', 'auto', 'auto: the JointState velocities, finite differences of '
          'positions when it has none; message; difference', choices=VELOCITY_SOURCES,
          read_only=True),
    Param('command_output', 'stamped', 'stamped: command_stamped (sensor_msgs/JointState); '
          'effort_array: std_msgs/Float64MultiArray on effort_topic', choices=COMMAND_OUTPUTS,
          read_only=True),
    Param('effort_topic', 'effort_controller/commands', 'effort_array: the forward command '
          "controller's topic", read_only=True),
    Param('effort_size', 1, 'effort_array: its length (the robot actuators)', 1, 1024,
          read_only=True),
    Param('effort_index', 0, "effort_array: the actuated joint's index in it", 0, 1023,
          read_only=True),
)
# decision-time planning (sapga_ros.evaluation.replan); all read-only
REPLAN_PARAMETERS = (
    Param('replan', False, "re-plan the policy's own episode at every state on the model "
          "(nominal, or fitted: replan_fit; the plan acts on the state predicted 'delay' "
          "steps ahead); a hold task's planner hands over to the classical LQR",
          read_only=True),
    *(replace(p, read_only=True) for p in declared(ReplanSettings)),
)
PARAMETERS = PARAMETERS + MAPPING_PARAMETERS + REPLAN_PARAMETERS


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None (files: the node)."""
    return check(PARAMETERS, name, value)
