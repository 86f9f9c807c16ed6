"""Experiment sets: msg_configs/experiments/<name>.yaml (the paper's Table 2; the styles
comparison), parsed and validated, and the one training run each (experiment, seed) is.
(Just over 300 lines: a row's fields are read here and turned into its run here, so a new
row setting is one place; the whole-set checks are ``experiment_checks.py``.)"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Any

import yaml

from sapga_ros.errors import ConfigError, UnknownProblemError
from sapga_ros.policies.controller_row import MAX_DELAY
from sapga_ros.policies.styles import STYLES
from sapga_ros.io.bounded import load_yaml, read_bounded
from sim_nodes.goal import alternative_goal
from sim_nodes.jit import compile_seconds
from sim_nodes.params import DELTA, MAX_EPISODES
from sim_nodes.problem import Problem, config_dir, load_problem

MAX_SET_BYTES = 1 << 20
METHODS = ('sapga', 'ql', 'cmaes', 'classical')
CATCHES = ('none', 'lqr')
CMAES_POP = 100        # CMA-ES candidates per generation in experiments (batches use the engine)
MAX_SEEDS = 10_000
MAX_STEPS = 10 ** 12
MAX_EXPERIMENTS = 1000
MAX_SCALE = 1000.0     # --scale (multiplier of every step budget) at most
_NAME_RE = re.compile(r'^[a-z0-9][a-z0-9_-]*$')
_WORD_RE = re.compile(r'[A-Za-z0-9][A-Za-z0-9_-]{0,39}')


@dataclass(frozen=True)
class Experiment:
    """One row of an experiment set: a method on a problem with a budget."""

    id: int
    problem: str
    delta: float
    method: str
    steps: int
    style: str = 'state-action'            # exemplar style of a SAP-GA experiment
    paper: str = ''                        # what the paper reports for this row
    group: str = 'paper'                   # paper | ablation | peer (report sections)
    variant: str = 'paper'                 # SAP-GA variant (optim/sapga.py VARIANTS)
    seeds: int | None = None               # this row's seed count (None: the set's)
    catch: str = 'none'                    # lqr: the hybrid (sapga train --catch lqr)
    disturbance: str = 'none'              # robust fitness (sapga train --disturbance)
    episodes: int = 1                      # disturbed episodes per evaluation
    robust_stat: str = 'mean'              # value over the episodes: mean or qNN
    redraw: bool = False                   # the episodes drawn anew each generation
    catch_delay: int = 0                   # MDP steps of delay the catch's LQR is designed for
    delay: int = 0                         # MDP steps of delay the exemplar selector predicts


def _count(value: Any, where: str, low: int, high: int) -> int:
    """An integer in [low, high] (YAML ints only; 3.0, .inf, strings are refused)."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(f'{where}: expected a whole number in [{low}, {high}], '
                          f'got {str(value)[:40]!r}')
    return value


_SET_KEYS = ('name', 'seeds', 'experiments', 'limits')
_EXPERIMENT_KEYS = ('id', 'problem', 'delta', 'method', 'steps', 'style', 'paper', 'group',
                    'variant', 'seeds', 'catch', 'disturbance', 'episodes', 'robust_stat',
                    'redraw', 'catch_delay', 'delay')
_LIMIT_KEYS = ('problem', 'alternative_goal', 'width', 'cells', 'per_cell')


def _known_keys(doc: dict, known: tuple[str, ...], where: str) -> None:
    """ConfigError for a key not in ``known`` (a misspelt setting is not ignored)."""
    unknown = [str(k)[:40] for k in doc if k not in known]
    if unknown:
        raise ConfigError(f'{where}: unknown key {unknown[0]!r} (known: {", ".join(known)})')


def _flag(e: dict, key: str, where: str) -> bool:
    """A true/false entry of a row (default false)."""
    value = e.get(key, False)
    if not isinstance(value, bool):
        raise ConfigError(f'{where}.{key}: expected true or false, got {str(value)[:40]!r}')
    return value


