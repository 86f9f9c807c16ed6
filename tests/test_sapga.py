"""SAP-GA as a whole: family alternation, value caching, budget, determinism,
checkpoint/resume (SPEC 3.2)."""
import json
import math

import numpy as np
import pytest

from sapga_ros.errors import CheckpointError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.sapga import SapGA, SapgaParams
from sapga_ros.training.loop import TrainConfig, train_sapga
from sim_nodes.problem import load_problem

SMALL = SapgaParams(n_pop=20, n_child=4, l_min=10, l_max=20)


def _run(config, **kw):
    return train_sapga(config, **kw)


def _same_policy(a, b):
    return (np.array_equal(a.states, b.states) and np.array_equal(a.actions, b.actions)
            and a.meta['value'] == b.meta['value'])


def test_family_alternation_keeps_best_and_evaluates_only_unknown_members():
    """After a generation each family's best member survives, its refreshed twin takes the
    other place, and only members without a known value were evaluated."""
    problem = load_problem('acrobot')
    ga = SapGA.create(problem, SMALL, seed=3)
    ev = Evaluator(problem, 0.02)
    batch = ga.ask()
    assert len(batch) == SMALL.n_pop + SMALL.n_pop // 2 * SMALL.n_child  # all unknown
    families = ga._families
    r = ev.evaluate(batch)
    ga.tell(r.returns, r.delta_star, r.steps, r.reached, r.used)
    for i, j, members in families:
        star = max(members, key=lambda m: m.value)
        assert ga.population[i] is star
        assert len(ga.population[j].policy) == len(star.policy)
    batch2 = ga.ask()
    # second generation: survivors are known; only twins that changed and children need it
    unknown_parents = sum(not m.known for m in ga.population)
    assert len(batch2) == unknown_parents + SMALL.n_pop // 2 * SMALL.n_child
    assert unknown_parents <= SMALL.n_pop // 2


def test_values_are_the_evaluated_returns_and_best_never_decreases():
    """The log's best value is monotone, budget counts simulated steps, and the final
    policy's recorded value is what evaluating it again gives (evaluation is deterministic)."""
    cfg = TrainConfig(problem='acrobot', delta=0.05, steps=150_000, seed=1, params=SMALL)
    result = _run(cfg)
    best = [row['best_value'] for row in result.history]
    assert best == sorted(best)
    assert result.history[-1]['steps'] >= cfg.steps
    assert result.stats['steps'] == result.history[-1]['steps']
    ep = Evaluator(load_problem('acrobot'), 0.05).episode(result.policy)
    assert ep.ret == result.policy.meta['value']
    assert ep.delta_star == result.policy.meta['delta_star']


def test_same_seed_same_result_and_other_seed_differs():
    """Two runs with one seed give the identical policy and log; another seed does not."""
    cfg = TrainConfig(problem='pdip', delta=0.05, steps=100_000, seed=7, params=SMALL)
    a, b = _run(cfg), _run(cfg)
    c = _run(TrainConfig(problem='pdip', delta=0.05, steps=100_000, seed=8, params=SMALL))
    assert _same_policy(a.policy, b.policy)
    strip = [{k: v for k, v in r.items() if k != 'steps_per_s'} for r in a.history]
    assert strip == [{k: v for k, v in r.items() if k != 'steps_per_s'} for r in b.history]
    assert not _same_policy(a.policy, c.policy)


def test_checkpoint_and_resume_continue_to_the_identical_result(tmp_path):
    """A run stopped after a checkpoint and resumed ends exactly where an uninterrupted run
    ends (population, generator and counters all restored)."""
    full = _run(TrainConfig(problem='acrobot', delta=0.05, steps=200_000, seed=5,
                            params=SMALL))
    ck = tmp_path / 'ck'
    first = _run(TrainConfig(problem='acrobot', delta=0.05, steps=90_000, seed=5,
                             params=SMALL, checkpoint=str(ck), checkpoint_every=1))
    assert (ck / 'checkpoint.npz').is_file()
    resumed = _run(TrainConfig(problem='acrobot', delta=0.05, steps=200_000, seed=5,
                               params=SMALL, checkpoint=str(ck), resume=True))
    assert first.stats['steps'] < resumed.stats['steps']
    assert _same_policy(full.policy, resumed.policy)
    assert full.stats == resumed.stats
    assert [r['best_value'] for r in full.history] == [r['best_value'] for r in resumed.history]


def test_resume_refuses_a_checkpoint_of_another_run(tmp_path):
    """Resuming with other settings than the checkpoint's is refused, naming the mismatch."""
    ck = tmp_path / 'ck'
    _run(TrainConfig(problem='acrobot', steps=20_000, seed=1, params=SMALL,
                     checkpoint=str(ck)))
    with pytest.raises(CheckpointError, match='checkpoint is of seed 1; this run: seed 2$'):
        _run(TrainConfig(problem='acrobot', steps=40_000, seed=2, params=SMALL,
                         checkpoint=str(ck), resume=True))


