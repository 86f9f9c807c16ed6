"""Tabular Q-learning baseline (paper section 4.3): the learning kernel, on the
same model kernels as the episode engine.

Square tiling: ``tiles_per_dim`` cells per coordinate over the problem's bounds, on the
coordinates ``q_learning.state_indices`` of the YAML (the PDIP-single baseline tiles
(x, v, theta1, theta1_dot): N_tile = 20^4).  epsilon-greedy (greedy ties to the lowest
action index), learning rate eta, gamma = 1, every episode from the fixed initial state:

    Q(s, a) += eta (r + gamma max_a' Q(s', a') - Q(s, a))     (target r at the goal)

The random stream is a xorshift64* generator whose one-word state is checkpointed, so a
resumed run is identical.  Measures per episode: return, steps, delta*.  The tiling, the
greedy action and the learnt table's file format (``sapga-qtable/1``) are the Q-table
policy's (``sapga_ros.policies.qtable``).
"""
from __future__ import annotations

import math

import numpy as np

from sapga_ros.policies.qtable import cell_index, greedy
from sim_nodes.goal import goal_delta
from sim_nodes.jit import kernel
from sim_nodes.models.dispatch import step_lanes


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


@kernel
def learn(model, q, visited, rng, s0, p, actions, idx, low, width, tiles, best, inv_scale,
          fixed, is_angle, delta, n_step, epsilon, eta, gamma, alt_inv_scale, alt_fixed,
          ends_in_goal, hold_bonus, contact_below, fail_charge, budget, ep_return, ep_steps,
          ep_dstar, ep_dstar_alt, width_lanes, done, n_ep):
    """Run whole episodes of model number ``model`` in each lane k until ``budget[k]`` steps
    are spent (or ``ep_return[k]`` is full): lane k learns its own table ``q[k]``
    (``visited[k]``, generator word ``rng[k]``) and no lane reads another's.

    The lanes' states step side by side in one ``step_lanes`` call of ``width_lanes``
    columns (>= the lane count: the spare columns only fill the model's vector loop), so a
    lane's run is bit-identical to the same run alone.  Per-episode measures go into row k
    of the ep_* arrays (``ep_dstar_alt``: delta* under the alternative goal reading, if
    alt_inv_scale is not empty); ``done[k]``, ``n_ep[k]``: steps simulated, episodes run.
    With ``ends_in_goal`` false (the hold task) S_delta is not terminal and a step ending
    there earns ``hold_bonus`` besides its reward, as in the episode engine.  Unless
    ``fail_charge`` is NaN, a step whose reward is below ``contact_below`` (an end-stop
    contact) is terminal and earns ``(n_step - t) * fail_charge`` besides, the engine's
    charge for the steps the episode did not run.
    """
    lanes = q.shape[0]
    dim = s0.shape[0]
    n_act = actions.shape[0]
    alt = alt_inv_scale.shape[0] > 0
    fail = not np.isnan(fail_charge)          # an end-stop contact ends the episode
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
            if r_buf[k] < contact_below and fail and not terminal:
                r += (n_step - t[k]) * fail_charge  # the steps it did not run
                terminal = True
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
