"""The episode engine: exemplar policies against one model (paper section 3, evaluation
procedure), batched over many policies on all cores.

``run_share`` is the one episode loop: from the initial state, select an action with the
policy's style (``sapga_ros.exemplars.selectors.select``), take one MDP step, add the
reward, test the goal on the new state after counting its reward, stop in S_delta or after
N_step steps, marking every exemplar referred to (for the refresh operator).
``evaluate_batch`` runs it in parallel shares; a traced single episode is ``run_share`` on
one policy with trace arrays of N_step + 1 rows.

Speed: one thread runs ``LANES`` episodes side by side.  Each MDP step selects an action per
lane, then the model advances all lanes together (``step_lanes``: the lane loop is
innermost, so the dependent chain of one episode's integration overlaps with the others and
vectorises).  A finished lane takes the next policy of its thread's share.  Arithmetic per
lane does not depend on the other lanes, so every result is that of a lone episode.  After
the step the lanes' delta(s), returns and counts are accounted side by side (kept per lane,
written to the policy's entries when its episode ends).  State-action policies without a
controller take their own selection loop (the nearest exemplar's action, what ``choose``
returns for them; the disturbances' draws as in the general loop): without the other
styles' and the controllers' code in its body the compiler keeps it in registers, which
roughly halves the selection's cost.  So do state-action policies that all select on the
state predicted the same d steps ahead (``AHEAD`` controllers of one delay, a run trained
with ``delay``): the lanes' predictions are d model steps of all lanes side by side, each
lane's arithmetic that of ``choose``'s ``predict``.  And so do state-action hybrids whose
catches are all designed for one delay (a run trained with ``catch: lqr``): the LQR is asked
lane by lane on the lanes' predictions, the lanes outside their regions search their
exemplars together (a hybrid's training runs about 2.4 times as fast as through the general
loop on acrobot_hold).

Packed policies (``Evaluator.pack``): ex (P, D, L) and ex2 (P, D, L or 1) normalised
states, act (P, L) action values, val (P, L) values, lengths (P,).  ``sel`` are the
selector's constants: (style, actions, via-point radius squared, best state normalised).
"""
from __future__ import annotations

import numpy as np
from numba import prange

from sapga_ros.evaluation.control import choose, lqr, memory_width, nearest_action
from sapga_ros.exemplars.distance import nearest, normalize_lanes
from sapga_ros.policies.styles import STATE_ACTION
from sim_nodes.draws import (LATENCY, MISMATCH, ON, PUSHES, command, episode_key, observe, push,
                             start_episode)
from sim_nodes.goal import goal_delta, lanes_delta
from sim_nodes.jit import kernel
from sim_nodes.models.dispatch import step_lanes, step_lanes_each

LANES = 16           # episodes side by side in one thread (two 8-wide vectors)
BLOCKS_PER_THREAD = 4  # shares of a batch per thread, for load balance


@kernel(inline='always')
def nearest_lanes(seen, pol, ex, act, lengths, inv_range, is_angle, U, acc, used, chosen, a):
    """State-action selection of every busy lane (policy ``pol[lane]`` >= 0) for the states
    ``seen`` (D, LANES): the lanes normalised side by side into U, then each lane's nearest
    exemplar (marked used), its index into ``chosen`` and its action into ``a``."""
    normalize_lanes(seen, LANES, inv_range, is_angle, U)
    for lane in range(LANES):
        k = pol[lane]
        if k >= 0:
            j = nearest(U[lane], ex[k], lengths[k], is_angle, acc)
            used[k, j] = True
            chosen[lane] = j
            a[lane] = act[k, j]


@kernel
def predict_lanes(model, seen, memory, ahead, p, predicted, in_flight, r_pred):
    """Into ``predicted``: each lane's state ``ahead`` nominal MDP steps on from ``seen``
    with the lane's commands in flight (``memory``, oldest first), the lanes side by side;
    lane by lane what ``control.predict`` computes."""
    predicted[:, :] = seen
    for m in range(ahead):
        for lane in range(predicted.shape[1]):
            in_flight[lane] = memory[lane, m]
        step_lanes(model, predicted, in_flight, p, predicted.shape[1], r_pred)


@kernel
def remember_lanes(memory, ahead, a):
    """Each lane's command ``a[lane]`` joins its ``ahead`` commands in flight (oldest first),
    as ``control.remember`` does."""
    for lane in range(a.shape[0]):
        for m in range(ahead - 1):
            memory[lane, m] = memory[lane, m + 1]
        memory[lane, ahead - 1] = a[lane]


