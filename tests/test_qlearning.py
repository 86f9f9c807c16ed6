"""The tabular Q-learning baseline (SPEC 3.4): determinism, resume, its policy file."""
import numpy as np
import pytest

from sapga_ros.errors import PolicyFileError
from sapga_ros.optim.qlearning import QTable, parse_json, qtable_from_document
from sapga_ros.training.ql_run import train_ql
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
