"""Disturbance profiles: what a plant that is not the model adds to an episode.

A profile is a YAML file in ``msg_configs/disturbances/`` (or any path), problem-independent:

=================  ==========================================================================
key                meaning
=================  ==========================================================================
initial_spread     the initial state moved by U(-a, a) per coordinate (state units)
sensor_sigma       Gaussian noise of sigma per coordinate on what the selector sees
latency            whole MDP steps between selecting an action and the plant getting it;
                   the plant gets 0 before the first selected action arrives
gain               actuator gain error: every command x U(1 - gain, 1 + gain) per episode
mismatch           physics entries x U(1 - m, 1 + m) per episode, each drawn on its own;
                   keys are physics names or the groups ``masses`` (m, m0, m1, ...) and
                   ``lengths`` (l, l1, lc1, ...)
pushes             {count, size, on}: ``count`` impulses per episode at steps drawn uniformly,
                   each a velocity change U(-size, size) on one coordinate drawn from ``on``
                   (state names; default: every velocity coordinate)
=================  ==========================================================================

``initial_spread`` and ``sensor_sigma`` are a number (every coordinate) or a mapping from
state names.  Absent keys are no disturbance; an empty profile is ``none``.  ``pack`` turns a
profile into the array the compiled engine reads (``sim_nodes.draws``).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim_nodes.draws import GAIN, HEAD, LATENCY, MISMATCH, OFF, ON, PUSH_SIZE, PUSHES
from sim_nodes.errors import ConfigError
from sim_nodes.files import TooLarge, load_yaml, read_bounded

KEYS = ('name', 'description', 'initial_spread', 'sensor_sigma', 'latency', 'gain', 'mismatch',
        'pushes')
GROUPS = {'masses': re.compile(r'^m\d*$'), 'lengths': re.compile(r'^lc?\d*$')}
MAX_LATENCY = 1000
MAX_PUSHES = 1000
MAX_BYTES = 1 << 16


@dataclass(frozen=True)
class Disturbance:
    """One disturbance profile (sizes as in the module's table)."""

    name: str = 'none'
    initial_spread: Any = 0.0              # number or {state name: number}
    sensor_sigma: Any = 0.0
    latency: int = 0
    gain: float = 0.0
    mismatch: dict = field(default_factory=dict)
    pushes: int = 0
    push_size: float = 0.0
    push_on: tuple = ()                    # state names; (): the velocity coordinates
    source: str = ''

    @property
    def is_none(self) -> bool:
        """Nothing disturbed: the undisturbed engine runs."""
        return replace(self, name=NONE.name, source='') == NONE

    def scaled(self, factor: float) -> 'Disturbance':
        """Every size x ``factor`` (latency and push count rounded; for sweeps)."""
        def times(v: Any) -> Any:
            return {k: x * factor for k, x in v.items()} if isinstance(v, dict) else v * factor
        return replace(self, initial_spread=times(self.initial_spread),
                       sensor_sigma=times(self.sensor_sigma),
                       latency=int(round(self.latency * factor)), gain=self.gain * factor,
                       mismatch=times(self.mismatch), pushes=self.pushes,
                       push_size=self.push_size * factor)

    def pack(self, problem) -> np.ndarray:
        """The profile for ``problem`` as the engine reads it (``sim_nodes.draws``)."""
        if self.is_none:
            return OFF.copy()
        names = problem.state_names
        dim = len(names)
        from sim_nodes.models import model_module
        physics = ('dt', 'substeps') + tuple(model_module(problem.model).PARAMS)
        out = np.zeros(HEAD + 3 * dim + len(physics))
        out[ON] = 1.0
        out[LATENCY] = self.latency
        out[GAIN] = self.gain
        out[PUSHES] = self.pushes
        out[PUSH_SIZE] = self.push_size
        out[HEAD:HEAD + dim] = self._per_coordinate(self.initial_spread, names, 'initial_spread')
        out[HEAD + dim:HEAD + 2 * dim] = self._per_coordinate(self.sensor_sigma, names,
                                                              'sensor_sigma')
        on = self.push_on or tuple(c.name for c in problem.state if c.field == 'velocity')
        for n in on:
            if n not in names:
                raise ConfigError(f'{self.where}: pushes.on: {n!r} is no state coordinate of '
                                  f'{problem.name} ({", ".join(names)})')
            out[HEAD + 2 * dim + names.index(n)] = 1.0
        if self.pushes and not on:
            raise ConfigError(f'{self.where}: pushes: {problem.name} has no velocity coordinate '
                              '(name one in pushes.on)')
        for key, size in self.mismatch.items():
            hits = [i for i, n in enumerate(physics) if i >= 2 and
                    (n == key or key in GROUPS and GROUPS[key].match(n))]
            if not hits and key not in GROUPS:
                raise ConfigError(f'{self.where}: mismatch: {key!r} is no physics entry of '
                                  f'{problem.name} nor a group ({", ".join(GROUPS)})')
            out[HEAD + 3 * dim + np.array(hits, dtype=np.int64)] = size
        out[MISMATCH] = float(np.any(out[HEAD + 3 * dim:] > 0))
        return out

    @property
    def where(self) -> str:
        return self.source or f'disturbance {self.name}'

    def _per_coordinate(self, value: Any, names: tuple, key: str) -> np.ndarray:
        if not isinstance(value, dict):
            return np.full(len(names), float(value))
        unknown = [k for k in value if k not in names]
        if unknown:
            raise ConfigError(f'{self.where}: {key}: {unknown[0]!r} is no state coordinate '
                              f'({", ".join(names)})')
        return np.array([float(value.get(n, 0.0)) for n in names])


NONE = Disturbance()


def _size(value: Any, where: str, high: float = 1e6) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not 0 <= value <= high:
        raise ConfigError(f'{where}: expected a number in [0, {high:g}], got {value!r:.40}')
    return float(value)


def _count(value: Any, where: str, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= high:
        raise ConfigError(f'{where}: expected an integer in [0, {high}], got {value!r:.40}')
    return value


def _sizes(value: Any, where: str) -> Any:
    if isinstance(value, dict):
        return {str(k): _size(v, f'{where}.{k}') for k, v in value.items()}
    return _size(value, where)


def parse_disturbance(doc: Any, source: str) -> Disturbance:
    """A profile from its parsed YAML document (ConfigError naming file and field)."""
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError(f'{source}: expected a mapping of {", ".join(KEYS)}')
    unknown = [k for k in doc if k not in KEYS]
    if unknown:
        raise ConfigError(f'{source}: unknown key {str(unknown[0])[:40]!r} (known: '
                          f'{", ".join(KEYS)})')
    pushes = doc.get('pushes') or {}
    if not isinstance(pushes, dict) or any(k not in ('count', 'size', 'on') for k in pushes):
        raise ConfigError(f'{source}: pushes: expected a mapping of count, size, on')
    on = pushes.get('on', [])
    if not isinstance(on, list) or not all(isinstance(n, str) for n in on):
        raise ConfigError(f'{source}: pushes.on: expected a list of state names')
    mismatch = doc.get('mismatch') or {}
    if not isinstance(mismatch, dict):
        raise ConfigError(f'{source}: mismatch: expected a mapping of physics names or groups '
                          f'({", ".join(GROUPS)}) to sizes')
    return Disturbance(
        name=str(doc.get('name', Path(source).stem)),
        initial_spread=_sizes(doc.get('initial_spread', 0.0), f'{source}: initial_spread'),
        sensor_sigma=_sizes(doc.get('sensor_sigma', 0.0), f'{source}: sensor_sigma'),
        latency=_count(doc.get('latency', 0), f'{source}: latency', MAX_LATENCY),
        gain=_size(doc.get('gain', 0.0), f'{source}: gain', 1.0),
        mismatch={str(k): _size(v, f'{source}: mismatch.{k}', 1.0) for k, v in mismatch.items()},
        pushes=_count(pushes.get('count', 0), f'{source}: pushes.count', MAX_PUSHES),
        push_size=_size(pushes.get('size', 0.0), f'{source}: pushes.size'),
        push_on=tuple(on), source=source)


def disturbance_dir() -> Path:
    from sim_nodes.problem import config_dir
    return config_dir() / 'disturbances'


def disturbance_names() -> list[str]:
    return sorted(p.stem for p in disturbance_dir().glob('*.yaml'))


def load_disturbance(name: str) -> Disturbance:
    """Profile ``name`` (msg_configs/disturbances/<name>.yaml) or a YAML file path."""
    path = Path(name) if name.endswith(('.yaml', '.yml')) else disturbance_dir() / f'{name}.yaml'
    if not path.is_file() and not name.endswith(('.yaml', '.yml')):
        raise ConfigError(f'unknown disturbance {name[:40]!r} (known: '
                          f'{", ".join(disturbance_names())}, or a .yaml file)')
    try:
        text = read_bounded(path, MAX_BYTES).decode('utf-8')
        doc = load_yaml(text)
    except TooLarge:
        raise ConfigError(f'{path}: larger than the {MAX_BYTES} bytes limit') from None
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read ({exc.strerror or exc})') from exc
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f'{path}: malformed YAML ({str(exc).splitlines()[0]})') from exc
    return parse_disturbance(doc, str(path))


class Plant:
    """One disturbed episode at a time, step by step, for a simulator that steps the model
    itself (the ROS simulator node): the same draws and the same order of operations as the
    episode engine (``sapga_ros.evaluation.engine.run_share``), so a simulator using it
    produces the engine's episode.  Per step: ``seen = observe(s)`` goes to the policy, its
    action goes through ``command``, then ``push(s)``, then the model's ``mdp_step`` with
    ``params``; ``advance()`` after the step."""

    def __init__(self, problem, disturbance: Disturbance, n_step: int | None = None) -> None:
        from sim_nodes.draws import LATENCY
        self.problem = problem
        self.dist = disturbance.pack(problem)
        self.n_step = problem.n_step if n_step is None else n_step
        self.nominal = problem.params()
        self.params = self.nominal.copy()
        latency = int(self.dist[LATENCY]) if self.dist[ON] else 0
        self.history = np.zeros(latency + 1)
        count = int(self.dist[PUSHES]) if self.dist[ON] else 0
        self.push_at = np.zeros(count, dtype=np.int64)
        self.push_dv = np.zeros(count)
        self.push_on = np.zeros(count, dtype=np.int64)
        self.key, self.gain, self.step = 0, 1.0, 0

    @property
    def on(self) -> bool:
        return bool(self.dist[ON])

    def reset(self, key: tuple) -> np.ndarray:
        """Start the episode of draw key (seed, generation, policy, episode); its initial
        state."""
        from sim_nodes.draws import episode_key, start_episode
        s = self.problem.initial_state.copy()
        self.params = self.nominal.copy()
        self.step = 0
        self.history[:] = 0.0
        if self.on:
            # as a numpy word: a Python int above 2^63 would not fit the kernels' int64
            self.key = np.uint64(episode_key(*(int(k) for k in key)))
            self.gain = start_episode(self.dist, self.key, self.problem.initial_state,
                                      self.nominal, self.problem.is_angle, self.n_step, s,
                                      self.params, self.push_at, self.push_dv, self.push_on)
        return s

    def observe(self, s: np.ndarray) -> np.ndarray:
        """What the policy sees of the state ``s`` at this step."""
        if not self.on:
            return s.copy()
        from sim_nodes.draws import observe
        o = np.empty_like(s)
        observe(self.dist, self.key, self.step, s, self.problem.is_angle, o)
        return o

    def command(self, action: float) -> float:
        """What the actuator applies at this step, given the action just selected."""
        if not self.on:
            return float(action)
        from sim_nodes.draws import command
        return command(self.history, self.step, float(action), self.gain)

    def push(self, s: np.ndarray) -> None:
        """This step's pushes on the state ``s`` (in place), before the model step."""
        if self.on:
            from sim_nodes.draws import push
            push(self.step, self.push_at, self.push_dv, self.push_on, s)

    def advance(self) -> None:
        self.step += 1
