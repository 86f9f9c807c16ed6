"""The ROS adapter of the parameter declarations (``sim_nodes/params.py``).

* ``descriptor(p)``: the ``ParameterDescriptor`` of a ``Param``: ``description`` (with its
  unit), ``read_only``, the type, the bounds as ``integer_range`` / ``floating_point_range``
  (rclpy refuses a value outside them; ``ros2 param describe`` shows them) and the choices
  as ``additional_constraints``;
* ``declare(node, table, problem)``: declares each row, a ``FromProblem`` default as the
  problem's value; an integer given for a double parameter (``-p delta:=0``, ``ros2 param
  set ... 0``) is taken as that double; a value refused at start is a ``ConfigError``
  ``<node>: <the one line of Param.reason>``, and a set refused later answers that line;
* ``check(table, name, value)``: the same line for a set-parameters callback, or None.
"""
from __future__ import annotations

from typing import Any, Iterable

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from sim_nodes.errors import ConfigError
from sim_nodes.params import Param
from sim_nodes.problem import Problem

__all__ = ['Param', 'check', 'declare', 'descriptor']

PARAMETER_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                   float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
                   list: ParameterType.PARAMETER_STRING_ARRAY}


def descriptor(p: Param) -> ParameterDescriptor:
    """The ROS descriptor: description, read_only, type, range or choices."""
    kind = (ParameterType.PARAMETER_DOUBLE_ARRAY if p.type is list and p.item is float
            else PARAMETER_TYPES[p.type])
    d = ParameterDescriptor(description=p.text, read_only=p.read_only, type=kind)
    if p.choices:
        d.additional_constraints = f'one of: {", ".join(p.choices)}'
    elif p.range_text():
        low, high = p.bounds()
        if p.type is int:
            d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                         to_value=float(high), step=0.0)]
    return d


def _as_doubles(table: dict[str, Param], params: list[Parameter]) -> list[Parameter]:
    """``params`` with an integer (array) given for a double (array) parameter made that
    double (array)."""
    def doubles(q: Parameter) -> Parameter:
        p = table.get(q.name)
        if p is not None and p.type is float and q.type_ == Parameter.Type.INTEGER:
            return Parameter(q.name, value=float(q.value))
        if (p is not None and p.type is list and p.item is float
                and q.type_ == Parameter.Type.INTEGER_ARRAY):
            return Parameter(q.name, value=[float(v) for v in q.value])
        return q
    return [doubles(q) for q in params]


def _adapt(node: Node, table: dict[str, Param]) -> None:
    """Integers for the double parameters of ``table``: in the start-up overrides, and in
    every later set (a pre-set callback, which runs before rclpy's type check).  A later set
    that rclpy refuses (its descriptor range check runs before any on-set callback, in its
    own words) answers the declaration's line instead, whenever the declaration refuses the
    value too."""
    overrides = getattr(node, '_parameter_overrides', {})
    for q in _as_doubles(table, list(overrides.values())):
        overrides[q.name] = q
    known = getattr(node, '_sapga_params', None)
    if known is None:
        node._sapga_params = known = {}
        node.add_pre_set_parameters_callback(lambda params: _as_doubles(known, params))
        rclpy_set = node._set_parameters_atomically

        def set_atomically(params: list[Parameter]) -> SetParametersResult:
            result = rclpy_set(params)
            if not result.successful:
                reasons = [known[q.name].reason(known[q.name].coerce(q.value)) for q in params
                           if q.name in known and q.type_ != Parameter.Type.NOT_SET]
                result.reason = next((r for r in reasons if r), result.reason)
            return result
        node._set_parameters_atomically = set_atomically
    known.update(table)


def _given(node: Node, name: str) -> Any:
    """The value the start-up overrides gave ``name`` (rclpy keeps them on the node)."""
    override = getattr(node, '_parameter_overrides', {}).get(name)
    return override.value if override is not None else None


def declare(node: Node, table: Iterable[Param], problem: Problem | None = None
            ) -> dict[str, Any]:
    """Declare ``table``'s parameters on ``node`` (a ``FromProblem`` default: ``problem``'s
    value); their values by name.  ``ConfigError`` with the one line of ``Param.reason``
    for a value of the wrong type, out of range or not one of the choices."""
    rows = list(table)
    _adapt(node, {p.name: p for p in rows})
    values: dict[str, Any] = {}
    for p in rows:
        default = problem.resolve(p.name) if p.from_problem else p.default
        if default == []:
            default = (Parameter.Type.DOUBLE_ARRAY if p.item is float
                       else Parameter.Type.STRING_ARRAY)
        try:
            values[p.name] = node.declare_parameter(p.name, default, descriptor(p)).value
        except ParameterException:
            reason = p.reason(_given(node, p.name))
            raise ConfigError(f'{node.get_name()}: {reason or p.name + ": refused"}') from None
        reason = p.reason(values[p.name]) if values[p.name] is not None else None
        if reason:
            raise ConfigError(f'{node.get_name()}: {reason}')
    return values


def check(table: Iterable[Param], name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name`` of ``table``, or None."""
    p = next((p for p in table if p.name == name), None)
    return p.reason(p.coerce(value)) if p is not None else None
