"""The Gymnasium environments (``sapga_ros.gym``): registered, valid for Gymnasium, and
the episode engine's problem bit for bit (kernel, reward, goal test, episode length)."""
from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.error import InvalidAction, ResetNeeded
from gymnasium.utils.env_checker import check_env

import sapga_ros.gym
from sapga_ros.errors import ConfigError
from sapga_ros.evaluation.engine import LANES
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.operators import random_policy
from sim_nodes.goal import delta_of
from sim_nodes.models import model_id
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import load_problem, problem_names

PROBLEMS = problem_names()


def make(name: str, **kwargs) -> gymnasium.Env:
    return gymnasium.make(sapga_ros.gym.ENV_IDS[name], **kwargs)


def run(env: gymnasium.Env, actions) -> tuple:
    """(observations with the reset one first, rewards, last terminated, last truncated,
    last info) of ``actions`` (indices) from a reset."""
    obs, info = env.reset(seed=0)
    states, rewards = [obs], []
    terminated = truncated = False
    for a in actions:
        obs, r, terminated, truncated, info = env.step(a)
        states.append(obs)
        rewards.append(r)
        if terminated or truncated:
            break
    return np.array(states), np.array(rewards), terminated, truncated, info


def test_every_problem_is_registered_under_its_id():
    """Importing sapga_ros.gym registers one id per configured problem, the four of the
    comparisons under their fixed names."""
    fixed = {'acrobot': 'sapga_ros/Acrobot-v0', 'pdip': 'sapga_ros/PDIP-v0',
             'pdip_single': 'sapga_ros/PDIPSingle-v0',
             'mountain_car': 'sapga_ros/MountainCar-v0', 'pendulum': 'sapga_ros/Pendulum-v0'}
    assert fixed.items() <= sapga_ros.gym.ENV_IDS.items()
    assert sorted(sapga_ros.gym.ENV_IDS) == PROBLEMS
    for name, env_id in sapga_ros.gym.ENV_IDS.items():
        assert env_id in gymnasium.registry
        assert make(name).unwrapped.problem.name == name
    assert sapga_ros.gym.register_problems() == sapga_ros.gym.ENV_IDS   # again: no-op


@pytest.mark.parametrize('name', PROBLEMS)
def test_gymnasium_env_checker_passes_without_a_warning(name):
    """Gymnasium's env checker accepts every environment and warns about nothing."""
    env = make(name)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        check_env(env.unwrapped)


@pytest.mark.parametrize('name', PROBLEMS)
def test_spaces_are_the_yaml_actions_and_state_layout(name):
    """Action i is the YAML's i-th action, the observation the state in the YAML's layout."""
    problem = load_problem(name)
    env = make(name)
    assert env.action_space == gymnasium.spaces.Discrete(len(problem.actions))
    assert env.observation_space.dtype == np.float64
    assert np.array_equal(env.observation_space.low, problem.low)
    assert np.array_equal(env.observation_space.high, problem.high)
    obs, info = env.reset(seed=123)
    assert np.array_equal(obs, problem.initial_state)
    assert info['delta'] == info['delta_star'] == delta_of(problem, obs)
    assert np.array_equal(env.reset(seed=7)[0], obs)   # the start draws nothing


@pytest.mark.parametrize('name', PROBLEMS)
def test_random_actions_step_like_the_kernel_on_a_lane(name, rng):
    """An episode of random actions equals, bit for bit, step_lanes stepping it on lane 0 of
    LANES lanes, the others busy with other states."""
    problem = load_problem(name)
    env = make(name, delta=0.0)
    actions = rng.integers(0, len(problem.actions), size=problem.n_step)
    states, rewards, _, _, _ = run(env, actions)
    S = rng.uniform(problem.low, problem.high, size=(LANES, problem.dim)).T.copy()
    S[:, 0] = problem.initial_state
    r = np.zeros(LANES)
    p = problem.params()
    want_states, want_rewards = [S[:, 0].copy()], []
    for a in actions[:len(rewards)]:
        values = problem.action_values[rng.integers(0, len(problem.actions), size=LANES)]
        values[0] = problem.actions[a]
        step_lanes(model_id(problem.model), S, values, p, LANES, r)
        want_states.append(S[:, 0].copy())
        want_rewards.append(r[0])
    if len(rewards) < problem.n_step and problem.end_stop == 'fail':  # ended at the rail:
        want_rewards[-1] += (problem.n_step - len(rewards)) * problem.fail_charge  # charged
    assert np.array_equal(states, np.array(want_states))
    assert np.array_equal(rewards, np.array(want_rewards))


