"""Tests of the MCAP recorder: sapga_ros.recording.mcap_io (core) and nodes.recorder_node.

The messages are published by a test node in this process; the recorder runs in this process
(round trip) or as a child process (hard kill, SIGTERM).  Every ROS test uses its own domain
and localhost-only discovery.
"""
from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rclpy
import yaml
from mcap.exceptions import McapError as McapLibError
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Int32, String

from sapga_ros.errors import McapError
from sapga_ros.recording.mcap_io import (SEPARATOR, ChannelInfo, McapRecordingWriter,
                                         RecordingSession, create_exclusive, message_definition,
                                         qos_profiles_yaml, read_recording, share_dirs)

TIMEOUT = 20.0          # [s] upper bound of every wait; never asserted on
JOINTS = ['shoulder', 'elbow']
DEPTH = 500             # publisher history: reliable delivery of a burst without overwrites
VENV_BIN = Path(sys.executable).parent


def free_domain_id() -> int:
    """A ROS domain whose Fast DDS discovery ports nobody on this host uses now."""
    rng = random.Random(os.getpid() ^ time.monotonic_ns())
    for _ in range(200):
        domain = rng.randint(1, 200)
        base = 7400 + 250 * domain          # RTPS port mapping: PB + DG * domain
        free = True
        for offset in (0, 1, 10, 11, 12, 13):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                try:
                    sock.bind(('', base + offset))
                except OSError:
                    free = False
        if free:
            return domain
    raise RuntimeError('no free ROS domain id')


@pytest.fixture(scope='module')
def ros_env():
    """A domain of its own and localhost-only discovery, for this process and children."""
    saved = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID')}
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(free_domain_id())
    yield dict(os.environ)
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture(scope='module')
def context(ros_env):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    yield ctx
    rclpy.try_shutdown(context=ctx)


class Publisher:
    """A test node publishing the acrobot's topics."""

    def __init__(self, context: Context) -> None:
        self.node = Node('recording_test_publisher', context=context)
        self.pubs = {
            'state': self.node.create_publisher(JointState, 'joint_states', DEPTH),
            'command': self.node.create_publisher(Float64, 'command', DEPTH),
            'reward': self.node.create_publisher(Float64, 'reward', DEPTH),
            'event': self.node.create_publisher(String, 'episode_event', DEPTH),
            'exemplar': self.node.create_publisher(Int32, 'exemplar_index', DEPTH),
        }
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)

    def spin_until(self, condition, what: str) -> None:
        deadline = time.monotonic() + TIMEOUT
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out waiting for {what}')
            self.executor.spin_once(timeout_sec=0.01)

    def wait_matched(self, roles=None) -> None:
        for role in roles or self.pubs:
            self.spin_until(lambda p=self.pubs[role]: p.get_subscription_count() >= 1,
                            f'the recorder to subscribe to {role}')

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def joint_state(k: int) -> JointState:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 50_000_000, 1_000_000_000)
    msg.header.frame_id = 'acrobot'
    msg.name = list(JOINTS)
    msg.position = [4.71 - 0.01 * k, 0.02 * k]
    msg.velocity = [0.1 * k, -0.1 * k]
    msg.effort = [0.0, 2.0 if k % 2 else -2.0]
    return msg


def episode_messages(n_steps: int) -> list[tuple[str, object]]:
    """(role, message) of one short episode, in publishing order."""
    out: list[tuple[str, object]] = [
        ('event', String(data=json.dumps({'event': 'start', 'episode': 0, 'step': 0})))]
    for k in range(n_steps):
        out.append(('state', joint_state(k)))
        out.append(('command', Float64(data=(-2.0, 0.0, 2.0)[k % 3])))
        out.append(('exemplar', Int32(data=k % 7)))
        out.append(('reward', Float64(data=-3.0 + 0.01 * k)))
    out.append(('event', String(data=json.dumps({'event': 'step_limit', 'episode': 0,
                                                 'step': n_steps}))))
    return out


