"""Robustness curves: a policy's success rate as each disturbance profile is scaled.

``sweep`` is what ``sapga robustness`` and the experiment report's curves both compute:
every factor of ``scales`` multiplies the profile's sizes (``Disturbance.scaled``: latency
rounded to whole steps) and the policy runs ``episodes`` held-out disturbed episodes at
each size (``episodes_summary``).  A factor of 0 is the undisturbed plant.

With ``replan`` (``ReplanSettings``) the policy's plan is re-planned as it runs
(``sapga_ros.evaluation.replan``) on the same held-out draws; the planner predicts for
``delay`` MDP steps of actuation delay, or, with ``delay`` 0, for the latency of each
point's plant (what an engineer measures on the robot before deploying).
"""
from __future__ import annotations

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.robust import Robust, episodes_summary


def sweep(policy, delta: float, profile, scales, episodes: int, seed: int = 0, replan=None,
          delay: int = 0, jobs: int = 1) -> list[dict]:
    """One ``episodes_summary`` per factor of ``scales`` (with ``scale`` and the profile's
    name added), of ``policy`` judged at ``delta``; re-planned with the settings
    ``replan`` (``jobs`` threads) when given."""
    rows = []
    for scale in scales:
        plant = profile.scaled(scale)
        if replan is None:
            row = episodes_summary(Evaluator(policy.problem, delta, disturbance=plant),
                                   policy, Robust(episodes, seed=seed))
        else:
            from sapga_ros.evaluation.replan import replanned
            row = replanned(policy, delta, plant, episodes, seed, replan,
                            delay or plant.latency, jobs=jobs)
        rows.append({**row, 'disturbance': profile.name, 'scale': float(scale)})
    return rows
