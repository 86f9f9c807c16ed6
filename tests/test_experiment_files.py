"""The files of an experiment directory read as hostile input: run files, summary.json,
experiment.json, limits/*.json, the set YAML and the options.  Each bad file or value is
one line naming the file and the field (exit status 2 from the command), a damaged run
file is run again on resume, nothing is written outside the directory or through a link,
and every file written is strict JSON."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from process_helpers import sapga_in_process, sapga_peak_rss
from sapga_ros.training.experiments import run_experiments
from sapga_ros.training.run_files import MAX_RUN_BYTES

SAPGA = [sys.executable, '-m', 'sapga_ros.cli.main']
QUICK = {'only': [11], 'seeds': 2, 'scale': 0.005, 'workers': 1}   # mountain car, 150 k steps


def sapga(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``sapga ARGS`` in a fresh process: the tests of the Ray backend, and one test per
    subcommand (report, limit), the rest call ``main`` in process (``in_process``)."""
    import os
    return subprocess.run([*SAPGA, *args], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})})


def in_process(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return sapga_in_process(list(args), env=env)


def one_line_error(done: subprocess.CompletedProcess, *words: str) -> str:
    """The command failed with exit status 2 and one line naming ``words``."""
    assert done.returncode == 2, done.stderr
    assert 'Traceback' not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def strict(text: str):
    """``json.loads`` that refuses NaN and Infinity."""
    def refuse(name):
        raise ValueError(f'{name} in strict JSON')
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope='module')
def base(tmp_path_factory) -> Path:
    """An experiment directory of two quick mountain-car runs."""
    out = tmp_path_factory.mktemp('exp') / 'base'
    run_experiments('styles', out, log=lambda *a: None, **QUICK)
    return out


@pytest.fixture
def exp_dir(base, tmp_path) -> Path:
    out = tmp_path / 'exp'
    shutil.copytree(base, out)
    return out


def _run_doc(out: Path) -> dict:
    return json.loads((out / 'runs' / '11-seed0.json').read_text())


def _with_run(doc: dict, **changes) -> str:
    run = {**doc['run'], **changes}
    return json.dumps({'key': doc['key'], 'run': run})


DAMAGED = {
    'empty run': lambda d: json.dumps({'key': d['key'], 'run': {}}),
    'steps text': lambda d: _with_run(d, steps='abc'),
    'best value text': lambda d: _with_run(d, final={**d['run']['final'],
                                                     'best_value': 'high'}),
    'lengths differ': lambda d: _with_run(d, best_value=d['run']['best_value'] * 2),
    'nan': lambda d: _with_run(d, best_value=[float('nan')] * len(d['run']['steps'])),
    'infinity': lambda d: _with_run(d, final={**d['run']['final'],
                                              'delta_star': float('inf')}),
    'no key': lambda d: json.dumps({'run': d['run']}),
    'policy reached text': lambda d: _with_run(d, final={**d['run']['final'],
                                                         'policy_reached': 'yes'}),
    'negative rail contacts': lambda d: _with_run(d, final={**d['run']['final'],
                                                            'policy_rail_contacts': -1}),
    'value beyond the figures': lambda d: _with_run(
        d, best_value=[-1e308] * len(d['run']['steps'])),
    'returned delta* beyond the figures': lambda d: _with_run(
        d, final={**d['run']['final'], 'policy_delta_star': 1e308}),
    'not json': lambda d: '{"key": ',
    'values bomb': lambda d: '[' + '[],' * 2_000_000 + '[]]',
    'too large': lambda d: ' ' * (MAX_RUN_BYTES + 1),
}


@pytest.mark.parametrize('damage', DAMAGED)
def test_a_damaged_run_file_is_reported_and_run_again(exp_dir, damage):
    """Resume: one line names the file (and the field), the run is trained again, the new
    file equals what the seed gives, and the summaries hold no bare NaN."""
    before = _run_doc(exp_dir)
    path = exp_dir / 'runs' / '11-seed0.json'
    path.write_text(DAMAGED[damage](before))
    lines: list[str] = []
    run_experiments('styles', exp_dir, log=lines.append, **QUICK)
    reported = [line for line in lines if str(path) in line]
    assert len(reported) == 1 and reported[0].endswith('running it again'), lines
    assert '1 runs done before, 1 to run' in '\n'.join(lines)
    after = strict(path.read_text())
    assert after['run']['final']['best_value'] == before['run']['final']['best_value']
    assert after['run']['policy']['exemplars'] == before['run']['policy']['exemplars']
    for name in ('summary.json', 'runs.json', 'experiment.json'):
        strict((exp_dir / name).read_text())


