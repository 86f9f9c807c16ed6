"""The Table 2 experiment runner (SPEC 3.5) on a tiny budget."""
import json

import numpy as np
import pytest

from sapga_ros.errors import ConfigError
from sapga_ros.training.experiment_report import resample
from sapga_ros.training.experiment_set import load_experiments
from sapga_ros.training.experiments import run_experiments
from sapga_ros.viz.summary_plot import plot_summaries
from sim_nodes.problem import load_problem


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
    assert plot_summaries(summaries, tmp_path) == [tmp_path / 'acrobot.png']
    assert (tmp_path / 'acrobot.png').stat().st_size > 10_000
    json.loads((tmp_path / 'summary.json').read_text())  # strict JSON: no NaN literals


def wilson(k: int, n: int, z: float = 1.959963984540054) -> list[float]:
    """The Wilson score interval, written out."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return [centre - half, centre + half]


def test_runs_carry_the_returned_policys_own_episode_beside_the_runs_bests(tmp_path):
    """Each run file holds the returned policy's own value, delta*, whether it reaches
    S_delta and its rail contacts, equal to an episode of the stored policy run here; the
    summary averages them and gives Wilson intervals for the counts; the tables show them."""
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.policies.runnable import policy_from_document
    from sapga_ros.training.experiment_report import markdown_table
    from sapga_ros.viz.report import table
    summaries = run_experiments('beyond', tmp_path, only=[2], seeds=3, scale=0.01,
                                workers=1, log=lambda *a: None)
    runs = json.loads((tmp_path / 'runs.json').read_text())['2']
    for r in runs:
        ep = Evaluator(load_problem('pdip'), 0.01).episode(
            policy_from_document(r['policy'], 'pdip', 'test'))
        f = r['final']
        assert (f['policy_value'], f['policy_delta_star'], f['policy_reached'],
                f['policy_rail_contacts']) == (ep.ret, ep.delta_star, ep.reached, ep.contacts)
        assert f['best_value'] >= f['policy_value']          # the run's best over episodes
        assert f['delta_star'] <= f['policy_delta_star']
    final = summaries[0]['final']
    assert final['policy_value_mean'] == pytest.approx(
        np.mean([r['final']['policy_value'] for r in runs]))
    assert final['policy_reached'] == sum(r['final']['policy_reached'] for r in runs)
    assert final['policy_rail_runs'] == sum(r['final']['policy_rail_contacts'] > 0
                                            for r in runs)
    assert final['achieved_ci95'] == pytest.approx(wilson(final['achieved'], 3))
    assert final['policy_reached_ci95'] == pytest.approx(wilson(final['policy_reached'], 3))
    assert wilson(14, 20) == pytest.approx([0.4810, 0.8545], abs=1e-4)
    low, high = final['achieved_ci95']
    assert f"{final['achieved']}/3 [{low:.2f}, {high:.2f}]" in markdown_table(summaries)
    assert f"{final['policy_value_mean']:.1f} ± " in '\n'.join(table(summaries))


def test_unknown_experiment_set_or_id_is_refused(tmp_path):
    """Unknown names and ids are errors naming what exists."""
    with pytest.raises(ConfigError, match='known: .*table2'):
        run_experiments('table9', tmp_path)
    with pytest.raises(ConfigError, match=r'no experiment \[7\]'):
        run_experiments('table2', tmp_path, only=[7])


def test_each_run_is_written_when_it_finishes_and_a_rerun_resumes(tmp_path):
    """Every (experiment, seed) run lands in runs/ as it finishes; a second call with the same
    --out runs nothing again and gives the same summary; a lost run is redone alone."""
    quiet = {'seeds': 2, 'scale': 0.01, 'workers': 2, 'log': lambda *a: None}
    first = run_experiments('styles', tmp_path, only=[1, 11], **quiet)
    files = sorted(p.name for p in (tmp_path / 'runs').iterdir())
    assert files == ['1-seed0.json', '1-seed1.json', '11-seed0.json', '11-seed1.json']
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / 'runs').iterdir()}
    (tmp_path / 'runs' / '11-seed1.json').unlink()     # as if killed before it finished
    lines = []
    again = run_experiments('styles', tmp_path, only=[1, 11], **{**quiet, 'log': lines.append})
    assert '3 runs done before, 1 to run' in lines[0]
    for path, stamp in stamps.items():
        if path.name != '11-seed1.json':
            assert path.stat().st_mtime_ns == stamp      # not redone
    strip = [{k: v for k, v in s.items() if k != 'timing'} for s in first]
    assert [{k: v for k, v in s.items() if k != 'timing'} for s in again] == strip


def test_runs_of_other_settings_are_refused_not_mixed(tmp_path):
    """An --out holding runs of another budget is an error naming the file."""
    run_experiments('styles', tmp_path, only=[11], seeds=1, scale=0.01, workers=1,
                    log=lambda *a: None)
    with pytest.raises(ConfigError, match=r'11-seed0.json: a run of other settings'):
        run_experiments('styles', tmp_path, only=[11], seeds=1, scale=0.02, workers=1,
                        log=lambda *a: None)


@pytest.mark.parametrize('body,message', [
    ('seeds: 0', r'seeds: expected a whole number in \[1,'),
    ('seeds: -3', r'seeds: expected a whole number'),
    ('seeds: .inf', r'seeds: expected a whole number'),
    ('experiments: [{id: 1, problem: acrobot, delta: 0.1, method: ql, steps: .inf}]',
     r'experiments\[0\].steps: expected a whole number'),
    ('experiments: [{id: 1, problem: acrobot, delta: .nan, method: ql, steps: 10}]',
     r'experiments\[0\].delta: expected a number in \[0, 1e9\], got nan'),
    ('experiments: [{id: 1, problem: nope, delta: 0.1, method: ql, steps: 10}]', 'nope'),
    ('experiments: [{id: 1, problem: acrobot, delta: 0.1, method: ga, steps: 10}]',
     r'method: expected one of sapga, ql, cmaes'),
    ('experiments: ' + '[' * 200 + ']' * 200, 'nested deeper'),
    ('experiments: 3', 'non-empty experiments list'),
])
def test_hostile_experiment_sets_are_one_line_errors(tmp_path, monkeypatch, body, message):
    """Bad numbers, unknown names, deep nesting: a ConfigError naming the field."""
    import shutil
    from sim_nodes.problem import config_dir
    conf = tmp_path / 'conf'
    shutil.copytree(config_dir(), conf)
    doc = 'name: bad\nseeds: 2\nexperiments: [{id: 1, problem: acrobot, delta: 0.1, ' \
          'method: ql, steps: 10}]\n'
    key = body.split(':')[0]
    lines = [line for line in doc.splitlines() if not line.startswith(key + ':')]
    (conf / 'experiments' / 'bad.yaml').write_text('\n'.join(lines + [body]) + '\n')
    monkeypatch.setenv('SAPGA_CONFIG_DIR', str(conf))
    with pytest.raises(ConfigError, match=message):
        load_experiments('bad')


@pytest.mark.parametrize('name', ['../x', '/etc/passwd', 'table2/../table2', '', 'a' * 300])
def test_experiment_set_names_are_names_not_paths(name):
    """A name that is a path (or not a known set) never reads a file outside the sets."""
    with pytest.raises(ConfigError, match='unknown experiment set'):
        load_experiments(name)


@pytest.mark.long
def test_the_ray_backend_gives_the_local_backends_summaries(tmp_path):
    """On a local Ray instance the runs are the same runs: summaries identical to local,
    for SAP-GA and mountain-car rows, and for a Q-learning row whose seeds learn side by
    side in one Ray task (one worker) while they ran alone locally (two workers).  One Ray
    instance serves both (the engine uses a running one): starting Ray is most of the cost."""
    import ray
    quiet = {'only': [1, 11], 'seeds': 2, 'scale': 0.005, 'workers': 2, 'log': lambda *a: None}
    ql = {'only': [3], 'seeds': 2, 'scale': 0.003, 'log': lambda *a: None}
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        local = run_experiments('styles', tmp_path / 'local', **quiet)
        on_ray = run_experiments('styles', tmp_path / 'ray', backend='ray', **quiet)
        ql_local = run_experiments('table2', tmp_path / 'ql-local', workers=2, **ql)
        ql_ray = run_experiments('table2', tmp_path / 'ql-ray', backend='ray', workers=1, **ql)
    finally:
        ray.shutdown()

    def strip(summaries: list[dict]) -> list[dict]:
        return [{k: v for k, v in s.items() if k != 'timing'} for s in summaries]
    assert strip(on_ray) == strip(local)
    assert sorted(p.name for p in (tmp_path / 'ray' / 'runs').iterdir()) == sorted(
        p.name for p in (tmp_path / 'local' / 'runs').iterdir())
    assert strip(ql_ray) == strip(ql_local)
    lanes = [json.loads((tmp_path / d / 'runs' / '3-seed1.json').read_text())['run']['lanes']
             for d in ('ql-local', 'ql-ray')]
    assert lanes == [1, 2]


def test_table2_writes_a_report_that_report_rewrites(tmp_path, capsys):
    """`sapga experiment table2` ends with report.md: the paper's claim beside each row, the
    physical limits, Figures 3-7; `sapga experiment report DIR` writes it again from the
    directory alone."""
    from sapga_ros.cli import main as cli
    out = tmp_path / 't2'
    assert cli.main(['experiment', 'table2', '--out', str(out), '--seeds', '2',
                     '--scale', '0.005', '--workers', '1']) == 0
    report = (out / 'report.md').read_text()
    assert '| #4 | pdip, δ = 0.01 | SAP-GA |' in report and 'reaches δ' in report
    assert report.count('| pdip | ') == 2 and '## Physical limits' in report
    for figure in ('acrobot.png', 'pdip.png', 'figure5_mountain_car.png',
                   'figure6_acrobot.png', 'figure7_pdip.png'):
        assert f']({figure})' in report and (out / figure).stat().st_size > 10_000
    info = json.loads((out / 'experiment.json').read_text())
    assert info['runs_run'] == 8 and info['command'].startswith('sapga experiment table2')
    (out / 'report.md').unlink()
    capsys.readouterr()
    assert cli.main(['experiment', 'report', str(out)]) == 0
    assert (out / 'report.md').read_text() == report
    assert cli.main(['experiment', 'report', str(tmp_path)]) == 2
    assert 'no summary.json' in capsys.readouterr().err


def test_sapga_limit_reports_and_writes_its_sequence(tmp_path, capsys):
    """`sapga limit` prints the smallest delta found and writes the action sequence."""
    from sapga_ros.cli import main as cli
    capsys.readouterr()
    assert cli.main(['limit', '--problem', 'pdip', '--width', '300', '--json', '--out',
                     str(tmp_path / 'l.json')]) == 0
    shown = json.loads(capsys.readouterr().out)
    stored = json.loads((tmp_path / 'l.json').read_text())
    assert shown['delta'] == stored['delta'] and len(stored['actions']) == stored['step']
    assert cli.main(['limit', '--problem', 'acrobot', '--alternative-goal']) == 2
    capsys.readouterr()
    assert cli.main(['limit', '--replay', str(tmp_path / 'l.json'), '--json']) == 0
    [replayed] = json.loads(capsys.readouterr().out)
    readings = {r['reading']: r for r in replayed['readings']}
    assert replayed['searched_under'] == 'printed' and set(readings) == {'printed',
                                                                         'alternative'}
    assert (readings['printed']['delta'], readings['printed']['step']) == \
        (stored['delta'], stored['step'])
    assert readings['alternative']['delta'] <= stored['delta']
    assert readings['printed']['rail_contacts'] == len(readings['printed']['contact_steps'])
    assert cli.main(['limit', '--replay', str(tmp_path / 'l.json'), '--problem', 'pdip']) == 2
    assert cli.main(['limit', '--problem', 'pdip', '--alternative-goal', '--width', '300',
                     '--out', str(tmp_path / 'a.json')]) == 0
    capsys.readouterr()
    assert cli.main(['limit', '--replay', str(tmp_path / 'a.json'), '--json']) == 0
    assert json.loads(capsys.readouterr().out)[0]['searched_under'] == 'alternative'
    assert cli.main(['limit']) == 2
    assert cli.main(['limit', '--replay', str(tmp_path / 'none.json')]) == 2
    assert 'none.json' in capsys.readouterr().err


def test_q_learning_seeds_run_side_by_side_equal_their_runs_alone(tmp_path):
    """With one worker a Q-learning row's seeds learn side by side in one job; with as many
    workers as seeds each runs alone.  The run files are the same but for timing."""
    quiet = {'only': [1, 3], 'seeds': 3, 'scale': 0.002, 'log': lambda *a: None}
    run_experiments('table2', tmp_path / 'lanes', workers=1, **quiet)
    run_experiments('table2', tmp_path / 'alone', workers=3, **quiet)
    for row in (1, 3):
        for seed in range(3):
            name = f'runs/{row}-seed{seed}.json'
            lanes = json.loads((tmp_path / 'lanes' / name).read_text())
            alone = json.loads((tmp_path / 'alone' / name).read_text())
            assert (lanes['run'].pop('lanes'), alone['run'].pop('lanes')) == (3, 1)
            for doc in (lanes, alone):
                del doc['run']['seconds'], doc['run']['final']['steps_per_s']
            assert lanes == alone
            assert len(lanes['run']['steps']) > 0


def test_jobs_group_q_learning_seeds_into_lanes_and_run_longest_first():
    """Every pending run is in exactly one job; a Q-learning row's seeds make groups of at
    most LANE_BLOCK, at least one per worker while seeds last; other runs are jobs alone."""
    from sapga_ros.optim.qlearner import LANE_BLOCK
    from sapga_ros.training.experiments import plan_jobs
    exps = {e.id: e for e in load_experiments('table2')[0]}
    pending = [(exps[i], s, exps[i].steps) for i in (1, 2, 3, 4) for s in range(20)]
    for workers in (1, 2, 5, 64):
        jobs = plan_jobs(pending, workers)
        runs = sorted((e.id, s) for e, seeds, _ in jobs for s in seeds)
        assert runs == sorted((e.id, s) for e, s, _ in pending)
        for exp, seeds, budget in jobs:
            if exp.method == 'ql':
                assert 1 <= len(seeds) <= LANE_BLOCK
            else:
                assert len(seeds) == 1
        groups = [len(seeds) for e, seeds, _ in jobs if e.id == 1]
        assert len(groups) == max(-(-20 // LANE_BLOCK), min(20, workers))
        assert max(groups) - min(groups) <= 1
        costs = [budget * len(seeds) for _, seeds, budget in jobs]
        assert costs == sorted(costs, reverse=True)


def test_limit_searches_are_jobs_between_the_seed_groups_and_the_single_runs():
    """Each pending limit search is one job (search, (), width), after every job of several
    seeds and before every single run; the runs keep their order."""
    from sapga_ros.training.experiment_set import load_limits
    from sapga_ros.training.experiments import plan_jobs
    exps = {e.id: e for e in load_experiments('table2')[0]}
    searches = [(s, 300 + i) for i, s in enumerate(load_limits('table2'))]
    assert len(searches) == 3
    pending = [(exps[i], s, exps[i].steps) for i in (1, 2, 3, 4) for s in range(20)]
    for workers in (1, 2, 5):
        runs_only = plan_jobs(pending, workers)
        jobs = plan_jobs(pending, workers, searches)
        kinds = ['limit' if not seeds else ('group' if len(seeds) > 1 else 'single')
                 for _, seeds, _ in jobs]
        assert kinds == sorted(kinds, key=['group', 'limit', 'single'].index)
        assert [(search, width) for search, seeds, width in jobs if not seeds] == searches
        assert [job for job in jobs if job[1]] == runs_only
