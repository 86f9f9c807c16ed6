"""Goal area S_delta and delta(s), shared by every model.

``delta(s)`` is the smallest delta with s in S_delta: the largest of the scaled deviations
|s_i - best_i| / scale_i (circular on angles), or infinity when a coordinate with a fixed
bound (the PDIP's |x| <= 2) is outside it, or when a coordinate is not a number (a nan
state is never in the goal area).  A run achieves delta when delta* <= delta.
"""
import dataclasses
import math

import numpy as np
from sim_nodes.jit import kernel

from sim_nodes.models.common import TWO_PI


@kernel(inline='always')
def circular_diff(a: float, b: float) -> float:
    """|a - b|_c: the shortest way round the circle [rad], in [0, pi]."""
    d = math.fabs(a - b)
    if d >= TWO_PI:        # wrapped angles never get here: fmod would return d unchanged
        d = d % TWO_PI
    return TWO_PI - d if d > math.pi else d


@kernel(inline='always')
def goal_delta(s, best, inv_scale, fixed, is_angle):
    """delta(s); inv_scale is 1/scale (0 where the coordinate has a fixed bound)."""
    worst = 0.0
    for i in range(s.shape[0]):
        d = circular_diff(s[i], best[i]) if is_angle[i] else math.fabs(s[i] - best[i])
        if not d <= fixed[i]:      # also a nan state: never in the goal area
            return math.inf
        d *= inv_scale[i]
        if d > worst:
            worst = d
    return worst


@kernel(inline='always')
def lanes_delta(S, n, best, inv_scale, fixed, is_angle, out):
    """out[k] = ``goal_delta(S[:, k], ...)`` for the columns k < n of S (D, W), the lanes
    side by side: the same values (the same comparisons in the same order; a failed bound
    gives inf, as the early return does), computed dimension by dimension so that the lane
    loops vectorise.  A circular difference of 2pi or more (an angle not wrapped) needs the
    remainder: then every lane is recomputed by ``goal_delta``."""
    for k in range(n):
        out[k] = 0.0
    far = 0
    for i in range(S.shape[0]):
        b = best[i]
        inv = inv_scale[i]
        bound = fixed[i]
        row = S[i]
        if is_angle[i]:
            for k in range(n):
                d = math.fabs(row[k] - b)
                far |= d >= TWO_PI
                d = TWO_PI - d if d > math.pi else d
                d = d * inv if d <= bound else math.inf
                out[k] = d if d > out[k] else out[k]
        else:
            for k in range(n):
                d = math.fabs(row[k] - b)
                d = d * inv if d <= bound else math.inf
                out[k] = d if d > out[k] else out[k]
    if far:
        for k in range(n):
            out[k] = goal_delta(S[:, k], best, inv_scale, fixed, is_angle)


def goal_arrays(problem):
    """(best, inv_scale, fixed) of a Problem, as the kernels take them."""
    scale = np.array(problem.goal_scale, dtype=np.float64)
    inv_scale = np.where(np.isnan(scale), 0.0, 1.0 / np.where(np.isnan(scale), 1.0, scale))
    return problem.best_state, inv_scale, np.array(problem.goal_fixed, dtype=np.float64)


def alternative_goal(problem):
    """``problem`` with its alternative goal reading (goal.alternative_scale) as its goal;
    None if it has none."""
    if problem.goal_alt_scale is None:
        return None
    return dataclasses.replace(problem, goal_scale=problem.goal_alt_scale)


def alt_goal_arrays(problem):
    """(inv_scale, fixed) of the problem's alternative goal reading; empty arrays if none
    (the kernels then measure no alternative delta*)."""
    alt = alternative_goal(problem)
    if alt is None:
        return np.zeros(0), np.zeros(0)
    return goal_arrays(alt)[1:]


def delta_of(problem, s) -> float:
    """delta(s) of one state (a convenience around ``goal_delta``)."""
    return float(goal_delta(np.asarray(s, dtype=np.float64), *goal_arrays(problem),
                            problem.is_angle))


def hold_measures(first: int, held: int, steps: int, contacts: int) -> dict:
    """The hold task's measures of an episode of ``steps`` steps whose first step in S_delta
    was ``first`` (0: never) with ``held`` steps in S_delta from it on and ``contacts``
    end-stop contacts: first_entry_step (None: never), hold_fraction (steps in S_delta from
    the first entry to the end / steps from the first entry to the end; 0 if never entered)
    and rail_contacts."""
    fraction = held / (steps - first + 1) if first > 0 else 0.0
    return {'first_entry_step': first if first > 0 else None, 'hold_fraction': fraction,
            'rail_contacts': contacts}


def trace_hold(problem, states, rewards, delta: float) -> dict:
    """``hold_measures`` of a recorded episode: ``states`` from the initial one on, one
    reward per step (a contact is a reward below ``problem.contact_below``)."""
    inside = [delta_of(problem, s) <= delta for s in states[1:]]
    first = inside.index(True) + 1 if True in inside else 0
    held = sum(inside[first - 1:]) if first else 0
    contacts = sum(1 for r in rewards if r < problem.contact_below)
    return hold_measures(first, held, len(inside), contacts)
