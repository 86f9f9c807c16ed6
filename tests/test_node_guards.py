"""Hostile load on the sim, policy and recorder nodes over real DDS: a flood their queues
cannot hold is counted and warned about (sim_nodes/ros/dropped.py), and an exception in any
callback (timer, subscription, service) is one log line while the node goes on, on either
executor the sim and the policy node run on (sim_nodes/ros/guarded.py: the nodes' guarded
callbacks; sim_nodes/ros/runner.py: spin_guarded, as every executable spins)."""
from __future__ import annotations

import threading
import time
from collections import Counter
from typing import Any, Callable

import numpy as np
import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from domains import claim_domain, release_domain
from ros_helpers import PROBE_QOS, Probe, new_node
from sapga_ros.policies.exemplar import ExemplarPolicy
from sapga_ros.nodes.policy_node import PolicyNode
from sapga_ros.nodes.recorder_node import RecorderNode
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import JointStateLayout
from sim_nodes.ros.executors import make_executor
from sim_nodes.ros.runner import spin_guarded
from sim_nodes.ros.sim_node import SimNode

FLOOD = 3000        # messages published as fast as the test can
WAIT_S = 60.0


class Guarded:
    """Nodes of one context spun by ``spin_guarded`` on a thread, as the executables spin."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, executor: str = 'single') -> None:
        self.domain = domain = claim_domain()
        monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
        monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = make_executor(executor, self.context)
        self.nodes: list[Any] = []
        self.thread: threading.Thread | None = None

    def add(self, make: Callable[..., Any], params: dict[str, Any] | None = None,
            **kwargs: Any) -> Any:
        node = new_node(make, self.context, params, **kwargs)
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin(self) -> None:
        self.thread = threading.Thread(target=spin_guarded,
                                       args=(self.executor, self.nodes[0].get_logger()),
                                       daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=5.0)
        for node in self.nodes:
            node.destroy_node()
        self.context.try_shutdown()
        if self.thread is not None:
            self.thread.join(timeout=5.0)
        release_domain(self.domain)


@pytest.fixture
def guarded(monkeypatch):
    g = Guarded(monkeypatch)
    yield g
    g.close()


@pytest.fixture
def guarded_on(monkeypatch):
    """``guarded_on(executor)``: a ``Guarded`` on that executor (closed after the test)."""
    made: list[Guarded] = []

    def make(executor: str) -> Guarded:
        made.append(Guarded(monkeypatch, executor))
        return made[-1]
    yield make
    for g in made:
        g.close()


def wait(condition: Callable[[], Any], what: str, timeout: float = WAIT_S) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.01)


@pytest.fixture(scope='module')
def acrobot():
    return load_problem('acrobot')


def test_a_state_flood_on_the_policy_node_is_counted_and_warned(guarded, acrobot, tmp_path,
                                                                capfd, monkeypatch):
    """States faster than the policy node answers overflow its sensor-data queue: the
    dropped ones are counted from the sequence numbers and a warning says how many.  (Each
    answer is made to take 2 ms, so the flood outruns the node on any machine.)"""
    rng = np.random.default_rng(1)
    ExemplarPolicy(acrobot, rng.uniform(acrobot.low, acrobot.high, (60, 4)),
                   rng.integers(0, 3, 60)).save(tmp_path / 'p.json')
    pol = guarded.add(PolicyNode, {'policy_file': str(tmp_path / 'p.json'),
                                   'qos_profile': 'sensor_data'})
    select = pol.select

    def slow_select(*args):
        time.sleep(0.002)
        return select(*args)
    monkeypatch.setattr(pol, 'select', slow_select)
    probe = guarded.add(Probe, problem=acrobot)
    guarded.spin()
    wait(lambda: pol._state_sub.get_publisher_count() == 1
         and probe.state_pub.get_subscription_count() >= 2, 'discovery both ways')
    layout = JointStateLayout(acrobot)
    msgs = [layout.to_msg(s, 0.0, k + 1) for k, s in
            enumerate(rng.uniform(acrobot.low, acrobot.high, (FLOOD, acrobot.dim)))]
    probe.state_pub.publish(msgs[0])          # the count's base: one message handled
    wait(lambda: pol.answered >= 1, 'the first state answered')
    for msg in msgs[1:]:
        probe.state_pub.publish(msg)
    last = layout.to_msg(acrobot.initial_state, 0.0, FLOOD + 1)     # after the flood

    def answered_last() -> bool:
        probe.state_pub.publish(last)
        time.sleep(0.05)
        return pol._last_stamp == FLOOD + 1       # answered (best effort: none hear it)

    wait(answered_last, 'the state after the flood answered')
    assert pol.dropped.count > 0 and pol.answered + pol.dropped.count <= FLOOD + 1
    assert 'messages dropped so far' in capfd.readouterr().err


def test_a_command_flood_on_the_sim_is_counted(guarded, acrobot):
    """Commands faster than the sim handles them are counted as dropped, not lost silently."""
    sim = guarded.add(SimNode, {'mode': 'lockstep', 'qos_profile': 'sensor_data',
                                'republish_period': 0.0})
    node = guarded.add(lambda **kw: rclpy.create_node('flooder', **kw))
    pub = node.create_publisher(Float64, 'command', PROBE_QOS)
    guarded.spin()
    wait(lambda: sim._command_sub.get_publisher_count() == 1
         and pub.get_subscription_count() >= 1, 'discovery both ways')
    pub.publish(Float64(data=0.0))            # the count's base: one command handled
    wait(lambda: sim.total_steps >= 1, 'the first command handled')
    for k in range(1, FLOOD):
        pub.publish(Float64(data=0.0))
    wait(lambda: sim.dropped['/command'].count > 0, 'the dropped commands counted')
    assert sim.total_steps + sim.dropped['/command'].count <= FLOOD


def test_commands_of_two_publishers_interleaved_count_no_drop(guarded):
    """A second publisher's few messages between a first one's (a hand ``ros2 topic pub``
    during a run) are no gap: the count is kept per publisher.  Reliable QoS, each batch
    handled before the next, so nothing is dropped and the count must say 0."""
    sim = guarded.add(SimNode, {'mode': 'lockstep', 'republish_period': 0.0,
                                'n_step': 1_000_000})
    first = guarded.add(lambda **kw: rclpy.create_node('first', **kw))
    hand = guarded.add(lambda **kw: rclpy.create_node('hand', **kw))
    pubs = [n.create_publisher(Float64, 'command', PROBE_QOS) for n in (first, hand)]
    guarded.spin()
    wait(lambda: sim._command_sub.get_publisher_count() == 2
         and all(p.get_subscription_count() >= 1 for p in pubs), 'discovery both ways')
    sent = 0
    for who, n in ((0, 300), (1, 2), (0, 300), (1, 1)):
        for _ in range(n):
            pubs[who].publish(Float64(data=0.0))
        sent += n
        wait(lambda: sim.total_steps == sent, f'{sent} commands handled')
    hand.destroy_publisher(pubs[1])         # it leaves after its message, as ros2 topic pub
    wait(lambda: sim._command_sub.get_publisher_count() == 1, 'the hand publisher gone')
    for _ in range(100):
        pubs[0].publish(Float64(data=0.0))
    wait(lambda: sim.total_steps == sent + 100, 'the last commands handled')
    assert sim.dropped['/command'].count == 0


def test_the_drop_counter_keeps_one_count_per_publisher():
    """Sequence numbers of two publishers interleaved: gaps within each are counted, the
    jumps between them are not (the numbers of the trial that once read 622 drops)."""
    from sim_nodes.ros.dropped import DropCounter

    class Log:
        def warning(self, *args: Any, **kwargs: Any) -> None:
            pass

    publishers = [1]
    counter = DropCounter(Log(), 'command_stamped', lambda: publishers[0], 10)

    def feed(*numbers: int) -> int:
        return sum(counter.seen({'publication_sequence_number': n}) for n in numbers)

    assert feed(*range(1, 601)) == 0
    publishers[0] = 2                       # ros2 topic pub joins: its numbers start at 1
    assert feed(1, 601, 2, 602) == 0
    publishers[0] = 1                       # and leaves
    assert feed(*range(603, 623)) == 0 and counter.count == 0
    assert feed(630) == 7 and counter.count == 7     # a real gap of the first publisher
    publishers[0] = 2
    assert feed(1, 2, 631, 5) == 2 and counter.count == 9   # and of the second
    assert feed(1) == 0                     # a publisher that starts again: a new base


def test_a_flood_on_a_recorded_topic_is_counted_by_the_recorder(guarded, tmp_path):
    """A topic recorded with a queue of 1 that gets a flood: the recorder counts what never
    reached it and says so when it finishes the bag."""
    rec = guarded.add(RecorderNode, {'output_dir': str(tmp_path), 'queue_depth': 1,
                                     'topics': ['flood:std_msgs/msg/Float64']})
    node = guarded.add(lambda **kw: rclpy.create_node('flooder', **kw))
    pub = node.create_publisher(Float64, 'flood', QoSProfile(
        depth=FLOOD, reliability=ReliabilityPolicy.RELIABLE))
    guarded.spin()
    wait(lambda: '/flood' in rec._subs and rec._subs['/flood'][0].get_publisher_count() == 1
         and pub.get_subscription_count() >= 1, 'discovery both ways')
    pub.publish(Float64(data=0.0))            # the count's base: one message recorded
    wait(lambda: rec.message_count >= 1, 'the first message recorded')
    for k in range(1, FLOOD):
        pub.publish(Float64(data=float(k)))
    wait(lambda: rec.dropped['/flood'].count > 0, 'the dropped messages counted')
    assert rec.message_count + rec.dropped['/flood'].count <= FLOOD


def boom(what: str, calls: Counter[str]) -> Callable[..., None]:
    def fail(*args: Any) -> None:
        calls[what] += 1
        raise ValueError(f'{what}\nsecond line')
    return fail


def fragile_entities(guarded: Guarded, node: Any, calls: Counter[str]) -> Callable[[], None]:
    """A raising timer, subscription and service on ``node`` (``calls`` counts their runs by
    kind); a function that triggers the subscription and the service from a helper node of
    the same context."""
    node.create_timer(0.05, boom('timer', calls))
    node.create_subscription(String, 'boom_topic', boom('subscription', calls), 10)
    node.create_service(Trigger, 'boom_service', boom('service', calls))
    helper = rclpy.create_node('boom_helper', context=guarded.context)
    guarded.nodes.append(helper)
    pub = helper.create_publisher(String, 'boom_topic', 10)
    client = helper.create_client(Trigger, 'boom_service')

    def trigger() -> None:
        wait(lambda: pub.get_subscription_count() == 1 and client.service_is_ready(),
             'the fragile entities')
        pub.publish(String(data='x'))
        client.call_async(Trigger.Request())
    return trigger


@pytest.mark.parametrize('kind, executor', [('sim', 'events'), ('sim', 'single'),
                                            ('policy', 'events'), ('policy', 'single'),
                                            ('recorder', 'single')])
def test_a_raising_callback_of_any_kind_is_one_line_and_the_node_goes_on(
        guarded_on, tmp_path, capfd, kind, executor):
    """Timer, subscription and service callbacks that raise are logged as one line each (no
    traceback, on either executor the node runs on); the node keeps doing its own work (the
    sim steps, the policy node answers, the recorder answers its ready service)."""
    guarded = guarded_on(executor)
    acrobot = load_problem('acrobot')
    if kind == 'sim':
        node = guarded.add(SimNode, {'real_time_factor': 20.0, 'wait_for_policy': False})
    elif kind == 'policy':
        rng = np.random.default_rng(2)
        ExemplarPolicy(acrobot, rng.uniform(acrobot.low, acrobot.high, (20, 4)),
                       rng.integers(0, 3, 20)).save(tmp_path / 'p.json')
        node = guarded.add(PolicyNode, {'policy_file': str(tmp_path / 'p.json')})
    else:
        node = guarded.add(RecorderNode, {'output_dir': str(tmp_path)})
    probe = guarded.add(Probe, problem=acrobot)
    calls: Counter[str] = Counter()
    trigger = fragile_entities(guarded, node, calls)
    guarded.spin()
    trigger()
    # Read what was logged once, when every kind's line is known to be written: the executor
    # thread logs a failure before it runs the next callback, so once the timer has run
    # again after the subscription and the service both ran, their lines and a timer's are
    # out.  (No polling of capfd: readouterr() reads the capture file, then truncates it, and
    # lines the node writes in between are lost; a subscription's and a service's failure,
    # logged once each and together, were lost so in about 1 run of the file in 10.)
    wait(lambda: calls['subscription'] and calls['service'], 'the subscription and the service')
    runs = calls['timer']
    wait(lambda: calls['timer'] > max(runs, 1), 'the timer to run after them')
    err = capfd.readouterr().err
    err = err[:err.rfind('\n') + 1]        # not a line the timer's next failure is writing
    for what in ('timer', 'subscription', 'service'):
        assert f'ValueError: {what} second line' in err, err
    failures = [line for line in err.splitlines() if 'callback failed' in line]
    assert all(line.endswith(' second line') for line in failures), failures
    assert 'Traceback' not in err and 'FATAL' not in err and 'occurred at' not in err, err
    if kind == 'sim':
        before = node.total_steps
        wait(lambda: node.total_steps > before + 5, 'the sim to step on')
    elif kind == 'policy':
        layout = JointStateLayout(acrobot)
        wait(lambda: node._state_sub.get_publisher_count() >= 1, 'discovery')
        probe.state_pub.publish(layout.to_msg(acrobot.initial_state, 0.0, 77))
        wait(lambda: 77 in probe.answered, 'an answer')
    else:
        answer = wait(lambda: _call(probe, 'recorder_node/ready'), 'the ready service')
        assert answer.message
    assert guarded.thread.is_alive()


def _call(node: Any, name: str) -> Any:
    client = node.create_client(Trigger, name)
    if not client.wait_for_service(timeout_sec=1.0):
        return None
    future = client.call_async(Trigger.Request())
    deadline = time.monotonic() + 5.0
    while not future.done() and time.monotonic() < deadline:
        time.sleep(0.01)
    return future.result() if future.done() else None
