"""The physical-limit search (sapga_ros/analysis/limit.py): exhaustive when the beam holds
every sequence, its answer replays through the model, deterministic in its seed."""
from __future__ import annotations

import itertools

import numpy as np

from sapga_ros.analysis.limit import beam_limit, with_goal_scale
from sim_nodes.goal import delta_of
from sim_nodes.models import model_module
from sim_nodes.problem import load_problem


def brute_force(problem, depth):
    """The smallest delta(s) over every state of every action sequence of ``depth`` steps."""
    step = model_module(problem.model).mdp_step
    best = (delta_of(problem, problem.initial_state), 0)
    for seq in itertools.product(problem.actions, repeat=depth):
        s = problem.initial_state.copy()
        for t, a in enumerate(seq, 1):
            step(s, a, problem.params())
            best = min(best, (delta_of(problem, s), t))
    return best


def test_a_beam_wide_enough_for_every_sequence_is_exhaustive():
    """With width >= 3^depth and one child per cell kept, nothing is pruned: the search
    finds the exact minimum over all sequences."""
    problem = load_problem('pdip')
    depth = 6
    limit = beam_limit(problem, n_step=depth, width=3 ** depth, cells=1000, per_cell=1)
    want, step = brute_force(problem, depth)
    assert limit.delta == want and limit.step == step
    assert len(limit.actions) == limit.step


def test_the_search_is_seeded_and_its_sequence_replays():
    """Same seed, same answer; the action sequence reaches the reported delta (replayed by
    the search itself, and again here)."""
    problem = load_problem('acrobot')
    a = beam_limit(problem, n_step=80, width=500, cells=32, seed=3)
    b = beam_limit(problem, n_step=80, width=500, cells=32, seed=3)
    assert a == b
    s = problem.initial_state.copy()
    for action in a.actions:
        model_module(problem.model).mdp_step(s, action, problem.params())
    assert delta_of(problem, s) == a.delta


def test_a_wider_goal_box_never_makes_the_limit_larger():
    """|v| <= 32 delta contains |v| <= 16 delta: the same sequences reach a delta no larger."""
    problem = load_problem('pdip')
    wide = with_goal_scale(problem, {'v': 32.0})
    assert wide.goal_scale[1] == 32.0
    s = np.array([0.1, 0.5, 1.6, 1.5, 0.2, -0.1])
    assert delta_of(wide, s) <= delta_of(problem, s)
