"""An exemplar policy designed for an actuation delay (``delay`` d, ``sapga train --delay``,
``sapga eval --delay``): its selector acts on the state the nominal model predicts for when
its command arrives, from the state it sees and the d commands in flight.

Properties: on the undisturbed plant that applies each command d steps late, its episode is
the undelayed policy's episode d steps later, bit for bit (the prediction is the plant's own
step), in every style and on both models; the policy node's selector and a simulator stepping
the disturbed plant replay the engine; the file's ``delay`` round-trips and a bad one is
refused with one line; a training run with ``delay`` is the same run on one and two threads,
returns a policy that keeps its delay, and bad combinations are refused up front.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from sapga_ros.errors import PolicyFileError, SapgaError
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.optim.operators import random_exemplars
from sapga_ros.policies.classical import AHEAD_KIND, ahead, with_catch
from sapga_ros.policies.runnable import policy_from_json
from sapga_ros.training.loop import TrainConfig, train
from sim_nodes.disturbance import Disturbance, load_disturbance
from process_helpers import sapga_in_process
from sim_nodes.problem import load_problem
from test_disturbance import plant_episode


def sapga(*args):
    """``sapga ARGS`` in this process (the commands' own processes are tested in
    test_cli.py)."""
    return sapga_in_process(list(args))


def late(d: int) -> Disturbance | None:
    return Disturbance(name='late', latency=d) if d else None


def trained(problem: str, seed: int = 0):
    """A short SAP-GA run's policy: a swing-up that goes somewhere, unlike random exemplars."""
    return train(TrainConfig(problem=problem, steps=300_000, seed=seed, jobs=1)).policy


@pytest.mark.parametrize('problem, style, d', [
    ('acrobot', 'state-action', 1), ('acrobot', 'state-action', 3),
    ('acrobot', 'via-point', 1), ('acrobot', 'state-value', 2), ('pdip', 'state-action', 1),
    ('pdip', 'state-state', 2), ('acrobot_hold', 'state-action-value', 1)])
def test_the_delayed_episode_is_the_undelayed_one_d_steps_later(problem, style, d):
    """Under latency d with no other disturbance the states from step d on are the undelayed
    policy's from the state reached while the plant waited for the first command (zero
    commands), and so are the actions, bit for bit."""
    base = load_problem(problem)
    rng = np.random.default_rng(d)
    # a start in motion, away from the goal: the selector switches exemplars many times
    start = base.low + rng.uniform(0.3, 0.7, base.dim) * (base.high - base.low)
    pr = dataclasses.replace(base, initial=tuple(start))
    policy = random_exemplars(pr, 100, rng, style)
    delayed = Evaluator(pr, disturbance=late(d)).episode(ahead(policy, d))
    assert np.all(delayed.actions[:d] == 0.0) and delayed.steps > d
    after = dataclasses.replace(pr, initial=tuple(delayed.states[d]), n_step=pr.n_step - d)
    policy.problem = after
    plain = Evaluator(after).episode(policy)
    assert plain.steps == delayed.steps - d
    np.testing.assert_array_equal(delayed.states[d:], plain.states)
    np.testing.assert_array_equal(delayed.actions[d:], plain.actions)
    # not vacuous: the actions change, and the policy acting on what it sees is another run
    assert len(set(plain.exemplars[plain.exemplars >= 0])) > 3
    assert len(set(plain.actions)) > 1
    policy.problem = pr
    seen = Evaluator(pr, disturbance=late(d)).episode(policy)
    assert not np.array_equal(seen.states, delayed.states)


def test_a_swing_up_goes_on_reaching_the_goal_under_latency():
    """A trained acrobot swing-up reaches S_delta on its own model; one step of latency takes
    that away; the same policy run as designed for one step of delay reaches it again, one
    step later."""
    policy = trained('acrobot')
    pr = policy.problem
    own = Evaluator(pr, 0.1).episode(policy)
    assert own.reached
    assert not Evaluator(pr, 0.1, disturbance=late(1)).episode(policy).reached
    again = Evaluator(pr, 0.1, disturbance=late(1)).episode(ahead(policy, 1))
    assert again.reached


