"""The episode engine's lanes path for hybrids (sapga_ros/evaluation/engine.py, ``catch``):
a state-action batch whose policies all hand over to an LQR catch designed for one delay d
asks the LQR lane by lane on the lanes' predictions stepped side by side and searches the
other lanes' exemplars together.  It must give the general loop's bits (``choose``, which
a batch mixing catch delays takes), with the catch engaged, disturbed or not."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.control import uniform_catch
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.optim.operators import random_exemplars
from sapga_ros.policies.classical import with_catch
from sapga_ros.policies.styles import STATE_ACTION
from sim_nodes.disturbance import load_disturbance
from sim_nodes.problem import load_problem

SCALES = (0.5, 1.0, 4.0, 30.0, 300.0)   # evolved catch regions: small to most of the space
FIELDS = ('returns', 'steps', 'delta_star', 'reached', 'first_entry', 'held', 'contacts')


def near_the_top(problem):
    """``problem`` started off its best state (5 % of each coordinate's range, the carts
    1 %: not into the end stop), where the catch regions of ``SCALES`` hold some starts and
    not others."""
    off = 0.01 if problem.model == 'pdip' else 0.05
    return dataclasses.replace(problem, initial=tuple(problem.best_state
                                                      + off * problem.ranges))


def hybrids(problem, design, rng, count: int) -> list:
    """``count`` random state-action policies behind ``design``'s catch, regions scaled."""
    return [with_catch(random_exemplars(problem, 40, rng), design, SCALES[k % len(SCALES)])
            for k in range(count)]


@pytest.mark.parametrize('name, d, disturbed', [
    ('acrobot_hold', 0, False), ('acrobot_hold', 1, True), ('acrobot', 1, False),
    ('pdip_hold', 0, True), ('pdip_hold', 2, False)])
def test_a_batch_of_one_catch_delay_takes_the_lanes_path_with_the_general_loops_bits(
        name, d, disturbed):
    """Hybrids of catch delay d alone (the lanes path) against the same hybrids interleaved
    with hybrids of catch delay d + 1 (every share in the general loop): each policy's
    entries and exemplar marks are the same bits, under field with pushes and a gain error
    as on the undisturbed model; the catch acts (the hybrids' results are not their bare
    policies')."""
    pr = near_the_top(load_problem(name))
    rng = np.random.default_rng(21)
    ours = hybrids(pr, classical_policy(pr, delay=d), rng, 20)
    others = hybrids(pr, classical_policy(pr, delay=d + 1), rng, 20)
    dist = dataclasses.replace(load_disturbance('field'), pushes=2, push_size=0.3,
                               gain=0.1) if disturbed else None
    ev = Evaluator(pr, disturbance=dist)
    mixed_list = [p for pair in zip(ours, others) for p in pair]
    assert uniform_catch(ev.controls(ours), STATE_ACTION) == d
    assert uniform_catch(ev.controls(mixed_list), STATE_ACTION) is None
    keys = np.array([[3, 2, k, k % 3] for k in range(20)])
    set_jobs(1)
    try:
        fast = ev.evaluate(ours, keys)
        mixed = ev.evaluate(mixed_list, np.repeat(keys, 2, axis=0))
        bare = ev.evaluate([_bare(p) for p in ours], keys)
    finally:
        set_jobs(0)
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(fast, field), getattr(mixed, field)[::2], field)
    for k in range(20):
        np.testing.assert_array_equal(fast.used[k], mixed.used[2 * k])
    assert np.sum(fast.returns != bare.returns) >= 5      # the catch acted in many episodes


def _bare(policy):
    """The hybrid's exemplar policy without its catch."""
    from sapga_ros.policies.exemplar import ExemplarPolicy
    return ExemplarPolicy(policy.problem, policy.states, policy.actions)


def test_a_traced_hybrid_episode_reports_the_catch_steps_and_replays_the_batch():
    """A hybrid's traced episode (one policy: the lanes path) marks its LQR steps with
    exemplar -1, takes the quantised LQR action there, and ends as its batch entry."""
    pr = near_the_top(load_problem('acrobot_hold'))
    design = classical_policy(pr, delay=1)
    policy = with_catch(random_exemplars(pr, 40, np.random.default_rng(4)), design, 300.0)
    ev = Evaluator(pr)
    ep = ev.episode(policy)
    batch = ev.evaluate([policy, policy])
    assert (ep.exemplars == -1).any() and (ep.exemplars >= 0).any()
    assert set(np.unique(ep.actions[ep.exemplars == -1])) <= set(pr.action_values)
    assert ep.ret == batch.returns[0] == batch.returns[1] and ep.steps == batch.steps[0]
