"""Plain NumPy reference of the models and of an episode: what a user would write first.

Used as the baseline of ``sapga bench`` and, in the tests, as an independent statement of
the equations that the compiled kernels must agree with (to rounding: these use NumPy's
sin/cos and the book's formulas as printed, the kernels ``sim_nodes.models.trig`` and an
algebraically equal form).
"""
from __future__ import annotations

import numpy as np


def acrobot_accel(s, tau, prm):
    t1, t2, w1, w2 = s
    names = ('m1', 'm2', 'l1', 'lc1', 'lc2', 'I1', 'I2', 'g')
    m1, m2, l1, lc1, lc2, i1, i2, g = (prm[k] for k in names)
    d1 = m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2 * l1 * lc2 * np.cos(t2)) + i1 + i2
    d2 = m2 * (lc2 ** 2 + l1 * lc2 * np.cos(t2)) + i2
    phi2 = m2 * lc2 * g * np.cos(t1 + t2)
    phi1 = (-m2 * l1 * lc2 * w2 ** 2 * np.sin(t2) - 2 * m2 * l1 * lc2 * w2 * w1 * np.sin(t2)
            + (m1 * lc1 + m2 * l1) * g * np.cos(t1) + phi2)
    a2 = ((tau + d2 / d1 * phi1 - m2 * l1 * lc2 * w1 ** 2 * np.sin(t2) - phi2)
          / (m2 * lc2 ** 2 + i2 - d2 ** 2 / d1))
    a1 = -(d2 * a2 + phi1) / d1
    return np.array([w1, w2, a1, a2])


def acrobot_step(s, tau, problem):
    """One MDP step of the acrobot (RK4 substeps, wrap, clip); (new state, reward)."""
    prm = problem.physics
    dt = problem.dt
    s = np.array(s, dtype=float)
    for _ in range(problem.substeps):
        k1 = acrobot_accel(s, tau, prm)
        k2 = acrobot_accel(s + dt / 2 * k1, tau, prm)
        k3 = acrobot_accel(s + dt / 2 * k2, tau, prm)
        k4 = acrobot_accel(s + dt * k3, tau, prm)
        s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        s[:2] = np.mod(s[:2], 2 * np.pi)
        s[2] = np.clip(s[2], -prm['max_theta1_dot'], prm['max_theta1_dot'])
        s[3] = np.clip(s[3], -prm['max_theta2_dot'], prm['max_theta2_dot'])
    return s, np.sin(s[0]) + np.sin(s[0] + s[1]) - 3.0


def pdip_step(s, force, problem):
    """One MDP step of the PDIP (paper's Euler substeps, clip, rail); (new state, reward)."""
    prm = problem.physics
    dt, g = problem.dt, prm['g']
    m0, m1, m2, l1, l2 = prm['m0'], prm['m1'], prm['m2'], prm['l1'], prm['l2']
    x, v, t1, t2, w1, w2 = (float(c) for c in s)
    hit = False
    for _ in range(problem.substeps):
        s1, c1, s2, c2 = np.sin(t1), np.cos(t1), np.sin(t2), np.cos(t2)
        a = ((g * (m1 * s1 * c1 + m2 * s2 * c2)
              - 4 / 3 * (force + m1 * l1 * w1 ** 2 * c1 + m2 * l2 * w2 ** 2 * c2))
             / (m1 * s1 ** 2 + m2 * s2 ** 2 - 4 / 3 * (m0 + m1 + m2)))
        w1 += (a * s1 - g * c1) / (4 / 3 * l1) * dt
        w2 += (a * s2 - g * c2) / (4 / 3 * l2) * dt
        t1, t2 = np.mod(t1 + w1 * dt, 2 * np.pi), np.mod(t2 + w2 * dt, 2 * np.pi)
        v += a * dt
        x += v * dt
        v = float(np.clip(v, -prm['v_max'], prm['v_max']))
        w1 = float(np.clip(w1, -prm['theta_dot_max'], prm['theta_dot_max']))
        w2 = float(np.clip(w2, -prm['theta_dot_max'], prm['theta_dot_max']))
        if abs(x) > prm['x_max']:
            x, v, hit = float(np.clip(x, -prm['x_max'], prm['x_max'])), 0.0, True
    r = np.sin(t1) + np.sin(t2) - 3.0 + (prm['rail_penalty'] if hit else 0.0)
    return np.array([x, v, t1, t2, w1, w2]), r


STEPS = {'acrobot': acrobot_step, 'pdip': pdip_step}


def goal_delta(problem, s) -> float:
    best = problem.best_state
    diff = np.abs(np.asarray(s) - best)
    ang = problem.is_angle
    diff[ang] = np.minimum(diff[ang] % (2 * np.pi), 2 * np.pi - diff[ang] % (2 * np.pi))
    fixed = np.array(problem.goal_fixed)
    if np.any(diff > fixed):
        return np.inf
    scale = np.array(problem.goal_scale)
    scaled = ~np.isnan(scale)
    return float(np.max(diff[scaled] / scale[scaled]))


def select(problem, states, state) -> int:
    """Nearest exemplar by the normalised, circular distance (lowest index on ties)."""
    ranges, ang = problem.ranges, problem.is_angle
    diff = np.abs(states / ranges - np.asarray(state) / ranges)
    diff[:, ang] = np.mod(diff[:, ang], 1.0)
    diff[:, ang] = np.minimum(diff[:, ang], 1.0 - diff[:, ang])
    return int(np.argmin((diff ** 2).sum(axis=1)))


def episode(problem, states, actions, delta, n_step=None):
    """(return, steps, delta*, reached) of the state-action policy (states, action values)."""
    step = STEPS[problem.model]
    n_step = problem.resolve('n_step', n_step)
    s = problem.initial_state
    total, dstar = 0.0, goal_delta(problem, s)
    for t in range(1, n_step + 1):
        a = actions[select(problem, states, s)]
        s, r = step(s, a, problem)
        total += r
        d = goal_delta(problem, s)
        dstar = min(dstar, d)
        if d <= delta:
            return total, t, dstar, True
    return total, n_step, dstar, False
