"""Fixtures and helpers for tests that run real rclpy nodes over real Fast DDS.

Each test gets its own ROS 2 domain (a ``ROS_DOMAIN_ID`` claimed with a lock,
tests/domains.py, so parallel test processes never share one; discovery limited to
localhost) and its own ``rclpy.Context``, so tests, and other people's test runs on the
same machine, never hear each other.  Nodes made with ``RosHarness.start`` spin on one
background executor thread; ``RosHarness.spawn`` runs the package's executables as child
processes in the same domain and stops them with Ctrl-C (SIGINT) at the end.

Use in a test module::

    @pytest.fixture
    def ros(monkeypatch, tmp_path):
        yield from isolated_ros(monkeypatch, tmp_path)

    def test_something(ros):
        node = ros.start(SimNode, params={'mode': 'lockstep'})
        ros.wait_for(lambda: ..., what='...')
"""
from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Int32, String
from std_srvs.srv import Trigger

from domains import ros_domain
from sim_nodes.ros.commands import StampedCommand
from sim_nodes.ros.common import EVENT_QOS, MessageError, stamp_ns, topic_names
from sim_nodes.problem import Problem

WAIT_S = 30.0  # [s] generous bound for any single wait: a failing test, not a timing check
# Keep every sample in tests: readers must not lose a state if the test thread is slow.
PROBE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def _die_with_parent() -> None:
    """In a child before exec: get SIGTERM if the test process dies (Linux), no orphans."""
    try:
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def new_node(make: Callable[..., Any], context: Any, params: dict[str, Any] | None = None,
             **kwargs: Any) -> Any:
    """A node made by ``make`` (a node class or factory) in ``context``, ``params`` as its
    parameter overrides."""
    overrides = [Parameter(k, value=v) for k, v in (params or {}).items()]
    return make(context=context, parameter_overrides=overrides, **kwargs)


def executable(name: str) -> Path:
    """Where ``ros2 run sapga_ros <name>`` finds it, else the console script of this venv."""
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
        try:
            path = Path(get_package_prefix('sapga_ros')) / 'lib' / 'sapga_ros' / name
            if path.is_file() and os.access(path, os.X_OK):
                return path
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    return Path(sys.prefix) / 'bin' / name


class RosHarness:
    """An isolated ROS 2 domain with an executor thread and child processes."""

    def __init__(self, domain_id: int, tmp_dir: Path) -> None:
        self.domain_id = domain_id
        self.tmp_dir = tmp_dir
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Node] = []
        self.children: list[tuple[subprocess.Popen, Path]] = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - reported, and the test then times out
            if self.context.ok():
                traceback.print_exc()

    def start(self, cls: Callable[..., Node], params: dict[str, Any] | None = None,
              **kwargs: Any) -> Any:
        """Make a node of class ``cls`` in this domain with parameter overrides; spin it."""
        node = new_node(cls, self.context, params, **kwargs)
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def wait_for(self, predicate: Callable[[], Any], what: str = 'condition',
                 timeout: float = WAIT_S) -> Any:
        """Poll ``predicate`` until it returns something truthy; fail after ``timeout``."""
        deadline = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out waiting for {what}{self._child_logs()}')
            time.sleep(0.01)

    def call(self, client: Any, request: Any, timeout: float = WAIT_S) -> Any:
        """Call a service from the test thread (the executor thread runs the client)."""
        self.wait_for(client.service_is_ready, f'service {client.srv_name}', timeout)
        future = client.call_async(request)
        self.wait_for(future.done, f'a response from {client.srv_name}', timeout)
        return future.result()

    def spawn(self, exe: str, *args: str) -> subprocess.Popen:
        """Run a package executable in this domain; its output goes to a log file."""
        log = self.tmp_dir / f'{exe}-{len(self.children)}.log'
        with open(log, 'wb') as out:
            proc = subprocess.Popen([str(executable(exe)), *args], env=self.env, stdout=out,
                                    stderr=subprocess.STDOUT, preexec_fn=_die_with_parent)
        self.children.append((proc, log))
        return proc

    def stop(self, proc: subprocess.Popen, timeout: float = 15.0) -> int:
        """Ctrl-C a child and wait for it; kill it if it does not stop. Its exit code."""
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return proc.returncode

    def _child_logs(self) -> str:
        text = ''
        for proc, log in self.children:
            tail = log.read_text(errors='replace')[-2000:] if log.exists() else ''
            text += f'\n--- {log.name} (exit {proc.poll()}) ---\n{tail}'
        return text

    def close(self) -> None:
        for proc, _ in self.children:
            self.stop(proc)
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        for node in self.nodes:
            node.destroy_node()
        self.context.try_shutdown()


