"""Goal area S_delta and delta(s) (SPEC 2), shared by every model.

``delta(s)`` is the smallest delta with s in S_delta: the largest of the scaled deviations
|s_i - best_i| / scale_i (circular on angles), or infinity when a coordinate with a fixed
bound (the PDIP's |x| <= 2) is outside it.  A run achieves delta when delta* <= delta.
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
        if d > fixed[i]:
            return math.inf
        d *= inv_scale[i]
        if d > worst:
            worst = d
    return worst


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
