"""Nothing lost: recorded launches hold every message, exactly; hostile input on the way.

``sapga launch swingup`` runs 3 lockstep episodes 10 times (2 times unless ``--long``), each in
a fresh ROS domain; every
bag, read with rosbags' ``AnyReader`` (an independent reader), must hold exactly the
episodes the offline evaluator computes: every start and end event, every reward, every
state, every command (each answering its state) and the markers of every state, in order.
Then the hostile inputs that used to break a recorded run: a deeply nested
``episode_event`` on the launcher's ROS thread, a callback that raises, and a simulator
waiting for a recorder that never comes.
"""
from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from domains import ros_domain
from ros_helpers import executable
from sapga_ros.evaluation.evaluator import run_policy_episode
from sapga_ros.policies.exemplar import ExemplarPolicy
from sim_nodes.problem import load_problem
from sim_nodes.ros.common import EVENT_QOS, JointStateLayout, spin_guarded
from test_launch import launch, the_bag

RUNS = 10
EPISODES = 3
DELTA = 0.4         # the policy below reaches it in 62 steps: goal events, short episodes


@pytest.fixture(scope='module')
def policy_file(tmp_path_factory) -> tuple[Path, object]:
    problem = load_problem('acrobot')
    rng = np.random.default_rng(7)
    policy = ExemplarPolicy(problem, rng.uniform(problem.low, problem.high, (60, 4)),
                            rng.integers(0, 3, 60), meta={'delta': DELTA})
    path = tmp_path_factory.mktemp('policy') / 'p.json'
    policy.save(path)
    return path, run_policy_episode(policy, DELTA)


def bag_messages(bag: Path) -> dict[str, list]:
    """topic -> decoded messages in receive order, read with rosbags' AnyReader."""
    out: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        for connection, _, raw in reader.messages():
            out.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype))
    return out


def check_bag(bag: Path, offline) -> None:
    """The bag holds exactly EPISODES copies of the offline episode."""
    problem = load_problem('acrobot')
    layout = JointStateLayout(problem)
    steps = offline.steps
    got = bag_messages(bag)
    events = [json.loads(m.data) for m in got['/episode_event']]
    assert [(e['event'], e['episode']) for e in events] == [
        (kind, n) for n in range(1, EPISODES + 1) for kind in ('start', 'goal')]
    for end in events[1::2]:
        assert (end['return'], end['step'], end['delta_star']) == (
            offline.ret, steps, offline.delta_star)
    assert [m.data for m in got['/reward']] == list(offline.rewards) * EPISODES
    first: dict[int, np.ndarray] = {}
    for msg in got['/joint_states']:        # re-published states repeat their stamp
        stamp = stamp_of(msg)
        state = layout.from_msg(msg)
        assert np.array_equal(first.setdefault(stamp, state), state)
    tick = round(problem.dt * problem.substeps * 1e9)
    assert sorted(first) == [k * tick for k in range(EPISODES * (steps + 1))]
    states = np.array([first[t] for t in sorted(first)])
    assert np.array_equal(states, np.vstack([offline.states] * EPISODES))
    commands = [m.effort[0] for m in got['/command_stamped']]
    answered = [stamp_of(m) for m in got['/command_stamped']]
    assert answered == sorted(first)[:len(answered)]   # each answers its state, in order
    exemplars = [m.data for m in got['/exemplar_index']]
    # one command per state: each step's, then the one answering the final state (which
    # restarts the episode; the last episode's may come after the launch stopped)
    assert len(commands) in (EPISODES * (steps + 1) - 1, EPISODES * (steps + 1))
    assert len(exemplars) == len(commands)
    for n in range(EPISODES):
        span = slice(n * (steps + 1), n * (steps + 1) + steps)
        assert commands[span] == list(offline.actions)
        assert exemplars[span] == list(offline.exemplars)
    # the markers: the simulator's scene of every state, the policy's ghost of every answer
    # (the launch stops the recorder only once they are in the bag too: verify.py)
    scenes = {stamp_of(m.markers[0]) for m in got['/markers'] if m.markers[0].ns == 'links'}
    ghosts = [stamp_of(m.markers[0]) for m in got['/markers'] if m.markers[0].ns == 'exemplar']
    assert scenes == set(first)
    assert ghosts == answered[:len(ghosts)] and len(ghosts) >= EPISODES * (steps + 1) - 1


