"""One training run, top to bottom, for any method: optimizer, rounds, log, checkpoints.

``train(config)`` drives an optimizer of the contract ``sapga_ros.optim.base`` (SAP-GA,
the Q-learning baseline or CMA-ES) until the MDP-step budget is spent (checked after each ask/tell
round, so a run simulates at most one generation, or one episode, more) or ``should_stop()``
says so: it evaluates what ``ask()`` hands out in one parallel batch, tells the measures,
logs a progress row per round (the optimizer's counters, ``achieved``, ``steps_per_s``, time
spent compiling kernels left out), saves at least every ``checkpoint_seconds`` of wall time
(and every ``checkpoint_every`` rounds, if set) and at the end, and returns the best policy
with its provenance in ``meta``.
A save writes the checkpoint (``training/checkpoints.py``) and hands the best policy so far
and the log to ``on_save``, which writes them where the caller keeps them: a killed run
loses at most one period.  Same seed, same result, with or without checkpoint/resume.
The CLI, the trainer node and the experiments all train through it.  With ``disturbance``
or ``episodes`` set, every evaluation is robust (``sapga_ros.evaluation.robust``).
(Longer than 300 lines: one run's settings, its round loop and its result belong together.)
"""
from __future__ import annotations

import csv
import io
import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Generator

import numpy as np

from sapga_ros import __version__
from sapga_ros.errors import CheckpointError, ConfigError
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.evaluation.robust import check_stat, robust_evaluator
from sapga_ros.policies.controller_row import MAX_DELAY
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.io.atomic import write_atomic
from sapga_ros.optim.base import Optimizer
from sapga_ros.optim.cmaes import Cmaes, CmaesParams
from sapga_ros.optim.qlearner import QLearning, QlParams, learn_together
from sapga_ros.optim.sapga import SapGA, SapgaParams
from sapga_ros.training import checkpoints
from sim_nodes.jit import compile_seconds
from sim_nodes.params import DELTA, MAX_EPISODES, check, param
from sim_nodes.problem import Problem, load_problem

