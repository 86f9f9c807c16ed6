"""The hybrid's evolved catch region: each SAP-GA individual's catch scale is inherited from
a parent and mutated log-normally from a generator of its own; the returned policy carries
the best individual's c; checkpoints keep scales and generator; bad settings are one line."""
import json

import numpy as np
import pytest

from process_helpers import sapga_in_process
from sapga_ros.evaluation.classical_design import classical_policy
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.io.checkpoint import load_checkpoint, save_checkpoint
from sapga_ros.optim.population import SCALE_RANGE
from sapga_ros.optim.sapga import SapGA, SapgaParams
from sapga_ros.policies.classical import ControlledPolicy, with_catch
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.training.loop import TrainConfig, train_sapga
from sim_nodes.problem import load_problem

SMALL = SapgaParams(n_pop=20, n_child=4, l_min=10, l_max=20)
PROBLEM = 'acrobot_hold'


def _design(problem):
    return with_catch(ExemplarPolicy(problem, np.zeros((0, problem.dim))),
                      classical_policy(problem))


def _generation(ga, evaluator):
    r = evaluator.evaluate(ga.ask())
    ga.tell(r.returns, r.delta_star, r.steps, r.reached, r.used)


def test_sigma_zero_keeps_every_scale_one_and_the_run_of_the_shared_catch():
    """Evolving with sigma 0 changes nothing: every scale stays 1.0 and the population, its
    values and the main generator are those of the run whose evaluator holds the one catch."""
    problem = load_problem(PROBLEM)
    catch = _design(problem)
    shared, own = Evaluator(problem), Evaluator(problem)
    shared.catch = catch.control
    today = SapGA.create(problem, SMALL, seed=3)
    evolving = SapGA.create(problem, SMALL, seed=3)
    evolving.evolve_catch(catch, 0.0, seed=3)
    for _ in range(3):
        _generation(today, shared)
        _generation(evolving, own)
    assert [m.scale for m in evolving.population] == [1.0] * SMALL.n_pop
    assert [m.value for m in today.population] == [m.value for m in evolving.population]
    assert all(np.array_equal(a.policy.states, b.policy.states)
               for a, b in zip(today.population, evolving.population))
    assert today.rng.bit_generator.state == evolving.rng.bit_generator.state


def test_a_child_inherits_a_parents_scale_mutated_and_clipped():
    """Each child's scale is one of its parents' (both parents hand theirs on) times the
    mutation; its policy's c is the design's c times it; the range clips it."""
    problem = load_problem(PROBLEM)
    catch = _design(problem)
    ga = SapGA.create(problem, SMALL, seed=4)
    ga.evolve_catch(catch, 1e-9, seed=4)
    for k, m in enumerate(ga.population):
        m.scale = 2.0 ** (k / 4 - 2)                      # distinct, inside the range
    policies = ga.ask()
    by_member = {id(m): p for m, p in zip(ga._pending, policies)}
    inherited = set()
    for i, j, members in ga._families:
        parents = (ga.population[i].scale, ga.population[j].scale)
        for kid in members[2:]:
            near = [s for s in parents if abs(kid.scale / s - 1) < 1e-6]
            assert near, (kid.scale, parents)
            inherited.add(near[0] == parents[0])
            policy = by_member[id(kid)]
            assert isinstance(policy, ControlledPolicy)
            assert policy.c == catch.c * kid.scale
    assert inherited == {True, False}                      # both parents hand theirs on

    ga = SapGA.create(problem, SMALL, seed=4)
    ga.evolve_catch(catch, 0.5, seed=4)
    for m in ga.population:
        m.scale = SCALE_RANGE[1]
    ga.ask()
    kids = [kid.scale for _, _, members in ga._families for kid in members[2:]]
    assert max(kids) == SCALE_RANGE[1] and min(kids) < SCALE_RANGE[1]   # clipped, mutated
    below = [k for k in kids if k < SCALE_RANGE[1]]
    assert len(set(below)) == len(below) >= len(kids) // 4   # each child its own draw


def test_the_refreshed_clone_keeps_its_stars_scale():
    """After tell, each family's two places (its best member and that one's refreshed
    clone) share one scale."""
    problem = load_problem(PROBLEM)
    ga = SapGA.create(problem, SMALL, seed=5)
    ga.evolve_catch(_design(problem), 0.5, seed=5)
    ga.ask()
    places = [(i, j) for i, j, _ in ga._families]
    r = Evaluator(problem).evaluate([with_catch(m.policy, ga.catch, m.scale)
                                     for m in ga._pending])
    ga.tell(r.returns, r.delta_star, r.steps, r.reached, r.used)
    for i, j in places:
        assert ga.population[i].scale == ga.population[j].scale


def test_the_returned_policy_carries_the_best_scale_and_evaluates_to_its_value(tmp_path):
    """The file's catch.c is the best individual's scale x the design's c, and sapga eval of
    the file gives the run's value of that policy."""
    problem = load_problem(PROBLEM)
    result = train_sapga(TrainConfig(problem=PROBLEM, steps=60_000, seed=2, params=SMALL,
                                     catch='lqr', catch_sigma=0.5, jobs=1))
    policy = result.policy
    scale = policy.meta['catch_scale']
    assert scale != 1.0 or len({r['best_value'] for r in result.history}) == 1
    assert policy.c == _design(problem).c * scale
    out = tmp_path / 'hybrid.json'
    out.write_text(policy.to_json())
    got = sapga_in_process(['eval', out, '--json'])
    assert got.returncode == 0, got.stderr
    assert json.loads(got.stdout)['return'] == policy.meta['value']
    assert json.loads(out.read_text())['catch']['c'] == policy.c


