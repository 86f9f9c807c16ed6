"""Decision-time planning over ROS: a policy node with ``replan`` (real rclpy nodes over
DDS), fitting its model, against a simulator with a spread start, sensor noise, latency and
model error plays, episode by episode, the offline planned episode of the same draws
(``sapga_ros.evaluation.replan``), bit for bit: the plan and the fit start again at the
second episode's first state, which is not the problem's initial state."""
from __future__ import annotations

import numpy as np
import pytest

from ros_helpers import isolated_ros, run_lockstep
from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.replan import planned_episodes
from sapga_ros.evaluation.replan_settings import ReplanSettings
from sapga_ros.optim.operators import random_exemplars
from sim_nodes.goal import hold_measures
from sim_nodes.problem import load_problem


@pytest.fixture
def ros(monkeypatch, tmp_path):
    yield from isolated_ros(monkeypatch, tmp_path)


def test_a_replanning_policy_node_plays_the_offline_planned_episodes(ros, tmp_path):
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 40, np.random.default_rng(23), 'state-action')
    policy.meta = {'delta': 0.3}                    # the goal the planner plays for
    profile = tmp_path / 'late.yaml'
    profile.write_text('initial_spread: 0.02\nsensor_sigma: 0.002\nlatency: 1\n'
                       'mismatch: {masses: 0.05, lengths: 0.05}\n')
    settings = ReplanSettings(replan_rounds=2, replan_window=60, replan_every=3,
                              replan_seed=5, replan_fit=0.05)
    offline = planned_episodes(policy, 0.3, str(profile), 2, 9, settings, delay=1)
    assert offline[0]['return'] != offline[1]['return']        # two different plants
    assert all(o['steps'] >= 50 for o in offline)   # RESTART_AFTER: the next start is seen
    params = {'replan': True, 'delay': 1, 'replan_rounds': 2, 'replan_window': 60,
              'replan_every': 3, 'replan_seed': 5, 'replan_fit': 0.05}
    probe, _ = run_lockstep(ros, problem, policy, tmp_path / 'policy.json', 0.3,
                            policy_params=params, disturbance=str(profile),
                            disturbance_seed=9)
    for k, ep in enumerate(offline, 1):
        end = probe.end_of(k)
        assert (end['step'], end['return'], end['delta_star']) == \
            (ep['steps'], ep['return'], ep['delta_star'])
    assert set(probe.indices) == {-1}                           # no exemplar chose


def test_a_replanning_node_holds_as_the_offline_planner_does(ros, tmp_path):
    """A hold task over ROS: the policy node re-plans towards the LQR's region and hands over
    to it, fitting its model and filtering what it sees, against a `field` simulator; the
    episode's end event (the hold measures of the true state) is the offline planned
    episode's."""
    problem = load_problem('acrobot_hold')
    policy = classical_policy(problem)
    settings = ReplanSettings(replan_rounds=1, replan_every=10, replan_fit=0.05,
                              replan_filter=0.002)
    (offline,) = planned_episodes(policy, 0.02, 'field', 1, 11, settings, delay=1)
    params = {'replan': True, 'delay': 1, 'replan_rounds': 1, 'replan_every': 10,
              'replan_fit': 0.05, 'replan_filter': 0.002}
    probe, _ = run_lockstep(ros, problem, policy, tmp_path / 'hold.json', 0.02, episodes=1,
                            policy_params=params, disturbance='field', disturbance_seed=11)
    end = probe.end_of(1)
    held = hold_measures(offline['first_entry'], offline['held'], offline['steps'],
                         offline['contacts'])
    assert offline['first_entry'] > 0 and end['event'] == 'step_limit'
    assert (end['step'], end['return'], end['delta_star']) == \
        (offline['steps'], offline['return'], offline['delta_star'])
    assert {k: end[k] for k in held} == held


@pytest.mark.parametrize('args, words', [
    (('-p', 'replan:=true', '-p', 'replan_rounds:=0'), 'replan_rounds: expected an integer'),
])
def test_a_replanning_node_it_cannot_run_stops_with_one_line(ros, args, words):
    proc = ros.spawn('policy_node', '--ros-args', *args)
    proc.wait(120)
    lines = [line for line in ros.children[-1][1].read_text().splitlines() if line.strip()]
    assert proc.returncode == 2, lines
    assert len(lines) == 1 and words in lines[0] and 'Traceback' not in lines[0], lines