METHODS: dict[str, type[Optimizer]] = {'sapga': SapGA, 'ql': QLearning, 'cmaes': Cmaes}


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run (``param`` fields: ``sapga train`` options and trainer
    node parameters alike; ``delta`` None: the problem's)."""

    problem: str = 'acrobot'               # problem name (msg_configs/<problem>.yaml)
    method: str = param('sapga', 'sapga (SAP-GA), ql (the tabular Q-learning baseline) or '
                        'cmaes (CMA-ES over state-action exemplars)', choices=tuple(METHODS))
    delta: float | None = param(DELTA)
    steps: int = param(30_000_000, 'budget of MDP steps simulated', low=1)
    seed: int = param(0, 'seed of every random choice of the run', low=0)
    jobs: int = param(0, 'evaluation threads; 0: every core', low=0)
    checkpoint: str | None = None          # directory for checkpoint.npz; None: none
    checkpoint_seconds: float = param(30.0, 'of wall time at most between saves of the '
                                      'checkpoint and the best policy so far', low=0.01,
                                      high=86400.0, unit='s')
    checkpoint_every: int = param(0, 'rounds (SAP-GA generations, Q-learning chunks) '
                                  'between checkpoints besides; 0: by time only', low=0)
    resume: bool = param(False, 'continue from the checkpoint in the checkpoint directory')
    catch: str = param('none', 'lqr: every policy hands over to the problem\'s LQR inside '
                       'its catch region x\'Px <= c (the hybrid; SAP-GA only); none: not',
                       choices=('none', 'lqr'))
    catch_delay: int = param(0, 'MDP steps of actuation delay the catch\'s LQR is designed '
                             'for (--catch lqr): it acts on the state predicted that far ahead '
                             'from the commands in flight; 0: none', low=0, high=MAX_DELAY)
    delay: int = param(0, 'MDP steps of actuation delay the exemplar selector is designed for '
                       '(a plant that applies each command that late): it acts on the state '
                       'predicted that far ahead from the commands in flight with the '
                       'nominal model; 0: on the state it sees (a hybrid: --catch-delay)',
                       low=0, high=MAX_DELAY)
    catch_sigma: float = param(0.0, 'log-normal mutation size of each policy\'s catch region '
                               '(--catch lqr): a child\'s c is a parent\'s times exp(sigma '
                               'N(0,1)), within 1/64..16 x the design\'s c; 0: the design\'s c '
                               'for every policy', low=0.0, high=4.0)
    disturbance: str = param('none', 'disturbance profile of every evaluation (robust '
                             'fitness): a name in msg_configs/disturbances or a .yaml file; '
                             'none: the undisturbed model')
    episodes: int = param(1, 'disturbed episodes per policy evaluation (the same draws for '
                          'every policy of the run)', low=1, high=MAX_EPISODES)
    robust_stat: str = param('mean', 'value of a policy over its episodes: mean, or qNN, the '
                             'NN-th percentile of the returns (a lower quantile, e.g. q10)')
    redraw: bool = param(False, 'draw the disturbed episodes anew each generation (the same '
                         'draws for every member of that generation, parents re-evaluated '
                         'on them) instead of once for the run')
    params: SapgaParams = field(default_factory=SapgaParams)
    ql: QlParams = field(default_factory=QlParams)
    cmaes: CmaesParams = field(default_factory=CmaesParams)

    def __post_init__(self) -> None:
        check(self)
        check_stat(self.robust_stat)
        if self.catch_delay and self.catch != 'lqr':
            raise ConfigError('catch_delay: the delay of the LQR catch needs catch lqr')
        if self.delay and self.catch != 'none':
            raise ConfigError('delay: a hybrid acts on the prediction of its catch\'s delay '
                              '(catch_delay); delay is for exemplar policies without a catch')
        if self.delay and self.method == 'ql':
            raise ConfigError('delay: a Q-table acts on the state it sees; exemplar methods '
                              '(sapga, cmaes) only')
        if self.catch_sigma and self.catch != 'lqr':
            raise ConfigError('catch_sigma: evolving the catch region needs catch lqr')
        if self.redraw and not self.disturbed:
            raise ConfigError('redraw: drawing episodes anew needs a disturbance or episodes > 1')
        if self.redraw and self.method != 'sapga':
            raise ConfigError('redraw: episodes drawn anew each generation: SAP-GA only')

    @property
    def disturbed(self) -> bool:
        """Evaluations are disturbed (``disturbance`` not none, or several episodes)."""
        return self.disturbance != 'none' or self.episodes > 1


@dataclass
class TrainResult:
    """What a run returns: the best policy (with meta), the log, the counters, and why it
    ended ({'budget': steps} or {'should_stop': True})."""

    policy: Any
    history: list[dict]
    stats: dict
    stop: dict = field(default_factory=dict)


Progress = Callable[[dict], None]


def json_roundtrip(obj: Any) -> Any:
    """``obj`` as it reads back from JSON (tuples become lists)."""
    return json.loads(json.dumps(obj))


def run_settings(config: TrainConfig, problem: Problem, delta: float) -> dict:
    """What a checkpoint must share with the run that resumes it."""
    cls = METHODS[config.method]
    robust = {'disturbance': config.disturbance, 'episodes': config.episodes,
              'robust_stat': config.robust_stat} if config.disturbed else {}
    if config.redraw:                   # absent when off: earlier checkpoints still resume
        robust['redraw'] = True
    # the catch is in the loop: a hybrid run resumes only as the same hybrid (no catch: the
    # paper's settings, so that checkpoints written before the catch existed still resume)
    hybrid = ({'catch': config.catch, 'catch_delay': config.catch_delay}
              if config.catch != 'none' else {})
    evolved = {'catch_sigma': config.catch_sigma} if config.catch_sigma else {}
    ahead = {'delay': config.delay} if config.delay else {}
    return json_roundtrip({'problem': problem.name, 'method': config.method, 'delta': delta,
                           'seed': config.seed, **cls.settings(problem, method_params(config)),
                           **robust, **hybrid, **evolved, **ahead})


def method_params(config: TrainConfig) -> SapgaParams | QlParams | CmaesParams:
    """The strategy parameters of the run's method."""
    return {'sapga': config.params, 'ql': config.ql, 'cmaes': config.cmaes}[config.method]


def _start(config: TrainConfig, problem: Problem, delta: float,
           initial: list[ExemplarPolicy]) -> tuple[Optimizer, list[dict]]:
    """A new optimizer, or the one of the checkpoint (with the log so far)."""
    if config.method != 'sapga' and initial:
        raise ConfigError(f'initial policies seed a SAP-GA population; {config.method} takes '
                          f'none')
    if not config.resume:
        if config.method == 'sapga':
            return SapGA.create(problem, config.params, config.seed, initial), []
        if config.method == 'cmaes':
            return Cmaes.create(problem, config.cmaes, config.seed), []
        return QLearning.create(problem, config.ql, config.seed, delta, config.steps), []
    if not config.checkpoint:
        raise CheckpointError('--resume needs --checkpoint DIR')
    cls, params = METHODS[config.method], method_params(config)
    return checkpoints.restore(
        config.checkpoint, run_settings(config, problem, delta),
        lambda state: cls.from_state(problem, params, state, delta=delta, budget=config.steps))


def _save(config: TrainConfig, problem: Problem, delta: float, opt: Optimizer,
          history: list[dict]) -> None:
    settings = {k: v for k, v in checkpoints.settings_of(config).items()
                if k not in ('resume', 'delta')}     # the run's delta is in run_settings
    checkpoints.save(config.checkpoint, run_settings(config, problem, delta),
                     json_roundtrip(settings), opt, history)


def _evaluate(evaluator: Evaluator, batch: list) -> tuple[tuple, float]:
    """((returns, delta_star, steps, reached, used), min delta* under the alternative goal
    reading, inf without one) of a batch of policies."""
    if not batch:
        return (np.empty(0), np.empty(0), np.empty(0, np.int64), np.empty(0, np.bool_),
                []), math.inf
    r = evaluator.evaluate(batch)
    alt = math.inf if r.delta_star_alt is None else float(np.min(r.delta_star_alt))
    return (r.returns, r.delta_star, r.steps, r.reached, r.used), alt


def train(config: TrainConfig, initial: list[ExemplarPolicy] = (),
          progress: Progress | None = None,
          on_best: Callable[[Any], None] | None = None,
          should_stop: Callable[[], bool] | None = None,
          on_save: Callable[[Any, list[dict]], None] | None = None) -> TrainResult:
    """Run ``config.method`` as configured; return the best policy and the log.

    ``progress(row)`` is called after each round, ``on_best(policy)`` whenever the best
    (of an optimizer that follows one: SAP-GA) improves, the policy carrying its meta;
    ``on_save(policy, history)`` with the best policy so far and the log at each save before
    the end (the caller writes the end's); the run ends early, with its best so far, once
    ``should_stop()`` is true.
    """
    rounds = _rounds(config, initial, progress, on_best, should_stop, on_save)
    while True:
        try:
            next(rounds)
        except StopIteration as end:
            return end.value


def train_lanes(configs: list[TrainConfig]) -> list[TrainResult]:
    """Q-learning runs of one problem and goal (e.g. the seeds of an experiment row),
    each as ``train(config)`` would run it, bit for bit, but learnt side by side: before
    each round, every run still going learns its next chunk in one ``learn_together``
    call (lanes of one vectorised model step)."""
    if any(c.method != 'ql' for c in configs):
        raise ConfigError('only Q-learning runs learn side by side')
    runs = [_rounds(c) for c in configs]
    going: dict[int, QLearning] = {}
    results: dict[int, TrainResult] = {}

    def advance(i: int) -> None:
        try:
            going[i] = next(runs[i])
        except StopIteration as end:
            going.pop(i, None)
            results[i] = end.value

    for i in range(len(runs)):
        advance(i)
    while going:
        learn_together(list(going.values()))
        for i in list(going):
            advance(i)
    return [results[i] for i in range(len(runs))]


SAME = 1e-9        # relative difference below which a seed's catch is the run's design


def initial_regions(initial: list, catch: Any, sigma: float) -> list[float]:
    """Each seed's catch scale (its region's c over the design's) in a run behind
    ``catch`` (the design as a hybrid): 1 for a plain policy; a hybrid's must have the
    design's LQR, and a region other than the design's only where regions evolve
    (``sigma`` > 0) and within their range: nothing of a seed is dropped unsaid."""
    from sapga_ros.optim.population import SCALE_RANGE
    from sapga_ros.policies.classical import catch_delay
    scales = []
    for i, policy in enumerate(initial):
        if catch_delay(policy) is None:
            scales.append(1.0)
            continue
        same = np.allclose(policy.K, catch.K, rtol=SAME, atol=0.0) and \
            np.allclose(policy.P, catch.P, rtol=SAME, atol=0.0)    # LAPACK's last bits aside
        if catch_delay(policy) != catch.delay or not same:
            raise ConfigError(f'initial policy {i}: its catch is not this run\'s (the LQR '
                              f'of the design for a delay of {catch.delay})')
        scale = policy.c / catch.c
        scale = 1.0 if abs(scale - 1.0) <= SAME else scale
        if scale != 1.0 and not sigma:
            raise ConfigError(f'initial policy {i}: its catch region is {scale:.6g} x the '
                              'design\'s; this run keeps the design\'s (--catch-sigma > 0 '
                              'evolves regions, starting from its own)')
        if not SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]:
            raise ConfigError(f'initial policy {i}: its catch region is {scale:.6g} x the '
                              f'design\'s, outside the evolved range [{SCALE_RANGE[0]:g}, '
                              f'{SCALE_RANGE[1]:g}]')
        scales.append(float(scale))
    return scales


