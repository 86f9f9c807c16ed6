"""The Q-learning baseline behind the optimizer contract (``optim.base``).

Q-learning evaluates its own candidates: each ``ask()`` runs the next chunk of whole
epsilon-greedy episodes inside the compiled ``learn`` kernel (at most ``chunk_steps`` steps,
never starting an episode once the budget is spent), so it returns no candidates and is told
nothing.  Chunk boundaries do not change what is learnt: episodes are never split.  The
state a checkpoint saves is the table, the visited marks, the xorshift64* word and the
counters.  ``result`` is the greedy policy of the table with its episode measured.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sapga_ros.errors import CheckpointError
from sapga_ros.optim.base import Optimizer, Result, State
from sapga_ros.optim.qlearning import learn
from sapga_ros.policies.qtable import QTable
from sim_nodes.params import check, param
from sim_nodes.goal import alt_goal_arrays, goal_arrays
from sim_nodes.models import model_id
from sim_nodes.problem import Problem

GAMMA = 1.0                                # discount
# The model kernels' lane loops vectorise in blocks of 8 columns (8 doubles: AVX-512 on
# this machine).  Measured with step_lanes on the acrobot: 8 or 16 columns run 8-9 M
# lane-steps/s, 10 or 12 only 3.4-4.5 M (the remainder runs scalar); spare columns cost less.
LANE_BLOCK = 8


@dataclass(frozen=True)
class QlParams:
    """Q-learning run parameters; epsilon, eta and the tiling are the problem's
    (``q_learning`` in msg_configs/<problem>.yaml)."""

    chunk_steps: int = param(1_000_000, 'Q-learning: MDP steps learnt per chunk (a '
                             'progress row, a checkpoint opportunity)', low=1000,
                             high=10_000_000)

    def __post_init__(self) -> None:
        check(self)


def seed_state(seed: int) -> np.ndarray:
    """The xorshift64* state of ``seed``: splitmix64 of it, never zero."""
    z = (seed + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return np.array([(z ^ (z >> 31)) or 1], dtype=np.uint64)


def lane_width(lanes: int) -> int:
    """Columns of the model step for ``lanes`` side-by-side runs: one alone, else the lanes
    rounded up to a multiple of ``LANE_BLOCK``."""
    return lanes if lanes == 1 else -(-lanes // LANE_BLOCK) * LANE_BLOCK


class QLearning(Optimizer):
    """Tabular Q-learning of one problem with goal difficulty ``delta``."""

    method = 'ql'

    def __init__(self, problem: Problem, params: QlParams, delta: float, budget: int,
                 q: np.ndarray, visited: np.ndarray, rng: np.ndarray,
                 counters: dict | None = None) -> None:
        self.problem, self.params, self.delta, self.budget = problem, params, delta, budget
        self.q, self.visited, self.rng = q, visited, rng
        c = counters or {}
        self._steps = int(c.get('steps', 0))
        self.episodes = int(c.get('episodes', 0))
        self.best_value = float(c.get('best_value', -math.inf))   # best episode return
        self.delta_star = float(c.get('delta_star', math.inf))    # min delta(s) so far
        self.delta_star_alt = float(c.get('delta_star_alt', math.inf))  # alternative goal
        self.chunks = int(c.get('chunks', 0))
        pr = problem
        idx, low, width, tiles = QTable(pr, q, visited, {}).tiling
        self._model = model_id(pr.model)
        self._consts = (pr.initial_state, pr.params(), pr.action_values, idx, low, width,
                        tiles, *goal_arrays(pr), pr.is_angle, delta, pr.n_step,
                        pr.ql_epsilon, pr.ql_eta, GAMMA, *alt_goal_arrays(pr),
                        pr.ends_in_goal, pr.hold_bonus, pr.contact_below,
                        pr.fail_charge)
        self._alt = pr.goal_alt_scale is not None
        self._lanes_key = (pr.name, delta, pr.goal_alt_scale)
        self._learnt: tuple | None = None      # a chunk learnt by ``learn_together``

    @classmethod
    def create(cls, problem: Problem, params: QlParams, seed: int, delta: float,
               budget: int) -> 'QLearning':
        """A zero table; the generator seeded from ``seed``."""
        cells = problem.ql_tiles_per_dim ** len(problem.ql_state_indices)
        return cls(problem, params, delta, budget, np.zeros((cells, len(problem.actions))),
                   np.zeros(cells, dtype=np.bool_), seed_state(seed))

    def ask(self) -> list:
        """Learn from the next chunk of episodes (unless ``learn_together`` did already);
        nothing is left to evaluate."""
        if self._learnt is None:
            learn_together([self])
        done, n_ep, ep_r, ep_d, ep_alt = self._learnt
        self._learnt = None
        self._steps += int(done)
        self.episodes += int(n_ep)
        if n_ep:
            self.best_value = max(self.best_value, float(ep_r[:n_ep].max()))
            self.delta_star = min(self.delta_star, float(ep_d[:n_ep].min()))
            if self._alt:
                self.delta_star_alt = min(self.delta_star_alt, float(ep_alt[:n_ep].min()))
        self.chunks += 1
        return []

    def tell(self, returns: np.ndarray, delta_star: np.ndarray, steps: np.ndarray,
             reached: np.ndarray, used: list[np.ndarray]) -> None:
        if len(returns):
            raise RuntimeError('Q-learning evaluates its own episodes: tell() takes none')

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def iteration(self) -> int:
        return self.chunks

    @property
    def result(self) -> Result:
        table = QTable(self.problem, self.q.copy(), self.visited.copy(), {})
        ep = table.episode(self.delta)
        return Result(table, {
            'value': ep.ret, 'delta_star': ep.delta_star, 'steps_to_end': ep.steps,
            'reached': ep.reached, 'best_training_value': self.best_value,
            'run_delta_star': self.delta_star, 'steps': self._steps,
            'episodes': self.episodes, 'method': self.method, 'epsilon': self.problem.ql_epsilon,
            'eta': self.problem.ql_eta, 'gamma': GAMMA})

    def counters(self) -> dict:
        counters = {'episodes': self.episodes, 'steps': self._steps,
                    'best_value': self.best_value, 'delta_star': self.delta_star}
        if self._alt:
            counters['delta_star_alt'] = self.delta_star_alt
        return counters

    @staticmethod
    def settings(problem: Problem, params: QlParams) -> dict:
        return {'epsilon': problem.ql_epsilon, 'eta': problem.ql_eta}

    def state_dict(self) -> State:
        if self._learnt is not None:
            raise RuntimeError('a chunk is learnt but not yet taken by ask()')
        return ({**self.counters(), 'chunks': self.chunks},
                {'q': self.q, 'visited': self.visited, 'rng': self.rng})

    @classmethod
    def from_state(cls, problem: Problem, params: QlParams, state: State, *, delta: float,
                   budget: int, **run: object) -> 'QLearning':
        meta, arrays = state
        cells = problem.ql_tiles_per_dim ** len(problem.ql_state_indices)
        try:
            q, visited, rng = arrays['q'], arrays['visited'], arrays['rng']
            counters = {'steps': int(meta['steps']), 'episodes': int(meta['episodes']),
                        'best_value': float(meta['best_value']),
                        'delta_star': float(meta['delta_star']),
                        'chunks': int(meta.get('chunks', 0))}
            if meta.get('delta_star_alt') is not None:
                counters['delta_star_alt'] = float(meta['delta_star_alt'])
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f'malformed run state ({exc})') from exc
        if q.shape != (cells, len(problem.actions)) or q.dtype != np.float64 or \
                not np.all(np.isfinite(q)):
            raise CheckpointError(f'Q-table of shape {q.shape} ({q.dtype}), expected finite '
                                  f'{(cells, len(problem.actions))} float64')
        if visited.shape != (cells,) or visited.dtype != np.bool_ or \
                rng.shape != (1,) or rng.dtype != np.uint64 or not rng[0]:
            raise CheckpointError('visited marks or generator state of the wrong form')
        return cls(problem, params, delta, budget, q, visited, rng, counters)


def learn_together(opts: list[QLearning]) -> None:
    """Learn the next chunk of every run in ``opts`` in one call of the ``learn`` kernel,
    the runs side by side as lanes (the model steps them together, vectorised); each
    run's next ``ask()`` takes its chunk.  The runs must share the problem and goal; what
    each learns is bit-identical to learning alone."""
    first = opts[0]
    if any(o._lanes_key != first._lanes_key for o in opts):
        raise ValueError('runs learnt together must share the problem and the goal')
    if any(o._learnt is not None for o in opts):
        raise RuntimeError('a run already holds a learnt chunk')
    lanes = len(opts)
    if lanes == 1:                             # the run's own arrays, in place
        q, visited, rng = first.q[None], first.visited[None], first.rng
    else:
        q = np.stack([o.q for o in opts])
        visited = np.stack([o.visited for o in opts])
        rng = np.concatenate([o.rng for o in opts])
    budget = np.array([min(o.params.chunk_steps, o.budget - o.steps) for o in opts])
    n = max(1, int(budget.max()))              # an episode has at least one step
    ep = (np.empty((lanes, n)), np.empty((lanes, n), np.int64), np.empty((lanes, n)),
          np.empty((lanes, n)))
    done = np.zeros(lanes, np.int64)
    n_ep = np.zeros(lanes, np.int64)
    learn(first._model, q, visited, rng, *first._consts, budget, *ep, lane_width(lanes),
          done, n_ep)
    for k, o in enumerate(opts):
        if lanes > 1:
            o.q[...] = q[k]
            o.visited[...] = visited[k]
            o.rng[...] = rng[k:k + 1]
        o._learnt = (done[k], n_ep[k], ep[0][k], ep[2][k], ep[3][k])
