"""Properties of the SAP-GA operators (paper section 3; SPEC 3.2)."""
import numpy as np
import pytest

from sapga_ros.optim.operators import (deduplicate, random_exemplars, random_policy, refresh,
                                       uniform_crossover)
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.problem import load_problem


@pytest.fixture(params=['acrobot', 'pdip'])
def problem(request):
    return load_problem(request.param)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def test_random_exemplars_lie_within_bounds(problem, rng):
    """Initial exemplar states are uniform over the state bounds, actions over the set."""
    fresh = random_exemplars(problem, 5000, rng)
    states, actions = fresh.states, fresh.actions
    assert np.all(states >= problem.low) and np.all(states < problem.high)
    assert set(np.unique(actions)) == set(range(len(problem.actions)))
    # uniform: each coordinate's mean is near the middle of its bounds
    mid = (problem.low + problem.high) / 2
    assert np.all(np.abs(states.mean(axis=0) - mid) < 0.05 * (problem.high - problem.low))


def test_initial_sizes_are_uniform_in_range(problem, rng):
    """Initial policy sizes cover [L_min, L_max] and nothing else."""
    sizes = [len(random_policy(problem, rng, 50, 100)) for _ in range(400)]
    assert min(sizes) >= 50 and max(sizes) <= 100
    assert len(set(sizes)) > 40


def test_deduplicate_keeps_first_occurrences_in_order(problem, rng):
    """Identical (state, action) pairs are removed; the first of each stays, in order."""
    fresh = random_exemplars(problem, 10, rng)
    states, actions = fresh.states, fresh.actions
    s = np.concatenate([states, states[[3, 0]], states[[5]]])
    a = np.concatenate([actions, actions[[3, 0]], (actions[[5]] + 1) % 3])
    dedup = deduplicate(ExemplarPolicy(problem, s, a))
    ds, da = dedup.states, dedup.actions
    assert len(da) == 11  # 10 + the one whose action differs
    np.testing.assert_array_equal(ds[:10], states)
    np.testing.assert_array_equal(da[:10], actions)


def test_crossover_child_is_legal_subset_of_parents(problem, rng):
    """A child's size is within [L_min, L_max], it has no duplicates, and every exemplar
    comes from a parent."""
    p1 = random_policy(problem, rng, 50, 100)
    p2 = random_policy(problem, rng, 50, 100)
    parents = {tuple(s) + (a,) for p in (p1, p2) for s, a in zip(p.states, p.actions)}
    for _ in range(50):
        child, repaired = uniform_crossover(p1, p2, rng, 50, 100)
        rows = [tuple(s) + (a,) for s, a in zip(child.states, child.actions)]
        assert 50 <= len(child) <= 100
        assert len(set(rows)) == len(rows)
        assert set(rows) <= parents
        assert not repaired


def test_converged_population_at_l_min_never_stalls(problem, rng):
    """Two identical parents of L_min exemplars yield legal children in bounded time: the
    retry stops after max_tries and the child is repaired (SPEC 3.2)."""
    p = random_policy(problem, rng, 50, 50)
    twin = ExemplarPolicy(problem, p.states.copy(), p.actions.copy())
    repairs = 0
    for _ in range(20):
        child, repaired = uniform_crossover(p, twin, rng, 50, 100, max_tries=100)
        repairs += repaired
        assert 50 <= len(child) <= 100
        rows = {tuple(s) + (a,) for s, a in zip(child.states, child.actions)}
        assert len(rows) == len(child)
    # the union of identical parents has exactly L_min exemplars: any legal child is it
    assert repairs > 0


def test_repair_tops_up_with_random_exemplars_below_l_min(problem, rng):
    """If the parents' union is smaller than L_min, the repaired child keeps all of it and
    is topped up with fresh exemplars to a legal size."""
    p = random_policy(problem, rng, 10, 10)
    child, repaired = uniform_crossover(p, p, rng, 50, 100, max_tries=3)
    assert repaired and 50 <= len(child) <= 100
    np.testing.assert_array_equal(child.states[:10], p.states)


def test_refresh_redraws_only_lazy_exemplars(problem, rng):
    """The refresh operator never touches an exemplar referred to in the last evaluation,
    and re-draws lazy ones with a rate in [0, 0.5]."""
    p = random_policy(problem, rng, 100, 100)
    used = rng.random(len(p)) < 0.3
    changed_total = 0
    for _ in range(200):
        clone, count = refresh(p, used, rng)
        changed = np.any(clone.states != p.states, axis=1) | (clone.actions != p.actions)
        assert not np.any(changed & used)
        assert int(changed.sum()) == count
        changed_total += count
        assert len(clone) == len(p)
    mean_rate = changed_total / 200 / (~used).sum()
    assert 0.15 < mean_rate < 0.35  # E[r] = 0.25 for r ~ U[0, 0.5]


def test_refresh_with_every_exemplar_used_is_identity(problem, rng):
    """A policy whose exemplars were all referred to comes back unchanged."""
    p = random_policy(problem, rng, 60, 60)
    clone, count = refresh(p, np.ones(len(p), dtype=bool), rng)
    assert count == 0
    np.testing.assert_array_equal(clone.states, p.states)
    np.testing.assert_array_equal(clone.actions, p.actions)
