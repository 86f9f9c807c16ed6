"""The hold task: problems whose episode runs all n_step steps, its measures (first entry,
hold fraction, end-stop contacts), the hold bonus, and the classical controller policy."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from sapga_ros.cli import main as cli
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.runnable import load_policy
from process_helpers import sapga_in_process
from sim_nodes import reference
from sim_nodes.errors import ConfigError
from sim_nodes.problem import load_problem, parse_problem


def sapga(*args):
    """``sapga ARGS`` in this process (the commands' own processes are tested in
    test_cli.py)."""
    return sapga_in_process(list(args))


def recompute(problem, ep, delta):
    """The hold measures from the traced states and actions, on the independent reference
    model: every step replayed from the traced state, contacts from its rail flag."""
    step = reference.STEPS[problem.model]
    inside, contacts = [], 0
    for t in range(ep.steps):
        s, r = step(ep.states[t], ep.actions[t], problem)
        gap = np.abs(s - ep.states[t + 1])
        gap[problem.is_angle] = np.minimum(gap[problem.is_angle],
                                           2 * np.pi - gap[problem.is_angle])
        assert gap.max() < 1e-9
        contacts += r < -50
        inside.append(reference.goal_delta(problem, ep.states[t + 1]) <= delta)
    inside = np.array(inside)
    if not inside.any():
        return None, 0.0, contacts
    first = int(np.argmax(inside)) + 1
    return first, float(inside[first - 1:].mean()), contacts


def test_paper_problems_end_in_the_goal_and_hold_problems_do_not():
    for name in ('acrobot', 'pdip', 'pdip_single'):
        pr = load_problem(name)
        assert pr.ends_in_goal and pr.hold_bonus == 0.0 and pr.end_stop == 'stop'
    acro, pdip = load_problem('acrobot_hold'), load_problem('pdip_hold')
    assert not acro.ends_in_goal and acro.n_step == 1000 and acro.default_delta == 0.02
    assert acro.actions == (-2.0, 0.0, 2.0)
    assert not pdip.ends_in_goal and pdip.n_step == 1000 and pdip.default_delta == 0.05
    assert pdip.end_stop == 'fail'
    assert pdip.actions == (-40.0, -20.0, -10.0, -5.0, 0.0, 5.0, 10.0, 20.0, 40.0)
    assert acro.contact_below == -math.inf and pdip.contact_below < -5.0


@pytest.mark.parametrize('field, value, words', [
    ('ends_in_goal', 'no', 'episode.ends_in_goal'),
    ('hold_bonus', -1, 'episode.hold_bonus'),
    ('end_stop', 'bounce', 'episode.end_stop'),
])
def test_bad_hold_settings_name_the_field(field, value, words):
    import yaml
    doc = yaml.safe_load(open(load_problem('pdip_hold').source))
    doc['episode'][field] = value
    with pytest.raises(ConfigError, match=words):
        parse_problem(doc, 'x.yaml')


def test_a_bonus_or_fail_needs_a_problem_that_can_use_it():
    import yaml
    doc = yaml.safe_load(open(load_problem('acrobot').source))
    doc['episode']['hold_bonus'] = 1.0
    with pytest.raises(ConfigError, match='hold_bonus'):
        parse_problem(doc, 'x.yaml')
    doc['episode']['hold_bonus'] = 0.0
    doc['episode']['end_stop'] = 'fail'
    with pytest.raises(ConfigError, match='end_stop'):
        parse_problem(doc, 'x.yaml')


@pytest.mark.parametrize('name', ['acrobot_hold', 'pdip_hold'])
def test_batch_and_traced_episode_report_the_independent_hold_measures(name):
    """Random policies: the batch engine's measures equal the traced episode's, which equal a
    replay of the traced actions on the reference model (pdip: rail contacts happen)."""
    pr = load_problem(name)
    rng = np.random.default_rng(3)
    policies = [ExemplarPolicy(pr, rng.uniform(pr.low, pr.high, (8, pr.dim)),
                               rng.integers(0, len(pr.actions), 8)) for _ in range(6)]
    ev = Evaluator(pr)
    batch = ev.evaluate(policies)
    for k, policy in enumerate(policies):
        ep = ev.episode(policy)
        assert ep.steps == batch.steps[k]
        # all n_step steps run, but for a rail contact under end_stop: fail
        assert ep.steps == pr.n_step or (pr.end_stop == 'fail' and ep.contacts == 1)
        assert batch.hold(k) == {key: ep.summary()[key] for key in batch.hold(k)}
        first, fraction, contacts = recompute(pr, ep, ev.delta)
        hold = ep.summary()
        assert (hold['first_entry_step'], hold['rail_contacts']) == (first, contacts)
        assert hold['hold_fraction'] == pytest.approx(fraction, abs=1e-12)
        inside = sum(reference.goal_delta(pr, s) <= ev.delta for s in ep.states[1:])
        charge = (pr.n_step - ep.steps) * pr.fail_charge if ep.contacts else 0.0
        assert ep.ret == pytest.approx(ep.rewards.sum() + pr.hold_bonus * inside + charge,
                                       rel=1e-12)
    if name == 'pdip_hold':
        assert batch.contacts.max() > 0 and min(batch.steps) < pr.n_step


@pytest.fixture(scope='module', params=['acrobot_hold', 'pdip_hold'])
def classical(request, tmp_path_factory):
    out = tmp_path_factory.mktemp('classical') / f'{request.param}.json'
    r = sapga('classical', '--problem', request.param, '--out', out)
    assert r.returncode == 0, r.stderr
    return request.param, out


def test_classical_policy_swings_up_and_holds(classical):
    """sapga classical writes a kind: classical policy; sapga eval --json prints the hold
    measures, equal to the replay of its traced episode on the reference model."""
    name, out = classical
    doc = json.loads(out.read_text())
    assert doc['kind'] == 'classical' and doc['problem'] == name
    r = sapga('eval', out, '--json')
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    pr = load_problem(name)
    ep = Evaluator(pr).episode(load_policy(out))
    first, fraction, contacts = recompute(pr, ep, pr.default_delta)
    assert got['first_entry_step'] == first and got['rail_contacts'] == contacts == 0
    assert got['hold_fraction'] == pytest.approx(fraction, abs=1e-12)
    assert got['hold_fraction'] >= 0.95        # measured: 1.0 and 0.9965


@pytest.mark.parametrize('edit, words', [
    (lambda d: d['controller'].update(K=[1.0]), 'controller.K'),
    (lambda d: d['controller']['P'][0].__setitem__(0, 'x'), 'controller.P[0][0]'),
    (lambda d: d['controller'].update(c=-1), 'controller.c'),
    (lambda d: d['controller'].pop('swing_up'), 'swing_up'),
    (lambda d: d['controller']['swing_up'].update(law='magic'), 'swing_up.law'),
    (lambda d: d['controller']['swing_up']['gains'].update(zz=1), 'swing_up.gains'),
    (lambda d: d.update(kind='neural'), 'kind'),
    (lambda d: d.update(controller=[]), 'controller'),
])
def test_hostile_classical_files_get_one_line(classical, tmp_path, capsys, edit, words):
    """In process (an exception escaping main fails the test); the subprocess path of the
    same refusal is test_a_nan_in_a_classical_file_is_refused."""
    _, out = classical
    doc = json.loads(out.read_text())
    edit(doc)
    bad = tmp_path / 'bad.json'
    bad.write_text(json.dumps(doc))
    capsys.readouterr()
    assert cli.main(['eval', str(bad)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and words in err


def test_a_nan_in_a_classical_file_is_refused(classical, tmp_path):
    _, out = classical
    bad = tmp_path / 'nan.json'
    bad.write_text(out.read_text().replace('"c": ', '"c": NaN, "x": ', 1))
    r = subprocess.run([sys.executable, '-m', 'sapga_ros.cli.main', 'eval', str(bad)],
                       capture_output=True, text=True, timeout=300)    # a real process
    assert r.returncode == 2 and 'Traceback' not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_catch_lqr_trains_a_hybrid_whose_file_runs_like_its_run(tmp_path):
    """sapga train --catch lqr writes an exemplar policy with a catch; sapga eval of the file
    reproduces the run's value and hold measures; a hostile catch gets one line."""
    out = tmp_path / 'hybrid.json'
    r = sapga('train', '--problem', 'acrobot_hold', '--steps', '300000', '--seed', '1',
              '--catch', 'lqr', '--quiet', '--out', out)
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    assert doc['exemplars'] and set(doc['catch']) == {'K', 'P', 'c'}
    got = json.loads(sapga('eval', out, '--json').stdout)
    meta = doc['meta']
    assert got['return'] == meta['value']
    assert [got[k] for k in ('first_entry_step', 'hold_fraction', 'rail_contacts')] == \
        [meta[k] for k in ('first_entry_step', 'hold_fraction', 'rail_contacts')]
    log = out.with_suffix('.log.csv').read_text().splitlines()
    assert 'best_hold_fraction' in log[0]
    doc['catch']['c'] = 'wide'
    bad = tmp_path / 'bad.json'
    bad.write_text(json.dumps(doc))
    r = sapga('eval', bad)
    assert r.returncode == 2 and 'catch.c' in r.stderr and 'Traceback' not in r.stderr


