"""Replaying a physical-limit action sequence (``sapga limit --replay FILE``).

A sequence found by the search under one goal reading is scored here under every reading
the problem has (the goal box as printed, and the alternative one where there is one): the
smallest delta(s) over the states the sequence visits (the initial state included), the
first step that reaches it, and the end-stop (rail) contacts on the way there, with their
steps.  A rail contact stops the cart at the rail at the price of a penalty in the reward:
a sequence that uses it brakes for free, which a report of the limit must say.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim_nodes.goal import alternative_goal, delta_of
from sim_nodes.models import model_module
from sim_nodes.problem import Problem


@dataclass(frozen=True)
class Replayed:
    """The score of an action sequence under one goal reading."""

    reading: str                 # 'printed' or 'alternative'
    delta: float                 # smallest delta(s) over the visited states
    step: int                    # the first step that reaches it (0: the initial state)
    contact_steps: tuple         # steps (1-based) that touched the rail, up to ``step``

    @property
    def rail_contacts(self) -> int:
        return len(self.contact_steps)


def readings(problem: Problem) -> list[tuple[str, Problem]]:
    """The goal readings of ``problem``: as printed, and the alternative one if it has one."""
    alt = alternative_goal(problem)
    return [('printed', problem)] + ([] if alt is None else [('alternative', alt)])


def replay(problem: Problem, actions: list[float]) -> list[Replayed]:
    """Score ``actions`` (action values, in order) from the initial state under every goal
    reading of ``problem`` (one simulation, the model's own MDP step)."""
    step = model_module(problem.model).mdp_step
    params = problem.params()
    s = problem.initial_state.copy()
    states, contacts = [s.copy()], []
    for t, a in enumerate(actions, 1):
        if step(s, float(a), params) < problem.contact_below:
            contacts.append(t)
        states.append(s.copy())
    out = []
    for name, goal in readings(problem):
        deltas = np.array([delta_of(goal, x) for x in states])
        best = int(np.argmin(deltas))
        out.append(Replayed(name, float(deltas[best]), best,
                            tuple(c for c in contacts if c <= best)))
    return out


def best_over(problem: Problem, sequences: dict[str, list[float]]) -> dict[str, tuple]:
    """Per goal reading, (replayed, source) of the smallest delta over every sequence of
    ``sequences`` (source name -> action values): the limit as the best over all searches."""
    best: dict[str, tuple] = {}
    for source, actions in sequences.items():
        for r in replay(problem, actions):
            if r.reading not in best or r.delta < best[r.reading][0].delta:
                best[r.reading] = (r, source)
    return best
