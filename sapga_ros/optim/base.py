"""The optimizer contract that one training loop drives (``sapga_ros.training.loop``).

After pycma's ``interfaces.py`` and evosax's ``base.py``: ``ask()`` hands out candidates,
the caller evaluates them in one batch and gives the measures back to ``tell()`` as plain
arrays; ``stop(budget)`` is a dict of the termination reasons met; ``result`` is the best
so far; ``state_dict()`` / ``from_state()`` are what a checkpoint saves and restores.
Fixed strategy parameters (a frozen dataclass of ``settings`` fields) live apart from the
changing state.

A method that evaluates its own candidates (Q-learning learns from the episodes it runs
inside its compiled kernel) returns no candidates from ``ask()`` and is told nothing.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

State = tuple[dict[str, Any], dict[str, np.ndarray]]   # (JSON meta, arrays) of a checkpoint


@dataclass(frozen=True)
class Result:
    """The best so far: a policy (exemplar policy or Q-table) and the optimizer's account
    of it and of the run (value, delta*, steps, counters, strategy parameters)."""

    policy: Any
    meta: dict[str, Any]


class Optimizer(ABC):
    """ask / tell / stop / result, and the state a checkpoint holds."""

    method: ClassVar[str]                  # 'sapga', 'ql': the run settings' method name

    @abstractmethod
    def ask(self) -> list:
        """The candidates to evaluate next, in one batch (may be empty: see the module)."""

    @abstractmethod
    def tell(self, returns: np.ndarray, delta_star: np.ndarray, steps: np.ndarray,
             reached: np.ndarray, used: list[np.ndarray]) -> None:
        """The measures of ``ask()``'s candidates, in order: accumulated reward, min
        delta(s) over the states reached, MDP steps, ended in S_delta, and per candidate the
        bool marks of the exemplars its episode referred to."""

    @property
    @abstractmethod
    def steps(self) -> int:
        """MDP steps simulated so far."""

    @property
    @abstractmethod
    def iteration(self) -> int:
        """ask/tell rounds so far (SAP-GA generations, Q-learning chunks)."""

    def stop(self, budget: int) -> dict[str, int]:
        """Termination reasons met (empty: go on)."""
        return {'budget': budget} if self.steps >= budget else {}

    @property
    def best(self) -> object | None:
        """A token of the best so far that changes whenever it improves (None: not
        followed, no policy to hand out during the run)."""
        return None

    @property
    @abstractmethod
    def result(self) -> Result | None:
        """The best so far (None before the first evaluation)."""

    @abstractmethod
    def counters(self) -> dict[str, Any]:
        """The run's counters (a progress row's first columns): steps, best_value,
        delta_star and the method's own."""

    @staticmethod
    @abstractmethod
    def settings(problem: Any, params: Any) -> dict[str, Any]:
        """What a resumed run must share with its checkpoint (the strategy parameters)."""

    @abstractmethod
    def state_dict(self) -> State:
        """The changing state, for a checkpoint: (JSON meta, arrays)."""

    @classmethod
    @abstractmethod
    def from_state(cls, problem: Any, params: Any, state: State, **run: Any) -> 'Optimizer':
        """The optimizer ``state_dict()`` described (``run``: what else the method needs to
        go on, e.g. Q-learning's delta and budget); CheckpointError if inconsistent."""
