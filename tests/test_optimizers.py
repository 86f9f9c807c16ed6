"""The optimizer contract (sapga_ros/optim/base.py) as SAP-GA, Q-learning and CMA-ES keep it:
ask / tell / stop / result, and a state_dict that continues a run to the identical result."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sapga_ros.errors import CheckpointError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.base import Optimizer
from sapga_ros.optim.cmaes import Cmaes, CmaesParams
from sapga_ros.optim.qlearner import QLearning, QlParams
from sapga_ros.optim.sapga import SapGA, SapgaParams

DELTA = 0.1
BUDGET = 60_000


def _make(method: str, problem) -> Optimizer:
    if method == 'sapga':
        return SapGA.create(problem, SapgaParams(n_pop=8, n_child=2, l_min=5, l_max=10), 4)
    if method == 'cmaes':
        return Cmaes.create(problem, CmaesParams(exemplars=6, popsize=6), 4)
    return QLearning.create(problem, QlParams(chunk_steps=10_000), 4, DELTA, BUDGET)


def _round(opt: Optimizer, evaluator: Evaluator) -> None:
    batch = opt.ask()
    if batch:
        r = evaluator.evaluate(batch)
        opt.tell(r.returns, r.delta_star, r.steps, r.reached, r.used)
    else:
        opt.tell(np.empty(0), np.empty(0), np.empty(0, np.int64), np.empty(0, bool), [])


def _copy(state):
    meta, arrays = state
    return json.loads(json.dumps(meta)), {k: v.copy() for k, v in arrays.items()}


@pytest.mark.parametrize('method', ['sapga', 'ql', 'cmaes'])
def test_ask_tell_until_stop_gives_a_result(method, acrobot_problem):
    """Rounds go on until stop(budget) names the budget; result is a policy with its
    measures, and the counters account for every step."""
    opt = _make(method, acrobot_problem)
    evaluator = Evaluator(acrobot_problem, DELTA)
    assert opt.stop(BUDGET) == {} and opt.iteration == 0
    while not opt.stop(BUDGET):
        _round(opt, evaluator)
    assert opt.stop(BUDGET) == {'budget': BUDGET} and opt.iteration >= 1
    assert opt.counters()['steps'] == opt.steps >= BUDGET
    result = opt.result
    assert result.meta['method'] == method and result.meta['steps'] == opt.steps
    assert result.meta['run_delta_star'] == opt.counters()['delta_star']


@pytest.mark.parametrize('method', ['sapga', 'ql', 'cmaes'])
def test_state_dict_continues_to_the_identical_result(method, acrobot_problem):
    """An optimizer restored from state_dict() (through JSON and copied arrays, as a
    checkpoint does) takes the same rounds as the one that goes on."""
    evaluator = Evaluator(acrobot_problem, DELTA)
    first = _make(method, acrobot_problem)
    for _ in range(2):
        _round(first, evaluator)
    params = first.params
    second = type(first).from_state(acrobot_problem, params, _copy(first.state_dict()),
                                    delta=DELTA, budget=BUDGET)
    for opt in (first, second):
        for _ in range(2):
            _round(opt, evaluator)
    assert first.counters() == second.counters()
    a, b = first.result, second.result
    assert a.meta['value'] == b.meta['value']
    if method == 'ql':
        assert np.array_equal(a.policy.q, b.policy.q)
    else:
        assert np.array_equal(a.policy.states, b.policy.states)
        assert np.array_equal(a.policy.actions, b.policy.actions)


@pytest.mark.parametrize('damage, needle', [
    (lambda meta, arrays: arrays.update(rng=np.zeros(1, np.uint64)), 'generator'),
    (lambda meta, arrays: arrays.update(rng=np.ones(2, np.int64)), 'generator'),
    (lambda meta, arrays: arrays['q'].__setitem__((0, 0), np.nan), 'Q-table'),
    (lambda meta, arrays: arrays.update(visited=arrays['visited'][:-1]), 'visited'),
    (lambda meta, arrays: meta.pop('episodes'), 'malformed'),
    (lambda meta, arrays: meta.update(steps='many'), 'malformed'),
])
def test_a_damaged_q_learning_state_is_refused(damage, needle, acrobot_problem):
    """A Q-learning checkpoint with a zero or misshapen generator, a non-finite table, short
    visited marks or missing counters is a CheckpointError naming what is wrong."""
    opt = _make('ql', acrobot_problem)
    _round(opt, Evaluator(acrobot_problem, DELTA))
    meta, arrays = _copy(opt.state_dict())
    damage(meta, arrays)
    with pytest.raises(CheckpointError, match=needle):
        QLearning.from_state(acrobot_problem, opt.params, (meta, arrays), delta=DELTA,
                             budget=BUDGET)


@pytest.mark.parametrize('damage, needle', [
    (lambda meta, arrays: arrays.update(told=arrays['told'][:, :-1]), 'told values'),
    (lambda meta, arrays: arrays['told'].__setitem__((0, 0), np.nan), 'told fitness'),
    (lambda meta, arrays: arrays.update(told=arrays['told'][:-1]), 'generator state'),
    (lambda meta, arrays: arrays.update(best_x=arrays['best_x'][:-1]), 'best candidate'),
    (lambda meta, arrays: meta.pop('rng'), 'malformed'),
    (lambda meta, arrays: meta.update(seed='zero'), 'malformed'),
])
def test_a_damaged_cmaes_state_is_refused(damage, needle, acrobot_problem):
    """A CMA-ES checkpoint whose recorded generations are misshapen, NaN, altered or cut
    short (the replay then misses the saved generator state), whose best candidate is
    misshapen or whose counters are missing is a CheckpointError naming what is wrong."""
    opt = _make('cmaes', acrobot_problem)
    evaluator = Evaluator(acrobot_problem, DELTA)
    for _ in range(3):
        _round(opt, evaluator)
    meta, arrays = _copy(opt.state_dict())
    damage(meta, arrays)
    with pytest.raises(CheckpointError, match=needle):
        Cmaes.from_state(acrobot_problem, opt.params, (meta, arrays))
