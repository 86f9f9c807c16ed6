"""Problem configuration: msg_configs/<name>.yaml parsed into a frozen ``Problem``.

One YAML file per problem is the single source of truth: state layout, ROS
interface, physical parameters, action set, bounds, goal area and episode settings.  YAML
is read with ``yaml.safe_load``; numbers may be written as multiples of pi ('3pi/2') and are
parsed by a regular expression, never evaluated.  The checks beyond parsing (the ``ros:``
section, size bounds, physics that must give numbers) are ``problem_checks.py``'s; this file
stays over 300 lines as the one parser of every section, read top to bottom.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sim_nodes.errors import ConfigError, UnknownProblemError
from sim_nodes.files import TooLarge, load_yaml, read_bounded
from sim_nodes.problem_checks import check_episode, check_physics, check_ros, check_sizes

CONFIG_ENV = 'SAPGA_CONFIG_DIR'
_FLOAT_RE = re.compile(r'^\s*[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?\s*$')
_PI_RE = re.compile(r'^\s*([+-]?)\s*(\d+(?:\.\d*)?|\.\d+)?\s*\*?\s*pi'
                    r'\s*(?:/\s*(\d+(?:\.\d*)?))?\s*$')
_NAME_RE = re.compile(r'^[a-z][a-z0-9_]*$')
MAX_CONFIG_BYTES = 1 << 20


def config_dir() -> Path:
    """Where problem YAML files live: $SAPGA_CONFIG_DIR, the source tree, or the install."""
    env = os.environ.get(CONFIG_ENV)
    if env:
        return Path(env)
    source = Path(__file__).resolve().parents[1] / 'msg_configs'
    if source.is_dir():
        return source
    import sys
    # this Python's prefix, then the ament prefixes that list sapga_ros in their resource
    # index (where ``ros2 pkg prefix`` looks; read as files: the environment imports no ROS)
    prefixes = [sys.prefix] + os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
    for prefix in filter(None, prefixes):
        installed = Path(prefix) / 'share' / 'sapga_ros' / 'msg_configs'
        index = Path(prefix, 'share', 'ament_index', 'resource_index', 'packages', 'sapga_ros')
        if installed.is_dir() and (prefix == sys.prefix or index.is_file()):
            return installed
    return source


def parse_number(value: Any, where: str) -> float:
    """A finite float from a YAML scalar: a number or a multiple of pi such as '-3pi/2'."""
    if isinstance(value, bool) or value is None:
        raise ConfigError(f'{where}: expected a number, got {value!r}')
    if isinstance(value, (int, float)):
        number = float(value)
    elif isinstance(value, str) and _FLOAT_RE.match(value):
        number = float(value)                      # YAML reads '1e-2' as a string
    elif isinstance(value, str):
        m = _PI_RE.match(value)
        if not m:
            raise ConfigError(f'{where}: expected a number or a multiple of pi, '
                              f'got {value[:40]!r}')
        sign, coef, denom = m.groups()
        if denom is not None and float(denom) == 0.0:
            raise ConfigError(f'{where}: zero denominator in {value!r}')
        number = (float(coef) if coef else 1.0) * math.pi / (float(denom) if denom else 1.0)
        number = -number if sign == '-' else number
    else:
        raise ConfigError(f'{where}: expected a number, got {type(value).__name__}')
    if not math.isfinite(number):
        raise ConfigError(f'{where}: not a finite number ({value!r})')
    return number


@dataclass(frozen=True)
class StateCoord:
    """One coordinate of the state vector."""

    name: str            # e.g. 'theta1'
    unit: str            # e.g. 'rad'
    angle: bool          # wrapped to [0, 2pi), compared on the circle
    range: float         # divisor of differences in the normalised distance
    low: float           # lower bound of random exemplar states and Q-learning tiles
    high: float          # upper bound
    joint: str           # JointState joint carrying it
    field: str           # 'position' or 'velocity'


@dataclass(frozen=True)
class Problem:
    """A problem as configured in msg_configs/<name>.yaml (see that file for units)."""

    name: str
    model: str
    description: str
    state: tuple[StateCoord, ...]
    initial: tuple[float, ...]
    best: tuple[float, ...]
    actions: tuple[float, ...]
    actuator_joint: str
    physics: dict[str, float]
    dt: float                                   # integration substep [s]
    substeps: int                               # substeps per MDP step
    n_step: int                                 # N_step
    default_delta: float
    goal_scale: tuple[float, ...]               # nan where the coordinate has a fixed bound
    goal_fixed: tuple[float, ...]               # inf where the coordinate is scaled by delta
    ql_state_indices: tuple[int, ...]
    ql_tiles_per_dim: int
    ql_epsilon: float
    ql_eta: float
    reward_range: tuple[float, float] | None = None  # one MDP step's reward [low, high]
    via_point_radius: float = 0.3               # normalised distance reaching a via-point
    goal_alt_scale: tuple[float, ...] | None = None  # another reading of goal.scale, measured
    ends_in_goal: bool = True                   # False: the hold task, all n_step steps run
    hold_bonus: float = 0.0                     # added to a step's reward when it ends in S_delta
    end_stop: str = 'stop'                      # 'fail': an end-stop contact ends the episode
    ros: dict[str, Any] = field(default_factory=dict, compare=False)
    source: str = ''

    def resolve(self, name: str, given: Any = None) -> Any:
        """The value of parameter ``name`` (``delta``, ``n_step``): ``given``, or the
        problem's if not given (None) -- the one place that rule is written."""
        default = {'delta': float(self.default_delta), 'n_step': int(self.n_step)}[name]
        return default if given is None else type(default)(given)

    @property
    def dim(self) -> int:
        """D, the state dimension."""
        return len(self.state)

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.state)

    @property
    def is_angle(self) -> np.ndarray:
        return np.array([c.angle for c in self.state], dtype=np.bool_)

    @property
    def ranges(self) -> np.ndarray:
        return np.array([c.range for c in self.state], dtype=np.float64)

    @property
    def low(self) -> np.ndarray:
        return np.array([c.low for c in self.state], dtype=np.float64)

    @property
    def high(self) -> np.ndarray:
        return np.array([c.high for c in self.state], dtype=np.float64)

    @property
    def initial_state(self) -> np.ndarray:
        return np.array(self.initial, dtype=np.float64)

    @property
    def best_state(self) -> np.ndarray:
        return np.array(self.best, dtype=np.float64)

    @property
    def action_values(self) -> np.ndarray:
        return np.array(self.actions, dtype=np.float64)

    @property
    def return_range(self) -> tuple[float, float]:
        """[low, high] of an episode's accumulated reward (1 to n_step steps)."""
        if self.reward_range is None:
            raise ConfigError(f'{self.source}: episode.reward_range is not set; the value '
                              'styles need it')
        low, high = self.reward_range
        return min(low, self.n_step * low), max(high, self.n_step * high)

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self.ros.get('joints', ()))

    @property
    def end_stop_penalty(self) -> float:
        """The reward added on an end-stop contact: the model's ``END_STOP_PENALTY``
        parameter (0: no end stop, or no ``reward_range`` to place it in)."""
        from sim_nodes.models import model_module
        name = getattr(model_module(self.model), 'END_STOP_PENALTY', None)
        penalty = self.physics.get(name, 0.0) if name else 0.0
        return penalty if penalty < 0.0 and self.reward_range is not None else 0.0

    @property
    def lowest_free_reward(self) -> float:
        """The lowest reward of a step that does not touch the end stop (-inf: no end stop):
        ``reward_range`` low is the lowest contact step, the penalty added, so the lowest
        contact-free step lies ``|penalty|`` above it."""
        penalty = self.end_stop_penalty
        return self.reward_range[0] - penalty if penalty < 0.0 else -math.inf

    @property
    def contact_below(self) -> float:
        """A step whose reward is below this touched the end stop (-inf: no end stop):
        halfway between the lowest contact-free reward and the lowest contact step."""
        penalty = self.end_stop_penalty
        return self.lowest_free_reward + penalty / 2.0 if penalty < 0.0 else -math.inf

    @property
    def fail_charge(self) -> float:
        """The reward charged for every step an episode did not run because it ended at an
        end-stop contact (``end_stop: fail``): an episode ending at the contact in step t of
        n_step gets ``(n_step - t) * fail_charge`` added to its return.  It is the lowest
        contact-free step reward, so an early end never scores above running the same
        trajectory on at the worst reward: without it every step's negative reward made
        an early end at the rail worth more than a full episode.  NaN: a contact does not
        end the episode (``end_stop: stop``)."""
        return self.lowest_free_reward if self.end_stop == 'fail' else math.nan

    def params(self) -> np.ndarray:
        """The model kernel's parameter vector (sim_nodes.models.<model>.pack_params)."""
        from sim_nodes.models import model_module
        return model_module(self.model).pack_params(self)


