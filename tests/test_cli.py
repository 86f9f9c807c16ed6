"""The ``sapga`` command as a user runs it: a real subprocess per call."""
import json
import os
import re
import subprocess
import sys

import pytest

from process_helpers import sapga_in_process

SAPGA = [sys.executable, '-m', 'sapga_ros.cli.main']


def sapga(*args, cwd=None):
    return subprocess.run([*SAPGA, *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ}, timeout=300)


@pytest.fixture(scope='module')
def trained(tmp_path_factory):
    """A policy trained by the CLI on the acrobot with delta 0.02 (5 M steps)."""
    out = tmp_path_factory.mktemp('train') / 'acro.json'
    r = sapga('train', '--problem', 'acrobot', '--delta', '0.02', '--steps', '5000000',
              '--seed', '0', '--out', out, '--quiet')
    assert r.returncode == 0, r.stderr
    return out, r


def test_train_achieves_delta_and_writes_policy_and_log(trained):
    """SAP-GA on the acrobot reaches delta* <= 0.02 within 5 M steps with seed 0, and
    writes the policy document and a CSV log of (steps, best value, delta*)."""
    out, r = trained
    doc = json.loads(out.read_text())
    assert doc['format'] == 'sapga-policy/1' and doc['problem'] == 'acrobot'
    assert doc['meta']['run_delta_star'] <= 0.02
    log = out.with_suffix('.log.csv').read_text().splitlines()
    assert log[0].startswith('generation,steps,best_value,delta_star')
    assert len(log) > 5
    assert 'achieved delta 0.02' in r.stdout


def test_eval_json_reproduces_the_training_value(trained):
    """``sapga eval --json`` prints return, delta_star, steps, reached equal to what the
    trainer recorded for the policy, the hold measures (an episode ending in S_delta enters
    it at its last step) and the delay its selector is designed for."""
    out, _ = trained
    r = sapga('eval', out, '--json')
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    meta = json.loads(out.read_text())['meta']
    assert set(got) == {'return', 'delta_star', 'steps', 'reached', 'first_entry_step',
                        'hold_fraction', 'rail_contacts', 'delay'}
    assert got['delay'] == 0                # acting on the state it sees
    assert got['return'] == meta['value'] and got['steps'] == meta['steps_to_end']
    assert got['reached'] is True
    assert (got['first_entry_step'], got['hold_fraction'], got['rail_contacts']) == \
        (got['steps'], 1.0, 0)


def test_eval_replan(trained):
    """``sapga eval --replan``: on the exact model the re-planned episode enters S_delta no
    later than the policy's own; disturbed, the same JSON for any --jobs; its settings are
    refused without --replan, and out of range, with one line and exit 2 (the first call a
    real process, the others in this one)."""
    out, _ = trained
    meta = json.loads(out.read_text())['meta']
    r = sapga('eval', out, '--replan', '--json', '--replan-rounds', '3')
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert got['success_rate'] == 1.0 and got['disturbance'] == 'none'
    assert got['episodes'] == 1 and got['delay'] == 0
    assert got['return']['max'] >= meta['value']
    assert got['replan'] == {'rounds': 3, 'window': 150, 'every': 1, 'seed': 0, 'fit': 0.0,
                             'filter': 0.0}
    runs = [sapga_in_process(['eval', out, '--replan', '--disturbance', 'field', '--episodes',
                              '3', '--delay', '1', '--replan-rounds', '2', '--replan-every',
                              '4', '--replan-fit', '0.05', '--replan-filter', '0.002',
                              '--json', '--jobs', jobs])
            for jobs in (1, 2)]
    assert all(r.returncode == 0 for r in runs), runs[0].stderr
    assert runs[0].stdout == runs[1].stdout
    disturbed = json.loads(runs[0].stdout)
    assert (disturbed['disturbance'], disturbed['episodes'], disturbed['delay'],
            disturbed['replan']['fit'], disturbed['replan']['filter']) == \
        ('field', 3, 1, 0.05, 0.002)
    for args, text in ((['--replan-rounds', '3'], '--replan-rounds is a setting of --replan'),
                       (['--jobs', '2'], '--jobs is a setting of --replan'),
                       (['--replan', '--replan-every', '0'], 'replan_every: expected'),
                       (['--replan', '--replan-fit', '2'], 'replan_fit: expected'),
                       (['--replan', '--replan-filter', 'nan'], 'replan_filter: expected')):
        r = sapga_in_process(['eval', out, *args])
        assert r.returncode == 2 and text in r.stderr, r.stderr
        assert 'Traceback' not in r.stderr


