"""The executor a node runs on, and subscription callbacks that work on either.

``events`` (the default for the simulator and the policy node): rclpy's
``rclpy.experimental.EventsExecutor``, which reacts to each ready entity instead of
rebuilding a wait set of every entity of the process for every callback; the lockstep loop
runs about three times as fast on it (``sapga bench --ros``).  ``single``: rclpy's
``SingleThreadedExecutor``.  A node's read-only ``executor`` parameter chooses
(``--ros-args -p executor:=single``).

Two things the EventsExecutor of Jazzy's rclpy does differently, handled here (the others,
its coroutine services, callback exceptions and signals: ``guarded.py``, ``runner.py``):

* a subscription callback that takes the message info is called with one argument, the
  pair (message, info), where the other executors pass two; ``with_info(fn)`` makes a
  callback ``fn(msg, info)`` that takes either call;
* it supports no guard conditions; a worker thread hands a result to the executor thread
  with ``Executor.create_task`` instead (thread-safe on both executors).
"""
from __future__ import annotations

import inspect
from typing import Any, Callable

from rclpy.executors import Executor, SingleThreadedExecutor

EXECUTORS = ('events', 'single')
DEFAULT_EXECUTOR = 'events'

_TWO = inspect.Signature([inspect.Parameter(name, inspect.Parameter.POSITIONAL_ONLY)
                          for name in ('msg', 'info')])


def make_executor(kind: str, context: Any = None) -> Executor:
    """A new executor of ``kind`` (``EXECUTORS``) on ``context`` (None: the default)."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    raise ValueError(f'executor {kind!r}: expected one of {", ".join(EXECUTORS)}')


def node_executor(node: Any) -> Executor:
    """The executor a node's ``executor`` parameter names, on the node's context."""
    return make_executor(node.get_parameter('executor').value, node.context)


def with_info(fn: Callable[[Any, Any], Any]) -> Callable[..., Any]:
    """A subscription callback that calls ``fn(msg, info)`` however the executor calls it:
    ``(msg, info)`` (``SingleThreadedExecutor``, ``MultiThreadedExecutor``) or
    ``((msg, info),)`` (``EventsExecutor``).  rclpy sees two parameters, so it takes the
    message info for it."""
    def call(*args: Any) -> Any:
        msg, info = args if len(args) == 2 else args[0]
        return fn(msg, info)
    call.__signature__ = _TWO     # type: ignore[attr-defined]
    call.__name__ = getattr(fn, '__name__', 'callback')
    return call
