"""A configured problem as a Gymnasium environment (``ProblemEnv``), for peers of SAP-GA.

The environment is the episode engine's (``sapga_ros.evaluation.engine``) without a policy:
the same compiled kernel (``sim_nodes.models.<model>.mdp_step``), reward, goal test and
episode length, so any Gymnasium agent meets the problem that SAP-GA meets.

==================  =========================================================================
action space        ``Discrete(len(problem.actions))``: index i applies ``problem.actions[i]``
                    (the YAML's order)
observation space   ``Box(problem.low, problem.high)``, float64: the state vector in the
                    YAML's layout and units (angles in [0, 2pi))
start               the problem's fixed initial state (``initial:``); a seed is accepted but
                    the start draws nothing
reward              the kernel's reward of the MDP step (+ ``hold_bonus`` in S_delta on a
                    problem with ``ends_in_goal: false``, the hold task; + the charge
                    ``(n_step - t) * problem.fail_charge`` for the steps not run when an
                    end-stop contact in step t ends the episode), so an episode's rewards
                    sum to the episode engine's return
terminated          ``delta(s) <= delta`` on the new state, after its reward is counted
                    (never on the hold task); an end-stop contact under ``end_stop: fail``
truncated           after ``n_step`` MDP steps without an end
info                ``delta``: delta(s) of the observed state; ``delta_star``: the least
                    delta(s) of the episode so far, the initial state included
==================  =========================================================================

Bounds: every kernel keeps its states inside the YAML's [low, high]: angles are wrapped to
[0, 2pi), velocities clipped at the YAML's bounds (the physics parameters name the same
numbers), the PDIP's cart stops at the rail ends +-x_max = +-2.5 m and the mountain car
between its wall x_min = -1.2 and the goal end x_max = 0.5.  ``tests/test_gym.py`` checks
this on random episodes of every problem; a problem whose states can leave its YAML bounds
needs its reachable bounds here.
"""
from __future__ import annotations

import math
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.error import InvalidAction, ResetNeeded

from sapga_ros.errors import ConfigError
from sim_nodes.goal import goal_arrays, goal_delta
from sim_nodes.models import model_module
from sim_nodes.params import DELTA, N_STEP, reason_of
from sim_nodes.problem import Problem, load_problem


class ProblemEnv(gymnasium.Env[np.ndarray, np.int64]):
    """One configured problem (``msg_configs/<name>.yaml``) with goal difficulty ``delta``
    (None: the problem's default) and episodes of at most ``n_step`` MDP steps (None: the
    problem's N_step)."""

    metadata: dict[str, Any] = {'render_modes': []}

    def __init__(self, problem: str | Problem = 'acrobot', delta: float | None = None,
                 n_step: int | None = None, render_mode: str | None = None) -> None:
        self.problem = load_problem(problem) if isinstance(problem, str) else problem
        p = self.problem
        for q, value in ((DELTA, delta), (N_STEP, n_step)):
            reason = reason_of(q, q.coerce(value))
            if reason:
                raise ConfigError(f'{p.name}: {reason}')
        self.delta = p.resolve('delta', delta)
        self.n_step = p.resolve('n_step', n_step)
        if render_mode is not None:
            raise ConfigError(f'{p.name}: no render modes, got {render_mode!r}')
        self.render_mode = render_mode
        self.action_space = spaces.Discrete(len(p.actions))
        self.observation_space = spaces.Box(p.low, p.high, dtype=np.float64)
        self._mdp_step = model_module(p.model).mdp_step
        self._params = p.params()
        self._goal = (*goal_arrays(p), p.is_angle)
        self._actions = p.action_values
        self._state: np.ndarray | None = None
        self._steps = 0
        self._delta_star = math.inf
        self._over = True

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """The initial state (deterministic) and its delta."""
        super().reset(seed=seed)
        self._state = self.problem.initial_state
        self._steps = 0
        self._delta_star = self._delta()
        self._over = False
        return self._state.copy(), {'delta': self._delta_star, 'delta_star': self._delta_star}

    def step(self, action: int | np.integer) -> tuple[np.ndarray, float, bool, bool,
                                                      dict[str, Any]]:
        """Hold action index ``action`` for one MDP step."""
        if self._state is None or self._over:
            raise ResetNeeded('call reset() before step(): the episode is over')
        if not self.action_space.contains(action):
            raise InvalidAction(f'{self.problem.name}: action {action!r} is not an index '
                                f'0..{self.action_space.n - 1}')
        reward = float(self._mdp_step(self._state, self._actions[int(action)], self._params))
        self._steps += 1
        d = self._delta()
        self._delta_star = min(self._delta_star, d)
        p = self.problem
        terminated = d <= self.delta and p.ends_in_goal  # after the step's reward is counted
        failed = reward < p.contact_below and p.end_stop == 'fail' and not terminated
        if d <= self.delta and not p.ends_in_goal:      # the hold task: bonus, no end
            reward += p.hold_bonus
        if failed:                                      # an end-stop contact ends it,
            reward += (self.n_step - self._steps) * p.fail_charge  # charged the steps left
            terminated = True
        truncated = not terminated and self._steps >= self.n_step
        self._over = terminated or truncated
        return (self._state.copy(), reward, terminated, truncated,
                {'delta': d, 'delta_star': self._delta_star})

    def _delta(self) -> float:
        """delta(s) of the current state."""
        return float(goal_delta(self._state, *self._goal))
