"""One policy answering one state at a time: the ROS policy node and the policy maps.

``StateSelector`` packs a policy exactly as ``Evaluator`` packs a batch and calls the same
compiled ``choose`` (the selector behind the policy's controller, if any), so each action
equals the one the offline episode takes.  Only the via-point style (the via-points passed so
far) and a controller designed for an actuation delay (its commands in flight) carry state
from one step to the next; ``reset()`` starts a new episode.
"""
from __future__ import annotations

import numpy as np

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.control import choose, memory_width
from sapga_ros.exemplars.selectors import scratch
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.styles import STYLES


class StateSelector:
    """A policy prepared for single states (not thread-safe: one caller at a time)."""

    def __init__(self, policy: ExemplarPolicy) -> None:
        ev = Evaluator(policy.problem)
        self.policy = policy
        self.style = STYLES[policy.style]
        number, ex, ex2, act, val, lengths = ev.pack([policy])
        self._args = (number, ev.model)
        self._policy_args = (ex[0], ex2[0], act[0], val[0], int(lengths[0]), ev.actions,
                             ev.params, ev.inv_range, ev.is_angle, ev.radius2, ev.goal_u)
        ctl = ev.controls([policy])
        self._scratch = (*scratch(policy.problem.dim, len(policy)), ctl[0],
                         policy.problem.best_state, np.empty(2 * policy.problem.dim))
        self.memory = np.zeros(memory_width(ctl))           # a controller's commands in flight
        self.delayed = getattr(policy, 'delay', 0) > 0
        self.used = np.zeros(len(policy), dtype=np.bool_)   # referred to since creation
        self.progress = 0                                   # via-points passed

    def __len__(self) -> int:
        return len(self.policy)

    @property
    def stateful(self) -> bool:
        """Whether an action depends on the states before (via-point, or a controller that
        remembers its commands in flight)."""
        return self.style.name == 'via-point' or self.delayed

    def reset(self) -> None:
        """A new episode starts: no via-point passed yet, no command in flight."""
        self.progress = 0
        self.memory[:] = 0.0

    def select(self, state: np.ndarray) -> tuple[int, float]:
        """(exemplar index reported, -1 for none; action value) for a raw state."""
        s = np.ascontiguousarray(state, dtype=np.float64)
        j, action, self.progress = choose(*self._args, s, *self._policy_args, self.progress,
                                          self.used, *self._scratch, self.memory)
        return int(j), float(action)
