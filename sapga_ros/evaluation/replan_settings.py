"""The settings of the re-planning controller (``sapga_ros.evaluation.replan``), declared
apart from its kernels so that the command line offers them without compiling anything."""
from __future__ import annotations

from dataclasses import dataclass

from sim_nodes.params import Param, check, param

JOBS = Param('jobs', 1, 'threads running the re-planned episodes; 0: every core', low=0)


@dataclass(frozen=True)
class ReplanSettings:
    """How the planner improves its plan (``sapga eval --replan``)."""

    replan_rounds: int = param(26, 'rounds of 16 mutant plans at each re-plan', low=1,
                               high=1_000)
    replan_window: int = param(150, 'a mutant redraws actions among the plan\'s next N steps',
                               low=1, high=10 ** 6)
    replan_every: int = param(1, 're-plan every N MDP steps', low=1, high=10 ** 6)
    replan_seed: int = param(0, 'seed of the planner\'s mutations', low=0)

    def __post_init__(self) -> None:
        check(self)
