"""The policy node driving robots that are not ours, over real Fast DDS.

* a fake robot (a small node here): foreign joint names, positions only (the node
  estimates velocities by finite differences), angle offsets and directions, a
  ``std_msgs/Float64MultiArray`` effort array of three with the actuated joint at index 1;
* the MuJoCo robot (``sim_node`` with ``engine:=mujoco``): the classical acrobot_hold
  controller, through the mapping, swings it up and holds it;
* mappings that do not fit are refused in one line.
"""
from __future__ import annotations

import array
import math
import threading

import numpy as np
import pytest
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ros_helpers import PROBE_QOS, Probe, isolated_ros
from sapga_ros.cli.main import main as sapga
from sapga_ros.nodes.policy_node import PolicyNode
from sim_nodes.errors import ConfigError
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import set_stamp
from sim_nodes.ros.sim_node import SimNode
from test_policy_node import expected_action, random_policy

OFFSETS = [1.5 * math.pi, 0.25]
DIRECTIONS = [-1.0, 1.0]
FOREIGN = {'robot_joints': ['upper_arm_joint', 'forearm_joint'], 'joint_offsets': OFFSETS,
           'joint_directions': DIRECTIONS, 'command_output': 'effort_array',
           'effort_size': 3, 'effort_index': 1}


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class FakeRobot(Node):
    """Publishes the next joint state (no velocities, an extra joint) once the effort array
    answering the previous one has come."""

    def __init__(self, positions: np.ndarray, **kwargs) -> None:
        super().__init__('fake_robot', **kwargs)
        self.positions = positions
        self.efforts: list[list[float]] = []
        self.lock = threading.Lock()
        self.pub = self.create_publisher(JointState, 'joint_states', PROBE_QOS)
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._on_effort, PROBE_QOS)

    def publish(self, k: int) -> None:
        msg = JointState()
        msg.name = ['gripper', 'forearm_joint', 'upper_arm_joint']
        q = self.positions[k]
        msg.position = array.array('d', [0.0, q[1], q[0]])
        set_stamp(msg.header, 50_000_000 * (k + 1))        # 0.05 s apart
        self.pub.publish(msg)

    def _on_effort(self, msg: Float64MultiArray) -> None:
        with self.lock:
            self.efforts.append(list(msg.data))
            k = len(self.efforts)
        if k < len(self.positions):
            self.publish(k)


def test_a_fake_robot_with_foreign_joints_and_no_velocities_is_driven(ros, tmp_path):
    acrobot = load_problem('acrobot')
    policy = random_policy(acrobot, 7)
    policy.save(tmp_path / 'p.json')
    rng = np.random.default_rng(11)
    positions = np.cumsum(rng.uniform(-0.2, 0.2, (12, 2)), axis=0)   # a smooth-ish path
    pol = ros.start(PolicyNode, params={'policy_file': str(tmp_path / 'p.json'), **FOREIGN})
    robot = ros.start(FakeRobot, positions=positions)
    ros.wait_for(lambda: pol._state_sub.get_publisher_count() == 1
                 and robot.pub.get_subscription_count() == 1
                 and pol._effort_pub.get_subscription_count() == 1, 'discovery')
    robot.publish(0)
    ros.wait_for(lambda: len(robot.efforts) == len(positions), 'an effort per state')
    assert pol.robot.estimated == len(positions)
    for k, effort in enumerate(robot.efforts):     # the state as the node must have seen it
        theta = np.array(OFFSETS) + np.array(DIRECTIONS) * positions[k]
        q = positions
        rate = np.array(DIRECTIONS) * (               # backward differences, 2nd order
            np.zeros(2) if k == 0 else (q[k] - q[k - 1]) / 0.05 if k == 1 else
            (3 * q[k] - 4 * q[k - 1] + q[k - 2]) / 0.1)
        _, action = expected_action(policy, np.concatenate([theta, rate]))
        assert len(effort) == 3 and effort[0] == effort[2] == 0.0
        assert effort[1] == pytest.approx(DIRECTIONS[1] * action), k
    assert {e[1] for e in robot.efforts} != {robot.efforts[0][1]}   # not one constant


def test_a_state_lacking_a_mapped_joint_is_skipped_and_the_node_goes_on(ros, tmp_path):
    acrobot = load_problem('acrobot')
    random_policy(acrobot, 8).save(tmp_path / 'p.json')
    pol = ros.start(PolicyNode, params={'policy_file': str(tmp_path / 'p.json'), **FOREIGN})
    robot = ros.start(FakeRobot, positions=np.zeros((1, 2)))
    ros.wait_for(lambda: pol._state_sub.get_publisher_count() == 1, 'discovery')
    msg = JointState(name=['shoulder', 'elbow'], position=[0.0, 0.0])
    robot.pub.publish(msg)
    ros.wait_for(lambda: pol.rejected == 1, 'the state refused')
    robot.publish(0)
    ros.wait_for(lambda: robot.efforts, 'the next good state answered')


