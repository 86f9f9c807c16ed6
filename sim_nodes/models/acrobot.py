"""Acrobot dynamics kernel (paper 4.1).

Two uniform links hang from a fixed shoulder; the only motor is at the elbow.

==============  ==========  =======================  ======================================
state           unit        bounds                   meaning
==============  ==========  =======================  ======================================
theta1          rad         [0, 2pi) wrapped         link 1 angle, counter-clockwise from +x
theta2          rad         [0, 2pi) wrapped         link 2 angle relative to link 1
theta1_dot      rad/s       [-4pi, 4pi] clipped      after every substep
theta2_dot      rad/s       [-9pi, 9pi] clipped      after every substep
==============  ==========  =======================  ======================================

Hanging straight down is theta1 = 3pi/2, upright pi/2.  Action: elbow torque tau in
{-2, 0, +2} N m held for one MDP step = ``substeps`` classic RK4 steps of ``dt``.
Reward after the step: sin(theta1) + sin(theta1 + theta2) - 3, the tip height minus 3.

Equations: the Spong acrobot as in Sutton & Barto (the "book" variant of Gymnasium's
``acrobot.py``, with the -m2 l1 lc2 theta1_dot^2 sin(theta2) term), written in this angle
convention so that the gravity terms use cos(theta1) and cos(theta1 + theta2).  sin and cos
are ``sim_nodes.models.trig`` (bit-identical in every kernel and on every machine).
"""
import math

import numpy as np
from sim_nodes.jit import kernel

from sim_nodes.models import pack_physics
from sim_nodes.models.common import clip, wrap_angle
from sim_nodes.models.trig import sin, sincos

PARAMS = ('m1', 'm2', 'l1', 'lc1', 'lc2', 'I1', 'I2', 'g', 'max_theta1_dot', 'max_theta2_dot')
# physics parameters that must be > 0 (the problem YAML is refused otherwise)
POSITIVE = ('m1', 'm2', 'l1', 'lc1', 'lc2', 'I1', 'I2', 'max_theta1_dot', 'max_theta2_dot')
# indices into the packed vector [dt, substeps, *PARAMS]
DT, SUBSTEPS, M1, M2, L1, LC1, LC2, I1, I2, G, MAX_W1, MAX_W2 = range(12)


def pack_params(problem) -> np.ndarray:
    return pack_physics(problem, PARAMS)


@kernel(inline='always')
def accelerations(t1, t2, w1, w2, tau, k):
    """(theta1_ddot, theta2_ddot) [rad/s^2]; k = ``constants(p)``."""
    m2l1lc2, g1, g2, d1c, d1v, d2c, d2v, d3 = k
    s1, c1 = sincos(t1)
    s2, c2 = sincos(t2)
    c12 = c1 * c2 - s1 * s2                      # cos(theta1 + theta2)
    d1 = d1c + d1v * c2                          # M11 (constants: see ``constants``)
    d2 = d2c + d2v * c2                          # M12 = m2 (lc2^2 + l1 lc2 c2) + I2
    phi2 = g2 * c12                              # dV/dtheta2 = m2 lc2 g cos(theta1 + theta2)
    phi1 = -m2l1lc2 * s2 * w2 * (w2 + 2.0 * w1) + g1 * c1 + phi2  # Coriolis + dV/dtheta1
    a2 = (tau + d2 / d1 * phi1 - m2l1lc2 * w1 * w1 * s2 - phi2) / (d3 - d2 * d2 / d1)
    a1 = -(d2 * a2 + phi1) / d1
    return a1, a2


@kernel(inline='always')
def constants(p):
    """Products of the parameters that the equations use, computed once per call."""
    m1, m2, l1, lc1, lc2, i1, i2, g = p[M1], p[M2], p[L1], p[LC1], p[LC2], p[I1], p[I2], p[G]
    return (m2 * l1 * lc2,                                   # m2 l1 lc2
            (m1 * lc1 + m2 * l1) * g,                        # gravity on link 1
            m2 * lc2 * g,                                    # gravity on link 2
            m1 * lc1 * lc1 + m2 * (l1 * l1 + lc2 * lc2) + i1 + i2,  # M11 constant part
            2.0 * m2 * l1 * lc2,                             # M11 cos(theta2) part
            m2 * lc2 * lc2 + i2,                             # M12 constant part
            m2 * l1 * lc2,                                   # M12 cos(theta2) part
            m2 * lc2 * lc2 + i2)                             # M22