def _rounds(config: TrainConfig, initial: list[ExemplarPolicy] = (),
            progress: Progress | None = None,
            on_best: Callable[[Any], None] | None = None,
            should_stop: Callable[[], bool] | None = None,
            on_save: Callable[[Any, list[dict]], None] | None = None
            ) -> Generator[Optimizer, None, TrainResult]:
    """``train`` as a generator: it yields the optimizer before each round (a caller may
    prepare the round, as ``train_lanes`` does) and returns the ``TrainResult``."""
    problem = load_problem(config.problem)
    delta = problem.resolve('delta', config.delta)
    jobs = set_jobs(config.jobs)
    evaluator = make_evaluator(config, problem, delta)
    catch = None
    if config.catch == 'lqr':
        if config.method != 'sapga':
            raise ConfigError('--catch lqr hands exemplar policies over to the LQR: SAP-GA only')
        from sapga_ros.evaluation.classical_design import classical_policy
        from sapga_ros.policies.classical import with_catch
        design = classical_policy(problem, delay=config.catch_delay)
        if not design.c > 0:
            raise ConfigError(f'{problem.name}: the LQR catch region measured empty (its LQR, '
                              f'quantised to the actions {list(problem.actions)}, keeps '
                              f'S_{problem.default_delta:g} from none of the probe starts): '
                              '--catch lqr would add nothing')
        catch = with_catch(ExemplarPolicy(problem, np.zeros((0, problem.dim))), design)
        evaluator.catch = catch.control
    elif config.delay:          # every policy selects on the state predicted that far ahead
        from sapga_ros.policies.classical import ahead
        catch = ahead(ExemplarPolicy(problem, np.zeros((0, problem.dim))), config.delay)
        evaluator.catch = catch.control
    regions = initial_regions(initial, catch, config.catch_sigma) if config.catch == 'lqr' \
        else []
    opt, history = _start(config, problem, delta, list(initial))
    if config.catch_sigma:
        opt.evolve_catch(catch, config.catch_sigma, config.seed)
    if regions and not config.resume:    # a hybrid seed keeps its region
        for member, scale in zip(opt.population, regions):
            member.scale = scale
    if config.redraw:
        opt.redraw = True
    start = last_save = time.perf_counter()
    steps_at_start, compiled_at_start = opt.steps, compile_seconds()
    alt_star = min([math.inf] + [r['delta_star_alt'] for r in history[-1:]
                                 if r.get('delta_star_alt') is not None])
    hold: dict = {}
    while not (reasons := opt.stop(config.steps)):
        if should_stop and should_stop():
            reasons = {'should_stop': True}
            break
        yield opt
        best_before = opt.best
        if config.redraw:
            evaluator.generation = opt.iteration
        results, alt = _evaluate(evaluator, opt.ask())
        opt.tell(*results)
        alt_star = min(alt_star, alt)
        if on_best and opt.best is not best_before:
            on_best(_best_policy(config, opt, delta, jobs, catch))
        row = opt.counters()
        if not problem.ends_in_goal:    # the hold task: the best policy's hold measures
            if opt.best is not best_before or not hold or config.method == 'ql':
                meta = _best_policy(config, opt, delta, jobs, catch).meta
                hold = {f'best_{k}': meta[k] for k in HOLD_KEYS}
            row.update(hold)
        if problem.goal_alt_scale is not None and 'delta_star_alt' not in row:
            row['delta_star_alt'] = alt_star   # the alternative goal reading, same runs
        now = time.perf_counter()
        busy = now - start - (compile_seconds() - compiled_at_start)   # compiling: not a rate
        row.update(achieved=row['delta_star'] <= delta,
                   steps_per_s=(opt.steps - steps_at_start) / max(busy, 1e-9))
        history.append(row)
        if progress:
            progress(row)
        timely = now - last_save >= config.checkpoint_seconds
        if config.checkpoint and (timely or config.checkpoint_every and
                                  opt.iteration % config.checkpoint_every == 0):
            _save(config, problem, delta, opt, history)
        if timely:
            if on_save:
                on_save(_best_policy(config, opt, delta, jobs, catch), history)
            last_save = time.perf_counter()
    if config.checkpoint:
        _save(config, problem, delta, opt, history)
    return TrainResult(_best_policy(config, opt, delta, jobs, catch), history, opt.counters(),
                       reasons)


