"""The classical controller designed for an actuation delay (``delay`` d): it remembers the
commands in flight and acts on the state the model predicts for when its command arrives.

Properties: on the undisturbed plant that applies each command d steps late, its episode is
the undelayed controller's episode d steps later (the prediction is the plant's own step),
so it holds the upright acrobot where the undelayed design falls; the policy node's selector
remembers and resets the same way as the engine; the ``delay`` of a policy file round-trips
and a bad one is refused with one line.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from sapga_ros.errors import PolicyFileError
from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.policies.classical import with_catch
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import policy_from_json
from sim_nodes.disturbance import Disturbance
from sim_nodes.goal import delta_of
from process_helpers import sapga_in_process
from sim_nodes.problem import load_problem

STEPS = 1000


def sapga(*args):
    """``sapga ARGS`` in this process (the commands' own processes are tested in
    test_cli.py)."""
    return sapga_in_process(list(args))


@pytest.fixture(scope='module')
def acrobot():
    return load_problem('acrobot_hold')


def near_top(problem):
    """The hold problem started just off the upright state (inside the catch region)."""
    start = problem.best_state + np.array([0.002, -0.003, 0.01, -0.01])
    return dataclasses.replace(problem, initial=tuple(start), n_step=STEPS)


def episode(policy, problem, latency):
    policy.problem = problem
    late = Disturbance(name='late', latency=latency) if latency else None
    return Evaluator(problem, disturbance=late).episode(policy)


def worst_delta(problem, ep) -> float:
    return max(delta_of(problem, s) for s in ep.states)


@pytest.mark.parametrize('d', [1, 2])
def test_the_delayed_design_holds_the_top_under_its_latency(acrobot, d):
    """Under latency d (no noise) the delay-d controller holds all 1000 steps inside the goal
    box, and its worst delta is no larger than the undelayed design's on the same plant."""
    pr = near_top(acrobot)
    delayed = episode(classical_policy(acrobot, delay=d), pr, d)
    plain = episode(classical_policy(acrobot), pr, d)
    assert delayed.steps == plain.steps == STEPS
    assert worst_delta(pr, delayed) <= pr.default_delta
    assert delayed.summary()['hold_fraction'] == 1.0
    assert worst_delta(pr, delayed) <= worst_delta(pr, plain)


@pytest.mark.parametrize('d', [1, 3])
def test_the_delayed_episode_is_the_undelayed_one_d_steps_later(acrobot, d):
    """The prediction is the plant's own MDP step, so on the undisturbed plant with latency d
    the states from step d on are the undelayed controller's from the state reached after
    the d steps before the first command arrives."""
    pr = near_top(acrobot)
    policy = classical_policy(acrobot, delay=d)
    delayed = episode(policy, pr, d)
    assert np.all(delayed.actions[:d] == 0.0)
    after = dataclasses.replace(pr, initial=tuple(delayed.states[d]), n_step=STEPS - d)
    plain = episode(classical_policy(acrobot, c=policy.c), after, 0)
    assert np.array_equal(delayed.states[d:], plain.states)
    assert np.array_equal(delayed.actions[d:], plain.actions)


def test_the_node_selector_remembers_and_resets_like_the_engine(acrobot):
    """StateSelector (the policy node's path) replays the engine's traced episode of a delay-2
    controller action for action, twice: reset() empties the commands in flight."""
    policy = classical_policy(acrobot, delay=2)
    ep = Evaluator(acrobot).episode(policy)
    selector = StateSelector(policy)
    assert selector.stateful
    for _ in range(2):
        selector.reset()
        got = [selector.select(s)[1] for s in ep.states[:-1]]
        assert got == list(ep.actions)
    assert not StateSelector(classical_policy(acrobot, c=policy.c)).stateful


def test_delay_round_trips_in_classical_and_hybrid_files(acrobot):
    """delay is stored (written only when not 0, so undelayed files are as before) and read
    back into the same controller row."""
    policy = classical_policy(acrobot, delay=1)
    back = policy_from_json(policy.to_json(), acrobot)
    assert back.delay == 1 and np.array_equal(back.control, policy.control)
    assert json.loads(policy.to_json())['controller']['delay'] == 1
    one = ExemplarPolicy(acrobot, acrobot.initial_state[None, :], np.array([0]))
    hybrid = with_catch(one, policy)
    doc = json.loads(hybrid.to_json())
    assert doc['catch']['delay'] == 1
    assert policy_from_json(hybrid.to_json(), acrobot).delay == 1
    plain = classical_policy(acrobot, c=policy.c)
    assert 'delay' not in json.loads(plain.to_json())['controller']
    assert policy_from_json(plain.to_json(), acrobot).delay == 0


@pytest.mark.parametrize('value', [-1, 17, 1.5, True, '1', None])
def test_a_bad_delay_is_refused_naming_the_field(acrobot, value):
    doc = json.loads(classical_policy(acrobot, delay=1).to_json())
    doc['controller']['delay'] = value
    with pytest.raises(PolicyFileError, match=r'controller\.delay: expected an integer'):
        policy_from_json(json.dumps(doc), acrobot)


def test_bad_delays_on_the_command_line_and_in_files_are_user_errors(tmp_path):
    """Exit 2 without a traceback, the last line naming the delay (a file's: its only line)."""
    out = tmp_path / 'c.json'
    r = sapga('classical', '--problem', 'acrobot_hold', '--delay', '1', '--out', out)
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert doc['controller']['delay'] == 1 and doc['meta']['latency'] == 1
    doc['controller']['delay'] = -2
    bad = tmp_path / 'bad.json'
    bad.write_text(json.dumps(doc))
    r = sapga('eval', bad)
    assert r.returncode == 2 and r.stderr.strip().count('\n') == 0
    assert 'controller.delay: expected an integer' in r.stderr
    for args in (
                 ('classical', '--problem', 'acrobot_hold', '--delay', '-1', '--out',
                  tmp_path / 'x.json'),
                 ('train', '--problem', 'acrobot_hold', '--catch-delay', '1', '--steps', '1000',
                  '--quiet', '--out', tmp_path / 'y.json')):
        r = sapga(*args)
        assert r.returncode == 2 and 'Traceback' not in r.stderr, args
        assert 'delay' in r.stderr.strip().splitlines()[-1], args
    assert not (tmp_path / 'x.json').exists() and not (tmp_path / 'y.json').exists()


def test_a_lockstep_ros_episode_of_a_delayed_controller_equals_sapga_eval(tmp_path, capsys):
    """The delay-1 classical policy through the policy node (its selector remembers the
    commands in flight and forgets them when the episode starts): the lockstep hold episode
    equals sapga eval, hold measures included."""
    from sapga_ros.cli import main as cli
    from test_launch import lockstep_hold_equals_eval
    assert cli.main(['classical', '--problem', 'acrobot_hold', '--delay', '1', '--out',
                     str(tmp_path / 'c.json')]) == 0
    end, _ = lockstep_hold_equals_eval('c.json', tmp_path, capsys)
    assert end['step'] == STEPS
