"""A recording on a disk that fills up: never silent, and metadata.yaml counts what is there.

A real small filesystem (a 1 MiB tmpfs mounted for the test) fills while a bag is written:
every write that fails is reported, the writer resumes in a new storage file once space is
back, ``metadata.yaml`` counts what the files hold (checked with the ``mcap`` library's
streaming reader) and says ``incomplete``; the recorder node logs the failure at once and
exits with status 1.  Skipped only where a tmpfs cannot be mounted (not root, no
CAP_SYS_ADMIN).
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
import yaml
from rosbags.rosbag2 import Reader as RosbagsReader

from sapga_ros.errors import McapError
from sapga_ros.recording import writer
from sapga_ros.recording.metadata import TopicInfo, qos_profile
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.repair import reindex
from sapga_ros.recording.schemas import type_hash
from sapga_ros.recording.session import RecordingSession
from test_recording import stream_count
from test_recording_files import T0, cdr_string, topics

TIMEOUT = 30.0          # [s] upper bound of every wait; never asserted on


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs at tmp_path/disk, unmounted afterwards."""
    disk = tmp_path / 'disk'
    disk.mkdir()
    done = subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=1m', 'tmpfs', str(disk)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f'cannot mount a small tmpfs here: {done.stderr.strip() or done.returncode}')
    try:
        yield disk
    finally:
        subprocess.run(['umount', '-l', str(disk)], check=True)


def fill(disk: Path, leave: int) -> Path:
    """A file taking all of ``disk`` but ``leave`` bytes."""
    filler = disk / 'filler'
    with open(filler, 'wb', buffering=0) as f:
        try:
            while True:
                f.write(bytes(4096))
        except OSError:
            pass
    os.truncate(filler, max(0, filler.stat().st_size - leave))
    return filler


def blob(k: int) -> bytes:
    return cdr_string(os.urandom(150).hex() + str(k))      # incompressible


def test_a_full_disk_is_reported_resumed_and_counted(small_disk, monkeypatch):
    """Writes fail once the disk is full (each one says so); after space is freed the bag
    goes on in a new storage file; close raises, metadata.yaml counts what the streaming
    reader reads, says incomplete, and reindex completes every file."""
    monkeypatch.setattr(writer, 'RETRY_S', 0.0)
    filler = fill(small_disk, 200_000)
    bag = small_disk / 'bag'
    session = RecordingSession(bag, event_topic='/episode_event', chunk_size=4096)
    for topic in topics() + [TopicInfo('/blob', 'std_msgs/msg/String', [qos_profile()],
                                       type_hash('std_msgs/msg/String'))]:
        session.add_topic(topic)
    failed = after = 0
    for k in range(3000):
        try:
            session.write('/blob', blob(k), T0 + k, T0 + k)
            after += failed > 0
        except McapError as exc:
            assert 'No space left on device' in str(exc) or 'not recording' in str(exc)
            failed += 1
            if failed == 100:
                filler.unlink()             # space is back
    assert failed >= 100 and after > 0
    with pytest.raises(McapError, match='incomplete.*No space left on device'):
        session.close()
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    files = [bag / name for name in meta['relative_file_paths']]
    assert len(files) >= 2
    assert [f['message_count'] for f in meta['files']] == [stream_count(p) for p in files]
    held = meta['message_count']
    assert held < 3000 and 'incomplete' in meta['custom_data']
    assert f'{held} of 3000 messages written' in meta['custom_data']['incomplete']
    rec = read_recording(bag)
    assert not rec.complete and 'incomplete' in rec.error and len(rec.messages) == held
    result = reindex(bag)
    assert result.repaired and result.messages == held
    with RosbagsReader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == held


def start_recorder(out: Path, log: Path, env: dict) -> subprocess.Popen:
    exe = Path(sys.executable).parent / 'recorder_node'
    cmd = ([str(exe)] if exe.exists()
           else [sys.executable, '-m', 'sapga_ros.nodes.recorder_node'])
    args = ['--ros-args', '-p', f'output_dir:={out}', '-p', 'bag:=bag', '-p',
            'flush_period:=0.1', '-p', 'chunk_size:=4096']
    return subprocess.Popen(cmd + args, env=env, stdout=log.open('wb'),
                            stderr=subprocess.STDOUT)


def test_the_recorder_node_says_so_and_exits_1_when_the_disk_fills(small_disk, tmp_path):
    """Over DDS: the recorder logs the failed write at once, and after Ctrl-C writes
    metadata.yaml marked incomplete with what the file holds, and exits 1."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from std_msgs.msg import String

    from domains import claim_domain, release_domain

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=str(claim_domain()))
    filler = fill(small_disk, 100_000)
    log = tmp_path / 'recorder.log'
    proc = start_recorder(small_disk, log, env)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(env['ROS_DOMAIN_ID']))
    node = Node('disk_publisher', context=ctx)
    pub = node.create_publisher(String, 'episode_event', 1000)
    try:
        deadline = time.monotonic() + TIMEOUT
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < deadline, 'the recorder never subscribed'
            time.sleep(0.05)
        k = 0
        while 'CANNOT WRITE THE BAG' not in log.read_text():
            assert time.monotonic() < deadline, log.read_text()
            pub.publish(String(data=json.dumps({'event': 'note', 'pad': os.urandom(400).hex(),
                                                'k': k})))
            k += 1
            time.sleep(0.002)
        filler.unlink()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=TIMEOUT) == 1, log.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        release_domain(int(env['ROS_DOMAIN_ID']))
    text = log.read_text()
    assert 'Traceback' not in text and 'No space left on device' in text, text
    meta = yaml.safe_load((small_disk / 'bag' / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert 'incomplete' in info['custom_data']
    files = [small_disk / 'bag' / name for name in info['relative_file_paths']]
    assert info['message_count'] == sum(stream_count(p) for p in files) > 0


CUT_SHORT = """
import resource, signal, sys
from pathlib import Path
from sapga_ros.errors import McapError
from sapga_ros.recording.storage import StorageFile
from test_recording_files import topics
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)    # a write past the limit fails, EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[2]), int(sys.argv[2])))
f = StorageFile(Path(sys.argv[1]), 1000, 'none')
topic = topics()[0]
f.add_topic(topic)
k = 0
try:
    while True:
        f.write(topic.name, bytes(range(256)) * 3, k, k)
        k += 1
except McapError as exc:
    print(k, exc)
"""


@pytest.mark.parametrize('limit', [20_000, 20_333, 31_111])
def test_a_write_cut_short_leaves_the_file_on_a_record_boundary(tmp_path, limit):
    """A file-size limit cuts a chunk's write short, the next write fails: the part of the
    chunk that reached the file is cut off, so mcap's streaming reader reads every whole
    chunk and meets a clean end of file (it met a half record before)."""
    path = tmp_path / 'x.mcap'
    done = subprocess.run([sys.executable, '-c', CUT_SHORT, str(path), str(limit)],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, 'PYTHONPATH': os.pathsep.join(
                              [str(Path(__file__).parent), os.environ.get('PYTHONPATH', '')])})
    assert done.returncode == 0 and 'write failed' in done.stdout, done.stderr[-2000:]
    size = path.stat().st_size
    assert size < limit
    count = stream_count(path)          # raised struct.error on the half record before
    assert 0 < count <= int(done.stdout.split()[0])
