"""The nearest-neighbour action selector (sapga_ros/exemplars/distance.py; SPEC 3.1): normalised,
circular distances, ties to the lowest index, and agreement with the plain NumPy statement
in sim_nodes/reference.py."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sapga_ros.exemplars.distance import (argmin, distances, nearest, normalize_into,
                                          normalize_states)
from sim_nodes import reference
from sim_nodes.models.common import TWO_PI


def select(problem, states, state, n: int | None = None) -> int:
    """Index of the nearest exemplar through the compiled path the evaluator uses."""
    states = np.asarray(states, dtype=np.float64)
    ex = normalize_states(states, problem.ranges, problem.is_angle)
    u = np.empty(problem.dim)
    normalize_into(np.asarray(state, dtype=np.float64), 1.0 / problem.ranges,
                   problem.is_angle, u)
    n = len(states) if n is None else n
    return int(nearest(u, ex, n, problem.is_angle, np.empty(len(states))))


def at_best(problem, count: int) -> np.ndarray:
    """``count`` copies of the best state, to move one coordinate at a time."""
    return np.repeat(problem.best_state[None], count, axis=0)


def test_angle_distance_goes_the_short_way_round(acrobot_problem):
    """An exemplar at theta = 0.01 is nearer to a state at theta = 2pi - 0.01 (0.02 rad
    round the circle) than one at theta = 0.1, for either angle coordinate."""
    for i in (0, 1):
        states = at_best(acrobot_problem, 2)
        states[:, i] = [0.1, 0.01]
        state = acrobot_problem.best_state
        state[i] = TWO_PI - 0.01
        assert select(acrobot_problem, states, state) == 1
        got = distances(state, states, acrobot_problem.ranges, acrobot_problem.is_angle)
        assert got == pytest.approx([0.11 / TWO_PI, 0.02 / TWO_PI])


def test_selection_is_invariant_to_whole_turns(problem, rng):
    """A state and the same state with whole turns added to its angles select the same
    exemplar."""
    states = rng.uniform(problem.low, problem.high, (50, problem.dim))
    for _ in range(200):
        s = rng.uniform(problem.low, problem.high)
        turned = s.copy()
        turned[problem.is_angle] += TWO_PI * rng.integers(-3, 4, problem.is_angle.sum())
        assert select(problem, states, s) == select(problem, states, turned)


def test_acrobot_velocities_are_compared_relative_to_their_ranges(acrobot_problem):
    """A 1.0 rad/s difference in theta2_dot (range 18pi) is nearer than 0.5 rad/s in
    theta1_dot (range 8pi): 1/18pi < 0.5/8pi, although the raw difference is larger."""
    states = at_best(acrobot_problem, 2)
    states[0, 2] += 0.5   # theta1_dot
    states[1, 3] += 1.0   # theta2_dot
    assert select(acrobot_problem, states, acrobot_problem.best_state) == 1
    assert distances(acrobot_problem.best_state, states, acrobot_problem.ranges,
                     acrobot_problem.is_angle) == pytest.approx([0.5 / (8 * math.pi),
                                                                 1.0 / (18 * math.pi)])


def test_pdip_cart_coordinates_are_compared_relative_to_their_ranges(pdip_problem):
    """A 2 m/s difference in v (range 32) is nearer than 0.5 m in x (range 5): 2/32 < 0.5/5;
    and a whole multi-coordinate distance is the Euclidean norm of the normalised parts."""
    states = at_best(pdip_problem, 3)
    states[0, 0] += 0.5
    states[1, 1] += 2.0
    states[2, [0, 1, 4]] += [0.5, 2.0, math.pi]
    best = pdip_problem.best_state
    assert select(pdip_problem, states, best) == 1
    expected = [0.1, 0.0625, math.sqrt(0.1 ** 2 + 0.0625 ** 2 + (1 / 8) ** 2)]
    assert distances(best, states, pdip_problem.ranges,
                     pdip_problem.is_angle) == pytest.approx(expected)


def test_ties_go_to_the_lowest_index(problem, rng):
    """Among exemplars at the same distance the lowest index wins: duplicates of the nearest
    state, exemplars mirrored about the state, and all-identical exemplars."""
    state = problem.best_state
    far = rng.uniform(problem.low, problem.high, (8, problem.dim))
    states = far.copy()
    near = state.copy()
    near[1] += 0.25  # a velocity (acrobot: theta2, an angle) a little away
    states[[2, 5, 6]] = near
    assert select(problem, states, state) == 2
    mirrored = at_best(problem, 2)
    velocity = int(np.flatnonzero(~problem.is_angle)[-1])
    mirrored[:, velocity] += [0.5, -0.5]  # exactly the same normalised distance
    assert select(problem, mirrored, state) == 0
    assert select(problem, mirrored[::-1], state) == 0
    assert select(problem, np.repeat(far[:1], 7, axis=0), state) == 0


def test_only_the_first_n_exemplars_are_considered(problem, rng):
    """nearest(..., n) ignores the padding after the first n exemplars, however near."""
    states = rng.uniform(problem.low, problem.high, (10, problem.dim))
    states[7] = problem.best_state
    assert select(problem, states, problem.best_state) == 7
    assert select(problem, states, problem.best_state, n=7) != 7


def test_normalised_angles_lie_in_zero_to_one(problem, rng):
    """normalize_into wraps an angle to a fraction of a turn in [0, 1), for angles far
    outside [0, 2pi) and just below 0 or 2pi, and divides other coordinates by their
    range."""
    inv = 1.0 / problem.ranges
    u = np.empty(problem.dim)
    for s in rng.uniform(-50.0, 50.0, (500, problem.dim)):
        for extra in (0.0, -1e-18, np.nextafter(TWO_PI, 0.0)):
            s2 = s.copy()
            s2[problem.is_angle] = extra if extra else s[problem.is_angle]
            normalize_into(s2, inv, problem.is_angle, u)
            assert np.all((u[problem.is_angle] >= 0.0) & (u[problem.is_angle] < 1.0))
            assert np.array_equal(u[~problem.is_angle], (s2 * inv)[~problem.is_angle])


def test_nearest_agrees_with_the_reference_selector(problem, rng):
    """On random exemplars and states the compiled selector picks the exemplar that
    sim_nodes.reference.select picks."""
    states = rng.uniform(problem.low, problem.high, (60, problem.dim))
    ex = normalize_states(states, problem.ranges, problem.is_angle)
    inv = 1.0 / problem.ranges
    u = np.empty(problem.dim)
    acc = np.empty(len(states))
    for s in rng.uniform(problem.low, problem.high, (3000, problem.dim)):
        normalize_into(s, inv, problem.is_angle, u)
        j = nearest(u, ex, len(states), problem.is_angle, acc)
        assert j == reference.select(problem, states, s)


def first_strict_minimum(acc: np.ndarray) -> int:
    """The scan the nearest-exemplar search defines: keep the first strict minimum."""
    best = 0
    for j in range(1, len(acc)):
        if acc[j] < acc[best]:
            best = j
    return best


def test_argmin_is_the_first_strict_minimum(rng):
    """``argmin`` (integer passes over the bits) returns what the plain scan returns, for
    squared distances with ties, zeros, infinities and NaNs, at every length."""
    for n in (1, 2, 7, 8, 9, 31, 100, 257):
        for _ in range(200):
            acc = rng.choice([0.0, 0.25, 0.5, 1.0, 1e-300, math.inf], size=n)
            mixed = rng.random(n) < 0.5
            acc[mixed] = rng.random(int(mixed.sum()))
            if rng.random() < 0.3:
                acc[rng.integers(n)] = np.nan
            if rng.random() < 0.1:
                acc[rng.integers(n)] = -np.nan
            assert argmin(acc, n) == first_strict_minimum(acc), acc


def test_the_short_way_round_squares_as_the_min_of_both_ways(rng):
    """``circular(diff)`` squared is ``min(|diff|, 1 - |diff|)`` squared bit for bit, for the
    differences of fractions of a turn: random ones, halves, the ends of [0, 1), values one
    ulp either side of 1/2 and 1/4, tiny ones and NaN."""
    from sapga_ros.exemplars.distance import circular
    from sim_nodes.jit import kernel

    @kernel
    def both(a, b, new, old):
        for j in range(a.shape[0]):
            d = a[j] - b[j]
            c = circular(d)
            new[j] = c * c
            m = min(math.fabs(d), 1.0 - math.fabs(d))
            old[j] = m * m

    edges = np.array([0.0, 0.5, 0.25, 0.75, 1e-300, 5e-324, np.nextafter(1.0, 0.0),
                      np.nextafter(0.5, 0.0), np.nextafter(0.5, 1.0),
                      np.nextafter(0.25, 0.0), np.nextafter(0.25, 1.0), np.nan])
    pairs = np.array(np.meshgrid(edges, edges)).reshape(2, -1)
    a = np.concatenate([pairs[0], rng.random(200_000), rng.random(1000) * 1e-12])
    b = np.concatenate([pairs[1], rng.random(200_000), 1.0 - rng.random(1000) * 1e-12])
    b[-1000:] = np.minimum(b[-1000:], np.nextafter(1.0, 0.0))
    new, old = np.empty_like(a), np.empty_like(a)
    both(a, b, new, old)
    finite = ~np.isnan(old)
    assert np.array_equal(np.isnan(new), ~finite)
    assert np.array_equal(new[finite].view(np.uint64), old[finite].view(np.uint64))
