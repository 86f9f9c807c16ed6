"""A problem YAML is checked whole before anything starts: every section (``ros:``
included), bounded sizes, and physics that cannot give a number refused up front; a state
that is not a number never counts as reaching the goal."""
from __future__ import annotations

import dataclasses
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from domains import ros_domain
from sapga_ros.errors import ConfigError
from sim_nodes.goal import delta_of
from sim_nodes.problem import config_dir, load_problem, parse_problem


def _acrobot() -> dict:
    return yaml.safe_load((config_dir() / 'acrobot.yaml').read_text())


def _parse(doc: dict):
    return parse_problem(doc, 'acrobot.yaml')


@pytest.mark.parametrize('ros,word', [
    (5, 'ros: expected a mapping'),
    ({'joints': 5}, 'ros.joints: expected a list'),
    ({'joints': ['shoulder']}, "ros.joints: 'elbow'"),
    ({'joints': ['shoulder', 'elbow', 'elbow']}, 'duplicate'),
    ({'joints': ['shoulder', 'elbow', 'a b']}, 'ros.joints'),
    ({'frame_id': 5}, 'ros.frame_id'),
    ({'frame_id': '/x y'}, 'ros.frame_id'),
    ({'topics': 5}, 'ros.topics: expected a mapping'),
    ({'topics': {'state': 'bad name!'}}, 'ros.topics.state'),
    ({'topics': {'state': ''}}, 'ros.topics.state'),
    ({'topics': {'state': 7}}, 'ros.topics.state'),
    ({'topics': {'stat': 'joint_states'}}, "ros.topics: unknown key 'stat'"),
    ({'qos': [1]}, 'ros.qos: expected a mapping'),
    ({'qos': {'depth': 10 ** 9}}, 'ros.qos.depth'),
    ({'qos': {'depth': 0}}, 'ros.qos.depth'),
    ({'qos': {'depth': True}}, 'ros.qos.depth'),
    ({'qos': {'reliability': 'maybe'}}, 'ros.qos.reliability'),
    ({'qos': {'durability': 3}}, 'ros.qos.durability'),
    ({'qos': {'dept': 3}}, "ros.qos: unknown key 'dept'"),
    ({'topic': {}}, "ros: unknown key 'topic'"),
    # two roles on one topic: each carries its own message type
    ({'topics': {'state': 'joint_states', 'reward': 'joint_states'}},
     "ros.topics.reward: 'joint_states' is the topic of ros.topics.state"),
    ({'topics': {'state': 'x', 'command': 'x'}}, "ros.topics.command: 'x'"),
    ({'topics': {'event': '/reward'}}, "ros.topics.event: '/reward' is the topic of "
                                       'ros.topics.reward'),
    ({'topics': {'markers': 'exemplar_index'}}, 'ros.topics.markers'),
    # nor on one the nodes publish otherwise
    ({'topics': {'state': '/clock'}}, "ros.topics.state: '/clock' is the topic of the nodes'"),
    ({'topics': {'reward': 'diagnostics'}}, 'ros.topics.reward'),
    ({'topics': {'command': 'effort_controller/commands'}}, 'ros.topics.command'),
])
def test_a_bad_ros_section_is_refused_naming_the_field(ros, word):
    doc = _acrobot()
    doc['ros'] = {**doc['ros'], **ros} if isinstance(ros, dict) else ros
    with pytest.raises(ConfigError, match=r'^acrobot\.yaml: ') as err:
        _parse(doc)
    assert word in str(err.value)


@pytest.mark.parametrize('section,key,value,word', [
    ('episode', 'substeps', 1e12, 'episode.substeps: at most'),
    ('episode', 'n_step', 10 ** 9, 'episode.n_step: at most'),
    ('episode', 'ends_in_goal', 'yes', 'episode.ends_in_goal'),
    ('q_learning', 'tiles_per_dim', 10 ** 6, 'q_learning.tiles_per_dim: at most'),
    ('physics', 'm1', 0, 'physics.m1: must be > 0'),
    ('physics', 'I2', -1.0, 'physics.I2: must be > 0'),
    ('physics', 'lc2', 0.0, 'physics.lc2: must be > 0'),
    ('physics', 'g', 1e308, 'non-finite state or reward'),
    ('episode', 'dt', 1e300, 'non-finite'),
])
def test_values_that_cannot_work_are_refused(section, key, value, word):
    doc = _acrobot()
    doc[section][key] = value
    with pytest.raises(ConfigError) as err:
        _parse(doc)
    assert word in str(err.value)


