"""The recorder node (sapga_ros/nodes/recorder_node.py) over real DDS: one rosbag2 bag per run.

The messages are published by a test node in this process; the recorder runs in this process
(round trip, QoS, readiness) or as a child process (hard kill, signals, bad parameters).
Every bag is read back by independent readers: rosbags' rosbag2 ``Reader`` and ``AnyReader``
on the directory, the ``mcap`` library's random-access reader and ``mcap_ros2``.
"""
from __future__ import annotations

import json
import os
import signal
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
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as RosbagsReader
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Int32, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from domains import ros_domain
from sapga_ros.recording.reader import decode_messages, read_recording
from sapga_ros.recording.schemas import SEPARATOR, message_definition, share_dirs

TIMEOUT = 20.0          # [s] upper bound of every wait; never asserted on
JOINTS = ['shoulder', 'elbow']
DEPTH = 500             # publisher history: reliable delivery of a burst without overwrites
VENV_BIN = Path(sys.executable).parent
EVENT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)   # as the sim publishes


@pytest.fixture(scope='module')
def ros_env():
    """A domain of its own and localhost-only discovery, for this process and children."""
    with ros_domain() as domain, pytest.MonkeyPatch.context() as patch:
        patch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        patch.setenv('ROS_DOMAIN_ID', str(domain))
        yield dict(os.environ)


@pytest.fixture(scope='module')
def context(ros_env):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    yield ctx
    rclpy.try_shutdown(context=ctx)