def test_corrupt_checkpoint_is_refused_and_missing_one_named(tmp_path):
    """A truncated checkpoint file or an absent one gives a CheckpointError, not a crash."""
    ck = tmp_path / 'ck'
    cfg = TrainConfig(problem='acrobot', steps=20_000, seed=1, params=SMALL,
                      checkpoint=str(ck))
    _run(cfg)
    data = (ck / 'checkpoint.npz').read_bytes()
    (ck / 'checkpoint.npz').write_bytes(data[:len(data) // 2])
    resume = TrainConfig(problem='acrobot', steps=40_000, seed=1, params=SMALL,
                         checkpoint=str(ck), resume=True)
    with pytest.raises(CheckpointError, match='checkpoint'):
        _run(resume)
    with pytest.raises(CheckpointError, match='no checkpoint'):
        _run(TrainConfig(problem='acrobot', steps=40_000, seed=1, params=SMALL,
                         checkpoint=str(tmp_path / 'none'), resume=True))


def test_initial_exemplars_enter_the_population():
    """Hand-written exemplars given as prior knowledge are the first initial policies."""
    problem = load_problem('acrobot')
    from sapga_ros.policies.exemplar import ExemplarPolicy
    prior = ExemplarPolicy(problem, [[problem.initial[0], 0.0, 0.0, 0.0]] * 1, [2])
    ga = SapGA.create(problem, SMALL, seed=0, initial=[prior])
    np.testing.assert_array_equal(ga.population[0].policy.states, prior.states)
    assert len(ga.population) == SMALL.n_pop


def test_progress_callbacks_report_each_generation_and_improvements():
    """progress is called once per generation and on_best with each better policy."""
    rows, bests = [], []
    cfg = TrainConfig(problem='acrobot', steps=60_000, seed=2, params=SMALL)
    result = _run(cfg, progress=rows.append, on_best=bests.append)
    assert len(rows) == len(result.history) and rows
    values = [p.meta['value'] for p in bests]
    assert values == sorted(values) and len(set(values)) == len(values)
    assert values[-1] == result.policy.meta['value']
    json.dumps(result.policy.to_document())  # meta is JSON-serialisable
    assert math.isfinite(result.policy.meta['value'])


@pytest.mark.parametrize('variant', ['paper', 'child-ties', 'dstar', 'dstar-child'])
def test_tell_takes_a_generation_as_taking_its_members_one_by_one(variant):
    """``tell`` takes the whole generation's results at once; the run's best, best value,
    delta*, steps and evaluation count are what taking the members one at a time in order
    gives, with NaN and infinite returns ranked worst, NaN delta* never lowering the run's,
    and ties going to the first member."""
    problem = load_problem('acrobot')
    rng = np.random.default_rng(7)
    for trial in range(12):
        ga = SapGA.create(problem, SapgaParams(n_pop=10, n_child=3, l_min=2, l_max=4,
                                               variant=variant), seed=trial)
        for generation in range(3):
            batch = ga.ask()
            n = len(batch)
            returns = rng.choice([-3.0, -2.0, -1.0, math.nan, math.inf, -math.inf], n)
            dstar = rng.choice([0.1, 0.2, 0.3, math.nan, math.inf], n)
            steps = rng.integers(0, 500, n)
            reached = rng.random(n) < 0.5
            used = [np.ones(len(p), dtype=np.bool_) for p in batch]
            before = (ga.best, ga.stats.best_value, ga.stats.delta_star, ga.stats.steps,
                      ga.stats.evaluations)
            pending = list(ga._pending)
            best, best_value, run_dstar, total, count = before
            best_key = ga._rank(best) if best is not None else None
            for m, value, d in zip(pending, returns.tolist(), dstar.tolist()):
                value = value if math.isfinite(value) else -math.inf
                key = ((-d if not math.isnan(d) else -math.inf, value)
                       if variant.startswith('dstar') else value)
                if best is None or key > best_key:
                    best, best_key = m, key
                run_dstar = min(run_dstar, d)
                best_value = max(best_value, value)
            ga.tell(returns, dstar, steps, reached, used)
            assert ga.best is best
            assert ga.stats.best_value == best_value
            assert ga.stats.delta_star == run_dstar or (
                math.isnan(ga.stats.delta_star) and math.isnan(run_dstar))
            assert ga.stats.steps == total + int(steps.sum())
            assert ga.stats.evaluations == count + n
            for m, value, d, k in zip(pending, returns.tolist(), dstar.tolist(), steps):
                assert m.value == (value if math.isfinite(value) else -math.inf)
                assert m.delta_star == d or (math.isnan(d) and math.isnan(m.delta_star))
                assert m.steps == k and type(m.steps) is int
