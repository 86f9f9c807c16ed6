"""Mountain car dynamics kernel (Sutton & Barto, section 10.1).

=====  ======  ==================  ==========================================
state  unit    bounds              meaning
=====  ======  ==================  ==========================================
x      m       [-1.2, 0.5]         position; the left wall stops the car
v      m/step  [-0.07, 0.07]       velocity, clipped
=====  ======  ==================  ==========================================

Per MDP step with throttle a: v += power a - gravity cos(3 x), clipped; x += v; at the
left wall x = -1.2 and v = 0; x is clamped at the goal end 0.5.  Reward -1 per step.
"""
import numpy as np

from sim_nodes.jit import kernel
from sim_nodes.models import pack_physics
from sim_nodes.models.common import clip
from sim_nodes.models.trig import cos

PARAMS = ('power', 'gravity', 'x_min', 'x_max', 'v_max')
# physics parameters that must be > 0 (the problem YAML is refused otherwise)
POSITIVE = ('v_max',)
# physics parameters that must be in increasing order (the problem YAML is refused otherwise)
ORDERED = ('x_min', 'x_max')
DT, SUBSTEPS, POWER, GRAVITY, X_MIN, X_MAX, V_MAX = range(7)


def pack_params(problem) -> np.ndarray:
    return pack_physics(problem, PARAMS)


@kernel(inline='always')
def substep_lane(S, k, throttle, power, gravity, x_min, x_max, v_max):
    """One substep of lane k of S; the left wall stops the car."""
    v = clip(S[1, k] + power * throttle - gravity * cos(3.0 * S[0, k]), -v_max, v_max)
    x = S[0, k] + v
    wall = x < x_min
    S[0, k] = clip(x, x_min, x_max)
    S[1, k] = 0.0 if wall else v


@kernel
def mdp_step_lanes(S, throttle, p, n, reward):
    """Advance columns 0..n-1 of S (2, W) by one MDP step, each with throttle[k]."""
    power, gravity, x_min, x_max, v_max = p[POWER], p[GRAVITY], p[X_MIN], p[X_MAX], p[V_MAX]
    for _ in range(int(p[SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, throttle[k], power, gravity, x_min, x_max, v_max)
    for k in range(n):
        reward[k] = -1.0


@kernel
def mdp_step_lanes_each(S, throttle, P, n, reward):
    """``mdp_step_lanes`` with lane k's own parameters, row k of P (W, 7); substeps of
    row 0 (never mismatched)."""
    Q = np.ascontiguousarray(P[:n].T)      # lane k's parameters in column k: loads vectorise
    for _ in range(int(P[0, SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, throttle[k], Q[POWER, k], Q[GRAVITY, k], Q[X_MIN, k],
                         Q[X_MAX, k], Q[V_MAX, k])
    for k in range(n):
        reward[k] = -1.0


@kernel
def mdp_step(s, throttle, p):
    """One MDP step on the state s (2,), in place; its reward."""
    reward = np.empty(1)
    mdp_step_lanes(s.reshape((s.shape[0], 1)), np.full(1, throttle), p, 1, reward)
    return reward[0]