def test_robustness_curves_replanned(trained, tmp_path):
    """``sapga robustness --replan``: each point is what ``sapga eval --replan`` gives on the
    same draws, the planner predicting for that point's latency (0 undisturbed, 1 under
    field); the planner's settings are refused without --replan."""
    out, _ = trained
    curves = tmp_path / 'curves'
    planner = ['--replan-rounds', '2', '--replan-every', '4', '--replan-fit', '0.05']
    r = sapga_in_process(['robustness', out, '--out', curves, '--disturbance', 'field',
                          '--scales', '0,1', '--episodes', '2', '--replan', *planner])
    assert r.returncode == 0, r.stderr
    rows = json.loads((curves / 'robustness.json').read_text())
    assert [(row['scale'], row['delay']) for row in rows] == [(0, 0), (1, 1)]
    assert rows[0]['success_rate'] == 1.0
    for row, args in ((rows[0], ['--disturbance', 'none']),
                      (rows[1], ['--disturbance', 'field', '--delay', '1'])):
        e = sapga_in_process(['eval', out, '--replan', '--json', '--episodes', '2', *args,
                              *planner])
        assert e.returncode == 0, e.stderr
        alone = json.loads(e.stdout)
        assert {k: v for k, v in row.items() if k not in ('scale', 'policy', 'disturbance')} \
            == {k: v for k, v in alone.items() if k != 'disturbance'}
    assert (curves / 'field.png').stat().st_size > 1000
    r = sapga_in_process(['robustness', out, '--replan-fit', '0.05', '--out', tmp_path / 'no'])
    assert r.returncode == 2 and '--replan-fit is a setting of --replan' in r.stderr, r.stderr
    assert not (tmp_path / 'no').exists()


def test_eval_max_steps_and_delta_options(trained):
    """--max-steps caps the episode and --delta 0 never ends it early."""
    out, _ = trained
    got = json.loads(sapga('eval', out, '--json', '--delta', '0', '--max-steps', '50').stdout)
    assert got['steps'] == 50 and got['reached'] is False


def test_exemplars_lists_plots_and_prunes(trained, tmp_path):
    """``sapga exemplars`` lists referral counts, draws a PNG and writes a pruned policy
    that behaves exactly like the original."""
    out, _ = trained
    png, pruned = tmp_path / 'ex.png', tmp_path / 'pruned.json'
    r = sapga('exemplars', out, '--json', '--plot', png, '--prune-unused', pruned)
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)
    used = [row for row in rows if row['uses'] > 0]
    assert 0 < len(used) < len(rows)
    assert png.stat().st_size > 10_000
    a = json.loads(sapga('eval', out, '--json').stdout)
    b = json.loads(sapga('eval', pruned, '--json').stdout)
    assert a == b


def test_exemplars_plot_finite_extremes_without_a_warning(tmp_path):
    """Exemplar states at the ends of the float range (1e308, 5e-324) are finite, so the
    policy is accepted; its plot is drawn and stderr holds only the plot's own line."""
    doc = {'format': 'sapga-policy/1', 'problem': 'acrobot', 'style': 'state-action',
           'state_names': ['theta1', 'theta2', 'theta1_dot', 'theta2_dot'],
           'actions': [-2.0, 0.0, 2.0],
           'exemplars': [{'state': [1e308, -1e308, 5e-324, 1e308], 'action': 2.0},
                         {'state': [-1e308, 5e-324, -1e308, -5e-324], 'action': -2.0},
                         {'state': [5e-324] * 4, 'action': 0.0}]}
    policy, png = tmp_path / 'extreme.json', tmp_path / 'extreme.png'
    policy.write_text(json.dumps(doc))
    r = sapga('exemplars', policy, '--plot', png)
    assert r.returncode == 0, r.stderr
    assert r.stderr.splitlines() == [f'plot: {png}'], r.stderr
    assert png.stat().st_size > 10_000


def test_ql_training_writes_an_evaluable_table(tmp_path):
    """``--method ql`` writes a sapga-qtable/1 file that ``sapga eval`` runs."""
    out = tmp_path / 'q.json'
    r = sapga('train', '--problem', 'pdip_single', '--method', 'ql', '--steps', '200000',
              '--delta', '0.01', '--out', out, '--quiet')
    assert r.returncode == 0, r.stderr
    got = json.loads(sapga('eval', out, '--json').stdout)
    assert got['return'] == json.loads(out.read_text())['meta']['value']


@pytest.mark.parametrize('args, needle', [
    (['train', '--problem', 'nope'], "unknown problem 'nope'"),
    (['train', '--problem', 'acrobot', '--steps', '-5'], 'positive integer'),
    (['train', '--problem', 'acrobot', '--delta', 'nan'],
     'delta: expected a number in [0, 1e9], got nan'),
    (['eval', 'missing.json'], 'cannot read'),
    (['train', '--problem', 'acrobot', '--resume'], 'no checkpoint to resume from'),
    (['train', '--resume'], '--resume needs --checkpoint DIR'),
])
def test_user_errors_print_one_line_and_exit_nonzero(args, needle, tmp_path):
    """Bad options print one clear line naming the problem, no traceback, status 2."""
    r = sapga(*args, cwd=tmp_path)
    assert r.returncode == 2
    assert needle in r.stderr
    assert 'Traceback' not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if 'error' in ln]) == 1


