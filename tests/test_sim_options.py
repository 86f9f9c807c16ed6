"""Simulator and policy node options for several simulators and realtime runs, over real Fast
DDS: ``publish_clock`` (two namespaced simulators in one domain, only one owns /clock) and
``qos_profile: sensor_data`` (best-effort state, command and marker topics)."""
from __future__ import annotations

import threading

import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from ros_helpers import isolated_ros
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sim_nodes.errors import ConfigError
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout, stamp_ns
from sim_nodes.ros.sim_node import SimNode


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class ClockListener(Node):
    """Hears /clock and counts the times it went backwards."""

    def __init__(self, **kwargs) -> None:
        super().__init__('clock_listener', **kwargs)
        self.lock = threading.Lock()
        self.times: list[int] = []
        self.backwards = 0
        self.create_subscription(Clock, '/clock', self._on_clock,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))

    def _on_clock(self, msg: Clock) -> None:
        t = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        with self.lock:
            if self.times and t < self.times[-1]:
                self.backwards += 1
            self.times.append(t)

    def count(self) -> int:
        with self.lock:
            return len(self.times)


def test_two_namespaced_sims_with_one_clock_keep_sim_time_monotonic(ros):
    """/a runs 1x, /b 4x faster with publish_clock false: a /clock subscriber never sees time
    go backwards.  Let /b publish too and it does: the parameter is what keeps it sane."""
    listener = ros.start(ClockListener)
    a = ros.start(SimNode, params={'real_time_factor': 1.0, 'wait_for_policy': False},
                  namespace='/a')
    b = ros.start(SimNode, params={'real_time_factor': 4.0, 'publish_clock': False,
                                   'wait_for_policy': False},
                  namespace='/b')
    assert a._state_pub.topic_name == '/a/joint_states'
    assert b._state_pub.topic_name == '/b/joint_states'
    ros.wait_for(lambda: listener.count() > 40 and b.total_steps > a.total_steps + 10,
                 '/clock from /a while /b runs ahead')
    assert listener.backwards == 0
    assert not clock_publisher(b) and clock_publisher(a)      # false: no /clock publisher
    assert b.set_parameters([Parameter('publish_clock', value=True)])[0].successful
    ros.wait_for(lambda: listener.backwards > 0, 'two clocks interleaving')
    assert clock_publisher(b)
    assert b.set_parameters([Parameter('publish_clock', value=False)])[0].successful
    ros.wait_for(lambda: not clock_publisher(b), "/b's /clock publisher gone")


def clock_publisher(sim: SimNode) -> bool:
    """``sim`` has a /clock publisher on the ROS graph."""
    topics = sim.get_publisher_names_and_types_by_node(sim.get_name(), sim.get_namespace())
    return any(name == '/clock' for name, _ in topics)


def test_sensor_data_qos_runs_a_realtime_loop(ros, tmp_path):
    """Sim and policy node with qos_profile sensor_data: the sim offers best effort, a
    sensor-data subscriber receives states, and the policy's stamped answers reach the sim."""
    problem = load_problem('acrobot')
    layout = JointStateLayout(problem)
    policy = ExemplarPolicy(problem, problem.initial_state[None, :], [2])   # always +2
    policy.save(tmp_path / 'p.json')
    states: dict[int, JointState] = {}
    listener = ros.start(Node, node_name='sensor_listener')
    listener.create_subscription(JointState, 'joint_states',
                                 lambda m: states.setdefault(stamp_ns(m), m),
                                 qos_profile_sensor_data)
    sim = ros.start(SimNode, params={'qos_profile': 'sensor_data', 'real_time_factor': 4.0})
    pol = ros.start(PolicyNode, params={'qos_profile': 'sensor_data',
                                        'policy_file': str(tmp_path / 'p.json')})
    (offer,) = listener.get_publishers_info_by_topic('/joint_states')
    assert offer.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    ros.wait_for(lambda: len(states) > 10, 'states over best effort')
    ros.wait_for(lambda: any(m.effort[layout.actuator] == 2.0 for m in list(states.values())),
                 "a step with the policy's command")
    assert pol.answered > 0 and sim.qos_profile == pol.qos_profile == 'sensor_data'


@pytest.mark.parametrize('node', [SimNode, PolicyNode])
def test_an_unknown_qos_profile_is_refused_at_start(ros, node):
    with pytest.raises(ConfigError, match='qos_profile: expected one of reliable, sensor_data'):
        ros.start(node, params={'qos_profile': 'fast'})