def _text(e: dict, key: str, where: str, default: str, max_len: int) -> str:
    value = e.get(key, default)
    if not isinstance(value, str) or len(value) > max_len:
        raise ConfigError(f'{where}.{key}: expected a text of at most {max_len} characters, '
                          f'got {str(value)[:40]!r}')
    return value


def _problem(name: str, where: str) -> Problem:
    """The problem a row names; an unknown name is refused naming the row."""
    try:
        return load_problem(name)
    except UnknownProblemError as exc:
        raise ConfigError(f'{where}.problem: {exc}') from None


def _robust(exp: Experiment, where: str) -> None:
    """Refuse a row's robust-fitness settings that cannot run, naming the row."""
    from sapga_ros.evaluation.robust import check_stat
    from sim_nodes.disturbance import load_disturbance
    try:
        load_disturbance(exp.disturbance)
        check_stat(exp.robust_stat)
    except ConfigError as exc:
        raise ConfigError(f'{where}: {exc}') from None
    robust = exp.disturbance != 'none' or exp.episodes > 1
    if robust and exp.method not in ('sapga', 'cmaes'):
        raise ConfigError(f'{where}: disturbance and episodes: SAP-GA and CMA-ES rows only')
    if exp.redraw and not (robust and exp.method == 'sapga'):
        raise ConfigError(f'{where}.redraw: episodes drawn anew each generation: SAP-GA rows '
                          'with a disturbance or episodes > 1 only')


def _experiment(e: Any, where: str) -> Experiment:
    if not isinstance(e, dict):
        raise ConfigError(f'{where}: expected a mapping')
    _known_keys(e, _EXPERIMENT_KEYS, where)
    for key in ('id', 'problem', 'delta', 'method', 'steps'):
        if key not in e:
            raise ConfigError(f'{where}: missing {key!r}')
    delta = e['delta']
    reason = DELTA.reason(DELTA.coerce(delta))
    if reason:
        raise ConfigError(f'{where}.{reason}')
    exp = Experiment(_count(e['id'], f'{where}.id', 0, MAX_SEEDS), str(e['problem'])[:80],
                     float(delta), str(e['method'])[:40],
                     _count(e['steps'], f'{where}.steps', 1, MAX_STEPS),
                     _text(e, 'style', where, 'state-action', 40),
                     _text(e, 'paper', where, '', 300), _text(e, 'group', where, 'paper', 40),
                     _text(e, 'variant', where, 'paper', 40),
                     None if e.get('seeds') is None else
                     _count(e['seeds'], f'{where}.seeds', 1, MAX_SEEDS),
                     _text(e, 'catch', where, 'none', 40),
                     _text(e, 'disturbance', where, 'none', 200),
                     _count(e.get('episodes', 1), f'{where}.episodes', 1, MAX_EPISODES),
                     _text(e, 'robust_stat', where, 'mean', 40),
                     _flag(e, 'redraw', where),
                     _count(e.get('catch_delay', 0), f'{where}.catch_delay', 0, MAX_DELAY),
                     _count(e.get('delay', 0), f'{where}.delay', 0, MAX_DELAY))
    if not _WORD_RE.fullmatch(exp.group):
        raise ConfigError(f'{where}.group: expected a word (letters, digits, _ and -), '
                          f'got {exp.group!r}')
    if exp.catch not in CATCHES or (exp.catch != 'none' and exp.method != 'sapga'):
        raise ConfigError(f'{where}.catch: expected one of {", ".join(CATCHES)} (lqr: SAP-GA '
                          f'rows only), got {exp.catch!r}')
    if exp.catch_delay and exp.catch != 'lqr':
        raise ConfigError(f'{where}.catch_delay: the delay of the LQR catch needs catch: lqr')
    if exp.delay and (exp.catch != 'none' or exp.method not in ('sapga', 'cmaes')):
        raise ConfigError(f'{where}.delay: the selector\'s delay is for exemplar rows without '
                          'a catch (sapga, cmaes; a hybrid: catch_delay)')
    _robust(exp, where)
    from sapga_ros.optim.sapga import VARIANTS
    if exp.variant not in VARIANTS:
        raise ConfigError(f'{where}.variant: unknown variant {exp.variant!r} '
                          f'(known: {", ".join(VARIANTS)})')
    _problem(exp.problem, where)
    if exp.method not in METHODS:
        raise ConfigError(f'{where}.method: expected one of {", ".join(METHODS)}, '
                          f'got {exp.method!r}')
    if exp.style not in STYLES:
        raise ConfigError(f'{where}.style: unknown style {exp.style!r} '
                          f'(known: {", ".join(STYLES)})')
    return exp


