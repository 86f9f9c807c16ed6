"""Benchmark of the ROS 2 shell: how fast a lockstep episode runs
through DDS and what one selection costs in the policy node, each printed beside a baseline
measured in the same process (the compiled offline episode kernel).

    python -m sapga_ros.bench.ros [--problem acrobot] [--steps 4000] [--processes]
                                  [--realtime]

* lockstep loop: ``SimNode`` (lockstep) and ``PolicyNode`` exchange state and command over
  Fast DDS, both nodes on one executor thread of this process, on each executor the nodes
  can run on (``events``, their default, and ``single``); ``--processes``: the two
  executables as child processes, timed from the episode events;
* selection: ``PolicyNode.select`` (JointState -> state, normalise, nearest) per call, and
  the whole state callback including the two publishes;
* floors (``ros_floor.py``): a bare JointState ping-pong between two nodes on each of the
  two executors, with the share of it the lockstep loop on the same executor reaches;
  ``--realtime``: the state->command latency of the realtime sim and policy node, matched
  by header stamp.

rclpy is imported inside the functions: importing this module costs nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import tempfile
import time
from pathlib import Path

import numpy as np

from sapga_ros.bench.ros_floor import ping_pong, realtime_latency, start_pair, stop_pair
from sapga_ros.evaluation.evaluator import Evaluator
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.problem import Problem, load_problem
from sim_nodes.ros.executors import DEFAULT_EXECUTOR, EXECUTORS, make_executor

N_EXEMPLARS = 100  # L_max of SAP-GA: the largest policy the trainer produces


def bench_policy(problem: Problem, seed: int = 0) -> ExemplarPolicy:
    """A random policy of N_EXEMPLARS exemplars (a seeded numpy generator)."""
    rng = np.random.default_rng(seed)
    return ExemplarPolicy(problem, rng.uniform(problem.low, problem.high,
                                               (N_EXEMPLARS, problem.dim)),
                          rng.integers(0, len(problem.actions), N_EXEMPLARS))


def kernel_step_us(problem: Problem, policy: ExemplarPolicy, repeats: int = 50) -> float:
    """Baseline: microseconds per MDP step (selection included) of the offline kernel."""
    evaluator = Evaluator(problem, n_step=problem.n_step)
    evaluator.episode(policy)  # compile / load from cache
    start = time.perf_counter()
    steps = sum(evaluator.episode(policy).steps for _ in range(repeats))
    return (time.perf_counter() - start) / steps * 1e6


def _domain() -> int:
    """A fresh random domain per run: no run hears another's nodes or stored events."""
    return random.randint(100, 200)


def _env(domain: int) -> None:
    os.environ['ROS_DOMAIN_ID'] = str(domain)  # for child processes
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def bench_selection(problem: Problem, policy: ExemplarPolicy, repeats: int = 20000) -> dict:
    """Microseconds per ``PolicyNode.select`` and per state callback (with publishing)."""
    import rclpy
    from rclpy.parameter import Parameter

    from sim_nodes.ros.common import JointStateLayout
    from sapga_ros.nodes.policy_node import PolicyNode, PreparedPolicy

    domain = _domain()
    _env(domain)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        node = PolicyNode(context=context, parameter_overrides=[
            Parameter('problem', value=problem.name)])
        prepared = PreparedPolicy.of(policy, 'bench')
        node.active = prepared
        layout = JointStateLayout(problem)
        rng = np.random.default_rng(1)
        msgs = [layout.to_msg(s, 0.0, k) for k, s in
                enumerate(rng.uniform(problem.low, problem.high, (64, problem.dim)))]
        for msg in msgs:
            node.select(msg, prepared)
        start = time.perf_counter()
        for k in range(repeats):
            node.select(msgs[k & 63], prepared)
        select_us = (time.perf_counter() - start) / repeats * 1e6
        start = time.perf_counter()
        for k in range(repeats):
            msg = msgs[k & 63]
            msg.header.stamp.nanosec = k  # a new stamp each time: every call answers
            node._on_state(msg, {})   # no message info: nothing to count
        callback_us = (time.perf_counter() - start) / repeats * 1e6
        node.destroy_node()
    finally:
        context.try_shutdown()
    return {'select_us': select_us, 'callback_us': callback_us}


def bench_lockstep(problem: Problem, policy: ExemplarPolicy, steps: int = 4000,
                   executor: str = DEFAULT_EXECUTOR) -> dict:
    """MDP steps/s of a lockstep sim <-> policy loop over DDS, one executor thread."""
    import rclpy
    from rclpy.parameter import Parameter

    from sapga_ros.nodes.policy_node import PolicyNode, PreparedPolicy
    from sim_nodes.ros.sim_node import SimNode

    domain = _domain()
    _env(domain)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        ex = make_executor(executor, context)
        sim = SimNode(default_problem=problem.name, context=context, parameter_overrides=[
            Parameter('mode', value='lockstep'), Parameter('republish_period', value=0.05)])
        pol = PolicyNode(context=context, parameter_overrides=[
            Parameter('problem', value=problem.name)])
        ex.add_node(sim)
        ex.add_node(pol)
        deadline = time.monotonic() + 30.0
        while sim.total_steps == 0 and time.monotonic() < deadline:  # discovery
            pol.active = pol.active or PreparedPolicy.of(policy, 'bench')
            ex.spin_once(timeout_sec=0.05)
        first, start = sim.total_steps, time.perf_counter()
        while sim.total_steps - first < steps and time.monotonic() < deadline + 60.0:
            ex.spin_once(timeout_sec=0.5)
        elapsed = time.perf_counter() - start
        done = sim.total_steps - first
        ex.shutdown()
        sim.destroy_node()
        pol.destroy_node()
    finally:
        context.try_shutdown()
    return {'steps': done, 'seconds': elapsed, 'steps_per_s': done / elapsed}