@kernel
def catch_lanes(predicted, pol, ctl, best, is_angle, actions, x, inside, a_lqr):
    """The hybrids' LQR on every busy lane's predicted state (column of ``predicted``):
    ``inside[lane]`` its x'Px <= c, ``a_lqr[lane]`` the action nearest its -Kx, lane by
    lane what ``choose`` computes for a ``CATCH`` controller."""
    for lane in range(LANES):
        k = pol[lane]
        inside[lane] = False
        if k >= 0:
            inside[lane], command = lqr(ctl[k], predicted[:, lane], best, is_angle, x)
            a_lqr[lane] = nearest_action(command, actions)


@kernel
def run_share(model, style, ex, ex2, act, val, lengths, first, stop, s0, p, inv_range,
              is_angle, best, inv_scale, fixed, delta, n_step, actions, radius2, goal_u,
              alt_inv_scale, alt_fixed, ends_in_goal, hold_bonus, contact_below, fail_charge,
              ctl, ahead, catch, dist, keys, returns, steps, dstar, dstar_alt, reached, used,
              first_entry, held, contacts, tr_state, tr_idx, tr_act, tr_reward):
    """Evaluate policies first..stop-1 on LANES lanes.

    The hold task: with ``ends_in_goal`` false an episode runs all n_step steps;
    ``hold_bonus`` is added to the return for every step that ends in S_delta;
    ``first_entry`` is the first such step (0: none), ``held`` their count from it on
    (``held / (steps - first_entry + 1)`` is the hold fraction).  A step whose reward is
    below ``contact_below`` touched the end stop (``contacts``); unless ``fail_charge`` is
    NaN (``end_stop: stop``) the contact ends the episode (a goal end in the same step
    comes first) and every step it did not run is charged ``fail_charge``
    (``Problem.fail_charge``): a contact ending step t adds ``(n_step - t) * fail_charge``
    to the return, after the step's reward and bonus.  ``ctl[k]`` is policy k's
    controller (``sapga_ros.evaluation.control``; one 0 column: none); a controller
    designed for an actuation delay remembers the commands it issued in its lane's
    ``memory`` (zero at the start of every episode).  ``ahead`` (state-action policies whose
    controllers are all ``AHEAD`` of one delay d: ``control.uniform_ahead``) is d, and the
    lanes' predictions are then stepped side by side; None otherwise (a None argument
    compiles that branch out of the loop, which the plain loop's speed depends on).
    ``catch`` (state-action hybrids whose catches are all designed for one delay d:
    ``control.uniform_catch``) is d: the LQR is asked lane by lane on the lanes'
    predictions stepped side by side, and the lanes outside their regions search their
    exemplars together; None otherwise.

    ``dstar_alt`` is delta* under an alternative reading of the goal box (alt_inv_scale,
    alt_fixed; measured only, never ending an episode); empty alt arrays: not measured.

    If ``tr_state`` has n_step + 1 rows, policy 0's episode is traced: its states (the
    initial one first), the exemplar index and action value chosen at each step and each
    step's reward.
    """
    dim = s0.shape[0]
    S = np.empty((dim, LANES))
    a = np.zeros(LANES)
    r = np.zeros(LANES)
    u = np.empty(dim)
    acc = np.empty(ex.shape[2])
    w_state = np.empty((dim, 1))
    w_act = np.zeros(1)
    w_rew = np.zeros(1)
    x = np.empty(2 * dim)
    pol = np.full(LANES, -1)                  # policy on each lane; -1: idle
    progress = np.zeros(LANES, dtype=np.int64)  # the selector's per-episode state
    memory = np.zeros((LANES, memory_width(ctl)))  # the controller's commands in flight
    # each lane's episode so far (written to the policy's entries when it ends), kept by
    # lane so that the accounting after a step runs over the lanes side by side
    ret = np.zeros(LANES)
    n = np.zeros(LANES, dtype=np.int64)
    best_d = np.zeros(LANES)
    best_alt = np.zeros(LANES)
    entry = np.zeros(LANES, dtype=np.int64)
    inside_n = np.zeros(LANES, dtype=np.int64)
    hits = np.zeros(LANES, dtype=np.int64)
    got = np.zeros(LANES, dtype=np.int64)     # entered S_delta
    ends = np.zeros(LANES, dtype=np.int64)    # 1: the step ended the episode; 2: by a contact
    chosen = np.zeros(LANES, dtype=np.int64)  # the exemplar each lane's selector chose
    d_now = np.zeros(LANES)
    U = np.empty((LANES, dim))                # the lanes' states normalised
    d_alt = np.zeros(LANES)
    trace = tr_state.shape[0] > n_step
    alt = alt_inv_scale.shape[0] > 0
    disturbed = dist[ON] > 0.0
    fail = not np.isnan(fail_charge)          # an end-stop contact ends the episode
    own_params = disturbed and dist[MISMATCH] > 0.0   # each lane steps its own plant
    # state-action without a controller (a 0 column): its own loop, where the compiler
    # knows the style (the other styles' and the controllers' code leaves it)
    plain = style == STATE_ACTION and ctl.shape[1] == 1
    predicted = np.empty((dim, LANES))          # where the selector's commands will act
    in_flight = np.zeros(LANES)
    r_pred = np.zeros(LANES)
    caught = np.zeros(LANES, dtype=np.bool_)   # a hybrid's lane in its catch region
    a_lqr = np.zeros(LANES)                     # its LQR's action
    outside = np.full(LANES, -1)                # the lanes its exemplars answer (-1: not)
    obs = np.zeros((dim, LANES))                # what the selector sees
    plant = np.empty((LANES, p.shape[0]))      # each lane's plant parameters (idle: p)
    for lane in range(LANES):
        plant[lane] = p
    n_push = int(dist[PUSHES]) if disturbed else 0
    push_at = np.zeros((LANES, n_push), dtype=np.int64)
    push_dv = np.zeros((LANES, n_push))
    push_on = np.zeros((LANES, n_push), dtype=np.int64)
    history = np.zeros((LANES, (int(dist[LATENCY]) if disturbed else 0) + 1))
    gain = np.ones(LANES)
    key = np.zeros(LANES, dtype=np.uint64)
    for lane in range(LANES):
        S[:, lane] = s0
    nxt = first
    active = 0
    while True:
        for lane in range(LANES):               # idle lanes take the next policies
            if pol[lane] < 0 and nxt < stop:
                pol[lane] = nxt
                progress[lane] = 0
                memory[lane, :] = 0.0
                ret[lane] = 0.0
                n[lane] = 0
                if disturbed:
                    key[lane] = episode_key(keys[nxt, 0], keys[nxt, 1], keys[nxt, 2],
                                            keys[nxt, 3])
                    gain[lane] = start_episode(dist, key[lane], s0, p, is_angle, n_step,
                                               S[:, lane], plant[lane], push_at[lane],
                                               push_dv[lane], push_on[lane])
                    history[lane, :] = 0.0
                best_d[lane] = goal_delta(S[:, lane], best, inv_scale, fixed, is_angle)
                if alt:
                    best_alt[lane] = goal_delta(S[:, lane], best, alt_inv_scale, alt_fixed,
                                                is_angle)
                got[lane] = 0
                entry[lane] = 0
                inside_n[lane] = 0
                hits[lane] = 0
                if trace and nxt == 0:
                    tr_state[0, :] = S[:, lane]
                nxt += 1
                active += 1
        if active == 0:
            break
        seen = S                                # what the selector sees
        if disturbed:                           # the state plus sensor noise
            for lane in range(LANES):
                if pol[lane] >= 0:
                    observe(dist, key[lane], n[lane], S[:, lane], is_angle, obs[:, lane])
            seen = obs
        if plain:                               # choose without a controller
            nearest_lanes(seen, pol, ex, act, lengths, inv_range, is_angle, U, acc, used,
                          chosen, a)
        elif ahead is not None:                 # the same on d nominal steps ahead
            predict_lanes(model, seen, memory, ahead, p, predicted, in_flight, r_pred)
            nearest_lanes(predicted, pol, ex, act, lengths, inv_range, is_angle, U, acc, used,
                          chosen, a)
            remember_lanes(memory, ahead, a)
        elif catch is not None:                 # hybrids: the LQR inside its region
            predict_lanes(model, seen, memory, catch, p, predicted, in_flight, r_pred)
            catch_lanes(predicted, pol, ctl, best, is_angle, actions, x, caught, a_lqr)
            for lane in range(LANES):
                outside[lane] = -1 if caught[lane] else pol[lane]
            nearest_lanes(seen, outside, ex, act, lengths, inv_range, is_angle, U, acc, used,
                          chosen, a)
            for lane in range(LANES):
                if caught[lane]:
                    chosen[lane] = -1
                    a[lane] = a_lqr[lane]
            if catch > 0:
                remember_lanes(memory, catch, a)
        else:
            for lane in range(LANES):
                k = pol[lane]
                if k >= 0:
                    chosen[lane], a[lane], progress[lane] = choose(
                        style, model, seen[:, lane], ex[k], ex2[k], act[k], val[k],
                        lengths[k], actions, p, inv_range, is_angle, radius2, goal_u,
                        progress[lane], used[k], u, acc, w_state, w_act, w_rew, ctl[k], best,
                        x, memory[lane])
        if disturbed:                           # late, scaled commands; pushes
            for lane in range(LANES):
                if pol[lane] >= 0:
                    a[lane] = command(history[lane], n[lane], a[lane], gain[lane])
                    push(n[lane], push_at[lane], push_dv[lane], push_on[lane], S[:, lane])
        if trace:
            for lane in range(LANES):
                if pol[lane] == 0:
                    tr_idx[n[lane]] = chosen[lane]
                    tr_act[n[lane]] = a[lane]
        if own_params:                          # mismatched plants: lane k with plant[k]
            step_lanes_each(model, S, a, plant, S.shape[1], r)
        else:
            step_lanes(model, S, a, p, S.shape[1], r)  # not the literal LANES: keeps a loop
        lanes_delta(S, LANES, best, inv_scale, fixed, is_angle, d_now)
        if alt:
            lanes_delta(S, LANES, best, alt_inv_scale, alt_fixed, is_angle, d_alt)
        for lane in range(LANES):               # every lane, idle ones too (reset on refill)
            d = d_now[lane]
            inside = d <= delta                 # goal test after the step's reward is counted
            hit = r[lane] < contact_below
            step = n[lane] + 1
            total = ret[lane] + r[lane]
            ret[lane] = total + hold_bonus if inside and not ends_in_goal else total
            n[lane] = step
            best_d[lane] = d if d < best_d[lane] else best_d[lane]
            best_alt[lane] = d_alt[lane] if d_alt[lane] < best_alt[lane] else best_alt[lane]
            hits[lane] += hit
            inside_n[lane] += inside
            entry[lane] = step if inside and entry[lane] == 0 else entry[lane]
            got[lane] |= inside
            goal = inside and ends_in_goal
            failed = hit and fail and not goal
            ends[lane] = 2 if failed else (1 if goal or step >= n_step else 0)
        if trace:
            for lane in range(LANES):
                if pol[lane] == 0:
                    tr_state[n[lane], :] = S[:, lane]
                    tr_reward[n[lane] - 1] = r[lane]
        for lane in range(LANES):
            k = pol[lane]
            if k < 0 or ends[lane] == 0:
                continue
            if ends[lane] == 2:                 # charged for the steps it did not run
                ret[lane] += (n_step - n[lane]) * fail_charge
            returns[k] = ret[lane]
            steps[k] = n[lane]
            dstar[k] = best_d[lane]
            if alt:
                dstar_alt[k] = best_alt[lane]
            reached[k] = got[lane] > 0
            first_entry[k] = entry[lane]
            held[k] = inside_n[lane]
            contacts[k] = hits[lane]
            S[:, lane] = s0
            a[lane] = 0.0
            pol[lane] = -1
            active -= 1


