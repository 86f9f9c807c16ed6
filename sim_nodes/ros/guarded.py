"""Callbacks that never end a node by accident, on either executor.

``GuardedNode`` (the simulator's and the policy node's base) wraps every timer,
subscription and service callback made with its ``create_*`` methods:

* an exception is logged as one line (``callback failed, going on: Type: message``) and the
  node goes on; a failing service answers its default response (``message`` says why, where
  the response has one) instead of none;
* ``NodeExit`` (a callback that must stop the node) is handed to ``spin_guarded``
  (``request_exit``), which raises it once the callback has returned: one line, exit 1.

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

from rclpy.node import Node

from sim_nodes.errors import SapgaError


class NodeExit(SapgaError):
    """Raised by a callback that must stop its node: one line on stderr, exit code 1."""


def one_line(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` of an exception on one line, at most ``limit`` characters."""
    text = ' '.join(str(exc).split())
    return f'{type(exc).__name__}: {text}'[:limit]


_EXITS: 'weakref.WeakKeyDictionary[Any, NodeExit]' = weakref.WeakKeyDictionary()


def request_exit(node: Any, exc: NodeExit) -> None:
    """Stop ``node``'s spin with ``exc`` once the running callback returns."""
    _EXITS[node] = exc


def take_exit(executor: Any) -> NodeExit | None:
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
    def failed(args: tuple, exc: Exception) -> Any:
        if isinstance(exc, NodeExit):
            request_exit(node, exc)
        else:
            log_failure(node.get_logger(), exc)
        return None if fallback is None else fallback(*args, exc)

    if inspect.iscoroutinefunction(callback):
        @functools.wraps(callback)
        async def guarded_async(*args: Any) -> Any:
            try:
                return await callback(*args)
            except Exception as exc:  # noqa: BLE001 - see the module docstring
                return failed(args, exc)
        return guarded_async

    @functools.wraps(callback)
    def guarded(*args: Any) -> Any:
        try:
            return callback(*args)
        except Exception as exc:  # noqa: BLE001 - see the module docstring
            return failed(args, exc)
    return guarded


def _failed_response(request: Any, response: Any, exc: Exception) -> Any:
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
