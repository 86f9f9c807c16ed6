"""The two executors the simulator and the policy node run on (sim_nodes/ros/executors.py,
sim_nodes/ros/guarded.py), each over real DDS: message info reaches ``with_info``
callbacks, a coroutine service answers after a worker thread hands it its result through
``create_task``, and a callback's ``NodeExit`` ends ``spin_guarded`` without a traceback."""
from __future__ import annotations

import threading
import time

import pytest
from rclpy.task import Future
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from sim_nodes.ros.executors import EXECUTORS, make_executor, with_info
from sim_nodes.ros.guarded import GuardedNode, NodeExit
from sim_nodes.ros.runner import spin_guarded

WAIT_S = 30.0


@pytest.fixture
def context(ros_context):
    return ros_context


def spin_until(executor, condition, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        executor.spin_once(timeout_sec=0.05)


def call(executor, client) -> Trigger.Response:
    """Call ``client``'s Trigger service, spinning ``executor`` until it answers."""
    spin_until(executor, client.service_is_ready, 'the service')
    future = client.call_async(Trigger.Request())
    spin_until(executor, future.done, 'the answer')
    return future.result()


@pytest.mark.parametrize('kind', EXECUTORS)
def test_with_info_gets_each_message_and_its_sequence_number(context, kind):
    node = GuardedNode('info_node', context=context)
    got = []
    node.create_subscription(Float64, 'numbers', with_info(lambda m, i: got.append(
        (m.data, i['publication_sequence_number']))), 10)
    pub = node.create_publisher(Float64, 'numbers', 10)
    executor = make_executor(kind, context)
    executor.add_node(node)
    spin_until(executor, lambda: pub.get_subscription_count() == 1, 'discovery')
    for k in range(5):
        pub.publish(Float64(data=float(k)))
    spin_until(executor, lambda: len(got) == 5, 'five messages')
    assert got == [(float(k), k + 1) for k in range(5)]
    executor.shutdown()
    node.destroy_node()


@pytest.mark.parametrize('kind', EXECUTORS)
def test_a_coroutine_service_answers_with_a_worker_threads_result(context, kind):
    """The service awaits a Future that a worker thread completes on the executor thread
    (create_task, as the policy loader does): the client gets the worker's answer."""
    node = GuardedNode('async_node', context=context)
    executor = make_executor(kind, context)

    async def slow(request, response):
        done = Future()

        def work() -> None:
            time.sleep(0.05)
            executor.create_task(lambda: done.set_result('from the worker'))
        threading.Thread(target=work, daemon=True).start()
        response.message = await done
        response.success = True
        return response
    node.create_service(Trigger, 'slow', slow)
    client = node.create_client(Trigger, 'slow')
    executor.add_node(node)
    answer = call(executor, client)
    assert answer.success and answer.message == 'from the worker'
    executor.shutdown()
    node.destroy_node()


@pytest.mark.parametrize('kind', EXECUTORS)
def test_a_failing_service_answers_and_a_node_exit_ends_the_spin(context, kind, capfd):
    node = GuardedNode('exit_node', context=context)
    executor = make_executor(kind, context)

    def broken(request, response):
        raise ValueError('no\nway')
    node.create_service(Trigger, 'broken', broken)
    client = node.create_client(Trigger, 'broken')
    executor.add_node(node)
    answer = call(executor, client)
    assert not answer.success and answer.message == 'failed: ValueError: no way'
    ticks = []

    def stop() -> None:
        ticks.append(1)
        if len(ticks) >= 3:
            raise NodeExit('exit_node: enough')
    node.create_timer(0.01, stop)
    with pytest.raises(NodeExit, match='enough'):
        spin_guarded(executor, node.get_logger())
    assert len(ticks) >= 3
    err = capfd.readouterr().err
    assert 'callback failed, going on: ValueError: no way' in err
    assert 'Traceback' not in err and 'FATAL' not in err, err
    executor.shutdown()
    node.destroy_node()


@pytest.mark.parametrize('kind', EXECUTORS)
def test_ctrl_c_in_a_callback_ends_the_spin_quietly(context, kind, capfd):
    """A KeyboardInterrupt raised while a callback runs (Ctrl-C under load) ends
    spin_guarded with KeyboardInterrupt and no FATAL line or traceback."""
    node = GuardedNode('ctrl_c_node', context=context)
    executor = make_executor(kind, context)

    def interrupted() -> None:
        raise KeyboardInterrupt
    node.create_timer(0.01, interrupted)
    executor.add_node(node)
    with pytest.raises(KeyboardInterrupt):
        spin_guarded(executor, node.get_logger())
    err = capfd.readouterr().err
    assert 'Traceback' not in err and 'FATAL' not in err and 'failed' not in err, err
    executor.shutdown()
    node.destroy_node()


@pytest.mark.parametrize('kind', EXECUTORS)
def test_a_callback_failing_after_shutdown_is_not_logged(context, kind, capfd):
    """A publish that fails because Ctrl-C or SIGTERM shut the context down meanwhile is no
    error: nothing is logged and the spin ends."""
    node = GuardedNode('late_node', context=context)
    pub = node.create_publisher(Float64, 'late', 10)
    executor = make_executor(kind, context)

    def publish_after_shutdown() -> None:
        context.try_shutdown()
        pub.publish(Float64(data=1.0))
    node.create_timer(0.01, publish_after_shutdown)
    executor.add_node(node)
    spin_guarded(executor, node.get_logger())
    err = capfd.readouterr().err
    assert 'failed' not in err and 'FATAL' not in err and 'Traceback' not in err, err


class CountingWait:
    """An awaitable that yields until ``done``; ``polls`` counts how often it was resumed."""

    def __init__(self) -> None:
        self.done = False
        self.polls = 0

    def __await__(self):
        while not self.done:
            self.polls += 1
            yield


@pytest.mark.parametrize('kind', EXECUTORS)
def test_a_waiting_coroutine_is_not_polled_in_a_busy_loop(context, kind):
    """While a coroutine service waits, spin_guarded resumes it a few times per window, not
    continuously (a busy loop kept a core busy for as long as load_policy waited)."""
    server = GuardedNode('waiting_server', context=context)
    client_node = GuardedNode('waiting_client', context=context)
    waiting = CountingWait()

    async def wait_for_release(request, response):
        await waiting
        response.success = True
        return response
    server.create_service(Trigger, 'wait', wait_for_release)
    executor = make_executor(kind, context)
    executor.add_node(server)
    spinner = threading.Thread(target=spin_guarded, args=(executor, server.get_logger()),
                               daemon=True)
    spinner.start()
    client_executor = make_executor('single', context)
    client_executor.add_node(client_node)
    client = client_node.create_client(Trigger, 'wait')
    spin_until(client_executor, client.service_is_ready, 'the service')
    future = client.call_async(Trigger.Request())
    spin_until(client_executor, lambda: waiting.polls > 0, 'the call to wait')
    time.sleep(1.0)     # four spin windows: a busy loop would poll tens of thousands of times
    polls = waiting.polls
    waiting.done = True
    spin_until(client_executor, future.done, 'the answer')
    assert future.result().success
    assert polls < 200, polls
    client_executor.shutdown()
    context.try_shutdown()
    spinner.join(timeout=10.0)