@kernel(parallel=True)
def evaluate_batch(model, style, ex, ex2, act, val, lengths, s0, p, inv_range, is_angle,
                   best, inv_scale, fixed, delta, n_step, actions, radius2, goal_u,
                   alt_inv_scale, alt_fixed, ends_in_goal, hold_bonus, contact_below,
                   fail_charge, ctl, ahead, catch, dist, keys, shares, returns, steps, dstar,
                   dstar_alt, reached, used, first_entry, held, contacts):
    """Evaluate policies ex[k, :, :lengths[k]] in ``shares`` parallel shares (untraced;
    ``dist``, ``keys``: the disturbances, as in ``run_share``)."""
    count = ex.shape[0]
    no_state = np.zeros((1, s0.shape[0]))
    no_idx = np.zeros(1, dtype=np.int64)
    no_val = np.zeros(1)
    for b in prange(shares):
        first = b * count // shares
        stop = (b + 1) * count // shares
        run_share(model, style, ex, ex2, act, val, lengths, first, stop, s0, p, inv_range,
                  is_angle, best, inv_scale, fixed, delta, n_step, actions, radius2, goal_u,
                  alt_inv_scale, alt_fixed, ends_in_goal, hold_bonus, contact_below,
                  fail_charge, ctl, ahead, catch, dist, keys, returns, steps, dstar, dstar_alt,
                  reached, used, first_entry, held, contacts, no_state, no_idx, no_val, no_val)
