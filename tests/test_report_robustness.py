"""The experiment report's robustness curves: each row's returned policies against each
disturbance profile's size, with an interval over the seeds."""
import json

from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.runnable import policy_from_document
from sapga_ros.training.experiments import run_experiments
from sapga_ros.training.run_files import read_run, run_path
from sapga_ros.viz.report import write_report
from sapga_ros.viz.report_robustness import CurveSettings
from sim_nodes.goal import hold_measures


def test_report_draws_each_rows_curves_from_its_returned_policies(tmp_path, capsys):
    out = tmp_path / 'hold'
    run_experiments('hold', out, only=[1, 5], seeds=2, scale=0.0002, workers=1,
                    log=lambda _: None)
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
    assert '## Robustness' in report and '| #5 classical | 2 | 1.00' in report
    for name in ('robustness_push.png', 'robustness_latency.png'):
        assert f']({name})' in report and (out / name).stat().st_size > 1000

    from sapga_ros.cli import main as cli
    capsys.readouterr()
    assert cli.main(['experiment', 'report', str(out), '--robustness', 'gust']) == 2
    err = capsys.readouterr().err
    assert "unknown disturbance 'gust'" in err and err.count('\n') == 1
