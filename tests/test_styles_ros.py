"""Every exemplar style deployed through ROS 2: a lockstep episode of the policy node (real
rclpy nodes over Fast DDS) equals the offline evaluation bit for bit, for two episodes in a
row (the via-point list starts again with each episode)."""
from __future__ import annotations

import numpy as np
import pytest

from ros_helpers import isolated_ros, run_lockstep
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.styles import STYLES
from sapga_ros.optim.operators import random_exemplars
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


@pytest.mark.parametrize('style,problem_name', [(s, 'acrobot') for s in STYLES]
                         + [('state-state', 'pdip'), ('via-point', 'mountain_car')])
def test_lockstep_episode_of_every_style_equals_offline(ros, tmp_path, style, problem_name):
    """States, actions, rewards, reported exemplar indices and the end event agree."""
    problem = load_problem(problem_name)
    policy = random_exemplars(problem, 60, np.random.default_rng(21), style)
    delta = 0.3 if problem_name != 'mountain_car' else 0.0
    ep = Evaluator(problem, delta).episode(policy)
    probe, sim = run_lockstep(ros, problem, policy, tmp_path / 'policy.json', delta)
    layout = JointStateLayout(problem)
    for k in (1, 2):
        end = probe.end_of(k)
        assert (end['step'], end['return'], end['delta_star']) == (ep.steps, ep.ret,
                                                                   ep.delta_star)
    states = [m for _, m in sorted(probe.states.items())]
    assert len(states) >= 2 * ep.steps + 1
    for k in range(2):  # episode k+1 starts after the first one's last state
        first = k * (ep.steps + 1)
        got = np.array([layout.from_msg(m) for m in states[first:first + ep.steps + 1]])
        assert np.array_equal(got, ep.states), f'episode {k + 1}'
    assert probe.commands[:ep.steps] == list(ep.actions)
    assert probe.rewards[:ep.steps] == list(ep.rewards)
    assert probe.indices[:ep.steps] == list(ep.exemplars)