def test_the_node_selector_and_a_disturbed_plant_replay_the_engine(acrobot_problem):
    """StateSelector (the policy node's path) stepping ``Plant`` under field with pushes and a
    gain error gives the engine's traced episode of a delay-1 policy, twice: reset() empties
    the commands in flight."""
    from sim_nodes.disturbance import Plant
    rng = np.random.default_rng(5)
    start = acrobot_problem.low + rng.uniform(0.3, 0.7, 4) * (acrobot_problem.high -
                                                              acrobot_problem.low)
    pr = dataclasses.replace(acrobot_problem, initial=tuple(start))
    plain = random_exemplars(pr, 100, rng)
    policy = ahead(plain, 1)
    dist = dataclasses.replace(load_disturbance('field'), pushes=2, push_size=0.3, gain=0.1)
    key = (3, 0, 1, 4)
    ep = Evaluator(pr, disturbance=dist).episode(policy, key)
    assert len(set(ep.exemplars)) > 3           # not vacuous: the selector switches, and
    assert Evaluator(pr, disturbance=dist).episode(plain, key).ret != ep.ret  # predicts
    selector = StateSelector(policy)
    assert selector.stateful
    for _ in range(2):
        selector.reset()
        states, actions = plant_episode(Plant(pr, dist), selector, key, ep.steps)
        np.testing.assert_array_equal(states, ep.states)
        np.testing.assert_array_equal(actions, ep.actions)


@pytest.mark.parametrize('problem, d', [('acrobot', 1), ('pdip', 2)])
def test_a_batch_of_one_delay_takes_the_lanes_loop_and_gives_the_general_loops_bits(
        problem, d):
    """A batch whose state-action policies all predict d steps ahead takes the engine's
    state-action loop (the lanes predicted side by side); interleaved with policies of
    another delay every share takes the general loop (``choose``).  Under field with pushes
    and a gain error, on the same draws, each policy's entries are the same bits."""
    pr = load_problem(problem)
    rng = np.random.default_rng(11)
    dist = dataclasses.replace(load_disturbance('field'), pushes=2, push_size=0.3, gain=0.1)
    ev = Evaluator(pr, 0.05, disturbance=dist)
    ours = [ahead(random_exemplars(pr, 50, rng), d) for _ in range(24)]
    others = [ahead(random_exemplars(pr, 50, rng), d + 1) for _ in range(24)]
    keys = np.array([[5, 1, k, k % 4] for k in range(24)])
    set_jobs(1)
    fast = ev.evaluate(ours, keys)
    mixed = ev.evaluate([p for pair in zip(ours, others) for p in pair],
                        np.repeat(keys, 2, axis=0))
    set_jobs(0)
    for name in ('returns', 'steps', 'delta_star', 'reached', 'first_entry', 'held',
                 'contacts'):
        np.testing.assert_array_equal(getattr(fast, name), getattr(mixed, name)[::2], name)
    for k in range(24):
        np.testing.assert_array_equal(fast.used[k], mixed.used[2 * k])
    assert len(set(fast.returns)) > 20                  # 24 different episodes


def test_delay_round_trips_and_zero_is_the_plain_policy(acrobot_problem):
    policy = random_exemplars(acrobot_problem, 5, np.random.default_rng(0))
    assert ahead(policy, 0) is policy
    one = ahead(policy, 2)
    doc = json.loads(one.to_json())
    assert doc['delay'] == 2 and 'catch' not in doc
    back = policy_from_json(one.to_json(), acrobot_problem)
    assert back.kind == AHEAD_KIND and back.delay == 2
    np.testing.assert_array_equal(back.control, one.control)
    np.testing.assert_array_equal(back.states, policy.states)
    assert 'delay' not in json.loads(policy.to_json())
    doc['delay'] = 0
    assert policy_from_json(json.dumps(doc), acrobot_problem).__class__ is policy.__class__


@pytest.mark.parametrize('value', [-1, 17, 1.5, True, '1', None])
def test_a_bad_delay_is_refused_naming_the_field(acrobot_problem, value):
    doc = json.loads(ahead(random_exemplars(acrobot_problem, 3,
                                            np.random.default_rng(0)), 1).to_json())
    doc['delay'] = value
    with pytest.raises(PolicyFileError, match=r'p\.json: delay: expected an integer'):
        policy_from_json(json.dumps(doc), acrobot_problem, 'p.json')


