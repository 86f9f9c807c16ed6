"""Policy evaluation (sapga_ros/evaluation/: evaluator.py, engine.py; paper section 3,
SPEC 2 and 3.1): the parallel lane batch equals single episodes bit for bit, episodes follow
the model and the selector, the goal test, the exemplars marked as used, thread-count
independence, and agreement with the plain NumPy episode of sim_nodes/reference.py."""
from __future__ import annotations

import numba
import numpy as np
import pytest

from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.optim.operators import random_exemplars
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.styles import STYLES
from sim_nodes import reference
from sim_nodes.goal import delta_of
from sim_nodes.models import model_module

# goal difficulty per problem at which a seeded random population is mixed: some policies
# reach S_delta within 400 steps, most do not
MIXED_DELTA = {'acrobot': 0.4, 'pdip': 0.3}


def random_policies(problem, rng, count: int) -> list[ExemplarPolicy]:
    """``count`` random state-action policies of mixed sizes (1 to 99 exemplars)."""
    return [ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (size, problem.dim)),
                           rng.integers(0, len(problem.actions), size))
            for size in rng.integers(1, 100, count)]


def constant_policy(problem, action: float) -> ExemplarPolicy:
    """A one-exemplar policy that always takes ``action``."""
    return ExemplarPolicy(problem, problem.best_state[None], [problem.actions.index(action)])


@pytest.fixture(scope='module')
def population(problem, seed):
    """(evaluator at the problem's mixed delta, 21 random policies of mixed sizes, batch
    result); 21 is not a multiple of the 8 lanes, so some lanes run dry."""
    policies = random_policies(problem, np.random.default_rng(seed), 21)
    evaluator = Evaluator(problem, MIXED_DELTA[problem.name])
    return evaluator, policies, evaluator.evaluate(policies)


@pytest.fixture
def restore_threads():
    """Put numba's thread count back after a test that changes it."""
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def assert_same_results(a, b) -> None:
    """Two BatchResults are identical (==), including the used marks."""
    assert np.array_equal(a.returns, b.returns)
    assert np.array_equal(a.steps, b.steps)
    assert np.array_equal(a.delta_star, b.delta_star)
    assert np.array_equal(a.reached, b.reached)
    assert len(a.used) == len(b.used)
    assert all(np.array_equal(x, y) for x, y in zip(a.used, b.used))


def test_batch_equals_single_episodes_exactly(population):
    """Evaluator.evaluate (parallel shares, 8 lanes per thread) gives exactly (==) the
    return, steps, delta* and reached of Evaluator.episode for each policy, with policies
    of mixed sizes; the population mixes reached and not reached."""
    evaluator, policies, result = population
    assert 0 < result.reached.sum() < len(policies)
    assert len({len(p) for p in policies}) > 10
    for k, policy in enumerate(policies):
        ep = evaluator.episode(policy)
        assert (ep.ret, ep.steps, ep.delta_star, ep.reached) == (
            result.returns[k], result.steps[k], result.delta_star[k], result.reached[k]), k


def test_used_marks_exactly_the_exemplars_of_the_trajectory(population):
    """The batch's used[k][j] is True exactly for the exemplars j that the selector chose
    at some step of policy k's episode."""
    evaluator, policies, result = population
    for k, policy in enumerate(policies):
        chosen = np.zeros(len(policy), dtype=bool)
        chosen[evaluator.episode(policy).exemplars] = True
        assert np.array_equal(result.used[k], chosen), k
        assert result.used[k].shape == (len(policy),)


