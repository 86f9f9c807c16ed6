"""PDIP dynamics kernel: two parallel inverted pendulums on a cart (paper 4.2).

==============  ======  ========================  =========================================
state           unit    bounds                    meaning
==============  ======  ========================  =========================================
x               m       [-2.5, 2.5] rail          cart position
v               m/s     [-16, 16] clipped         cart velocity
theta1, theta2  rad     [0, 2pi) wrapped          pole angles, counter-clockwise from +x
theta{1,2}_dot  rad/s   [-4pi, 4pi] clipped       pole angular velocities
==============  ======  ========================  =========================================

Down is 3pi/2, up pi/2.  Action: force T on the cart in {-40, 0, +40} N.  Each substep of
dt (paper's equations, s_i = sin theta_i, c_i = cos theta_i):

    a = (g (m1 s1 c1 + m2 s2 c2) - 4/3 (T + m1 l1 w1^2 c1 + m2 l2 w2^2 c2))
        / (m1 s1^2 + m2 s2^2 - 4/3 (m0 + m1 + m2))          car acceleration
    w_i += (a s_i - g c_i) / (4/3 l_i) dt,  theta_i += w_i dt  (with the new w_i)
    v += a dt,  x += v dt                                     (with the new v)

then wrap the angles, clip the velocities (after the substep's updates: theta_i and x
move with the unclipped new velocities), and apply the rail: if x left [-x_max, x_max]
the cart stops at the rail end (x clamped, v = 0) and the MDP step gets ``rail_penalty``.
Reward: sin(theta1) + sin(theta2) - 3 (+ rail penalty).  With l2 = l1 and the symmetric
start both poles move identically: the single inverted pendulum (``pdip_single``).
"""
import numpy as np
from sim_nodes.jit import kernel

from sim_nodes.models import pack_physics
from sim_nodes.models.common import clip, wrap_angle
from sim_nodes.models.trig import sin, sincos

END_STOP_PENALTY = 'rail_penalty'  # added on a rail contact (counted as rail_contacts)
PARAMS = ('m0', 'm1', 'm2', 'l1', 'l2', 'g', 'x_max', 'v_max', 'theta_dot_max', 'rail_penalty')
# physics parameters that must be > 0 (the problem YAML is refused otherwise)
POSITIVE = ('m0', 'm1', 'm2', 'l1', 'l2', 'x_max', 'v_max', 'theta_dot_max')
DT, SUBSTEPS, M0, M1, M2, L1, L2, G, X_MAX, V_MAX, W_MAX, RAIL = range(12)


def pack_params(problem) -> np.ndarray:
    return pack_physics(problem, PARAMS)


@kernel(inline='always')
def substep_lane(S, k, force, dt, g, m0, m1, m2, l1, l2, x_max, v_max, w_max, rail, reward):
    """One substep of lane k of S holding ``force``; reward[k] becomes ``rail`` on a rail
    contact."""
    x, v, t1, t2, w1, w2 = S[0, k], S[1, k], S[2, k], S[3, k], S[4, k], S[5, k]
    s1, c1 = sincos(t1)
    s2, c2 = sincos(t2)
    a = ((g * (m1 * s1 * c1 + m2 * s2 * c2)
          - 4.0 / 3.0 * (force + m1 * l1 * w1 * w1 * c1 + m2 * l2 * w2 * w2 * c2))
         / (m1 * s1 * s1 + m2 * s2 * s2 - 4.0 / 3.0 * (m0 + m1 + m2)))  # car accel.
    w1 = w1 + (a * s1 - g * c1) / (4.0 / 3.0 * l1) * dt
    w2 = w2 + (a * s2 - g * c2) / (4.0 / 3.0 * l2) * dt
    t1 = t1 + w1 * dt
    t2 = t2 + w2 * dt
    v = v + a * dt
    x = x + v * dt
    # after the substep's updates: wrap, clip, then the rail
    S[2, k] = wrap_angle(t1)
    S[3, k] = wrap_angle(t2)
    S[4, k] = clip(w1, -w_max, w_max)
    S[5, k] = clip(w2, -w_max, w_max)
    xc = clip(x, -x_max, x_max)
    hit = xc != x
    S[0, k] = xc
    S[1, k] = 0.0 if hit else clip(v, -v_max, v_max)
    # rail penalty once per MDP step: reward[k] is 0 or rail, and becomes rail on a
    # hit.  Stored unconditionally: the masked store of ``rail if hit else
    # reward[k]`` kept the loop from vectorising (5 M vs 24 M lane-steps/s)
    reward[k] += (rail - reward[k]) * hit


@kernel(inline='always')
def heights(S, n, reward):
    """reward[k] += pole heights - 3 of lanes 0..n-1."""
    for k in range(n):
        reward[k] += sin(S[2, k]) + sin(S[3, k]) - 3.0


@kernel
def mdp_step_lanes(S, force, p, n, reward):
    """Advance columns 0..n-1 of S (6, W) by one MDP step, each holding force[k] [N].

    The lane loop is innermost so independent episodes run side by side (vectorised).
    """
    dt, g = p[DT], p[G]
    m0, m1, m2, l1, l2 = p[M0], p[M1], p[M2], p[L1], p[L2]
    x_max, v_max, w_max, rail = p[X_MAX], p[V_MAX], p[W_MAX], p[RAIL]
    for k in range(n):
        reward[k] = 0.0
    for _ in range(int(p[SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, force[k], dt, g, m0, m1, m2, l1, l2, x_max, v_max, w_max, rail,
                         reward)
    heights(S, n, reward)


@kernel
def mdp_step_lanes_each(S, force, P, n, reward):
    """``mdp_step_lanes`` with lane k's own parameters, row k of P (W, 12) (a mismatched
    plant per episode); dt and substeps of row 0 (never mismatched)."""
    dt = P[0, DT]
    Q = np.ascontiguousarray(P[:n].T)      # lane k's parameters in column k: loads vectorise
    for k in range(n):
        reward[k] = 0.0
    for _ in range(int(P[0, SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, force[k], dt, Q[G, k], Q[M0, k], Q[M1, k], Q[M2, k], Q[L1, k],
                         Q[L2, k], Q[X_MAX, k], Q[V_MAX, k], Q[W_MAX, k], Q[RAIL, k], reward)
    heights(S, n, reward)


@kernel
def mdp_step(s, force, p):
    """Hold force [N] for one MDP step on the state s (6,), in place; its reward."""
    reward = np.empty(1)
    mdp_step_lanes(s.reshape((s.shape[0], 1)), np.full(1, force), p, 1, reward)
    return reward[0]
