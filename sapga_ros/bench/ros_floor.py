"""The floors and the latency of the ROS 2 shell, measured beside the lockstep loop.

* ``ping_pong``: round trips/s of a bare rclpy ``sensor_msgs/JointState`` ping-pong between
  two nodes of this process on one executor (``events``: ``rclpy.experimental.
  EventsExecutor``, the nodes' default; ``single``: the ``SingleThreadedExecutor``), with
  the problem's state message and the nodes' QoS.  One lockstep MDP step is one such round
  trip plus the work of both nodes, so the ping-pong on the loop's executor is the floor the
  loop cannot beat.
* ``realtime_latency``: the simulator (realtime) and the policy node as two child
  processes; a probe node records when it receives each state and the command whose header
  stamp names that state (the policy node stamps its answer with the state's stamp), so the
  state->command latency of each step is the difference of the two receive times, matched
  by header stamp.  Reported as median, p99 and max over the steps of the run.

rclpy is imported inside the functions: importing this module costs nothing.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.models.registry import sim_executable
from sim_nodes.problem import Problem
from sim_nodes.ros.executors import make_executor


def start_pair(problem: Problem, policy_file: Path, env: dict, sim_args: list[str]
               ) -> list[subprocess.Popen]:
    """The policy node (``policy_file``) and the problem's simulator (``sim_args`` after
    its ``problem``) as child processes of this one, output discarded."""
    bin_dir = Path(sys.prefix) / 'bin'
    quiet = {'env': env, 'stdout': subprocess.DEVNULL, 'stderr': subprocess.DEVNULL}
    return [subprocess.Popen([str(bin_dir / 'policy_node'), '--ros-args', '-p',
                              f'problem:={problem.name}', '-p', f'policy_file:={policy_file}'],
                             **quiet),
            subprocess.Popen([str(bin_dir / sim_executable(problem.model)), '--ros-args',
                              '-p', f'problem:={problem.name}', *sim_args], **quiet)]


def stop_pair(procs: list[subprocess.Popen], executor, node, context) -> None:
    """Ctrl-C to the child processes, then the probe ``node`` and its ROS context down."""
    for proc in procs:
        proc.send_signal(2)
        proc.wait(15)
    executor.shutdown()
    node.destroy_node()
    context.try_shutdown()


def ping_pong(problem: Problem, domain: int, executor: str = 'single',
              trips: int = 4000) -> dict:
    """Round trips/s of a JointState ping-pong between two nodes on one executor."""
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from sim_nodes.ros.common import QUIET_PUBLISHER, JointStateLayout, qos_profile

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    qos = qos_profile(problem)
    quiet = {'event_callbacks': QUIET_PUBLISHER}
    try:
        ex = make_executor(executor, context)
        ping = Node('bench_ping', context=context)
        pong = Node('bench_pong', context=context)
        msg = JointStateLayout(problem).to_msg(problem.initial_state)
        ping_pub = ping.create_publisher(JointState, 'bench_ping', qos, **quiet)
        pong_pub = pong.create_publisher(JointState, 'bench_pong', qos, **quiet)
        count = [0]

        def back(m: JointState) -> None:
            count[0] += 1
            m.header.stamp.nanosec = count[0] % 1_000_000_000
            ping_pub.publish(m)

        ping.create_subscription(JointState, 'bench_pong', back, qos)
        pong.create_subscription(JointState, 'bench_ping', pong_pub.publish, qos)
        ex.add_node(ping)
        ex.add_node(pong)
        deadline = time.monotonic() + 30.0
        while count[0] == 0 and time.monotonic() < deadline:      # discovery
            ping_pub.publish(msg)
            ex.spin_once(timeout_sec=0.05)
        first, start = count[0], time.perf_counter()
        while count[0] - first < trips and time.monotonic() < deadline + 60.0:
            ex.spin_once(timeout_sec=0.5)
        elapsed = time.perf_counter() - start
        done = count[0] - first
        ex.shutdown()
        ping.destroy_node()
        pong.destroy_node()
    finally:
        context.try_shutdown()
    return {'trips': done, 'seconds': elapsed, 'trips_per_s': done / elapsed}


def realtime_latency(problem: Problem, policy: ExemplarPolicy, domain: int,
                     seconds: float = 10.0, real_time_factor: float = 4.0) -> dict:
    """State->command latency [ms] of the realtime sim and the policy node (two processes),
    matched by header stamp at a probe node: median, p99, max, and the steps measured."""
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from sim_nodes.ros.common import qos_profile, stamp_ns, topic_names

    topics = topic_names(problem)
    qos = qos_profile(problem)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1')
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    states: dict[int, float] = {}
    commands: dict[int, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'policy.json'
        policy.save(path)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = Node('bench_latency_probe', context=context)
        node.create_subscription(JointState, topics['state'], lambda m: states.setdefault(
            stamp_ns(m), time.perf_counter()), qos)
        node.create_subscription(JointState, topics['command_stamped'],
                                 lambda m: commands.setdefault(stamp_ns(m),
                                                               time.perf_counter()), qos)
        ex = make_executor('single', context)
        ex.add_node(node)
        procs = start_pair(problem, path, env, ['-p', 'mode:=realtime', '-p',
                                                f'real_time_factor:={float(real_time_factor)}'])
        try:
            deadline = time.monotonic() + 120.0
            while not commands and time.monotonic() < deadline:   # start-up and discovery
                ex.spin_once(timeout_sec=0.1)
            first = len(commands)
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                ex.spin_once(timeout_sec=0.1)
        finally:
            stop_pair(procs, ex, node, context)
    stamps = sorted(commands)[first:]
    ms = np.array([(commands[s] - states[s]) * 1e3 for s in stamps if s in states])
    if ms.size == 0:
        raise RuntimeError('no state was answered during the measurement')
    return {'steps': int(ms.size), 'median_ms': float(np.median(ms)),
            'p99_ms': float(np.percentile(ms, 99)), 'max_ms': float(ms.max()),
            'hz': real_time_factor / (problem.dt * problem.substeps)}
