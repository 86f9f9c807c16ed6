"""A generation's crossovers in compiled passes (``optim.generation``) are, bit for bit and
draw for draw, ``parents_union`` and ``uniform_crossover`` applied family by family, as
SAP-GA's ``ask`` once ran them: the same children, the same repairs, the generator left in
the same state."""
from __future__ import annotations

import numpy as np
import pytest

from sapga_ros.errors import SapgaError
from sapga_ros.optim.generation import crossover_group, refreshes
from sapga_ros.optim.pcg import pcg_doubles, set_state, state_of
from sapga_ros.optim.operators import (parents_union, random_policy, refresh,
                                       uniform_crossover)
from sapga_ros.policies.exemplar import concat_policies
from sim_nodes.problem import load_problem


def one_by_one(parents, rng, n_child, l_min, l_max, rate, max_tries):
    """The children as ``ask`` made them before: family by family, child by child."""
    kids, repairs = [], 0
    for p1, p2 in parents:
        union = parents_union(p1, p2)
        for _ in range(n_child):
            kid, repaired = uniform_crossover(p1, p2, rng, l_min, l_max, rate, max_tries,
                                              union)
            kids.append(kid)
            repairs += repaired
    return kids, repairs


def population(problem, style, seed, count=12, l_min=20, l_max=40):
    """Random policies, some sharing exemplars (as a converging population does) and one
    pair of identical parents."""
    rng = np.random.default_rng(seed)
    pols = [random_policy(problem, rng, l_min, l_max, style) for _ in range(count)]
    for k in range(2, count, 3):                       # half of a neighbour's exemplars
        pols[k] = concat_policies([pols[k].subset(slice(0, 10)), pols[k - 1].subset(
            slice(0, l_min))])
    pols[1] = pols[0]
    return [(pols[2 * f], pols[2 * f + 1]) for f in range(count // 2)]


@pytest.mark.parametrize('style', ['state-action', 'state-state', 'state-action-value',
                                   'via-point'])
@pytest.mark.parametrize('limits', [(20, 40, 100), (25, 30, 3), (60, 70, 5), (1, 1, 2)])
def test_crossovers_draw_for_draw_as_one_by_one(style, limits):
    problem = load_problem('pdip' if style == 'state-state' else 'acrobot')
    l_min, l_max, tries = limits
    parents = population(problem, style, 3)
    fast_rng, slow_rng = np.random.default_rng(9), np.random.default_rng(9)
    fast_rng.integers(0, 5, size=3)                    # a buffered 32-bit half pending
    slow_rng.integers(0, 5, size=3)
    assert fast_rng.bit_generator.state['has_uint32'] == 1
    group, fast_repairs = crossover_group(parents, fast_rng, 7, l_min, l_max, (0.3, 0.7),
                                          tries)
    fast = [group.policy(k) for k in range(len(group))]
    slow, slow_repairs = one_by_one(parents, slow_rng, 7, l_min, l_max, (0.3, 0.7), tries)
    assert fast_repairs == slow_repairs
    assert len(fast) == len(slow)
    for a, b in zip(fast, slow):
        for name in ('states', 'states2', 'actions', 'values'):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert fast_rng.bit_generator.state == slow_rng.bit_generator.state
    assert fast_rng.random() == slow_rng.random()
    if l_min == l_max == 1 or tries == 3 and l_min == 60:
        assert fast_repairs > 0                        # the repair path was taken


class Star:
    """A family's best member as ``tell`` hands it to the refresh operator."""

    def __init__(self, policy, used):
        self.policy, self.used = policy, used


@pytest.mark.parametrize('style', ['state-action', 'state-state', 'state-action-value',
                                   'via-point', 'state-value'])
def test_refreshes_draw_for_draw_as_one_by_one(style):
    problem = load_problem('pdip' if style == 'state-state' else 'acrobot')
    rng = np.random.default_rng(4)
    stars = []
    for k in range(9):
        policy = random_policy(problem, rng, 5, 40, style)
        used = rng.random(len(policy)) < (0.5 if k != 3 else 1.1)   # star 3: all used
        stars.append(Star(policy, used))
    fast_rng, slow_rng = np.random.default_rng(8), np.random.default_rng(8)
    fast = refreshes(stars, fast_rng, (0.1, 0.6))
    slow = [refresh(s.policy, s.used, slow_rng, (0.1, 0.6)) for s in stars]
    for (a, n), (b, m) in zip(fast, slow):
        assert n == m
        for name in ('states', 'states2', 'actions', 'values'):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert fast_rng.bit_generator.state == slow_rng.bit_generator.state
    assert sum(n for _, n in fast) > 0 and fast[3][1] == 0


@pytest.mark.parametrize('seed', [0, 7, 2**63 + 5])
def test_inline_pcg64_draws_numpys_doubles_and_leaves_its_state(seed):
    """A million ``pcg_double`` draws are ``Generator.random()``'s, bit for bit, and the
    state put back is the generator's after the same draws (its buffered 32 bits kept)."""
    ours, theirs = np.random.default_rng(seed), np.random.default_rng(seed)
    ours.integers(0, 2**31, dtype=np.uint32)      # a buffered half word, kept
    theirs.integers(0, 2**31, dtype=np.uint32)
    words = state_of(ours)
    drawn = np.empty(1_000_000)
    pcg_doubles(words, drawn)
    set_state(ours, words)
    assert np.array_equal(drawn, theirs.random(len(drawn)))
    assert ours.bit_generator.state == theirs.bit_generator.state
    assert ours.random() == theirs.random()
    assert ours.integers(0, 2**31, dtype=np.uint32) == theirs.integers(0, 2**31, dtype=np.uint32)


def test_compiled_crossovers_refuse_another_bit_generator():
    """The inline draws are PCG64's: another bit generator is refused, not misread."""
    with pytest.raises(SapgaError, match='PCG64'):
        state_of(np.random.Generator(np.random.MT19937(0)))
