"""The speed measures of ``sapga_ros.bench``: the share of a training run's CPU time spent in
the batch kernel, and the cost of robust evaluation per step (numbers only: no time is
asserted, only that they are measured and the kernel is left as it was)."""
from __future__ import annotations

from sapga_ros.bench.robust import run_robust_bench
from sapga_ros.bench.training import kernel_share
from sapga_ros.evaluation import evaluator
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig, train


def test_kernel_share_of_a_run_is_a_fraction_and_the_kernel_is_restored():
    kernel = evaluator.evaluate_batch
    config = TrainConfig(problem='acrobot', steps=20_000, jobs=1,
                         params=SapgaParams(n_pop=6, n_child=3))
    share = kernel_share(lambda: train(config))
    assert 0.0 < share < 1.0
    assert evaluator.evaluate_batch is kernel


def test_robust_bench_reports_every_profile():
    d = run_robust_bench('pendulum', policies=3, episodes=2, repeats=1)
    assert d['plain_steps_per_s'] > 0
    for name in ('none', 'field_without_mismatch', 'field'):
        assert d[f'{name}_cost_per_step'] > 0