class Publisher:
    """A test node publishing the acrobot's topics with the simulator's QoS."""

    def __init__(self, context: Context, event_qos: QoSProfile = EVENT_QOS,
                 name: str = 'recording_test_publisher') -> None:
        self.node = Node(name, context=context)
        self.pubs = {
            'state': self.node.create_publisher(JointState, 'joint_states', DEPTH),
            'command': self.node.create_publisher(Float64, 'command', DEPTH),
            'reward': self.node.create_publisher(Float64, 'reward', DEPTH),
            'event': self.node.create_publisher(String, 'episode_event', event_qos),
            'exemplar': self.node.create_publisher(Int32, 'exemplar_index', DEPTH),
            'command_stamped': self.node.create_publisher(JointState, 'command_stamped', DEPTH),
            'markers': self.node.create_publisher(MarkerArray, 'markers', DEPTH),
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

    def ready(self, service: str = '/recorder_node/ready') -> Trigger.Response:
        """The recorder's answer to its readiness service."""
        client = self.node.create_client(Trigger, service)
        try:
            self.spin_until(client.service_is_ready, service)
            future = client.call_async(Trigger.Request())
            self.spin_until(future.done, f'the answer of {service}')
            return future.result()
        finally:
            self.node.destroy_client(client)

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


def event(kind: str, episode, step: int = 0) -> String:
    return String(data=json.dumps({'event': kind, 'episode': episode, 'step': step}))


def episode_messages(n_steps: int, episode: int = 1) -> list[tuple[str, object]]:
    """(role, message) of one short episode, in publishing order."""
    out: list[tuple[str, object]] = [('event', event('start', episode))]
    for k in range(n_steps):
        out.append(('state', joint_state(k)))
        out.append(('command', Float64(data=(-2.0, 0.0, 2.0)[k % 3])))
        out.append(('exemplar', Int32(data=k % 7)))
        out.append(('reward', Float64(data=-3.0 + 0.01 * k)))
    out.append(('event', event('step_limit', episode, n_steps)))
    return out


def fields(msg: object) -> dict:
    """The comparable field values of a published or decoded message (rclpy, mcap_ros2 or
    rosbags)."""
    if hasattr(msg, 'header'):
        return {'stamp': (msg.header.stamp.sec, msg.header.stamp.nanosec),
                'frame_id': msg.header.frame_id, 'name': list(msg.name),
                'position': list(msg.position), 'velocity': list(msg.velocity),
                'effort': list(msg.effort)}
    return {'data': msg.data}


def record(context, out: Path, messages, **params) -> tuple[Path, list]:
    """Run an in-process recorder over ``messages`` (each waited for); (bag, published)."""
    from sapga_ros.nodes.recorder_node import RecorderNode

    overrides = [Parameter('output_dir', value=str(out)), Parameter('chunk_size', value=1024),
                 Parameter('flush_period', value=0.0)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    recorder = RecorderNode(context=context, parameter_overrides=overrides)
    pub = Publisher(context)
    pub.executor.add_node(recorder)
    published = []
    try:
        pub.wait_matched()
        for role, msg in messages:
            pub.pubs[role].publish(msg)
            published.append((pub.pubs[role].topic_name, msg))
            pub.spin_until(lambda: recorder.message_count == len(published),
                           f'message {len(published)} to be recorded')
    finally:
        pub.executor.remove_node(recorder)
        recorder.destroy_node()
        pub.close()
    (bag,) = [p for p in out.iterdir() if p.is_dir()]
    return bag, published


@pytest.fixture(scope='module')
def recorded(context, tmp_path_factory):
    """A bag made by an in-process RecorderNode of one published episode."""
    return record(context, tmp_path_factory.mktemp('recorded'), episode_messages(40))


def test_the_bag_is_a_rosbag2_directory(recorded):
    """metadata.yaml (rosbag2 version 9, storage mcap) and <bag>_0.mcap, as rosbag2 lays out."""
    bag, published = recorded
    names = sorted(['metadata.yaml', f'{bag.name}_0.mcap'])
    assert sorted(p.name for p in bag.iterdir()) == names
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == [f'{bag.name}_0.mcap']
    assert info['message_count'] == len(published) == info['files'][0]['message_count']
    assert info['ros_distro'] == 'jazzy' and info['compression_mode'] == ''
    assert info['custom_data']['problem'] == 'acrobot'
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/episode_event': 2, '/joint_states': 40, '/command': 40,
                      '/exemplar_index': 40, '/reward': 40}
    for topic in info['topics_with_message_count']:
        meta = topic['topic_metadata']
        assert meta['serialization_format'] == 'cdr'
        assert meta['type_description_hash'].startswith('RIHS01_')
        (offer,) = meta['offered_qos_profiles']
        assert offer['reliability'] == 'reliable'      # history: as the graph says (unknown)
        assert offer['durability'] == ('transient_local' if meta['name'] == '/episode_event'
                                       else 'volatile')


def test_rosbags_reads_the_directory_and_decodes_every_message(recorded):
    """rosbags' rosbag2 Reader and AnyReader open the bag directory; every message decodes
    to what was published, in order."""
    bag, published = recorded
    with RosbagsReader(bag) as reader:
        assert reader.message_count == len(published)
        assert sum(1 for _ in reader.messages()) == len(published)
    with AnyReader([bag]) as reader:
        got = [(c.topic, fields(reader.deserialize(raw, c.msgtype)))
               for c, _, raw in reader.messages()]
    assert got == [(topic, fields(msg)) for topic, msg in published]


def test_mcap_random_access_reader_decodes_every_message_in_order(recorded):
    """mcap's make_reader and the mcap_ros2 decoder read exactly the published messages."""
    bag, published = recorded
    with open(bag / f'{bag.name}_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        got = [(channel.topic, fields(decoded))
               for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=False)]
    assert got == [(topic, fields(msg)) for topic, msg in published]


