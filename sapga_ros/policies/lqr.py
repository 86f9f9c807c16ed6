"""A linear-quadratic regulator about the upright state, from the compiled model.

The model is linearised numerically at the compiled MDP step (one step of the problem's
kernel holding the action, central differences about the best state with no action), so
the regulator is designed for exactly the discrete plant the episodes run: x' = A x + B u
with x the state minus the best state.  The gain solves the discrete algebraic Riccati
equation (SciPy): u = -K x, K = (R + B'PB)^-1 B'PA.

Weights, decided: Q = diag(1 / w_i^2) with w_i the goal box half-width of coordinate i at
delta = 1 (``goal.scale``; a coordinate with a fixed bound uses that bound), so x'Qx is the
squared goal-box distance; R = ``effort`` / a_max^2 with a_max the largest action
magnitude.  The designs (``sapga_ros.policies.classical.DESIGNS``) pick ``effort``: on the
acrobot with {-2, 0, 2} (five starts near the top) effort 1 leaves a limit cycle of
delta ~0.03 and 1e-4 holds within delta <= 0.008, because the quantiser, not R, limits the
command and a stiff gain keeps the cycle small.  ``inscribed_c(P, problem, delta)`` is the
largest c whose ellipsoid x'Px <= c lies inside the goal box S_delta.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sapga_ros.errors import SapgaError
from sim_nodes.models import model_module
from sim_nodes.problem import Problem

EPS = 1e-6          # central-difference step (raw units)
EFFORT = 1.0        # R weight, relative to the largest action squared


@dataclass(frozen=True)
class Regulator:
    """The discrete LQR of a problem: x' = A x + B u, u = -K x, cost-to-go x'Px."""

    A: np.ndarray   # (D, D)
    B: np.ndarray   # (D,)
    K: np.ndarray   # (D,)
    P: np.ndarray   # (D, D)
    half_width: np.ndarray  # (D,) goal box half-widths at delta = 1


def difference(problem: Problem, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a - b, angles the short way round (to [-pi, pi))."""
    d = a - b
    angle = problem.is_angle
    d[angle] = (d[angle] + math.pi) % (2 * math.pi) - math.pi
    return d


def linearise(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of one MDP step about the best state and zero action."""
    step = model_module(problem.model).mdp_step
    p = problem.params()
    best = problem.best_state
    dim = problem.dim

    def after(s: np.ndarray, u: float) -> np.ndarray:
        s = s.copy()
        step(s, u, p)
        return s

    A = np.empty((dim, dim))
    for i in range(dim):
        e = np.zeros(dim)
        e[i] = EPS
        A[:, i] = difference(problem, after(best + e, 0.0), after(best - e, 0.0)) / (2 * EPS)
    B = difference(problem, after(best, EPS), after(best, -EPS)) / (2 * EPS)
    return A, B


def inscribed_c(P: np.ndarray, problem: Problem, delta: float) -> float:
    """The largest c with {x'Px <= c} inside S_delta: min_i (delta w_i)^2 / (P^-1)_ii."""
    return float(np.min((delta * half_widths(problem)) ** 2 / np.diag(np.linalg.inv(P))))


def half_widths(problem: Problem) -> np.ndarray:
    """The goal box half-widths at delta = 1 (a fixed bound where a coordinate has one)."""
    scale = np.array(problem.goal_scale)
    fixed = np.array(problem.goal_fixed)
    return np.where(np.isnan(scale), fixed, scale)


def regulator(problem: Problem, effort: float = EFFORT) -> Regulator:
    """The LQR of ``problem`` about its best state."""
    from scipy.linalg import solve_discrete_are
    A, B = linearise(problem)
    w = half_widths(problem)
    Q = np.diag(1.0 / w ** 2)
    a_max = float(np.max(np.abs(problem.action_values)))
    R = np.array([[effort / a_max ** 2]])
    Bm = B.reshape(-1, 1)
    try:
        P = solve_discrete_are(A, Bm, Q, R)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SapgaError(f'{problem.name}: no LQR about the best state ({exc})') from exc
    K = np.linalg.solve(R + Bm.T @ P @ Bm, Bm.T @ P @ A).reshape(-1)
    return Regulator(A, B, K, P, w)