def _integer(value: Any, where: str, minimum: int) -> int:
    number = parse_number(value, where)
    if number != int(number) or number < minimum:
        raise ConfigError(f'{where}: expected an integer >= {minimum}, got {value!r}')
    return int(number)


def _mapping(doc: dict, key: str, where: str, optional: bool = False) -> dict:
    """doc[key] as a mapping ({} if optional and absent)."""
    if key not in doc and optional:
        return {}
    value = _require(doc, key, where)
    if value is None and optional:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f'{where}: {key}: expected a mapping')
    return value


def _require(doc: dict, key: str, where: str) -> Any:
    if key not in doc:
        raise ConfigError(f'{where}: missing field {key!r}')
    return doc[key]


def _numbers(values: Any, where: str, length: int | None = None) -> tuple[float, ...]:
    if not isinstance(values, list):
        raise ConfigError(f'{where}: expected a list of numbers')
    if length is not None and len(values) != length:
        raise ConfigError(f'{where}: expected {length} numbers, got {len(values)}')
    return tuple(parse_number(v, f'{where}[{i}]') for i, v in enumerate(values))


def _optional_numbers(values: Any, where: str, length: int, missing: float) -> tuple[float, ...]:
    if values is None:
        return (missing,) * length
    if not isinstance(values, list) or len(values) != length:
        raise ConfigError(f'{where}: expected a list of {length} numbers or nulls')
    return tuple(missing if v is None else parse_number(v, f'{where}[{i}]')
                 for i, v in enumerate(values))


