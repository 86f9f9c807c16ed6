"""The planner's Kalman filter (``sapga_ros.evaluation.state_filter``): on an exact,
noiseless plant it is the state itself, bit for bit, so a filtered planner plays the
unfiltered planner's episodes; under sensor noise its estimate is nearer the true state than
what the sensors say."""
import numpy as np
import pytest

from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.evaluator import model_id
from sapga_ros.evaluation.replan import Replanner, first_plan, planned_episodes
from sapga_ros.evaluation.replan_settings import ReplanSettings
from sapga_ros.evaluation.state_filter import StateFilter, filter_gain
from sapga_ros.optim.operators import random_exemplars
from sapga_ros.policies.lqr import regulator
from sim_nodes.disturbance import Disturbance, Plant
from sim_nodes.errors import ConfigError
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import load_problem


def test_on_the_exact_plant_the_estimate_is_the_state_and_the_episodes_unchanged(rng):
    """With one step of latency the filter must step its estimate with the command in flight
    (not the one just issued) to find the state seen again, bit for bit."""
    problem = load_problem('acrobot_hold')
    plain = ReplanSettings(replan_rounds=1, replan_every=10)
    filtered = ReplanSettings(replan_rounds=1, replan_every=10, replan_filter=0.002)
    policy = classical_policy(problem)
    late = Disturbance(name='late', latency=1)
    for profile, delay in (('none', 0), (late, 1)):
        assert planned_episodes(policy, 0.02, profile, 1, 0, plain, delay, 300) == \
            planned_episodes(policy, 0.02, profile, 1, 0, filtered, delay, 300)
    swing = load_problem('acrobot')
    guess = random_exemplars(swing, 20, rng)
    assert planned_episodes(guess, 0.47, late, 2, 0, plain, delay=1, n_step=200) == \
        planned_episodes(guess, 0.47, late, 2, 0, filtered, delay=1, n_step=200)
    # the planner's own estimate, step by step, on the plant with latency
    planner = Replanner(problem, first_plan(policy, 300, 0.02), filtered, 0.02, 1)
    plant = Plant(problem, late, 300)
    s = plant.reset((0, 0, 0, 0))
    S, a, r = np.empty((problem.dim, 1)), np.empty(1), np.empty(1)
    for _ in range(300):
        a[0] = plant.command(planner.act(plant.observe(s)))
        assert np.array_equal(planner.filter.estimate, s)
        S[:, 0] = s
        step_lanes(planner.model, S, a, plant.params, 1, r)
        s = S[:, 0].copy()
        plant.advance()


def test_under_noise_the_filtered_planner_plays_another_episode():
    problem = load_problem('acrobot_hold')
    policy = classical_policy(problem)
    plain = ReplanSettings(replan_rounds=1, replan_every=10)
    filtered = ReplanSettings(replan_rounds=1, replan_every=10, replan_filter=0.002)
    noisy = Disturbance(name='noisy', sensor_sigma=0.002)
    assert planned_episodes(policy, 0.02, noisy, 1, 0, plain, 0, 200) != \
        planned_episodes(policy, 0.02, noisy, 1, 0, filtered, 0, 200)


def held_by_the_lqr(problem, sigma, steps):
    """(true states, states seen, estimates) of the LQR holding ``problem`` from upright on
    the state seen, the sensors adding noise ``sigma``."""
    reg = regulator(problem, 1e-4)
    model = model_id(problem.model)
    plant = Plant(problem, Disturbance(name='noisy', sensor_sigma=sigma), steps)
    flt = StateFilter(problem, model, sigma)
    s = plant.reset((0, 0, 0, 0))
    s[:] = problem.best_state
    S, a, r = np.empty((problem.dim, 1)), np.empty(1), np.empty(1)
    applied, out = 0.0, []
    actions = np.asarray(problem.action_values)
    for _ in range(steps):
        seen = plant.observe(s)
        est = flt.update(seen, applied, problem.params())
        x = est - problem.best_state
        x[problem.is_angle] = (x[problem.is_angle] + np.pi) % (2 * np.pi) - np.pi
        applied = float(actions[np.argmin(np.abs(actions + reg.K @ x))])
        out.append((s.copy(), seen, est))
        S[:, 0], a[0] = s, applied
        step_lanes(model, S, a, problem.params(), 1, r)
        s = S[:, 0].copy()
        plant.advance()
    return [np.array(v) for v in zip(*out)]


def test_under_sensor_noise_the_estimate_is_nearer_the_state_than_the_sensors():
    problem = load_problem('acrobot_hold')
    true, seen, est = held_by_the_lqr(problem, 0.002, 400)
    wrap = np.where(problem.is_angle, 2 * np.pi, np.inf)

    def rms(v):
        d = v[50:] - true[50:]
        d = np.where(np.isinf(wrap), d, (d + np.pi) % (2 * np.pi) - np.pi)
        return np.sqrt(np.mean(d ** 2, axis=0))

    raw, filtered = rms(seen), rms(est)
    assert np.all(raw > 0.0015)                        # the sensors' noise, sigma 0.002
    assert np.all(filtered < 0.6 * raw), (raw, filtered)          # measured 0.33-0.51
    assert np.all(filtered[problem.is_angle] < 0.4 * raw[problem.is_angle])
    # and the pendulum stays up on the filtered state
    offset = true[:, 0] - problem.best_state[0]
    assert np.max(np.abs(offset)) < 0.1


def test_the_gain_and_the_setting():
    problem = load_problem('acrobot_hold')
    L = filter_gain(problem, 0.002)
    assert L.shape == (4, 4) and np.all(np.isfinite(L))
    assert np.all(np.abs(np.linalg.eigvals(np.eye(4) - L)) < 1)   # corrects, never overshoots
    # noisier sensors: the estimate trusts the model more
    assert np.all(np.abs(np.diag(filter_gain(problem, 0.02))) < np.abs(np.diag(L)))
    assert np.all(np.abs(np.diag(filter_gain(problem, 0.0002))) > np.abs(np.diag(L)))
    for bad in (-0.1, 2.0, float('nan')):
        with pytest.raises(ConfigError, match='replan_filter'):
            ReplanSettings(replan_filter=bad)