def test_a_delay_beside_a_catch_or_on_a_controller_is_refused():
    pr = load_problem('acrobot_hold')
    policy = random_exemplars(pr, 3, np.random.default_rng(0))
    catch = classical_policy(pr, c=0.1)
    doc = json.loads(with_catch(policy, catch).to_json())
    doc['delay'] = 1
    with pytest.raises(PolicyFileError, match=r"h\.json: delay: a hybrid's delay is its "):
        policy_from_json(json.dumps(doc), pr, 'h.json')
    for other in (catch, with_catch(policy, catch)):
        with pytest.raises(PolicyFileError, match='only a plain exemplar policy'):
            ahead(other, 1)
    with pytest.raises(PolicyFileError,
                       match=r'designed for a delay of 1 MDP step\(s\) already'):
        ahead(ahead(policy, 1), 2)


def test_training_with_a_delay_is_one_run_on_any_thread_count():
    """Robust fitness under latency with the delay-1 selector: the same policy and log on one
    and two evaluation threads; the policy keeps its delay, and its own disturbed episodes
    give the value the run logged."""
    config = TrainConfig(problem='acrobot', steps=400_000, seed=3, delay=1,
                         disturbance='field', episodes=3)
    one = train(dataclasses.replace(config, jobs=1))
    two = train(dataclasses.replace(config, jobs=2))
    set_jobs(0)
    assert one.policy.kind == AHEAD_KIND and one.policy.delay == 1
    assert one.policy.to_json().split('"time"')[0].replace('"jobs": 1', '') == \
        two.policy.to_json().split('"time"')[0].replace('"jobs": 2', '')
    assert [h['best_value'] for h in one.history] == [h['best_value'] for h in two.history]
    from sapga_ros.evaluation.robust import robust_evaluator
    ev = robust_evaluator(one.policy.problem, 0.02, 'field', 3, 'mean', 3)
    assert ev.evaluate([one.policy]).returns[0] == one.policy.meta['value']


@pytest.mark.parametrize('changes, message', [
    ({'catch': 'lqr'}, 'delay: a hybrid acts on the prediction of its catch'),
    ({'method': 'ql'}, 'delay: a Q-table acts on the state it sees'),
    ({'delay': 17}, r'delay: expected an integer in \[0, 16\]'),
])
def test_bad_training_delays_are_refused_before_anything_runs(changes, message):
    with pytest.raises(SapgaError, match=message):
        TrainConfig(problem='acrobot', **{'delay': 1, **changes})


def test_eval_delay_on_the_command_line(tmp_path):
    """sapga eval --delay 1 runs a plain policy file as designed for the delay (under
    latency: the undelayed episode one step later), a file designed for that delay as it is;
    on a Q-table, a hybrid or a policy designed for another delay, exit 2 and one line.
    The JSON says the delay run."""
    out = tmp_path / 'p.json'
    trained('acrobot').save(out)
    r = sapga('eval', out, '--delta', '0.1', '--disturbance', 'latency', '--episodes', '1',
              '--delay', '1', '--json')
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)['success_rate'] == 1.0 and json.loads(r.stdout)['delay'] == 1
    r = sapga('eval', out, '--delta', '0.1', '--disturbance', 'latency', '--episodes', '1',
              '--json')
    assert json.loads(r.stdout)['success_rate'] == 0.0 and json.loads(r.stdout)['delay'] == 0
    delayed = tmp_path / 'd.json'
    delayed.write_text(ahead(policy_from_json(out.read_text()), 1).to_json())
    as_file, as_asked = (sapga('eval', delayed, '--delta', '0.1', '--disturbance', 'latency',
                               '--episodes', '1', '--json', *extra) for extra in
                         ((), ('--delay', '1')))    # its own delay asked again: the same run
    assert as_file.returncode == as_asked.returncode == 0, as_asked.stderr
    assert as_file.stdout == as_asked.stdout and json.loads(as_file.stdout)['delay'] == 1
    q = tmp_path / 'q.json'
    assert sapga('train', '--problem', 'pendulum', '--method', 'ql', '--steps', '20000',
                 '--quiet', '--out', q).returncode == 0
    for f, d in ((delayed, '2'), (q, '1')):
        r = sapga('eval', f, '--delay', d)
        assert r.returncode == 2 and 'Traceback' not in r.stderr
        assert r.stderr.strip().count('\n') == 0 and 'delay: ' in r.stderr, r.stderr
    r = sapga('eval', out, '--delay', '99')
    assert r.returncode == 2 and 'delay: expected an integer in [0, 16]' in r.stderr