def parse_problem(doc: Any, source: str) -> Problem:
    """Validate a parsed YAML document and build the ``Problem``."""
    if not isinstance(doc, dict):
        raise ConfigError(f'{source}: expected a mapping at the top level')
    name = _require(doc, 'name', source)
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ConfigError(f'{source}: name: expected a lower-case identifier, got {name!r}')
    state_doc = _require(doc, 'state', source)
    if not isinstance(state_doc, list) or not state_doc:
        raise ConfigError(f'{source}: state: expected a non-empty list of coordinates')
    coords = []
    for i, c in enumerate(state_doc):
        where = f'{source}: state[{i}]'
        if not isinstance(c, dict):
            raise ConfigError(f'{where}: expected a mapping')
        angle = c.get('angle', False)
        if not isinstance(angle, bool):
            raise ConfigError(f'{where}.angle: expected true or false, got {angle!r}')
        coord = StateCoord(
            name=str(_require(c, 'name', where)), unit=str(c.get('unit', '')), angle=angle,
            range=parse_number(_require(c, 'range', where), f'{where}.range'),
            low=parse_number(_require(c, 'low', where), f'{where}.low'),
            high=parse_number(_require(c, 'high', where), f'{where}.high'),
            joint=str(_require(c, 'joint', where)), field=str(_require(c, 'field', where)))
        if coord.range <= 0 or coord.high <= coord.low:
            raise ConfigError(f'{where}: needs range > 0 and high > low')
        if coord.field not in ('position', 'velocity'):
            raise ConfigError(f'{where}.field: expected position or velocity, got {coord.field!r}')
        coords.append(coord)
    dim = len(coords)
    actions = _numbers(_require(doc, 'actions', source), f'{source}: actions')
    if not actions or len(set(actions)) != len(actions):
        raise ConfigError(f'{source}: actions: expected distinct numbers')
    physics_doc = _mapping(doc, 'physics', source)
    physics = {str(k): parse_number(v, f'{source}: physics.{k}') for k, v in physics_doc.items()}
    episode = _mapping(doc, 'episode', source)
    goal = _mapping(doc, 'goal', source)
    ql = _mapping(doc, 'q_learning', source, optional=True)
    ros = _mapping(doc, 'ros', source, optional=True)
    styles = _mapping(doc, 'exemplars', source, optional=True)
    reward_range = None
    if episode.get('reward_range') is not None:
        reward_range = _numbers(episode['reward_range'], f'{source}: episode.reward_range', 2)
        if reward_range[0] > reward_range[1]:
            raise ConfigError(f'{source}: episode.reward_range: needs low <= high')
    actuator = _mapping(doc, 'actuator', source, optional=True)
    model = _require(doc, 'model', source)
    from sim_nodes.models import MODELS
    if model not in MODELS:
        raise ConfigError(f'{source}: model: unknown model {str(model)[:40]!r} '
                          f'(known: {", ".join(MODELS)})')
    goal_scale = _optional_numbers(goal.get('scale'), f'{source}: goal.scale', dim, math.nan)
    goal_fixed = _optional_numbers(goal.get('fixed'), f'{source}: goal.fixed', dim, math.inf)
    for i, (s, f) in enumerate(zip(goal_scale, goal_fixed)):
        if math.isnan(s) == math.isinf(f):
            raise ConfigError(f'{source}: goal: coordinate {i} needs exactly one of scale, fixed')
    alt_scale = None
    if goal.get('alternative_scale') is not None:
        alt_scale = _optional_numbers(goal['alternative_scale'],
                                      f'{source}: goal.alternative_scale', dim, math.nan)
        if any(math.isnan(a) != math.isnan(s) for a, s in zip(alt_scale, goal_scale)):
            raise ConfigError(f'{source}: goal.alternative_scale: null exactly where '
                              'goal.scale is null')
    substeps = _integer(_require(episode, 'substeps', f'{source}: episode'),
                        f'{source}: episode.substeps', 1)
    n_step = _integer(_require(episode, 'n_step', f'{source}: episode'),
                      f'{source}: episode.n_step', 1)
    raw_indices = ql.get('state_indices', list(range(dim)))
    if not isinstance(raw_indices, list) or not raw_indices:
        raise ConfigError(f'{source}: q_learning.state_indices: expected a list of indices')
    indices = tuple(_integer(i, f'{source}: q_learning.state_indices', 0) for i in raw_indices)
    if any(i >= dim for i in indices):
        raise ConfigError(f'{source}: q_learning.state_indices: out of range 0..{dim - 1}')
    tiles = _integer(ql.get('tiles_per_dim', 20), f'{source}: q_learning.tiles_per_dim', 1)
    check_sizes(source, dim, len(actions), substeps, n_step, tiles)
    check_episode(episode, source)
    check_ros(ros, source, [c.joint for c in coords]
              + ([str(actuator['joint'])] if 'joint' in actuator else []))
    problem = Problem(
        name=name, model=model,
        description=str(doc.get('description', '')), state=tuple(coords),
        initial=_numbers(_require(doc, 'initial', source), f'{source}: initial', dim),
        best=_numbers(_require(doc, 'best', source), f'{source}: best', dim),
        actions=actions, actuator_joint=str(actuator.get('joint', '')), physics=physics,
        dt=parse_number(_require(episode, 'dt', f'{source}: episode'), f'{source}: episode.dt'),
        substeps=substeps, n_step=n_step,
        default_delta=parse_number(episode.get('delta', 0.05), f'{source}: episode.delta'),
        goal_scale=goal_scale, goal_fixed=goal_fixed, ql_state_indices=indices,
        ql_tiles_per_dim=tiles,
        ql_epsilon=parse_number(ql.get('epsilon', 0.02), f'{source}: q_learning.epsilon'),
        ql_eta=parse_number(ql.get('eta', 0.02), f'{source}: q_learning.eta'),
        reward_range=reward_range, goal_alt_scale=alt_scale,
        via_point_radius=parse_number(styles.get('via_point_radius', 0.3),
                                      f'{source}: exemplars.via_point_radius'),
        ros=ros, source=source, **_hold_settings(episode, f'{source}: episode'))
    _check_hold(problem)
    if problem.dt <= 0 or problem.default_delta < 0:
        raise ConfigError(f'{source}: episode: needs dt > 0 and delta >= 0')
    if not problem.via_point_radius > 0:
        raise ConfigError(f'{source}: exemplars.via_point_radius: needs a number > 0')
    problem.params()  # the model checks its own physics parameters
    check_physics(problem)
    return problem