@pytest.mark.parametrize('name', [n for n in PROBLEMS if load_problem(n).ends_in_goal])
def test_replaying_an_evaluator_episode_gives_that_episode(name, rng):
    """Evaluator.episode's actions replayed through the env give its states, rewards, return,
    delta* and end (goal or N_step), for policies that reach the goal and ones that do not
    (the hold task's problems: tests/test_hold.py)."""
    problem = load_problem(name)
    policies = [random_policy(problem, rng, 20, 60) for _ in range(12)]
    dstar = Evaluator(problem, 0.0).evaluate(policies).delta_star
    delta = float(np.median(dstar))                    # about half reach S_delta
    index = {v: i for i, v in enumerate(problem.actions)}
    env = make(name, delta=delta)
    ends = set()
    for policy in policies:
        ep = Evaluator(problem, delta).episode(policy)
        states, rewards, terminated, truncated, info = run(env, [index[a] for a in ep.actions])
        assert np.array_equal(states, ep.states)
        assert np.array_equal(rewards, ep.rewards)
        ret = 0.0
        for r in rewards:
            ret += r                                   # accumulated as the engine does
        assert ret == ep.ret and len(rewards) == ep.steps
        assert info['delta_star'] == ep.delta_star
        assert (terminated, truncated) == (ep.reached, not ep.reached)
        assert ep.reached or ep.steps == problem.n_step
        ends.add(terminated)
    assert ends == {True, False}


@pytest.mark.parametrize('name', PROBLEMS)
def test_states_stay_in_the_observation_space(name, rng):
    """Long episodes of held random actions never leave the box (the kernels wrap angles,
    clip velocities and stop carts at their ends)."""
    problem = load_problem(name)
    env = make(name, delta=0.0, n_step=3000)
    space = env.observation_space
    extremes = [np.full(problem.dim, np.inf), np.full(problem.dim, -np.inf)]
    for _ in range(6):
        actions = np.repeat(rng.integers(0, len(problem.actions), size=300),
                            rng.integers(1, 40, size=300))
        states, _, _, _, _ = run(env, actions)
        assert all(space.contains(s) for s in states)
        extremes = [np.minimum(extremes[0], states.min(0)), np.maximum(extremes[1], states.max(0))]
    assert np.all(extremes[0] >= problem.low) and np.all(extremes[1] <= problem.high)
    assert np.any(extremes[0] == problem.low) or np.any(extremes[1] == problem.high)  # edges met


def test_delta_and_n_step_reach_the_environment():
    """make(delta=, n_step=) set the goal difficulty and the episode length."""
    env = make('acrobot', delta=0.49, n_step=5)
    assert (env.unwrapped.delta, env.unwrapped.n_step) == (0.49, 5)
    _, rewards, terminated, truncated, info = run(env, [1] * 10)
    assert len(rewards) == 5 and truncated and not terminated and info['delta'] > 0.49
    env = make('acrobot', delta=0.5)                   # delta(s0) = 0.5: the first step ends
    _, rewards, terminated, truncated, _ = run(env, [2] * 10)
    assert len(rewards) == 1 and terminated and not truncated
    default = make('pdip').unwrapped
    assert (default.delta, default.n_step) == (0.01, 400)


def test_misuse_is_refused_with_a_reason():
    """Bad settings, an action out of range and a step after the end raise typed errors."""
    for kwargs in ({'delta': -1.0}, {'delta': float('nan')}, {'n_step': 0},
                   {'n_step': 2.5}, {'render_mode': 'human'}):
        with pytest.raises(ConfigError):
            sapga_ros.gym.ProblemEnv('acrobot', **kwargs)
    env = make('mountain_car', n_step=1).unwrapped
    env.reset()
    with pytest.raises(InvalidAction, match='0..1'):
        env.step(2)
    env.step(0)
    with pytest.raises(ResetNeeded):
        env.step(0)