def test_storage_file_follows_the_mcap_plugin(recorded):
    """Profile ros2, a rosbag2 metadata record, ros2msg schemas named pkg/msg/Type, cdr
    channels with offered_qos_profiles and topic_type_hash, as rosbag2's plugin writes."""
    bag, published = recorded
    with open(bag / f'{bag.name}_0.mcap', 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert summary.statistics.message_count == len(published) and summary.chunk_indexes
    stored = yaml.safe_load(records['rosbag2']['serialized_metadata'])
    assert stored['version'] == 9 and stored['message_count'] == len(published)
    assert {s.name for s in summary.schemas.values()} == {
        'sensor_msgs/msg/JointState', 'std_msgs/msg/Float64', 'std_msgs/msg/String',
        'std_msgs/msg/Int32'}
    assert all(s.encoding == 'ros2msg' for s in summary.schemas.values())
    for channel in summary.channels.values():
        assert channel.message_encoding == 'cdr'
        offered = yaml.safe_load(channel.metadata['offered_qos_profiles'])
        assert isinstance(offered, list) and offered[0]['reliability'] == 'reliable'
        assert offered[0]['deadline'] == {'sec': 9223372036, 'nsec': 854775807}
        assert channel.metadata['topic_type_hash'].startswith('RIHS01_')


def test_schema_holds_the_complete_definition_with_dependencies(recorded):
    """The JointState schema carries Header and Time after 80-'=' separators."""
    bag, _ = recorded
    with open(bag / f'{bag.name}_0.mcap', 'rb') as f:
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
    bag, published = recorded
    rec = read_recording(bag)
    for msg, (_, sent) in zip(rec.messages, published):
        assert msg.log_time > 1_000_000_000 * 1_000_000_000     # a wall clock, after 2001
        if msg.topic == '/joint_states':
            stamp = sent.header.stamp
            assert msg.publish_time == stamp.sec * 1_000_000_000 + stamp.nanosec


def test_episode_split_makes_one_bag_of_one_file_per_episode(context, tmp_path):
    """split:=episode starts a new storage file of the same bag at each start event, named
    <bag>_<i>.mcap; readers see one bag; a 300-digit episode number is just metadata, a
    deeply nested event just a message."""
    huge = int('9' * 300)
    nested = ('event', String(data='[' * 100_000 + ']' * 100_000))
    messages = (episode_messages(3, 1) + [nested] + episode_messages(4, 2)
                + episode_messages(2, huge))
    bag, published = record(context, tmp_path, messages, split='episode')
    names = [f'{bag.name}_{i}.mcap' for i in range(3)]
    assert sorted(p.name for p in bag.iterdir()) == sorted(names + ['metadata.yaml'])
    with AnyReader([bag]) as reader:
        got = [(c.topic, fields(reader.deserialize(raw, c.msgtype)))
               for c, _, raw in reader.messages()]
    assert got == [(topic, fields(msg)) for topic, msg in published]
    rec = read_recording(bag)
    assert rec.complete and [f.metadata['sapga']['episode'] for f in rec.files] == [
        '1', '2', str(huge)]
    for path in names:      # each file opens with its start event and stands alone
        with open(bag / path, 'rb') as f:
            first = next(make_reader(f).iter_messages(log_time_order=False))[1]
        assert first.topic == '/episode_event'


def test_transient_local_events_published_before_the_recorder_starts_are_recorded(
        context, tmp_path):
    """The recorder subscribes to episode_event transient local, as the sim publishes it:
    events published before the recorder existed reach the bag."""
    from sapga_ros.nodes.recorder_node import RecorderNode

    pub = Publisher(context, name='early_publisher')
    early = [event('start', 1), event('step_limit', 1, 5)]
    for msg in early:
        pub.pubs['event'].publish(msg)
    recorder = RecorderNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path)), Parameter('flush_period', value=0.0)])
    pub.executor.add_node(recorder)
    try:
        pub.spin_until(lambda: recorder.message_count == 2, 'the earlier events')
    finally:
        pub.executor.remove_node(recorder)
        recorder.destroy_node()
        pub.close()
    decoded, _ = decode_messages(read_recording(recorder.bag_path))
    assert [m.value.data for m in decoded] == [m.data for m in early]


