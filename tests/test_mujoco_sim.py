"""The simulator node with ``engine:=mujoco`` over real Fast DDS: the MuJoCo robot's joint
states (its names, its zero) answered by ``std_msgs/Float64MultiArray`` effort commands, the
same trajectory as the plant stepped offline (with a profile's model error, the robot of the
episode's drawn masses and lengths), and malformed efforts ignored."""
from __future__ import annotations

import threading

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ros_helpers import PROBE_QOS, Probe, isolated_ros
from sim_nodes.disturbance import Plant, load_disturbance
from sim_nodes.draws import HELD_OUT
from sim_nodes.mujoco_plant import MujocoPlant
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import stamp_ns
from sim_nodes.ros.sim_node import SimNode
from rclpy.node import Node

pytest.importorskip('mujoco')


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class EffortDriver(Node):
    """Answers each new joint state with the next effort of ``efforts`` (robot convention),
    after the malformed ``bad`` one at step ``bad_at``."""

    def __init__(self, efforts: list[list[float]], bad: list[float], bad_at: int,
                 **kwargs) -> None:
        super().__init__('driver', **kwargs)
        self.efforts = list(efforts)
        self.bad, self.bad_at = bad, bad_at
        self.states: list[JointState] = []
        self.lock = threading.Lock()
        self.pub = self.create_publisher(Float64MultiArray, 'effort_controller/commands',
                                         PROBE_QOS)
        self.create_subscription(JointState, 'joint_states', self._on_state, PROBE_QOS)

    def _on_state(self, msg: JointState) -> None:
        with self.lock:
            if self.states and stamp_ns(self.states[-1]) == stamp_ns(msg):
                return                                   # a lockstep re-publish
            self.states.append(msg)
            k = len(self.states) - 1
        if k == self.bad_at:
            self.pub.publish(Float64MultiArray(data=self.bad))
        if k < len(self.efforts):
            self.pub.publish(Float64MultiArray(data=self.efforts[k]))


@pytest.mark.parametrize('off', [False, True])
def test_the_mujoco_robot_is_driven_by_effort_arrays(ros, tmp_path, off):
    """``off``: under a profile of model error alone, the robot is the one rebuilt with the
    episode's drawn masses and lengths."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(3)
    efforts = [[float(v)] for v in rng.choice([-2.0, 0.0, 2.0], 30)]
    params = {'engine': 'mujoco', 'mode': 'lockstep', 'republish_period': 0.05}
    if off:
        profile = tmp_path / 'off.yaml'
        profile.write_text('mismatch: {masses: 0.05, lengths: 0.05}\n')
        params.update(disturbance=str(profile), disturbance_seed=4)
    sim = ros.start(SimNode, params=params)
    probe = ros.start(Probe, problem=problem)
    ros.wait_for(lambda: sim._effort_sub.get_publisher_count() == 0 and probe.states,
                 'the first state')
    driver = ros.start(EffortDriver, efforts=efforts, bad=[1.0, 2.0], bad_at=5)
    ros.wait_for(lambda: len(driver.states) >= 31, '30 steps driven by effort arrays')
    states = driver.states[:31]
    assert all(list(m.name) == ['shoulder', 'elbow'] for m in states)
    assert np.allclose(states[0].position, 0.0)              # hanging down: MuJoCo's zero
    assert sim.commands.ignored == 1                          # the wrong length
    plant = MujocoPlant(problem)                              # the same robot, offline
    if off:
        drawn = Plant(problem, load_disturbance(str(profile)))
        drawn.reset((4, 0, HELD_OUT, 0))
        plant.set_physics(drawn.params)
        assert not np.array_equal(drawn.params, problem.params())
    plant.reset(problem.initial_state)
    good = efforts
    for k in range(30):
        plant.step(good[k][0])
        assert np.array_equal(np.asarray(states[k + 1].position), plant.positions), k
        assert np.array_equal(np.asarray(states[k + 1].velocity), plant.velocities), k
        assert states[k + 1].effort[1] == good[k][0]
    assert max(abs(p) for m in states for p in m.position) > 0.05    # it swings
    assert sim._s[0] != problem.initial_state[0]           # the problem state follows
