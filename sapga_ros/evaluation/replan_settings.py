"""The settings of the re-planning controller (``sapga_ros.evaluation.replan``), declared
apart from its kernels so that the command line offers them without compiling anything."""
from __future__ import annotations

import os
from dataclasses import dataclass

from sapga_ros.errors import SapgaError
from sim_nodes.params import Param, check, declared, param

JOBS = Param('jobs', 1, 'threads running the re-planned episodes; 0: every core', low=0)


def threads(jobs: int) -> int:
    """The threads ``JOBS`` = ``jobs`` means (0: every core)."""
    return jobs or os.cpu_count() or 1


@dataclass(frozen=True)
class ReplanSettings:
    """How the planner improves its plan (``sapga eval --replan``)."""

    replan_rounds: int = param(26, 'rounds of 16 mutant plans at each re-plan', low=1,
                               high=1_000)
    replan_window: int = param(150, 'a mutant redraws actions among the plan\'s next N steps',
                               low=1, high=10 ** 6)
    replan_every: int = param(1, 're-plan every N MDP steps', low=1, high=10 ** 6)
    replan_seed: int = param(0, 'seed of the planner\'s mutations', low=0)
    replan_fit: float = param(0.0, 'relative prior spread of the masses and lengths the '
                              'planner fits to the transitions it sees; 0: the nominal model',
                              low=0.0, high=1.0)
    replan_filter: float = param(0.0, 'sensor noise sigma the planner\'s Kalman filter '
                                 'assumes: it acts on the filtered state; 0: on the state '
                                 'seen', low=0.0, high=1.0)

    def __post_init__(self) -> None:
        check(self)


def plannable(problem) -> bool:
    """Whether ``problem``'s episode ends in S_delta or it is a hold task with a classical
    LQR to hand over to (``hold_catch``): staying is what a plan's score does not measure."""
    from sapga_ros.evaluation.hold_catch import plannable_hold
    return problem.ends_in_goal or plannable_hold(problem)


def check_plannable(problem, name: str = 'replan') -> None:
    """One line (``SapgaError``, naming the setting ``name``) unless ``plannable``."""
    if not plannable(problem):
        raise SapgaError(f'{name}: {problem.name} is a hold task without a classical LQR to '
                         'hand over to (re-planning needs one, or an episode that ends in '
                         'S_delta)')


def planner_delay(policy, delay: int) -> int:
    """The actuation delay a planner on ``policy`` predicts for: ``delay`` when given (not
    0), else the delay the policy file's selector is designed for."""
    from sapga_ros.policies.classical import selector_delay
    return delay or selector_delay(policy)


def refuse_stray_settings(given, replan: bool) -> None:
    """One line (``SapgaError``) when a setting of ``--replan`` (``given``: the options named
    on the command line) comes without ``--replan``."""
    stray = sorted(set(given) & {JOBS.name, *(p.name for p in declared(ReplanSettings))})
    if stray and not replan:
        raise SapgaError(f'--{stray[0].replace("_", "-")} is a setting of --replan')
