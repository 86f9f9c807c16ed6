"""Policies prepared off the executor thread, handed back to it to be swapped in.

Parsing and checking a policy document and packing it for the selector (``PreparedPolicy``)
takes about 0.13 s per MB (a 60 MB file: 8 s and more): done on the executor thread it
would leave the node deaf to states that long.  ``PolicyLoader.start`` does it in a worker
thread; the executor thread goes on answering states with the current policy, and when the
worker is done it hands the ``LoadResult`` to the executor thread (``Executor.create_task``:
thread-safe, and the one way to wake the EventsExecutor, which has no guard conditions), where
the node swaps it in (one reference assignment) or reports why it was refused.  Only the newest
request counts: a load that ends after a newer one was asked for is dropped (``supersede``
stands for a request handled elsewhere, e.g. a small file loaded at once).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from typing import Any, Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.client import Client
from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import Trigger

from sapga_ros.errors import SapgaError
from sapga_ros.evaluation.state_selector import StateSelector
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.ros.common import one_line, steady_clock
from sim_nodes.ros.guarded import guard

POLL_S = 0.02  # [s] how often a pending fetch checks for the service and its deadline


@dataclass(frozen=True)
class PreparedPolicy:
    """A validated policy in the selector's layout; never modified once made."""

    policy: ExemplarPolicy
    selector: Any            # a StateSelector (its scratch changes) or a PlanningSelector
    source: str             # where it came from (file path or service name)

    @classmethod
    def of(cls, policy: ExemplarPolicy, source: str,
           make: Callable[[ExemplarPolicy], Any] = StateSelector) -> PreparedPolicy:
        """``policy`` with its selector made by ``make`` (the policy node's: a
        ``StateSelector``, or with ``replan`` a ``PlanningSelector``)."""
        return cls(policy, make(policy), source)

    def __len__(self) -> int:
        return len(self.policy)


@dataclass(frozen=True)
class LoadResult:
    """What a worker made of one request: the policy, or why there is none."""

    number: int
    source: str
    prepared: PreparedPolicy | None
    error: str | None
    current: bool = True    # no newer request came while it loaded


class PolicyLoader:
    """Loads and prepares policies in worker threads; results come back on the executor."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._logger = node.get_logger()
        self._lock = threading.Lock()
        self._latest = 0                    # number of the newest request
        self._done: list[tuple[LoadResult, Callable[[LoadResult], None]]] = []
        self._closed = False
        self.loading: str | None = None     # source of the newest request in progress

    def supersede(self) -> None:
        """Drop the result of every request in progress (a newer policy was chosen)."""
        with self._lock:
            self._latest += 1
            self.loading = None

    def start(self, source: str, load: Callable[[], ExemplarPolicy],
              done: Callable[[LoadResult], None]) -> int:
        """Run ``load()`` and prepare its policy in a worker thread; ``done(result)`` is
        called on the executor thread (``result.current`` false if a newer request came
        meanwhile: it is not to be used).  The request's number."""
        with self._lock:
            self._latest += 1
            number = self._latest
            self.loading = source
        threading.Thread(target=self._work, args=(number, source, load, done), daemon=True,
                         name=f'policy-load-{number}').start()
        return number

    def _work(self, number: int, source: str, load: Callable[[], ExemplarPolicy],
              done: Callable[[LoadResult], None]) -> None:
        prepared = error = None
        try:
            prepared = PreparedPolicy.of(load(), source,
                                         getattr(self._node, 'make_selector', StateSelector))
        except SapgaError as exc:
            error = str(exc)
        except MemoryError:
            error = f'{source}: out of memory'
        except Exception as exc:  # noqa: BLE001 - a worker never dies silently
            error = f'{source}: {one_line(exc)}'
        with self._lock:
            self._done.append((LoadResult(number, source, prepared, error), done))
        executor = self._node.executor
        if executor is None:
            return          # on no executor: delivered with the next result that has one
        try:    # guarded as the node's callbacks are (a failure: one line, node goes on)
            executor.create_task(guard(self._node, self._deliver))
        except Exception:  # noqa: BLE001 - the executor was shut down meanwhile
            pass

    def _deliver(self) -> None:
        with self._lock:
            if self._closed:
                return
            results, self._done = self._done, []
            latest = self._latest
            if any(r.number == latest for r, _ in results):
                self.loading = None
        for result, done in results:
            if result.number != latest:
                self._logger.info(f'policy from {result.source} dropped: a newer one was '
                                  'chosen while it loaded')
                result = replace(result, prepared=None, current=False,
                                 error='a newer policy was chosen while this one loaded')
            done(result)

    def destroy(self, node: Node) -> None:
        """Results of workers still running are dropped."""
        self.supersede()
        with self._lock:
            self._closed = True


async def fetch_text(node: Node, client: Client, timeout: float, group: CallbackGroup
                     ) -> tuple[str, str | None]:
    """Call the trainer's Trigger ``client`` without blocking the executor: (text, error or
    None).  Its poll timer runs in ``group`` (reentrant, as the client's: the calling
    coroutine stays in progress while it waits)."""
    done = Future()
    deadline = time.monotonic() + timeout
    call: list[Future] = []

    def finish(result: tuple[str, str | None]) -> None:
        if not done.done():
            done.set_result(result)

    def answered(future: Future) -> None:
        try:
            reply = future.result()
        except Exception as exc:  # noqa: BLE001 - reported to the caller
            finish(('', f'{client.srv_name} failed: {exc}'))
            return
        if reply is None or not reply.success:
            why = reply.message[:300] if reply is not None else 'no response'
            finish(('', f'{client.srv_name} refused: {why}'))
        else:
            finish((reply.message, None))

    def poll() -> None:
        if done.done():
            return
        if not call and client.service_is_ready():
            call.append(client.call_async(Trigger.Request()))
            call[0].add_done_callback(answered)
        elif time.monotonic() >= deadline:
            if call:
                client.remove_pending_request(call[0])
            what = 'did not answer' if call else 'is not available'
            finish(('', f'trainer service {client.srv_name} {what} within '
                        f'{timeout} s'))

    timer = node.create_timer(POLL_S, poll, callback_group=group, clock=steady_clock())
    poll()
    try:
        return await done
    finally:
        node.destroy_timer(timer)
