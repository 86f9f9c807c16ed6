"""The catch a hold task's planner hands over to: the classical LQR about the upright state.

A planner (``replan.Replanner``) on a problem whose episode does not end in S_delta (the hold
task: swing up and stay up) cannot score a plan by its entry into S_delta, since entering is
not staying, and it cannot hold the pendulum by re-planning alone.  It plans instead to enter
``AIM`` x the region x'Px <= c of this LQR, c being ``SHARE`` x the catch region measured for
the classical design on the plant with the planner's delay (``basin_c``).  The LQR commands
(the action nearest -Kx: the quantised LQR of the classical controller,
``sapga_ros.evaluation.classical_design``) once the state predicted for its command is
within ``GATE`` x c and the quantised LQR, run on the planner's model (nominal, or fitted)
from there for ``HORIZON`` MDP steps, ends inside ``SETTLE`` x c: the model's word that it
settles.  The ellipsoid alone is the wrong test: the LQR's gains are stiff and its command
is one of a few actions, so what it can stop depends on the direction a state comes from
as much as on x'Px, and a swing-up arriving fast passes through the ellipsoid and out the
other side (docs/robustness.md, "Handing over where the LQR settles").  With the model
fitted as it runs (``--replan-fit``) K and P are designed again on the fitted masses and
lengths every ``REDESIGN`` steps.  SHARE and AIM were chosen on the acrobot under ``field``;
GATE, HORIZON and SETTLE are the first values tried (docs/robustness.md).
"""
from __future__ import annotations

import dataclasses
import math
import threading

import numpy as np

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.control import nearest_action
from sapga_ros.policies.lqr import difference
from sim_nodes.jit import kernel
from sim_nodes.models import model_module
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import Problem

SHARE = 0.3        # c: SHARE x the classical design's catch region
AIM = 0.5          # the planner aims at AIM x c
GATE = 20.0        # the LQR is tried from states within GATE x c
HORIZON = 80       # MDP steps of the quantised LQR on the model that must settle
SETTLE = 0.1       # ... inside SETTLE x c
REDESIGN = 50      # steps between designs on the fitted model

_NOMINAL: dict[tuple, tuple[np.ndarray, np.ndarray, float]] = {}
_LOCK = threading.Lock()


@kernel(nogil=True)
def settles(model, s, K, P, c, actions, best, is_angle, p, steps, S, a, r):
    """Whether the quantised LQR (u = -Kx, the nearest action) run on model number ``model``
    with packed parameters ``p`` for ``steps`` MDP steps from the state ``s`` ends inside
    x'Px <= c (x: the state minus ``best``, angles the short way round; NaN: not inside).
    S (D, 1), a (1,) and r (1,) are work space."""
    dim = s.shape[0]
    for i in range(dim):
        S[i, 0] = s[i]
    x = np.empty(dim)
    for k in range(steps + 1):
        for i in range(dim):
            d = S[i, 0] - best[i]
            if is_angle[i]:
                d = (d + math.pi) % (2.0 * math.pi) - math.pi
            x[i] = d
        if k == steps:
            break
        u = 0.0
        for i in range(dim):
            u -= K[i] * x[i]
        a[0] = nearest_action(u, actions)
        step_lanes(model, S, a, p, 1, r)
    q = 0.0
    for i in range(dim):
        for j in range(dim):
            q += x[i] * P[i, j] * x[j]
    return q <= c


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
        from sapga_ros.evaluation.evaluator import model_id
        self.model = model_id(problem.model)
        self._work = (np.empty((problem.dim, 1)), np.empty(1), np.empty(1))
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
        return difference(self.problem, np.asarray(s, dtype=np.float64), self.best)

    def command(self, s: np.ndarray, p: np.ndarray) -> float | None:
        """The quantised LQR's action for the (predicted) state s where it settles on the
        model with packed parameters ``p`` (module docstring), else None."""
        x = self.offset(s)
        if not float(x @ self.P @ x) <= GATE * self.c:     # NaN: not inside
            return None
        if not settles(self.model, np.asarray(s, dtype=np.float64), self.K, self.P,
                       SETTLE * self.c, self.actions, self.best, self.problem.is_angle, p,
                       HORIZON, *self._work):
            return None
        return float(nearest_action(-float(self.K @ x), self.actions))
