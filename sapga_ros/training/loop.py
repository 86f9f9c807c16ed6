"""One training run, top to bottom, for either method: optimizer, rounds, log, checkpoints.

``train(config)`` drives an optimizer of the contract ``sapga_ros.optim.base`` (SAP-GA, or
the Q-learning baseline) until the MDP-step budget is spent (checked after each ask/tell
round, so a run simulates at most one generation, or one episode, more) or ``should_stop()``
says so: it evaluates what ``ask()`` hands out in one parallel batch, tells the measures,
logs a progress row per round (the optimizer's counters, ``achieved``, ``steps_per_s``),
checkpoints every ``checkpoint_every`` rounds and at the end, and returns the best policy
with its provenance in ``meta``.  Same seed, same result, with or without checkpoint/resume.
The CLI, the trainer node and the experiments all train through it.
"""
from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sapga_ros import __version__
from sapga_ros.errors import CheckpointError, ConfigError
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.exemplars.policy import ExemplarPolicy
from sapga_ros.io.checkpoint import load_checkpoint, save_checkpoint
from sapga_ros.optim.base import Optimizer
from sapga_ros.optim.qlearner import QLearning, QlParams
from sapga_ros.optim.sapga import SapGA, SapgaParams
from sapga_ros.optim.settings import check, setting
from sim_nodes.problem import Problem, load_problem