def test_recorded_episode_follows_the_model_and_the_selector(population):
    """An episode's record is a true trajectory: it starts at the initial state, each action
    is that of the exemplar nearest to the current state, each next state and reward is one
    MDP step of the model (==), the return is the sum of the rewards in step order (==),
    and delta* is the least delta(s) over every state including the first."""
    evaluator, policies, _ = population
    problem = evaluator.problem
    step = model_module(problem.model).mdp_step
    p = problem.params()
    for policy in policies[:6]:
        ep = evaluator.episode(policy)
        assert ep.states.shape == (ep.steps + 1, problem.dim)
        assert np.array_equal(ep.states[0], problem.initial_state)
        for t in range(ep.steps):
            j = reference.select(problem, policy.states, ep.states[t])
            assert ep.exemplars[t] == j and ep.actions[t] == policy.action_values[j]
            s = ep.states[t].copy()
            assert step(s, ep.actions[t], p) == ep.rewards[t]
            assert np.array_equal(s, ep.states[t + 1])
        assert sum(ep.rewards.tolist()) == ep.ret
        assert ep.delta_star == min(delta_of(problem, s) for s in ep.states)


def test_goal_test_stops_at_the_step_that_enters_the_goal(population):
    """With delta set to the delta(s) of a state reached mid-episode, the episode stops at
    the first step whose new state is in S_delta, counting that step's reward, and reports
    reached with delta* = delta(that state)."""
    evaluator, policies, _ = population
    problem = evaluator.problem
    for policy in policies[:6]:
        long = Evaluator(problem, delta=-1.0, n_step=60).episode(policy)  # never reaches
        deltas = np.array([delta_of(problem, s) for s in long.states[1:]])
        t_goal = int(np.argmin(deltas[:40]))  # first step attaining the least delta(s)
        goal = Evaluator(problem, delta=float(deltas[t_goal]), n_step=60).episode(policy)
        assert goal.reached and goal.steps == t_goal + 1
        assert goal.ret == sum(long.rewards[:t_goal + 1].tolist())
        assert goal.delta_star == deltas[t_goal]
        assert np.array_equal(goal.states, long.states[:t_goal + 2])


def test_goal_is_tested_only_after_a_step(problem):
    """The initial state is never tested against the goal: with delta above delta(s0) the
    episode still takes one step and counts its reward."""
    delta = delta_of(problem, problem.initial_state) + 1.0
    ep = Evaluator(problem, delta).episode(constant_policy(problem, 0.0))
    assert ep.reached and ep.steps == 1 and ep.ret == ep.rewards[0] < 0.0


def test_rail_hits_do_not_end_an_episode(pdip_problem):
    """A PDIP policy that always pushes +40 runs all 400 steps: after reaching the rail end
    the cart stays there, each such step is penalised, and the episode goes on."""
    ep = Evaluator(pdip_problem, 0.01).episode(constant_policy(pdip_problem, 40.0))
    assert ep.steps == 400 and not ep.reached
    at_end = ep.states[1:, 0] == 2.5
    assert at_end.sum() > 300 and np.all(ep.states[1:][at_end, 1] == 0.0)
    assert np.all(ep.rewards[at_end] <= -101.0) and np.all(ep.rewards[~at_end] >= -5.0)
    assert ep.ret == sum(ep.rewards.tolist())


def test_episode_matches_the_reference_for_short_horizons(problem, seed):
    """Over 20 steps (before chaos amplifies rounding), each policy's episode has the step
    count and reached of sim_nodes.reference.episode, and its return and delta* to 1e-9;
    delta lies between two policies' delta* so some reach the goal and some do not."""
    policies = random_policies(problem, np.random.default_rng(seed + 1), 12)
    dstar = np.sort(Evaluator(problem, -1.0, n_step=20).evaluate(policies).delta_star)
    delta = float((dstar[5] + dstar[6]) / 2)  # no policy's delta* within rounding of delta
    assert dstar[6] - dstar[5] > 1e-6
    result = Evaluator(problem, delta, n_step=20).evaluate(policies)
    assert 0 < result.reached.sum() < len(policies)
    for k, policy in enumerate(policies):
        ret, steps, ref_dstar, reached = reference.episode(
            problem, policy.states, policy.action_values, delta, n_step=20)
        assert (steps, reached) == (result.steps[k], result.reached[k]), k
        assert result.returns[k] == pytest.approx(ret, rel=1e-9, abs=1e-9), k
        assert result.delta_star[k] == pytest.approx(ref_dstar, rel=1e-9, abs=1e-12), k


