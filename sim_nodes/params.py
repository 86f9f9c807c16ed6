"""Parameters declared once: the one declaration type and its pure adapters.

A parameter is one ``Param`` -- name, type, default (or ``FromProblem``: the problem's
value), range or choices, unit, one-line help.  A config dataclass declares its fields with
``param(default, help, ...)`` (the name is the field's); a node lists ``Param`` rows.  From
the declaration come:

* ``Param.reason(value)``: the ONE line refusing a value, ``<name>: expected <what>, got
  <value>``, which the CLI, the ROS nodes and parameter YAML files all print;
* ``check(config)``: the validation of a config dataclass (its ``__post_init__`` calls it);
* ``check_mapping(table, mapping)``: the check of a parameter YAML file's mapping;
* ``usage_lines(table)``: the ``--help`` table of a node executable;
* the argparse options (``sapga_ros.cli.args``) and the ROS descriptors and declarations
  (``sim_nodes.ros.params``), each generated here-from.

Problem-dependent defaults: one convention everywhere.  A parameter whose default is the
problem's is declared with ``FromProblem(field)``; not giving it (no CLI option, no ``-p``
override, no YAML key) means the problem's value, ``Problem.resolve(name, given)``; every
value that is given is used as it is (0 is 0).  A config dataclass holds None for "not
given"; a node declares the problem's value itself, so ``ros2 param get`` shows what runs.

Numbers: an integer is accepted wherever a double is (``-p delta:=0``); a bool is never a
number.  Adding a parameter is one line: a ``param(...)`` field or a ``Param(...)`` row.
"""
from __future__ import annotations

import array
import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable, Iterable, Sequence

from sim_nodes.errors import ConfigError

MAX_INT = 10 ** 15    # the largest integer parameter: fits a ROS int64, bounds a typo's harm
MAX_EPISODES = 10_000  # disturbed episodes of one policy evaluation, at most
TYPE_NAMES = {bool: 'boolean', int: 'integer', float: 'double', str: 'string',
              list: 'string array'}


@dataclass(frozen=True)
class FromProblem:
    """A default that is the problem's value: ``field`` names it in the problem YAML."""

    field: str

    def __str__(self) -> str:
        return f"the problem's {self.field}"


@dataclass(frozen=True)
class Param:
    """One parameter (see the module docstring); ``kind`` is needed only when the default
    does not give the type (``FromProblem``)."""

    name: str
    default: Any
    help: str                              # one line: --help and the ROS description
    low: float | None = None               # inclusive bounds of a number
    high: float | None = None              # None: MAX_INT for an integer, inf for a double
    choices: tuple[str, ...] = ()          # the values a string may take
    unit: str = ''                         # 's', 'bytes', ...: shown as '[s]' before help
    kind: type | None = None               # bool, int, float, str or list
    read_only: bool = False
    flag: str = ''                         # the CLI option; '': --<name-with-dashes>
    item: type = str                       # a list's items: str, or float (a double array)
    cli: bool = True                       # offered on the command line

    @property
    def type(self) -> type:
        return self.kind or type(self.default)

    @property
    def from_problem(self) -> bool:
        return isinstance(self.default, FromProblem)

    @property
    def text(self) -> str:
        """The help with its unit: '[s] between saves'."""
        return f'[{self.unit}] {self.help}' if self.unit else self.help

    def option(self) -> str:
        return self.flag or '--' + self.name.replace('_', '-')

    def bounds(self) -> tuple[float, float]:
        """(low, high) of a number; an integer's at most +-MAX_INT."""
        top = MAX_INT if self.type is int else math.inf
        return (-top if self.low is None else self.low, top if self.high is None else self.high)

    def expected(self) -> str:
        """What a valid value is, in words ('a positive integer', 'one of a, b')."""
        kind = self.type
        if self.choices:
            return f'one of {", ".join(self.choices)}'
        if kind is list:
            return 'a list of numbers' if self.item is float else 'a list of strings'
        if kind in (bool, str):
            return {bool: 'true or false', str: 'a string'}[kind]
        low, high = self.bounds()
        if kind is float:
            return f'a number in [{number_text(low)}, {number_text(high)}]'
        if high < MAX_INT:
            return f'an integer in [{number_text(low)}, {number_text(high)}]'
        return 'a positive integer' if low == 1 else f'an integer >= {int(low)}'

    def coerce(self, value: Any) -> Any:
        """``value`` with an integer made a double for a double parameter."""
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        if self.type is list and self.item is float and _numbers(value):
            return [float(v) for v in value]
        return value

    def fits(self, value: Any) -> bool:
        kind = self.type
        if self.choices:
            return isinstance(value, str) and value in self.choices
        if kind is list and self.item is float:
            return _numbers(value) and all(math.isfinite(v) for v in value)
        if kind is list:
            return isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)
        if kind in (bool, str):
            return isinstance(value, kind)
        if isinstance(value, bool) or not isinstance(value, int if kind is int else (int, float)):
            return False
        low, high = self.bounds()
        return math.isfinite(value) and low <= value <= high

    def reason(self, value: Any) -> str | None:
        """The one line refusing ``value``, or None if it is acceptable."""
        if self.fits(value):
            return None
        return f'{self.name}: expected {self.expected()}, got {value_text(value)}'

    def shown_default(self) -> str:
        """The default as --help shows it."""
        d = self.default
        if isinstance(d, bool):
            return str(d).lower()
        if isinstance(d, float) and math.isfinite(d):
            return repr(d)
        if d == '':
            return "''"
        return str(d)

    def range_text(self) -> str:
        """'[low, high]', the choices, or ''."""
        if self.choices:
            return ', '.join(self.choices)
        if self.type in (int, float) and (self.low is not None or self.type is int):
            low, high = self.bounds()
            if self.type is float and not (math.isfinite(low) and math.isfinite(high)):
                return ''
            return f'[{number_text(low)}, {number_text(high)}]'
        return ''