@dataclass(frozen=True)
class LimitSearch:
    """A physical-limit search to run with a set (``sapga_ros.analysis.limit``)."""

    problem: str
    alternative_goal: bool = False
    width: int = 50_000
    cells: int = 32
    per_cell: int = 4

    @property
    def file_name(self) -> str:
        return f'{self.problem}{"-alternative" if self.alternative_goal else ""}.json'


def load_limits(name: str) -> list[LimitSearch]:
    """The ``limits`` of experiment set ``name`` (none if it lists none)."""
    path = config_dir() / 'experiments' / f'{name}.yaml'
    doc = _set_document(name)
    out = []
    limits = doc.get('limits')
    if limits is not None and not isinstance(limits, list):
        raise ConfigError(f'{path}: limits: expected a list of searches, got '
                          f'{str(limits)[:40]!r}')
    for i, e in enumerate(limits or []):
        where = f'{path}: limits[{i}]'
        if not isinstance(e, dict) or not isinstance(e.get('problem'), str):
            raise ConfigError(f'{where}: expected a mapping with a problem')
        _known_keys(e, _LIMIT_KEYS, where)
        alt = e.get('alternative_goal', False)
        if not isinstance(alt, bool):
            raise ConfigError(f'{where}.alternative_goal: expected true or false, '
                              f'got {str(alt)[:40]!r}')
        search = LimitSearch(_text(e, 'problem', where, '', 80), alt,
                             _count(e.get('width', 50_000), f'{where}.width', 1, 10 ** 7),
                             _count(e.get('cells', 32), f'{where}.cells', 1, 1000),
                             _count(e.get('per_cell', 4), f'{where}.per_cell', 1, 1000))
        problem = _problem(search.problem, where)
        if search.alternative_goal and alternative_goal(problem) is None:
            raise ConfigError(f'{where}: {search.problem} has no alternative goal reading')
        out.append(search)
    return out


def _set_document(name: str) -> dict:
    """The parsed YAML of experiment set ``name`` (a known name, never a path)."""
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
    _known_keys(doc, _SET_KEYS, str(path))
    if len(doc['experiments']) > MAX_EXPERIMENTS:
        raise ConfigError(f'{path}: experiments: at most {MAX_EXPERIMENTS} rows')
    return doc


def load_experiments(name: str) -> tuple[list[Experiment], int]:
    """Experiments and seed count of msg_configs/experiments/<name>.yaml."""
    doc = _set_document(name)
    path = config_dir() / 'experiments' / f'{name}.yaml'
    exps = [_experiment(e, f'{path}: experiments[{i}]')
            for i, e in enumerate(doc['experiments'])]
    if len({e.id for e in exps}) != len(exps):
        raise ConfigError(f'{path}: experiment ids repeat')
    return exps, _count(doc.get('seeds', 20), f'{path}: seeds', 1, MAX_SEEDS)


