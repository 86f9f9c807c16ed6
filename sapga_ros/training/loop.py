"""A SAP-GA training run, top to bottom: population, generations, log, checkpoints.

``train_sapga(config)`` evolves exemplar policies until the MDP-step budget is spent
(checked after each generation, so a run simulates at most one generation more), logging
(generation, steps, best value, delta*) per generation, checkpointing every
``checkpoint_every`` generations, and returns the best policy found with its provenance in
``meta``.  Same seed, same result, with or without checkpoint/resume.
"""
from __future__ import annotations

import csv
import time
from pathlib import Path
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from sapga_ros import __version__
from sapga_ros.io.checkpoint import load_checkpoint, save_checkpoint
from sapga_ros.errors import CheckpointError, SapgaError
from sapga_ros.evaluation.evaluator import Evaluator, set_jobs
from sapga_ros.exemplars.policy import ExemplarPolicy
from sapga_ros.optim.sapga import Individual, SapGA, SapgaParams, Stats
from sim_nodes.problem import Problem, load_problem


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run (each field is a ``sapga train`` option)."""

    problem: str = 'acrobot'               # problem name (msg_configs/<problem>.yaml)
    method: str = 'sapga'                  # 'sapga' or 'ql' (Q-learning baseline)
    delta: float | None = None             # goal difficulty; None: the problem's default
    steps: int = 30_000_000                # budget of MDP steps simulated
    seed: int = 0                          # seed of every random choice of the run
    jobs: int = 0                          # evaluation threads; 0: every core
    checkpoint: str | None = None          # directory for checkpoint.npz; None: none
    checkpoint_every: int = 20             # generations (SAP-GA) between checkpoints
    resume: bool = False                   # continue from the checkpoint in ``checkpoint``
    params: SapgaParams = field(default_factory=SapgaParams)


@dataclass
class TrainResult:
    """What a run returns: the best policy (with meta), the log, the counters."""

    policy: object
    history: list[dict]
    stats: dict


Progress = Callable[[dict], None]


def _pack(individuals: list[Individual], prefix: str) -> dict[str, np.ndarray]:
    """Population arrays for a checkpoint."""
    dim = individuals[0].policy.problem.dim if individuals else 0
    used = [m.used if m.used is not None else np.zeros(len(m.policy), np.bool_)
            for m in individuals]
    return {
        f'{prefix}_states': np.concatenate([m.policy.states for m in individuals]).reshape(
            -1, dim),
        f'{prefix}_actions': np.concatenate([m.policy.actions for m in individuals]),
        f'{prefix}_exemplar_values': np.concatenate([m.policy.values for m in individuals]),
        f'{prefix}_states2': np.concatenate([m.policy.states2 for m in individuals]),
        f'{prefix}_lengths': np.array([len(m.policy) for m in individuals], dtype=np.int64),
        f'{prefix}_values': np.array([m.value for m in individuals]),
        f'{prefix}_delta_star': np.array([m.delta_star for m in individuals]),
        f'{prefix}_steps': np.array([m.steps for m in individuals], dtype=np.int64),
        f'{prefix}_reached': np.array([m.reached for m in individuals], dtype=np.bool_),
        f'{prefix}_has_used': np.array([m.used is not None for m in individuals]),
        f'{prefix}_used': np.concatenate(used),
    }


def _unpack(problem: Problem, arrays: dict, prefix: str,
            style: str = 'state-action') -> list[Individual]:
    try:
        values = arrays.get(f'{prefix}_exemplar_values')
        states2 = arrays.get(f'{prefix}_states2')
        lengths = arrays[f'{prefix}_lengths']
        states, actions = arrays[f'{prefix}_states'], arrays[f'{prefix}_actions']
        if np.any(lengths < 1) or lengths.sum() != len(actions) or len(states) != len(actions):
            raise ValueError('exemplar counts do not add up')
        if not np.all(np.isfinite(states)) or np.any(actions < 0) or \
                np.any(actions >= len(problem.actions)):
            raise ValueError('non-finite states or action indices out of range')
        bounds = np.concatenate([[0], np.cumsum(lengths)])
        out = []
        for k in range(len(lengths)):
            a, b = bounds[k], bounds[k + 1]
            policy = ExemplarPolicy(
                problem, arrays[f'{prefix}_states'][a:b], arrays[f'{prefix}_actions'][a:b],
                style=style, values=None if values is None else values[a:b],
                states2=None if states2 is None or not states2.shape[1] else states2[a:b])
            used = arrays[f'{prefix}_used'][a:b].copy() if arrays[f'{prefix}_has_used'][k] \
                else None
            out.append(Individual(policy, float(arrays[f'{prefix}_values'][k]),
                                  float(arrays[f'{prefix}_delta_star'][k]),
                                  int(arrays[f'{prefix}_steps'][k]),
                                  bool(arrays[f'{prefix}_reached'][k]), used))
        return out
    except (KeyError, IndexError, ValueError, SapgaError) as exc:
        raise CheckpointError(f'checkpoint population {prefix!r} is inconsistent ({exc})') \
            from exc


def _run_settings(config: TrainConfig, problem: Problem, delta: float) -> dict:
    return {'problem': problem.name, 'method': config.method, 'delta': delta,
            'seed': config.seed, 'params': asdict(config.params)}


def _save(config: TrainConfig, ga: SapGA, delta: float, history: list[dict]) -> None:
    arrays = _pack(ga.population, 'pop')
    if ga.best is not None:
        arrays.update(_pack([ga.best], 'best'))
    meta = {'run': _run_settings(config, ga.problem, delta), 'stats': asdict(ga.stats),
            'rng': ga.rng.bit_generator.state, 'history': history}
    save_checkpoint(config.checkpoint, meta, arrays)


def _restore(config: TrainConfig, problem: Problem, delta: float) -> tuple[SapGA, list[dict]]:
    meta, arrays = load_checkpoint(config.checkpoint)
    want = json_roundtrip(_run_settings(config, problem, delta))
    if meta.get('run') != want:
        raise CheckpointError(f'{config.checkpoint}: checkpoint is of another run '
                              f'({meta.get("run")}), not {want}')
    rng = np.random.default_rng()
    try:
        rng.bit_generator.state = meta['rng']
        stats = Stats(**meta['stats'])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f'{config.checkpoint}: malformed run state ({exc})') from exc
    population = _unpack(problem, arrays, 'pop', config.params.style)
    if len(population) != config.params.n_pop:
        raise CheckpointError(f'{config.checkpoint}: population of {len(population)}, '
                              f'expected {config.params.n_pop}')
    ga = SapGA(problem, config.params, rng, population, stats)
    if 'best_lengths' in arrays:
        ga.best = _unpack(problem, arrays, 'best', config.params.style)[0]
    return ga, list(meta.get('history', []))


def json_roundtrip(obj):
    """``obj`` as it reads back from JSON (tuples become lists)."""
    import json
    return json.loads(json.dumps(obj))


def train_sapga(config: TrainConfig, initial: list[ExemplarPolicy] = (),
                progress: Progress | None = None,
                on_best: Callable[[ExemplarPolicy], None] | None = None,
                should_stop: Callable[[], bool] | None = None) -> TrainResult:
    """Run SAP-GA as configured; return the best policy and the log.

    ``progress(row)`` is called after each generation, ``on_best(policy)`` whenever the best
    value improves (the policy carries its meta), and the run ends early, with its best so
    far, once ``should_stop()`` is true.
    """
    problem = load_problem(config.problem)
    delta = float(problem.default_delta if config.delta is None else config.delta)
    jobs = set_jobs(config.jobs)
    evaluator = Evaluator(problem, delta)
    if config.resume:
        if not config.checkpoint:
            raise CheckpointError('--resume needs --checkpoint DIR')
        ga, history = _restore(config, problem, delta)
    else:
        ga, history = SapGA.create(problem, config.params, config.seed, initial), []
    start = time.perf_counter()
    steps_at_start = ga.stats.steps
    while not ga.stop(config.steps) and not (should_stop and should_stop()):
        batch = ga.ask()
        best_before = ga.best
        ga.tell(evaluator.evaluate(batch))
        if on_best and ga.best is not best_before:
            on_best(_best_policy(config, ga, delta, jobs))
        st = ga.stats
        elapsed = time.perf_counter() - start
        row = {'generation': st.generation, 'steps': st.steps, 'best_value': st.best_value,
               'delta_star': st.delta_star, 'achieved': st.delta_star <= delta,
               'evaluations': st.evaluations, 'repairs': st.repairs,
               'steps_per_s': (st.steps - steps_at_start) / max(elapsed, 1e-9)}
        history.append(row)
        if progress:
            progress(row)
        if config.checkpoint and st.generation % config.checkpoint_every == 0:
            _save(config, ga, delta, history)
    if config.checkpoint:
        _save(config, ga, delta, history)
    return TrainResult(_best_policy(config, ga, delta, jobs), history, asdict(ga.stats))


def _best_policy(config: TrainConfig, ga: SapGA, delta: float, jobs: int) -> ExemplarPolicy:
    """The best policy so far, with its provenance in ``meta``."""
    best = ga.best
    meta = {
        'value': best.value, 'delta_star': best.delta_star, 'steps_to_end': best.steps,
        'reached': best.reached, 'run_delta_star': ga.stats.delta_star, 'delta': delta,
        'seed': config.seed, 'steps': ga.stats.steps, 'generations': ga.stats.generation,
        'method': 'sapga', 'trainer': asdict(config.params), 'jobs': jobs,
        'software': f'sapga_ros {__version__}',
        'time': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
    }
    policy = best.policy.subset(slice(None))
    policy.meta = meta
    return policy


def write_log(path: Path, history: list[dict]) -> None:
    """Write a run's log rows (one per progress report) as CSV."""
    if not history:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w', newline='', encoding='utf-8') as f:
        writer = csv.DictWriter(f, fieldnames=list(history[0]))
        writer.writeheader()
        writer.writerows(history)
