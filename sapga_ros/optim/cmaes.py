"""CMA-ES (Hansen's pycma) over a fixed-size state-action policy: a peer of SAP-GA on the
same problems, episode engine and budget (MDP steps simulated).

A candidate is a vector of L (D + 1) genes in [0, 1] (pycma's ``bounds=[0, 1]``), one row
of D + 1 per exemplar: D state genes mapped linearly onto [low, high] of the problem's
state coordinates and one action gene mapped to the action index
``min(floor(gene * n_actions), n_actions - 1)``.  It decodes to a state-action
``ExemplarPolicy``; its fitness is the return of one episode (``Evaluator.evaluate``, the
whole population in one parallel batch), and pycma minimises -return (NaN ranks worst).

Randomness comes from one ``numpy.random.Generator`` seeded with ``seed``: the initial mean
(uniform in [0, 1]) and pycma's normal draws (its ``randn`` option; pycma's ``seed`` option
would seed NumPy's global generator, which any other code may draw from, and treats 0 as
"from the clock").  A run is deterministic for a seed.  When pycma's own termination
criteria fire before the budget is spent (flat fitness: every episode of the mountain car
times out), the strategy restarts from a fresh random mean, as pycma's ``fmin`` restarts.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable

import cma
import numpy as np

from sapga_ros.evaluation.evaluator import BatchResult, Evaluator
from sapga_ros.exemplars.policy import ExemplarPolicy
from sim_nodes.problem import Problem, load_problem

Progress = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class CmaesParams:
    """Strategy parameters of the CMA-ES peer."""

    exemplars: int = 50                    # L, exemplars of every policy
    sigma0: float = 0.3                    # initial step size, in gene units ([0, 1])
    popsize: int | None = None             # lambda; None: pycma's 4 + 3 ln(N)

    def __post_init__(self) -> None:
        if self.exemplars < 1 or not 0.0 < self.sigma0 <= 1.0 or \
                (self.popsize is not None and self.popsize < 2):
            raise ValueError(f'CMA-ES needs exemplars >= 1, 0 < sigma0 <= 1 and popsize >= 2 '
                             f'or None, got {self}')


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


@dataclass
class Best:
    """The best evaluated policy so far and its episode's measures."""

    policy: ExemplarPolicy
    value: float
    delta_star: float
    steps: int
    reached: bool


class CmaesSearch:
    """ask / tell of pycma's ``CMAEvolutionStrategy`` on state-action policies."""

    method = 'cmaes'

    def __init__(self, problem: Problem, params: CmaesParams, seed: int) -> None:
        self.problem = problem
        self.params = params
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.generation = 0
        self.steps = 0                     # MDP steps simulated (the budget's unit)
        self.evaluations = 0
        self.restarts = 0
        self.delta_star = math.inf         # min delta(s) over every state reached
        self.best: Best | None = None
        self.es = self._strategy()
        self._asked: list | None = None

    def _strategy(self) -> cma.CMAEvolutionStrategy:
        """A fresh strategy from a random mean, its normal draws from ``self.rng``."""
        p = self.params
        x0 = self.rng.uniform(0.0, 1.0, genes(self.problem, p.exemplars))
        opts = {'bounds': [0.0, 1.0], 'randn': self._randn, 'seed': math.nan,
                'verbose': -9, 'verb_log': 0, 'verb_disp': 0}
        if p.popsize is not None:
            opts['popsize'] = p.popsize
        return cma.CMAEvolutionStrategy(x0, p.sigma0, opts)

    def _randn(self, *shape: int) -> np.ndarray:
        return self.rng.standard_normal(shape)

    def ask(self) -> list[ExemplarPolicy]:
        """This generation's candidates as policies (restarting first if pycma stopped)."""
        if self._asked is not None:
            raise RuntimeError('ask() called twice without tell()')
        if self.es.stop():
            self.restarts += 1
            self.es = self._strategy()
        self._asked = self.es.ask()
        return [decode(self.problem, x, self.params.exemplars) for x in self._asked]

    def tell(self, policies: list[ExemplarPolicy], result: BatchResult) -> None:
        """The evaluations of ``ask()``'s policies, in order."""
        if self._asked is None or not len(policies) == len(self._asked) == len(result.returns):
            raise RuntimeError('tell() needs the results of the last ask(), in order')
        values = np.where(np.isfinite(result.returns), result.returns, -np.inf)
        self.es.tell(self._asked, [float(-v) for v in values])   # pycma minimises
        self._asked = None
        self.generation += 1
        self.steps += int(result.steps.sum())
        self.evaluations += len(policies)
        self.delta_star = min(self.delta_star, float(result.delta_star.min()))
        k = int(np.argmax(values))                                # first of equals
        if self.best is None or values[k] > self.best.value:
            self.best = Best(policies[k], float(values[k]), float(result.delta_star[k]),
                             int(result.steps[k]), bool(result.reached[k]))

    def counters(self) -> dict[str, Any]:
        """A log row's counters (the SAP-GA log's columns first)."""
        return {'generation': self.generation, 'steps': self.steps,
                'best_value': self.best.value if self.best else -math.inf,
                'delta_star': self.delta_star, 'evaluations': self.evaluations,
                'restarts': self.restarts, 'sigma': float(self.es.sigma)}

    def result(self, delta: float) -> ExemplarPolicy:
        """The best policy so far, its account of itself and of the run in ``meta``."""
        if self.best is None:
            raise RuntimeError('no evaluation yet: no policy to return')
        b = self.best
        policy = b.policy.subset(slice(None))
        policy.meta = {'value': b.value, 'delta_star': b.delta_star, 'steps_to_end': b.steps,
                       'reached': b.reached, 'run_delta_star': self.delta_star,
                       'steps': self.steps, 'generations': self.generation,
                       'evaluations': self.evaluations, 'restarts': self.restarts,
                       'delta': delta, 'seed': self.seed, 'method': self.method,
                       'trainer': asdict(self.params)}
        return policy


def train_cmaes(problem_name: str, delta: float | None, steps: int, seed: int,
                exemplars: int = 50, sigma0: float = 0.3, popsize: int | None = None,
                progress: Progress | None = None,
                evaluator: Evaluator | None = None) -> tuple[ExemplarPolicy, list[dict]]:
    """Run CMA-ES on ``problem_name`` until ``steps`` MDP steps are simulated (the
    generation that crosses the budget completes, as in SAP-GA); return the best policy
    (its ``meta``: value, delta_star, run_delta_star, steps, seed, method) and the log, one
    row per generation (``progress(row)`` is called with each).  ``evaluator``: another
    evaluation of the same problem and delta (robust fitness:
    ``sapga_ros.evaluation.robust``)."""
    problem = load_problem(problem_name)
    delta = problem.resolve('delta', delta)
    evaluator = evaluator or Evaluator(problem, delta)
    search = CmaesSearch(problem, CmaesParams(exemplars, sigma0, popsize), seed)
    history: list[dict] = []
    start = time.perf_counter()
    while search.steps < steps:
        policies = search.ask()
        search.tell(policies, evaluator.evaluate(policies))
        row = search.counters()
        row.update(achieved=row['delta_star'] <= delta,
                   steps_per_s=search.steps / max(time.perf_counter() - start, 1e-9))
        history.append(row)
        if progress:
            progress(row)
    return search.result(delta), history
