"""CMA-ES (Hansen's pycma) over a fixed-size state-action policy, behind the optimizer contract
(``sapga_ros.optim.base``): a peer of SAP-GA on the same problems, episode engine and budget
(MDP steps simulated), driven by the one training loop (``sapga train --method cmaes``).

A candidate is a vector of L (D + 1) genes in [0, 1] (pycma's ``bounds=[0, 1]``), one row
of D + 1 per exemplar: D state genes mapped linearly onto [low, high] of the problem's
state coordinates and one action gene mapped to the action index
``min(floor(gene * n_actions), n_actions - 1)``.  It decodes to a state-action
``ExemplarPolicy``; its fitness is the return of one episode (the loop evaluates the whole
population in one parallel batch), and pycma minimises -return (NaN ranks worst).

Randomness comes from one ``numpy.random.Generator`` seeded with ``seed``: the initial mean
(uniform in [0, 1]) and pycma's normal draws (its ``randn`` option; pycma's ``seed`` option
would seed NumPy's global generator, which any other code may draw from, and treats 0 as
"from the clock").  A run is deterministic for a seed.  pycma's linear algebra (the
covariance's eigendecomposition, the sampling products) runs on one BLAS thread
(threadpoolctl): OpenBLAS's sums depend on its thread count, by default the machine's
cores, so on more threads a seed's run would differ between machines of different sizes,
and workers running side by side would each start as many threads as there are cores.
When pycma's own termination criteria fire before the budget is spent (flat fitness: every
episode of the mountain car times out), the strategy restarts from a fresh random mean, as
pycma's ``fmin`` restarts.

A checkpoint holds no pycma object (that would need pickle): it holds the fitness values
told in every generation (``told``), the best candidate's genes and the counters.  Resuming
re-derives the strategy: a fresh one from the seed, then ask/tell replayed with the recorded
values, which redraws the same normal vectors from the same generator and so rebuilds
pycma's mean, step size, covariance, paths and termination history exactly, restarts
included; the generator state the replay reaches must equal the saved one.
"""
from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass

import cma
import numpy as np
from threadpoolctl import ThreadpoolController

from sapga_ros.errors import CheckpointError, ConfigError
from sapga_ros.optim.base import Optimizer, Result, State
from sim_nodes.params import check, param
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.problem import Problem


@functools.cache
def _blas() -> ThreadpoolController:
    """The thread pools of the libraries loaded at the first call (NumPy's BLAS among them)."""
    return ThreadpoolController()


def one_blas_thread():
    """A context in which the BLAS libraries loaded (NumPy's, SciPy's) use one thread."""
    return _blas().limit(limits=1, user_api='blas')


@dataclass(frozen=True)
class CmaesParams:
    """Strategy parameters of CMA-ES."""

    exemplars: int = param(50, 'CMA-ES: L, exemplars of every policy', low=1, high=100_000)
    sigma0: float = param(0.3, 'CMA-ES: initial step size, in gene units (each gene is in '
                          '[0, 1])', low=1e-12, high=1.0)
    popsize: int = param(0, 'CMA-ES: lambda, candidates per generation; 0: pycma\'s '
                         '4 + 3 ln N', low=0, high=1_000_000)

    def __post_init__(self) -> None:
        check(self)
        if self.popsize == 1:
            raise ConfigError('popsize: expected 0 (pycma\'s default) or at least 2, got 1')


# pycma keeps about three N x N matrices (measured: 3.0 N^2 doubles for N = 2,000 and 4,000);
# four leave room for its eigendecomposition, and each of lambda candidates N more doubles
MATRICES = 4
MAX_HELD_BYTES = 8 << 30                   # [bytes] as the GA's population may need