METHODS: dict[str, type[Optimizer]] = {'sapga': SapGA, 'ql': QLearning}


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run (``setting`` fields: ``sapga train`` options and trainer
    node parameters alike)."""

    problem: str = 'acrobot'               # problem name (msg_configs/<problem>.yaml)
    method: str = setting('sapga', 'sapga (SAP-GA) or ql (the tabular Q-learning baseline)',
                          choices=tuple(METHODS))
    delta: float | None = None             # goal difficulty; None: the problem's default
    steps: int = setting(30_000_000, 'budget of MDP steps simulated', low=1)
    seed: int = setting(0, 'seed of every random choice of the run', low=0)
    jobs: int = setting(0, 'evaluation threads; 0: every core', low=0)
    checkpoint: str | None = None          # directory for checkpoint.npz; None: none
    checkpoint_every: int = setting(20, 'rounds (SAP-GA generations, Q-learning chunks) '
                                    'between checkpoints', low=1)
    resume: bool = setting(False, 'continue from the checkpoint in the checkpoint directory')
    params: SapgaParams = field(default_factory=SapgaParams)
    ql: QlParams = field(default_factory=QlParams)

    def __post_init__(self) -> None:
        check(self)


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


def _run_settings(config: TrainConfig, problem: Problem, delta: float) -> dict:
    """What a checkpoint must share with the run that resumes it."""
    cls = METHODS[config.method]
    return json_roundtrip({'problem': problem.name, 'method': config.method, 'delta': delta,
                           'seed': config.seed, **cls.settings(problem, _params(config))})


def _params(config: TrainConfig) -> SapgaParams | QlParams:
    return config.params if config.method == 'sapga' else config.ql


def _start(config: TrainConfig, problem: Problem, delta: float,
           initial: list[ExemplarPolicy]) -> tuple[Optimizer, list[dict]]:
    """A new optimizer, or the one of the checkpoint (with the log so far)."""
    if config.method != 'sapga' and initial:
        raise ConfigError('initial policies seed a SAP-GA population; Q-learning takes none')
    if not config.resume:
        if config.method == 'sapga':
            return SapGA.create(problem, config.params, config.seed, initial), []
        return QLearning.create(problem, config.ql, config.seed, delta, config.steps), []
    if not config.checkpoint:
        raise CheckpointError('--resume needs --checkpoint DIR')
    meta, arrays = load_checkpoint(config.checkpoint)
    want = _run_settings(config, problem, delta)
    if meta.get('run') != want:
        raise CheckpointError(f'{config.checkpoint}: checkpoint is of another run '
                              f'({meta.get("run")}), not {want}')
    try:
        opt = METHODS[config.method].from_state(problem, _params(config), (meta, arrays),
                                                delta=delta, budget=config.steps)
    except CheckpointError as exc:
        raise CheckpointError(f'{config.checkpoint}: {exc}') from exc
    history = meta.get('history', [])
    return opt, list(history) if isinstance(history, list) else []


def _save(config: TrainConfig, problem: Problem, delta: float, opt: Optimizer,
          history: list[dict]) -> None:
    meta, arrays = opt.state_dict()
    save_checkpoint(config.checkpoint, {'run': _run_settings(config, problem, delta), **meta,
                                        'history': history}, arrays)


def _evaluate(evaluator: Evaluator, batch: list) -> tuple:
    """(returns, delta_star, steps, reached, used) of a batch of policies."""
    if not batch:
        return np.empty(0), np.empty(0), np.empty(0, np.int64), np.empty(0, np.bool_), []
    r = evaluator.evaluate(batch)
    return r.returns, r.delta_star, r.steps, r.reached, r.used


def train(config: TrainConfig, initial: list[ExemplarPolicy] = (),
          progress: Progress | None = None,
          on_best: Callable[[Any], None] | None = None,
          should_stop: Callable[[], bool] | None = None) -> TrainResult:
    """Run ``config.method`` as configured; return the best policy and the log.

    ``progress(row)`` is called after each round, ``on_best(policy)`` whenever the best
    (of an optimizer that follows one: SAP-GA) improves, the policy carrying its meta, and
    the run ends early, with its best so far, once ``should_stop()`` is true.
    """
    problem = load_problem(config.problem)
    delta = float(problem.default_delta if config.delta is None else config.delta)
    jobs = set_jobs(config.jobs)
    evaluator = Evaluator(problem, delta)
    opt, history = _start(config, problem, delta, list(initial))
    start = time.perf_counter()
    steps_at_start = opt.steps
    while not (reasons := opt.stop(config.steps)):
        if should_stop and should_stop():
            reasons = {'should_stop': True}
            break
        best_before = opt.best
        opt.tell(*_evaluate(evaluator, opt.ask()))
        if on_best and opt.best is not best_before:
            on_best(_best_policy(config, opt, delta, jobs))
        row = opt.counters()
        elapsed = time.perf_counter() - start
        row.update(achieved=row['delta_star'] <= delta,
                   steps_per_s=(opt.steps - steps_at_start) / max(elapsed, 1e-9))
        history.append(row)
        if progress:
            progress(row)
        if config.checkpoint and opt.iteration % config.checkpoint_every == 0:
            _save(config, problem, delta, opt, history)
    if config.checkpoint:
        _save(config, problem, delta, opt, history)
    return TrainResult(_best_policy(config, opt, delta, jobs), history, opt.counters(),
                       reasons)


def train_sapga(config: TrainConfig, initial: list[ExemplarPolicy] = (),
                progress: Progress | None = None,
                on_best: Callable[[ExemplarPolicy], None] | None = None,
                should_stop: Callable[[], bool] | None = None) -> TrainResult:
    """``train`` with SAP-GA."""
    return train(replace(config, method='sapga'), initial, progress, on_best, should_stop)


def _best_policy(config: TrainConfig, opt: Optimizer, delta: float, jobs: int) -> Any:
    """The best policy so far, with its provenance in ``meta``."""
    result = opt.result
    if result is None:
        raise ConfigError('the run ended before its first evaluation: no policy to return')
    policy = result.policy
    policy.meta = {**result.meta, 'delta': delta, 'seed': config.seed, 'jobs': jobs,
                   'software': f'sapga_ros {__version__}',
                   'time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}
    return policy


def write_log(path: Path, history: list[dict]) -> None:
    """Write a run's log rows (one per progress report) as CSV (columns: every key, in order
    of appearance; a row resumed from an older checkpoint may lack some)."""
    if not history:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w', newline='', encoding='utf-8') as f:
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for row in history
                                                                 for k in row)))
        writer.writeheader()
        writer.writerows(history)