def test_a_run_file_that_names_a_field_says_which(exp_dir):
    doc = _run_doc(exp_dir)
    (exp_dir / 'runs' / '11-seed1.json').write_text(_with_run(doc, seed=1, steps='abc'))
    lines: list[str] = []
    run_experiments('styles', exp_dir, log=lines.append, **QUICK)
    assert any('11-seed1.json: run.steps: expected a list' in line for line in lines), lines


def test_a_link_in_place_of_a_run_file_is_replaced_not_followed(exp_dir, tmp_path):
    """A planted link is not read as a run: the run is trained again and the link replaced
    by a file; the link's target is untouched."""
    target = tmp_path / 'elsewhere.json'
    original = (exp_dir / 'runs' / '11-seed0.json').read_text()
    target.write_text(original)
    path = exp_dir / 'runs' / '11-seed0.json'
    path.unlink()
    path.symlink_to(target)
    lines: list[str] = []
    run_experiments('styles', exp_dir, log=lines.append, **QUICK)
    assert any('a symbolic link' in line for line in lines)
    assert not path.is_symlink() and target.read_text() == original
    assert strict(path.read_text())['run']['seed'] == 0


SUMMARY_DAMAGE = {
    'not a list': ('{}', 'expected a list'),
    'empty object': ('[{}]', "missing field 'steps'"),
    'problem a path': (None, 'problem'),
    'grid lengths': (None, 'best_value.mean'),
    'string value': (None, 'final.best_value_mean'),
    'nan': (None, 'not valid JSON'),
    'deep': ('[' * 100_000 + ']' * 100_000, 'summary.json'),
    'huge': (' ' * (17 << 20), 'larger than'),
}


def _damaged_summary(out: Path, damage: str) -> str:
    text, _ = SUMMARY_DAMAGE[damage]
    if text is not None:
        return text
    doc = json.loads((out / 'summary.json').read_text())
    s = doc[0]
    if damage == 'problem a path':
        s['problem'] = str(out.parent / 'outside' / 'x')
    elif damage == 'grid lengths':
        s['best_value']['mean'] = s['best_value']['mean'][:-1]
    elif damage == 'string value':
        s['final']['best_value_mean'] = 'high'
    elif damage == 'nan':
        return json.dumps(doc).replace('"steps":', '"x": NaN, "steps":', 1)
    return json.dumps(doc)


@pytest.mark.parametrize('damage', SUMMARY_DAMAGE)
def test_a_damaged_summary_is_one_line_from_report(exp_dir, damage):
    (exp_dir / 'summary.json').write_text(_damaged_summary(exp_dir, damage))
    line = one_line_error(in_process('experiment', 'report', str(exp_dir)), 'summary.json',
                          SUMMARY_DAMAGE[damage][1])
    assert line.startswith('sapga experiment: error:')
    assert not (exp_dir / 'report.md').exists()
    assert not (exp_dir.parent / 'outside').exists()


def _curve(s: dict, key: str, mean: float, std: float) -> None:
    s[key] = {'mean': [mean] * len(s['grid']), 'std': [std] * len(s['grid'])}


def _final(s: dict, **changes) -> None:
    s['final'].update(changes)


def _drop(s: dict, *keys: str) -> None:
    for key in keys:
        s['final'].pop(key, None)


