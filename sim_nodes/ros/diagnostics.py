"""``/diagnostics`` of a node: one ``diagnostic_msgs/DiagnosticStatus`` a second, as
``diagnostic_updater`` publishes them (``rqt_runtime_monitor``, Foxglove and
``ros2 topic echo /diagnostics`` read it).

``NodeDiagnostics(node, what, report)`` publishes one status named ``<node>: <what>`` (the
node's full name), ``hardware_id`` the problem, every ``DIAGNOSTICS_PERIOD_S`` and on
``publish()``; ``report()`` gives ``(level, message, values)``: ``OK``, ``WARN`` or ``ERROR``,
one line, and the key values (numbers, strings, booleans as ``true``/``false``).
"""
from __future__ import annotations

from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from sim_nodes.ros.common import QUIET_PUBLISHER, steady_clock

DIAGNOSTICS_PERIOD_S = 1.0
OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR
Report = tuple[bytes, str, dict[str, Any]]


def key_values(values: dict[str, Any]) -> list[KeyValue]:
    """Diagnostic key values: booleans as true/false, floats by repr, the rest by str."""
    return [KeyValue(key=k, value=str(v).lower() if isinstance(v, bool)
                     else repr(v) if isinstance(v, float) else str(v))
            for k, v in values.items()]


class NodeDiagnostics:
    """Publishes a node's status on /diagnostics (see the module docstring)."""

    def __init__(self, node: Node, what: str, hardware_id: str,
                 report: Callable[[], Report]) -> None:
        self._node = node
        self._report = report
        self._msg = DiagnosticArray()
        self._status = DiagnosticStatus(hardware_id=hardware_id)
        self._status.name = f'{node.get_fully_qualified_name().lstrip("/")}: {what}'
        self._msg.status = [self._status]
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10,
                                          event_callbacks=QUIET_PUBLISHER)
        self._timer = node.create_timer(DIAGNOSTICS_PERIOD_S, self.publish,
                                        clock=steady_clock())

    def publish(self) -> None:
        """Publish the node's status now."""
        level, message, values = self._report()
        self._status.level = level
        self._status.message = message
        self._status.values = key_values(values)
        self._msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(self._msg)
