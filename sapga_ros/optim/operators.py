"""SAP-GA operators (paper section 3) as pure functions of an explicit generator.

* ``random_exemplars``: records of any style: states uniform over the problem's bounds,
  actions uniform, values uniform over an episode's return range.
* ``uniform_crossover``: each exemplar of parent 1 joins with probability r, each of parent 2
  with 1 - r (r drawn from [0.3, 0.7] per attempt); identical exemplars deduplicated; retried
  until the size is in [L_min, L_max], at most ``max_tries`` times, then *repaired*.
* ``refresh``: each exemplar not referred to in the last evaluation ("lazy") is re-drawn at
  random with probability r drawn from [0, 0.5].
"""
from __future__ import annotations

import numpy as np

from sapga_ros.policies.exemplar import ExemplarPolicy, concat_policies
from sapga_ros.policies.styles import style_named
from sim_nodes.problem import Problem


def random_exemplars(problem: Problem, count: int, rng: np.random.Generator,
                     style: str = 'state-action') -> ExemplarPolicy:
    """``count`` random exemplar records of ``style``: states uniform over
    [low, high), action indices uniform, values uniform over an episode's return range.
    Drawn field by field in the order state, state2, action, value."""
    states, states2, actions, values = _draw(problem, count, rng, style)
    return ExemplarPolicy(problem, states, actions, style=style, values=values,
                          states2=states2)


def _draw(problem: Problem, count: int, rng: np.random.Generator, style: str) -> tuple:
    """``random_exemplars``' draws: (states, states2, actions, values), None for a field
    the style does not use; angles not yet wrapped."""
    spec = style_named(style)
    states = rng.uniform(problem.low, problem.high, size=(count, problem.dim))
    states2 = actions = values = None
    if spec.uses('state2'):
        states2 = rng.uniform(problem.low, problem.high, size=(count, problem.dim))
    if spec.uses('action'):
        actions = rng.integers(0, len(problem.actions), size=count)
    if spec.uses('value'):
        values = rng.uniform(*problem.return_range, size=count)
    return states, states2, actions, values


def random_policy(problem: Problem, rng: np.random.Generator, l_min: int,
                  l_max: int, style: str = 'state-action') -> ExemplarPolicy:
    """An initial policy: size uniform in [l_min, l_max], random exemplars."""
    size = int(rng.integers(l_min, l_max + 1))
    return random_exemplars(problem, size, rng, style)


def _keys(policy: ExemplarPolicy) -> np.ndarray:
    """One opaque byte string per exemplar record (equal records, equal keys)."""
    rows = policy.records()
    return rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()


def deduplicate(policy: ExemplarPolicy) -> ExemplarPolicy:
    """Drop exemplars identical (bit for bit, every field) to an earlier one; keep order."""
    _, first = np.unique(_keys(policy), return_index=True)
    if len(first) == len(policy):
        return policy
    first.sort()
    return policy.subset(first)


def parents_union(p1: ExemplarPolicy, p2: ExemplarPolicy) -> tuple[ExemplarPolicy, np.ndarray]:
    """The deduplicated union of p1 and p2 (first-seen order) and, for every exemplar of
    p1 then p2, the index of its record in that union (computed once per family)."""
    both = concat_policies([p1, p2])
    _, first, inverse = np.unique(_keys(both), return_index=True, return_inverse=True)
    order = np.argsort(first, kind='stable')
    rank = np.empty(len(first), dtype=np.int64)
    rank[order] = np.arange(len(first))
    return both.subset(first[order]), rank[inverse.ravel()]


def uniform_crossover(p1: ExemplarPolicy, p2: ExemplarPolicy, rng: np.random.Generator,
                      l_min: int, l_max: int, rate: tuple[float, float] = (0.3, 0.7),
                      max_tries: int = 100, union: tuple | None = None
                      ) -> tuple[ExemplarPolicy, bool]:
    """A child of p1 and p2 and whether it had to be repaired.

    Each attempt keeps the selected exemplars deduplicated in first-seen order (computed
    on record indices into the parents' union, so an attempt builds no policy until its
    size is legal).  Repair, after ``max_tries`` failed attempts: draw a legal size, fill
    it from the parents' deduplicated union, topped up with fresh random exemplars only if
    the union is smaller than l_min.  (A converged population of near-identical parents of
    about l_min exemplars almost never yields a legal size; an unbounded retry would stall
    the run.)  ``union``: ``parents_union(p1, p2)`` if already computed.
    """
    union, ids = parents_union(p1, p2) if union is None else union
    ids1, ids2 = ids[:len(p1)], ids[len(p1):]
    for _ in range(max_tries):
        r = rng.uniform(*rate)                                    # selection rate
        take1 = rng.random(len(p1)) < r                           # e in E^p1 with prob r
        take2 = rng.random(len(p2)) < 1.0 - r                     # e in E^p2 with prob 1 - r
        chosen = np.concatenate([ids1[take1], ids2[take2]])
        _, first = np.unique(chosen, return_index=True)           # identical ones once
        if l_min <= len(first) <= l_max:
            first.sort()
            return union.subset(chosen[first]), False
    return repair(union, l_min, l_max, rng), True


def repair(union: ExemplarPolicy, l_min: int, l_max: int,
           rng: np.random.Generator) -> ExemplarPolicy:
    """A child of legal size from its parents' deduplicated ``union`` (``uniform_crossover``
    after ``max_tries`` failed attempts)."""
    size = int(rng.integers(l_min, l_max + 1))
    if len(union) >= l_min:
        size = min(size, len(union))
        return union.subset(np.sort(rng.choice(len(union), size=size, replace=False)))
    extra = random_exemplars(union.problem, size - len(union), rng, union.style)
    return concat_policies([union, extra])


def refresh(policy: ExemplarPolicy, used: np.ndarray, rng: np.random.Generator,
            rate: tuple[float, float] = (0.0, 0.5)) -> tuple[ExemplarPolicy, int]:
    """A clone of ``policy`` with lazy exemplars re-drawn; and how many were re-drawn.

    ``used`` marks the exemplars referred to in the policy's last evaluation.  The fresh
    records are ``random_exemplars``' draws.
    """
    r = rng.uniform(*rate)                                        # refresh rate
    redraw = ~used & (rng.random(len(policy)) < r)                # lazy, with prob r
    count = int(np.count_nonzero(redraw))
    clone = ExemplarPolicy.of_valid(policy.problem, policy.states.copy(),
                                    policy.actions.copy(), policy.style,
                                    policy.values.copy(), policy.states2.copy())
    if count:
        states, states2, actions, values = _draw(policy.problem, count, rng, policy.style)
        clone.states[redraw] = policy._wrapped(states)
        if states2 is not None:
            clone.states2[redraw] = policy._wrapped(states2)
        clone.actions[redraw] = 0 if actions is None else actions   # a style's unused
        clone.values[redraw] = 0.0 if values is None else values    # fields: zeros
    return clone, count
