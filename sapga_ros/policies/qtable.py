"""The Q-table policy of the Q-learning baseline and its file format
``sapga-qtable/1``.

The table covers a square tiling: ``tiles_per_dim`` cells per coordinate over the problem's
bounds, on the coordinates ``q_learning.state_indices`` of the problem's YAML; the policy
acts greedily (ties to the lowest action index) on the tile of the state.  On disk: a JSON
document of the visited cells only, which ``sapga eval`` runs exactly.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sapga_ros.errors import PolicyFileError
from sapga_ros.io.atomic import write_atomic
from sapga_ros.policies.episode import Episode
from sapga_ros.policies.jsonfile import excerpt, finite, json_safe, meta_of
from sapga_ros.policies.jsonstream import Bulk, complete, require
from sim_nodes.goal import goal_arrays, goal_delta
from sim_nodes.jit import kernel
from sim_nodes.models import model_id
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import Problem, load_problem

FORMAT = 'sapga-qtable/1'
BULK = frozenset({'q'})                    # read one row at a time
HEADER = ('problem', 'state_names', 'actions', 'state_indices', 'tiles_per_dim', 'q')


@kernel(inline='always')
def cell_index(s, idx, low, width, tiles):
    """Index of the tile holding s (coordinates idx); clipped to the edge tiles."""
    cell = 0
    mult = 1
    top = float(tiles - 1)
    for i in range(idx.shape[0]):
        c = np.floor((s[idx[i]] - low[i]) / width[i])
        c = 0.0 if c < 0.0 else (top if c > top else c)
        cell += int(c) * mult
        mult *= tiles
    return cell


@kernel(inline='always')
def greedy(q, cell):
    best = 0
    for a in range(1, q.shape[1]):
        if q[cell, a] > q[cell, best]:
            best = a
    return best


@kernel
def greedy_episode(model, q, s0, p, actions, idx, low, width, tiles, best, inv_scale, fixed,
                   is_angle, delta, n_step, ends_in_goal, hold_bonus, contact_below,
                   fail_charge, tr_state, tr_action, tr_reward, hold):
    """The greedy policy's traced episode, with the episode engine's goal, hold-task and
    end-stop rules (``fail_charge`` NaN: a contact does not end the episode, else the
    missed steps' charge); hold = [first entry step (0: none), steps held, contacts]."""
    dim = s0.shape[0]
    S = np.empty((dim, 1))
    S[:, 0] = s0
    s = S[:, 0]
    a_buf = np.zeros(1)
    r_buf = np.zeros(1)
    tr_state[0, :] = s
    total = 0.0
    dstar = goal_delta(s, best, inv_scale, fixed, is_angle)
    t = 0
    reached = False
    hold[:] = 0
    while t < n_step:
        cell = cell_index(s, idx, low, width, tiles)
        a = greedy(q, cell)
        a_buf[0] = actions[a]
        step_lanes(model, S, a_buf, p, 1, r_buf)
        total += r_buf[0]
        tr_action[t] = a
        tr_reward[t] = r_buf[0]
        t += 1
        tr_state[t, :] = s
        d = goal_delta(s, best, inv_scale, fixed, is_angle)
        if d < dstar:
            dstar = d
        hit = r_buf[0] < contact_below
        if hit:
            hold[2] += 1
        if d <= delta:
            reached = True
            if hold[0] == 0:
                hold[0] = t
            hold[1] += 1
            if ends_in_goal:
                break
            total += hold_bonus
        if hit and not np.isnan(fail_charge):  # charged for the steps it did not run
            total += (n_step - t) * fail_charge
            break
    return total, t, dstar, reached


@dataclass
class QTable:
    """A learnt Q-table over the square tiling of a problem."""

    problem: Problem
    q: np.ndarray                  # (tiles^D', n_actions)
    visited: np.ndarray            # (tiles^D',) bool
    meta: dict

    @property
    def tiling(self):
        pr = self.problem
        idx = np.array(pr.ql_state_indices, dtype=np.int64)
        low = pr.low[idx]
        width = (pr.high[idx] - low) / pr.ql_tiles_per_dim
        return idx, low, width, pr.ql_tiles_per_dim

    def episode(self, delta: float, n_step: int | None = None) -> Episode:
        """The greedy policy's episode from the initial state."""
        pr = self.problem
        n_step = pr.n_step if n_step is None else n_step
        tr_state = np.zeros((n_step + 1, pr.dim))
        tr_a = np.zeros(n_step, dtype=np.int64)
        tr_r = np.zeros(n_step)
        hold = np.zeros(3, dtype=np.int64)
        ret, steps, dstar, reached = greedy_episode(
            model_id(pr.model), self.q, pr.initial_state, pr.params(), pr.action_values,
            *self.tiling, *goal_arrays(pr), pr.is_angle, delta, n_step, pr.ends_in_goal,
            pr.hold_bonus, pr.contact_below, pr.fail_charge, tr_state, tr_a, tr_r, hold)
        a = tr_a[:steps]
        return Episode(tr_state[:steps + 1].copy(), pr.action_values[a], np.full(steps, -1),
                       tr_r[:steps].copy(), float(ret), int(steps), float(dstar), bool(reached),
                       None, *(int(h) for h in hold))

    def to_json(self) -> str:
        pr = self.problem
        cells = np.flatnonzero(self.visited)
        doc = {'format': FORMAT, 'problem': pr.name, 'state_names': list(pr.state_names),
               'actions': list(pr.actions), 'state_indices': list(pr.ql_state_indices),
               'tiles_per_dim': pr.ql_tiles_per_dim, 'meta': json_safe(self.meta)}
        head = json.dumps(doc, indent=1, allow_nan=False)[:-2]
        row = lambda c: json.dumps([float(v) for v in self.q[c]], allow_nan=False)  # noqa: E731
        rows = ',\n  '.join(f'"{c}": ' + row(c) for c in cells)
        return head + ',\n "q": {\n  ' + rows + '\n }\n}\n'

    def save(self, path) -> Path:
        path = Path(path)
        write_atomic(path, self.to_json())
        return path


def qtable_from_document(doc: dict, source: str) -> QTable:
    """Validate a parsed ``sapga-qtable/1`` document (its ``q`` a dict, or a ``Bulk`` read
    one row at a time)."""
    require(doc, HEADER, source)
    try:
        pr = load_problem(doc['problem'])
    except Exception as exc:  # noqa: BLE001 - reported as a policy file error
        raise PolicyFileError(f'{source}: problem: {exc}') from exc
    if doc['state_names'] != list(pr.state_names):
        raise PolicyFileError(f'{source}: state_names: expected {list(pr.state_names)}')
    if not isinstance(doc['actions'], list) or \
            [finite(a, f'{source}: actions') for a in doc['actions']] != list(pr.actions):
        raise PolicyFileError(f'{source}: actions: expected {list(pr.actions)}')
    if doc['state_indices'] != list(pr.ql_state_indices) or \
            doc['tiles_per_dim'] != pr.ql_tiles_per_dim:
        raise PolicyFileError(f'{source}: tiling differs from {pr.name}\'s configuration')
    cells = pr.ql_tiles_per_dim ** len(pr.ql_state_indices)
    q = np.zeros((cells, len(pr.actions)))
    visited = np.zeros(cells, dtype=np.bool_)
    rows = doc['q']
    if not (isinstance(rows, dict) or isinstance(rows, Bulk) and rows.kind == 'object'):
        raise PolicyFileError(f'{source}: q: expected an object of cell: [values]')
    for key, values in rows.items():
        if not (key.isascii() and key.isdigit()) or len(key) > 18 or int(key) >= cells:
            raise PolicyFileError(f'{source}: q: cell {excerpt(key)} is not in 0..{cells - 1}')
        if not isinstance(values, list) or len(values) != len(pr.actions):
            raise PolicyFileError(f'{source}: q[{key}]: expected {len(pr.actions)} numbers')
        if visited[int(key)]:                # '5' and '05': one cell written twice
            raise PolicyFileError(f'{source}: q: cell {int(key)} given twice')
        q[int(key)] = [finite(v, f'{source}: q[{key}]') for v in values]
        visited[int(key)] = True
    complete(doc)                           # the fields after the rows
    if 'delay' in doc:                      # a field of exemplar policies: never ignored
        raise PolicyFileError(f'{source}: delay: a Q-table acts on the state it sees (only an '
                              'exemplar policy is designed for a delay)')
    return QTable(pr, q, visited, meta_of(doc, source))
