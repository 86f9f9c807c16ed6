"""SAP-GA operators (paper section 3; SPEC 3.2) as pure functions of an explicit generator.

* ``random_exemplars``: states uniform over the problem's bounds, actions uniform.
* ``uniform_crossover``: each exemplar of parent 1 joins with probability r, each of parent 2
  with 1 - r (r drawn from [0.3, 0.7] per attempt); identical exemplars deduplicated; retried
  until the size is in [L_min, L_max], at most ``max_tries`` times, then *repaired*.
* ``refresh``: each exemplar not referred to in the last evaluation ("lazy") is re-drawn at
  random with probability r drawn from [0, 0.5].
"""
from __future__ import annotations

import numpy as np

from sapga_ros.exemplars.policy import ExemplarPolicy
from sim_nodes.problem import Problem


def random_exemplars(problem: Problem, count: int,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` exemplars: states uniform over [low, high), action indices uniform."""
    states = rng.uniform(problem.low, problem.high, size=(count, problem.dim))
    actions = rng.integers(0, len(problem.actions), size=count)
    return states, actions


def random_policy(problem: Problem, rng: np.random.Generator, l_min: int,
                  l_max: int) -> ExemplarPolicy:
    """An initial policy: size uniform in [l_min, l_max], random exemplars."""
    size = int(rng.integers(l_min, l_max + 1))
    return ExemplarPolicy(problem, *random_exemplars(problem, size, rng))


def deduplicate(states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop exemplars identical (bit for bit) to an earlier one; keep first-seen order."""
    rows = np.ascontiguousarray(np.column_stack([states, actions.astype(np.float64)]))
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()
    _, first = np.unique(keys, return_index=True)
    if len(first) == len(rows):
        return states, actions
    first.sort()
    return states[first], actions[first]


def uniform_crossover(p1: ExemplarPolicy, p2: ExemplarPolicy, rng: np.random.Generator,
                      l_min: int, l_max: int, rate: tuple[float, float] = (0.3, 0.7),
                      max_tries: int = 100) -> tuple[ExemplarPolicy, bool]:
    """A child of p1 and p2 and whether it had to be repaired (SPEC 3.2).

    Repair, after ``max_tries`` failed attempts: draw a legal size, fill it from the
    parents' deduplicated union, topped up with fresh random exemplars only if the union is
    smaller than l_min.  (A converged population of near-identical parents of about l_min
    exemplars almost never yields a legal size; an unbounded retry would stall the run.)
    """
    problem = p1.problem
    for _ in range(max_tries):
        r = rng.uniform(*rate)                                    # selection rate
        take1 = rng.random(len(p1)) < r                           # e in E^p1 with prob r
        take2 = rng.random(len(p2)) < 1.0 - r                     # e in E^p2 with prob 1 - r
        states, actions = deduplicate(np.concatenate([p1.states[take1], p2.states[take2]]),
                                      np.concatenate([p1.actions[take1], p2.actions[take2]]))
        if l_min <= len(actions) <= l_max:
            return ExemplarPolicy(problem, states, actions), False
    states, actions = deduplicate(np.concatenate([p1.states, p2.states]),
                                  np.concatenate([p1.actions, p2.actions]))
    size = int(rng.integers(l_min, l_max + 1))
    if len(actions) >= l_min:
        size = min(size, len(actions))
        keep = np.sort(rng.choice(len(actions), size=size, replace=False))
        states, actions = states[keep], actions[keep]
    else:
        extra_s, extra_a = random_exemplars(problem, size - len(actions), rng)
        states = np.concatenate([states, extra_s])
        actions = np.concatenate([actions, extra_a])
    return ExemplarPolicy(problem, states, actions), True


def refresh(policy: ExemplarPolicy, used: np.ndarray, rng: np.random.Generator,
            rate: tuple[float, float] = (0.0, 0.5)) -> tuple[ExemplarPolicy, int]:
    """A clone of ``policy`` with lazy exemplars re-drawn; and how many were re-drawn.

    ``used`` marks the exemplars referred to in the policy's last evaluation.
    """
    r = rng.uniform(*rate)                                        # refresh rate
    redraw = ~used & (rng.random(len(policy)) < r)                # lazy, with prob r
    count = int(redraw.sum())
    states = policy.states.copy()
    actions = policy.actions.copy()
    if count:
        states[redraw], actions[redraw] = random_exemplars(policy.problem, count, rng)
    return ExemplarPolicy(policy.problem, states, actions), count