def memory_problem(problem: Problem, params: CmaesParams) -> str | None:
    """The one line refusing a strategy whose covariance cannot fit in memory, or None."""
    n = genes(problem, params.exemplars)
    lam = params.popsize or 4 + int(3 * math.log(n))
    held = 8 * n * (MATRICES * n + 4 * lam)
    if held <= MAX_HELD_BYTES:
        return None
    return (f'CMA-ES: exemplars {params.exemplars} make N = {n} genes on {problem.name}; its '
            f'covariance and {lam} candidates need about {held / (1 << 30):,.0f} GiB, more '
            f'than the {MAX_HELD_BYTES >> 30} GiB a run may hold: lower exemplars or popsize')


def genes(problem: Problem, exemplars: int) -> int:
    """N, the length of a candidate vector: L (D + 1)."""
    return exemplars * (problem.dim + 1)


def decode(problem: Problem, x: np.ndarray, exemplars: int) -> ExemplarPolicy:
    """The state-action policy of candidate ``x`` (genes in [0, 1], see the module)."""
    rows = np.clip(np.asarray(x, dtype=np.float64).reshape(exemplars, problem.dim + 1), 0, 1)
    states = problem.low + rows[:, :-1] * (problem.high - problem.low)
    n = len(problem.actions)
    actions = np.minimum(np.floor(rows[:, -1] * n), n - 1).astype(np.int64)
    return ExemplarPolicy(problem, states, actions, style='state-action')


@dataclass(frozen=True)
class Best:
    """The best evaluated candidate so far (its genes) and its episode's measures."""

    x: np.ndarray
    value: float
    delta_star: float
    steps: int
    reached: bool


