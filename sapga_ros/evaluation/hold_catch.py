"""The catch a hold task's planner hands over to: the classical LQR about the upright state.

A planner (``replan.Replanner``) on a problem whose episode does not end in S_delta (the hold
task: swing up and stay up) cannot score a plan by its entry into S_delta, since entering is
not staying, and it cannot hold the pendulum by re-planning alone.  It plans instead to enter
``AIM`` x the region of this LQR, and once the state predicted for its command lies inside
x'Px <= c the LQR commands: the action nearest -Kx (the quantised LQR of the classical
controller, ``sapga_ros.evaluation.classical_design``).  c is ``SHARE`` x the catch region
measured for the classical design on the plant with the planner's delay (``basin_c``):
deeper than that region, since a disturbed plant is noisy and not the model.  With the model
fitted as it runs (``--replan-fit``) K and P are designed again on the fitted masses and
lengths every ``REDESIGN`` steps.  SHARE and AIM were chosen on the acrobot under ``field``
(docs/robustness.md, "How small the hold's catch is").
"""
from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.control import nearest_action
from sim_nodes.models import model_module
from sim_nodes.problem import Problem

SHARE = 0.3        # the hand-over region: SHARE x the classical design's catch region
AIM = 0.5          # the planner aims at AIM x the hand-over region
REDESIGN = 50      # steps between designs on the fitted model

_NOMINAL: dict[tuple, tuple[np.ndarray, np.ndarray, float]] = {}
_LOCK = threading.Lock()


def plannable_hold(problem: Problem) -> bool:
    """Whether a hold task has a classical design to hand over to."""
    from sapga_ros.policies.classical import DESIGNS
    return problem.model in DESIGNS


def _nominal(problem: Problem, delay: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(K, P, c) of the classical design of ``problem`` for ``delay`` (its catch region
    measured once per problem and delay: some 0.1 s)."""
    key = (repr(dataclasses.replace(problem, ros={}, source='')), delay)   # every setting
    with _LOCK:
        found = _NOMINAL.get(key)
    if found is None:
        from sapga_ros.evaluation.classical_design import classical_policy
        design = classical_policy(problem, delay=delay)
        found = (design.K.copy(), design.P.copy(), float(design.c))
        with _LOCK:
            _NOMINAL[key] = found
    return found


class HoldCatch:
    """The LQR a hold task's planner hands over to (module docstring)."""

    def __init__(self, problem: Problem, delay: int) -> None:
        if not plannable_hold(problem):
            raise SapgaError(f'replan: {problem.name} is a hold task without a classical '
                             f'design to hand over to (model {problem.model})')
        self.problem = problem
        self.K0, self.P0, c = _nominal(problem, delay)
        if not c > 0.0:
            raise SapgaError(f'replan: the classical LQR of {problem.name} has no catch region '
                             f'for a delay of {delay} steps (nothing to hand over to)')
        self.c = SHARE * c
        self.aim = AIM * self.c
        self.best = np.asarray(problem.best_state, dtype=np.float64)
        self.actions = np.asarray(problem.action_values, dtype=np.float64)
        self.names = model_module(problem.model).PARAMS
        self.reset()

    def reset(self) -> None:
        self.K, self.P = self.K0, self.P0

    def design(self, p: np.ndarray) -> None:
        """K and P designed again on the packed parameters ``p`` (the fitted model)."""
        from sapga_ros.policies.classical import DESIGNS
        from sapga_ros.policies.lqr import regulator
        physics = dict(self.problem.physics,
                       **{name: float(p[2 + i]) for i, name in enumerate(self.names)})
        try:
            reg = regulator(dataclasses.replace(self.problem, physics=physics),
                            DESIGNS[self.problem.model].effort)
        except SapgaError:
            return                      # no LQR on this estimate: keep the last one
        self.K, self.P = reg.K, reg.P

    def offset(self, s: np.ndarray) -> np.ndarray:
        """s minus the upright state, angles the short way round."""
        x = np.asarray(s, dtype=np.float64) - self.best
        angle = self.problem.is_angle
        x[angle] = np.remainder(x[angle] + math.pi, 2 * math.pi) - math.pi
        return x

    def command(self, s: np.ndarray) -> float | None:
        """The quantised LQR's action for the (predicted) state s inside x'Px <= c, else
        None."""
        x = self.offset(s)
        if not float(x @ self.P @ x) <= self.c:     # NaN: not inside
            return None
        return float(nearest_action(-float(self.K @ x), self.actions))