def test_a_run_with_a_delay_resumes_as_itself_and_only_as_itself(tmp_path):
    """The delay is a run setting: a run stopped at a checkpoint and resumed ends where the
    uninterrupted one does; resumed with another delay (or none) it is refused, naming
    the setting."""
    from sapga_ros.optim.sapga import SapgaParams
    config = dict(problem='acrobot', seed=4, jobs=1, delay=1, disturbance='latency',
                  params=SapgaParams(n_pop=10, n_child=4, l_min=5, l_max=20))
    full = train(TrainConfig(steps=150_000, **config))
    ck = tmp_path / 'ck'
    first = train(TrainConfig(steps=60_000, checkpoint=str(ck), checkpoint_every=1, **config))
    resumed = train(TrainConfig(steps=150_000, checkpoint=str(ck), resume=True, **config))
    assert first.stats['steps'] < resumed.stats['steps']
    assert resumed.policy.meta['value'] == full.policy.meta['value']
    assert resumed.policy.delay == 1 and full.stats == resumed.stats
    for delay in (0, 2):
        with pytest.raises(SapgaError, match='delay'):
            train(TrainConfig(steps=150_000, checkpoint=str(ck), resume=True,
                              **{**config, 'delay': delay}))


def test_experiment_rows_take_a_delay():
    """A row's ``delay`` reaches its runs, is part of the run key only when set (stored
    runs without it are reused), and is refused beside a catch or on a Q-learning row."""
    from sapga_ros.errors import ConfigError
    from sapga_ros.training.experiment_set import _experiment
    from sapga_ros.training.experiments import run_key
    row = {'id': 1, 'problem': 'acrobot', 'delta': 0.02, 'method': 'sapga', 'steps': 1000}
    delayed = _experiment({**row, 'delay': 1, 'disturbance': 'field', 'episodes': 8},
                          'set.experiments[0]')
    assert delayed.delay == 1
    assert run_key('s', delayed, 0, 1000)['experiment']['delay'] == 1
    assert 'delay' not in run_key('s', _experiment(row, 'e'), 0, 1000)['experiment']
    for bad, message in (({'delay': 1, 'catch': 'lqr'}, "delay: the selector's delay"),
                         ({'delay': 1, 'method': 'ql'}, "delay: the selector's delay"),
                         ({'delay': 17}, r'delay: expected a whole number in \[0, 16\]')):
        with pytest.raises(ConfigError, match=r'set\.experiments\[0\].*' + message):
            _experiment({**row, **bad}, 'set.experiments[0]')


def test_a_delay_is_never_dropped_or_ignored(tmp_path):
    """A delay on a classical or Q-table file is refused, not ignored; pruning unused
    exemplars keeps the delay (and a hybrid's catch); a delayed file seeding a run of
    another delay is refused (a plain one may seed a delayed run); a refused --delay names
    the file."""
    pr = load_problem('acrobot_hold')
    classical = json.loads(classical_policy(pr, c=0.1).to_json())
    classical['delay'] = 1
    (tmp_path / 'c.json').write_text(json.dumps(classical))
    q = tmp_path / 'q.json'
    assert sapga('train', '--problem', 'pendulum', '--method', 'ql', '--steps', '20000',
                 '--quiet', '--out', q).returncode == 0
    doc = json.loads(q.read_text())
    doc['delay'] = 1
    (tmp_path / 'qd.json').write_text(json.dumps(doc))
    for name, words in (('c.json', "delay: a classical policy's delay is its controller's"),
                        ('qd.json', 'delay: a Q-table acts on the state it sees')):
        r = sapga('eval', tmp_path / name)
        assert r.returncode == 2 and r.stderr.strip().count('\n') == 0, r.stderr
        assert f'{tmp_path / name}: {words}' in r.stderr
    delayed = tmp_path / 'd.json'
    trained('acrobot').save(tmp_path / 'p.json')
    delayed.write_text(ahead(policy_from_json((tmp_path / 'p.json').read_text()), 1).to_json())
    hybrid = tmp_path / 'h.json'
    hybrid.write_text(with_catch(random_exemplars(pr, 30, np.random.default_rng(1)),
                                 classical_policy(pr, c=0.1)).to_json())
    for f in (delayed, hybrid):
        out = tmp_path / f'pruned-{f.name}'
        assert sapga('exemplars', f, '--prune-unused', out).returncode == 0
        pruned, whole = json.loads(out.read_text()), json.loads(f.read_text())
        assert pruned.get('delay') == whole.get('delay')
        assert pruned.get('catch') == whole.get('catch')
        assert len(pruned['exemplars']) < len(whole['exemplars'])
        ran = [json.loads(sapga('eval', g, '--json').stdout)['return'] for g in (f, out)]
        assert ran[0] == ran[1]
    r = sapga('train', '--problem', 'acrobot', '--steps', '20000', '--quiet', '--init',
              delayed, '--out', tmp_path / 'x.json')
    assert r.returncode == 2 and 'designed for a delay of 1' in r.stderr
    assert not (tmp_path / 'x.json').exists()
    assert sapga('train', '--problem', 'acrobot', '--steps', '20000', '--quiet', '--init',
                 delayed, '--delay', '1', '--out', tmp_path / 'y.json').returncode == 0
    assert sapga('train', '--problem', 'acrobot', '--steps', '20000', '--quiet', '--init',
                 tmp_path / 'p.json', '--delay', '1', '--out',
                 tmp_path / 'z.json').returncode == 0
    r = sapga('eval', delayed, '--delay', '2')
    assert r.returncode == 2 and f'{delayed}: delay: the policy is designed for' in r.stderr