def test_a_volatile_publisher_is_matched_by_adapting_the_subscription(context, tmp_path):
    """A volatile episode_event publisher (not the sim's QoS) is matched too: the recorder
    subscribes again as rosbag2 does, and records it."""
    from sapga_ros.nodes.recorder_node import RecorderNode

    recorder = RecorderNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path)), Parameter('flush_period', value=0.0)])
    pub = Publisher(context, event_qos=QoSProfile(depth=10), name='volatile_publisher')
    pub.executor.add_node(recorder)
    try:
        pub.wait_matched(['event'])
        pub.pubs['event'].publish(event('start', 7))
        pub.spin_until(lambda: recorder.message_count == 1, 'the volatile event')
    finally:
        pub.executor.remove_node(recorder)
        recorder.destroy_node()
        pub.close()
    (offer,) = read_recording(recorder.bag_path).bag_metadata[
        'topics_with_message_count'][0]['topic_metadata']['offered_qos_profiles']
    assert offer['durability'] == 'volatile'


def test_ready_says_what_is_missing_until_every_publisher_is_matched(context, tmp_path):
    """~/ready fails, naming the topics, until each recorded topic's publishers are matched;
    the hand-use command topic needs no publisher."""
    from sapga_ros.nodes.recorder_node import RecorderNode

    recorder = RecorderNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path))])
    probe = Publisher(context, name='probe')
    probe.executor.add_node(recorder)
    try:
        for role in list(probe.pubs):       # a node with no publishers yet
            probe.node.destroy_publisher(probe.pubs.pop(role))
        answer = probe.ready()
        assert not answer.success and '/joint_states' in answer.message
        assert '/command_stamped (' in answer.message and '/command (' not in answer.message
        full = Publisher(context, name='all_topics')
        full.node.destroy_publisher(full.pubs.pop('command'))
        probe.executor.add_node(full.node)
        probe.spin_until(lambda: probe.ready().success, 'the recorder to be ready')
        assert 'recording 7 topics' in probe.ready().message
        probe.executor.remove_node(full.node)
        full.close()
    finally:
        probe.executor.remove_node(recorder)
        recorder.destroy_node()
        probe.close()


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


def start_recorder(out: Path, env: dict, *params: str) -> subprocess.Popen:
    exe = VENV_BIN / 'recorder_node'
    cmd = ([str(exe)] if exe.exists()
           else [sys.executable, '-m', 'sapga_ros.nodes.recorder_node'])
    args = ['--ros-args', '-p', f'output_dir:={out}', '-p', 'bag:=bag']
    for p in params:
        args += ['-p', p]
    with open(out / 'recorder.log', 'wb') as log:
        return subprocess.Popen(cmd + args, env=env, stdout=log, stderr=subprocess.STDOUT)


