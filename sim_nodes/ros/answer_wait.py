"""Realtime start: the first state re-published until a command answers it.

A realtime simulator steps on its own, so a state published before the policy node hears it
goes unanswered.  Only an answer proves that the policy node's subscription and publisher are
both matched (the simulator sees its own side of each match only), so ``AnswerWait``
re-publishes the first state every ``POLL_S`` until ``answered()`` says a command answered
it, then calls ``on_answer`` (the simulator makes its step timer then).  Past ``timeout`` it
stops the node with one line (``NodeExit``: exit 1) saying what the graph shows: no node that
subscribes to the states and publishes ``command_stamped``, or such a node that stays silent.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from rclpy.node import Node

from sim_nodes.ros.common import NodeExit, steady_clock

POLL_S = 0.1     # [s] between re-publishes of the first state


def _nodes(endpoints: list) -> set[str]:
    return {f'{e.node_namespace.rstrip("/")}/{e.node_name}' for e in endpoints}


def policy_on_graph(node: Node, state_topic: str, command_topic: str) -> str:
    """What the graph shows of a policy node for ``state_topic`` / ``command_topic``."""
    policies = (_nodes(node.get_subscriptions_info_by_topic(state_topic))
                & _nodes(node.get_publishers_info_by_topic(command_topic)))
    if not policies:
        return f'no node subscribes to {state_topic} and publishes {command_topic}'
    return f'{", ".join(sorted(policies))} on the graph but silent'


class AnswerWait:
    """Re-publishes the first state until it is answered (see the module docstring)."""

    def __init__(self, node: Node, answered: Callable[[], bool], republish: Callable[[], None],
                 on_answer: Callable[[], None], topics: tuple[str, str],
                 timeout: float) -> None:
        self._node = node
        self._answered = answered
        self._republish = republish
        self._on_answer = on_answer
        self._topics = topics
        self._timeout = timeout
        self._since = time.monotonic()
        self._timer: Any = node.create_timer(POLL_S, self._poll, clock=steady_clock())
        node.get_logger().info('waiting for a command answering the first state')

    @property
    def waiting(self) -> bool:
        return self._timer is not None

    def _poll(self) -> None:
        if self._timer is None:
            return
        if self._answered():
            self._stop()
            self._node.get_logger().info('the first state is answered: the run starts')
            self._on_answer()
        elif time.monotonic() - self._since > self._timeout:
            self._stop()
            raise NodeExit(f'{self._node.get_name()}: no command answered the first state '
                           f'within {self._timeout:g} s '
                           f'({policy_on_graph(self._node, *self._topics)}); start a policy '
                           'node in this domain and namespace, or set wait_for_policy:=false')
        else:
            self._republish()           # for a policy node matched since

    def _stop(self) -> None:
        self._node.destroy_timer(self._timer)
        self._timer = None
