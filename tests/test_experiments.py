"""The Table 2 experiment runner (SPEC 3.5) on a tiny budget."""
import json

import numpy as np
import pytest

from sapga_ros.errors import ConfigError
from sapga_ros.training.experiments import load_experiments, resample, run_experiments


def test_table2_defines_the_papers_four_experiments():
    """msg_configs/experiments/table2.yaml holds Table 2: problems, deltas, methods,
    budgets, 20 seeds."""
    exps, seeds = load_experiments('table2')
    assert seeds == 20
    assert [(e.problem, e.delta, e.method, e.steps) for e in exps] == [
        ('acrobot', 0.1, 'ql', 100_000_000), ('acrobot', 0.02, 'sapga', 30_000_000),
        ('pdip_single', 0.01, 'ql', 30_000_000), ('pdip', 0.01, 'sapga', 30_000_000)]


def test_resample_takes_the_value_in_force_at_each_step():
    """A logged curve is read as a step function of the step count."""
    got = resample([10, 20, 30], [1.0, 2.0, 3.0], np.array([5, 10, 25, 40]))
    assert np.isnan(got[0]) and got[1:].tolist() == [1.0, 2.0, 3.0]


def test_summary_statistics_are_those_of_the_runs(tmp_path):
    """Means, deviations and the achieved count are computed from the seeds' own logs, and
    the figures are written."""
    summaries = run_experiments('table2', tmp_path, only=[2], seeds=2, scale=0.02,
                                workers=1, log=lambda *a: None)
    runs = json.loads((tmp_path / 'runs.json').read_text())['2']
    final = summaries[0]['final']
    values = [r['final']['best_value'] for r in runs]
    assert final['best_value_mean'] == pytest.approx(np.mean(values))
    assert final['best_value_std'] == pytest.approx(np.std(values))
    assert final['runs'] == 2 and [r['seed'] for r in runs] == [0, 1]
    grid = np.array(summaries[0]['grid'])
    at_end = [resample(r['steps'], r['best_value'], grid[-1:])[0] for r in runs]
    assert summaries[0]['best_value']['mean'][-1] == pytest.approx(np.mean(at_end))
    assert (tmp_path / 'acrobot.png').stat().st_size > 10_000
    json.loads((tmp_path / 'summary.json').read_text())  # strict JSON: no NaN literals


def test_unknown_experiment_set_or_id_is_refused(tmp_path):
    """Unknown names and ids are errors naming what exists."""
    with pytest.raises(ConfigError, match='known: table2'):
        run_experiments('table9', tmp_path)
    with pytest.raises(ConfigError, match=r'no experiment \[7\]'):
        run_experiments('table2', tmp_path, only=[7])
