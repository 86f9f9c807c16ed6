"""Exemplar policies held side by side as flat arrays, and a batch made of such groups.

A SAP-GA generation makes some 500 children; making each one an ``ExemplarPolicy`` object
and concatenating their arrays again to evaluate them cost more than a tenth of a run's time
around the batch kernel.  ``FlatPolicies`` keeps a group's exemplar records concatenated
(policy k is rows ``bounds[k]:bounds[k + 1]``), or the rows each policy takes of arrays
held once (a child's of its parents' records), and makes a policy object only when one is
asked for.  ``PolicyBatch`` is a sequence of policies (held as some policy objects and a
flat group, in any order) that the evaluator packs group by group, without a policy object
per member.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.styles import STYLES
from sim_nodes.problem import Problem


@dataclass
class FlatPolicies:
    """Policies of one problem and style, their records concatenated in policy order, or,
    with ``rows``, the records rows[...] of the arrays (a generation's children are rows of
    their parents' records: nothing is copied until a child is asked for)."""

    problem: Problem
    style: str
    states: np.ndarray          # (N, D) float64, angles wrapped
    actions: np.ndarray         # (N,) action indices
    values: np.ndarray          # (N,) float64
    states2: np.ndarray         # (N, D) (state-state) or (N, 0)
    lengths: np.ndarray         # (count,) int64 exemplars of each policy
    rows: np.ndarray | None = None   # (sum of lengths,) int64: the records, in order

    def __post_init__(self) -> None:
        self._bounds = [0] + np.cumsum(self.lengths).tolist()

    def __len__(self) -> int:
        return len(self.lengths)

    def policy(self, k: int) -> ExemplarPolicy:
        """Policy k: its arrays views into the group's, or copies of its rows."""
        a, b = self._bounds[k], self._bounds[k + 1]
        if self.rows is None:
            return ExemplarPolicy.of_valid(self.problem, self.states[a:b], self.actions[a:b],
                                           self.style, self.values[a:b], self.states2[a:b])
        rows = self.rows[a:b]
        return ExemplarPolicy.of_valid(
            self.problem, self.states.take(rows, axis=0), self.actions.take(rows), self.style,
            self.values.take(rows), self.states2.take(rows, axis=0) if self.states2.shape[1]
            else np.zeros((b - a, 0)))


def flat_of(policies: list[ExemplarPolicy], empty: Callable | None = None) -> FlatPolicies:
    """``policies`` (one problem and style, at least one) as a flat group (copies; into
    ``empty(name, shape, dtype)``'s arrays if given, the evaluator's kept buffers)."""
    first = policies[0]
    lengths = np.fromiter((len(p.states) for p in policies), dtype=np.int64,
                          count=len(policies))
    n = int(lengths.sum())

    def joined(name: str, parts: list[np.ndarray]) -> np.ndarray:
        shape = (n, *parts[0].shape[1:])
        return np.concatenate(parts, out=None if empty is None else
                              empty(name, shape, parts[0].dtype))
    states2 = joined('states2', [p.states2 for p in policies]) \
        if STYLES[first.style].uses('state2') else np.zeros((n, 0))   # none but there
    return FlatPolicies(first.problem, first.style,
                        joined('states', [p.states for p in policies]),
                        joined('actions', [p.actions for p in policies]),
                        joined('values', [p.values for p in policies]), states2, lengths)


class PolicyBatch(Sequence):
    """A sequence of policies held as ``policies`` (objects) followed by the policies of
    ``group`` (flat): position s of the sequence is held at ``rows[s]`` of that order (None:
    in it).  ``groups()`` gives the evaluator the held order as flat groups; the evaluator
    returns its results in the sequence's order."""

    def __init__(self, policies: list[ExemplarPolicy], group: FlatPolicies,
                 rows: np.ndarray | None = None) -> None:
        self.policies, self.group, self.rows = policies, group, rows
        self.style = group.style
        self._rows = None if rows is None else rows.tolist()

    def __len__(self) -> int:
        return len(self.policies) + len(self.group)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        count = len(self)
        if not -count <= index < count:
            raise IndexError(index)
        index %= count
        if self._rows is not None:
            index = self._rows[index]
        held = len(self.policies)
        return self.policies[index] if index < held else self.group.policy(index - held)

    def groups(self) -> list[FlatPolicies]:
        """The batch in its held order as flat groups."""
        return ([flat_of(self.policies)] if self.policies else []) + [self.group]
