"""Cost of robust evaluation per MDP step against a plain batch, in the same process.

``python -m sapga_ros.bench.robust [--problem acrobot] [--policies 200] [--episodes 8]``
evaluates random policies of 100 exemplars (delta = 0: every episode runs its N_step
steps) on one thread, plain, and with K episodes each under three profiles: ``none``
(only the larger batch), ``field`` without its parameter mismatch (initial spread,
sensor noise, latency), and ``field``.  It prints each one's seconds per MDP step as a
multiple of the plain batch's (best of ``repeats``; CPU time of the process, steadier than
wall time on a shared machine).  Numbers only: nothing here asserts
a time.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.evaluation.robust import Robust, RobustEvaluator
from sapga_ros.optim.operators import random_exemplars
from sim_nodes.disturbance import Disturbance, load_disturbance
from sim_nodes.problem import load_problem


def _per_step(evaluate, repeats: int) -> float:
    """CPU seconds per MDP step of ``evaluate()`` (best of ``repeats``, after one warm-up)."""
    evaluate()
    best = np.inf
    for _ in range(repeats):
        start = time.process_time()
        steps = int(evaluate().steps.sum())
        best = min(best, (time.process_time() - start) / steps)
    return best


def run_robust_bench(problem: str = 'acrobot', policies: int = 200, episodes: int = 8,
                     repeats: int = 3, seed: int = 0) -> dict:
    """CPU seconds per MDP step of each profile as a multiple of the plain batch's."""
    prob = load_problem(problem)
    rng = np.random.default_rng(seed)
    pols = [random_exemplars(prob, 100, rng) for _ in range(policies)]
    set_jobs(1)
    plain = Evaluator(prob, delta=0.0)
    base = _per_step(lambda: plain.evaluate(pols), repeats)
    field = load_disturbance('field')
    profiles = {'none': Disturbance(), 'field_without_mismatch':
                dataclasses.replace(field, mismatch={}), 'field': field}
    out = {'problem': problem, 'policies': policies, 'episodes': episodes,
           'plain_steps_per_s': 1.0 / base}
    for name, dist in profiles.items():
        robust = RobustEvaluator(prob, 0.0, dist, Robust(episodes, seed=seed))
        out[f'{name}_cost_per_step'] = _per_step(lambda: robust.evaluate(pols), repeats) / base
    set_jobs(None)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m sapga_ros.bench.robust',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--problem', default='acrobot')
    parser.add_argument('--policies', type=int, default=200)
    parser.add_argument('--episodes', type=int, default=8)
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args(argv)
    print(json.dumps(run_robust_bench(args.problem, args.policies, args.episodes,
                                      args.repeats)))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
