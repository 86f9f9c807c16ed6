"""The trainer node's run status and its ``/diagnostics`` message.

``RunStatus`` is the one place the training thread and the executor share: a dict of the
values ``/diagnostics`` reports, read and written under a lock.  ``diagnostics`` turns a
snapshot into a ``diagnostic_msgs/DiagnosticArray`` with one status named
``<node>: training``: level ERROR when the run failed, OK otherwise; key values ``state``
(idle | training | stopped | done | failed), ``steps``, ``budget``, ``best_value``,
``delta_star``, ``delta``, ``achieved``, ``steps_per_s``, ``generation`` (SAP-GA),
``episodes`` (QL), ``method``, ``seed``, ``served``, ``out``, ``checkpoint``.
"""
from __future__ import annotations

import math
import threading
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

from sim_nodes.ros.diagnostics import key_values

STATES = ('idle', 'training', 'stopped', 'done', 'failed')


class RunStatus:
    """The status of the current or last run, safe to share between threads."""

    def __init__(self, delta: float, method: str, seed: int) -> None:
        self._lock = threading.Lock()
        self._values: dict[str, Any] = {
            'state': 'idle', 'message': 'idle', 'steps': 0, 'budget': 0,
            'best_value': -math.inf, 'delta_star': math.inf, 'delta': delta,
            'steps_per_s': 0.0, 'generation': 0, 'episodes': 0, 'method': method,
            'seed': seed, 'checkpoint': ''}

    def snapshot(self) -> dict[str, Any]:
        """A copy of the values."""
        with self._lock:
            return dict(self._values)

    def update(self, **values: Any) -> bool:
        """Set ``values``; True when the state changed."""
        with self._lock:
            changed = 'state' in values and values['state'] != self._values['state']
            self._values.update(values)
        return changed


def diagnostics(name: str, hardware_id: str, st: dict[str, Any], served: str, out: str
                ) -> DiagnosticArray:
    """The /diagnostics message of status snapshot ``st`` (stamp left to the caller)."""
    status = DiagnosticStatus()
    status.level = DiagnosticStatus.ERROR if st['state'] == 'failed' else DiagnosticStatus.OK
    status.name = f'{name}: training'
    status.hardware_id = hardware_id
    status.message = st['message']
    values = {
        'state': st['state'], 'steps': st['steps'], 'budget': st['budget'],
        'best_value': float(st['best_value']), 'delta_star': float(st['delta_star']),
        'delta': float(st['delta']), 'achieved': st['delta_star'] <= st['delta'],
        'steps_per_s': float(st['steps_per_s']), 'generation': st['generation'],
        'episodes': st['episodes'], 'method': st['method'], 'seed': st['seed'],
        'served': served or 'none', 'out': out, 'checkpoint': st['checkpoint'],
    }
    status.values = key_values(values)
    msg = DiagnosticArray()
    msg.status = [status]
    return msg
