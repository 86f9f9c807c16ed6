"""Robust fitness and robustness measures: a policy judged on K disturbed episodes.

Draw keys are (seed, generation, policy, episode) (``sim_nodes.draws``).  Training keys every
episode e < K as (seed, 0, TRAINING, e): every policy of a run meets the same K draws (common
random numbers, within each generation and across them), so a value once computed stays
valid and SAP-GA's reuse of known values (and checkpoint/resume) is unchanged.  The price:
the K draws are fixed for the run, so a policy may fit them; a larger K lowers that.  With
``redraw`` the keys are (seed, g, TRAINING, e) in generation g: every member of a generation
meets the same K draws, parents included (SAP-GA re-evaluates them), and each generation
new ones.  The evaluation (``sapga eval --disturbance``) draws with ``policy`` = HELD_OUT,
episodes the run never saw.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from sapga_ros.errors import ConfigError
from sapga_ros.evaluation.evaluator import BatchResult, Evaluator
from sapga_ros.policies.classical import selector_delay
from sim_nodes.disturbance import Disturbance, load_disturbance
from sim_nodes.draws import HELD_OUT, TRAINING
STAT_RE = re.compile(r'^(mean|q(\d{1,2}))$')


def check_stat(stat: str) -> str:
    """``stat`` if it is mean or qNN (the NN-th percentile, 0..99); ConfigError if not."""
    if not isinstance(stat, str) or not STAT_RE.match(stat):
        raise ConfigError(f'robust_stat: expected mean or qNN (a lower percentile, e.g. q10), '
                          f'got {str(stat)[:40]!r}')
    return stat


@dataclass(frozen=True)
class Robust:
    """K disturbed episodes per policy, and the statistic of their returns taken as value."""

    episodes: int
    stat: str = 'mean'
    seed: int = 0
    redraw: bool = False                   # training draws keyed by generation, not fixed

    def __post_init__(self) -> None:
        check_stat(self.stat)
        if self.episodes < 1:
            raise ConfigError(f'episodes: expected a positive integer, got {self.episodes}')

    def keys(self, count: int, purpose: int = TRAINING, generation: int = 0) -> np.ndarray:
        """(count x K, 4) draw keys: policy i's episode e is row i K + e."""
        e = np.tile(np.arange(self.episodes), count)
        keys = np.zeros((count * self.episodes, 4), dtype=np.int64)
        keys[:, 0] = self.seed
        keys[:, 1] = generation
        keys[:, 2] = purpose
        keys[:, 3] = e
        return keys


def statistic(values: np.ndarray, stat: str, worse_high: bool = False) -> np.ndarray:
    """``stat`` over the last axis: the mean, or the qNN percentile of the bad tail (low
    values; high ones with ``worse_high``)."""
    if stat == 'mean':
        return values.mean(axis=-1)
    q = int(stat[1:]) / 100.0
    return np.quantile(values, 1.0 - q if worse_high else q, axis=-1)


def _each_episode(evaluator, policies: list, keys: np.ndarray) -> BatchResult:
    """The plain result of each (policy, key) row, one episode each."""
    return Evaluator.evaluate(evaluator, policies, keys)


class RobustEvaluator(Evaluator):
    """An ``Evaluator`` whose ``evaluate`` is robust fitness (``evaluate_robust``)."""

    def __init__(self, problem, delta: float, disturbance: Disturbance, robust: Robust) -> None:
        super().__init__(problem, delta, disturbance=disturbance)
        self.robust = robust
        self.generation = 0                # the draws' generation (with robust.redraw)

    def evaluate(self, policies: list, keys: None = None) -> BatchResult:
        if keys is not None:
            raise ConfigError('robust fitness draws its own keys')
        return evaluate_robust(self, policies, self.robust)


