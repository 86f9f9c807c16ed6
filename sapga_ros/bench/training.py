"""``sapga bench --training``: end-to-end training speed, whole runs through the one
training loop (``training.loop``) on one evaluation thread.

* SAP-GA: MDP steps per second of a whole ``train`` run (evaluation, selection, operators,
  logging), the paper's settings, on the acrobot and the PDIP, and the share of the run's
  CPU time spent in the batch kernel (``evaluate_batch``; the rest is the generation's
  Python and NumPy: operators, packing, bookkeeping).
* Q-learning: MDP steps per second of one run alone, and of ``LANE_BLOCK`` runs (seeds)
  learnt side by side (``train_lanes``, as the experiments run a Q-learning row), on the
  acrobot (row #1) and the single pendulum (row #3), and the ratio of the two measured in
  the same process.  The runs side by side are bit-identical to the runs alone (tested).

Numbers only: nothing here asserts a time.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Callable, Iterator

from sapga_ros.evaluation import evaluator
from sapga_ros.optim.qlearner import LANE_BLOCK
from sapga_ros.training.loop import TrainConfig, TrainResult, train, train_lanes

QL_ROWS = (('acrobot', 0.1), ('pdip_single', 0.01))
SAPGA_ROWS = (('acrobot', 0.02), ('pdip', 0.01))


def _rate(run: Callable[[], list[TrainResult]]) -> float:
    """MDP steps per second of the training runs ``run()`` makes."""
    start = time.perf_counter()
    results = run()
    return sum(r.stats['steps'] for r in results) / (time.perf_counter() - start)


@contextmanager
def kernel_seconds() -> Iterator[list[float]]:
    """Within the block, adds up the CPU seconds spent in ``evaluate_batch`` (the batch
    kernel the evaluator calls) into the list's one entry."""
    spent = [0.0]
    kernel = evaluator.evaluate_batch

    def timed(*args):
        start = time.process_time()
        kernel(*args)
        spent[0] += time.process_time() - start
    evaluator.evaluate_batch = timed
    try:
        yield spent
    finally:
        evaluator.evaluate_batch = kernel


def kernel_share(run: Callable[[], object]) -> float:
    """The share of ``run()``'s CPU time spent in the batch kernel."""
    with kernel_seconds() as spent:
        start = time.process_time()
        run()
        total = time.process_time() - start
    return spent[0] / total


def run_training_bench(steps: int = 2_000_000, lanes: int = LANE_BLOCK) -> dict:
    """Steps/s of SAP-GA and of Q-learning alone and side by side (each after a short
    warm-up run that compiles the kernels)."""
    out = {'lanes': lanes, 'steps_per_run': steps}
    for problem, delta in SAPGA_ROWS:
        def sapga(budget: int) -> TrainConfig:
            return TrainConfig(problem=problem, method='sapga', delta=delta, steps=budget,
                               jobs=1)
        train(sapga(20_000))                                    # compile
        out[f'sapga_{problem}_steps_per_s'] = _rate(lambda: [train(sapga(steps))])
        out[f'sapga_{problem}_kernel_share'] = kernel_share(lambda: train(sapga(steps)))
    for problem, delta in QL_ROWS:
        def ql(seed: int, budget: int = steps) -> TrainConfig:
            return TrainConfig(problem=problem, method='ql', delta=delta, steps=budget,
                               seed=seed)
        train_lanes([ql(s, 20_000) for s in range(2)])          # compile
        alone = _rate(lambda: [train(ql(0))])
        together = _rate(lambda: train_lanes([ql(s) for s in range(lanes)]))
        out[f'ql_{problem}_alone_steps_per_s'] = alone
        out[f'ql_{problem}_lanes_steps_per_s'] = together
        out[f'ql_{problem}_lanes_speedup'] = together / alone
    return out
