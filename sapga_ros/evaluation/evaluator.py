"""Policy evaluation (paper section 3, evaluation procedure) on the compiled kernels.

``Evaluator`` packs exemplar policies into padded arrays and runs them in one parallel
batch; ``Evaluator.episode`` runs one policy with its trajectory recorded.  Fitness is the
episode's accumulated reward; the evaluation is deterministic.

With a disturbance profile (``sim_nodes.disturbance``) each episode is disturbed by draws
keyed by its row of ``keys`` (seed, generation, policy, episode); robust fitness (each
policy on K disturbed episodes) is ``sapga_ros.evaluation.robust.RobustEvaluator``.
"""
from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.control import uniform_ahead, uniform_catch
from sapga_ros.evaluation.engine import BLOCKS_PER_THREAD, evaluate_batch, run_share
from sapga_ros.exemplars.distance import (normalize_padded_into, normalize_rows_padded_into,
                                          normalize_states, pad_into, pad_rows_into)
from sapga_ros.policies.batch import PolicyBatch, flat_of
from sapga_ros.policies.episode import Episode
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.styles import STYLES
from sim_nodes.disturbance import Disturbance
from sim_nodes.models import model_id
from sim_nodes.goal import alt_goal_arrays, goal_arrays, hold_measures
from sim_nodes.problem import Problem


@dataclass(frozen=True)
class BatchResult:
    """Results of a batch evaluation, one entry per policy."""

    returns: np.ndarray     # accumulated reward
    steps: np.ndarray       # MDP steps simulated
    delta_star: np.ndarray  # min delta(s) over the states reached
    reached: np.ndarray     # ended in S_delta
    used: Sequence          # per policy: bool (L,), exemplars referred to
    delta_star_alt: np.ndarray | None = None  # delta* under the alternative goal reading
    first_entry: np.ndarray | None = None   # first step in S_delta, 0: never
    held: np.ndarray | None = None          # steps in S_delta from the first entry on
    contacts: np.ndarray | None = None      # steps that touched the end stop

    def hold(self, k: int) -> dict:
        """Policy k's hold measures (``hold_measures``)."""
        return hold_measures(int(self.first_entry[k]), int(self.held[k]), int(self.steps[k]),
                             int(self.contacts[k]))


class RowMarks(Sequence):
    """Per policy, the exemplars its episode referred to: row k of a padded (P, Lmax) mask,
    its first lengths[k] entries, copied when asked for (a generation asks for few)."""

    def __init__(self, marks: np.ndarray, lengths: np.ndarray) -> None:
        self.marks, self.lengths = marks, lengths.tolist()

    def __len__(self) -> int:
        return len(self.lengths)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        return self.marks[k, :self.lengths[k]].copy()


