"""Disturbances in the one episode engine: each kind checked as a physical property of the
traced episode (replayed through the model's own step), the undisturbed profile bit for bit
the plain engine, draws independent of batch, order and thread count."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sapga_ros.errors import ConfigError
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.optim.operators import random_policy
from sim_nodes.disturbance import Disturbance, load_disturbance, parse_disturbance
from sim_nodes.draws import S_PARAMS, episode_key, start_episode, symmetric
from sim_nodes.models import model_module

N = 80


@pytest.fixture(scope='module')
def policies(acrobot_problem):
    rng = np.random.default_rng(5)
    return [random_policy(acrobot_problem, rng, 50, 100, 'state-action') for _ in range(12)]


def ev(problem, disturbance=None) -> Evaluator:
    return Evaluator(problem, 0.0, n_step=N, disturbance=disturbance)


def replay(problem, ep, params=None, pushes=()) -> np.ndarray:
    """The states of the model driven by the episode's applied actions from its first state
    (``pushes``: (step, coordinate, velocity change) added before that step)."""
    p = problem.params() if params is None else params
    s = ep.states[0].copy()
    out = [s.copy()]
    for t, a in enumerate(ep.actions):
        for step, i, dv in pushes:
            if step == t:
                s[i] += dv
        model_module(problem.model).mdp_step(s, a, p)
        out.append(s.copy())
    return np.array(out)


def selected(problem, policy, ep) -> np.ndarray:
    """The action values of the exemplars the selector chose."""
    return problem.action_values[policy.actions[ep.exemplars]]


def same(a, b) -> None:
    for field in ('returns', 'steps', 'delta_star', 'reached', 'first_entry', 'held'):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    for u, v in zip(a.used, b.used):
        np.testing.assert_array_equal(u, v)


def test_none_and_zero_size_profiles_are_the_plain_engine(acrobot_problem, policies):
    plain = ev(acrobot_problem).evaluate(policies)
    none = ev(acrobot_problem, load_disturbance('none'))
    assert none.dist[0] == 0                    # the undisturbed path
    same(plain, none.evaluate(policies))
    zero = ev(acrobot_problem, dataclasses.replace(
        load_disturbance('field').scaled(0.0), pushes=3))   # the disturbed path, sizes 0
    assert zero.dist[0] == 1
    keys = np.arange(48).reshape(12, 4)
    same(plain, zero.evaluate(policies, keys))
    a, b = ev(acrobot_problem).episode(policies[0]), zero.episode(policies[0], (3, 1, 4, 1))
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.actions, b.actions)


def test_latency_shifts_the_actions_by_whole_steps(acrobot_problem, policies):
    for steps in (1, 3):
        d = Disturbance('late', latency=steps)
        ep = ev(acrobot_problem, d).episode(policies[1], (0, 0, 0, 0))
        chosen = selected(acrobot_problem, policies[1], ep)
        np.testing.assert_array_equal(ep.actions[:steps], 0.0)
        np.testing.assert_array_equal(ep.actions[steps:], chosen[:-steps])
        np.testing.assert_array_equal(replay(acrobot_problem, ep), ep.states)


def test_sensor_noise_changes_what_is_seen_not_the_plant(acrobot_problem, policies):
    d = Disturbance('noisy', sensor_sigma=0.3)
    plain = ev(acrobot_problem).episode(policies[2])
    ep = ev(acrobot_problem, d).episode(policies[2], (0, 0, 0, 0))
    np.testing.assert_array_equal(ep.states[0], acrobot_problem.initial_state)
    np.testing.assert_array_equal(ep.actions, selected(acrobot_problem, policies[2], ep))
    np.testing.assert_array_equal(replay(acrobot_problem, ep), ep.states)
    assert not np.array_equal(ep.exemplars, plain.exemplars)   # it chose from noisy states


def test_initial_spread_stays_within_its_bounds(acrobot_problem, policies):
    spread = {'theta1': 0.02, 'theta2_dot': 0.5}
    d = Disturbance('spread', initial_spread=spread)
    s0 = acrobot_problem.initial_state
    firsts = np.array([ev(acrobot_problem, d).episode(policies[0], (1, 0, 0, e)).states[0]
                       for e in range(40)])
    moved = firsts - s0
    np.testing.assert_array_equal(moved[:, [1, 2]], 0.0)
    assert np.all(np.abs(moved[:, 0]) <= 0.02) and np.all(np.abs(moved[:, 3]) <= 0.5)
    assert moved[:, 0].std() > 0.005 and moved[:, 3].std() > 0.1


def test_mismatch_is_the_model_with_drawn_parameters(acrobot_problem, policies):
    d = Disturbance('m', mismatch={'masses': 0.1, 'g': 0.2})
    key = (2, 0, 0, 5)
    ep = ev(acrobot_problem, d).episode(policies[3], key)
    p = acrobot_problem.params()
    names = ('dt', 'substeps') + model_module('acrobot').PARAMS
    q = p.copy()
    k = np.uint64(episode_key(*key))
    for name, size in (('m1', 0.1), ('m2', 0.1), ('g', 0.2)):
        i = names.index(name)
        q[i] = p[i] * (1.0 + symmetric(k, S_PARAMS, i, size))
        assert q[i] != p[i] and abs(q[i] / p[i] - 1) <= size
    np.testing.assert_array_equal(replay(acrobot_problem, ep, q), ep.states)
    assert not np.array_equal(replay(acrobot_problem, ep, p), ep.states)


def test_gain_scales_every_command_by_one_factor(acrobot_problem, policies):
    ep = ev(acrobot_problem, Disturbance('g', gain=0.2)).episode(policies[4], (0, 0, 0, 1))
    chosen = selected(acrobot_problem, policies[4], ep)
    ratio = ep.actions[chosen != 0] / chosen[chosen != 0]
    assert len(ratio) and np.all(ratio == ratio[0]) and 0.8 <= ratio[0] <= 1.2
    assert ratio[0] != 1.0
    np.testing.assert_array_equal(replay(acrobot_problem, ep), ep.states)


def test_pushes_are_velocity_changes_at_drawn_steps(acrobot_problem, policies):
    d = Disturbance('p', pushes=2, push_size=1.0)
    key = (0, 0, 0, 7)
    problem = acrobot_problem
    ep = ev(problem, d).episode(policies[5], key)
    at, dv, on = np.zeros(2, np.int64), np.zeros(2), np.zeros(2, np.int64)
    start_episode(d.pack(problem), np.uint64(episode_key(*key)), problem.initial_state,
                  problem.params(), problem.is_angle, N, np.zeros(4), np.zeros(12), at, dv, on)
    assert set(on) <= {2, 3} and np.all(np.abs(dv) <= 1.0)     # velocity coordinates
    np.testing.assert_array_equal(replay(problem, ep, pushes=list(zip(at, on, dv))),
                                  ep.states)
    assert not np.array_equal(replay(problem, ep), ep.states)


def test_draws_do_not_depend_on_batch_order_or_threads(acrobot_problem, policies):
    field = ev(acrobot_problem, load_disturbance('field'))
    keys = np.array([[9, 2, k % 3, k] for k in range(len(policies))])
    set_jobs(1)
    one = field.evaluate(policies, keys)
    set_jobs(2)
    two = field.evaluate(policies, keys)
    order = np.random.default_rng(1).permutation(len(policies))
    shuffled = field.evaluate([policies[k] for k in order], keys[order])
    set_jobs(0)
    same(one, two)
    np.testing.assert_array_equal(shuffled.returns, one.returns[order])
    alone = field.episode(policies[4], tuple(keys[4]))
    assert alone.ret == one.returns[4] and alone.steps == one.steps[4]
    other = field.evaluate(policies, keys + [[1, 0, 0, 0]])
    assert not np.array_equal(other.returns, one.returns)


def test_field_profile_is_the_fixed_one(acrobot_problem):
    d = load_disturbance('field')
    assert (d.initial_spread, d.sensor_sigma, d.latency, d.pushes) == (0.02, 0.002, 1, 0)
    assert d.mismatch == {'masses': 0.05, 'lengths': 0.05} and d.gain == 0.0
    packed = d.pack(acrobot_problem)
    names = ('dt', 'substeps') + model_module('acrobot').PARAMS
    sizes = dict(zip(names, packed[-len(names):]))
    assert {k for k, v in sizes.items() if v} == {'m1', 'm2', 'l1', 'lc1', 'lc2'}
    for name in ('none', 'sensor', 'latency', 'mismatch', 'push', 'field'):
        for problem in ('acrobot', 'pdip', 'pendulum'):
            from sim_nodes.problem import load_problem
            load_disturbance(name).pack(load_problem(problem))


@pytest.mark.parametrize('doc, message', [
    ({'latency': -1}, 'latency: expected an integer in [0, 1000]'),
    ({'sensor_sigma': 'x'}, 'sensor_sigma: expected a number'),
    ({'pushes': {'count': 1, 'size': 0.1, 'on': ['nope']}}, "pushes.on: 'nope'"),
    ({'mismatch': {'q9': 0.1}}, "mismatch: 'q9' is no physics entry"),
    ({'initial_spread': {'x': 0.1}}, "initial_spread: 'x' is no state coordinate"),
    ({'noise': 1}, "unknown key 'noise'"),
])
def test_bad_profiles_are_refused_with_one_line(acrobot_problem, doc, message):
    with pytest.raises(ConfigError, match='bad.yaml: ' + message.replace('[', r'\[')
                       .replace(']', r'\]')):
        parse_disturbance(doc, 'bad.yaml').pack(acrobot_problem)
    with pytest.raises(ConfigError, match='unknown disturbance'):
        load_disturbance('nosuchprofile')


def test_a_simulator_stepping_the_plant_reproduces_the_engine(acrobot_problem, policies):
    """``Plant``, step by step as the simulator node runs it, with the policy answering what
    it sees: the engine's traced episode, bit for bit, for every disturbance kind."""
    from sapga_ros.evaluation.state_selector import StateSelector
    from sim_nodes.disturbance import Plant
    d = dataclasses.replace(load_disturbance('field'), pushes=2, push_size=0.3, gain=0.1)
    key = (4, 0, 1, 2)
    ep = ev(acrobot_problem, d).episode(policies[6], key)
    states, actions = plant_episode(Plant(acrobot_problem, d, N), StateSelector(policies[6]),
                                    key, ep.steps)
    np.testing.assert_array_equal(states, ep.states)
    np.testing.assert_array_equal(actions, ep.actions)


def plant_episode(plant, selector, key, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(states, applied commands) of ``steps`` steps of ``plant`` (a ``Plant``) stepped as
    the simulator node steps it, ``selector`` (a ``StateSelector``) answering what it sees."""
    s = plant.reset(key)
    states, actions = [s.copy()], []
    step = model_module(plant.problem.model).mdp_step
    for _ in range(steps):
        a = plant.command(selector.select(plant.observe(s))[1])
        plant.push(s)
        step(s, a, plant.params)
        plant.advance()
        states.append(s.copy())
        actions.append(a)
    return np.array(states), np.array(actions)
