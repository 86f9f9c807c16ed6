"""What running a policy of any kind for one episode yields: the trajectory and its measures
(the shared vocabulary of the policy kinds, the episode engine and the recordings)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_nodes.goal import hold_measures


@dataclass(frozen=True)
class Episode:
    """One recorded episode."""

    states: np.ndarray      # (steps + 1, D), initial state first
    actions: np.ndarray     # (steps,) action values
    exemplars: np.ndarray   # (steps,) index of the exemplar the selector reported (-1: none)
    rewards: np.ndarray     # (steps,)
    ret: float
    steps: int
    delta_star: float
    reached: bool
    used: np.ndarray | None = None  # (L,) exemplars referred to (exemplar policies)
    first_entry: int = 0            # first step in S_delta, 0: never
    held: int = 0                   # steps in S_delta from the first entry on
    contacts: int = 0               # steps that touched the end stop

    def summary(self) -> dict:
        return {'return': self.ret, 'delta_star': self.delta_star, 'steps': self.steps,
                'reached': self.reached,
                **hold_measures(self.first_entry, self.held, self.steps, self.contacts)}
