"""The state a controller acts on when its sensors are noisy: a steady-state Kalman filter.

A plant measured with sensor noise of sigma 0.002 on every coordinate cannot be held by the
quantised LQR acting on what it sees: near the top the LQR's stiff gains turn that noise into
commands that jump between the actuator's few actions, and an acrobot it could hold from
upright +-0.005 falls in about one episode of ten (docs/robustness.md, "Seeing through the
sensor noise").  ``StateFilter`` estimates the state instead: each step the last estimate is
stepped one MDP step on the controller's model (the nominal one, or the fitted one of
``--replan-fit``) with the command the plant applied during it, and corrected towards the
state seen by the constant gain L, angles the short way round.  L is the steady-state Kalman
gain of the model linearised about the best state (``sapga_ros.policies.lqr``), measured
directly (C = I) with noise ``sigma`` on every coordinate and process noise ``PROCESS`` per
coordinate and step (rad or rad/s; m or m/s on a cart): the model error a 5 % mismatch of
masses and lengths leaves, chosen on the acrobot under ``field``.  The noisier the sensors,
the more the estimate trusts the model.  The first state seen after a reset is the first
estimate.  The estimate is a pure function of the states seen and the commands issued, so a
controller using it is still a function of what it has seen.
"""
from __future__ import annotations

import math

import numpy as np

from sapga_ros.errors import SapgaError
from sapga_ros.policies.lqr import difference, linearise
from sim_nodes.models.dispatch import step_lanes

PROCESS = 5e-4     # process noise per step and coordinate (the model's error)


def filter_gain(problem, sigma: float) -> np.ndarray:
    """The steady-state Kalman gain L (D, D) of ``problem``'s model linearised about its
    best state, measured with noise ``sigma`` on every coordinate."""
    from scipy.linalg import solve_discrete_are
    A, _ = linearise(problem)
    dim = problem.dim
    R = sigma ** 2 * np.eye(dim)
    Q = PROCESS ** 2 * np.eye(dim)
    try:
        prior = solve_discrete_are(A.T, np.eye(dim), Q, R)
        gain = prior @ np.linalg.inv(prior + R)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise SapgaError(f'replan_filter: no Kalman filter about the best state of '
                         f'{problem.name} ({exc})') from exc
    if not np.all(np.isfinite(gain)):
        raise SapgaError(f'replan_filter: no Kalman filter about the best state of '
                         f'{problem.name} (the gain is not finite)')
    return gain


class StateFilter:
    """The filtered state of one episode (module docstring): ``reset()`` at its start,
    ``update(seen, applied, p)`` at every step."""

    def __init__(self, problem, model: int, sigma: float) -> None:
        self.problem, self.model = problem, model
        self.L = filter_gain(problem, sigma)
        self.angle = np.asarray(problem.is_angle, dtype=bool)
        self._one = (np.empty((problem.dim, 1)), np.empty(1), np.empty(1))
        self.reset()

    def reset(self) -> None:
        self.estimate: np.ndarray | None = None

    def update(self, seen: np.ndarray, applied: float, p: np.ndarray) -> np.ndarray:
        """The estimate of the state ``seen`` measures, the command ``applied`` having acted
        since the last update, on the model with packed parameters ``p``."""
        if self.estimate is None or not np.all(np.isfinite(self.estimate)):
            self.estimate = np.array(seen, dtype=np.float64)
            return self.estimate.copy()
        S, a, r = self._one
        S[:, 0] = self.estimate
        a[0] = applied
        step_lanes(self.model, S, a, p, 1, r)
        prior = S[:, 0]
        x = prior + self.L @ difference(self.problem, seen, prior)
        x[self.angle] = np.remainder(x[self.angle], 2 * math.pi)
        self.estimate = x
        return x.copy()