def bench_lockstep_processes(problem: Problem, policy: ExemplarPolicy,
                             episodes: int = 10) -> dict:
    """MDP steps/s with the sim and the policy node as two child processes."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from sim_nodes.ros.common import EVENT_QOS, topic_names

    domain = _domain()
    _env(domain)
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'policy.json'
        policy.save(path)
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        events: list[tuple[float, dict]] = []
        node = Node('bench_probe', context=context)
        sub = node.create_subscription(String, topic_names(problem)['event'],
                                       lambda m: events.append((time.perf_counter(),
                                                                json.loads(m.data))), EVENT_QOS)

        def ready(request, response):
            # the sim's recorder gate: start once this probe hears the events
            response.success = sub.get_publisher_count() > 0
            return response
        node.create_service(Trigger, 'bench_probe/ready', ready)
        ex = SingleThreadedExecutor(context=context)
        ex.add_node(node)
        procs = start_pair(problem, path, env, ['-p', 'mode:=lockstep', '-p',
                                                f'max_episodes:={episodes + 1}', '-p',
                                                'wait_for_recorder:=bench_probe'])
        try:
            deadline = time.monotonic() + 120.0
            while time.monotonic() < deadline and not any(
                    e['episode'] == episodes + 1 and e['event'] in ('goal', 'step_limit')
                    for _, e in events):
                ex.spin_once(timeout_sec=0.1)
        finally:
            stop_pair(procs, ex, node, context)
    # from the start of episode 2 (the loop is warm) to the end of the last one
    t0 = next(t for t, e in events if e['event'] == 'start' and e['episode'] == 2)
    ends = [(t, e) for t, e in events if e['event'] in ('goal', 'step_limit')
            and e['episode'] >= 2]
    steps = sum(e['step'] + 1 for _, e in ends)  # +1: the tick that starts the next episode
    return {'steps': steps, 'seconds': ends[-1][0] - t0,
            'steps_per_s': steps / (ends[-1][0] - t0)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--problem', default='acrobot', help='problem name (msg_configs)')
    parser.add_argument('--steps', type=int, default=4000, help='MDP steps to time in process')
    parser.add_argument('--processes', action='store_true',
                        help='also time the two executables as child processes')
    parser.add_argument('--realtime', action='store_true',
                        help='also the realtime state->command latency (two processes)')
    args = parser.parse_args(argv)
    problem = load_problem(args.problem)
    policy = bench_policy(problem)
    base_us = kernel_step_us(problem, policy)
    print(f'{problem.name}, {N_EXEMPLARS} exemplars; baseline: offline kernel '
          f'{base_us:.2f} us/step ({1e6 / base_us:,.0f} steps/s)')
    sel = bench_selection(problem, policy)
    print(f'policy node select:   {sel["select_us"]:8.1f} us/step  '
          f'({sel["select_us"] / base_us:6.1f} x kernel step)')
    print(f'policy node callback: {sel["callback_us"]:8.1f} us/step  '
          f'({sel["callback_us"] / base_us:6.1f} x kernel step, incl. 2 publishes)')
    runs = [(f'lockstep, 1 thread, {kind}', bench_lockstep(problem, policy, args.steps, kind))
            for kind in EXECUTORS]
    if args.processes:
        runs.append(('lockstep, 2 processes', bench_lockstep_processes(problem, policy)))
    for label, r in runs:
        print(f'{label + ":":30s} {r["steps_per_s"]:8,.0f} steps/s  ({r["steps"]} steps in '
              f'{r["seconds"]:.2f} s; kernel is {1e6 / base_us / r["steps_per_s"]:,.0f} x '
              f'faster)')
    for kind, (_, r) in zip(EXECUTORS, runs):
        floor = ping_pong(problem, _domain(), kind, args.steps)
        print(f'JointState ping-pong, {kind}: {floor["trips_per_s"]:8,.0f} round trips/s; '
              f'lockstep 1 thread on it is {r["steps_per_s"] / floor["trips_per_s"]:.0%} of it')
    if args.realtime:
        r = realtime_latency(problem, policy, _domain())
        print(f'realtime state->command latency at {r["hz"]:.0f} Hz, {r["steps"]} steps '
              f'(header stamps): median {r["median_ms"]:.2f} ms, p99 {r["p99_ms"]:.2f} ms, '
              f'max {r["max_ms"]:.2f} ms')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
