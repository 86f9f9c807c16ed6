"""The tabular Q-learning baseline (SPEC 3.4): determinism, resume, its policy file."""
import numpy as np
import pytest

from sapga_ros.errors import PolicyFileError
from sapga_ros.policies.jsonfile import parse_json
from sapga_ros.policies.qtable import QTable, qtable_from_document
from ql_run import train_ql
from sapga_ros.training.loop import TrainConfig
from sim_nodes.problem import load_problem


def _cfg(**kw):
    base = dict(problem='pdip_single', method='ql', delta=0.05, steps=300_000, seed=3)
    base.update(kw)
    return TrainConfig(**base)


def test_tiling_has_twenty_to_the_d_cells_on_the_configured_coordinates():
    """N_tile = 20^4 for the acrobot and for pdip_single's (x, v, theta1, theta1_dot)."""
    for name, idx in (('acrobot', (0, 1, 2, 3)), ('pdip_single', (0, 1, 2, 4))):
        pr = load_problem(name)
        assert pr.ql_state_indices == idx
        assert pr.ql_tiles_per_dim ** len(idx) == 160_000


def test_same_seed_same_table_and_other_seed_differs():
    """Q-learning is reproducible from its seed."""
    a, b = train_ql(_cfg()), train_ql(_cfg())
    c = train_ql(_cfg(seed=4))
    np.testing.assert_array_equal(a.policy.q, b.policy.q)
    assert a.history[-1]['best_value'] == b.history[-1]['best_value']
    assert not np.array_equal(a.policy.q, c.policy.q)


def test_only_visited_cells_learn_and_values_stay_finite():
    """Every non-zero Q entry belongs to a visited cell; rewards are negative so learnt
    values are <= 0 (gamma = 1, Q starts at 0)."""
    r = train_ql(_cfg(problem='acrobot', delta=0.1))
    q, visited = r.policy.q, r.policy.visited
    assert np.all(q[~visited] == 0.0)
    assert visited.sum() > 10
    assert np.all(np.isfinite(q)) and np.all(q <= 0.0)


def test_checkpoint_resume_gives_the_identical_table(tmp_path):
    """A Q-learning run resumed from its checkpoint ends with the same table."""
    full = train_ql(_cfg(steps=2_500_000))
    ck = str(tmp_path / 'ck')
    train_ql(_cfg(steps=1_000_000, checkpoint=ck))
    resumed = train_ql(_cfg(steps=2_500_000, checkpoint=ck, resume=True))
    np.testing.assert_array_equal(full.policy.q, resumed.policy.q)
    assert full.stats == resumed.stats


def test_qtable_file_round_trip_runs_the_same_greedy_episode(tmp_path):
    """A saved sapga-qtable/1 document loads back to a table whose greedy episode is the
    one measured at the end of training."""
    r = train_ql(_cfg())
    path = r.policy.save(tmp_path / 'q.json')
    table = qtable_from_document(parse_json(path.read_bytes(), str(path)), str(path))
    assert isinstance(table, QTable)
    ep = table.episode(0.05)
    assert ep.ret == r.policy.meta['value'] and ep.steps == r.policy.meta['steps_to_end']


@pytest.mark.parametrize('mutate, message', [
    (lambda d: d.update(problem='nope'), 'problem'),
    (lambda d: d['q'].update({'99999999': [0, 0, 0]}), 'cell'),
    (lambda d: d['q'].update({'1': [0, 0]}), r'q\[1\]'),
    (lambda d: d.update(tiles_per_dim=10), 'tiling'),
])
def test_bad_qtable_documents_are_refused(mutate, message):
    """Inconsistent Q-table documents are refused with the field named."""
    table = train_ql(_cfg(steps=20_000)).policy
    doc = parse_json(table.to_json().encode(), 'q.json')
    mutate(doc)
    with pytest.raises(PolicyFileError, match=message):
        qtable_from_document(doc, 'q.json')


# --- runs side by side (lanes) -----------------------------------------------------------

def _alone_and_together(problem, delta, seeds, budgets, chunk):
    """The runs of ``seeds`` learnt alone, and learnt side by side with learn_together
    (runs drop out as their budgets end; chunks end at different steps in each lane)."""
    from sapga_ros.optim.qlearner import QLearning, QlParams, learn_together
    pr = load_problem(problem)

    def create(seed, budget):
        return QLearning.create(pr, QlParams(chunk_steps=chunk), seed, delta, budget)
    alone = []
    for seed, budget in zip(seeds, budgets):
        opt = create(seed, budget)
        while not opt.stop(budget):
            opt.ask()
        alone.append(opt)
    together = [create(s, b) for s, b in zip(seeds, budgets)]
    rounds = 0
    while going := [o for o, b in zip(together, budgets) if not o.stop(b)]:
        learn_together(going)
        for opt in going:
            opt.ask()
        rounds += 1
    return alone, together, rounds


@pytest.mark.parametrize('problem,delta', [('acrobot', 0.1), ('pdip_single', 0.01),
                                           ('mountain_car', 0.05)])
def test_runs_learnt_side_by_side_are_bit_identical_to_runs_alone(problem, delta):
    """Nine runs (more than one vector block of lanes) with different seeds and budgets
    learnt together end with exactly the table, visited marks, generator word and counters
    of each run learnt alone."""
    seeds = [0, 1, 2, 3, 4, 5, 6, 7, 11]
    budgets = [60_000, 45_000, 60_000, 5_000, 60_000, 30_001, 60_000, 60_000, 12_345]
    alone, together, rounds = _alone_and_together(problem, delta, seeds, budgets, 4_000)
    assert rounds == 15                        # the longest run's chunks
    for a, t in zip(alone, together):
        np.testing.assert_array_equal(a.q, t.q)
        np.testing.assert_array_equal(a.visited, t.visited)
        assert a.rng[0] == t.rng[0] and a.counters() == t.counters()
        assert a.steps >= a.budget
    assert len({t.rng[0] for t in together}) == len(seeds)   # the lanes did differ


def test_side_by_side_needs_one_problem_and_goal():
    from sapga_ros.optim.qlearner import QLearning, QlParams, learn_together
    pr = load_problem('acrobot')
    a = QLearning.create(pr, QlParams(), 0, 0.1, 10_000)
    b = QLearning.create(pr, QlParams(), 1, 0.2, 10_000)
    c = QLearning.create(load_problem('pdip_single'), QlParams(), 1, 0.1, 10_000)
    for pair in ((a, b), (a, c)):
        with pytest.raises(ValueError, match='share the problem and the goal'):
            learn_together(list(pair))


def test_train_lanes_equals_train_run_by_run():
    """The training loop's side-by-side form gives each run's log and policy as ``train``
    does (timing aside), chunk by chunk, with budgets that end at different chunks."""
    from sapga_ros.optim.qlearner import QlParams
    from sapga_ros.training.loop import train, train_lanes
    configs = [_cfg(seed=s, steps=st, ql=QlParams(chunk_steps=50_000))
               for s, st in ((0, 180_000), (1, 120_000), (2, 180_000))]
    together = train_lanes(configs)
    for config, t in zip(configs, together):
        a = train(config)
        np.testing.assert_array_equal(a.policy.q, t.policy.q)
        assert a.stats == t.stats and a.stop == t.stop

        def untimed(rows):
            return [{k: v for k, v in r.items() if k != 'steps_per_s'} for r in rows]
        assert untimed(a.history) == untimed(t.history) and len(a.history) > 2
        assert {k: v for k, v in a.policy.meta.items() if k != 'time'} == \
            {k: v for k, v in t.policy.meta.items() if k != 'time'}
