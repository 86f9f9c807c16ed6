"""The start of a realtime run over real Fast DDS (sim_nodes/ros/sim_node.py): the simulator
executable re-publishes its first state until a command answers it (or stops with one line
after ``policy_timeout``), so a policy node started later misses no state; its ticks then
come one period apart, with no stall followed by a burst of catch-up ticks."""
from __future__ import annotations

import json
import threading

import pytest
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from ros_helpers import PROBE_QOS, isolated_ros
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import EVENT_QOS, stamp_ns


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class Listener(Node):
    """Hears states (with the sim's source timestamps), answers and events; publishes no
    command, so it is no policy node to the simulator's gate."""

    def __init__(self, **kwargs) -> None:
        super().__init__('listener', **kwargs)
        self.lock = threading.Lock()
        self.sent: dict[int, int] = {}          # state stamp -> source timestamp [ns]
        self.answered: set[int] = set()
        self.events: list[dict] = []
        self.create_subscription(JointState, 'joint_states', self._on_state, PROBE_QOS)
        self.create_subscription(JointState, 'command_stamped',
                                 lambda m: self._add(self.answered.add, stamp_ns(m)),
                                 PROBE_QOS)
        self.create_subscription(String, 'episode_event',
                                 lambda m: self._add(self.events.append, json.loads(m.data)),
                                 EVENT_QOS)

    def _add(self, add, item) -> None:
        with self.lock:
            add(item)

    def _on_state(self, msg: JointState, info: dict) -> None:
        with self.lock:
            self.sent.setdefault(stamp_ns(msg), info['source_timestamp'])

    def end(self, episode: int) -> dict | None:
        with self.lock:
            return next((e for e in self.events if e['episode'] == episode
                         and e['event'] in ('goal', 'step_limit')), None)


def always(tmp_path) -> str:
    problem = load_problem('acrobot')
    path = tmp_path / 'p.json'
    ExemplarPolicy(problem, problem.initial_state[None, :], [2]).save(path)
    return str(path)


def test_a_realtime_sim_started_first_waits_for_the_policy_node(ros, tmp_path):
    """``ros2 run``-style: the simulator starts and publishes its first state before the
    policy node exists; it steps only once that state is answered, and the episode's
    late_commands is at least the states the policy never answered."""
    listener = ros.start(Listener)
    sim = ros.spawn('acrobot_sim', '--ros-args', '-p', 'real_time_factor:=2.0', '-p',
                    'n_step:=30', '-p', 'max_episodes:=1')
    ros.wait_for(lambda: 0 in listener.sent, 'the first state')
    assert len(listener.sent) == 1
    ros.start(PolicyNode, params={'policy_file': always(tmp_path)})
    end = ros.wait_for(lambda: listener.end(1), 'the end of episode 1')
    with listener.lock:
        states = sorted(t for t in listener.sent if t < end['time'] * 1e9 - 1)
        never = [t for t in states if t not in listener.answered]
    assert states[0] == 0 and 0 in listener.answered       # the start state was answered
    assert len(states) == end['step'] == 30
    assert len(never) <= end['late_commands'] <= 30
    assert ros.stop(sim) == 0


def test_a_realtime_sim_without_a_policy_stops_after_policy_timeout(ros):
    """No answer within ``policy_timeout``: one error line naming what is missing and how
    to go on without one, exit status 1."""
    proc = ros.spawn('acrobot_sim', '--ros-args', '-p', 'policy_timeout:=1.0')
    proc.wait(120)
    text = ros.children[-1][1].read_text()
    errors = [line for line in text.splitlines() if 'error' in line.lower()]
    assert proc.returncode == 1, text
    assert len(errors) == 1 and errors[0].startswith('acrobot_sim: error: '), errors
    assert 'no command answered the first state within 1 s' in errors[0]
    assert 'no node subscribes to /joint_states' in errors[0]
    assert 'wait_for_policy:=false' in errors[0]
    assert 'Traceback' not in text


def test_realtime_ticks_start_one_period_after_the_start_state_without_a_burst(ros, tmp_path):
    """The first ten states, timed by the simulator's own clock (DDS source timestamps): no
    two are published within half a period of each other (a stall followed by catch-up
    ticks would be), and their stamps are consecutive ticks of sim time."""
    period_ns = 100_000_000                       # real_time_factor 0.5: 0.05 s sim per 0.1 s
    listener = ros.start(Listener)
    sim = ros.spawn('acrobot_sim', '--ros-args', '-p', 'real_time_factor:=0.5')
    ros.start(PolicyNode, params={'policy_file': always(tmp_path)})
    ros.wait_for(lambda: len(listener.sent) >= 10, 'ten states')
    with listener.lock:
        first = sorted(listener.sent.items())[:10]
    stamps = [stamp for stamp, _ in first]
    assert stamps == [k * 50_000_000 for k in range(10)]
    gaps = [b - a for (_, a), (_, b) in zip(first, first[1:])]
    assert min(gaps) >= period_ns // 2, gaps
    assert ros.stop(sim) == 0