def fields(msg: object) -> dict:
    """The comparable field values of a published or decoded message."""
    if hasattr(msg, 'header'):
        return {'stamp': (msg.header.stamp.sec, msg.header.stamp.nanosec),
                'frame_id': msg.header.frame_id, 'name': list(msg.name),
                'position': list(msg.position), 'velocity': list(msg.velocity),
                'effort': list(msg.effort)}
    return {'data': msg.data}


@pytest.fixture(scope='module')
def recorded(context, tmp_path_factory):
    """A recording made by an in-process RecorderNode of one published episode."""
    from sapga_ros.nodes.recorder_node import RecorderNode

    out = tmp_path_factory.mktemp('recorded')
    recorder = RecorderNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(out)), Parameter('chunk_size', value=1024),
        Parameter('flush_period', value=0.0)])
    pub = Publisher(context)
    pub.executor.add_node(recorder)
    published = []
    try:
        pub.wait_matched()
        for role, msg in episode_messages(40):
            pub.pubs[role].publish(msg)
            published.append((pub.pubs[role].topic_name, msg))
            pub.spin_until(lambda: recorder.message_count == len(published),
                           f'message {len(published)} to be recorded')
    finally:
        pub.executor.remove_node(recorder)
        recorder.destroy_node()
        pub.close()
    files = sorted(out.glob('*.mcap'))
    assert len(files) == 1
    return files[0], published


def test_independent_reader_reads_back_every_message_in_order(recorded):
    """An independent MCAP reader decodes exactly the published messages, in order."""
    path, published = recorded
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        got = [(channel.topic, fields(decoded))
               for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=False)]
    assert len(got) == len(published)
    assert got == [(topic, fields(msg)) for topic, msg in published]


