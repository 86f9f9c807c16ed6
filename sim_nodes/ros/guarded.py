"""Callbacks that never end a node by accident, on either executor.

``GuardedNode`` (the simulator's and the policy node's base) wraps every timer,
subscription and service callback made with its ``create_*`` methods:

* an exception is logged as one line (``callback failed, going on: Type: message``) and the
  node goes on; a failing service answers its default response (``message`` says why, where
  the response has one) instead of none; once the context is shut down (Ctrl-C, SIGTERM: a
  publish then fails) nothing is logged;
* ``NodeExit`` (a callback that must stop the node) and ``KeyboardInterrupt`` (Ctrl-C while
  a callback runs) are raised as they are on rclpy's own executors; on the
  ``EventsExecutor`` they are handed to ``spin_guarded`` (``request_exit``), which raises
  them once the callback has returned (a node spun otherwise on it does not stop).

Without the guard an exception would reach the executor: the ``SingleThreadedExecutor``
raises it from ``spin_once`` (``spin_guarded`` logs it as one line), but rclpy's
``EventsExecutor`` first logs it as FATAL with its traceback.  The guard keeps every
callback's signature (rclpy tells message-only from message-info subscription callbacks by
it) and its kind: a coroutine callback stays a coroutine.

A coroutine service callback needs one more thing on the ``EventsExecutor``: it calls the
callback and hands its result, a coroutine, to the service's ``send_response`` with the
request's header, where the other executors await it first.  The service made here awaits
such a result in a task of the node's executor, then sends the response.
"""
from __future__ import annotations

import functools
import inspect
import weakref
from typing import Any, Callable

from rclpy.executors import Executor
from rclpy.node import Node

from sim_nodes.errors import SapgaError


class NodeExit(SapgaError):
    """Raised by a callback that must stop its node: one line on stderr, exit code 1."""


def one_line(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` of an exception on one line, at most ``limit`` characters."""
    text = ' '.join(str(exc).split())
    return f'{type(exc).__name__}: {text}'[:limit]


_EXITS: 'weakref.WeakKeyDictionary[Any, BaseException]' = weakref.WeakKeyDictionary()


def request_exit(node: Any, exc: BaseException) -> None:
    """Stop ``node``'s spin (``spin_guarded``) with ``exc`` once the running callback
    returns."""
    _EXITS[node] = exc


def on_events_executor(node: Any) -> bool:
    """Whether ``node`` is spun by the EventsExecutor (which is no rclpy ``Executor``)."""
    executor = node.executor
    return executor is not None and not isinstance(executor, Executor)


def take_exit(executor: Any) -> BaseException | None:
    """The exit a node of ``executor`` requested, if any (taken: asked once)."""
    if not _EXITS:
        return None
    for node in executor.get_nodes():
        exc = _EXITS.pop(node, None)
        if exc is not None:
            return exc
    return None


def log_failure(logger: Any, exc: BaseException) -> None:
    logger.error(f'callback failed, going on: {one_line(exc)}')


def guard(node: Any, callback: Callable[..., Any], fallback: Callable[..., Any] | None = None
          ) -> Callable[..., Any]:
    """``callback`` with its exceptions handled as the module says; ``fallback(*args, exc)``
    gives the result of a call that failed (default None)."""
    def failed(args: tuple, exc: BaseException) -> Any:
        if isinstance(exc, (NodeExit, KeyboardInterrupt)):
            if not on_events_executor(node):
                raise exc
            request_exit(node, exc)
        elif node.context.ok():
            log_failure(node.get_logger(), exc)
        return None if fallback is None else fallback(*args, exc)

    if inspect.iscoroutinefunction(callback):
        @functools.wraps(callback)
        async def guarded_async(*args: Any) -> Any:
            try:
                return await callback(*args)
            except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - see the module
                return failed(args, exc)
        return guarded_async

    @functools.wraps(callback)
    def guarded(*args: Any) -> Any:
        try:
            return callback(*args)
        except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - see the module
            return failed(args, exc)
    return guarded


def _failed_response(request: Any, response: Any, exc: BaseException) -> Any:
    if hasattr(response, 'message'):
        response.message = f'failed: {one_line(exc)}'
    return response


class GuardedNode(Node):
    """A node whose timer, subscription and service callbacks are guarded (module)."""

    def create_timer(self, timer_period_sec: float, callback: Callable[..., Any] | None,
                     *args: Any, **kwargs: Any) -> Any:
        if callback is not None:
            callback = guard(self, callback)
        return super().create_timer(timer_period_sec, callback, *args, **kwargs)

    def create_subscription(self, msg_type: Any, topic: str, callback: Callable[..., Any],
                            *args: Any, **kwargs: Any) -> Any:
        return super().create_subscription(msg_type, topic, guard(self, callback), *args,
                                           **kwargs)

    def create_service(self, srv_type: Any, srv_name: str, callback: Callable[..., Any],
                       *args: Any, **kwargs: Any) -> Any:
        service = super().create_service(srv_type, srv_name,
                                         guard(self, callback, _failed_response), *args,
                                         **kwargs)
        plain = service.send_response

        def send_response(response: Any, header: Any) -> None:
            if not inspect.iscoroutine(response):
                plain(response, header)
                return

            async def finish() -> None:
                plain(await response, header)
            self.executor.create_task(finish)
        service.send_response = send_response
        return service
