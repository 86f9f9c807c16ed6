"""CMA-ES (``sapga_ros.optim.cmaes``) driven by the training loop: the decoding of a candidate,
a short run that learns, determinism for a seed, a recorded best value that its episode
reproduces, restarts, and checkpoints that re-derive pycma's state."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sapga_ros.errors import ConfigError
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.optim.cmaes import Cmaes, CmaesParams, decode, genes
from sapga_ros.training.loop import TrainConfig, train
from sim_nodes.problem import load_problem

BUDGET = 200_000
GENERATIONS = 12


def train_cmaes(problem: str, steps: int, seed: int, **params) -> tuple:
    """(best policy, log) of a CMA-ES run through the training loop."""
    r = train(TrainConfig(problem=problem, method='cmaes', steps=steps, seed=seed,
                          cmaes=CmaesParams(**params)))
    return r.policy, r.history


@pytest.fixture(scope='module')
def acrobot_run() -> tuple:
    """A CMA-ES run on the acrobot of BUDGET MDP steps, seed 11."""
    return train_cmaes('acrobot', BUDGET, 11)


def without_timing(history: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k != 'steps_per_s'} for row in history]


def timeless(meta: dict) -> dict:
    return {k: v for k, v in meta.items() if k != 'time'}


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
        runs.append(train_cmaes('pendulum', 40_000, 5, exemplars=10))
    (p1, h1), (p2, h2) = runs
    assert without_timing(h1) == without_timing(h2)
    assert np.array_equal(p1.states, p2.states) and np.array_equal(p1.actions, p2.actions)
    assert timeless(p1.meta) == timeless(p2.meta)
    p3, h3 = train_cmaes('pendulum', 40_000, 6, exemplars=10)
    assert not np.array_equal(p1.states, p3.states)


def test_seed_zero_is_a_seed_too():
    """Seed 0 (pycma's 'from the clock') is as deterministic as any other."""
    a = train_cmaes('pendulum', 8_000, 0, exemplars=5, popsize=4)
    b = train_cmaes('pendulum', 8_000, 0, exemplars=5, popsize=4)
    assert np.array_equal(a[0].states, b[0].states) and timeless(a[0].meta) == timeless(b[0].meta)


def flat_round(search: Cmaes) -> None:
    """One generation in which every episode times out with the same return (flat
    fitness)."""
    n = len(search.ask())
    search.tell(np.full(n, -400.0), np.full(n, 0.5), np.full(n, 400, np.int64),
                np.zeros(n, np.bool_), [None] * n)


def test_the_strategy_restarts_when_pycma_stops_before_the_budget():
    """Flat fitness (every episode times out, as on the mountain car at first) stops pycma;
    the next ask restarts from a fresh random mean and the search goes on."""
    problem = load_problem('mountain_car')
    search = Cmaes.create(problem, CmaesParams(exemplars=5, popsize=6), 3)
    mean0 = search.es.mean.copy()
    for _ in range(12):
        flat_round(search)
        if search.restarts:
            break
    assert search.restarts == 1 and search.generation >= 1
    assert not np.array_equal(search.es.mean, mean0)
    assert search.counters()['best_value'] == -400.0


def test_a_checkpoint_across_a_restart_re_derives_the_strategy(tmp_path):
    """A state saved after a restart replays to the same pycma state (mean, step size,
    covariance) and generator, and both go on alike."""
    problem = load_problem('mountain_car')
    search = Cmaes.create(problem, CmaesParams(exemplars=5, popsize=6), 3)
    while not search.restarts:
        flat_round(search)
    flat_round(search)
    meta, arrays = search.state_dict()
    again = Cmaes.from_state(problem, search.params, (meta, arrays))
    assert again.restarts == search.restarts and again.generation == search.generation
    for a, b in ((again.es.mean, search.es.mean), (again.es.C, search.es.C)):
        assert np.array_equal(a, b)
    assert again.es.sigma == search.es.sigma
    assert again.counters() == search.counters()
    xs = [np.array(o._ask_genes()) for o in (search, again)]
    assert np.array_equal(*xs)


def test_misuse_is_refused():
    """ask twice, tell without the last ask's results and bad settings raise."""
    problem = load_problem('pendulum')
    search = Cmaes.create(problem, CmaesParams(exemplars=4, popsize=4), 1)
    policies = search.ask()
    with pytest.raises(RuntimeError):
        search.ask()
    r = Evaluator(problem).evaluate(policies[:2])
    with pytest.raises(RuntimeError):
        search.tell(r.returns, r.delta_star, r.steps, r.reached, r.used)
    with pytest.raises(RuntimeError):
        search.state_dict()
    assert Cmaes.create(problem, CmaesParams(exemplars=4), 1).result is None
    for kwargs in ({'exemplars': 0}, {'sigma0': 0.0}, {'sigma0': 2.0}, {'popsize': 1},
                   {'popsize': -3}, {'sigma0': math.nan}):
        with pytest.raises(ConfigError):
            CmaesParams(**kwargs)


def test_a_covariance_that_cannot_fit_in_memory_is_refused_before_it_is_made():
    """N = L (D + 1) genes need some 4 N^2 doubles: past 8 GiB one line naming the settings,
    before pycma allocates anything (it would raise MemoryError or take the machine)."""
    problem = load_problem('acrobot')
    for params in (CmaesParams(exemplars=100_000, popsize=1000), CmaesParams(exemplars=4000)):
        with pytest.raises(ConfigError, match=r'^CMA-ES: exemplars \d+ make N = \d+ genes on '
                                              r'acrobot; .* GiB, more than the 8 GiB'):
            Cmaes.create(problem, params, 0)
    assert Cmaes.create(problem, CmaesParams(exemplars=600), 0).es.N == 3000


@pytest.mark.parametrize('problem_name', ['acrobot', 'pdip'])
def test_a_seed_gives_the_same_strategy_whatever_the_blas_thread_count(problem_name):
    """OpenBLAS's sums depend on how many threads it uses (by default the machine's cores);
    the strategy's linear algebra runs on one, so a seed's run is the same on a machine of
    any size and whatever the caller set."""
    from threadpoolctl import threadpool_limits
    problem = load_problem(problem_name)

    def strategy(threads: int) -> tuple:
        with threadpool_limits(limits=threads, user_api='blas'):
            opt = Cmaes.create(problem, CmaesParams(popsize=100), seed=5)
            for _ in range(GENERATIONS):
                x = np.array([genes_of(p) for p in opt.ask()])
                fitness = np.sin(7.0 * x).sum(axis=1) + (x ** 2).sum(axis=1)
                n = len(x)
                opt.tell(-fitness, np.ones(n), np.ones(n, dtype=np.int64),
                         np.zeros(n, dtype=bool), [np.ones(50, dtype=bool)] * n)
            return opt.es.mean.copy(), opt.es.sigma, opt.es.C.copy()

    def genes_of(policy) -> np.ndarray:
        return np.concatenate([policy.states.ravel(), policy.actions.astype(float)])

    one, many = strategy(1), strategy(2)
    assert np.array_equal(one[0], many[0]) and one[1] == many[1]
    assert np.array_equal(one[2], many[2])