@pytest.mark.parametrize('params, line', [
    ({'robot_joints': ['a']}, 'robot_joints: expected 2 values, one per joint of problem '
     'acrobot (shoulder, elbow), got 1'),
    ({'joint_offsets': [0.0, 1.0, 2.0]}, 'joint_offsets: expected 2 values'),
    ({'joint_directions': [1.0, 0.5]}, 'joint_directions: expected 1 or -1 for each joint, '
     'got 0.5'),
    ({'effort_size': 2, 'effort_index': 2}, 'effort_index: expected an index below '
     'effort_size 2, got 2'),
    ({'velocity_source': 'guess'}, 'velocity_source: expected one of auto, message, '
     'difference'),
])
def test_a_mapping_that_does_not_fit_is_refused_in_one_line(ros, params, line):
    with pytest.raises(ConfigError) as err:
        ros.start(PolicyNode, params=params)
    assert line in str(err.value) and '\n' not in str(err.value)


@pytest.mark.parametrize('output', ['effort_array', 'stamped'])
def test_the_classical_controller_swings_up_the_mujoco_acrobot_through_the_mapping(
        ros, tmp_path, output):
    pytest.importorskip('mujoco')
    problem = load_problem('acrobot_hold')
    assert sapga(['classical', '--problem', 'acrobot_hold',
                  '--out', str(tmp_path / 'c.json')]) == 0
    probe = ros.start(Probe, problem=problem)
    pol = ros.start(PolicyNode, params={
        'problem': 'acrobot_hold', 'policy_file': str(tmp_path / 'c.json'),
        'robot_joints': ['shoulder', 'elbow'], 'joint_offsets': [1.5 * math.pi, 0.0],
        'joint_directions': [-1.0, -1.0], 'command_output': output})
    sim = ros.start(SimNode, params={'problem': 'acrobot_hold', 'engine': 'mujoco',
                                     'mode': 'lockstep', 'n_step': 600, 'max_episodes': 1,
                                     'republish_period': 0.05})
    end = ros.wait_for(lambda: probe.end_of(1), 'the end of the episode', timeout=240)
    assert pol.answered >= 600 and sim.commands.ignored == sim.commands.late == 0
    assert 0 < end['first_entry_step'] < 600 and end['hold_fraction'] > 0.5
    assert end['delta_star'] <= 0.02
    names = {tuple(m.name) for m in probe.states.values()}
    assert names == {('shoulder', 'elbow')}


def test_sapga_launch_engine_mujoco_records_the_robot_driven_through_the_mapping(
        tmp_path, capsys):
    """`sapga launch swingup --engine mujoco`: the classical acrobot_hold controller swings
    up and holds the MuJoCo acrobot; the bag (read back by rosbags) holds the robot's joint
    states, an effort array answering every state (the last one's steps nothing), and the
    end event; `sapga inspect` reads the robot's states and effort arrays as the problem's
    (the elbow's effort is minus the problem's torque)."""
    pytest.importorskip('mujoco')
    import json

    from rosbags.highlevel import AnyReader
    from test_launch import launch, the_bag
    policy = tmp_path / 'c.json'
    assert sapga(['classical', '--problem', 'acrobot_hold', '--out', str(policy)]) == 0
    launch(['swingup', '--policy', str(policy), '--out', str(tmp_path / 'rec'),
            '--engine', 'mujoco'], tmp_path)
    with AnyReader([the_bag(tmp_path / 'rec')]) as reader:
        msgs = [(c.topic, reader.deserialize(raw, c.msgtype))
                for c, _, raw in reader.messages()]
    states = {(m.header.stamp.sec, m.header.stamp.nanosec): m for t, m in msgs
              if t == '/joint_states'}
    efforts = [m.data for t, m in msgs if t == '/effort_controller/commands']
    end = [json.loads(m.data) for t, m in msgs if t == '/episode_event'][-1]
    assert {tuple(m.name) for m in states.values()} == {('shoulder', 'elbow')}
    assert len(states) == 1001 and len(efforts) in (1000, 1001)   # the last: no step
    assert {float(e[0]) for e in efforts} <= {-2.0, 0.0, 2.0} and len(
        {float(e[0]) for e in efforts}) > 1
    assert end['event'] == 'step_limit' and end['first_entry_step'] is not None
    assert end['hold_fraction'] >= 0.9
    capsys.readouterr()
    assert sapga(['inspect', str(the_bag(tmp_path / 'rec')), '--json']) == 0
    summary = json.loads(capsys.readouterr().out)
    ep, = summary['episodes']
    assert summary['robot_joints'] and end['engine'] == 'mujoco'
    answers = [-float(e[0]) + 0.0 for e in efforts[:1000]]    # the episode's 1,000 steps
    assert ep['actions'] == {f'{v:g}': answers.count(v) for v in sorted(set(answers))}
    assert ep['delta_star_from_states'] <= end['goal_delta']   # held: in S_delta