def test_file_follows_the_ros2_profile(recorded):
    """Profile ros2, ros2msg schemas named pkg/msg/Type, cdr channels with QoS metadata."""
    path, published = recorded
    with open(path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
    assert summary is not None and summary.statistics.message_count == len(published)
    assert {s.name for s in summary.schemas.values()} == {
        'sensor_msgs/msg/JointState', 'std_msgs/msg/Float64', 'std_msgs/msg/String',
        'std_msgs/msg/Int32'}
    assert all(s.encoding == 'ros2msg' for s in summary.schemas.values())
    assert {c.topic for c in summary.channels.values()} == {
        '/joint_states', '/command', '/reward', '/episode_event', '/exemplar_index'}
    for channel in summary.channels.values():
        assert channel.message_encoding == 'cdr'
        offered = yaml.safe_load(channel.metadata['offered_qos_profiles'])
        assert isinstance(offered, list) and offered[0]['reliability'] == 'reliable'
        assert offered[0]['deadline'] == {'sec': 9223372036, 'nsec': 854775807}
        assert channel.metadata['topic_type_hash'].startswith('RIHS01_')


def test_schema_holds_the_complete_definition_with_dependencies(recorded):
    """The JointState schema carries Header and Time after 80-'=' separators."""
    path, _ = recorded
    with open(path, 'rb') as f:
        schemas = make_reader(f).get_summary().schemas.values()
    text = next(s for s in schemas if s.name == 'sensor_msgs/msg/JointState').data.decode()
    assert text.startswith(read_msg('sensor_msgs', 'JointState'))
    assert f'\n{SEPARATOR}\nMSG: std_msgs/Header\n' in text
    assert f'\n{SEPARATOR}\nMSG: builtin_interfaces/Time\n' in text
    assert text.count(SEPARATOR) == 2


def read_msg(pkg: str, name: str) -> str:
    for share in share_dirs():
        path = share / pkg / 'msg' / f'{name}.msg'
        if path.is_file():
            return path.read_text(encoding='utf-8')
    raise FileNotFoundError(f'{pkg}/msg/{name}.msg')


def test_message_definition_has_rosbag2_form():
    """The complete definition is the .msg text, then each dependency, as rosbag2 writes it."""
    expected = (read_msg('sensor_msgs', 'JointState')
                + f'\n{SEPARATOR}\nMSG: std_msgs/Header\n' + read_msg('std_msgs', 'Header')
                + f'\n{SEPARATOR}\nMSG: builtin_interfaces/Time\n'
                + read_msg('builtin_interfaces', 'Time'))
    assert message_definition('sensor_msgs/msg/JointState') == expected
    assert message_definition('std_msgs/Float64') == read_msg('std_msgs', 'Float64')


def test_times_are_receive_time_and_header_stamp(recorded):
    """log_time is the receive time; publish_time is header.stamp for JointState."""
    path, published = recorded
    rec = read_recording(path)
    topics = {c.id: c.topic for c in rec.channels.values()}
    for msg, (_, sent) in zip(rec.messages, published):
        assert msg.log_time > 1_000_000_000 * 1_000_000_000     # a wall clock, after 2001
        if topics[msg.channel_id] == '/joint_states':
            stamp = sent.header.stamp
            assert msg.publish_time == stamp.sec * 1_000_000_000 + stamp.nanosec


def test_inspect_summarises_the_recorder_file(recorded, capsys):
    """sapga inspect --json finds the recorded episode, its steps, return and actions."""
    from sapga_ros.recording.inspect import run_inspect

    path, published = recorded
    assert run_inspect(str(path), json_out=True) == 0
    summary = json.loads(capsys.readouterr().out)
    (episode,) = summary['episodes']
    commands = [m.data for topic, m in published if topic == '/command']
    rewards = [m.data for topic, m in published if topic == '/reward']
    assert episode['end'] == 'step_limit' and episode['steps'] == 40
    assert episode['reached_goal'] is False and episode['steps_to_goal'] is None
    assert episode['return'] == pytest.approx(sum(rewards))
    assert episode['actions'] == {'-2': commands.count(-2.0), '0': commands.count(0.0),
                                  '2': commands.count(2.0)}
    assert episode['messages']['states'] == 40


def test_params_file_configures_the_recorder(context, tmp_path):
    """msg_configs/params/recorder_node.yaml sets every recorder parameter, with its type."""
    from sapga_ros.nodes.recorder_node import RecorderNode

    path = Path(__file__).resolve().parents[1] / 'msg_configs' / 'params' / 'recorder_node.yaml'
    expected = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    node = RecorderNode(context=context, cli_args=[
        '--ros-args', '--params-file', str(path), '-p', f'output_dir:={tmp_path}'])
    try:
        for name, value in expected.items():
            got = node.get_parameter(name).value
            assert got == (str(tmp_path) if name == 'output_dir' else value), name
            assert type(got) is type(value), name
    finally:
        node.destroy_node()


def test_existing_files_are_never_overwritten(tmp_path):
    """A writer never opens an existing file: it picks the next free name."""
    (tmp_path / 'run.mcap').write_bytes(b'precious')
    with McapRecordingWriter.create(tmp_path, 'run') as writer:
        assert writer.path.name == 'run_1.mcap'
    path, f = create_exclusive(tmp_path, 'run')
    f.close()
    assert path.name == 'run_2.mcap'
    assert (tmp_path / 'run.mcap').read_bytes() == b'precious'


def cdr(msg: object) -> bytes:
    return serialize_message(msg)


def test_episode_split_writes_one_file_per_episode(tmp_path):
    """split='episode' starts a new file at each start event; split='run' keeps one file."""
    info = {role: ChannelInfo(topic, type_name, qos_profiles_yaml([{}])) for role, topic,
            type_name in (('state', '/joint_states', 'sensor_msgs/msg/JointState'),
                          ('event', '/episode_event', 'std_msgs/msg/String'))}
    for split, n_files in (('episode', 3), ('run', 1)):
        session = RecordingSession(tmp_path / split, 'acrobot', split=split,
                                   event_topic='/episode_event', chunk_size=512)
        t = 1
        for episode in range(3):
            for kind, steps in (('start', 0), (None, 5), ('goal', 5)):
                if kind:
                    ev = json.dumps({'event': kind, 'episode': episode, 'step': steps})
                    session.write(info['event'], cdr(String(data=ev)), t, t)
                    t += 1
                else:
                    for k in range(steps):
                        session.write(info['state'], cdr(joint_state(k)), t, t)
                        t += 1
        session.close()
        files = sorted((tmp_path / split).glob('*.mcap'))
        assert len(files) == n_files == len(session.paths)
        total = 0
        for path in files:
            rec = read_recording(path)
            assert rec.complete and rec.error is None
            assert rec.metadata['sapga']['split'] == split
            first = rec.channels[rec.messages[0].channel_id].topic
            assert first == '/episode_event'
            total += len(rec.messages)
        assert total == 3 * 7
    assert [p.name for p in sorted((tmp_path / 'episode').glob('*.mcap'))] == [
        'acrobot_ep0000.mcap', 'acrobot_ep0001.mcap', 'acrobot_ep0002.mcap']


def test_writer_rejects_bad_options(tmp_path):
    """Unknown compression or split modes are refused with a typed error."""
    with pytest.raises(McapError, match='compression'):
        RecordingSession(tmp_path, 'x', compression='gzip')
    with pytest.raises(McapError, match='split'):
        RecordingSession(tmp_path, 'x', split='hour')


def start_recorder(out: Path, env: dict, *params: str) -> subprocess.Popen:
    exe = VENV_BIN / 'recorder_node'
    cmd = ([str(exe)] if exe.exists()
           else [sys.executable, '-m', 'sapga_ros.nodes.recorder_node'])
    args = ['--ros-args', '-p', f'output_dir:={out}']
    for p in params:
        args += ['-p', p]
    with open(out / 'recorder.log', 'wb') as log:
        return subprocess.Popen(cmd + args, env=env, stdout=log, stderr=subprocess.STDOUT)


def read_count(out: Path) -> int:
    files = list(out.glob('*.mcap'))
    return len(read_recording(files[0]).messages) if files else 0


def test_hard_kill_keeps_every_complete_chunk(context, ros_env, tmp_path):
    """After SIGKILL the file reads (ours and mcap's streaming reader) up to its last chunk."""
    proc = start_recorder(tmp_path, ros_env, 'chunk_size:=2048', 'flush_period:=0.0')
    pub = Publisher(context)
    n = 400
    try:
        pub.wait_matched(['state'])
        for k in range(n):
            pub.pubs['state'].publish(joint_state(k))
            pub.executor.spin_once(timeout_sec=0.001)
        # at most one 2 KiB chunk (~12 JointStates) may still be in the recorder's memory
        pub.spin_until(lambda: read_count(tmp_path) >= n - 20, 'the chunks to reach the disk')
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
        pub.close()
    (path,) = tmp_path.glob('*.mcap')
    rec = read_recording(path)
    assert not rec.complete and 'no footer' in rec.error and str(path) in rec.error
    assert n - 20 <= len(rec.messages) <= n
    decoded = [fields(m) for m in decode_all(rec)]
    assert decoded == [fields(joint_state(k)) for k in range(len(decoded))]

    recovered = 0
    with open(path, 'rb') as f:
        try:
            for _ in NonSeekingReader(f).iter_messages(log_time_order=False):
                recovered += 1
        except McapLibError:
            pass            # the stream ends without a footer
    assert recovered == len(rec.messages)


def decode_all(rec):
    from sapga_ros.recording.mcap_io import decode_messages
    messages, failed = decode_messages(rec)
    assert not failed
    return [m.value for m in messages]


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_ctrl_c_finish_the_file(context, ros_env, tmp_path, sig):
    """SIGTERM or Ctrl-C makes the recorder write the summary and footer and exit 0."""
    proc = start_recorder(tmp_path, ros_env, 'flush_period:=0.1')
    pub = Publisher(context)
    n = 50
    try:
        pub.wait_matched(['state', 'event'])
        pub.pubs['event'].publish(String(data=json.dumps({'event': 'start', 'episode': 0})))
        for k in range(n):
            pub.pubs['state'].publish(joint_state(k))
            pub.executor.spin_once(timeout_sec=0.001)
        pub.spin_until(lambda: read_count(tmp_path) == n + 1, 'every message to be flushed')
        proc.send_signal(sig)
        assert proc.wait(timeout=TIMEOUT) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        pub.close()
    (path,) = tmp_path.glob('*.mcap')
    rec = read_recording(path)
    assert rec.complete and rec.error is None
    with open(path, 'rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == n + 1
    assert summary.chunk_indexes
