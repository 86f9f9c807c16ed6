"""Tabular Q-learning baseline (paper section 4.3) on the same model kernels.

Square tiling: ``tiles_per_dim`` cells per coordinate over the problem's bounds, on the
coordinates ``q_learning.state_indices`` of the YAML (the PDIP-single baseline tiles
(x, v, theta1, theta1_dot): N_tile = 20^4).  epsilon-greedy (greedy ties to the lowest
action index), learning rate eta, gamma = 1, every episode from the fixed initial state:

    Q(s, a) += eta (r + gamma max_a' Q(s', a') - Q(s, a))     (target r at the goal)

The random stream is a xorshift64* generator whose one-word state is checkpointed, so a
resumed run is identical.  Measures per episode: return, steps, delta*.  The learnt greedy
policy is written as a ``sapga-qtable/1`` JSON document (visited cells only), which
``sapga eval`` runs exactly.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sapga_ros.errors import PolicyFileError
from sapga_ros.evaluation.evaluator import Episode
from sapga_ros.io.atomic import write_atomic
from sapga_ros.exemplars.policy import (MAX_POLICY_BYTES, _check_finite_tree, _finite,
                                        _reject_constant, excerpt, json_safe)
from sim_nodes.goal import goal_arrays, goal_delta
from sim_nodes.jit import kernel
from sim_nodes.models import model_id
from sim_nodes.models.dispatch import step_lanes
from sim_nodes.problem import Problem, load_problem

FORMAT = 'sapga-qtable/1'


@kernel(inline='always')
def xorshift_uniform(rng):
    """Uniform [0, 1) from the xorshift64* state rng[0] (uint64), advanced in place."""
    x = rng[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    rng[0] = x
    mixed = (x * np.uint64(2685821657736338717)) >> np.uint64(11)  # top 53 bits
    return float(mixed) * (1.0 / 9007199254740992.0)                  # / 2^53


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
def learn(model, q, visited, rng, s0, p, actions, idx, low, width, tiles, best, inv_scale,
          fixed, is_angle, delta, n_step, epsilon, eta, gamma, alt_inv_scale, alt_fixed,
          ends_in_goal, hold_bonus, budget, ep_return, ep_steps, ep_dstar, ep_dstar_alt,
          width_lanes, done, n_ep):
    """Run whole episodes of model number ``model`` in each lane k until ``budget[k]`` steps
    are spent (or ``ep_return[k]`` is full): lane k learns its own table ``q[k]``
    (``visited[k]``, generator word ``rng[k]``) and no lane reads another's.

    The lanes' states step side by side in one ``step_lanes`` call of ``width_lanes``
    columns (>= the lane count: the spare columns only fill the model's vector loop), so a
    lane's run is bit-identical to the same run alone.  Per-episode measures go into row k
    of the ep_* arrays (``ep_dstar_alt``: delta* under the alternative goal reading, if
    alt_inv_scale is not empty); ``done[k]``, ``n_ep[k]``: steps simulated, episodes run.
    With ``ends_in_goal`` false (the hold task) S_delta is not terminal and a step ending
    there earns ``hold_bonus`` besides its reward, as in the episode engine.
    """
    lanes = q.shape[0]
    dim = s0.shape[0]
    n_act = actions.shape[0]
    alt = alt_inv_scale.shape[0] > 0
    S = np.empty((dim, width_lanes))
    for k in range(width_lanes):
        S[:, k] = s0
    a_buf = np.zeros(width_lanes)
    r_buf = np.zeros(width_lanes)
    cell = np.zeros(lanes, np.int64)
    act = np.zeros(lanes, np.int64)
    total = np.zeros(lanes)
    dstar = np.zeros(lanes)
    dstar_alt = np.full(lanes, math.inf)
    t = np.zeros(lanes, np.int64)
    active = np.zeros(lanes, np.bool_)
    running = 0
    for k in range(lanes):
        done[k] = 0
        n_ep[k] = 0
        if budget[k] > 0 and ep_return.shape[1] > 0:
            active[k] = True
            running += 1
    starting = active.copy()
    while running > 0:
        for k in range(lanes):
            s = S[:, k]
            if not active[k]:                  # finished: idles at the initial state
                s[:] = s0
                continue
            if starting[k]:                    # a new episode from the initial state
                starting[k] = False
                s[:] = s0
                cell[k] = cell_index(s, idx, low, width, tiles)
                total[k] = 0.0
                t[k] = 0
                dstar[k] = goal_delta(s, best, inv_scale, fixed, is_angle)
                if alt:
                    dstar_alt[k] = goal_delta(s, best, alt_inv_scale, alt_fixed, is_angle)
            g = rng[k:k + 1]
            if xorshift_uniform(g) < epsilon:
                act[k] = min(int(xorshift_uniform(g) * n_act), n_act - 1)
            else:
                act[k] = greedy(q[k], cell[k])
            a_buf[k] = actions[act[k]]
        step_lanes(model, S, a_buf, p, width_lanes, r_buf)
        for k in range(lanes):
            if not active[k]:
                continue
            s = S[:, k]
            r = r_buf[k]
            t[k] += 1
            d = goal_delta(s, best, inv_scale, fixed, is_angle)
            terminal = d <= delta and ends_in_goal
            if d <= delta and not ends_in_goal:
                r += hold_bonus
            total[k] += r
            if d < dstar[k]:
                dstar[k] = d
            if alt:
                d_alt = goal_delta(s, best, alt_inv_scale, alt_fixed, is_angle)
                if d_alt < dstar_alt[k]:
                    dstar_alt[k] = d_alt
            nxt = cell_index(s, idx, low, width, tiles)
            qk = q[k]
            target = r
            if not terminal:                   # bootstrap
                target += gamma * qk[nxt, greedy(qk, nxt)]
            c, a = cell[k], act[k]
            qk[c, a] += eta * (target - qk[c, a])
            visited[k, c] = True
            cell[k] = nxt
            if terminal or t[k] >= n_step:     # the episode ends
                e = n_ep[k]
                ep_return[k, e] = total[k]
                ep_steps[k, e] = t[k]
                ep_dstar[k, e] = dstar[k]
                ep_dstar_alt[k, e] = dstar_alt[k]
                n_ep[k] = e + 1
                done[k] += t[k]
                starting[k] = True
                if done[k] >= budget[k] or n_ep[k] >= ep_return.shape[1]:
                    active[k] = False
                    running -= 1


@kernel
def greedy_episode(model, q, s0, p, actions, idx, low, width, tiles, best, inv_scale, fixed,
                   is_angle, delta, n_step, ends_in_goal, hold_bonus, contact_below,
                   fail_on_contact, tr_state, tr_action, tr_reward, hold):
    """The greedy policy's traced episode, with the episode engine's goal, hold-task and
    end-stop rules; hold = [first entry step (0: none), steps held, end-stop contacts]."""
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
        if hit and fail_on_contact:
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
            pr.hold_bonus, pr.contact_below, pr.end_stop == 'fail', tr_state, tr_a, tr_r, hold)
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
        rows = ',\n  '.join(f'"{c}": ' + json.dumps([float(v) for v in self.q[c]])
                            for c in cells)
        return head + ',\n "q": {\n  ' + rows + '\n }\n}\n'

    def save(self, path) -> Path:
        path = Path(path)
        write_atomic(path, self.to_json())
        return path


def qtable_from_document(doc: dict, source: str) -> QTable:
    """Validate a parsed ``sapga-qtable/1`` document."""
    if not isinstance(doc, dict):
        raise PolicyFileError(f'{source}: expected a JSON object at the top level')
    for key in ('problem', 'state_names', 'actions', 'state_indices', 'tiles_per_dim', 'q'):
        if key not in doc:
            raise PolicyFileError(f'{source}: missing field {key!r}')
    try:
        pr = load_problem(doc['problem'])
    except Exception as exc:  # noqa: BLE001 - reported as a policy file error
        raise PolicyFileError(f'{source}: problem: {exc}') from exc
    if doc['state_names'] != list(pr.state_names):
        raise PolicyFileError(f'{source}: state_names: expected {list(pr.state_names)}')
    if not isinstance(doc['actions'], list) or \
            [_finite(a, f'{source}: actions') for a in doc['actions']] != list(pr.actions):
        raise PolicyFileError(f'{source}: actions: expected {list(pr.actions)}')
    if doc['state_indices'] != list(pr.ql_state_indices) or \
            doc['tiles_per_dim'] != pr.ql_tiles_per_dim:
        raise PolicyFileError(f'{source}: tiling differs from {pr.name}\'s configuration')
    cells = pr.ql_tiles_per_dim ** len(pr.ql_state_indices)
    q = np.zeros((cells, len(pr.actions)))
    visited = np.zeros(cells, dtype=np.bool_)
    if not isinstance(doc['q'], dict):
        raise PolicyFileError(f'{source}: q: expected an object of cell: [values]')
    for key, values in doc['q'].items():
        if not (key.isascii() and key.isdigit()) or len(key) > 18 or int(key) >= cells:
            raise PolicyFileError(f'{source}: q: cell {excerpt(key)} is not in 0..{cells - 1}')
        if not isinstance(values, list) or len(values) != len(pr.actions):
            raise PolicyFileError(f'{source}: q[{key}]: expected {len(pr.actions)} numbers')
        q[int(key)] = [_finite(v, f'{source}: q[{key}]') for v in values]
        visited[int(key)] = True
    meta = doc.get('meta', {})
    if not isinstance(meta, dict):
        raise PolicyFileError(f'{source}: meta: expected an object')
    _check_finite_tree(meta, f'{source}: meta')
    return QTable(pr, q, visited, meta)


def parse_json(data: bytes, source: str):
    """Parse a JSON document refusing NaN/Infinity and oversized input."""
    if len(data) > MAX_POLICY_BYTES:
        raise PolicyFileError(f'{source}: larger than the '
                              f'{MAX_POLICY_BYTES // (1024 * 1024)} MB limit')
    try:
        return json.loads(data.decode('utf-8'), parse_constant=_reject_constant)
    except UnicodeDecodeError as exc:
        raise PolicyFileError(f'{source}: not UTF-8 text (byte {exc.start})') from exc
    except json.JSONDecodeError as exc:
        raise PolicyFileError(f'{source}: malformed JSON ({exc.msg}, line {exc.lineno} '
                              f'column {exc.colno})') from exc
    except (ValueError, RecursionError) as exc:
        raise PolicyFileError(f'{source}: {exc}') from exc
