"""The planner's model fit (``sapga_ros.evaluation.model_fit``): on the plant it was built
for it stays the nominal model bit for bit; on a plant whose masses and lengths are off it
predicts the plant's next states far better than the nominal model does; a re-planned
episode with the fit on an undisturbed plant is the episode without it."""
import numpy as np
import pytest

from sapga_ros.evaluation.evaluator import model_id
from sapga_ros.evaluation.model_fit import MIN_SEEN, ModelFit, fitted_entries
from sapga_ros.evaluation.replan import Replanner, first_plan, planned_episodes
from sapga_ros.evaluation.replan_settings import ReplanSettings
from sapga_ros.optim.operators import random_exemplars
from sim_nodes.disturbance import Plant, parse_disturbance
from sim_nodes.errors import ConfigError
from sim_nodes.models import model_module
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import load_problem

OFF = {'masses': 0.05, 'lengths': 0.05}


def transitions(problem, plant, actions, seen_noise=0.0, seed=0):
    """(x, a, y) of the plant driven by ``actions``; x, y as a sensor of ``seen_noise``
    sees them."""
    rng = np.random.default_rng(seed)
    s = problem.initial_state.astype(np.float64).copy()
    S, a, r = np.empty((problem.dim, 1)), np.empty(1), np.empty(1)
    out, seen = [], s + rng.normal(0, seen_noise, problem.dim) if seen_noise else s.copy()
    for value in actions:
        a[0] = value
        S[:, 0] = s
        step_lanes(model_id(problem.model), S, a, plant, 1, r)
        s = S[:, 0].copy()
        after = s + rng.normal(0, seen_noise, problem.dim) if seen_noise else s.copy()
        out.append((seen, float(value), after))
        seen = after
    return out


def one_step_error(problem, params, data):
    """Root mean square of the next states ``params`` predicts for ``data`` against the
    states seen (angles the short way round)."""
    S, a, r = np.empty((problem.dim, 1)), np.empty(1), np.empty(1)
    err = []
    for x, value, y in data:
        S[:, 0], a[0] = x, value
        step_lanes(model_id(problem.model), S, a, params, 1, r)
        d = y - S[:, 0]
        d[problem.is_angle] = (d[problem.is_angle] + np.pi) % (2 * np.pi) - np.pi
        err.append(d)
    return float(np.sqrt(np.mean(np.square(err))))


