"""Hold a recorded run until the recorder hears every recorded topic (nothing lost).

A node publishing what a recorder records (the simulator) starts its run only once the
recorder's ``<recorder>/ready`` service (``std_srvs/Trigger``) answers success: every topic it
records is matched to each of its publishers, with QoS that deliver (durability included).
Publishing before that would lose the first messages to a volatile recorder subscription
still being matched.  ``RecorderGate`` declares two parameters on its node:

- ``wait_for_recorder`` (string, default ''): the recorder node's name ('' = do not wait);
- ``recorder_timeout`` (double, default 60 s): past it the node stops with a one-line error
  naming what the recorder still lacks (``NodeExit``: exit code 1).
"""
from __future__ import annotations

import time
from typing import Any, Callable

from rclpy.node import Node
from std_srvs.srv import Trigger

from sim_nodes.ros.common import NodeExit, steady_clock
from sim_nodes.params import Param
from sim_nodes.ros.params import declare

POLL_S = 0.1                # [s] between readiness questions
DEFAULT_TIMEOUT_S = 60.0
READY_SERVICE = 'ready'     # relative to the recorder node: <recorder>/ready


def gate_parameters() -> list[Param]:
    """The two parameters the gate declares on its node."""
    return [Param('wait_for_recorder', '', 'recorder node to wait for before the run starts '
                  "('' = none)", read_only=True),
            Param('recorder_timeout', DEFAULT_TIMEOUT_S, 'how long to wait for the recorder '
                  '(longer: the node stops, exit 1)', 1e-3, 86400.0, unit='s', read_only=True)]


class RecorderGate:
    """Calls ``on_ready`` once the named recorder is ready (at once if none is named)."""

    def __init__(self, node: Node, on_ready: Callable[[], None]) -> None:
        self._node = node
        self._on_ready = on_ready
        values = declare(node, gate_parameters())
        recorder, timeout = values['wait_for_recorder'], values['recorder_timeout']
        self.recorder = recorder
        self.open = not recorder
        self._last = 'no answer yet'
        self._future: Any = None
        if self.open:
            on_ready()
            return
        self._client = node.create_client(Trigger, f'{recorder.rstrip("/")}/{READY_SERVICE}')
        self._deadline = time.monotonic() + timeout
        self._timeout = timeout
        self._timer = node.create_timer(POLL_S, self._poll, clock=steady_clock())
        node.get_logger().info(f'waiting for recorder {recorder!r} before the run starts')

    def _poll(self) -> None:
        if self.open:
            return
        if self._future is not None and self._future.done():
            response, self._future = self._future.result(), None
            if response is not None and response.success:
                self._open(response.message)
                return
            self._last = response.message if response is not None else 'no response'
        if self._future is None and self._client.service_is_ready():
            self._future = self._client.call_async(Trigger.Request())
        if time.monotonic() > self._deadline:
            self._timer.cancel()
            raise NodeExit(f'{self._node.get_name()}: recorder {self.recorder!r} not ready '
                           f'after {self._timeout:g} s ({self._last[:200]}); is it running '
                           'in this domain and namespace?')

    def _open(self, message: str) -> None:
        self.open = True
        self._timer.cancel()
        self._node.destroy_timer(self._timer)
        self._node.destroy_client(self._client)
        self._node.get_logger().info(f'recorder ready ({message[:200]}): the run starts')
        self._on_ready()
