"""``sapga inspect`` of large valid recordings: every message is counted, however many, in
streamed passes (recording/inspect.py, cutter.py); episodes cut one at a time give the same
summary as cutting them all at once.

The files are written as rosbag2's compressed presets write them (zstd chunks, no message
indexes): a few bytes a message, so a bound on kept messages per file byte stopped early."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.writer import CompressionType, IndexType, Writer
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64, String

from sapga_ros.cli import main as cli
from sapga_ros.recording.cutter import build_episodes
from sapga_ros.recording.episodes import topic_roles
from sapga_ros.recording.reader import decode_messages, read_recording


def float_file(path: Path, n: int, events_every: int = 0) -> Path:
    """One MCAP file of ``n`` Float64 rewards (and, every ``events_every`` rewards, an
    episode's end and the next start on /episode_event)."""
    values = [serialize_message(Float64(data=float(v))) for v in range(4)]
    with open(path, 'wb') as f:
        w = Writer(f, chunk_size=4 << 20, compression=CompressionType.ZSTD,
                   index_types=IndexType.NONE)
        w.start(profile='ros2', library='test')
        s = w.register_schema('std_msgs/msg/Float64', 'ros2msg', b'float64 data')
        reward = w.register_channel('/reward', 'cdr', s)
        e = w.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        event = w.register_channel('/episode_event', 'cdr', e)
        t = 1_700_000_000_000_000_000
        episode = 0
        for i in range(n):
            t += 1_000_000
            if events_every and i % events_every == 0:
                if i:
                    w.add_message(event, t, serialize_message(String(data=json.dumps(
                        {'event': 'step_limit', 'episode': episode - 1}))), t)
                w.add_message(event, t, serialize_message(String(data=json.dumps(
                    {'event': 'start', 'episode': episode}))), t)
                episode += 1
            w.add_message(reward, t, values[i % 4], t)
        w.finish()
    return path


def inspect_json(capsys, path: Path) -> dict:
    assert cli.main(['inspect', str(path), '--json']) == 0
    out, err = capsys.readouterr()
    assert err == ''
    return json.loads(out)


def test_sixty_thousand_small_messages_are_all_counted(capsys, tmp_path):
    """60 000 Float64 messages in a 240 KB file: all counted, the summary complete."""
    summary = inspect_json(capsys, float_file(tmp_path / 'f.mcap', 60_000))
    assert summary['complete'] is True and summary['error'] is None
    assert summary['message_count'] == 60_000
    assert summary['topics'][0]['count'] == 60_000


def test_streamed_episodes_equal_the_episodes_cut_at_once(capsys, tmp_path):
    """The streamed summary's episodes are those of cutting every message at once."""
    path = float_file(tmp_path / 'e.mcap', 9_000, events_every=1_000)
    summary = inspect_json(capsys, path)
    rec = read_recording(path)
    roles = topic_roles(rec, None)
    episodes, bad = build_episodes(decode_messages(rec)[0], roles, None)
    assert len(summary['episodes']) == len(episodes) == 9 and bad == 0
    assert [e['messages']['rewards'] for e in summary['episodes']] == \
        [len(ep.rewards) for ep in episodes] == [1000] * 9
    assert [e['return_from_rewards'] for e in summary['episodes']] == \
        [sum(ep.rewards) for ep in episodes]


@pytest.mark.long
def test_a_million_small_messages_are_all_counted(capsys, tmp_path):
    """A million Float64 messages (4 MB on disk) in 200 episodes: every one counted."""
    summary = inspect_json(capsys, float_file(tmp_path / 'm.mcap', 1_000_000,
                                              events_every=5_000))
    assert summary['complete'] is True and summary['message_count'] == 1_000_000 + 399
    assert len(summary['episodes']) == 200
    assert all(e['messages']['rewards'] == 5_000 for e in summary['episodes'])
