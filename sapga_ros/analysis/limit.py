"""The physical limit of a problem: the smallest delta any action sequence reaches within
N_step MDP steps from the initial state, searched open loop.

A *cell beam search* over action sequences: at each depth every state of the beam is
expanded with every action (one batch of ``step_lanes``, the engine's own model step), the
children are binned into cells of a grid over the normalised state space, each cell keeps
its child of smallest delta(s), each cell keeps its ``per_cell`` children of smallest delta,
and the beam keeps ``width`` of those: half of smallest delta, half drawn at random from the
rest (diversity: a swing-up must first move
away from the goal to gain energy).  The smallest delta(s) of any state visited, the step it
was visited and its action sequence are returned; the sequence is replayed through the model
state by state to confirm it.  The result is an upper bound on the limit (what the search
found), not a proof that nothing smaller exists.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sim_nodes.goal import goal_arrays, goal_delta
from sim_nodes.jit import kernel
from sim_nodes.models import model_id, model_module
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import Problem


@kernel
def lane_deltas(S, n, best, inv_scale, fixed, is_angle, out):
    """out[k] = delta(S[:, k]) for the first n lanes."""
    for k in range(n):
        out[k] = goal_delta(S[:, k], best, inv_scale, fixed, is_angle)


@dataclass(frozen=True)
class Limit:
    """What the search found."""

    problem: str
    goal_scale: tuple                  # the goal box used (scale per coordinate)
    delta: float                       # smallest delta(s) reached
    step: int                          # the MDP step that reached it
    actions: list                      # the action values that lead there, in order
    width: int                         # beam width
    cells: int                         # grid cells per coordinate
    steps_simulated: int               # MDP steps the search simulated

    def reaches(self, delta: float) -> bool:
        return self.delta <= delta


def with_goal_scale(problem: Problem, scale: dict[str, float]) -> Problem:
    """``problem`` with the goal scale of some coordinates replaced (e.g. {'v': 32.0})."""
    names = problem.state_names
    unknown = set(scale) - set(names)
    if unknown:
        raise ValueError(f'no coordinate {sorted(unknown)} in {problem.name}')
    new = tuple(scale.get(n, s) for n, s in zip(names, problem.goal_scale))
    return dataclasses.replace(problem, goal_scale=new)


def _cells(S: np.ndarray, problem: Problem, cells: int) -> np.ndarray:
    """The grid cell of each state (column of S), as one integer."""
    low, high = problem.low[:, None], problem.high[:, None]
    u = (S - low) / (high - low)
    idx = np.clip((u * cells).astype(np.int64), 0, cells - 1)
    key = np.zeros(S.shape[1], dtype=np.int64)
    for d in range(S.shape[0]):
        key = key * cells + idx[d]
    return key


def beam_limit(problem: Problem, n_step: int | None = None, width: int = 20_000,
               cells: int = 64, per_cell: int = 2, seed: int = 0) -> Limit:
    """Search the smallest delta reachable within ``n_step`` steps (see the module doc)."""
    n_step = problem.resolve('n_step', n_step)
    rng = np.random.default_rng(seed)
    model, params = model_id(problem.model), problem.params()
    best, inv_scale, fixed = goal_arrays(problem)
    is_angle = problem.is_angle
    actions = problem.action_values
    n_act = len(actions)
    beam = problem.initial_state[:, None].copy()
    found = float(goal_delta(problem.initial_state, best, inv_scale, fixed, is_angle))
    found_step, found_path = 0, []
    parents, moves = [], []                 # per depth: parent index and action of each
    simulated = 0
    for depth in range(1, n_step + 1):
        k = beam.shape[1]
        S = np.repeat(beam, n_act, axis=1)
        act = np.tile(actions, k)
        reward = np.empty(S.shape[1])
        step_lanes(model, S, act, params, S.shape[1], reward)
        simulated += S.shape[1]
        deltas = np.empty(S.shape[1])
        lane_deltas(S, S.shape[1], best, inv_scale, fixed, is_angle, deltas)
        j = int(np.argmin(deltas))
        if deltas[j] < found:
            found, found_step = float(deltas[j]), depth
            found_path = _path(parents, moves, j // n_act) + [j % n_act]
        keep = _select(_cells(S, problem, cells), deltas, width, per_cell, rng)
        parents.append((keep // n_act).astype(np.int32))
        moves.append((keep % n_act).astype(np.int8))
        beam = S[:, keep]
    limit = Limit(problem.name, tuple(problem.goal_scale), found, found_step,
                  [float(actions[a]) for a in found_path], width, cells, simulated)
    _confirm(problem, limit)
    return limit


def _select(keys: np.ndarray, deltas: np.ndarray, width: int, per_cell: int,
            rng) -> np.ndarray:
    """Indices of the children kept: the ``per_cell`` best of each cell, then ``width`` of
    those (half of smallest delta, half at random)."""
    d = np.where(np.isfinite(deltas), deltas, 1e300)
    order = np.lexsort((d, keys))
    sorted_keys = keys[order]
    start = np.ones(len(order), dtype=bool)
    start[1:] = sorted_keys[1:] != sorted_keys[:-1]
    group_start = np.maximum.accumulate(np.where(start, np.arange(len(order)), 0))
    heads = order[np.arange(len(order)) - group_start < per_cell]
    if len(heads) <= width:
        return np.sort(heads)
    by_delta = heads[np.argsort(d[heads], kind='stable')]
    half = width // 2
    rest = by_delta[half:]
    chosen = np.concatenate([by_delta[:half],
                             rest[rng.choice(len(rest), width - half, replace=False)]])
    return np.sort(chosen)


def _path(parents: list, moves: list, index: int) -> list[int]:
    """The action indices leading to beam member ``index`` of the last depth kept."""
    path = []
    for depth in range(len(parents) - 1, -1, -1):
        path.append(int(moves[depth][index]))
        index = int(parents[depth][index])
    return path[::-1]


def _confirm(problem: Problem, limit: Limit) -> None:
    """Replay the action sequence one state at a time; it must reach the same delta."""
    step = model_module(problem.model).mdp_step
    best, inv_scale, fixed = goal_arrays(problem)
    s = problem.initial_state.copy()
    d = goal_delta(s, best, inv_scale, fixed, problem.is_angle)
    for a in limit.actions:
        step(s, a, problem.params())
        d = goal_delta(s, best, inv_scale, fixed, problem.is_angle)
    same = d == limit.delta or (math.isinf(d) and math.isinf(limit.delta))
    if len(limit.actions) != limit.step or not same:
        raise AssertionError(f'replay of the found sequence gives delta {d}, '
                             f'not {limit.delta}')
