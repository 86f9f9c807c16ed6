"""The members of a SAP-GA population and their checkpoint form.

``pack`` lays a list of individuals out as flat arrays (exemplar records concatenated, one
length per policy); ``unpack`` reads them back, refusing counts that do not add up,
non-finite states and action indices out of range (a checkpoint is read without pickle and
trusted no further than that: shapes, types and counts are checked before use).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sapga_ros.errors import CheckpointError, SapgaError
from sapga_ros.policies.batch import FlatPolicies
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.problem import Problem


@dataclass
class Individual:
    """A policy and what its last evaluation found (value nan: not evaluated yet)."""

    policy: ExemplarPolicy
    value: float = math.nan                # f(pi): accumulated reward of its episode
    delta_star: float = math.inf
    steps: int = 0                         # MDP steps of its episode
    reached: bool = False
    used: np.ndarray | None = None         # exemplars referred to in that episode
    scale: float = 1.0                     # catch region c = the design's c x this (evolved)

    @property
    def known(self) -> bool:
        return not math.isnan(self.value)


class Generation:
    """A SAP-GA generation between ``ask`` and ``tell``: each family's parents (individuals),
    every child as one flat group (family-major) with its catch scale, and the parents
    without a known value (``waiting``).  The members to evaluate, in family order (each
    family's waiting parents, then its children), are held as the waiting parents followed
    by the children: member s at ``rows[s]``.  A child becomes an ``Individual`` only when
    one is asked for (a family's best, the run's best), the same object each time; one asked
    for before the results gets them when they come."""

    def __init__(self, couples: list[tuple[int, int]], parents: list[tuple[Individual,
                 Individual]], kids: FlatPolicies, scales: list[float], n_child: int) -> None:
        self.couples, self.parents, self.kids = couples, parents, kids
        self.scales, self.n_child = scales, n_child
        waiting = [(f, m) for f, pair in enumerate(parents) for m in pair if not m.known]
        self.waiting = [m for _, m in waiting]
        family = np.concatenate([np.array([f for f, _ in waiting], dtype=np.int64),
                                 np.repeat(np.arange(len(parents)), n_child)])
        self.rows = np.argsort(family, kind='stable')    # held in family order
        self.place = np.empty_like(self.rows)        # held position -> member position
        self.place[self.rows] = np.arange(len(self.rows))
        self.made: dict[int, Individual] = {}
        self.results: tuple | None = None

    def __len__(self) -> int:
        return len(self.rows)

    def child(self, k: int) -> Individual:
        """Child k (family-major), the same object each time."""
        m = self.made.get(k)
        if m is None:
            m = self.made[k] = Individual(self.kids.policy(k), scale=self.scales[k])
            if self.results is not None:
                self._fill(m, int(self.place[len(self.waiting) + k]))
        return m

    def member(self, s: int) -> Individual:
        """Member s in family order."""
        r, held = int(self.rows[s]), len(self.waiting)
        return self.waiting[r] if r < held else self.child(r - held)

    def take(self, values: np.ndarray, dstar: np.ndarray, steps: np.ndarray,
             reached: np.ndarray, used) -> None:
        """The members' results (in family order) to the waiting parents and every child
        made."""
        self.results = (values, dstar, steps, reached, used)
        place = self.place.tolist()
        for p, m in enumerate(self.waiting):
            self._fill(m, place[p])
        for k, m in self.made.items():
            self._fill(m, place[len(self.waiting) + k])

    def child_values(self, values: np.ndarray) -> np.ndarray:
        """(families, n_child): ``values`` (family order) of each family's children."""
        return values[self.place[len(self.waiting):]].reshape(-1, self.n_child)

    def _fill(self, m: Individual, s: int) -> None:
        values, dstar, steps, reached, used = self.results
        m.value, m.delta_star = float(values[s]), float(dstar[s])
        m.steps, m.reached, m.used = int(steps[s]), bool(reached[s]), used[s]


SCALE_RANGE = (1 / 64, 16.0)               # an evolved catch scale stays inside this
PER_POLICY = ('values', 'delta_star', 'steps', 'reached', 'has_used')   # one entry a policy


def pack(individuals: list[Individual], prefix: str) -> dict[str, np.ndarray]:
    """The arrays ``prefix``_* of a checkpoint holding ``individuals``."""
    dim = individuals[0].policy.problem.dim if individuals else 0
    used = [m.used if m.used is not None else np.zeros(len(m.policy), np.bool_)
            for m in individuals]
    return {
        f'{prefix}_states': np.concatenate([m.policy.states for m in individuals]).reshape(
            -1, dim),
        f'{prefix}_actions': np.concatenate([m.policy.actions for m in individuals]),
        f'{prefix}_exemplar_values': np.concatenate([m.policy.values for m in individuals]),
        f'{prefix}_states2': np.concatenate([m.policy.states2 for m in individuals]),
        f'{prefix}_lengths': np.array([len(m.policy) for m in individuals], dtype=np.int64),
        f'{prefix}_values': np.array([m.value for m in individuals]),
        f'{prefix}_delta_star': np.array([m.delta_star for m in individuals]),
        f'{prefix}_steps': np.array([m.steps for m in individuals], dtype=np.int64),
        f'{prefix}_reached': np.array([m.reached for m in individuals], dtype=np.bool_),
        f'{prefix}_has_used': np.array([m.used is not None for m in individuals]),
        f'{prefix}_used': np.concatenate(used),
        f'{prefix}_catch_scale': np.array([m.scale for m in individuals]),
    }


def unpack(problem: Problem, arrays: dict[str, np.ndarray], prefix: str,
           style: str = 'state-action') -> list[Individual]:
    """The individuals ``pack`` wrote; CheckpointError if the arrays are inconsistent."""
    try:
        values = arrays.get(f'{prefix}_exemplar_values')
        states2 = arrays.get(f'{prefix}_states2')
        lengths = arrays[f'{prefix}_lengths']
        states, actions = arrays[f'{prefix}_states'], arrays[f'{prefix}_actions']
        used = arrays[f'{prefix}_used']
        per_policy = [arrays[f'{prefix}_{k}'] for k in PER_POLICY]
        scales = arrays.get(f'{prefix}_catch_scale')     # absent in older checkpoints: 1
        if scales is None:
            scales = np.ones(len(lengths))
        per_policy.append(scales)
        if lengths.dtype.kind not in 'iu' or lengths.ndim != 1 or np.any(lengths < 1) or \
                lengths.sum() != len(actions) or len(states) != len(actions) or \
                len(used) != len(actions) or \
                any(a.ndim != 1 or len(a) != len(lengths) for a in per_policy):
            raise ValueError('exemplar counts do not add up')
        if states.ndim != 2 or states.shape[1] != problem.dim or actions.ndim != 1 or \
                actions.dtype.kind not in 'iu' or used.ndim != 1 or used.dtype != np.bool_:
            raise ValueError('exemplar arrays of the wrong shape or type')
        if scales.dtype.kind != 'f' or not np.all((scales >= SCALE_RANGE[0]) &
                                                  (scales <= SCALE_RANGE[1])):
            raise ValueError(f'catch scales outside [{SCALE_RANGE[0]}, {SCALE_RANGE[1]}]')
        if not np.all(np.isfinite(states)) or np.any(actions < 0) or \
                np.any(actions >= len(problem.actions)):
            raise ValueError('non-finite states or action indices out of range')
        bounds = np.concatenate([[0], np.cumsum(lengths)])
        out = []
        for k in range(len(lengths)):
            a, b = bounds[k], bounds[k + 1]
            policy = ExemplarPolicy(
                problem, states[a:b], actions[a:b], style=style,
                values=None if values is None else values[a:b],
                states2=None if states2 is None or not states2.shape[1] else states2[a:b])
            marks = used[a:b].copy() if arrays[f'{prefix}_has_used'][k] else None
            out.append(Individual(policy, float(arrays[f'{prefix}_values'][k]),
                                  float(arrays[f'{prefix}_delta_star'][k]),
                                  int(arrays[f'{prefix}_steps'][k]),
                                  bool(arrays[f'{prefix}_reached'][k]), marks,
                                  float(scales[k])))
        return out
    except (KeyError, IndexError, TypeError, ValueError, SapgaError) as exc:
        raise CheckpointError(f'checkpoint population {prefix!r} is inconsistent ({exc})') \
            from exc