# Values the report cannot print or draw, and sets of measures left incomplete: each is
# one line naming summary.json and the field, before any figure is drawn.
SUMMARY_FIELDS = {
    'returned set without delta*': (
        lambda s: _drop(s, 'policy_delta_star_mean', 'policy_delta_star_std',
                        'policy_delta_star_ci95'), "missing field 'policy_delta_star_mean'"),
    'returned set without value': (
        lambda s: _drop(s, 'policy_value_mean', 'policy_value_std', 'policy_value_ci95'),
        "missing field 'policy_value_mean'"),
    'returned set without reached': (
        lambda s: _drop(s, 'policy_reached'), "missing field 'policy_reached'"),
    'hold set without fraction': (
        lambda s: _final(s, holding=0, holding_clean=0), "missing field 'hold_fraction_mean'"),
    'extreme delta* curve': (
        lambda s: _curve(s, 'delta_star', 1e308, 1e308), 'delta_star.mean[0]'),
    'negative delta* curve': (
        lambda s: _curve(s, 'delta_star', -1.0, 0.0), 'delta_star.mean[0]'),
    'extreme value curve': (
        lambda s: _curve(s, 'best_value', -1e308, 0.0), 'best_value.mean[0]'),
    'extreme value std': (
        lambda s: _curve(s, 'best_value', 0.0, 1e308), 'best_value.std[0]'),
    'negative std': (lambda s: _curve(s, 'best_value', 0.0, -1.0), 'best_value.std[0]'),
    'extreme grid': (lambda s: s.update(grid=[1e308] * len(s['grid'])), 'grid[0]'),
    'extreme final value': (lambda s: _final(s, best_value_mean=-1e308),
                            'final.best_value_mean'),
    'extreme final delta*': (lambda s: _final(s, delta_star_std=1e300),
                             'final.delta_star_std'),
    'extreme returned value': (lambda s: _final(s, policy_value_mean=1e308),
                               'final.policy_value_mean'),
    'extreme interval': (lambda s: _final(s, best_value_ci95=[-1e308, 0.0]),
                         'final.best_value_ci95[0]'),
    'interval upside down': (lambda s: _final(s, delta_star_ci95=[0.5, 0.1]),
                             'final.delta_star_ci95'),
    'more achieved than runs': (lambda s: _final(s, achieved=s['final']['runs'] + 1),
                                'final.achieved'),
    'extreme delta': (lambda s: s.update(delta=1e300), '.delta'),
    'unknown problem': (lambda s: s.update(problem='nope'), "problem: unknown problem 'nope'"),
}


@pytest.mark.parametrize('damage', SUMMARY_FIELDS)
def test_a_summary_field_the_report_cannot_use_is_one_line(exp_dir, damage):
    doc = json.loads((exp_dir / 'summary.json').read_text())
    assert 'policy_value_mean' in doc[0]['final']          # the run set the returned measures
    change, word = SUMMARY_FIELDS[damage]
    change(doc[0])
    (exp_dir / 'summary.json').write_text(json.dumps(doc))
    one_line_error(in_process('experiment', 'report', str(exp_dir)), 'summary.json', word)
    assert not (exp_dir / 'report.md').exists()


def test_the_largest_accepted_values_draw_without_a_warning(exp_dir):
    """Every value the summary's schema accepts works: the bounds themselves, the smallest
    positive numbers, curves of nulls, a one-point grid; the figures are drawn and nothing
    is said on stderr."""
    import warnings

    from sapga_ros.training.run_files import MAX_DELTA_STAR, MAX_VALUE
    from sapga_ros.viz.report import write_report
    doc = json.loads((exp_dir / 'summary.json').read_text())
    s = doc[0]
    rows = [json.loads(json.dumps(s)) for _ in range(4)]
    _curve(rows[0], 'best_value', -MAX_VALUE, MAX_VALUE)
    _curve(rows[0], 'delta_star', MAX_DELTA_STAR, MAX_DELTA_STAR)
    _final(rows[0], best_value_mean=MAX_VALUE, best_value_std=MAX_VALUE,
           best_value_ci95=[-MAX_VALUE, MAX_VALUE], delta_star_mean=MAX_DELTA_STAR,
           policy_value_mean=-MAX_VALUE)
    _curve(rows[1], 'best_value', 5e-324, 5e-324)
    _curve(rows[1], 'delta_star', 5e-324, 0.0)
    _curve(rows[2], 'best_value', None, None)
    _curve(rows[2], 'delta_star', None, None)
    rows[3].update(grid=[float(s['steps'])], achieved_fraction=[1.0], delta=0.0)
    _curve(rows[3], 'best_value', 0.0, 0.0)
    _curve(rows[3], 'delta_star', 0.0, 0.0)
    (exp_dir / 'summary.json').write_text(json.dumps(rows))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        path = write_report(exp_dir, with_figure5=False)
    assert not caught, [str(w.message) for w in caught]
    assert '1000000000.0 ± 1000000000.0' in path.read_text()
    assert (exp_dir / 'mountain.png').stat().st_size > 1000