DELTA = Param('delta', FromProblem('episode.delta'), 'goal difficulty: an episode ends in '
              'S_delta', low=0.0, high=1e9, kind=float)
N_STEP = Param('n_step', FromProblem('episode.n_step'), 'MDP steps per episode at most',
               low=1, high=10 ** 9, kind=int)


def _numbers(value: Any) -> bool:
    """A sequence of numbers (no bools): a double array's value."""
    return isinstance(value, (list, tuple, array.array)) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)


def number_text(x: float) -> str:
    """A number as people write it: 0.001, 3600, 1e9, 1e15."""
    if not math.isfinite(x) or not float(x).is_integer():
        return f'{x:g}'
    digits = str(abs(int(x)))
    if len(digits) > 6 and digits.strip('0') == '1':        # a power of ten: 1e9
        return f'{"-" if x < 0 else ""}1e{len(digits) - 1}'
    return str(int(x))


def value_text(value: Any) -> str:
    """A refused value as the line shows it: numbers plain, text quoted, at most 40 chars."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return repr(value)
    return repr(value)[:40]


# config dataclasses ---------------------------------------------------------------------------

def param(default: Any, help: str = '', **how: Any) -> Any:
    """A dataclass field declared as a parameter (keywords: those of ``Param``), or as the
    ``Param`` given (``param(DELTA)``).  A ``FromProblem`` default makes the field None
    until given."""
    p = default if isinstance(default, Param) else Param('', default, help, **how)
    value = None if p.from_problem else p.default
    return field(default=value, metadata={'param': p})


def declared(cls: type) -> list[Param]:
    """The parameters of dataclass ``cls``, named, in declaration order."""
    return [replace(f.metadata['param'], name=f.name) for f in fields(cls)
            if 'param' in f.metadata]


def reason_of(p: Param, value: Any) -> str | None:
    """Why ``value`` does not fit ``p``; None (not given) fits a problem's default."""
    return None if value is None and p.from_problem else p.reason(value)


def check(config: Any) -> None:
    """ConfigError with the one line of the first parameter of ``config`` that is refused."""
    for p in declared(type(config)):
        text = reason_of(p, getattr(config, p.name))
        if text:
            raise ConfigError(text)


def build(cls: type, value: Callable[[str], Any], **others: Any) -> Any:
    """``cls`` with each parameter read by ``value(name)`` and the other fields given."""
    return cls(**{p.name: value(p.name) for p in declared(cls)}, **others)


# tables: YAML files and --help ----------------------------------------------------------------

def check_mapping(table: Iterable[Param], mapping: dict, where: str) -> None:
    """ConfigError ``<where>: <one line>`` for an unknown key or a refused value."""
    by_name = {p.name: p for p in table}
    for name, value in mapping.items():
        p = by_name.get(name)
        if p is None:
            raise ConfigError(f'{where}: unknown parameter {str(name)[:40]!r} (known: '
                              f'{", ".join(sorted(by_name))})')
        text = reason_of(p, p.coerce(value))
        if text:
            raise ConfigError(f'{where}: {text}')


def usage_lines(table: Sequence[Param]) -> list[str]:
    """The parameter table: name, type, default, range / choices, description."""
    rows = [('name', 'type', 'default', 'range / choices', 'description')]
    for p in table:
        text = p.text + (' (read-only)' if p.read_only else '')
        kind = 'double array' if p.type is list and p.item is float else TYPE_NAMES[p.type]
        rows.append((p.name, kind, p.shown_default(), p.range_text(), text))
    widths = [max(len(r[k]) for r in rows) for k in range(4)]
    return ['  ' + '  '.join(cell.ljust(w) for cell, w in zip(r[:4], widths)) + '  ' + r[4]
            for r in rows]