def stamp_of(msg) -> int:
    """header.stamp [ns] of a decoded message."""
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


@pytest.mark.parametrize('runs', [1, pytest.param(RUNS, marks=pytest.mark.long)])
def test_lockstep_launches_record_every_message_exactly(tmp_path, policy_file, runs):
    """1 (``make test``) or 10 (``make test-long``) x `sapga launch swingup --episodes 3`:
    every bag is whole and exact."""
    path, offline = policy_file
    assert offline.reached and offline.steps == 62
    for run in range(runs):
        done = launch(['swingup', '--policy', str(path), '--out', f'run{run}', '--episodes',
                       str(EPISODES)], tmp_path)
        assert 'every lockstep episode is equal' in done.stdout, done.stdout[-3000:]
        assert 'incomplete' not in done.stdout
        try:
            check_bag(the_bag(tmp_path / f'run{run}'), offline)
        except AssertionError as exc:
            raise AssertionError(f'run {run}: {exc}\n{done.stdout[-3000:]}') from exc


def test_the_gap_check_asks_for_the_markers_of_every_state_and_answer():
    """recording_gaps: the simulator's scene of every state and, in lockstep, the policy's
    ghost of every answer, once the bag has such markers (none: not asked for)."""
    from types import SimpleNamespace

    from rclpy.serialization import serialize_message
    from visualization_msgs.msg import Marker, MarkerArray

    from sapga_ros.recording.verify import recording_gaps

    def markers(ns: str, tick: int) -> SimpleNamespace:
        m = Marker(ns=ns)
        m.header.frame_id, m.header.stamp.nanosec = 'acrobot', tick * 1000
        return SimpleNamespace(topic='/markers', data=serialize_message(
            MarkerArray(markers=[m, Marker(ns='joints')])))

    def state(tick: int) -> SimpleNamespace:
        msg = JointState()
        msg.header.stamp.nanosec = tick * 1000
        return SimpleNamespace(topic='/joint_states', data=serialize_message(msg))

    def event(kind: str) -> SimpleNamespace:
        return SimpleNamespace(topic='/episode_event',
                               data=serialize_message(String(data=json.dumps({'event': kind}))))

    roles = {'event': '/episode_event', 'reward': '/reward', 'state': '/joint_states',
             'command': '/command', 'markers': '/markers'}
    ends = [{'event': 'goal', 'step': 3}]
    base = [event('start'), *[state(k) for k in range(4)], event('goal'),
            *[SimpleNamespace(topic=t, data=b'') for t in ('/reward', '/command')
              for _ in range(3)]]
    whole = base + [markers('links', k) for k in (0, 1, 1, 2, 3)] + [
        markers('exemplar', k) for k in range(3)]
    assert recording_gaps(SimpleNamespace(messages=whole), roles, ends) == []
    assert recording_gaps(SimpleNamespace(messages=base), roles, ends) == []
    lacking = whole[:-2] + whole[-1:]
    lacking.remove(next(m for m in lacking if m.data == markers('links', 3).data))
    assert recording_gaps(SimpleNamespace(messages=lacking), roles, ends) == [
        '3 of 4 state markers', '2 of 3 exemplar markers']
    assert recording_gaps(SimpleNamespace(messages=lacking), roles, ends, lockstep=False) == [
        '3 of 4 state markers']


def test_a_launch_whose_bag_is_incomplete_exits_1():
    """The swingup report fails (exit 1, the reason printed) when the bag lacks messages,
    even though every episode equals the offline one."""
    from sapga_ros.launch.supervisor import Supervisor
    from sapga_ros.launch.swingup import SwingupResult, print_swingup

    end = {'event': 'goal', 'episode': 1, 'step': 3, 'return': -3.0, 'delta_star': 0.1}
    offline = {'return': -3.0, 'delta_star': 0.1, 'steps': 3, 'reached': True}
    whole = SwingupResult([end], [], offline, True)
    lacking = SwingupResult([end], [], offline, True, 'the recording b is incomplete: ...')
    assert print_swingup(Supervisor(), whole) == 0
    assert print_swingup(Supervisor(), lacking) == 1


def wait(condition, what: str, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.02)


