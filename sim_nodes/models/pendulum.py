"""Simple pendulum dynamics kernel: torque-limited swing-up (the one-link relative of the
acrobot; added from docs/architecture.md, "How to add a problem").

==========  =====  ======================  ===============================================
state       unit   bounds                  meaning
==========  =====  ======================  ===============================================
theta       rad    [0, 2pi) wrapped        angle of the rod, counter-clockwise from +x
theta_dot   rad/s  [-4pi, 4pi] clipped     angular velocity, clipped after every substep
==========  =====  ======================  ===============================================

Hanging straight down is theta = 3pi/2, upright pi/2.  Action: torque tau at the pivot,
held for one MDP step = ``substeps`` classic RK4 steps of ``dt``.  A point mass m on a
massless rod of length l with viscous friction b:

    m l^2 theta_ddot = tau - m g l cos(theta) - b theta_dot

With |tau| below m g l the pendulum cannot be lifted straight up: it has to swing.  Reward
after the step: sin(theta) - 1, the height of the mass in rod lengths minus 1 (in [-2, 0]).
sin and cos are ``sim_nodes.models.trig`` (bit-identical in every kernel and on every
machine).
"""
import numpy as np

from sim_nodes.jit import kernel
from sim_nodes.models import pack_physics
from sim_nodes.models.common import clip, wrap_angle
from sim_nodes.models.trig import cos, sin

PARAMS = ('m', 'l', 'g', 'b', 'max_theta_dot')
# physics parameters that must be > 0 (the problem YAML is refused otherwise)
POSITIVE = ('m', 'l', 'max_theta_dot')
DT, SUBSTEPS, M, L, G, B, MAX_W = range(7)


def pack_params(problem) -> np.ndarray:
    return pack_physics(problem, PARAMS)


@kernel(inline='always')
def acceleration(theta, w, tau, inv_ml2, mgl, b):
    """theta_ddot [rad/s^2]."""
    return (tau - mgl * cos(theta) - b * w) * inv_ml2


@kernel(inline='always')
def rk4_substep(t, w, tau, dt, inv_ml2, mgl, b):
    """One classic RK4 step of dt from (theta, theta_dot); the new state, unclipped."""
    h = 0.5 * dt
    k1 = acceleration(t, w, tau, inv_ml2, mgl, b)
    w2 = w + h * k1
    k2 = acceleration(t + h * w, w2, tau, inv_ml2, mgl, b)
    w3 = w + h * k2
    k3 = acceleration(t + h * w2, w3, tau, inv_ml2, mgl, b)
    w4 = w + dt * k3
    k4 = acceleration(t + dt * w3, w4, tau, inv_ml2, mgl, b)
    c = dt / 6.0
    return t + c * (w + 2.0 * w2 + 2.0 * w3 + w4), w + c * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@kernel(inline='always')
def substep_lane(S, k, tau, dt, inv_ml2, mgl, b, max_w):
    """One RK4 substep of lane k of S; the angle wrapped, the velocity clipped."""
    t, w = rk4_substep(S[0, k], S[1, k], tau, dt, inv_ml2, mgl, b)
    S[0, k] = wrap_angle(t)
    S[1, k] = clip(w, -max_w, max_w)


@kernel
def mdp_step_lanes(S, tau, p, n, reward):
    """Advance columns 0..n-1 of S (2, W) by one MDP step, each holding torque tau[k] [N m].

    The angle is wrapped and the velocity clipped after every substep; reward[k] =
    sin(theta) - 1.  The lane loop is innermost (vectorised).
    """
    dt, max_w, b = p[DT], p[MAX_W], p[B]
    inv_ml2 = 1.0 / (p[M] * p[L] * p[L])
    mgl = p[M] * p[G] * p[L]
    for _ in range(int(p[SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, tau[k], dt, inv_ml2, mgl, b, max_w)
    for k in range(n):
        reward[k] = sin(S[0, k]) - 1.0


@kernel
def mdp_step_lanes_each(S, tau, P, n, reward):
    """``mdp_step_lanes`` with lane k's own parameters, row k of P (W, 7) (a mismatched
    plant per episode); dt and substeps of row 0 (never mismatched)."""
    dt = P[0, DT]
    C = np.empty((4, n))                   # lane k's constants in column k: loads vectorise
    for k in range(n):
        C[0, k] = 1.0 / (P[k, M] * P[k, L] * P[k, L])
        C[1, k] = P[k, M] * P[k, G] * P[k, L]
        C[2, k], C[3, k] = P[k, B], P[k, MAX_W]
    for _ in range(int(P[0, SUBSTEPS])):
        for k in range(n):
            substep_lane(S, k, tau[k], dt, C[0, k], C[1, k], C[2, k], C[3, k])
    for k in range(n):
        reward[k] = sin(S[0, k]) - 1.0


@kernel
def mdp_step(s, tau, p):
    """Hold torque tau [N m] for one MDP step on the state s (2,), in place; its reward."""
    reward = np.empty(1)
    mdp_step_lanes(s.reshape((s.shape[0], 1)), np.full(1, tau), p, 1, reward)
    return reward[0]