class Cmaes(Optimizer):
    """ask / tell of pycma's ``CMAEvolutionStrategy`` on state-action policies."""

    method = 'cmaes'

    def __init__(self, problem: Problem, params: CmaesParams, seed: int) -> None:
        reason = memory_problem(problem, params)
        if reason:
            raise ConfigError(reason)
        self.problem = problem
        self.params = params
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.generation = 0
        self._steps = 0                    # MDP steps simulated (the budget's unit)
        self.evaluations = 0
        self.restarts = 0
        self.delta_star = math.inf         # min delta(s) over every state reached
        self._best: Best | None = None
        self._told: list[np.ndarray] = []  # the fitness values told, one row a generation
        self.es = self._strategy()
        self._asked: list | None = None

    @classmethod
    def create(cls, problem: Problem, params: CmaesParams, seed: int) -> 'Cmaes':
        """A strategy from a random mean drawn from ``seed``'s generator."""
        return cls(problem, params, seed)

    def _strategy(self) -> cma.CMAEvolutionStrategy:
        """A fresh strategy from a random mean, its normal draws from ``self.rng``."""
        p = self.params
        x0 = self.rng.uniform(0.0, 1.0, genes(self.problem, p.exemplars))
        opts = {'bounds': [0.0, 1.0], 'randn': self._randn, 'seed': math.nan,
                'verbose': -9, 'verb_log': 0, 'verb_disp': 0}
        if p.popsize:
            opts['popsize'] = p.popsize
        with one_blas_thread():
            return cma.CMAEvolutionStrategy(x0, p.sigma0, opts)

    def _randn(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)

    def _ask_genes(self) -> list[np.ndarray]:
        """This generation's candidate vectors (restarting first if pycma stopped)."""
        if self._asked is not None:
            raise RuntimeError('ask() called twice without tell()')
        with one_blas_thread():
            if self.es.stop():
                self.restarts += 1
                self.es = self._strategy()
            self._asked = self.es.ask()
        return self._asked

    def _tell_fitness(self, fitness: np.ndarray) -> None:
        """pycma's tell of the last asked vectors (fitness: -return, minimised)."""
        with one_blas_thread():
            self.es.tell(self._asked, [float(f) for f in fitness])
        self._told.append(np.asarray(fitness, dtype=np.float64))
        self._asked = None
        self.generation += 1

    def ask(self) -> list[ExemplarPolicy]:
        """This generation's candidates as policies."""
        return [decode(self.problem, x, self.params.exemplars) for x in self._ask_genes()]

    def tell(self, returns: np.ndarray, delta_star: np.ndarray, steps: np.ndarray,
             reached: np.ndarray, used: list[np.ndarray]) -> None:
        """The measures of ``ask()``'s candidates, in order."""
        if self._asked is None or len(returns) != len(self._asked):
            raise RuntimeError('tell() needs the results of the last ask(), in order')
        values = np.where(np.isfinite(returns), returns, -np.inf)
        asked = self._asked
        self._tell_fitness(-values)
        self._steps += int(np.sum(steps))
        self.evaluations += len(values)
        self.delta_star = min(self.delta_star, float(np.min(delta_star)))
        k = int(np.argmax(values))                                # first of equals
        if self._best is None or values[k] > self._best.value:
            self._best = Best(np.array(asked[k]), float(values[k]), float(delta_star[k]),
                              int(steps[k]), bool(reached[k]))

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def iteration(self) -> int:
        return self.generation

    @property
    def best(self) -> Best | None:
        return self._best

    @property
    def result(self) -> Result | None:
        b = self._best
        if b is None:
            return None
        return Result(decode(self.problem, b.x, self.params.exemplars), {
            'value': b.value, 'delta_star': b.delta_star, 'steps_to_end': b.steps,
            'reached': b.reached, 'run_delta_star': self.delta_star, 'steps': self._steps,
            'generations': self.generation, 'evaluations': self.evaluations,
            'restarts': self.restarts, 'method': self.method, 'trainer': asdict(self.params)})

    def counters(self) -> dict:
        """A log row's counters (the SAP-GA log's columns first)."""
        return {'generation': self.generation, 'steps': self._steps,
                'best_value': self._best.value if self._best else -math.inf,
                'delta_star': self.delta_star, 'evaluations': self.evaluations,
                'restarts': self.restarts, 'sigma': float(self.es.sigma)}

    @staticmethod
    def settings(problem: Problem, params: CmaesParams) -> dict:
        return {'cmaes': asdict(params)}

    def state_dict(self) -> State:
        if self._asked is not None:
            raise RuntimeError('candidates are asked but not yet told')
        b = self._best
        told = np.array(self._told) if self._told else np.empty((0, 0))
        meta = {'seed': self.seed, 'steps': self._steps, 'evaluations': self.evaluations,
                'delta_star': self.delta_star, 'rng': self.rng.bit_generator.state,
                'best': None if b is None else {'value': b.value, 'delta_star': b.delta_star,
                                                'steps': b.steps, 'reached': b.reached}}
        arrays = {'told': told}
        if b is not None:
            arrays['best_x'] = b.x
        return meta, arrays

    @classmethod
    def from_state(cls, problem: Problem, params: CmaesParams, state: State,
                   **run: object) -> 'Cmaes':
        """The strategy re-derived by replaying the recorded generations (see the module)."""
        meta, arrays = state
        try:
            opt = cls(problem, params, int(meta['seed']))
            told, best = arrays['told'], meta['best']
            counters = (int(meta['steps']), int(meta['evaluations']),
                        float(meta['delta_star']))
            rng = meta['rng']
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f'malformed run state ({exc})') from exc
        if told.dtype != np.float64 or told.ndim != 2 or np.isnan(told).any():
            raise CheckpointError(f'told fitness of the wrong form ({told.dtype}, '
                                  f'{told.ndim} dimensions, or NaN)')
        for row in told:
            if len(opt._ask_genes()) != len(row):
                raise CheckpointError(f'a generation of {len(row)} told values, expected '
                                      f'{len(opt._asked)}')
            opt._tell_fitness(row)
        if opt.rng.bit_generator.state != rng:
            raise CheckpointError('the replayed generations do not reach the saved generator '
                                  'state')
        opt._steps, opt.evaluations, opt.delta_star = counters
        if best is not None:
            x = arrays.get('best_x')
            if x is None or x.dtype != np.float64 or x.shape != (genes(problem,
                                                                       params.exemplars),):
                raise CheckpointError('best candidate missing or of the wrong form')
            opt._best = Best(x, float(best['value']), float(best['delta_star']),
                             int(best['steps']), bool(best['reached']))
        return opt
