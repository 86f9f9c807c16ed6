"""The experiment report of a hold set: the hold table and figures, and the robustness
curves (each row's returned policies against each disturbance profile's size, with an
interval over the seeds)."""
import json

import pytest

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.runnable import policy_from_document
from sapga_ros.training.experiments import run_experiments
from sapga_ros.training.run_files import read_run, run_path
from sapga_ros.viz.report import write_report
from sapga_ros.viz.report_robustness import CurveSettings
from sim_nodes.goal import hold_measures


@pytest.fixture(scope='module')
def hold_dir(tmp_path_factory):
    """Rows 1 (SAP-GA) and 5 (classical) of the hold set, 2 seeds, a tiny budget."""
    out = tmp_path_factory.mktemp('report') / 'hold'
    run_experiments('hold', out, only=[1, 5], seeds=2, scale=0.0002, workers=1,
                    log=lambda _: None)
    return out


def test_report_has_the_hold_table_and_figures_of_the_runs(hold_dir):
    out = hold_dir
    report = write_report(out, with_figure5=False).read_text()
    for e in (1, 5):
        finals = [read_run(run_path(out, e, seed), seed)[1]['final'] for seed in (0, 1)]
        holding = sum(f['hold_fraction'] >= 0.95 for f in finals)
        row = next(line for line in report.split('\n') if line.startswith(f'| {e} | acrobot'))
        assert f'| {holding}/2 |' in row, row
        values = [f['policy_value'] for f in finals]
        mean, std = sum(values) / 2, abs(values[0] - values[1]) / 2
        assert row.endswith(f'| {mean:.1f} ± {std:.1f} |'), row
    assert '## Hold' in report and '| 5 | acrobot_hold | classical | 1.000 ± 0.000 |' in report
    for name in ('hold_fraction.png', 'hold_episodes.png'):
        assert f']({name})' in report and (out / name).stat().st_size > 5000


def test_report_draws_each_rows_curves_from_its_returned_policies(hold_dir, capsys):
    out = hold_dir
    settings = CurveSettings(('push', 'latency'), (0.0, 4.0), 3)
    report = write_report(out, with_figure5=False, curves=settings).read_text()
    doc = json.loads((out / 'robustness.json').read_text())
    points = doc['points']
    # rows x seeds x profiles x sizes, each point a policy's held-out episodes
    assert len(points) == 2 * 2 * 2 * 2
    assert {(p['experiment'], p['run_seed'], p['disturbance'], p['scale']) for p in points} == {
        (e, s, d, x) for e in (1, 5) for s in (0, 1) for d in ('push', 'latency')
        for x in (0.0, 4.0)}
    assert all(p['episodes'] == 3 for p in points)
    # size 0 is the undisturbed plant: the returned policy's own episode decides success
    for e, seed in ((1, 0), (5, 1)):
        doc_policy = read_run(run_path(out, e, seed), seed)[1]['policy']
        policy = policy_from_document(doc_policy, 'acrobot_hold')
        ep = Evaluator(policy.problem, 0.02).episode(policy)
        hold = hold_measures(ep.first_entry, ep.held, ep.steps, ep.contacts)['hold_fraction']
        at0 = [p for p in points
               if (p['experiment'], p['run_seed'], p['scale']) == (e, seed, 0.0)]
        assert all(p['success_rate'] == float(hold >= 0.9) for p in at0)
    assert '## Robustness' in report and '| #5 classical (acrobot_hold) | 2 | 1.00' in report
    for name in ('robustness_push.png', 'robustness_latency.png'):
        assert f']({name})' in report and (out / name).stat().st_size > 1000

    from sapga_ros.cli import main as cli
    capsys.readouterr()
    assert cli.main(['experiment', 'report', str(out), '--robustness', 'gust']) == 2
    err = capsys.readouterr().err
    assert "unknown disturbance 'gust'" in err and err.count('\n') == 1


def test_report_curves_re_planned_are_sapga_eval_replan_of_each_returned_policy(
        tmp_path, capsys):
    """``--robustness-replan``: each point is the re-planned sweep of the row's returned
    policy (the planner predicting for the point's latency), Q-learning rows are left out
    with the reason, and a planner setting without the option is refused."""
    from sapga_ros.cli import main as cli
    from sapga_ros.evaluation.replan_settings import ReplanSettings
    from sapga_ros.evaluation.sweep import sweep
    from sim_nodes.disturbance import load_disturbance

    out = tmp_path / 't2'
    run_experiments('table2', out, only=[1, 2], seeds=1, scale=0.0002, workers=1,
                    log=lambda _: None)
    replan = ReplanSettings(replan_rounds=2, replan_fit=0.05, replan_filter=0.002)
    settings = CurveSettings(('field',), (0.0, 1.0), 2, replan=replan, jobs=2)
    report = write_report(out, with_figure5=False, curves=settings).read_text()
    doc = json.loads((out / 'robustness.json').read_text())
    assert doc['settings']['replan']['replan_fit'] == 0.05 and 'jobs' not in doc['settings']
    policy = policy_from_document(read_run(run_path(out, 2, 0), 0)[1]['policy'], 'acrobot')
    want = sweep(policy, 0.02, load_disturbance('field'), (0.0, 1.0), 2, 0, replan, 0, 1)
    got = [p for p in doc['points'] if p['experiment'] == 2]
    assert [{k: p[k] for k in w} for p, w in zip(got, want)] == want
    assert 'Re-planned as they run' in report and '#1 (Q-learning' in report
    assert 'Kalman-filtered state (sensor sigma 0.002)' in report
    assert doc['settings']['replan']['replan_filter'] == 0.002

    capsys.readouterr()
    for args in (['--robustness', 'field', '--replan-fit', '0.05'],
                 ['--robustness-replan']):
        assert cli.main(['experiment', 'report', str(out), *args]) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and 'setting of --r' in err, err
