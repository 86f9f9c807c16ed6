"""SAP-GA: exemplar-based policy search with a genetic algorithm (paper section 3).

The optimizer speaks ask/tell (``sapga_ros.optim.base``, as pycma and evosax do): ``ask()``
pairs the population at random into families, makes N_child children per family by uniform
exemplar crossover, and returns every family member without a known value; the caller
evaluates them (all families of a generation in one parallel batch: families are disjoint,
so this equals processing them one by one) and hands the results to ``tell()``, which keeps
each family's best member pi* in one parent's place and a refreshed clone of pi* in the
other's.

Fixed strategy parameters live in ``SapgaParams``; the changing state (population, values,
generator, counters) is what a checkpoint saves (``state_dict`` / ``from_state``).

With an evolved catch (``evolve_catch``: the hybrid, exemplars plus the LQR catch), each
individual carries a catch scale (its region x'Px <= c with c = the design's c x scale): a
child inherits one parent's (a fair coin), times exp(sigma N(0, 1)), clipped to
``SCALE_RANGE``; a refreshed clone keeps its star's.  These draws come from a generator of
their own, so the run's generator draws as without them.

With ``redraw`` (robust fitness whose episodes are drawn anew each generation) a value holds
for one generation only: ``ask`` returns the parents too, to be evaluated on the
generation's draws beside their children, and the best is the generation's best.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from sapga_ros.errors import CheckpointError, ConfigError
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.policies.styles import STYLES
from sapga_ros.optim.base import Optimizer, Result, State
from sapga_ros.optim.generation import compact, crossover_group, refreshes
from sapga_ros.optim.operators import random_policy
from sapga_ros.optim.population import SCALE_RANGE, Generation, Individual, pack, unpack
from sapga_ros.policies.batch import PolicyBatch
from sapga_ros.policies.classical import ControlledPolicy, hybrid_of_valid
from sim_nodes.params import check, param
from sim_nodes.problem import Problem

COUNT = 1_000_000                          # most policies, children or exemplars a setting asks
# Memory of a generation: about 100 bytes per n_pop x (n_child + 1) x l_max exemplars at the
# peak of ask() and the batch evaluation (measured on pdip, D = 6: 101 bytes); 128 leaves room.
EXEMPLAR_BYTES = 128
# and about 1.4 kB a policy whatever its exemplars (its objects and arrays: measured with one
# or two exemplars a policy, 40,000 policies, acrobot); 2,048 leaves room
POLICY_BYTES = 2048
MAX_HELD_BYTES = 8 << 30                   # [bytes] a run's population may need, at most
VARIANTS = {                               # name -> what changes from the paper's algorithm
    'paper': 'the paper\'s SAP-GA: the family member of best value survives (a parent '
             'among equals)',
    'child-ties': 'as paper, but among members of equal value a child survives (drift '
                  'across plateaus of identical behaviour)',
    'dstar': 'the member whose episode came nearest the goal (smallest delta*) survives, '
             'value breaking ties; the run\'s result is chosen the same way',
    'dstar-child': 'dstar, and among equal members a child survives',
}


@dataclass(frozen=True)
class SapgaParams:
    """SAP-GA strategy parameters (paper 4.3 defaults)."""

    n_pop: int = param(100, 'N_pop, policies in the population', flag='--pop', low=2,
                       high=COUNT)
    n_child: int = param(10, 'N_child, children per family', flag='--children', low=1,
                         high=COUNT)
    l_min: int = param(50, 'L_min, fewest exemplars in a policy', low=1, high=COUNT)
    l_max: int = param(100, 'L_max, most exemplars in a policy', low=1, high=COUNT)
    crossover_rate: tuple = (0.3, 0.7)     # range of r in uniform exemplar crossover
    refresh_rate: tuple = (0.0, 0.5)       # range of r in the refresh operator
    max_tries: int = 100                   # crossover attempts before a child is repaired
    style: str = param('state-action', 'exemplar style of the policies evolved: ' + '; '.join(
        f'{s.name}: {s.summary}' for s in STYLES.values()), choices=tuple(STYLES))
    variant: str = param('paper', 'SAP-GA variant (paper is the published algorithm): '
                         + '; '.join(f'{k}: {v}' for k, v in VARIANTS.items()),
                         choices=tuple(VARIANTS))

    def __post_init__(self) -> None:
        check(self)
        if self.l_min > self.l_max:
            raise ConfigError(f'l_min {self.l_min} is larger than l_max {self.l_max}')
        reason = memory_problem(self.n_pop, self.n_child, self.l_max)
        if reason:
            raise ConfigError(reason)


def memory_problem(n_pop: int, n_child: int, l_max: int) -> str | None:
    """The one line refusing a population whose exemplars cannot fit in memory, or None."""
    held = n_pop * (n_child + 1) * (l_max * EXEMPLAR_BYTES + POLICY_BYTES)
    if held <= MAX_HELD_BYTES:
        return None
    return (f'n_pop {n_pop} x (n_child {n_child} + 1) policies of up to l_max {l_max} '
            f'exemplars need about {held / (1 << 30):,.0f} GiB, more than the '
            f'{MAX_HELD_BYTES >> 30} GiB a run may hold: lower n_pop, n_child or l_max')


@dataclass
class Stats:
    """Counters of a run."""

    generation: int = 0
    steps: int = 0                         # MDP steps simulated (the paper's total steps)
    best_value: float = -math.inf          # best evaluated value so far
    delta_star: float = math.inf           # min delta(s) over every state reached so far
    evaluations: int = 0
    repairs: int = 0                       # children repaired after max_tries
    refreshed: int = 0                     # exemplars re-drawn by the refresh operator


@dataclass
class SapGA(Optimizer):
    """The SAP-GA optimizer for one problem."""

    method = 'sapga'

    problem: Problem
    params: SapgaParams
    rng: np.random.Generator
    population: list[Individual]
    stats: Stats = field(default_factory=Stats)
    best: Individual | None = None         # the best evaluated member so far
    _gen: 'Generation | None' = field(default=None, repr=False)   # between ask and tell
    catch: ControlledPolicy | None = None  # the design's catch, when its region evolves
    catch_sigma: float = 0.0               # log-normal mutation size of the catch scale
    catch_rng: np.random.Generator | None = None   # draws of the catch scales only
    redraw: bool = False                   # episodes drawn anew each generation (see above)

    def evolve_catch(self, catch: ControlledPolicy, sigma: float, seed: int) -> None:
        """Evolve each individual's catch scale (``catch``: the design's LQR and c); ``ask``
        then returns policies with their own catch.  A resumed run keeps its generator."""
        self.catch, self.catch_sigma = catch, sigma
        if self.catch_rng is None:
            self.catch_rng = np.random.default_rng([seed, 0xCA7C4])

    @classmethod
    def create(cls, problem: Problem, params: SapgaParams, seed: int,
               initial: list[ExemplarPolicy] = ()) -> 'SapGA':
        """A random initial population; ``initial`` policies (prior knowledge) replace the
        first members."""
        rng = np.random.default_rng(seed)
        pop = [Individual(random_policy(problem, rng, params.l_min, params.l_max, params.style))
               for _ in range(params.n_pop)]
        for i, policy in enumerate(list(initial)[:params.n_pop]):
            if policy.problem.name != problem.name:
                raise ValueError(f'initial policy {i} is for {policy.problem.name}, '
                                 f'not {problem.name}')
            if policy.style != params.style:
                raise ValueError(f'initial policy {i} is of style {policy.style}, '
                                 f'not {params.style}')
            pop[i] = Individual(policy.subset(slice(None)))
        return cls(problem, params, rng, pop)

    def ask(self) -> list[ExemplarPolicy]:
        """Form this generation's families; return the members that need an evaluation,
        family by family (its parents without a known value, then its children): a
        ``PolicyBatch`` (with an evolved catch, a list of hybrid policies)."""
        if self._gen is not None:
            raise RuntimeError('ask() called twice without tell()')
        p = self.params
        order = self.rng.permutation(p.n_pop).tolist()            # random couples
        pop = self.population
        if self.redraw:                     # last generation's values: other episodes
            for m in pop:
                m.value = math.nan
        couples = [(order[2 * f], order[2 * f + 1]) for f in range(p.n_pop // 2)]
        kids, repaired = crossover_group([(pop[i].policy, pop[j].policy) for i, j in couples],
                                         self.rng, p.n_child, p.l_min, p.l_max,
                                         p.crossover_rate, p.max_tries)  # = uniform_crossover
        self.stats.repairs += repaired
        gen = Generation(couples, [(pop[i], pop[j]) for i, j in couples], kids,
                         self._child_scales(couples), p.n_child)
        self._gen = gen
        batch = PolicyBatch([m.policy for m in gen.waiting], kids, gen.rows)
        if self.catch is not None:
            held = [m.scale for m in gen.waiting] + gen.scales
            return [hybrid_of_valid(policy, self.catch, held[r])
                    for policy, r in zip(batch, gen.rows.tolist())]
        return batch

    @property
    def _families(self) -> list | None:
        """This generation's families (i, j, [parent i, parent j, children...])."""
        g = self._gen
        return None if g is None else [
            (i, j, [a, b] + [g.child(f * g.n_child + c) for c in range(g.n_child)])
            for f, ((i, j), (a, b)) in enumerate(zip(g.couples, g.parents))]

    @property
    def _pending(self) -> list | None:
        """The members ``ask`` returned, in its order (family by family)."""
        g = self._gen
        return None if g is None else [g.member(s) for s in range(len(g))]

    def _child_scales(self, couples: list[tuple[int, int]]) -> list[float]:
        """Each child's catch scale, family by family: one parent's (a fair coin), mutated
        log-normally; 1.0 each while the catch does not evolve."""
        count = len(couples) * self.params.n_child
        if self.catch is None:
            return [1.0] * count
        coins = self.catch_rng.random(count) < 0.5
        noise = self.catch_rng.standard_normal(count)
        pop, n = self.population, self.params.n_child
        parents = np.array([pop[i if coins[k] else j].scale
                            for f, (i, j) in enumerate(couples)
                            for k in range(f * n, (f + 1) * n)])
        return np.clip(parents * np.exp(self.catch_sigma * noise), *SCALE_RANGE).tolist()

    def tell(self, returns: np.ndarray, delta_star: np.ndarray, steps: np.ndarray,
             reached: np.ndarray, used: list[np.ndarray]) -> None:
        """Take the evaluations of ``ask()``'s policies, in order; replace the parents."""
        g = self._gen
        if g is None or not \
                len(returns) == len(delta_star) == len(steps) == len(reached) == len(used) \
                == len(g):
            raise RuntimeError('tell() needs the results of the last ask(), in order')
        st = self.stats
        values = np.asarray(returns, dtype=float)
        values = np.where(np.isfinite(values), values, -math.inf)    # NaN ranks worst
        dstar = np.asarray(delta_star, dtype=float)
        steps = np.asarray(steps).astype(np.int64, copy=False)
        g.take(values, dstar, steps, np.asarray(reached), used)
        if len(values):
            # As taking the members one by one: NaN delta* never lowers the run's, and the
            # best is the first member (in family order) of highest rank, if it ranks above
            # the best so far.
            st.steps += int(steps.sum())
            st.evaluations += len(values)
            seen = dstar[~np.isnan(dstar)]
            if len(seen):
                st.delta_star = min(st.delta_star, float(seen.min()))
            st.best_value = max(st.best_value, float(values.max()))
            first = g.member(self._first_best(values, dstar))
            if self.best is None or self.redraw or self._rank(first) > self._rank(self.best):
                self.best = first
        stars = self._stars(g, values, dstar)
        clones = refreshes(stars, self.rng, self.params.refresh_rate)  # = refresh each
        for (i, j), star, (clone, count) in zip(g.couples, stars, clones):
            st.refreshed += count
            twin = Individual(clone, scale=star.scale)
            if count == 0:                                        # unchanged: value known
                twin = Individual(clone, star.value, star.delta_star, star.steps,
                                  star.reached, star.used, star.scale)
            star.policy = compact(star.policy)      # a child: arrays of its own
            self.population[i] = star
            self.population[j] = twin
        st.generation += 1
        self._gen = None

    def _stars(self, g: 'Generation', values: np.ndarray, dstar: np.ndarray) -> list:
        """Each family's best member pi* (``_rank``; the first of equals in the order parent
        i, parent j, children, or children first for the *-child variants)."""
        vals, dists = g.child_values(values), g.child_values(dstar)
        if self.params.variant in ('dstar', 'dstar-child'):
            best = [self._first_best(v, d) for v, d in zip(vals, dists)]
        else:
            best = vals.argmax(axis=1).tolist()   # ``_first_best`` of each row, at once
        children_first = self.params.variant in ('child-ties', 'dstar-child')
        stars = []
        for f, (a, b) in enumerate(g.parents):
            c = best[f]
            child = self._key(float(vals[f, c]), float(dists[f, c]))
            if children_first:                    # as max over (children..., a, b)
                star, key = None, child
                for m in (a, b):
                    if self._rank(m) > key:
                        star, key = m, self._rank(m)
            else:                                 # as max over (a, b, children...)
                star = b if self._rank(b) > self._rank(a) else a
                if child > self._rank(star):
                    star = None
            stars.append(g.child(f * g.n_child + c) if star is None else star)
        return stars

    def _first_best(self, values: np.ndarray, dstar: np.ndarray) -> int:
        """Index of the first entry of highest ``_rank`` (values already NaN-free)."""
        if self.params.variant in ('dstar', 'dstar-child'):
            near = np.where(np.isnan(dstar), -math.inf, -dstar)
            ties = np.flatnonzero(near == near.max())
            return int(ties[np.argmax(values[ties])])
        return int(np.argmax(values))

    def _rank(self, m: Individual):
        """What selection maximises: the value (paper), or nearness to the goal first."""
        return self._key(m.value, m.delta_star)

    def _key(self, value: float, delta_star: float):
        """``_rank`` of a member of this value and delta*."""
        if self.params.variant in ('dstar', 'dstar-child'):
            return (-delta_star if not math.isnan(delta_star) else -math.inf, value)
        return value

    @property
    def steps(self) -> int:
        return self.stats.steps

    @property
    def iteration(self) -> int:
        return self.stats.generation

    @property
    def result(self) -> Result | None:
        best = self.best
        if best is None:
            return None
        st = self.stats
        return Result(best.policy.subset(slice(None)), {
            'value': best.value, 'delta_star': best.delta_star, 'steps_to_end': best.steps,
            'reached': best.reached, 'run_delta_star': st.delta_star, 'steps': st.steps,
            'generations': st.generation, 'method': self.method,
            'trainer': asdict(self.params),
            **({'catch_scale': best.scale} if self.catch is not None else {})})

    def counters(self) -> dict:
        return asdict(self.stats)

    @staticmethod
    def settings(problem: Problem, params: SapgaParams) -> dict:
        return {'params': asdict(params)}

    def state_dict(self) -> State:
        arrays = pack(self.population, 'pop')
        if self.best is not None:
            arrays.update(pack([self.best], 'best'))
        meta = {'stats': asdict(self.stats), 'rng': self.rng.bit_generator.state}
        if self.catch_rng is not None:
            meta['catch_rng'] = self.catch_rng.bit_generator.state
        return meta, arrays

    @classmethod
    def from_state(cls, problem: Problem, params: SapgaParams, state: State,
                   **run: object) -> 'SapGA':
        meta, arrays = state
        rng = np.random.default_rng()
        try:
            rng.bit_generator.state = meta['rng']
            stats = Stats(**meta['stats'])
            catch_rng = None
            if 'catch_rng' in meta:
                catch_rng = np.random.default_rng()
                catch_rng.bit_generator.state = meta['catch_rng']
        except (KeyError, TypeError, ValueError) as exc:
            raise CheckpointError(f'malformed run state ({exc})') from exc
        population = unpack(problem, arrays, 'pop', params.style)
        if len(population) != params.n_pop:
            raise CheckpointError(f'population of {len(population)}, expected {params.n_pop}')
        ga = cls(problem, params, rng, population, stats, catch_rng=catch_rng)
        if 'best_lengths' in arrays:
            ga.best = unpack(problem, arrays, 'best', params.style)[0]
        return ga
