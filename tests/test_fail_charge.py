"""The end stop's fail rule charges an early end: an episode that ends at an end-stop
contact in step t (``end_stop: fail``) gets ``(n_step - t) * Problem.fail_charge`` added to
its return, the lowest contact-free step reward for each step it did not run.  The episode
engine (batch and traced), Q-learning's greedy and learning episodes, the Gymnasium env and
the ROS simulator node all apply it; so an early end at the rail never scores above a
full-length contact-free episode of the worst reward."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ros_helpers import isolated_ros, run_lockstep
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.qlearner import QLearning, QlParams, learn_together
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.qtable import QTable
from sim_nodes import reference
from sim_nodes.problem import load_problem

HOLD = load_problem('pdip_hold')


def constant(problem, action: int) -> ExemplarPolicy:
    """One exemplar: the nearest-neighbour selector always takes ``action``."""
    return ExemplarPolicy(problem, problem.initial_state[None, :], np.array([action]))


def policies(problem) -> list[ExemplarPolicy]:
    """Full force either way (the rail within a few steps), no force (never the rail) and
    random exemplar policies (some touch the rail late)."""
    rng = np.random.default_rng(11)
    return [constant(problem, 0), constant(problem, len(problem.actions) - 1),
            constant(problem, problem.actions.index(0.0))] + [
        ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (8, problem.dim)),
                       rng.integers(0, len(problem.actions), 8)) for _ in range(8)]


def charged_return(problem, ep, delta) -> float:
    """The return from the traced rewards, in the engine's order: each step's reward, then
    the bonus of a step in S_delta, then the charge of the steps not run."""
    total = 0.0
    for t, r in enumerate(ep.rewards):
        total += r
        if reference.goal_delta(problem, ep.states[t + 1]) <= delta:
            total += problem.hold_bonus
    if ep.contacts:
        total += (problem.n_step - ep.steps) * problem.fail_charge
    return total


def test_the_charge_is_the_lowest_contact_free_reward_and_only_under_fail():
    assert HOLD.end_stop == 'fail' and HOLD.fail_charge == HOLD.lowest_free_reward == -5.0
    assert HOLD.reward_range[0] - HOLD.end_stop_penalty == -5.0      # -105 + 100
    assert HOLD.lowest_free_reward > HOLD.contact_below > HOLD.reward_range[0]
    for name in ('pdip', 'acrobot', 'acrobot_hold', 'mountain_car'):
        assert math.isnan(load_problem(name).fail_charge)            # end_stop: stop


def test_a_fail_episode_returns_its_rewards_plus_the_charge_in_batch_and_trace():
    """Batch and traced episode agree bit for bit; a contact ends the episode and its
    return is the sum of its rewards and bonuses plus (n_step - t) x the charge, exactly."""
    ev = Evaluator(HOLD)
    pols = policies(HOLD)
    batch = ev.evaluate(pols)
    ended = 0
    for k, policy in enumerate(pols):
        ep = ev.episode(policy)
        assert (ep.ret, ep.steps, ep.contacts) == (batch.returns[k], batch.steps[k],
                                                   batch.contacts[k])
        assert ep.contacts <= 1 and (ep.contacts == 1 or ep.steps == HOLD.n_step)
        assert ep.contacts == 0 or ep.rewards[-1] < HOLD.contact_below
        assert ep.ret == charged_return(HOLD, ep, ev.delta)
        ended += ep.steps < HOLD.n_step
    assert ended >= 2                       # both full-force policies hit the rail early


def test_an_early_end_at_the_rail_scores_below_the_worst_full_episode():
    """Full force into the rail ends within a few steps; its return is below n_step x the
    lowest contact-free reward (the worst full episode without a contact: no force at all
    here, the poles hanging still), though its rewards alone sum far above it."""
    ev = Evaluator(HOLD)
    worst = HOLD.n_step * HOLD.lowest_free_reward
    idle = ev.episode(constant(HOLD, HOLD.actions.index(0.0)))
    assert (idle.steps, idle.contacts, idle.ret) == (HOLD.n_step, 0, pytest.approx(worst))
    for action in (0, len(HOLD.actions) - 1):
        ep = ev.episode(constant(HOLD, action))
        assert ep.contacts == 1 and ep.steps < 50
        assert ep.rewards.sum() > worst / 10           # what an early end used to be worth
        assert ep.ret < worst and ep.ret < idle.ret
        stop = Evaluator(dataclasses.replace(HOLD, end_stop='stop')).episode(
            constant(HOLD, action))
        assert stop.steps == HOLD.n_step and stop.contacts > 1
        assert math.isclose(stop.ret, stop.rewards.sum(), rel_tol=1e-12)  # no charge


def test_q_learning_greedy_and_learning_episodes_charge_alike():
    """A Q-table whose greedy action is full force: its greedy episode equals the engine's
    episode of the constant policy bit for bit; learning episodes of the same table
    (epsilon 0, eta 0: each one the greedy episode) end at the contact with the same return."""
    # 3 tiles a coordinate (729 cells) instead of the problem's 20 (64 M cells, 4.6 GB a table)
    problem = dataclasses.replace(HOLD, ql_epsilon=0.0, ql_eta=0.0, ql_tiles_per_dim=3)
    top = len(problem.actions) - 1
    cells = problem.ql_tiles_per_dim ** len(problem.ql_state_indices)
    q = np.zeros((cells, len(problem.actions)))
    q[:, top] = 1.0
    greedy = QTable(problem, q, np.ones(cells, dtype=bool), {}).episode(problem.default_delta)
    engine = Evaluator(problem).episode(constant(problem, top))
    assert np.array_equal(greedy.states, engine.states)
    assert np.array_equal(greedy.rewards, engine.rewards)
    assert (greedy.ret, greedy.steps, greedy.contacts) == (engine.ret, engine.steps, 1)
    assert engine.steps < problem.n_step
    run = QLearning.create(problem, QlParams(chunk_steps=1000), 0, problem.default_delta, 1000)
    run.q[...] = q
    learn_together([run])
    done, n_ep, returns = run._learnt[0], run._learnt[1], run._learnt[2]
    assert n_ep == math.ceil(1000 / engine.steps) and done == n_ep * engine.steps
    assert returns[:n_ep] == pytest.approx(np.full(n_ep, engine.ret), rel=1e-12)


def test_the_gym_env_puts_the_charge_into_the_terminating_reward():
    """The env's rewards of an engine episode: the kernel's, the last one plus the charge;
    they sum to the engine's return."""
    import gymnasium
    import sapga_ros.gym
    env = gymnasium.make(sapga_ros.gym.ENV_IDS['pdip_hold'])
    index = {v: i for i, v in enumerate(HOLD.actions)}
    for policy in policies(HOLD):
        ep = Evaluator(HOLD).episode(policy)
        env.reset(seed=0)
        rewards = []
        for t, a in enumerate(ep.actions):
            _, r, terminated, truncated, _ = env.step(index[a])
            inside = reference.goal_delta(HOLD, ep.states[t + 1]) <= HOLD.default_delta
            expected = ep.rewards[t] + (HOLD.hold_bonus if inside else 0.0)
            if terminated:
                expected += (HOLD.n_step - ep.steps) * HOLD.fail_charge
            assert r == expected
            rewards.append(r)
        assert terminated == (ep.contacts == 1)
        assert math.fsum(rewards) == pytest.approx(ep.ret, rel=1e-12)


@pytest.fixture
def ros(monkeypatch, tmp_path):
    """An isolated ROS 2 domain with an executor thread (tests/ros_helpers.py)."""
    yield from isolated_ros(monkeypatch, tmp_path)


def test_a_lockstep_ros_episode_ending_at_the_rail_returns_the_offline_charge(ros, tmp_path):
    """The simulator node over DDS, full force into the rail: the episode ends with event
    end_stop at the engine's step, and its return, the charge included, equals the
    offline episode's bit for bit."""
    policy = constant(HOLD, len(HOLD.actions) - 1)
    ep = Evaluator(HOLD).episode(policy)
    probe, _ = run_lockstep(ros, HOLD, policy, tmp_path / 'rail.json', HOLD.default_delta,
                            episodes=1)
    end = probe.end_of(1)
    assert (end['event'], end['step'], end['rail_contacts']) == ('end_stop', ep.steps, 1)
    assert end['return'] == ep.ret < HOLD.n_step * HOLD.lowest_free_reward
    assert probe.rewards[:ep.steps] == list(ep.rewards)     # the topic: the kernel's rewards