def make_evaluator(config: TrainConfig, problem: Problem, delta: float) -> Evaluator:
    """The run's evaluator: with robust fitness, every policy on ``episodes`` episodes of the
    ``disturbance`` profile (``sapga_ros.evaluation.robust``)."""
    if config.disturbed and config.method == 'ql':
        raise ConfigError('--disturbance and --episodes evaluate policies: SAP-GA and CMA-ES '
                          'only')
    return robust_evaluator(problem, delta, config.disturbance, config.episodes,
                            config.robust_stat, config.seed, config.redraw) \
        or Evaluator(problem, delta)


def hold_of(policy: Any, delta: float) -> dict:
    """The hold measures of ``policy``'s episode (first_entry_step, hold_fraction,
    rail_contacts)."""
    from sapga_ros.evaluation.evaluator import run_policy_episode
    summary = run_policy_episode(policy, delta).summary()
    return {k: summary[k] for k in HOLD_KEYS}


HOLD_KEYS = ('first_entry_step', 'hold_fraction', 'rail_contacts')


def train_sapga(config: TrainConfig, initial: list[ExemplarPolicy] = (),
                progress: Progress | None = None,
                on_best: Callable[[ExemplarPolicy], None] | None = None,
                should_stop: Callable[[], bool] | None = None) -> TrainResult:
    """``train`` with SAP-GA."""
    return train(replace(config, method='sapga'), initial, progress, on_best, should_stop)


