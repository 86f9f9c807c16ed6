"""Node parameters from one table: declarations with ranges, checks and the --help text.

A node lists its parameters once, as ``Param`` rows (name, default, one-line description,
bounds or choices, read-only).  From that one table:

* ``declare(node, table)`` declares each with a ``ParameterDescriptor``: ``description``,
  ``read_only``, the bounds as ``integer_range`` / ``floating_point_range`` (rclpy refuses a
  value outside them, at start and on every change; ``ros2 param describe`` shows them) and
  the choices as ``additional_constraints``.  A value of the wrong type or out of range at
  start is a ``ConfigError`` naming the parameter, the value and what it takes;
* ``Param.problem(value)``: why a value is not acceptable (the set-parameters callbacks);
* ``usage_lines(rows)``: the parameter table of an executable's ``--help`` (``runner.py``),
  from ``(name, default, descriptor)`` rows, the form ``Param.row()`` gives (and the
  trainer's ``trainer_params.parameters()``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterException)
from rclpy.node import Node
from rclpy.parameter import Parameter

from sim_nodes.errors import ConfigError

Row = tuple[str, Any, ParameterDescriptor]      # name, default, descriptor
TYPE_NAMES = {bool: 'boolean', int: 'integer', float: 'double', str: 'string',
              list: 'string array'}
PARAMETER_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                   float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
                   list: ParameterType.PARAMETER_STRING_ARRAY}
TYPE_IDS = {PARAMETER_TYPES[k]: name for k, name in TYPE_NAMES.items()}


@dataclass(frozen=True)
class Param:
    """One node parameter: its default's type is the parameter's (``[]``: string array)."""

    name: str
    default: Any
    help: str
    low: float | None = None        # bounds, inclusive (numbers only)
    high: float | None = None
    choices: tuple[str, ...] = ()   # the accepted strings
    read_only: bool = False
    shown: str = ''                 # the default as --help shows it, when not a constant

    @property
    def kind(self) -> type:
        return type(self.default)

    def descriptor(self) -> ParameterDescriptor:
        """The ROS descriptor: description, read_only, range or choices."""
        d = ParameterDescriptor(description=self.help, read_only=self.read_only,
                                type=PARAMETER_TYPES[self.kind])
        if self.choices:
            d.additional_constraints = f'one of: {", ".join(self.choices)}'
        elif self.kind is int and self.low is not None:
            d.integer_range = [IntegerRange(from_value=int(self.low), to_value=int(self.high),
                                            step=1)]
        elif self.kind is float and self.low is not None:
            d.floating_point_range = [FloatingPointRange(
                from_value=float(self.low), to_value=float(self.high), step=0.0)]
        return d

    def row(self) -> Row:
        """``(name, default, descriptor)``; ``shown`` stands for a non-constant default."""
        return self.name, (self.shown or self.default), self.descriptor()

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is not acceptable, or None."""
        if self.choices and value not in self.choices:
            return f'{self.name}: expected one of {", ".join(self.choices)}, got {value!r}'
        if self.low is not None and self.kind in (int, float) and not (
                isinstance(value, (int, float)) and self.low <= value <= self.high):
            return (f'{self.name}: expected a number in [{self.low:g}, {self.high:g}], '
                    f'got {value!r}')
        return None


def _given(node: Node, name: str, exc: Exception) -> str:
    """The value the start-up overrides gave ``name`` (rclpy keeps them on the node)."""
    override = getattr(node, '_parameter_overrides', {}).get(name)
    return repr(override.value) if override is not None else str(exc)


def declare(node: Node, table: Iterable[Param]) -> dict[str, Any]:
    """Declare ``table``'s parameters on ``node``; their values by name.

    ``ConfigError`` naming the parameter for a value of the wrong type, out of range or not
    one of the choices.
    """
    values: dict[str, Any] = {}
    for p in table:
        default = Parameter.Type.STRING_ARRAY if p.default == [] else p.default
        try:
            values[p.name] = node.declare_parameter(p.name, default, p.descriptor()).value
        except InvalidParameterTypeException as exc:
            given = _given(node, p.name, exc)
            hint = f' (write {given}.0)' if p.kind is float and given.lstrip('-').isdigit() else ''
            raise ConfigError(f'{node.get_name()}: parameter {p.name}: expected '
                              f'{TYPE_NAMES[p.kind]}, got {given}{hint}') from None
        except InvalidParameterValueException as exc:
            raise ConfigError(f'{node.get_name()}: parameter {p.name}: '
                              f'{_given(node, p.name, exc)} is not in {range_text(p.descriptor())}'
                              ) from None
        except ParameterException as exc:
            raise ConfigError(f'{node.get_name()}: parameter {p.name}: {exc}') from None
        reason = p.problem(values[p.name]) if values[p.name] is not None else None
        if reason:
            raise ConfigError(f'{node.get_name()}: parameter {reason}')
    return values


def check(table: Iterable[Param], name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name`` of ``table``, or None."""
    p = next((p for p in table if p.name == name), None)
    return p.problem(value) if p is not None else None


# --help ---------------------------------------------------------------------------------------

def _number(x: float) -> str:
    """A bound as people write it: 0.001, 3600, 1e9."""
    if not math.isfinite(x) or not float(x).is_integer():
        return f'{x:g}'
    digits = str(abs(int(x)))
    if len(digits) > 6 and digits.strip('0') == '1':        # a power of ten: 1e9
        return f'{"-" if x < 0 else ""}1e{len(digits) - 1}'
    return str(int(x))


def range_text(d: ParameterDescriptor) -> str:
    """'[low, high]', the choices, or ''."""
    if d.integer_range:
        r = d.integer_range[0]
        return f'[{_number(r.from_value)}, {_number(r.to_value)}]'
    if d.floating_point_range:
        r = d.floating_point_range[0]
        return f'[{_number(r.from_value)}, {_number(r.to_value)}]'
    return d.additional_constraints.removeprefix('one of: ')


def _type_text(default: Any, d: ParameterDescriptor) -> str:
    if d.dynamic_typing:
        return 'number'
    if d.type in TYPE_IDS:
        return TYPE_IDS[d.type]
    if default == [] or default is Parameter.Type.STRING_ARRAY:
        return 'string array'
    return TYPE_NAMES.get(type(default), type(default).__name__)


def _default_text(default: Any) -> str:
    if isinstance(default, bool):
        return str(default).lower()
    if isinstance(default, float) and math.isfinite(default):
        return repr(default)
    if default == '':
        return "''"
    if default == []:
        return '[]'
    return str(default)


def usage_lines(rows: Sequence[Row]) -> list[str]:
    """The parameter table: name, type, default, range / choices, description."""
    table = [('name', 'type', 'default', 'range / choices', 'description')]
    for name, default, d in rows:
        text = d.description
        if d.read_only and 'read-only' not in text:
            text += ' (read-only)'
        table.append((name, _type_text(default, d), _default_text(default), range_text(d), text))
    widths = [max(len(r[k]) for r in table) for k in range(4)]
    return ['  ' + '  '.join(cell.ljust(w) for cell, w in zip(r[:4], widths)) + '  ' + r[4]
            for r in table]
