"""Robustness curves: a policy's success rate as each disturbance profile is scaled.

``sweep`` is what ``sapga robustness`` and the experiment report's curves both compute:
every factor of ``scales`` multiplies the profile's sizes (``Disturbance.scaled``: latency
rounded to whole steps) and the policy runs ``episodes`` held-out disturbed episodes at
each size (``episodes_summary``).  A factor of 0 is the undisturbed plant.
"""
from __future__ import annotations

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.robust import Robust, episodes_summary


def sweep(policy, delta: float, profile, scales, episodes: int, seed: int = 0) -> list[dict]:
    """One ``episodes_summary`` per factor of ``scales`` (with ``scale`` and the profile's
    name added), of ``policy`` judged at ``delta``."""
    rows = []
    for scale in scales:
        ev = Evaluator(policy.problem, delta, disturbance=profile.scaled(scale))
        row = episodes_summary(ev, policy, Robust(episodes, seed=seed))
        rows.append({**row, 'disturbance': profile.name, 'scale': float(scale)})
    return rows
