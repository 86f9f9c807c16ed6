"""Robust fitness (every policy on the same K disturbed episodes, their mean or a lower
percentile its value) and the robustness evaluation (``sapga eval --disturbance``)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from process_helpers import sapga_in_process
from sapga_ros.errors import ConfigError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.evaluation.robust import Robust, evaluate_robust
from sapga_ros.optim.operators import random_policy
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.training.loop import TrainConfig, train
from sim_nodes.disturbance import load_disturbance

SMALL = SapgaParams(n_pop=12, n_child=3, l_min=10, l_max=20)


def robust_run(**kw):
    config = dict(problem='acrobot', delta=0.05, steps=60_000, seed=4, params=SMALL,
                  disturbance='field', episodes=3, robust_stat='q10')
    return train(TrainConfig(**{**config, **kw}))


def test_common_random_numbers_and_the_statistic(acrobot_problem):
    """Each policy meets the same K draws whatever the batch holds; its value is the
    statistic of those K episodes' returns."""
    rng = np.random.default_rng(2)
    pols = [random_policy(acrobot_problem, rng, 20, 40, 'state-action') for _ in range(4)]
    ev = Evaluator(acrobot_problem, 0.02, 120, disturbance=load_disturbance('field'))
    mean = evaluate_robust(ev, pols, Robust(5, 'mean', seed=3))
    alone = evaluate_robust(ev, pols[2:3], Robust(5, 'mean', seed=3))
    assert mean.returns[2] == alone.returns[0] and mean.steps[2] == alone.steps[0]
    episodes = [ev.episode(pols[2], (3, 0, 0, e)) for e in range(5)]
    assert mean.returns[2] == np.mean([e.ret for e in episodes])
    assert mean.steps[2] == sum(e.steps for e in episodes)
    # the same draws for every policy: the same initial states
    for e in range(5):
        np.testing.assert_array_equal(episodes[e].states[0],
                                      ev.episode(pols[0], (3, 0, 0, e)).states[0])
    q10 = evaluate_robust(ev, pols, Robust(5, 'q10', seed=3))
    assert np.all(q10.returns <= mean.returns)
    with pytest.raises(ConfigError, match='robust_stat: expected mean or qNN'):
        Robust(3, 'median')


def test_a_disturbed_run_is_the_same_for_any_thread_count_and_after_resume(tmp_path):
    one = robust_run(jobs=1)
    two = robust_run(jobs=2)
    assert one.stats == two.stats
    np.testing.assert_array_equal(one.policy.states, two.policy.states)
    assert one.policy.meta['disturbance'] == 'field' and one.policy.meta['episodes'] == 3
    ck = tmp_path / 'ck'
    first = robust_run(steps=25_000, checkpoint=str(ck), checkpoint_every=1)
    resumed = robust_run(checkpoint=str(ck), resume=True)
    assert first.stats['steps'] < resumed.stats['steps']
    assert resumed.stats == one.stats
    np.testing.assert_array_equal(resumed.policy.states, one.policy.states)
    plain = train(TrainConfig(problem='acrobot', delta=0.05, steps=60_000, seed=4,
                              params=SMALL))
    assert plain.stats != one.stats          # the disturbance changed the run
    with pytest.raises(Exception, match='disturbance'):
        robust_run(checkpoint=str(ck), resume=True, disturbance='latency')


def test_redraw_keys_each_generations_draws_and_reevaluates_the_parents(acrobot_problem):
    """With redraw every generation meets K new draws (generation g keys (seed, g, 0, e)),
    every member of it the same ones, parents re-evaluated: the returned policy's value is
    its statistic on the last generation's draws, which a fixed-draw run's is not."""
    run = robust_run(redraw=True, steps=200_000)
    g = run.stats['generation'] - 1
    assert g > 2 and run.policy.meta['redraw'] is True
    ev = Evaluator(acrobot_problem, 0.05, disturbance=load_disturbance('field'))
    ev.generation = g
    last = evaluate_robust(ev, [run.policy], Robust(3, 'q10', seed=4, redraw=True))
    assert last.returns[0] == run.policy.meta['value']
    ev.generation = 0
    first = evaluate_robust(ev, [run.policy], Robust(3, 'q10', seed=4, redraw=True))
    assert first.returns[0] != run.policy.meta['value']
    fixed = robust_run(steps=200_000)
    assert fixed.stats != run.stats and 'redraw' not in fixed.policy.meta
    # each generation evaluates its parents again: more evaluations than the fixed run's
    # generations alike
    per_gen = run.stats['evaluations'] / run.stats['generation']
    assert per_gen == SMALL.n_pop + SMALL.n_pop // 2 * SMALL.n_child