def wait_until(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT
    while not condition():
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        time.sleep(0.05)


def read_count(bag: Path) -> int:
    try:
        return len(read_recording(bag).messages)
    except Exception:  # noqa: BLE001 - not on disk yet
        return 0


def stream_count(path: Path) -> int:
    """Messages mcap's streaming reader yields before the file ends."""
    n = 0
    with open(path, 'rb') as f:
        try:
            for _ in NonSeekingReader(f).iter_messages(log_time_order=False):
                n += 1
        except McapLibError:
            pass            # the stream ends without a footer
    return n


def test_hard_kill_loses_nothing_flushed_and_reindex_completes_the_bag(
        context, ros_env, tmp_path):
    """Messages a SIGKILLed recorder had flushed (its flush timer closes a chunk every
    second) survive; `sapga bag reindex` makes the bag whole: mcap's random-access reader
    yields every message its streaming reader yields, rosbags reads the directory."""
    proc = start_recorder(tmp_path, ros_env, 'flush_period:=1.0')
    pub = Publisher(context, name='kill_publisher')
    n = 400
    bag = tmp_path / 'bag'
    try:
        pub.wait_matched(['state'])
        for k in range(n):
            pub.pubs['state'].publish(joint_state(k))
            pub.executor.spin_once(timeout_sec=0.001)
        pub.spin_until(lambda: read_count(bag) == n, 'the flush timer to write every state')
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
        pub.close()
    storage = bag / 'bag_0.mcap'
    assert not (bag / 'metadata.yaml').exists()
    rec = read_recording(bag)
    assert not rec.complete and 'sapga bag reindex' in rec.error and len(rec.messages) == n
    assert 'no footer' in rec.files[0].error
    streamed = stream_count(storage)
    assert streamed == n
    done = subprocess.run([str(VENV_BIN / 'sapga'), 'bag', 'reindex', str(bag)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert 'repaired bag_0.mcap' in done.stdout
    with open(storage, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = [fields(m) for _, _, _, m in reader.iter_decoded_messages()]
    assert decoded == [fields(joint_state(k)) for k in range(streamed)]
    with RosbagsReader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == n
    assert read_recording(bag).complete


def test_a_topic_published_with_another_type_is_recorded_as_published(
        context, ros_env, tmp_path):
    """The problem says command is std_msgs/Float64; a publisher of another type on it is
    recorded with its own type (schema and all), not missed."""
    from std_msgs.msg import Float32

    proc = start_recorder(tmp_path, ros_env, 'flush_period:=0.1')
    node = Node('float32_publisher', context=context)
    pub = node.create_publisher(Float32, 'command', DEPTH)
    bag = tmp_path / 'bag'
    try:
        wait_until(lambda: pub.get_subscription_count() >= 1, 'a Float32 subscription')
        pub.publish(Float32(data=1.5))
        wait_until(lambda: read_count(bag) == 1, 'the Float32 command on disk')
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=TIMEOUT) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        node.destroy_node()
    rec = read_recording(bag)
    assert rec.topics['/command'].type == 'std_msgs/msg/Float32'
    assert [m.value.data for m in decode_messages(rec)[0]] == [1.5]


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_ctrl_c_finish_the_bag(tmp_path, sig):
    """SIGTERM or Ctrl-C makes the recorder finish the bag (footer, metadata.yaml), exit 0.
    In a domain of its own: it counts every message of the bag, so nothing of another test
    (a transient-local event, a node still shutting down) may reach its recorder."""
    with ros_domain() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        ctx = Context()
        rclpy.init(context=ctx, domain_id=domain)
        try:
            _record_then_signal(ctx, env, tmp_path, sig)
        finally:
            rclpy.try_shutdown(context=ctx)


def _record_then_signal(context, ros_env, tmp_path, sig) -> None:
    proc = start_recorder(tmp_path, ros_env, 'flush_period:=0.1')
    pub = Publisher(context, name=f'signal_publisher_{sig}')
    n = 50
    bag = tmp_path / 'bag'
    try:
        pub.wait_matched(['state', 'event'])
        pub.pubs['event'].publish(event('start', 0))
        for k in range(n):
            pub.pubs['state'].publish(joint_state(k))
            pub.executor.spin_once(timeout_sec=0.001)
        pub.spin_until(lambda: read_count(bag) == n + 1, 'every message to be flushed')
        proc.send_signal(sig)
        assert proc.wait(timeout=TIMEOUT) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        pub.close()
    rec = read_recording(bag)
    assert rec.complete and rec.error is None and len(rec.messages) == n + 1
    with RosbagsReader(bag) as reader:
        assert reader.message_count == n + 1


@pytest.mark.parametrize('param, what', [
    ('chunk_size:=abc', 'chunk_size'),
    ('flush_period:=nan', 'flush_period'),
    ('split:=hour', 'split'),
    ('bag:=../escape', 'bag'),
    ('chunk_size:=1073741824', 'chunk_size'),
    ('output_dir:=/dev/null', '/dev/null: a device, not a directory'),
])
def test_bad_parameters_give_one_line_and_exit_2(ros_env, tmp_path, param, what):
    """A wrongly typed or out-of-range parameter: one line naming it, exit 2, no traceback."""
    done = subprocess.run([str(VENV_BIN / 'recorder_node'), '--ros-args', '-p',
                           f'output_dir:={tmp_path}', '-p', param], env=ros_env,
                          capture_output=True, text=True, timeout=60)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and 'Traceback' not in done.stderr, done.stderr
    assert len(lines) == 1 and lines[0].startswith('recorder_node: error: ') and what in lines[0]
