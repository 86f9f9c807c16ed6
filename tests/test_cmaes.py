"""The CMA-ES peer (``sapga_ros.optim.cmaes``): the decoding of a candidate, a short run that
learns, determinism for a seed, and a recorded best value that its episode reproduces."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sapga_ros.evaluation.evaluator import BatchResult, Evaluator
from sapga_ros.optim.cmaes import CmaesParams, CmaesSearch, decode, genes, train_cmaes
from sim_nodes.problem import load_problem

BUDGET = 200_000


@pytest.fixture(scope='module')
def acrobot_run() -> tuple:
    """A CMA-ES run on the acrobot of BUDGET MDP steps, seed 11."""
    return train_cmaes('acrobot', None, BUDGET, 11)


def without_timing(history: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k != 'steps_per_s'} for row in history]


def test_genes_decode_onto_the_state_bounds_and_the_action_indices(acrobot_problem):
    """State genes 0 and 1 are the bounds (angles wrap 2pi to 0), an action gene picks
    floor(gene * n_actions), gene 1 the last action."""
    p = acrobot_problem
    assert genes(p, 50) == 50 * 5
    x = np.array([[0.0, 0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0, 1.0, 1.0],
                  [0.5, 0.25, 0.5, 0.75, 0.5], [0.3, 0.3, 0.3, 0.3, 1 / 3 - 1e-12],
                  [0.3, 0.3, 0.3, 0.3, 1 / 3 + 1e-12], [1.5, -1.0, 0.5, 0.5, 2.0]])
    policy = decode(p, x.ravel(), len(x))
    assert policy.style == 'state-action' and len(policy) == len(x)
    assert np.array_equal(policy.states[0], p.low)
    assert np.array_equal(policy.states[1], [0.0, 0.0, p.high[2], p.high[3]])
    assert np.allclose(policy.states[2], [math.pi, math.pi / 2, 0.0, p.high[3] / 2])
    assert np.array_equal(policy.states[5], [0.0, 0.0, 0.0, 0.0])   # clipped into [0, 1]
    assert policy.actions.tolist() == [0, 2, 1, 0, 1, 2]


def test_a_short_run_improves_on_its_first_generation(acrobot_run):
    """Within BUDGET steps the best return and the run's delta* improve on the first
    generation's, and the log counts every MDP step simulated."""
    policy, history = acrobot_run
    first, last = history[0], history[-1]
    assert last['best_value'] > first['best_value']
    assert last['delta_star'] < first['delta_star']
    assert BUDGET <= last['steps'] == policy.meta['steps']
    assert history[-2]['steps'] < BUDGET                   # stopped at the budget
    for a, b in zip(history, history[1:]):
        assert b['generation'] == a['generation'] + 1 and b['steps'] > a['steps']
        assert b['best_value'] >= a['best_value'] and b['delta_star'] <= a['delta_star']
    assert {'generation', 'steps', 'best_value', 'delta_star', 'achieved'} <= set(last)


def test_the_best_policy_replays_its_recorded_value(acrobot_run, acrobot_problem):
    """Evaluator.episode of the returned policy gives the value and delta* in its meta."""
    policy, history = acrobot_run
    meta = policy.meta
    ep = Evaluator(acrobot_problem, meta['delta']).episode(policy)
    assert ep.ret == meta['value'] == history[-1]['best_value']
    assert ep.delta_star == meta['delta_star'] and ep.steps == meta['steps_to_end']
    assert meta['run_delta_star'] == history[-1]['delta_star'] <= meta['delta_star']
    assert (meta['method'], meta['seed'], meta['delta']) == ('cmaes', 11, 0.02)
    assert len(policy) == meta['trainer']['exemplars'] == 50


def test_a_seed_gives_the_same_run_whatever_numpy_global_state():
    """Two runs with one seed give the same log and policy even when NumPy's global
    generator is reseeded and drawn from in between; another seed gives another run."""
    runs = []
    for global_seed in (1, 2):
        np.random.seed(global_seed)
        np.random.standard_normal(global_seed)
        runs.append(train_cmaes('pendulum', None, 40_000, 5, exemplars=10))
    (p1, h1), (p2, h2) = runs
    assert without_timing(h1) == without_timing(h2)
    assert np.array_equal(p1.states, p2.states) and np.array_equal(p1.actions, p2.actions)
    assert p1.meta == p2.meta
    p3, h3 = train_cmaes('pendulum', None, 40_000, 6, exemplars=10)
    assert not np.array_equal(p1.states, p3.states)


def test_seed_zero_is_a_seed_too():
    """Seed 0 (pycma's 'from the clock') is as deterministic as any other."""
    a = train_cmaes('pendulum', None, 8_000, 0, exemplars=5, popsize=4)
    b = train_cmaes('pendulum', None, 8_000, 0, exemplars=5, popsize=4)
    assert np.array_equal(a[0].states, b[0].states) and a[0].meta == b[0].meta


def test_the_strategy_restarts_when_pycma_stops_before_the_budget():
    """Flat fitness (every episode times out, as on the mountain car at first) stops pycma;
    the next ask restarts from a fresh random mean and the search goes on."""
    problem = load_problem('mountain_car')
    search = CmaesSearch(problem, CmaesParams(exemplars=5, popsize=6), 3)
    mean0 = search.es.mean.copy()
    for _ in range(12):
        policies = search.ask()
        if search.restarts:
            break
        n = len(policies)
        search.tell(policies, BatchResult(np.full(n, -400.0), np.full(n, 400, np.int64),
                                          np.full(n, 0.5), np.zeros(n, np.bool_), [None] * n))
    assert search.restarts == 1 and search.generation >= 1
    assert not np.array_equal(search.es.mean, mean0)
    assert search.counters()['best_value'] == -400.0


def test_misuse_is_refused():
    """ask twice, tell without the last ask's results and bad settings raise."""
    problem = load_problem('pendulum')
    search = CmaesSearch(problem, CmaesParams(exemplars=4, popsize=4), 1)
    policies = search.ask()
    with pytest.raises(RuntimeError):
        search.ask()
    result = Evaluator(problem).evaluate(policies[:2])
    with pytest.raises(RuntimeError):
        search.tell(policies[:2], result)
    with pytest.raises(RuntimeError):
        CmaesSearch(problem, CmaesParams(exemplars=4), 1).result(0.01)
    for kwargs in ({'exemplars': 0}, {'sigma0': 0.0}, {'sigma0': 2.0}, {'popsize': 1}):
        with pytest.raises(ValueError):
            CmaesParams(**kwargs)
