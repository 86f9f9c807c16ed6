"""The trainer node's parameters, generated from the config dataclasses (SPEC 4).

Every ``setting`` field (``sapga_ros.optim.settings``) of ``TrainConfig``, ``SapgaParams``,
``QlParams``, ``CmaesParams`` and ``NodeSettings`` is a parameter of the same name, default
and description, with its bounds as the descriptor's ``integer_range`` /
``floating_point_range`` (rclpy refuses values outside them) and its choices in
``additional_constraints``.  Written here are only the node's forms of three run fields:
``problem`` (read-only), ``delta`` (any number; < 0 or NaN: the problem's default) and
``checkpoint`` ('': ``<out without suffix>.ckpt`` beside ``out``; none without ``out``).  A
change applies to the next run."""
from __future__ import annotations

import math
from dataclasses import Field, dataclass
from pathlib import Path
from typing import Any, Callable

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from sapga_ros.errors import ConfigError
from sapga_ros.optim.cmaes import CmaesParams
from sapga_ros.optim.qlearner import QlParams
from sapga_ros.optim.sapga import SapgaParams
from sapga_ros.optim.settings import Setting, build, described, kind_of, setting
from sapga_ros.training.loop import TrainConfig


@dataclass(frozen=True)
class NodeSettings:
    """The trainer node's own parameters (beside the run's)."""

    out: str = setting('', 'best policy file to write (its .log.csv beside it); empty: none')
    train_on_start: bool = setting(False, 'start a run when the node starts')
    policy_file: str = setting('', 'policy served on get_policy until training has a best; '
                               'empty: none')
    diagnostics_period: float = setting(1.0, '[s] between /diagnostics messages', low=1e-3,
                                        high=3600.0)
    log_period: float = setting(5.0, '[s] between progress lines in the log', low=1e-3,
                                high=3600.0)


PROBLEM = ('acrobot', 'msg_configs/<problem>.yaml (read-only)')
OTHERS: dict[str, tuple[Any, str]] = {
    'delta': (-1.0, 'goal difficulty; < 0 or NaN: the problem\'s default'),
    'checkpoint': ('', 'checkpoint directory; empty: <out without suffix>.ckpt beside out '
                   '(none without out)'),
}
SETTINGS: dict[str, tuple[Field, Setting]] = {
    f.name: (f, s) for cls in (TrainConfig, SapgaParams, QlParams, CmaesParams, NodeSettings)
    for f, s in described(cls)}


def descriptor(f: Field, s: Setting) -> ParameterDescriptor:
    """The parameter descriptor of a setting: description, range or choices."""
    kind = kind_of(f)
    d = ParameterDescriptor(description=s.help)
    if s.choices:
        d.additional_constraints = f'one of: {", ".join(s.choices)}'
    elif kind is int:
        low, high = s.bounds(int)
        d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    elif kind is float and all(map(math.isfinite, s.bounds(float))):
        low, high = s.bounds(float)
        d.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    return d


def parameters() -> dict[str, tuple[Any, ParameterDescriptor]]:
    """Every parameter but ``problem``: name -> (default, descriptor)."""
    table = {name: (f.default, descriptor(f, s)) for name, (f, s) in SETTINGS.items()}
    for name, (default, text) in OTHERS.items():
        table[name] = (default, ParameterDescriptor(description=text,
                                                    dynamic_typing=name == 'delta'))
    return table


def check_setting(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None."""
    if name == 'delta':
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f'delta: expected a number, got {value!r}'
        if value == math.inf:
            return 'delta: expected a finite number (< 0 or NaN: the problem default)'
    if name in SETTINGS:
        f, s = SETTINGS[name]
        reason = s.problem(value, kind_of(f))
        return f'{name}: {reason}' if reason else None
    return None


def train_config(value: Callable[[str], Any], problem: str, delta: float) -> TrainConfig:
    """The run parameters ``value(name)`` describe (ConfigError if inconsistent, or if
    ``out`` or the checkpoint directory is not in an existing folder)."""
    out = value('out')
    checkpoint = value('checkpoint') or (str(Path(out).with_suffix('.ckpt')) if out else '')
    if value('resume') and not checkpoint:
        raise ConfigError('resume needs a checkpoint directory (parameter checkpoint, or out: '
                          'the checkpoint beside it)')
    for what, path in (('out', out), ('checkpoint', checkpoint)):
        if path and not Path(path).parent.is_dir():
            raise ConfigError(f'{what} {path}: {Path(path).parent} is not an existing folder')
    return build(TrainConfig, value, problem=problem, delta=delta,
                 checkpoint=checkpoint or None, params=build(SapgaParams, value),
                 ql=build(QlParams, value), cmaes=build(CmaesParams, value))
