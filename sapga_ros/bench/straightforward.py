"""The straightforward numba kernel ``sapga bench`` compares the batch kernel with.

What a numba user writes first for the acrobot's state-action episodes: the plain NumPy
reference (``sim_nodes.reference``: the book's equations, RK4 on state vectors, the nearest
exemplar by normalised circular distance) compiled with numba's default options, one
episode and one step at a time.  It is a yardstick, not part of the product: nothing else
calls it, and it agrees with the batch kernel to rounding, not bit for bit (libm sin/cos).
"""
from __future__ import annotations

import math

import numpy as np
import sim_nodes.jit  # noqa: F401  numba's code generator is set up there, before these
from numba import njit  # njit functions make it (the same compiler settings for both)

TWO_PI = 2.0 * math.pi


@njit
def _accel(s, tau, prm):
    m1, m2, l1, lc1, lc2, i1, i2, g = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], \
        prm[6], prm[7]
    t1, t2, w1, w2 = s[0], s[1], s[2], s[3]
    d1 = m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2 * l1 * lc2 * math.cos(t2)) + i1 + i2
    d2 = m2 * (lc2 ** 2 + l1 * lc2 * math.cos(t2)) + i2
    phi2 = m2 * lc2 * g * math.cos(t1 + t2)
    phi1 = (-m2 * l1 * lc2 * w2 ** 2 * math.sin(t2) - 2 * m2 * l1 * lc2 * w2 * w1
            * math.sin(t2) + (m1 * lc1 + m2 * l1) * g * math.cos(t1) + phi2)
    a2 = ((tau + d2 / d1 * phi1 - m2 * l1 * lc2 * w1 ** 2 * math.sin(t2) - phi2)
          / (m2 * lc2 ** 2 + i2 - d2 ** 2 / d1))
    a1 = -(d2 * a2 + phi1) / d1
    return np.array([w1, w2, a1, a2])


@njit
def _step(s, tau, prm, dt, substeps):
    """One MDP step: RK4 substeps, angles wrapped, velocities clipped; (state, reward)."""
    for _ in range(substeps):
        k1 = _accel(s, tau, prm)
        k2 = _accel(s + dt / 2 * k1, tau, prm)
        k3 = _accel(s + dt / 2 * k2, tau, prm)
        k4 = _accel(s + dt * k3, tau, prm)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[0] = s[0] % TWO_PI
        s[1] = s[1] % TWO_PI
        s[2] = min(max(s[2], -prm[8]), prm[8])
        s[3] = min(max(s[3], -prm[9]), prm[9])
    return s, math.sin(s[0]) + math.sin(s[0] + s[1]) - 3.0


@njit
def _nearest(states, s, ranges, is_angle):
    best, best_d = 0, math.inf
    for j in range(states.shape[0]):
        total = 0.0
        for d in range(states.shape[1]):
            diff = abs(states[j, d] / ranges[d] - s[d] / ranges[d])
            if is_angle[d]:
                diff = diff % 1.0
                diff = min(diff, 1.0 - diff)
            total += diff ** 2
        if total < best_d:
            best, best_d = j, total
    return best


@njit
def episodes(states, actions, s0, prm, dt, substeps, ranges, is_angle, n_step):
    """Run each policy (states (P, L, D), actions (P, L)) for n_step steps from s0 (no
    goal test: the bench's delta is 0); (returns (P,), MDP steps simulated)."""
    returns = np.zeros(states.shape[0])
    for k in range(states.shape[0]):
        s = s0.copy()
        for _ in range(n_step):
            a = actions[k, _nearest(states[k], s, ranges, is_angle)]
            s, r = _step(s, a, prm, dt, substeps)
            returns[k] += r
    return returns, states.shape[0] * n_step


def acrobot_arguments(problem, policies) -> tuple:
    """``episodes``' arguments for acrobot state-action policies."""
    names = ('m1', 'm2', 'l1', 'lc1', 'lc2', 'I1', 'I2', 'g', 'max_theta1_dot',
             'max_theta2_dot')
    prm = np.array([problem.physics[n] for n in names], dtype=np.float64)
    states = np.array([p.states for p in policies], dtype=np.float64)
    actions = np.array([problem.action_values[p.actions] for p in policies])
    return (states, actions, problem.initial_state.astype(np.float64), prm,
            float(problem.dt), int(problem.substeps), problem.ranges, problem.is_angle,
            int(problem.n_step))
