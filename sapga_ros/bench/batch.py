"""``sapga bench``: batch evaluation speed against a straightforward numba kernel and a
plain NumPy step-by-step loop.

Measures policy-environment MDP steps per second for batch evaluation (100 exemplars per
policy, 500 policies, full 400-step episodes: delta = 0 so no episode ends early) on one
thread (the per-core figure) and on every core, and the ratios of the per-core figure to
the straightforward numba kernel (``sapga_ros.bench.straightforward``, acrobot only) and to
``sim_nodes.reference.episode`` (plain NumPy, one step at a time, one core), both run in
the same process on some of the same policies.  ``style`` measures another exemplar style's
selector on the same problems (its NumPy baseline exists for state-action only).  Numbers
only: nothing here asserts a time.
"""
from __future__ import annotations

import time

import numpy as np

from sapga_ros.bench import straightforward
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.optim.operators import random_exemplars
from sim_nodes import reference
from sim_nodes.problem import load_problem


def bench_problem(name: str, policies: int = 500, exemplars: int = 100, seed: int = 0,
                  baseline_policies: int = 2, numba_policies: int = 20, repeats: int = 3,
                  style: str = 'state-action') -> dict:
    """Speed figures of one problem."""
    problem = load_problem(name)
    rng = np.random.default_rng(seed)
    pols = [random_exemplars(problem, exemplars, rng, style) for _ in range(policies)]
    evaluator = Evaluator(problem, delta=0.0)  # delta 0: every episode runs 400 steps
    evaluator.evaluate(pols[:2])               # compile outside the timing

    def rate(jobs: int | None) -> tuple[float, int, int]:
        threads = set_jobs(jobs)
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            result = evaluator.evaluate(pols)
            best = min(best, time.perf_counter() - t0)
        return int(result.steps.sum()) / best, threads, int(result.steps.sum())

    one_core, _, steps = rate(1)                # per core: one thread on one core
    all_cores, threads, _ = rate(None)
    set_jobs(None)
    figures = {'problem': name, 'style': style, 'threads': threads, 'steps': steps,
               'steps_per_s_per_core': one_core, 'steps_per_s_all_cores': all_cores}
    if style != 'state-action':
        return figures
    t0 = time.perf_counter()
    base_steps = 0
    for p in pols[:baseline_policies]:
        ret, n, _, _ = reference.episode(problem, p.states, p.action_values, 0.0)
        base_steps += n
    base_time = time.perf_counter() - t0
    base_rate = base_steps / base_time
    figures = {**figures, 'numpy_steps_per_s': base_rate,
               'speedup_vs_numpy': one_core / base_rate}
    if name != 'acrobot':
        return figures
    args = straightforward.acrobot_arguments(problem, pols[:numba_policies])
    straightforward.episodes(*args)            # compile outside the timing
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        _, numba_steps = straightforward.episodes(*args)
        best = min(best, time.perf_counter() - t0)
    numba_rate = numba_steps / best
    return {**figures, 'numba_steps_per_s': numba_rate,
            'speedup_vs_numba': one_core / numba_rate}


def run_bench() -> dict:
    """Both problems; the ratios are one core against the straightforward numba kernel
    (acrobot) and the NumPy loop, each on one core."""
    acro = bench_problem('acrobot')
    pdip = bench_problem('pdip')
    return {'acrobot_steps_per_s_per_core': acro['steps_per_s_per_core'],
            'pdip_steps_per_s_per_core': pdip['steps_per_s_per_core'],
            'numba_steps_per_s': acro['numba_steps_per_s'],
            'speedup_vs_numba': acro['speedup_vs_numba'],
            'speedup_vs_numpy': acro['speedup_vs_numpy'],
            'pdip_speedup_vs_numpy': pdip['speedup_vs_numpy'],
            'threads': acro['threads'], 'details': [acro, pdip]}


def run_style_bench(styles) -> dict:
    """MDP steps/s per core and on every core of each style, on acrobot and PDIP."""
    out = {}
    for style in styles:
        acro = bench_problem('acrobot', style=style, repeats=2)
        pdip = bench_problem('pdip', style=style, repeats=2)
        out[style] = {'acrobot_steps_per_s_per_core': acro['steps_per_s_per_core'],
                      'acrobot_steps_per_s_all_cores': acro['steps_per_s_all_cores'],
                      'pdip_steps_per_s_per_core': pdip['steps_per_s_per_core'],
                      'pdip_steps_per_s_all_cores': pdip['steps_per_s_all_cores'],
                      'threads': acro['threads']}
    return out