def evaluate_robust(evaluator, policies: list, robust: Robust):
    """``BatchResult`` of ``policies``, each on ``robust.episodes`` disturbed episodes:
    value = the statistic of the returns, delta* = the same statistic of the episodes' delta*
    (its bad tail), steps = all steps simulated, reached = in every episode, used = referred
    to in any; hold measures: first entry the latest, held and contacts summed."""
    k = robust.episodes
    count = len(policies)
    generation = getattr(evaluator, 'generation', 0) if robust.redraw else 0
    r = _each_episode(evaluator, [p for p in policies for _ in range(k)],
                      robust.keys(count, generation=generation))

    def per(a: np.ndarray) -> np.ndarray:
        return a.reshape(count, k)
    alt = None if r.delta_star_alt is None else statistic(per(r.delta_star_alt), robust.stat,
                                                          True)
    return BatchResult(statistic(per(r.returns), robust.stat),
                       per(r.steps).sum(axis=1), statistic(per(r.delta_star), robust.stat, True),
                       per(r.reached).all(axis=1),
                       [np.any(r.used[i * k:(i + 1) * k], axis=0) for i in range(count)], alt,
                       per(r.first_entry).max(axis=1), per(r.held).sum(axis=1),
                       per(r.contacts).sum(axis=1))


def episodes_summary(evaluator, policy, robust: Robust, purpose: int = HELD_OUT) -> dict:
    """Robustness of one policy over ``robust.episodes`` disturbed episodes (drawn with
    ``purpose``): ``summary`` of the engine's episodes."""
    k = robust.episodes
    r = _each_episode(evaluator, [policy] * k, robust.keys(1, purpose))
    return summary(evaluator.problem, evaluator.delta, evaluator.disturbance.name, robust.seed,
                   selector_delay(policy), r.first_entry, r.held, r.steps, r.contacts,
                   r.delta_star, r.returns)


def summary(problem, delta: float, disturbance: str, seed: int, delay: int, first_entry,
            held, steps, contacts, delta_star, returns) -> dict:
    """Success rate (entered S_delta; hold problems: hold fraction >= 0.9), hold fraction
    and delta* distributions, rail contacts of episodes given by their measures (one entry
    per episode); ``delay``: the actuation delay the policy's selector is designed for (0:
    it acts on the state it sees)."""
    from sim_nodes.goal import hold_measures
    first_entry, contacts = np.asarray(first_entry), np.asarray(contacts)
    k = len(first_entry)
    holds = [hold_measures(int(first_entry[e]), int(held[e]), int(steps[e]),
                           int(contacts[e])) for e in range(k)]
    fraction = np.array([h['hold_fraction'] for h in holds])
    hold_task = not problem.ends_in_goal
    success = fraction >= 0.9 if hold_task else first_entry > 0

    def spread(a) -> dict:
        return {'mean': float(np.mean(a)), 'min': float(np.min(a)),
                'q10': float(np.quantile(a, 0.1)), 'median': float(np.median(a)),
                'q90': float(np.quantile(a, 0.9)), 'max': float(np.max(a))}
    return {'disturbance': disturbance, 'episodes': k, 'seed': seed, 'delta': delta,
            'delay': delay, 'success_rate': float(np.mean(success)),
            'success': 'hold_fraction >= 0.9' if hold_task else 'entered S_delta',
            'entered_rate': float(np.mean(first_entry > 0)),
            'hold_fraction': spread(fraction), 'delta_star': spread(delta_star),
            'return': spread(returns),
            'rail_contacts': {'total': int(contacts.sum()),
                              'episodes_with': int((contacts > 0).sum())}}


def robustness(policy, delta: float, disturbance: str, episodes: int, seed: int = 0,
               n_step: int | None = None) -> dict:
    """``episodes_summary`` of an exemplar or classical policy under profile
    ``disturbance`` (a name or a .yaml file), on held-out draws of ``seed``."""
    from sapga_ros.policies.exemplar import ExemplarPolicy
    if not isinstance(policy, ExemplarPolicy):
        raise ConfigError('disturbed episodes run exemplar and classical policies; a '
                          'Q-learning table is run undisturbed (sapga eval without '
                          '--disturbance)')
    evaluator = Evaluator(policy.problem, delta, n_step,
                          disturbance=load_disturbance(disturbance))
    return episodes_summary(evaluator, policy, Robust(episodes, seed=seed))


def robust_evaluator(problem, delta: float, disturbance: str, episodes: int, stat: str,
                     seed: int, redraw: bool = False):
    """The evaluator of robust fitness (each policy on ``episodes`` episodes of profile
    ``disturbance``), or None for the plain evaluation (none, one episode)."""
    if disturbance == 'none' and episodes == 1:
        return None
    return RobustEvaluator(problem, delta, load_disturbance(disturbance),
                           Robust(episodes, stat, seed, redraw))