def swing(problem, n, seed):
    """Bang-bang commands held for a few steps: motion that shows the physics."""
    rng = np.random.default_rng(seed)
    values = np.asarray(problem.action_values, dtype=np.float64)
    return np.repeat(rng.choice(values[[0, -1]], n // 5 + 1), 5)[:n]


def mismatched(problem, episode):
    plant = Plant(problem, parse_disturbance({'mismatch': OFF}, 'off'))
    plant.reset((0, 0, 1, episode))
    return plant.params


def test_the_fitted_entries_are_the_masses_and_lengths():
    problem = load_problem('acrobot')
    names = ('dt', 'substeps') + tuple(model_module(problem.model).PARAMS)
    assert [names[i] for i in fitted_entries(problem)] == ['m1', 'm2', 'l1', 'lc1', 'lc2']


@pytest.mark.parametrize('name', ['acrobot', 'pdip'])
def test_on_its_own_model_the_fit_is_the_nominal_model_bit_for_bit(name):
    problem = load_problem(name)
    fit = ModelFit(problem, model_id(problem.model), 0.05)
    for x, a, y in transitions(problem, problem.params(), swing(problem, 60, 1)):
        fit.add(x, a, y)
    assert fit.count == 60
    assert np.array_equal(fit.params, problem.params())


@pytest.mark.parametrize('episode', range(4))
def test_on_a_plant_that_is_off_the_fit_predicts_it_far_better_than_the_nominal(episode):
    problem = load_problem('acrobot')
    plant = mismatched(problem, episode)
    entries = fitted_entries(problem)
    assert np.max(np.abs(plant[entries] / problem.params()[entries] - 1)) > 0.01
    fit = ModelFit(problem, model_id(problem.model), 0.05)
    seen = transitions(problem, plant, swing(problem, 160, episode), 0.002, episode)
    for x, a, y in seen[:120]:
        fit.add(x, a, y)
    test = transitions(problem, plant, swing(problem, 200, 100 + episode))[100:]
    nominal, fitted = (one_step_error(problem, p, test) for p in (problem.params(), fit.params))
    assert fitted < 0.25 * nominal, (fitted, nominal)


def test_a_lost_state_or_a_value_that_is_not_finite_does_not_spoil_the_fit():
    """Two steps seen as one (a state lost on the way) weigh like a few ordinary
    transitions (Huber's loss): the fit still predicts far better than the nominal model; a
    transition with a NaN is not kept."""
    problem = load_problem('acrobot')
    plant = mismatched(problem, 0)
    data = transitions(problem, plant, swing(problem, 160, 0), 0.002, 0)
    test = transitions(problem, plant, swing(problem, 200, 100))[100:]
    nominal = one_step_error(problem, problem.params(), test)
    fit = ModelFit(problem, model_id(problem.model), 0.05)
    for k, (x, a, y) in enumerate(data[:120]):
        if k == 61:
            continue
        fit.add(x, a, data[k + 1][2] if k == 60 else y)
        if k == 62:
            assert one_step_error(problem, fit.params, test) < 0.5 * nominal
    assert one_step_error(problem, fit.params, test) < 0.25 * nominal
    count, params = fit.count, fit.params.copy()
    fit.add(data[0][0], float('nan'), data[0][2])
    fit.add(np.full(problem.dim, np.nan), 0.0, data[0][2])
    assert fit.count == count and np.array_equal(fit.params, params)


def test_the_fit_starts_after_a_few_transitions_and_reset_forgets_them():
    problem = load_problem('acrobot')
    plant = mismatched(problem, 0)
    fit = ModelFit(problem, model_id(problem.model), 0.05)
    data = transitions(problem, plant, swing(problem, 40, 0))
    for k, (x, a, y) in enumerate(data, 1):
        fit.add(x, a, y)
        assert np.array_equal(fit.params, problem.params()) == (k < MIN_SEEN)
    fit.reset()
    assert fit.count == 0 and np.array_equal(fit.params, problem.params())


def test_the_planner_plans_on_the_fitted_model():
    """On a plant whose masses and lengths are off, the planner's model moves off the
    nominal one after a few steps, towards the plant's (it predicts the plant's next state
    better than the nominal model), and starts again nominal with the next episode."""
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 40, np.random.default_rng(3), 'state-action')
    settings = ReplanSettings(replan_rounds=1, replan_fit=0.05)
    planner = Replanner(problem, first_plan(policy, 150, 0.3), settings, 0.3, delay=1)
    plant = Plant(problem, parse_disturbance({'mismatch': OFF, 'latency': 1}, 'off'), 150)
    s = plant.reset((0, 0, 1, 2))
    S, a, r = np.empty((problem.dim, 1)), np.empty(1), np.empty(1)
    for t in range(40):
        a[0] = plant.command(planner.act(plant.observe(s)))
        S[:, 0] = s
        step_lanes(model_id(problem.model), S, a, plant.params, 1, r)
        s = S[:, 0].copy()
        plant.advance()
        if t == MIN_SEEN - 1:
            assert np.array_equal(planner.p, problem.params())     # not yet fitted
    assert not np.array_equal(planner.p, problem.params())
    test = transitions(problem, plant.params, swing(problem, 100, 7))
    assert one_step_error(problem, planner.p, test) < \
        0.5 * one_step_error(problem, problem.params(), test)
    planner.reset()
    assert np.array_equal(planner.p, problem.params())


def test_a_replanned_episode_on_its_own_model_is_the_same_with_the_fit():
    """On the model itself, its commands arriving as late as the planner was told, the fit
    stays the model: the same episode."""
    problem = load_problem('acrobot')
    policy = random_exemplars(problem, 40, np.random.default_rng(3), 'state-action')
    plain, fitting = ReplanSettings(replan_rounds=3), ReplanSettings(replan_rounds=3,
                                                                     replan_fit=0.05)
    for delay, profile in ((0, 'none'), (1, 'latency')):
        a = planned_episodes(policy, 0.3, profile, 1, 0, plain, delay, 150)
        b = planned_episodes(policy, 0.3, profile, 1, 0, fitting, delay, 150)
        assert a == b
    assert len(first_plan(policy, 150, 0.3)) == 150


@pytest.mark.parametrize('value', [-0.1, 1.5, float('nan')])
def test_a_prior_out_of_range_is_refused_with_its_line(value):
    with pytest.raises(ConfigError, match='replan_fit: expected a number'):
        ReplanSettings(replan_fit=value)