def test_kill_and_resume_with_the_catch_evolving_equals_the_uninterrupted_run(tmp_path):
    """Scales and their generator are checkpointed: a resumed run ends where the
    uninterrupted one does; resuming with another catch_sigma is refused."""
    config = dict(problem=PROBLEM, seed=6, params=SMALL, catch='lqr', catch_sigma=0.5,
                  jobs=1)
    full = train_sapga(TrainConfig(steps=100_000, **config))
    ck = tmp_path / 'ck'
    first = train_sapga(TrainConfig(steps=45_000, checkpoint=str(ck), checkpoint_every=1,
                                    **config))
    resumed = train_sapga(TrainConfig(steps=100_000, checkpoint=str(ck), resume=True,
                                      **config))
    assert first.stats['steps'] < resumed.stats['steps']
    assert resumed.policy.c == full.policy.c
    assert resumed.policy.meta['value'] == full.policy.meta['value']
    assert np.array_equal(resumed.policy.states, full.policy.states)
    assert full.stats == resumed.stats
    assert [r['best_value'] for r in full.history] == [r['best_value'] for r in resumed.history]
    with pytest.raises(Exception, match='catch_sigma'):
        train_sapga(TrainConfig(steps=100_000, checkpoint=str(ck), resume=True,
                                **{**config, 'catch_sigma': 0.25}))
    # the catch itself is part of the run: resumed without it, or designed for another
    # delay, the checkpoint is refused, naming what differs
    with pytest.raises(Exception, match='catch lqr'):
        train_sapga(TrainConfig(steps=100_000, checkpoint=str(ck), resume=True,
                                **{**config, 'catch': 'none', 'catch_sigma': 0.0}))
    with pytest.raises(Exception, match='catch_delay 0.*catch_delay 1'):
        train_sapga(TrainConfig(steps=100_000, checkpoint=str(ck), resume=True,
                                **{**config, 'catch_delay': 1}))
    # a checkpoint written before the catch was a run setting still resumes, as the hybrid
    # its settings record, and only as that
    meta, arrays = load_checkpoint(str(ck))
    meta['run'] = {k: v for k, v in meta['run'].items() if k not in ('catch', 'catch_delay')}
    save_checkpoint(str(ck), meta, arrays)
    again = train_sapga(TrainConfig(steps=100_000, checkpoint=str(ck), resume=True, **config))
    assert again.policy.meta['value'] == full.policy.meta['value']
    with pytest.raises(Exception, match='catch_delay 1'):
        train_sapga(TrainConfig(steps=100_000, checkpoint=str(ck), resume=True,
                                **{**config, 'catch_delay': 1}))


@pytest.mark.parametrize('args, needle', [
    (['--catch', 'lqr', '--catch-sigma', '-1'], 'catch_sigma'),
    (['--catch', 'lqr', '--catch-sigma', 'nan'], 'catch_sigma'),
    (['--catch', 'lqr', '--catch-sigma', '9'], 'catch_sigma'),
    (['--catch-sigma', '0.5'], 'needs catch lqr'),
])
def test_bad_catch_sigma_is_one_line_and_exit_2(args, needle, tmp_path):
    r = sapga_in_process(['train', '--problem', PROBLEM, '--steps', '1000', '--out',
                          tmp_path / 'p.json', *args])
    assert r.returncode == 2 and needle in r.stderr and 'Traceback' not in r.stderr
    errors = [line for line in r.stderr.splitlines() if 'error' in line]
    assert len(errors) == 1
    assert not (tmp_path / 'p.json').exists()


def test_a_hybrid_seed_keeps_its_evolved_region_or_is_refused(tmp_path):
    """A hybrid seeding a run behind the same catch design starts with its own region (c
    over the design's) where regions evolve; where they do not, or its LQR is another
    design's, the run is refused with one line: nothing of the seed is dropped unsaid."""
    import dataclasses as dc
    from sapga_ros.errors import ConfigError
    from sapga_ros.optim.operators import random_exemplars
    from sapga_ros.policies.classical import with_catch
    from sapga_ros.training.loop import TrainConfig, _rounds, train
    pr = load_problem('acrobot_hold')
    design = classical_policy(pr, delay=1)
    seed = with_catch(random_exemplars(pr, 5, np.random.default_rng(3)), design, 7.0)
    base = TrainConfig(problem='acrobot_hold', steps=3_000, jobs=1, catch='lqr',
                       catch_delay=1, params=SapgaParams(n_pop=4, n_child=2, l_min=3,
                                                         l_max=6))
    rounds = _rounds(dc.replace(base, catch_sigma=0.3), [seed])
    first = next(rounds).population        # before the first generation
    rounds.close()
    assert first[0].scale == pytest.approx(7.0, rel=1e-12)
    assert [m.scale for m in first[1:]] == [1.0] * 3
    with pytest.raises(ConfigError, match=r'initial policy 0: its catch region is 7 x the '
                                          r"design's; this run keeps the design's"):
        train(base, [seed])
    other = with_catch(seed, classical_policy(pr, delay=0), 1.0)
    with pytest.raises(ConfigError, match="initial policy 0: its catch is not this run's"):
        train(base, [other])
