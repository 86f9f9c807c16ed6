"""Every node reports on /diagnostics over real Fast DDS (sim_nodes/ros/diagnostics.py): the
simulator, the policy node, the recorder and the trainer, each one status named
``<node>: <what>`` with its problem as hardware id, a level saying whether it can do its job,
and its counters."""
from __future__ import annotations

import threading

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node

from ros_helpers import isolated_ros
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.nodes.recorder_node import RecorderNode
from sapga_ros.nodes.trainer_node import TrainerNode
from sim_nodes.problem import load_problem
from sim_nodes.ros.sim_node import SimNode


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


class Monitor(Node):
    """The latest status of each name heard on /diagnostics."""

    def __init__(self, **kwargs) -> None:
        super().__init__('monitor', **kwargs)
        self.lock = threading.Lock()
        self.latest: dict[str, DiagnosticStatus] = {}
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on, 100)

    def _on(self, msg: DiagnosticArray) -> None:
        with self.lock:
            for status in msg.status:
                self.latest[status.name] = status

    def values(self, name: str) -> dict[str, str] | None:
        with self.lock:
            status = self.latest.get(name)
        return None if status is None else {kv.key: kv.value for kv in status.values}

    def level(self, name: str) -> int:
        with self.lock:
            return int.from_bytes(self.latest[name].level, 'big')


def test_every_node_publishes_its_status_on_diagnostics(ros, tmp_path):
    problem = load_problem('acrobot')
    monitor = ros.start(Monitor)
    ros.start(RecorderNode, params={'output_dir': str(tmp_path)})
    ros.start(TrainerNode)
    ExemplarPolicy(problem, problem.initial_state[None, :], [2]).save(tmp_path / 'p.json')
    ros.start(PolicyNode, params={'policy_file': str(tmp_path / 'p.json')})
    ros.start(SimNode, params={'mode': 'lockstep', 'republish_period': 0.05,
                               'max_episodes': 1})
    sim = ros.wait_for(lambda: (v := monitor.values('sim: simulator'))
                       and int(v['total_steps']) > 0 and v, 'the simulator status')
    assert sim['mode'] == 'lockstep' and int(sim['episode']) >= 1
    assert {'late_commands', 'dropped_commands', 'sim_time'} <= set(sim)
    pol = ros.wait_for(lambda: (v := monitor.values('policy_node: policy'))
                       and int(v['answered']) > 0 and v, 'the policy status')
    assert pol['policy'] == str(tmp_path / 'p.json') and pol['exemplars'] == '1'
    assert monitor.level('policy_node: policy') == 0
    rec = ros.wait_for(lambda: (v := monitor.values('recorder_node: recorder'))
                       and int(v['messages']) > 0 and v, 'the recorder status')
    assert rec['bag'].startswith(str(tmp_path)) and rec['write_errors'] == '0'
    trainer = ros.wait_for(lambda: monitor.values('trainer_node: training'),
                           'the trainer status')
    assert trainer['state'] == 'idle'


def test_a_policy_node_without_a_policy_warns_on_diagnostics(ros):
    monitor = ros.start(Monitor)
    ros.start(PolicyNode)
    ros.wait_for(lambda: monitor.values('policy_node: policy'), 'the policy status')
    assert monitor.level('policy_node: policy') == 1           # WARN
    assert monitor.values('policy_node: policy')['policy'] == 'none'