def test_a_nested_episode_event_does_not_kill_the_launchers_ros_thread(ros_context):
    """'[' * 100000 + ']' * 100000 on episode_event is no event; the launcher's ROS thread
    goes on and hears the next real one."""
    from sapga_ros.launch.swingup import LaunchRos

    ros = LaunchRos(load_problem('acrobot'))
    node = Node('hostile_publisher', context=ros_context)
    pub = node.create_publisher(String, 'episode_event', EVENT_QOS)
    try:
        wait(lambda: pub.get_subscription_count() >= 1, 'the launcher to subscribe')
        pub.publish(String(data='[' * 100_000 + ']' * 100_000))
        pub.publish(String(data=json.dumps({'event': 'goal', 'episode': 1, 'step': 3})))
        wait(lambda: ros.node.end_events(), 'the real event after the hostile one')
        assert ros.node.end_events() == [{'event': 'goal', 'episode': 1, 'step': 3}]
        assert ros._thread.is_alive()
    finally:
        node.destroy_node()
        ros.close()


def test_an_idempotent_request_without_an_answer_is_sent_again(ros_context):
    """A server that never answers the first request (as when it has not yet discovered a
    new client's response reader and drops the response): the launcher's idempotent call
    sends it again and takes the first answer; a call that is not idempotent sends once."""
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from std_srvs.srv import Trigger
    from sapga_ros.launch.launch_node import LaunchRos
    from sapga_ros.launch.supervisor import LaunchError, Supervisor

    release = threading.Event()
    calls = []

    def answer(request, response):
        calls.append(1)
        if len(calls) in (1, 3):
            release.wait(60.0)      # a lost response: not before the test ends
            response.message = 'lost'
        else:
            response.message = 'again'
        response.success = True
        return response

    server = Node('flaky_server', context=ros_context)
    server.create_service(Trigger, 'flaky', answer, callback_group=ReentrantCallbackGroup())
    executor = MultiThreadedExecutor(num_threads=3, context=ros_context)
    executor.add_node(server)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    ros = LaunchRos(load_problem('acrobot'))
    try:
        assert ros.trigger(Supervisor(), 'flaky', idempotent=True).message == 'again'
        assert len(calls) == 2
        with pytest.raises(LaunchError, match='timed out after 8 s waiting for the response'):
            ros.call(Supervisor(), Trigger, 'flaky', Trigger.Request(), timeout=8.0)
        assert len(calls) == 3          # sent once
    finally:
        release.set()
        ros.close()
        executor.shutdown()
        server.destroy_node()


def test_a_raising_callback_is_logged_in_one_line_and_the_node_goes_on(ros_context, capfd):
    """spin_guarded (every node's spin): a callback that raises is one error line; the other
    callbacks keep running."""
    node = Node('fragile', context=ros_context)
    ticks = []

    def boom() -> None:
        raise ValueError('boom\nsecond line')

    node.create_timer(0.01, boom)
    node.create_timer(0.01, lambda: ticks.append(1))
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    spinner = threading.Thread(target=spin_guarded, args=(executor, node.get_logger()),
                               daemon=True)
    spinner.start()
    wait(lambda: len(ticks) >= 20, 'the healthy timer to tick on')
    assert spinner.is_alive()
    executor.shutdown()
    node.destroy_node()
    err = capfd.readouterr().err
    failures = [line for line in err.splitlines() if 'callback failed' in line]
    assert failures and all(line.endswith('ValueError: boom second line') for line in failures)


def test_a_sim_waiting_for_a_missing_recorder_stops_with_one_line(tmp_path):
    """wait_for_recorder names a recorder that never answers: after recorder_timeout the sim
    exits 1 with one line saying so; no episode started, no traceback."""
    with ros_domain() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        done = subprocess.run([str(executable('acrobot_sim')), '--ros-args', '-p',
                               'mode:=lockstep', '-p', 'wait_for_recorder:=recorder_node',
                               '-p', 'recorder_timeout:=2.0'], env=env, capture_output=True,
                              text=True, timeout=60)
    errors = [line for line in done.stderr.splitlines()
              if line.startswith('acrobot_sim: error: ')]
    assert done.returncode == 1 and 'Traceback' not in done.stderr, done.stderr
    assert len(errors) == 1 and "recorder 'recorder_node' not ready after 2 s" in errors[0]