def test_catch_lqr_refuses_q_learning(tmp_path, capsys):
    assert cli.main(['train', '--problem', 'acrobot_hold', '--method', 'ql', '--catch', 'lqr',
                     '--steps', '1000', '--quiet', '--out', str(tmp_path / 'x.json')]) == 2
    assert '--catch' in capsys.readouterr().err
    assert not (tmp_path / 'x.json').exists()


def test_the_hold_experiment_set_parses_and_its_classical_rows_run(tmp_path):
    """msg_configs/experiments/hold.yaml: every row parses (a catch on a CMA-ES row is
    refused); its classical rows run and their summary carries the hold measures."""
    from sapga_ros.training.experiment_set import _experiment, load_experiments
    exps, seeds = load_experiments('hold')
    assert seeds == 20 and {e.problem for e in exps} == {'acrobot_hold', 'pdip_hold'}
    assert {(e.method, e.catch) for e in exps} >= {('sapga', 'lqr'), ('classical', 'none')}
    with pytest.raises(ConfigError, match='catch'):
        _experiment({'id': 1, 'problem': 'acrobot_hold', 'delta': 0.02, 'method': 'cmaes',
                     'steps': 10, 'catch': 'lqr'}, 'x')
    r = sapga('experiment', 'hold', '--out', tmp_path / 'x', '--only', '5,10', '--seeds', '1',
              '--workers', '1')
    assert r.returncode == 0, r.stderr
    summaries = json.loads((tmp_path / 'x' / 'summary.json').read_text())
    summary = {s['id']: s['final'] for s in summaries}
    assert summary[5]['holding'] == 1 and summary[10]['holding_clean'] == 1
    assert 'hold fraction' in (tmp_path / 'x' / 'summary.md').read_text()