def test_results_do_not_depend_on_the_thread_count(population, restore_threads):
    """set_jobs(1) and set_jobs(2) (so other shares and lane fillings) give identical
    results."""
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip('numba has a single thread here')
    evaluator, policies, _ = population
    assert set_jobs(1) == 1
    one = evaluator.evaluate(policies)
    assert set_jobs(2) == 2
    assert_same_results(one, evaluator.evaluate(policies))


def test_results_do_not_depend_on_the_order_of_the_batch(population):
    """Each policy's result is the same wherever it sits in the batch (and next to which
    others it runs in the lanes)."""
    evaluator, policies, result = population
    order = np.random.default_rng(7).permutation(len(policies))
    shuffled = evaluator.evaluate([policies[k] for k in order])
    assert np.array_equal(shuffled.returns, result.returns[order])
    assert np.array_equal(shuffled.steps, result.steps[order])
    assert np.array_equal(shuffled.delta_star, result.delta_star[order])
    assert all(np.array_equal(shuffled.used[i], result.used[k]) for i, k in enumerate(order))


def test_single_policy_batches_equal_the_whole_batch(population):
    """A policy evaluated alone in a batch of one gets its result in the whole batch."""
    evaluator, policies, result = population
    for k in (0, 7, 20):
        alone = evaluator.evaluate([policies[k]])
        assert (alone.returns[0], alone.steps[0], alone.delta_star[0]) == (
            result.returns[k], result.steps[k], result.delta_star[k])


@pytest.mark.parametrize('style', list(STYLES))
def test_a_packed_batch_holds_each_policy_as_packed_alone(problem, style):
    """The batch's padded arrays hold, in policy k's slots, exactly what packing policy k
    alone gives (normalised states and second states, action values, values) and zeros
    after its length: packing many at once is the same arithmetic per exemplar."""
    rng = np.random.default_rng(5)
    policies = [random_exemplars(problem, int(n), rng, style) for n in rng.integers(1, 40, 30)]
    policies[4].states[0, 0] = np.nan
    evaluator = Evaluator(problem)
    number, ex, ex2, act, val, lengths = evaluator.pack(policies)
    assert lengths.tolist() == [len(p) for p in policies]
    for k, p in enumerate(policies):
        alone = evaluator.pack([p])
        n = len(p)
        assert alone[0] == number
        assert ex[k, :, :n].tobytes() == alone[1][0].tobytes() and not ex[k, :, n:].any()
        assert ex2[k, :, :alone[2].shape[2]].tobytes() == alone[2][0].tobytes()
        assert act[k, :n].tobytes() == alone[3][0].tobytes() and not act[k, n:].any()
        assert val[k, :n].tobytes() == alone[4][0].tobytes() and not val[k, n:].any()