def test_a_redrawn_run_is_the_same_for_any_thread_count_and_after_resume(tmp_path):
    one = robust_run(redraw=True, jobs=1)
    two = robust_run(redraw=True, jobs=2)
    assert one.stats == two.stats
    np.testing.assert_array_equal(one.policy.states, two.policy.states)
    ck = tmp_path / 'ck'
    robust_run(redraw=True, steps=25_000, checkpoint=str(ck), checkpoint_every=1)
    resumed = robust_run(redraw=True, checkpoint=str(ck), resume=True)
    assert resumed.stats == one.stats
    np.testing.assert_array_equal(resumed.policy.states, one.policy.states)
    with pytest.raises(Exception, match='redraw'):
        robust_run(checkpoint=str(ck), resume=True)


@pytest.mark.parametrize('kw, needle', [
    (dict(disturbance='none', episodes=1), 'redraw: drawing episodes anew needs'),
    (dict(method='cmaes'), 'redraw: episodes drawn anew each generation: SAP-GA only'),
])
def test_redraw_without_disturbed_sapga_episodes_is_refused(kw, needle):
    with pytest.raises(ConfigError, match=needle):
        TrainConfig(problem='acrobot', redraw=True, **{'disturbance': 'field', **kw})


def test_eval_reports_success_rate_and_distributions(tmp_path):
    policy = tmp_path / 'lqr.json'
    made = sapga_in_process(['classical', '--problem', 'acrobot_hold', '--out', policy])
    assert made.returncode == 0, made.stderr

    def evaluate(*args):
        out = sapga_in_process(['eval', policy, '--json', *args])
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout)
    none = evaluate('--disturbance', 'none', '--episodes', '4')
    assert none['success_rate'] == 1.0 and none['success'] == 'hold_fraction >= 0.9'
    assert none['hold_fraction']['min'] == none['hold_fraction']['max']   # four equal runs
    pushed = evaluate('--disturbance', 'push', '--episodes', '6', '--seed', '2')
    assert pushed['episodes'] == 6 and pushed['disturbance'] == 'push'
    assert set(pushed['delta_star']) == {'mean', 'min', 'q10', 'median', 'q90', 'max'}
    assert pushed['rail_contacts'] == {'total': 0, 'episodes_with': 0}
    assert pushed['hold_fraction']['min'] < pushed['hold_fraction']['max']
    bad = sapga_in_process(['eval', policy, '--disturbance', 'gust'])
    assert bad.returncode == 2 and "unknown disturbance 'gust'" in bad.stderr
    assert 'Traceback' not in bad.stderr


def test_robustness_curves(tmp_path):
    policy = tmp_path / 'lqr.json'
    assert sapga_in_process(['classical', '--problem', 'acrobot_hold', '--out',
                             policy]).returncode == 0
    out = tmp_path / 'curves'
    done = sapga_in_process(['robustness', policy, policy, '--out', out, '--disturbance',
                             'push', '--scales', '0,4', '--episodes', '3'])
    assert done.returncode == 0, done.stderr
    rows = json.loads((out / 'robustness.json').read_text())
    assert [(r['scale'], r['episodes']) for r in rows] == [(0, 3), (4, 3)] * 2
    assert rows[0]['success_rate'] == 1.0 and rows[0] == {**rows[2], 'policy': rows[0]['policy']}
    assert (out / 'push.png').stat().st_size > 1000