@kernel(inline='always')
def rk4_substep(t1, t2, w1, w2, tau, dt, k):
    """One classic RK4 step of dt from (theta1, theta2, w1, w2); the new state, unclipped."""
    k1a1, k1a2 = accelerations(t1, t2, w1, w2, tau, k)
    h = 0.5 * dt
    k2w1, k2w2 = w1 + h * k1a1, w2 + h * k1a2
    k2a1, k2a2 = accelerations(t1 + h * w1, t2 + h * w2, k2w1, k2w2, tau, k)
    k3w1, k3w2 = w1 + h * k2a1, w2 + h * k2a2
    k3a1, k3a2 = accelerations(t1 + h * k2w1, t2 + h * k2w2, k3w1, k3w2, tau, k)
    k4w1, k4w2 = w1 + dt * k3a1, w2 + dt * k3a2
    k4a1, k4a2 = accelerations(t1 + dt * k3w1, t2 + dt * k3w2, k4w1, k4w2, tau, k)
    c = dt / 6.0
    return (t1 + c * (w1 + 2.0 * k2w1 + 2.0 * k3w1 + k4w1),
            t2 + c * (w2 + 2.0 * k2w2 + 2.0 * k3w2 + k4w2),
            w1 + c * (k1a1 + 2.0 * k2a1 + 2.0 * k3a1 + k4a1),
            w2 + c * (k1a2 + 2.0 * k2a2 + 2.0 * k3a2 + k4a2))


@kernel(inline='always')
def substep_lane(S, k, tau, dt, max_w1, max_w2, consts):
    """One RK4 substep of lane k of S holding torque tau; angles wrapped, velocities
    clipped."""
    t1, t2, w1, w2 = rk4_substep(S[0, k], S[1, k], S[2, k], S[3, k], tau, dt, consts)
    S[0, k] = wrap_angle(t1)
    S[1, k] = wrap_angle(t2)
    S[2, k] = clip(w1, -max_w1, max_w1)
    S[3, k] = clip(w2, -max_w2, max_w2)


@kernel(inline='always')
def rewards(S, n, reward):
    """reward[k] = tip height - 3 of lanes 0..n-1."""
    for k in range(n):
        reward[k] = sin(S[0, k]) + sin(S[0, k] + S[1, k]) - 3.0


@kernel
def mdp_step_lanes(S, tau, p, n, reward):
    """Advance columns 0..n-1 of S (4, W) by one MDP step, each holding torque tau[k] [N m].

    Angles wrapped and velocities clipped after every substep; reward[k] = tip height - 3.
    The lane loop is innermost so independent episodes run side by side (vectorised).
    """
    max_w1, max_w2, dt = p[MAX_W1], p[MAX_W2], p[DT]
    consts = constants(p)
    for _ in range(int(p[SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, tau[k], dt, max_w1, max_w2, consts)
    rewards(S, n, reward)


@kernel
def mdp_step_lanes_each(S, tau, P, n, reward):
    """``mdp_step_lanes`` with lane k's own parameters, row k of P (W, 12) (a mismatched
    plant per episode); dt and substeps of row 0 (never mismatched).  Each lane computes
    what ``mdp_step_lanes`` computes with P[k]."""
    dt = P[0, DT]
    C = np.empty((10, n))                  # lane k's constants in column k: loads vectorise
    for k in range(n):
        C[:8, k] = constants(P[k])
        C[8, k], C[9, k] = P[k, MAX_W1], P[k, MAX_W2]
    for _ in range(int(P[0, SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, tau[k], dt, C[8, k], C[9, k], (
                C[0, k], C[1, k], C[2, k], C[3, k], C[4, k], C[5, k], C[6, k], C[7, k]))
    rewards(S, n, reward)


@kernel
def mdp_step(s, tau, p):
    """Hold torque tau [N m] for one MDP step on the state s (4,), in place; its reward."""
    reward = np.empty(1)
    mdp_step_lanes(s.reshape((s.shape[0], 1)), np.full(1, tau), p, 1, reward)
    return reward[0]


def energy(s, p) -> float:
    """Total mechanical energy [J] (kinetic + potential, heights up from the shoulder)."""
    t1, t2, w1, w2 = s
    m1, m2, l1, lc1, lc2, i1, i2, g = (p[k] for k in (M1, M2, L1, LC1, LC2, I1, I2, G))
    c2 = math.cos(t2)
    d1 = m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2 * l1 * lc2 * c2) + i1 + i2
    d2 = m2 * (lc2 ** 2 + l1 * lc2 * c2) + i2
    d3 = m2 * lc2 ** 2 + i2
    kinetic = 0.5 * d1 * w1 ** 2 + d2 * w1 * w2 + 0.5 * d3 * w2 ** 2
    potential = g * ((m1 * lc1 + m2 * l1) * math.sin(t1) + m2 * lc2 * math.sin(t1 + t2))
    return kinetic + potential