def test_a_hold_row_whose_run_lacks_the_hold_measures_names_the_run_file(exp_dir):
    doc = json.loads((exp_dir / 'summary.json').read_text())
    _final(doc[0], holding=0, holding_clean=0, hold_fraction_mean=0.5, hold_fraction_std=0.0,
           rail_contacts_mean=0.0)
    (exp_dir / 'summary.json').write_text(json.dumps(doc))
    one_line_error(in_process('experiment', 'report', str(exp_dir)), '11-seed0.json',
                   "run.final: missing field 'hold_fraction'")


@pytest.mark.parametrize('name,text,word', [
    ('experiment.json', '{"wall_s": "slow"}', 'wall_s'),
    ('experiment.json', '[1, 2]', 'expected an object'),
    ('experiment.json', '{"runs_run": NaN}', 'not valid JSON'),
    ('limits/acrobot.json', '{"problem": "acrobot"}', 'missing field'),
    ('limits/acrobot.json', '{"problem": "../x", "delta": 0, "step": 0, "width": 1, '
     '"cells": 1, "steps_simulated": 0, "actions": [], "goal_scale": []}', 'problem'),
    ('limits/acrobot.json', '{"problem": "acrobot", "delta": "small", "step": 0, '
     '"width": 1, "cells": 1, "steps_simulated": 0, "actions": [], "goal_scale": []}',
     'delta'),
])
def test_damaged_info_and_limit_files_are_one_line_from_report(exp_dir, name, text, word):
    (exp_dir / name).write_text(text)
    one_line_error(in_process('experiment', 'report', str(exp_dir)), name.split('/')[-1],
                   word)


def test_a_run_policy_the_report_cannot_load_names_the_run_file(exp_dir):
    """The hold figures evaluate the best run's policy: its error names that run file."""
    doc = json.loads((exp_dir / 'summary.json').read_text())
    _final(doc[0], holding=0, holding_clean=0, hold_fraction_mean=0.5, hold_fraction_std=0.0,
           rail_contacts_mean=0.0)
    (exp_dir / 'summary.json').write_text(json.dumps(doc))
    for seed in (0, 1):
        path = exp_dir / 'runs' / f'11-seed{seed}.json'
        run = json.loads(path.read_text())
        run['run']['final'].update(hold_fraction=0.5, first_entry_step=1, rail_contacts=0)
        del run['run']['policy']['problem']
        path.write_text(json.dumps(run))
    one_line_error(in_process('experiment', 'report', str(exp_dir)), 'runs/11-seed',
                   ".json: run.policy: missing field 'problem'")


def test_a_limit_file_that_does_not_fit_its_problem_is_one_line_from_report(exp_dir):
    """The report replays every limit file: actions outside the problem's set are refused
    before the replay (the other fields' fit: tests/test_limit.py)."""
    doc = json.loads((Path(__file__).parents[1] / 'docs' / 'limits' / 'acrobot.json')
                     .read_text())
    (exp_dir / 'limits').mkdir(exist_ok=True)
    (exp_dir / 'limits' / 'acrobot.json').write_text(json.dumps(
        {**doc, 'actions': [1e308] * doc['step']}))
    one_line_error(in_process('experiment', 'report', str(exp_dir)), 'acrobot.json',
                   'actions[0]', '1e+308')


def test_a_values_bomb_summary_is_refused_in_bounded_memory(exp_dir):
    """A summary.json of a million empty lists (under the byte bound) is refused before it
    is parsed: the report's peak memory stays far below what parsing it would take."""
    (exp_dir / 'summary.json').write_text('[' + '[],' * 5_000_000 + '[]]')
    rc, err, peak_mib = sapga_peak_rss(['experiment', 'report', str(exp_dir)])
    assert rc == 2 and 'JSON values' in err and 'Traceback' not in err
    assert peak_mib < 400, peak_mib          # parsing it would take about 1 GB


