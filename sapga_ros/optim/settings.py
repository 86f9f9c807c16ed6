"""Config fields that describe themselves (cleanrl's habit: a dataclass field per setting).

A field made with ``setting(default, help, ...)`` carries its one-line help, its
``sapga train`` option, its bounds or choices; from these the CLI options
(``sapga_ros.cli.args.add_settings``) and the trainer node's parameters
(``sapga_ros.nodes.trainer_params``) are both generated, so each default is written once,
in the dataclass.  ``check`` refuses a value outside its bounds, naming the field.
"""
from __future__ import annotations

import math
from dataclasses import Field, dataclass, field, fields
from typing import Any, Callable

from sapga_ros.errors import ConfigError

MAX_INT = 10 ** 15    # the largest integer setting: fits a ROS int64, bounds a typo's harm


@dataclass(frozen=True)
class Setting:
    """How one config field is offered: help text, CLI flag, bounds, choices."""

    help: str                              # one line: --help and the parameter descriptor
    flag: str = ''                         # ``sapga train`` option; '': --<name-with-dashes>
    low: float | None = None               # inclusive bounds of a number
    high: float | None = None              # None: MAX_INT for an integer, inf for a float
    choices: tuple[str, ...] = ()          # the values a string may take
    cli: bool = True                       # offered by ``sapga train``

    def option(self, name: str) -> str:
        return self.flag or '--' + name.replace('_', '-')

    def bounds(self, kind: type) -> tuple[float, float]:
        """(low, high) of a number; an integer's at most +-MAX_INT."""
        top = MAX_INT if kind is int else math.inf
        return (-top if self.low is None else self.low, top if self.high is None else self.high)

    def expected(self, kind: type) -> str:
        """What a valid value is, in words ('a positive integer', 'one of a, b')."""
        if self.choices:
            return f'one of {", ".join(self.choices)}'
        if kind is bool or kind is str:
            return 'true or false' if kind is bool else 'a string'
        low, high = self.bounds(kind)
        if kind is float:
            return f'a number in [{low:g}, {high:g}]'
        if high < MAX_INT:
            return f'an integer in [{int(low)}, {int(high)}]'
        return 'a positive integer' if low == 1 else f'an integer >= {int(low)}'

    def problem(self, value: Any, kind: type) -> str | None:
        """Why ``value`` does not fit, or None."""
        if self.choices:
            ok = value in self.choices
        elif kind is bool or kind is str:
            ok = isinstance(value, kind)
        elif isinstance(value, bool) or \
                not isinstance(value, int if kind is int else (int, float)):
            ok = False
        else:
            low, high = self.bounds(kind)
            ok = math.isfinite(value) and low <= value <= high
        return None if ok else f'expected {self.expected(kind)}, got {value!r}'


def setting(default: Any, help: str, **how: Any) -> Any:
    """A dataclass field with a default and a ``Setting`` (keywords: flag, low, high,
    choices, cli)."""
    return field(default=default, metadata={'setting': Setting(help, **how)})


def described(cls: type) -> list[tuple[Field, Setting]]:
    """The fields of dataclass ``cls`` that are settings, in declaration order."""
    return [(f, f.metadata['setting']) for f in fields(cls) if 'setting' in f.metadata]


def kind_of(f: Field) -> type:
    """The value type of a setting: that of its default (bool before int)."""
    return type(f.default)


def check(config: Any) -> None:
    """ConfigError naming the first setting of ``config`` that is out of bounds."""
    for f, s in described(type(config)):
        reason = s.problem(getattr(config, f.name), kind_of(f))
        if reason:
            raise ConfigError(f'{f.name}: {reason}')


def build(cls: type, value: Callable[[str], Any], **others: Any) -> Any:
    """``cls`` with each setting read by ``value(name)`` and the other fields given."""
    return cls(**{f.name: value(f.name) for f, _ in described(cls)}, **others)