def isolated_ros(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[RosHarness]:
    """Body of a ``ros`` fixture: an isolated ROS 2 domain for one test (``RosHarness``)."""
    with ros_domain() as domain:
        monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
        monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        harness = RosHarness(domain, tmp_path)
        try:
            yield harness
        finally:
            harness.close()


class Probe(Node):
    """A test node on a problem's topics: records what it hears, publishes what it is told.

    ``states`` maps stamp [ns] -> JointState (re-publishes collapse), in arrival order;
    ``events`` are the parsed episode events; ``rewards``, ``indices`` lists; ``commands``
    the values of the stamped commands (``command_stamped``) and ``answered`` their stamps.
    ``command_pub`` publishes hand-use ``Float64`` commands, ``answer`` stamped ones.
    """

    def __init__(self, problem: Problem, node_name: str = 'probe', sim: str = 'sim',
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        topics = topic_names(problem)
        self.states: dict[int, JointState] = {}
        self.events: list[dict] = []
        self.rewards: list[float] = []
        self.commands: list[float] = []
        self.answered: list[int] = []
        self.indices: list[int] = []
        self.lock = threading.Lock()
        self._stamped = StampedCommand(problem)
        self.create_subscription(JointState, topics['state'], self._on_state, PROBE_QOS)
        self.create_subscription(String, topics['event'], self._on_event, EVENT_QOS)
        self.create_subscription(Float64, topics['reward'],
                                 lambda m: self.rewards.append(m.data), PROBE_QOS)
        self.create_subscription(JointState, topics['command_stamped'], self._on_command,
                                 PROBE_QOS)
        self.create_subscription(Int32, topics['exemplar'],
                                 lambda m: self.indices.append(m.data), PROBE_QOS)
        self.command_pub = self.create_publisher(Float64, topics['command'], PROBE_QOS)
        self.stamped_pub = self.create_publisher(JointState, topics['command_stamped'],
                                                 PROBE_QOS)
        self.state_pub = self.create_publisher(JointState, topics['state'], PROBE_QOS)
        self.reset = self.create_client(Trigger, f'{sim}/reset')
        self.load_policy = self.create_client(Trigger, 'policy_node/load_policy')

    def _on_state(self, msg: JointState) -> None:
        with self.lock:
            self.states.setdefault(stamp_ns(msg), msg)

    def _on_command(self, msg: JointState) -> None:
        try:
            stamp, value = self._stamped.read(msg)
        except MessageError:
            return                  # a test's malformed command: not the policy node's
        with self.lock:
            self.answered.append(stamp)
            self.commands.append(value)

    def answer(self, value: float, stamp: int) -> None:
        """Publish a stamped command answering the state stamped ``stamp`` [ns]."""
        self.stamped_pub.publish(self._stamped.fill(value, stamp))

    def _on_event(self, msg: String) -> None:
        with self.lock:
            self.events.append(json.loads(msg.data))

    def latest_state(self) -> JointState | None:
        with self.lock:
            return next(reversed(self.states.values()), None)

    def event(self, kind: str, episode: int) -> dict | None:
        """The first event ``kind`` of ``episode`` heard so far, or None."""
        with self.lock:
            return next((e for e in self.events
                         if e['event'] == kind and e['episode'] == episode), None)

    def heard(self, states: int, steps: int) -> bool:
        """At least ``states`` states and ``steps`` rewards, commands and exemplar indices
        heard: an end event (its own topic) can arrive before the episode's last messages."""
        with self.lock:
            return len(self.states) >= states and min(
                len(self.rewards), len(self.commands), len(self.indices)) >= steps

    def end_of(self, episode: int) -> dict | None:
        """The goal / step_limit / end_stop event that ended ``episode``, or None."""
        return self.event('goal', episode) or self.event('step_limit', episode) or \
            self.event('end_stop', episode)


def run_lockstep(ros, problem, policy, path, delta, episodes=2, policy_params=None,
                 **sim_params):
    """Sim (lockstep) + policy node + probe in process; the policy is set once all match
    (``policy_params``, ``sim_params``: more policy node and simulator parameters)."""
    from sapga_ros.nodes.policy_node import PolicyNode
    from sim_nodes.ros.sim_node import SimNode
    probe = ros.start(Probe, problem=problem)
    pol = ros.start(PolicyNode, params={'problem': problem.name, **(policy_params or {})})
    sim = ros.start(SimNode, params={'problem': problem.name, 'mode': 'lockstep',
                                     'delta': delta, 'max_episodes': episodes,
                                     'republish_period': 0.05, **sim_params})
    ros.wait_for(lambda: sim._state_pub.get_subscription_count() == 2
                 and sim._stamped_sub.get_publisher_count() == 2 and probe.states,
                 'discovery of sim, policy node and probe')
    policy.save(path)
    assert pol.set_parameters([Parameter('policy_file', value=str(path))])[0].successful
    for k in range(1, episodes + 1):
        ros.wait_for(lambda k=k: probe.end_of(k), f'the end of episode {k}')
    steps = sum(probe.end_of(k)['step'] for k in range(1, episodes + 1))
    ros.wait_for(lambda: probe.heard(steps + episodes, steps),
                 'the last states, rewards, commands and exemplar indices')
    return probe, sim
