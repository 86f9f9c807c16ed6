"""Experiment sets: msg_configs/experiments/<name>.yaml (the paper's Table 2; the styles
comparison), parsed and validated, and the one training run each (experiment, seed) is."""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import yaml

from sapga_ros.errors import ConfigError
from sapga_ros.exemplars.styles import STYLES
from sapga_ros.io.bounded import load_yaml, read_bounded
from sim_nodes.problem import config_dir, load_problem

MAX_SET_BYTES = 1 << 20
MAX_SEEDS = 10_000
MAX_STEPS = 10 ** 12
_NAME_RE = re.compile(r'^[a-z0-9][a-z0-9_-]*$')


@dataclass(frozen=True)
class Experiment:
    """One row of an experiment set: a method on a problem with a budget."""

    id: int
    problem: str
    delta: float
    method: str
    steps: int
    style: str = 'state-action'            # exemplar style of a SAP-GA experiment


def _count(value: Any, where: str, low: int, high: int) -> int:
    """An integer in [low, high] (YAML ints only; 3.0, .inf, strings are refused)."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(f'{where}: expected a whole number in [{low}, {high}], '
                          f'got {str(value)[:40]!r}')
    return value


def _experiment(e: Any, where: str) -> Experiment:
    if not isinstance(e, dict):
        raise ConfigError(f'{where}: expected a mapping')
    for key in ('id', 'problem', 'delta', 'method', 'steps'):
        if key not in e:
            raise ConfigError(f'{where}: missing {key!r}')
    delta = e['delta']
    if isinstance(delta, bool) or not isinstance(delta, (int, float)) or \
            not (math.isfinite(delta) and delta >= 0):
        raise ConfigError(f'{where}.delta: expected a finite number >= 0, '
                          f'got {str(delta)[:40]!r}')
    exp = Experiment(_count(e['id'], f'{where}.id', 0, MAX_SEEDS), str(e['problem'])[:80],
                     float(delta), str(e['method'])[:40],
                     _count(e['steps'], f'{where}.steps', 1, MAX_STEPS),
                     str(e.get('style', 'state-action'))[:40])
    load_problem(exp.problem)
    if exp.method not in ('sapga', 'ql'):
        raise ConfigError(f'{where}.method: expected sapga or ql, got {exp.method!r}')
    if exp.style not in STYLES:
        raise ConfigError(f'{where}.style: unknown style {exp.style!r} '
                          f'(known: {", ".join(STYLES)})')
    return exp


def load_experiments(name: str) -> tuple[list[Experiment], int]:
    """Experiments and seed count of msg_configs/experiments/<name>.yaml."""
    folder = config_dir() / 'experiments'
    known = sorted(p.stem for p in folder.glob('*.yaml'))
    if not isinstance(name, str) or not _NAME_RE.match(name) or name not in known:
        raise ConfigError(f'unknown experiment set {str(name)[:60]!r} '
                          f'(known: {", ".join(known)})')
    path = folder / f'{name}.yaml'
    try:
        doc = load_yaml(read_bounded(path, MAX_SET_BYTES))
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f'{path}: cannot read the experiment set ({exc})') from exc
    if not isinstance(doc, dict) or not isinstance(doc.get('experiments'), list) or \
            not doc['experiments']:
        raise ConfigError(f'{path}: expected a mapping with a non-empty experiments list')
    exps = [_experiment(e, f'{path}: experiments[{i}]')
            for i, e in enumerate(doc['experiments'])]
    if len({e.id for e in exps}) != len(exps):
        raise ConfigError(f'{path}: experiment ids repeat')
    return exps, _count(doc.get('seeds', 20), f'{path}: seeds', 1, MAX_SEEDS)


def run_one(exp: Experiment, seed: int, steps: int) -> dict:
    """Train one run of ``exp`` with ``seed`` on ``steps`` (one evaluation thread); its log
    and final measures."""
    from sapga_ros.optim.sapga import SapgaParams
    from sapga_ros.training.loop import TrainConfig, train_sapga
    from sapga_ros.training.ql_run import train_ql
    cfg = TrainConfig(problem=exp.problem, method=exp.method, delta=exp.delta, steps=steps,
                      seed=seed, jobs=1, params=SapgaParams(style=exp.style))
    result = train_sapga(cfg) if exp.method == 'sapga' else train_ql(cfg)
    hist = result.history
    return {'seed': seed, 'steps': [r['steps'] for r in hist],
            'best_value': [r['best_value'] for r in hist],
            'delta_star': [r['delta_star'] for r in hist],
            'final': {'best_value': hist[-1]['best_value'],
                      'delta_star': hist[-1]['delta_star'],
                      'achieved': hist[-1]['delta_star'] <= exp.delta,
                      'steps_per_s': hist[-1]['steps_per_s']}}