def run_seeds(exp: Experiment, seeds: list[int], steps: int) -> list[dict]:
    """Train the runs of ``exp`` with ``seeds`` on ``steps`` each (one evaluation thread):
    each run's log, final measures and best policy (exemplar policies: the policy file's
    JSON document).  Q-learning runs of several seeds learn side by side
    (``training.loop.train_lanes``), each bit-identical to its run alone: their
    ``steps_per_s`` is the lanes' MDP steps per second together (the worker's rate) and
    their ``seconds`` a share of the wall time in proportion to their steps (time spent
    compiling kernels left out of both)."""
    from sapga_ros.optim.cmaes import CmaesParams
    from sapga_ros.optim.sapga import SapgaParams
    from sapga_ros.training.loop import TrainConfig, train, train_lanes
    start, compiled = time.perf_counter(), compile_seconds()
    if exp.method == 'classical':       # deterministic: the same controller every seed
        done = [_classical(exp) for _ in seeds]
    else:
        configs = [TrainConfig(problem=exp.problem, method=exp.method, delta=exp.delta,
                               steps=steps, seed=seed, jobs=1,
                               params=SapgaParams(style=exp.style, variant=exp.variant),
                               cmaes=CmaesParams(popsize=CMAES_POP), catch=exp.catch,
                               catch_delay=exp.catch_delay, delay=exp.delay,
                               disturbance=exp.disturbance, episodes=exp.episodes,
                               robust_stat=exp.robust_stat, redraw=exp.redraw)
                   for seed in seeds]
        if exp.method == 'ql' and len(configs) > 1:
            results = train_lanes(configs)
        else:
            results = [train(c) for c in configs]
        done = [(r.policy, r.history) for r in results]
    wall = max(time.perf_counter() - start - (compile_seconds() - compiled), 1e-9)
    total = sum(hist[-1]['steps'] for _, hist in done)
    return [_run(exp, seed, policy, hist, wall, total, len(seeds))
            for seed, (policy, hist) in zip(seeds, done)]


def _run(exp: Experiment, seed: int, policy: Any, hist: list[dict], wall: float, total: int,
         lanes: int) -> dict:
    """The record of one run trained with ``lanes - 1`` others in ``wall`` seconds, the
    runs together simulating ``total`` MDP steps."""
    last = hist[-1]
    final = {'best_value': last['best_value'], 'delta_star': last['delta_star'],
             'achieved': last['delta_star'] <= exp.delta, 'steps_per_s': total / wall}
    if last.get('delta_star_alt') is not None:
        final['delta_star_alt'] = last['delta_star_alt']
    run = {'seed': seed, 'steps': [r['steps'] for r in hist],
           'best_value': [r['best_value'] for r in hist],
           'delta_star': [r['delta_star'] for r in hist], 'final': final,
           'seconds': wall * last['steps'] / max(total, 1), 'lanes': lanes}
    final.update(returned_measures(policy, exp.delta, load_problem(exp.problem).ends_in_goal))
    if exp.method == 'ql':
        final['greedy_delta_star'] = policy.meta.get('delta_star')
        final['greedy_value'] = policy.meta.get('value')
    else:
        run['policy'] = policy.to_document()
    return run


def returned_measures(policy: Any, delta: float, ends_in_goal: bool = True) -> dict:
    """The returned policy's own episode at ``delta``: its value (``policy_value``), its
    delta* (``policy_delta_star``), whether it reaches S_delta (``policy_reached``) and its
    end-stop contacts (``policy_rail_contacts``); for the hold task also the hold measures.
    A run's ``best_value`` and ``delta_star`` are the bests over every episode the run
    evaluated, which need not be this policy's."""
    from sapga_ros.evaluation.evaluator import run_policy_episode
    from sapga_ros.training.loop import HOLD_KEYS
    own = run_policy_episode(policy, delta).summary()
    out = {'policy_value': own['return'], 'policy_delta_star': own['delta_star'],
           'policy_reached': bool(own['reached']), 'policy_rail_contacts': own['rail_contacts']}
    if not ends_in_goal:                               # the hold task's measures
        out.update({k: own[k] for k in HOLD_KEYS})
    return out


def _classical(exp: Experiment) -> tuple[Any, list[dict]]:
    """The classical controller of ``exp.problem`` and a one-row log (no search: 0 steps
    beyond its one evaluated episode)."""
    from sapga_ros.evaluation.evaluator import Evaluator
    from sapga_ros.evaluation.classical_design import classical_policy
    problem = load_problem(exp.problem)
    policy = classical_policy(problem)
    ep = Evaluator(problem, exp.delta).episode(policy)
    policy.meta.update(value=ep.ret, delta_star=ep.delta_star)
    return policy, [{'steps': ep.steps, 'best_value': ep.ret, 'delta_star': ep.delta_star}]