END_STOPS = ('stop', 'fail')


def _hold_settings(episode: dict, where: str) -> dict:
    """episode.ends_in_goal, episode.hold_bonus and episode.end_stop, checked."""
    ends = episode.get('ends_in_goal', True)
    if not isinstance(ends, bool):
        raise ConfigError(f'{where}.ends_in_goal: expected true or false, got {ends!r}')
    bonus = parse_number(episode.get('hold_bonus', 0.0), f'{where}.hold_bonus')
    if bonus < 0:
        raise ConfigError(f'{where}.hold_bonus: needs a number >= 0, got {bonus!r}')
    stop = episode.get('end_stop', 'stop')
    if stop not in END_STOPS:
        raise ConfigError(f'{where}.end_stop: expected one of {", ".join(END_STOPS)}, '
                          f'got {str(stop)[:40]!r}')
    return {'ends_in_goal': ends, 'hold_bonus': bonus, 'end_stop': stop}


def _check_hold(problem: Problem) -> None:
    if problem.hold_bonus and problem.ends_in_goal:
        raise ConfigError(f'{problem.source}: episode.hold_bonus: only for ends_in_goal: false '
                          '(an episode that ends in S_delta holds nothing)')
    if problem.end_stop == 'fail' and problem.contact_below == -math.inf:
        raise ConfigError(f'{problem.source}: episode.end_stop: fail needs a model with an end '
                          f'stop and its penalty (model {problem.model} has none)')