def _best_policy(config: TrainConfig, opt: Optimizer, delta: float, jobs: int,
                 catch: Any = None) -> Any:
    """The best policy so far, with its provenance in ``meta`` (behind ``catch``, the
    hybrid's LQR or the prediction of a policy designed for a delay, if given)."""
    result = opt.result
    if result is None:
        raise ConfigError('the run ended before its first evaluation: no policy to return')
    policy = result.policy
    if catch is not None:
        from sapga_ros.policies.classical import with_catch
        policy = with_catch(policy, catch, result.meta.get('catch_scale', 1.0))
    policy.meta = {**result.meta, 'delta': delta, 'seed': config.seed, 'jobs': jobs,
                   'software': f'sapga_ros {__version__}',
                   'time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}
    if config.disturbed:        # value and delta*: over the run's disturbed episodes
        policy.meta.update(disturbance=config.disturbance, episodes=config.episodes,
                           robust_stat=config.robust_stat,
                           **({'redraw': True} if config.redraw else {}))
    if not policy.problem.ends_in_goal:
        policy.meta.update(hold_of(policy, delta))
    return policy


def write_log(path: Path, history: list[dict]) -> None:
    """Write a run's log rows (one per progress report) as CSV, atomically (columns: every
    key, in order of appearance; a row resumed from an older checkpoint may lack some)."""
    if not history:
        return
    text = io.StringIO(newline='')
    columns = list(dict.fromkeys(k for row in history for k in row))
    writer = csv.DictWriter(text, fieldnames=columns)
    writer.writeheader()
    writer.writerows(history)
    write_atomic(path, text.getvalue())