@pytest.mark.parametrize('x_min,x_max', [(0.5, 0.5), (0.6, 0.5), (-1.2, -1.3)])
def test_a_track_whose_ends_do_not_increase_is_refused(x_min, x_max):
    """Mountain car's x_min must lie below x_max (a zero-width track trained before)."""
    doc = yaml.safe_load((config_dir() / 'mountain_car.yaml').read_text())
    doc['physics'].update(x_min=x_min, x_max=x_max)
    with pytest.raises(ConfigError, match=r'^mountain_car\.yaml: physics\.x_min \(.*\) must be '
                                          r'below physics\.x_max'):
        parse_problem(doc, 'mountain_car.yaml')
    doc['physics'].update(x_min=-1.2, x_max=0.5)
    assert parse_problem(doc, 'mountain_car.yaml').physics['x_min'] == -1.2


def test_actions_are_bounded_and_any_count_is_accepted():
    doc = _acrobot()
    doc['actions'] = [float(a) for a in range(1000)]
    with pytest.raises(ConfigError, match='actions: at most'):
        _parse(doc)
    doc['actions'] = [-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0]   # nine levels
    assert len(_parse(doc).actions) == 9


@pytest.mark.parametrize('value', [True, False])
def test_ends_in_goal_is_accepted_as_a_bool(value):
    doc = _acrobot()
    doc['episode']['ends_in_goal'] = value
    assert _parse(doc).name == 'acrobot'


def test_a_nan_state_is_never_in_the_goal_area():
    for name in ('acrobot', 'pdip', 'mountain_car'):
        problem = load_problem(name)
        s = problem.best_state.copy()
        assert delta_of(problem, s) == 0.0 or name == 'mountain_car'
        s[0] = math.nan
        assert delta_of(problem, s) == math.inf


def test_an_episode_of_nan_physics_never_reaches_the_goal():
    """Physics that gives nan (zero masses, let past the checks here) must not read as the
    goal reached by any evaluator: nan states are at delta infinity."""
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.policies.exemplar import ExemplarPolicy
    good = load_problem('acrobot')
    bad = dataclasses.replace(good, physics={**good.physics, 'm1': 0.0, 'm2': 0.0,
                                             'I1': 0.0, 'I2': 0.0})
    policy = ExemplarPolicy(bad, bad.initial_state[None, :], [0])
    ep = Evaluator(bad, 0.02).episode(policy)
    assert not ep.reached and not math.isfinite(ep.ret)
    assert ep.delta_star == delta_of(good, good.initial_state)


def _conf(tmp_path: Path, edit) -> dict:
    conf = tmp_path / 'conf'
    shutil.copytree(config_dir(), conf)
    doc = _acrobot()
    edit(doc)
    (conf / 'acrobot.yaml').write_text(yaml.safe_dump(doc))
    return {**os.environ, 'SAPGA_CONFIG_DIR': str(conf)}


@pytest.mark.parametrize('edit,word', [
    (lambda d: d['physics'].update(m1=0.0, m2=0.0, I1=0.0, I2=0.0), 'physics.m1'),
    (lambda d: d['episode'].update(substeps=1e12), 'episode.substeps'),
    (lambda d: d['ros']['qos'].update(depth='deep'), 'ros.qos.depth'),
])
def test_train_refuses_such_a_problem_in_one_line(tmp_path, edit, word):
    """Through the command: exit 2, one line, nothing trained (no 'goal achieved')."""
    done = subprocess.run([sys.executable, '-m', 'sapga_ros.cli.main', 'train', '--problem',
                           'acrobot', '--steps', '2000', '--out', str(tmp_path / 'o')],
                          capture_output=True, text=True, timeout=300,
                          env=_conf(tmp_path, edit))
    assert done.returncode == 2 and 'Traceback' not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and word in done.stderr
    assert not (tmp_path / 'o').exists() or not any((tmp_path / 'o').iterdir())


def test_the_simulator_node_refuses_a_bad_ros_section_in_one_line(tmp_path):
    """The simulator executable with a problem whose ros.topics holds a bad name: exit 2
    and one line, not a crash in rclpy."""
    env = _conf(tmp_path, lambda d: d['ros']['topics'].update(state='bad name!'))
    with ros_domain() as domain:
        env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        done = subprocess.run([sys.executable, '-m', 'sim_nodes.ros.sim_node', '--ros-args',
                               '-p', 'problem:=acrobot'], capture_output=True, text=True,
                              timeout=120, env=env)
    assert done.returncode == 2, done.stderr
    assert 'Traceback' not in done.stderr and 'ros.topics.state' in done.stderr
    assert np.sum([('ros.topics.state' in line) for line in done.stderr.splitlines()]) == 1
