"""The pendulum problem (added as one YAML + one kernel, docs/architecture.md): physics
properties of its kernel."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from sim_nodes.models import pendulum
from sim_nodes.problem import load_problem


def energy(s, problem) -> float:
    ph = problem.physics
    return 0.5 * ph['m'] * ph['l'] ** 2 * s[1] ** 2 + ph['m'] * ph['g'] * ph['l'] * math.sin(s[0])


def test_without_friction_or_torque_energy_is_conserved():
    """b = 0, tau = 0: total energy stays within RK4's error over 200 steps (10 s)."""
    problem = load_problem('pendulum')
    problem = dataclasses.replace(problem, physics={**problem.physics, 'b': 0.0})
    s = np.array([0.3, 0.0])
    e0 = energy(s, problem)
    for _ in range(200):
        pendulum.mdp_step(s, 0.0, problem.params())
        assert abs(energy(s, problem) - e0) < 1e-6 * abs(e0)


def test_friction_only_takes_energy_and_hanging_at_rest_stays():
    """With friction and no torque the energy never rises; the bottom is an equilibrium."""
    problem = load_problem('pendulum')
    s = np.array([0.3, 2.0])
    e = energy(s, problem)
    for _ in range(100):
        pendulum.mdp_step(s, 0.0, problem.params())
        assert energy(s, problem) <= e + 1e-9
        e = energy(s, problem)
    rest = problem.initial_state.copy()
    reward = pendulum.mdp_step(rest, 0.0, problem.params())
    assert abs(rest[0] - 1.5 * math.pi) < 1e-12 and abs(rest[1]) < 1e-12
    assert reward == math.sin(rest[0]) - 1.0


def test_torque_below_mgl_cannot_hold_the_pendulum_horizontal():
    """|tau| = 3 < m g l = 4.9: pushing up from horizontal at rest, it still falls."""
    problem = load_problem('pendulum')
    s = np.array([0.0, 0.0])                 # horizontal, at rest
    pendulum.mdp_step(s, max(problem.actions), problem.params())
    assert s[1] < 0.0                        # falls (clockwise), whatever the torque
