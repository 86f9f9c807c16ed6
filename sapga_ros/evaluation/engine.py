"""Compiled episode kernels: exemplar policies against one model (paper section 3,
evaluation procedure), batched over many policies on all cores.

``episode``, ``run_share`` and ``evaluate_batch`` are the numba functions that run episodes
of the model whose number they are given (``episode_kernels(model)`` binds it):
from the initial state, select the nearest exemplar's action, take one MDP step, add the
reward, test the goal on the new state after counting its reward, stop in S_delta or after
N_step steps, marking every exemplar referred to (for the refresh operator).

Speed: one thread runs ``LANES`` episodes side by side.  Each MDP step selects an action per
lane, then the model advances all lanes together (``mdp_step_lanes``: the lane loop is
innermost, so the dependent chain of one episode's integration overlaps with the others and
vectorises).  A finished lane takes the next policy of its thread's share.  Arithmetic per
lane is the same as in a single episode, so results are bit-identical to ``episode``.
"""
from __future__ import annotations

from functools import lru_cache, partial
from typing import NamedTuple

import numpy as np
from numba import prange

from sapga_ros.exemplars.distance import nearest, normalize_into
from sim_nodes.goal import goal_delta
from sim_nodes.jit import kernel
from sim_nodes.models import model_id
from sim_nodes.models.dispatch import step_lanes

LANES = 8            # episodes side by side in one thread
BLOCKS_PER_THREAD = 4  # shares of a batch per thread, for load balance


class EpisodeKernels(NamedTuple):
    episode: object          # one policy, optional trajectory
    evaluate_batch: object   # many policies in parallel


@lru_cache(maxsize=None)
def episode_kernels(model: str) -> EpisodeKernels:
    """The kernels bound to ``model`` (compiled on first use, then from numba's disk cache)."""
    number = model_id(model)
    return EpisodeKernels(partial(episode, number), partial(evaluate_batch, number))


@kernel
def episode(model, ex, act, n, s0, p, inv_range, is_angle, best, inv_scale, fixed, delta,
            n_step, used, tr_state, tr_idx, tr_reward):
    """Run one episode; return (return, steps, delta*, reached).

    ex (D, L) normalised exemplar states, act (L,) action values, n exemplars used.
    ``used[j]`` is set for each exemplar referred to.  If ``tr_state`` has n_step + 1
    rows the trajectory is recorded: states (including the initial one), the exemplar
    index chosen at each step and each step's reward.
    """
    dim = s0.shape[0]
    S = np.empty((dim, 1))
    S[:, 0] = s0
    s = S[:, 0]
    a = np.zeros(1)
    r = np.zeros(1)
    u = np.empty(dim)
    acc = np.empty(n)
    record = tr_state.shape[0] > n_step
    if record:
        tr_state[0, :] = s
    total = 0.0
    dstar = goal_delta(s, best, inv_scale, fixed, is_angle)
    reached = False
    steps = 0
    while steps < n_step:
        normalize_into(s, inv_range, is_angle, u)
        j = nearest(u, ex, n, is_angle, acc)
        used[j] = True
        a[0] = act[j]
        step_lanes(model, S, a, p, 1, r)
        total += r[0]
        steps += 1
        d = goal_delta(s, best, inv_scale, fixed, is_angle)
        if d < dstar:
            dstar = d
        if record:
            tr_state[steps, :] = s
            tr_idx[steps - 1] = j
            tr_reward[steps - 1] = r[0]
        if d <= delta:  # goal test after the step's reward is counted
            reached = True
            break
    return total, steps, dstar, reached


@kernel
def run_share(model, ex, act, lengths, first, stop, s0, p, inv_range, is_angle, best,
              inv_scale, fixed, delta, n_step, returns, steps, dstar, reached, used):
    """Evaluate policies first..stop-1 on LANES lanes (same results as ``episode``)."""
    dim = s0.shape[0]
    S = np.empty((dim, LANES))
    a = np.zeros(LANES)
    r = np.zeros(LANES)
    u = np.empty(dim)
    acc = np.empty(ex.shape[2])
    pol = np.full(LANES, -1)                  # policy on each lane; -1: idle
    for lane in range(LANES):
        S[:, lane] = s0
    nxt = first
    active = 0
    while True:
        for lane in range(LANES):               # idle lanes take the next policies
            if pol[lane] < 0 and nxt < stop:
                pol[lane] = nxt
                returns[nxt] = 0.0
                steps[nxt] = 0
                dstar[nxt] = goal_delta(s0, best, inv_scale, fixed, is_angle)
                reached[nxt] = False
                nxt += 1
                active += 1
        if active == 0:
            break
        for lane in range(LANES):
            k = pol[lane]
            if k >= 0:
                normalize_into(S[:, lane], inv_range, is_angle, u)
                j = nearest(u, ex[k], lengths[k], is_angle, acc)
                used[k, j] = True
                a[lane] = act[k, j]
        step_lanes(model, S, a, p, S.shape[1], r)  # not the literal LANES: keeps it a loop
        for lane in range(LANES):
            k = pol[lane]
            if k < 0:
                continue
            returns[k] += r[lane]
            steps[k] += 1
            d = goal_delta(S[:, lane], best, inv_scale, fixed, is_angle)
            if d < dstar[k]:
                dstar[k] = d
            if d <= delta:  # goal test after the step's reward is counted
                reached[k] = True
            if reached[k] or steps[k] >= n_step:
                S[:, lane] = s0
                a[lane] = 0.0
                pol[lane] = -1
                active -= 1


@kernel(parallel=True)
def evaluate_batch(model, ex, act, lengths, s0, p, inv_range, is_angle, best, inv_scale,
                   fixed, delta, n_step, shares, returns, steps, dstar, reached, used):
    """Evaluate policies ex[k, :, :lengths[k]] in ``shares`` parallel shares."""
    count = ex.shape[0]
    for b in prange(shares):
        first = b * count // shares
        stop = (b + 1) * count // shares
        run_share(model, ex, act, lengths, first, stop, s0, p, inv_range, is_angle, best,
                  inv_scale, fixed, delta, n_step, returns, steps, dstar, reached, used)