def test_report_writes_only_inside_dir_and_never_through_a_link(exp_dir, tmp_path):
    """Planted links named like the report's figures: each is replaced by the figure, and
    the files they pointed at keep their content."""
    victims = {}
    for name in ('mountain.png', 'figure5_mountain_car.png', 'report.md'):
        victim = tmp_path / f'victim-{name}'
        victim.write_text('keep me')
        (exp_dir / name).unlink(missing_ok=True)
        (exp_dir / name).symlink_to(victim)
        victims[name] = victim
    done = sapga('experiment', 'report', str(exp_dir))
    assert done.returncode == 0, done.stderr
    for name, victim in victims.items():
        assert victim.read_text() == 'keep me'
        assert not (exp_dir / name).is_symlink() and (exp_dir / name).stat().st_size > 100


def test_figure_names_from_data_stay_inside_dir(tmp_path):
    """A summary (in memory) whose problem is a path cannot name a figure outside DIR."""
    from sapga_ros.viz.summary_plot import plot_summaries
    summary = {'problem': '../../escaped', 'grid': [1.0], 'id': 1, 'method': 'sapga',
               'delta': 0.1, 'best_value': {'mean': [1.0], 'std': [0.0]},
               'delta_star': {'mean': [1.0], 'std': [0.0]}, 'achieved_fraction': [0.0]}
    (tmp_path / 'd').mkdir()
    with pytest.raises(ValueError, match='not a plain file name'):
        plot_summaries([summary], tmp_path / 'd')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['d']


@pytest.mark.parametrize('args,word', [
    (['--seeds', '1000000000000'], '--seeds'),
    (['--seeds', '0'], '--seeds'),
    (['--scale', '1e300'], '--scale'),
    (['--scale', 'nan'], '--scale'),
    (['--scale', '0'], '--scale'),
    (['--workers', '100000'], '--workers'),
])
def test_seeds_scale_and_workers_are_bounded(tmp_path, args, word):
    done = in_process('experiment', 'table2', '--out', str(tmp_path / 'o'), *args)
    assert done.returncode == 2 and word in done.stderr and 'Traceback' not in done.stderr
    assert not (tmp_path / 'o').exists()


@pytest.mark.parametrize('address,word', [
    ('garbage:::', 'expected HOST:PORT'),
    ('127.0.0.1:99999', 'expected HOST:PORT'),
    ('127.0.0.1:1', 'no Ray cluster reachable'),
])
def test_a_bad_ray_address_is_one_line(tmp_path, address, word):
    """Malformed, or nothing listening: one line, exit 2, no run trained (the connection
    attempt is bounded in time: nothing listens on port 1)."""
    out = tmp_path / 'o'
    run = sapga if 'reachable' in word else in_process   # a malformed one never meets Ray
    done = run('experiment', 'styles', '--out', str(out), '--only', '11', '--seeds', '1',
               '--scale', '0.005', '--backend', 'ray', '--address', address)
    one_line_error(done, word)
    assert not (out / 'runs').exists() or not any((out / 'runs').iterdir())


def _conf_with_set(tmp_path: Path, body: str) -> dict:
    from sim_nodes.problem import config_dir
    conf = tmp_path / 'conf'
    shutil.copytree(config_dir(), conf)
    (conf / 'experiments' / 'bad.yaml').write_text(
        'name: bad\nseeds: 1\nexperiments: [{id: 1, problem: mountain_car, delta: 0.0, '
        'method: sapga, steps: 1000}]\n' + body)
    return {'SAPGA_CONFIG_DIR': str(conf)}


@pytest.mark.parametrize('body,word', [
    ('limits: 5\n', 'limits: expected a list'),
    ('limits: [{problem: nope}]\n', 'nope'),
    ('limits: [{problem: acrobot, alternative_goal: yes please}]\n', 'alternative_goal'),
    ('limits: [{problem: acrobot, width: 1e99}]\n', 'width'),
    ('limit: []\n', "unknown key 'limit'"),
])
def test_the_whole_set_is_checked_before_any_run(tmp_path, body, word):
    """A bad limits section is found before a run trains, not after every run."""
    out = tmp_path / 'o'
    done = in_process('experiment', 'bad', '--out', str(out),
                      env=_conf_with_set(tmp_path, body))
    one_line_error(done, 'bad.yaml', word)
    assert not (out / 'runs').exists() or not any((out / 'runs').iterdir())