def load_problem_file(path: str | os.PathLike) -> Problem:
    """Parse one problem YAML file."""
    path = Path(path)
    try:
        text = read_bounded(path, MAX_CONFIG_BYTES).decode('utf-8')
    except TooLarge:
        raise ConfigError(f'{path}: larger than the {MAX_CONFIG_BYTES} bytes limit') from None
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read ({exc.strerror or exc})') from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f'{path}: not UTF-8 text') from exc
    try:
        doc = load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f'{path}: malformed YAML ({str(exc).splitlines()[0]})') from exc
    return parse_problem(doc, str(path))


def problem_names() -> list[str]:
    """Names of every configured problem."""
    return sorted(p.stem for p in config_dir().glob('*.yaml') if _NAME_RE.match(p.stem))


@lru_cache(maxsize=None)
def load_problem(name: str) -> Problem:
    """The configured problem called ``name``; UnknownProblemError lists the known ones."""
    if not isinstance(name, str) or not _NAME_RE.match(name) or name not in problem_names():
        known = ', '.join(problem_names())
        raise UnknownProblemError(f'unknown problem {str(name)[:40]!r} (known: {known})')
    problem = load_problem_file(config_dir() / f'{name}.yaml')
    if problem.name != name:
        raise ConfigError(f'{problem.source}: name {problem.name!r} does not match the file name')
    return problem