@pytest.mark.parametrize('content, needle', [
    ('{"format": "sapga-policy/1", "problem": "acrobot", "style": "state-action", '
     '"state_names": ["theta1", "theta2", "theta1_dot", "theta2_dot"], '
     '"actions": [-2.0, 0.0, 2.0], "exemplars": [{"state": [NaN, 0, 0, 0], "action": 2.0}]}',
     'NaN'),
    ('{"format": "sapga-policy/1", "problem": "acrobot", "style": "state-action", '
     '"state_names": ["theta1", "theta2", "theta1_dot", "theta2_dot"], '
     '"actions": [-2.0, 0.0, 2.0], "exemplars": [{"state": [0, 0, 0], "action": 2.0}]}',
     'exemplars[0].state: expected 4 numbers'),
    ('{"format": "sapga-policy/1", "problem": "acrobot"', 'malformed JSON'),
])
def test_bad_policy_files_are_refused_by_eval(content, needle, tmp_path):
    """``sapga eval`` refuses hostile policy files with the field named."""
    path = tmp_path / 'bad.json'
    path.write_text(content)
    r = sapga('eval', path)
    assert r.returncode == 2 and needle in r.stderr and 'Traceback' not in r.stderr


def test_bench_json_reports_rates_and_ratio():
    """``sapga bench --json`` prints the per-core rates and the ratios to the NumPy loop and
    to the straightforward numba kernel as numbers."""
    r = sapga('bench', '--json')
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    for key in ('acrobot_steps_per_s_per_core', 'pdip_steps_per_s_per_core',
                'speedup_vs_numpy', 'numba_steps_per_s', 'speedup_vs_numba'):
        assert got[key] > 0
    assert got['speedup_vs_numba'] == pytest.approx(
        got['acrobot_steps_per_s_per_core'] / got['numba_steps_per_s'])


def test_bench_yardstick_runs_the_same_episodes():
    """The straightforward numba kernel the bench compares with runs the episodes the batch
    kernel runs (to rounding: it uses libm's sin and cos)."""
    import numpy as np

    from sapga_ros.bench.straightforward import acrobot_arguments, episodes
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.optim.operators import random_exemplars
    from sim_nodes.problem import load_problem
    problem = load_problem('acrobot')
    rng = np.random.default_rng(3)
    policies = [random_exemplars(problem, 30, rng) for _ in range(4)]
    returns, steps = episodes(*acrobot_arguments(problem, policies))
    batch = Evaluator(problem, delta=0.0).evaluate(policies)
    assert steps == int(batch.steps.sum()) == 4 * problem.n_step
    assert returns == pytest.approx(batch.returns, rel=1e-9)


def test_training_bench_measures_whole_runs_alone_and_side_by_side():
    """``sapga_ros.bench.training`` (``sapga bench --training``) reports positive rates of
    SAP-GA runs and of Q-learning alone and side by side, and their ratio."""
    from sapga_ros.bench.training import QL_ROWS, SAPGA_ROWS, run_training_bench
    d = run_training_bench(steps=60_000, lanes=3)
    assert d['lanes'] == 3
    for problem, _ in SAPGA_ROWS:
        assert d[f'sapga_{problem}_steps_per_s'] > 0
    for problem, _ in QL_ROWS:
        alone, lanes = d[f'ql_{problem}_alone_steps_per_s'], d[f'ql_{problem}_lanes_steps_per_s']
        assert alone > 0 and lanes > 0
        assert d[f'ql_{problem}_lanes_speedup'] == pytest.approx(lanes / alone)


@pytest.mark.parametrize('steps', ['5', '1e12', 'abc', 'nan'])
def test_training_bench_refuses_run_lengths_out_of_range(steps):
    r = sapga('bench', '--training', '--steps', steps)
    last = r.stderr.strip().splitlines()[-1]                  # the usage, then one line
    assert r.returncode == 2 and 'Traceback' not in r.stderr
    assert '--steps' in last and 'expected an integer in [20000, 1000000000]' in last, last


def test_experiment_help_names_every_shipped_set():
    from sim_nodes.problem import config_dir
    r = sapga('experiment', '--help')
    assert r.returncode == 0, r.stderr
    text = ' '.join(r.stdout.split())
    sets = sorted(p.stem for p in (config_dir() / 'experiments').glob('*.yaml'))
    assert sets and all(re.search(rf'\b{name}\b', text) for name in sets), (sets, text)