def test_the_limit_file_is_strict_json_and_reads_back(tmp_path):
    """The PDIP's goal scale holds nan (the rail has a fixed bound): written as null."""
    from sapga_ros.analysis.limit_file import read_limit
    path = tmp_path / 'pdip.json'
    done = sapga('limit', '--problem', 'pdip', '--width', '200', '--json', '--out', str(path))
    assert done.returncode == 0, done.stderr
    doc = strict(path.read_text())
    assert doc['goal_scale'][0] is None
    strict(done.stdout)
    back = read_limit(path)
    assert back['delta'] == doc['delta'] and len(back['actions']) == back['step']


def test_an_address_where_something_else_listens_is_one_line(tmp_path):
    """A TCP server that is not Ray (it closes at once): refused, never a hang in Ray."""
    import socket
    import threading
    server = socket.create_server(('127.0.0.1', 0))
    port = server.getsockname()[1]

    def serve():
        for _ in range(4):
            conn, _ = server.accept()
            conn.close()
    threading.Thread(target=serve, daemon=True).start()
    try:
        done = sapga('experiment', 'styles', '--out', str(tmp_path / 'o'), '--only', '11',
                     '--seeds', '1', '--scale', '0.005', '--backend', 'ray', '--address',
                     f'127.0.0.1:{port}')
    finally:
        server.close()
    one_line_error(done, 'not a Ray cluster')


def test_a_fifo_run_file_or_linked_runs_folder_is_refused_before_any_run(exp_dir, tmp_path):
    """What a run file cannot replace is refused up front, in one line: a FIFO (reading it
    would block), and a runs/ folder that is a link out of DIR."""
    import os
    path = exp_dir / 'runs' / '11-seed1.json'
    path.unlink()
    os.mkfifo(path)
    done = in_process('experiment', 'styles', '--out', str(exp_dir), '--only', '11',
                      '--seeds', '2', '--scale', '0.005', '--workers', '1')
    one_line_error(done, '11-seed1.json', 'not a regular file')
    path.unlink()
    elsewhere = tmp_path / 'elsewhere'
    (exp_dir / 'runs').rename(elsewhere)
    (exp_dir / 'runs').symlink_to(elsewhere)
    done = in_process('experiment', 'styles', '--out', str(exp_dir), '--only', '11',
                      '--seeds', '2', '--scale', '0.005', '--workers', '1')
    one_line_error(done, 'runs', 'not a directory of this experiment')
    assert sorted(p.name for p in elsewhere.iterdir()) == ['11-seed0.json']


def test_a_folder_or_device_among_the_limits_is_one_line_from_report(exp_dir):
    (exp_dir / 'limits' / 'acrobot.json').mkdir()
    one_line_error(in_process('experiment', 'report', str(exp_dir)), 'acrobot.json',
                   'not a regular file')


def test_a_ray_resume_that_only_searches_limits_checks_the_address_first(tmp_path):
    """Every run done, a limit file missing: the search goes to Ray, so an address where
    nothing listens is one line and exit 2 (not a connection retried for ever); the runs
    already written stay as they were."""
    env = _conf_with_set(tmp_path, 'limits: [{problem: acrobot}]\n')
    out = tmp_path / 'o'
    first = in_process('experiment', 'bad', '--out', str(out), '--scale', '0.001', env=env)
    assert first.returncode == 0, first.stderr
    runs = {p.name: p.read_bytes() for p in (out / 'runs').iterdir()}
    (out / 'limits' / 'acrobot.json').unlink()
    done = sapga('experiment', 'bad', '--out', str(out), '--scale', '0.001', '--backend', 'ray',
                 '--address', '127.0.0.1:1', env=env)
    one_line_error(done, 'no Ray cluster reachable')
    assert {p.name: p.read_bytes() for p in (out / 'runs').iterdir()} == runs