@pytest.mark.parametrize('name', ['acrobot_hold', 'pdip_hold'])
def test_the_gym_env_runs_the_hold_task_like_the_engine(name):
    """Evaluator episodes replayed through the Gymnasium env: the same states, rewards plus
    the bonus in S_delta summing to the engine's return, no goal end; under end_stop: fail
    the contact terminates, its reward charged for the steps not run."""
    import gymnasium
    import sapga_ros.gym
    pr = load_problem(name)
    env = gymnasium.make(sapga_ros.gym.ENV_IDS[name])
    rng = np.random.default_rng(5)
    index = {v: i for i, v in enumerate(pr.actions)}
    for policy in [classical_policy_of(pr)] + [
            ExemplarPolicy(pr, rng.uniform(pr.low, pr.high, (8, pr.dim)),
                           rng.integers(0, len(pr.actions), 8)) for _ in range(3)]:
        ep = Evaluator(pr).episode(policy)
        env.reset(seed=0)
        total, states = 0.0, []
        for t, a in enumerate(ep.actions):
            obs, r, terminated, truncated, _ = env.step(index[a])
            states.append(obs)
            inside = reference.goal_delta(pr, ep.states[t + 1]) <= pr.default_delta
            charge = (pr.n_step - ep.steps) * pr.fail_charge if terminated else 0.0
            assert r == ep.rewards[t] + (pr.hold_bonus if inside else 0.0) + charge
            total += r
        assert np.array_equal(np.array(states), ep.states[1:])
        assert total == pytest.approx(ep.ret, rel=1e-12)   # the engine adds the bonus apart
        assert terminated == (ep.contacts > 0 and pr.end_stop == 'fail')
        assert truncated == (not terminated and ep.steps == pr.n_step)


def classical_policy_of(problem):
    from sapga_ros.evaluation.classical_design import classical_policy
    return classical_policy(problem)