def test_experiment_rows_take_the_robust_settings():
    from sapga_ros.training.experiment_set import _experiment, load_experiments
    from sapga_ros.training.experiments import run_key
    row = {'id': 1, 'problem': 'acrobot', 'delta': 0.02, 'method': 'sapga', 'steps': 1000}
    plain = _experiment(row, 'set.experiments[0]')
    robust = _experiment({**row, 'disturbance': 'field', 'episodes': 8, 'robust_stat': 'q10'},
                         'set.experiments[0]')
    assert (robust.disturbance, robust.episodes, robust.robust_stat) == ('field', 8, 'q10')
    assert 'disturbance' not in run_key('s', plain, 0, 1000)['experiment']  # keys unchanged
    assert run_key('s', robust, 0, 1000)['experiment']['episodes'] == 8
    for bad, message in (({'disturbance': 'gust'}, "unknown disturbance 'gust'"),
                         ({'robust_stat': 'q'}, 'robust_stat: expected mean or qNN'),
                         ({'episodes': 0}, r'episodes: expected a whole number in \[1, 10000\]'),
                         ({'method': 'ql', 'episodes': 2}, 'SAP-GA and CMA-ES rows only')):
        with pytest.raises(ConfigError, match=r'set\.experiments\[0\].*' + message):
            _experiment({**row, **bad}, 'set.experiments[0]')
    assert any(e.catch == 'lqr' for e in load_experiments('hold')[0])
    redrawn = _experiment({**row, 'disturbance': 'field', 'episodes': 8, 'redraw': True},
                          'set.experiments[0]')
    assert redrawn.redraw and 'redraw' not in run_key('s', robust, 0, 1000)['experiment']
    assert run_key('s', redrawn, 0, 1000)['experiment']['redraw'] is True
    for bad, message in (({'redraw': 'yes', 'episodes': 8}, 'redraw: expected true or false'),
                         ({'redraw': True}, 'redraw: episodes drawn anew each generation'),
                         ({'redraw': True, 'episodes': 8, 'method': 'cmaes'},
                          'redraw: episodes drawn anew')):
        with pytest.raises(ConfigError, match=r'set\.experiments\[0\].*' + message):
            _experiment({**row, **bad}, 'set.experiments[0]')
    robust_set = load_experiments('robust')[0]
    assert [e.redraw for e in robust_set] == [False, False, True, False, False, False]
    assert [e.catch_delay for e in robust_set] == [0, 0, 0, 1, 1, 0]
    assert [e.delay for e in robust_set] == [0, 0, 0, 0, 0, 1]
    delayed = _experiment({**row, 'catch': 'lqr', 'catch_delay': 1}, 'set.experiments[0]')
    assert run_key('s', delayed, 0, 1000)['experiment']['catch_delay'] == 1
    assert 'catch_delay' not in run_key('s', redrawn, 0, 1000)['experiment']
    for bad, message in (({'catch_delay': 1}, 'catch_delay: the delay of the LQR catch needs'),
                         ({'catch': 'lqr', 'catch_delay': 99},
                          r'catch_delay: expected a whole number in \[0, 16\]')):
        with pytest.raises(ConfigError, match=r'set\.experiments\[0\].*' + message):
            _experiment({**row, **bad}, 'set.experiments[0]')


def test_cmaes_takes_robust_fitness(acrobot_problem):
    """CMA-ES through the training loop with robust fitness: its policy's value is the mean
    of its K disturbed episodes, and every candidate costs K episodes."""
    from sapga_ros.optim.cmaes import CmaesParams
    from sapga_ros.training.loop import make_evaluator, train
    config = TrainConfig(problem='acrobot', method='cmaes', delta=0.02, steps=20_000, seed=1,
                         disturbance='field', episodes=3, jobs=1,
                         cmaes=CmaesParams(exemplars=10, popsize=6))
    result = train(config)
    robust = make_evaluator(config, acrobot_problem, 0.02)
    again = evaluate_robust(robust, [result.policy], robust.robust)
    assert result.policy.meta['value'] == again.returns[0]   # the mean of its 3 episodes
    assert result.history[0]['steps'] == 6 * 3 * 400       # K episodes a candidate
