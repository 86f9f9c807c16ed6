"""The ROS simulator node disturbs its plant as the episode engine does: a lockstep episode
of the policy node against a disturbed simulator (real rclpy nodes over DDS) ends where the
engine's disturbed episode of the same draws ends, with the same return and delta*, and the
policy node answered the noisy states it was sent."""
from __future__ import annotations

import numpy as np
import pytest

from ros_helpers import isolated_ros, run_lockstep
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.operators import random_exemplars
from sim_nodes.disturbance import Disturbance, load_disturbance
from sim_nodes.draws import HELD_OUT
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


def test_lockstep_episodes_of_a_disturbed_simulator_equal_the_engine(ros, tmp_path):
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 60, np.random.default_rng(21), 'state-action')
    profile = tmp_path / 'bench.yaml'
    profile.write_text('initial_spread: 0.02\nsensor_sigma: 0.002\nlatency: 1\n'
                       'mismatch: {masses: 0.05, lengths: 0.05}\ngain: 0.05\n'
                       'pushes: {count: 2, size: 0.3}\n')
    disturbance = load_disturbance(str(profile))
    assert disturbance != Disturbance() and disturbance.pushes == 2
    ev = Evaluator(problem, 0.3, disturbance=disturbance)
    eps = [ev.episode(policy, (7, 0, HELD_OUT, k)) for k in range(2)]
    probe, sim = run_lockstep(ros, problem, policy, tmp_path / 'policy.json', 0.3,
                              disturbance=str(profile), disturbance_seed=7)
    layout = JointStateLayout(problem)
    states = [layout.from_msg(m) for _, m in sorted(probe.states.items())]
    start = 0
    for k, ep in enumerate(eps, 1):
        end = probe.end_of(k)
        assert (end['step'], end['return'], end['delta_star']) == (ep.steps, ep.ret,
                                                                   ep.delta_star)
        seen = np.array(states[start:start + ep.steps + 1])
        noise = seen - ep.states
        noise[:, problem.is_angle] = (noise[:, problem.is_angle] + np.pi) % (2 * np.pi) - np.pi
        assert 0 < np.max(np.abs(noise)) < 0.02           # published: the state + sigma 0.002
        start += ep.steps + 1
    chosen = problem.action_values[policy.actions[eps[0].exemplars]]
    assert probe.commands[:eps[0].steps] == list(chosen)  # what the policy answered
    assert sim._plant.on


@pytest.mark.parametrize('how', ['file', 'node'])
def test_a_policy_designed_for_the_delay_runs_over_ros_as_in_the_engine(ros, tmp_path, how):
    """A delay-1 policy (the file's own ``delay``, or a plain file run by a policy node with
    ``delay:=1``) against a simulator with one step of latency and model error: each lockstep
    episode ends where the engine's ends, the node predicting with the commands in flight and
    forgetting them when an episode starts (the problem's initial state)."""
    from sapga_ros.policies.classical import ahead
    problem = load_problem('acrobot')
    plain = random_exemplars(problem, 60, np.random.default_rng(22), 'state-action')
    policy = ahead(plain, 1)
    profile = tmp_path / 'late.yaml'
    profile.write_text('latency: 1\nmismatch: {masses: 0.05, lengths: 0.05}\n')
    ev = Evaluator(problem, 0.3, disturbance=load_disturbance(str(profile)))
    eps = [ev.episode(policy, (9, 0, HELD_OUT, k)) for k in range(2)]
    assert ev.episode(plain, (9, 0, HELD_OUT, 0)).ret != eps[0].ret   # the prediction acts
    probe, _ = run_lockstep(ros, problem, policy if how == 'file' else plain,
                            tmp_path / 'policy.json', 0.3,
                            policy_params={'delay': 1} if how == 'node' else None,
                            disturbance=str(profile), disturbance_seed=9)
    for k, ep in enumerate(eps, 1):
        end = probe.end_of(k)
        assert (end['step'], end['return'], end['delta_star']) == (ep.steps, ep.ret,
                                                                   ep.delta_star)