class _Scratch(threading.local):
    """Arrays a thread's ``Evaluator.evaluate`` packs its batches into, kept from one call
    to the next.  A batch of 500 policies of 100 exemplars packs some 3 MB; fresh arrays
    of that size come from the system as new pages each call, and packing into them took
    about a thirteenth of the whole evaluation (the acrobot, one thread), half of it those
    pages' first touch.  Only ``evaluate``
    packs into them (nothing it returns refers to them); every array is overwritten or
    zeroed before use, so a batch packs to the same values as into fresh arrays."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def zeros(self, name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
        """A zeroed array of ``shape`` (a view of this thread's buffer ``name``)."""
        out = self.empty(name, shape, dtype)
        out[...] = 0
        return out

    def empty(self, name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
        """An array of ``shape`` with any contents (a view of buffer ``name``)."""
        size = int(np.prod(shape))
        held = self.arrays.get(name)
        if held is None or held.size < size or held.dtype != dtype:
            held = self.arrays[name] = np.empty(size, dtype=dtype)
        return held[:size].reshape(shape)


def set_jobs(jobs: int | None) -> int:
    """Use ``jobs`` threads for batch evaluation (None or 0: every core); return the count."""
    n = numba.config.NUMBA_NUM_THREADS
    jobs = n if not jobs or jobs <= 0 else min(jobs, n)
    numba.set_num_threads(jobs)
    return jobs


class Evaluator:
    """Evaluates exemplar policies (of any style) of one problem with goal difficulty
    ``delta``."""

    def __init__(self, problem: Problem, delta: float | None = None,
                 n_step: int | None = None, disturbance: Disturbance | None = None) -> None:
        self.problem = problem
        self.delta = problem.resolve('delta', delta)
        self.n_step = problem.resolve('n_step', n_step)
        self.model = model_id(problem.model)
        self.params = problem.params()
        self.ranges = problem.ranges
        self.inv_range = 1.0 / self.ranges
        self.is_angle = problem.is_angle
        self.goal = goal_arrays(problem)
        self.alt_goal = alt_goal_arrays(problem)
        self.s0 = problem.initial_state
        self.actions = problem.action_values
        self.radius2 = problem.via_point_radius ** 2
        self.goal_u = normalize_states(problem.best_state[None, :], self.ranges,
                                       self.is_angle)[:, 0].copy()
        self.catch: np.ndarray | None = None   # controller row of policies without one
        self.hold = (problem.ends_in_goal, problem.hold_bonus, problem.contact_below,
                     problem.fail_charge)     # NaN: an end-stop contact does not end it
        self.disturbance = disturbance or Disturbance()
        self.dist = self.disturbance.pack(problem)
        self._scratch = _Scratch()

    def _consts(self):
        return (self.s0, self.params, self.inv_range, self.is_angle, *self.goal, self.delta,
                self.n_step, self.actions, self.radius2, self.goal_u, *self.alt_goal,
                *self.hold)

    def controls(self, policies) -> np.ndarray:
        """(P, C) controller rows (``sapga_ros.evaluation.control``), zero-padded: a policy's
        own, else the evaluator's ``catch`` (None: no controller)."""
        rows = [self.catch] * len(policies) if isinstance(policies, PolicyBatch) else \
            [getattr(p, 'control', self.catch) for p in policies]   # a batch: none its own
        width = max([1] + [len(r) for r in rows if r is not None])
        ctl = np.zeros((len(policies), width))
        for k, r in enumerate(rows):
            if r is not None:
                ctl[k, :len(r)] = r
        return ctl

    def pack(self, policies: list[ExemplarPolicy], scratch: _Scratch | None = None):
        """(style number, ex, ex2, act, val, lengths): padded (P, D, Lmax) normalised
        states, (P, D, Lmax or 1) second states, (P, Lmax) action values and values, (P,)
        lengths.  A ``PolicyBatch`` is packed from its flat groups.  With ``scratch`` the
        arrays are views of its buffers (valid until the thread's next pack into it)."""
        if isinstance(policies, PolicyBatch):
            groups = policies.groups()
        else:
            styles = {p.style for p in policies}
            if len(styles) > 1:
                raise SapgaError(f'one batch holds one exemplar style, got {sorted(styles)}')
            groups = [flat_of(policies, None if scratch is None else scratch.empty)] \
                if policies else []
        style = STYLES[groups[0].style if groups else 'state-action']
        count, dim = sum(len(g) for g in groups), self.problem.dim
        lengths = np.concatenate([g.lengths for g in groups]) if groups else \
            np.zeros(0, dtype=np.int64)
        lmax = int(lengths.max()) if count else 1

        def zeros(shape: tuple, name: str) -> np.ndarray:
            return np.zeros(shape) if scratch is None else scratch.zeros(name, shape)

        ex = zeros((count, dim, lmax), 'ex')
        ex2 = zeros((count, dim, lmax if style.uses('state2') else 1), 'ex2')
        act = zeros((count, lmax), 'act')
        val = zeros((count, lmax), 'val')
        # Each group's exemplars, normalised into their padded slots in one compiled call:
        # the same ``normalize_into`` per row as each policy alone.
        inv = 1.0 / self.ranges
        start = 0
        for g in groups:
            at = slice(start, start + len(g))
            values = g.values.astype(np.float64, copy=False)
            if g.rows is None:
                normalize_padded_into(g.states, g.lengths, inv, self.is_angle, ex[at])
                if style.uses('state2'):
                    normalize_padded_into(g.states2, g.lengths, inv, self.is_angle, ex2[at])
                pad_into(self.actions[g.actions], g.lengths, act[at])
                pad_into(values, g.lengths, val[at])
            else:                       # records picked by rows: the same per row
                normalize_rows_padded_into(g.states, g.rows, g.lengths, inv, self.is_angle,
                                           ex[at])
                if style.uses('state2'):
                    normalize_rows_padded_into(g.states2, g.rows, g.lengths, inv,
                                               self.is_angle, ex2[at])
                pad_rows_into(self.actions[g.actions], g.rows, g.lengths, act[at])
                pad_rows_into(values, g.rows, g.lengths, val[at])
            start += len(g)
        return style.number, ex, ex2, act, val, lengths

    def evaluate(self, policies: list[ExemplarPolicy],
                 keys: np.ndarray | None = None) -> BatchResult:
        """Evaluate every policy once (in parallel on the configured threads), disturbed by
        the draws of ``keys`` (P, 4) (None: all zero)."""
        count = len(policies)
        style, ex, ex2, act, val, lengths = self.pack(policies, self._scratch)
        returns = np.empty(count)
        steps = np.empty(count, dtype=np.int64)
        dstar = np.empty(count)
        dstar_alt = np.full(count, np.nan)
        reached = np.zeros(count, dtype=np.bool_)
        used = np.zeros(act.shape, dtype=np.bool_)
        first, held, contacts = (np.zeros(count, dtype=np.int64) for _ in range(3))
        draws = _held_keys(policies, keys, count)
        if count:
            shares = max(1, min(count, numba.get_num_threads() * BLOCKS_PER_THREAD))
            ctl = self.controls(policies)
            evaluate_batch(self.model, style, ex, ex2, act, val, lengths, *self._consts(),
                           ctl, uniform_ahead(ctl, style), uniform_catch(ctl, style), self.dist,
                           draws, shares, returns, steps, dstar, dstar_alt, reached, used,
                           first, held, contacts)
        rows = getattr(policies, 'rows', None)
        if rows is not None:            # a batch held in another order: back to its own
            returns, steps, dstar, dstar_alt, reached, used, lengths, first, held, \
                contacts = (a[rows] for a in (returns, steps, dstar, dstar_alt, reached, used,
                                              lengths, first, held, contacts))
        return BatchResult(returns, steps, dstar, reached, RowMarks(used, lengths) if count
                           else [],
                           dstar_alt if len(self.alt_goal[0]) else None, first, held, contacts)

    def episode(self, policy: ExemplarPolicy, key: tuple = (0, 0, 0, 0)) -> Episode:
        """Run ``policy`` once from the initial state and record the trajectory (disturbed by
        the draws of ``key``: seed, generation, policy, episode)."""
        style, ex, ex2, act, val, lengths = self.pack([policy])
        returns, dstar, dstar_alt = np.zeros(1), np.zeros(1), np.zeros(1)
        steps = np.zeros(1, dtype=np.int64)
        reached = np.zeros(1, dtype=np.bool_)
        used = np.zeros(act.shape, dtype=np.bool_)
        first, held, contacts = (np.zeros(1, dtype=np.int64) for _ in range(3))
        tr_state = np.zeros((self.n_step + 1, self.problem.dim))
        tr_idx = np.zeros(self.n_step, dtype=np.int64)
        tr_act = np.zeros(self.n_step)
        tr_reward = np.zeros(self.n_step)
        ctl = self.controls([policy])
        run_share(self.model, style, ex, ex2, act, val, lengths, 0, 1, *self._consts(),
                  ctl, uniform_ahead(ctl, style), uniform_catch(ctl, style), self.dist,
                  _keys([key], 1), returns, steps, dstar, dstar_alt, reached, used, first, held,
                  contacts, tr_state, tr_idx, tr_act, tr_reward)
        n = int(steps[0])
        return Episode(tr_state[:n + 1].copy(), tr_act[:n].copy(), tr_idx[:n].copy(),
                       tr_reward[:n].copy(), float(returns[0]), n, float(dstar[0]),
                       bool(reached[0]), used[0, :len(policy)].copy(), int(first[0]),
                       int(held[0]), int(contacts[0]))


def run_policy_episode(policy: Any, delta: float, max_steps: int | None = None) -> Episode:
    """One recorded episode of a policy of any kind: an exemplar policy runs on the episode
    engine, every other kind runs its own ``episode`` (``sapga_ros.policies.kinds``)."""
    if isinstance(policy, ExemplarPolicy):
        return Evaluator(policy.problem, delta, max_steps).episode(policy)
    return policy.episode(delta, max_steps)


def _held_keys(policies, keys, count: int) -> np.ndarray:
    """``_keys``, each row at its policy's place in the batch's held order."""
    out = _keys(keys, count)
    rows = getattr(policies, 'rows', None)
    if rows is None or keys is None:
        return out
    held = np.empty_like(out)
    held[rows] = out
    return held


def _keys(keys, count: int) -> np.ndarray:
    """(count, 4) int64 draw keys (None: zeros)."""
    if keys is None:
        return np.zeros((count, 4), dtype=np.int64)
    out = np.ascontiguousarray(keys, dtype=np.int64)
    if out.shape != (count, 4) or (out < 0).any():
        raise SapgaError(f'draw keys: expected ({count}, 4) integers >= 0')
    return out