@pytest.mark.parametrize('style', list(STYLES))
def test_packing_into_reused_buffers_gives_the_fresh_arrays(problem, style):
    """``evaluate`` packs into buffers kept from its last call: after a larger batch with
    other values has filled them, a smaller batch of mixed lengths packs to exactly the
    fresh arrays (padding zeroed, nothing left of the larger batch)."""
    rng = np.random.default_rng(11)
    big = [random_exemplars(problem, 60, rng, style) for _ in range(25)]
    small = [random_exemplars(problem, int(n), rng, style) for n in rng.integers(1, 30, 9)]
    evaluator = Evaluator(problem)
    scratch = type(evaluator._scratch)()
    evaluator.pack(big, scratch)
    reused = evaluator.pack(small, scratch)
    fresh = evaluator.pack(small)
    assert reused[0] == fresh[0]
    for a, b in zip(reused[1:], fresh[1:]):
        assert a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_evaluate_results_do_not_depend_on_the_batches_before_or_other_threads(problem):
    """One evaluator, its buffers reused: each batch's results equal a fresh evaluator's,
    whatever it evaluated before, and two threads evaluating different batches on it at
    once each get their own batch's results (each thread packs into its own buffers)."""
    import threading
    rng = np.random.default_rng(12)
    batches = [random_policies(problem, rng, n) for n in (40, 7, 23)]
    expected = [Evaluator(problem, MIXED_DELTA[problem.name]).evaluate(b) for b in batches]
    shared = Evaluator(problem, MIXED_DELTA[problem.name])
    for batch, want in zip(batches + batches[::-1], expected + expected[::-1]):
        got = shared.evaluate(batch)
        assert got.returns.tobytes() == want.returns.tobytes()
        assert got.steps.tolist() == want.steps.tolist()
        assert [u.tolist() for u in got.used] == [u.tolist() for u in want.used]
    results: dict[int, list] = {0: [], 1: []}

    def work(i: int) -> None:
        for _ in range(6):
            results[i].append(shared.evaluate(batches[i]).returns.tobytes())
    threads = [threading.Thread(target=work, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i in (0, 1):
        assert results[i] == [expected[i].returns.tobytes()] * 6


def test_empty_batch_gives_empty_results(problem):
    """Evaluating no policies returns empty arrays and simulates nothing."""
    result = Evaluator(problem).evaluate([])
    assert result.returns.shape == result.steps.shape == (0,) and result.used == []


def test_set_jobs_clamps_to_the_available_threads(restore_threads):
    """set_jobs(None) or 0 uses every thread; more than numba has is clamped to that."""
    n = numba.config.NUMBA_NUM_THREADS
    assert set_jobs(None) == n and set_jobs(0) == n and set_jobs(n + 5) == n
    assert numba.get_num_threads() == n
    assert set_jobs(1) == 1 and numba.get_num_threads() == 1


@pytest.mark.parametrize('disturbance', ['none', 'field'])
@pytest.mark.parametrize('held_as', ['copies', 'rows'])
def test_a_policy_batch_held_in_another_order_gives_the_lists_results(population,
                                                                      disturbance, held_as):
    """A ``PolicyBatch`` (some policy objects, then a flat group, held in an order of its
    own; the group's records copied side by side or picked by rows from other arrays)
    evaluates to the results of the plain list of the same policies in the batch's order,
    bit for bit, disturbed draws and used marks included."""
    from sapga_ros.policies.batch import FlatPolicies, PolicyBatch, flat_of
    from sim_nodes.disturbance import load_disturbance
    base, policies, _ = population
    evaluator = Evaluator(base.problem, base.delta, disturbance=load_disturbance(disturbance))
    held = np.random.default_rng(3).permutation(len(policies))   # held order -> policy
    objects, group = [policies[k] for k in held[:6]], flat_of([policies[k] for k in held[6:]])
    if held_as == 'rows':          # the same records, reversed in the arrays, picked by rows
        n = len(group.states)
        group = FlatPolicies(group.problem, group.style, group.states[::-1].copy(),
                             group.actions[::-1].copy(), group.values[::-1].copy(),
                             group.states2[::-1].copy(), group.lengths,
                             np.arange(n - 1, -1, -1))
    rows = np.empty_like(held)
    rows[held] = np.arange(len(held))                            # policy -> held position
    batch = PolicyBatch(objects, group, rows)
    assert len(batch) == len(policies)
    assert all(np.array_equal(batch[k].states, p.states) for k, p in enumerate(policies))
    keys = np.zeros((len(policies), 4), dtype=np.int64)
    keys[:, 0], keys[:, 2] = 5, np.arange(len(policies))          # a draw of its own each
    got, want = evaluator.evaluate(batch, keys), evaluator.evaluate(policies, keys)
    assert_same_results(got, want)
    assert np.array_equal(got.first_entry, want.first_entry)
    assert np.array_equal(got.contacts, want.contacts)
    if disturbance == 'field':      # the draws differ by policy, so an order mix-up shows
        assert len(set(want.returns.tolist())) > len(policies) // 2