def test_a_hybrid_seeds_only_a_run_behind_its_own_catch(tmp_path):
    """A hybrid file seeding a run without a catch, or behind a catch designed for another
    delay, is refused with one line naming the file and what to give (its exemplars were
    evolved behind its catch); behind the same catch it seeds the run.  A classical file
    (no exemplars) seeds none."""
    pr = load_problem('acrobot_hold')
    hybrid = tmp_path / 'h.json'
    hybrid.write_text(with_catch(random_exemplars(pr, 5, np.random.default_rng(2)),
                                 classical_policy(pr, delay=2)).to_json())   # the design's
    base = ('train', '--problem', 'acrobot_hold', '--steps', '20000', '--quiet', '--init',
            hybrid)
    for extra in ((), ('--catch', 'lqr'), ('--catch', 'lqr', '--catch-delay', '1')):
        r = sapga(*base, *extra, '--out', tmp_path / 'x.json')
        assert r.returncode == 2 and r.stderr.strip().count('\n') == 0, r.stderr
        assert f'{hybrid}: a hybrid whose catch is designed for a delay of 2' in r.stderr
        assert '--catch lqr --catch-delay 2' in r.stderr and not (tmp_path / 'x.json').exists()
    r = sapga(*base, '--catch', 'lqr', '--catch-delay', '2', '--out', tmp_path / 'y.json')
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / 'y.json').read_text())['catch']['delay'] == 2
    classical = tmp_path / 'c.json'
    classical.write_text(classical_policy(pr, c=0.1, delay=1).to_json())
    for extra in ((), ('--delay', '1'), ('--catch', 'lqr', '--catch-delay', '1')):
        r = sapga('train', '--problem', 'acrobot_hold', '--steps', '20000', '--quiet',
                  '--init', classical, *extra, '--out', tmp_path / 'z.json')
        assert r.returncode == 2 and r.stderr.strip().count('\n') == 0, r.stderr
        assert f'{classical}: a classical policy has no exemplars to seed a run' in r.stderr
    r = sapga('eval', tmp_path / 'y.json', '--json')
    assert r.returncode == 0 and json.loads(r.stdout)['delay'] == 0   # a hybrid's: its catch's


def test_the_report_tables_name_a_rows_delay_catch_and_robust_fitness():
    """The report's results table names what a row's policies run behind and were trained
    against, as the console summary and the curves' legends do."""
    from sapga_ros.training.experiment_report import row_method
    from sapga_ros.viz.report import _row
    final = {'achieved': 1, 'runs': 2, 'delta_star_mean': 0.1, 'delta_star_std': 0.0,
             'best_value_mean': -1.0, 'best_value_std': 0.0}
    row = {'id': 6, 'problem': 'acrobot', 'delta': 0.02, 'method': 'sapga', 'steps': 1000,
           'final': final, 'delay': 1, 'disturbance': 'field', 'episodes': 8}
    words = 'acting 1 step ahead robust (field, K = 8)'
    assert f'SAP-GA {words} |' in _row(row) and row_method(row) == f'sapga {words}'
    hybrid = {**row, 'delay': 0, 'disturbance': 'none', 'catch': 'lqr', 'catch_delay': 1}
    assert 'SAP-GA + LQR catch (delay 1) |' in _row(hybrid)
