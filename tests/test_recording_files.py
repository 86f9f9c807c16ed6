"""Recording files without a ROS graph: the bag writer, the bounded reader, reindexing.

Bags are written with ``recording/writer.py`` and ``session.py`` from CDR bytes; hostile files
(decompression bombs, FIFOs, nested YAML, cut files) are made here byte by byte.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import zlib
from pathlib import Path

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Chunk, Header, Message, Schema
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_typestore

from process_helpers import sapga_peak_rss
from sapga_ros.errors import McapError
from sapga_ros.recording.metadata import TopicInfo, qos_profile
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.repair import reindex
from sapga_ros.recording.schemas import type_hash
from sapga_ros.recording.session import RecordingSession
from sapga_ros.recording.writer import BagWriter

TYPES = get_typestore(Stores.ROS2_JAZZY)
MAGIC = b'\x89MCAP0\r\n'
T0 = 1_700_000_000_000_000_000


def cdr_float(x: float) -> bytes:
    return bytes(TYPES.serialize_cdr(TYPES.types['std_msgs/msg/Float64'](x),
                                     'std_msgs/msg/Float64'))


def cdr_string(text: str) -> bytes:
    return bytes(TYPES.serialize_cdr(TYPES.types['std_msgs/msg/String'](text),
                                     'std_msgs/msg/String'))


def topics() -> list[TopicInfo]:
    return [TopicInfo('/reward', 'std_msgs/msg/Float64', [qos_profile(depth=1000)],
                      type_hash('std_msgs/msg/Float64')),
            TopicInfo('/episode_event', 'std_msgs/msg/String',
                      [qos_profile(depth=10, durability='transient_local')],
                      type_hash('std_msgs/msg/String'))]


def write_episodes(bag: Path, episodes: int, steps: int, split: str = 'run',
                   **kwargs) -> RecordingSession:
    """A session of ``episodes`` episodes of ``steps`` rewards each, not closed."""
    session = RecordingSession(bag, split=split, event_topic='/episode_event', **kwargs)
    for topic in topics():
        session.add_topic(topic)
    t = T0
    for ep in range(1, episodes + 1):
        for kind, n in (('start', 0), (None, steps), ('goal', steps)):
            if kind:
                session.write('/episode_event', cdr_string(json.dumps(
                    {'event': kind, 'episode': ep, 'step': n})), t, t)
                t += 1
            else:
                for k in range(n):
                    session.write('/reward', cdr_float(-1.0 - k), t, t + 7)
                    t += 1
    return session


def rosbags_count(bag: Path) -> int:
    with RosbagsReader(bag) as reader:
        return sum(1 for _ in reader.messages())


def test_episode_split_makes_one_bag_that_readers_open_whole(tmp_path):
    """split='episode': <bag>_0..2.mcap + metadata.yaml; rosbags reads all messages once."""
    session = write_episodes(tmp_path / 'b', 3, 5, split='episode', chunk_size=256)
    session.close()
    assert sorted(p.name for p in (tmp_path / 'b').iterdir()) == [
        'b_0.mcap', 'b_1.mcap', 'b_2.mcap', 'metadata.yaml']
    assert rosbags_count(tmp_path / 'b') == 3 * 7
    rec = read_recording(tmp_path / 'b')
    assert rec.complete and len(rec.files) == 3 and len(rec.messages) == 21
    assert [f.metadata['sapga']['episode'] for f in rec.files] == ['1', '2', '3']
    assert [m.publish_time - m.log_time for m in rec.messages if m.topic == '/reward'] == \
        [7] * 15


def test_the_gap_check_names_what_a_bag_lacks(tmp_path):
    """recording_gaps (what a launch checks before it reports) counts events, rewards,
    states and commands against the episodes' end events."""
    from sapga_ros.recording.verify import recording_gaps

    session = write_episodes(tmp_path / 'b', 2, 5)
    session.close()
    rec = read_recording(tmp_path / 'b')
    ends = [{'event': 'goal', 'step': 5}] * 2
    roles = {'event': '/episode_event', 'reward': '/reward', 'state': '/joint_states',
             'command': '/command'}
    assert recording_gaps(rec, roles, ends, lockstep=False) == ['0 of 12 states']
    del rec.messages[3]         # a reward
    assert recording_gaps(rec, roles, ends) == ['9 of 10 rewards', '0 of 12 states',
                                                '0 of 11 commands']
    assert recording_gaps(rec, roles, ends[:1] * 3)[0] == '2 of 3 start events'


def test_bag_reindex_command_reports_and_refuses_in_one_line(tmp_path, capsys):
    """`sapga bag reindex`: what it did on stdout; a path that is no recording: one line,
    exit 2."""
    from sapga_ros.cli import main as cli

    write_episodes(tmp_path / 'b', 1, 3).close()
    assert cli.main(['bag', 'reindex', str(tmp_path / 'b')]) == 0
    assert capsys.readouterr().out == (f'{tmp_path / "b"}: every storage file was complete; '
                                       'wrote metadata.yaml; 5 messages\n')
    for bad in (tmp_path / 'nope', tmp_path):
        assert cli.main(['bag', 'reindex', str(bad)]) == 2
        err = capsys.readouterr().err
        assert err.startswith('sapga bag: error: ') and err.count('\n') == 1 and str(bad) in err


def test_a_bag_is_never_overwritten(tmp_path):
    """An existing directory is refused, as rosbag2 refuses it."""
    (tmp_path / 'b').mkdir()
    (tmp_path / 'b' / 'precious').write_text('x')
    with pytest.raises(McapError, match='exists already'):
        BagWriter(tmp_path / 'b')
    assert (tmp_path / 'b' / 'precious').read_text() == 'x'


def test_writer_rejects_bad_options(tmp_path):
    """Unknown compression or split modes are refused with a typed error."""
    with pytest.raises(McapError, match='compression'):
        RecordingSession(tmp_path / 'a', compression='gzip')
    with pytest.raises(McapError, match='split'):
        RecordingSession(tmp_path / 'b', split='hour')
    with pytest.raises(McapError, match='chunk_size'):
        BagWriter(tmp_path / 'c', chunk_size=0)


def killed_bag(tmp_path: Path, split: str) -> Path:
    """A bag whose writer process was SIGKILLed after flushing (no footer, no metadata)."""
    code = f"""
import os, signal, sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
from test_recording_files import write_episodes
s = write_episodes({str(tmp_path / "k")!r}, 3, 40, split={split!r}, chunk_size=512)
s.flush()
s.write('/reward', b'\\x00\\x01\\x00\\x00' + bytes(8), 1, 1)   # in memory only: lost
os.kill(os.getpid(), signal.SIGKILL)
"""
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, timeout=60)
    assert done.returncode == -9, done.stderr.decode()
    return tmp_path / 'k'


def streamed(path: Path) -> list[tuple[int, bytes]]:
    out = []
    with open(path, 'rb') as f:
        try:
            for _, _, m in NonSeekingReader(f).iter_messages(log_time_order=False):
                out.append((m.log_time, m.data))
        except Exception:  # noqa: BLE001 - the stream ends without a footer
            pass
    return out


@pytest.mark.parametrize('split', ['run', 'episode'])
def test_reindex_makes_a_killed_bag_whole(tmp_path, split):
    """After SIGKILL, `reindex` rewrites the unfinished file: mcap's random-access reader
    yields every message the streaming reader yields, metadata.yaml lists every file,
    rosbags reads the directory; a second reindex changes nothing."""
    bag = killed_bag(tmp_path, split)
    assert not (bag / 'metadata.yaml').exists()
    files = sorted(bag.glob('*.mcap'))
    before = {p.name: streamed(p) for p in files}
    assert sum(map(len, before.values())) == 3 * 42     # every flushed message, no more
    result = reindex(bag)
    assert result.repaired == [files[-1]] and result.messages == 3 * 42
    for p in files:
        with open(p, 'rb') as f:
            reader = make_reader(f)
            got = [(m.log_time, m.data) for _, _, m in reader.iter_messages(
                log_time_order=False)]
            assert reader.get_summary() is not None
        assert got == before[p.name]
    assert rosbags_count(bag) == 3 * 42
    rec = read_recording(bag)
    assert rec.complete and rec.metadata['split'] == split
    assert reindex(bag).repaired == []


def test_reindex_repairs_a_single_cut_file(tmp_path):
    """A storage file cut mid-way is rewritten complete in place, keeping what was whole."""
    session = write_episodes(tmp_path / 'b', 2, 50, chunk_size=300)
    session.close()
    path = tmp_path / 'b' / 'b_0.mcap'
    data = path.read_bytes()
    path.write_bytes(data[:len(data) * 2 // 5])
    before = streamed(path)
    assert 0 < len(before) < 104
    assert reindex(path).repaired == [path]
    with open(path, 'rb') as f:
        assert [(m.log_time, m.data) for _, _, m in make_reader(f).iter_messages(
            log_time_order=False)] == before


def bomb(path: Path, size: int = 1 << 30) -> Path:
    """An MCAP file of 33 KB whose one chunk expands to ``size`` bytes of zeros."""
    squeeze = zstandard.ZstdCompressor(level=3).compressobj()
    block = bytes(1 << 20)
    data = b''.join(squeeze.compress(block) for _ in range(size >> 20)) + squeeze.flush()
    b = RecordBuilder()
    Header(profile='ros2', library='bomb').write(b)
    Chunk(compression='zstd', data=data, message_start_time=0, message_end_time=0,
          uncompressed_crc=0, uncompressed_size=size).write(b)
    path.write_bytes(MAGIC + b.end())
    return path


def message_chunks(path: Path, chunks: int, per_chunk: int) -> Path:
    """Small zstd chunks of many small messages: a 'message bomb' within each chunk's limit."""
    b = RecordBuilder()
    Header(profile='ros2', library='bomb').write(b)
    Schema(id=1, name='std_msgs/msg/Float64', encoding='ros2msg', data=b'float64 data').write(b)
    Channel(id=1, topic='/x', message_encoding='cdr', schema_id=1, metadata={}).write(b)
    inner = RecordBuilder()
    for _ in range(per_chunk):
        Message(channel_id=1, log_time=0, publish_time=0, sequence=0,
                data=cdr_float(0.0)).write(inner)
    raw = inner.end()
    packed = zstandard.compress(raw, 3)         # 3000:1
    for _ in range(chunks):
        Chunk(compression='zstd', data=packed, message_start_time=0,
              message_end_time=per_chunk, uncompressed_crc=zlib.crc32(raw),
              uncompressed_size=len(raw)).write(b)
    path.write_bytes(MAGIC + b.end())
    return path


def max_rss_of_inspect(path: Path) -> tuple[int, str, int]:
    """(exit status, stderr, peak RSS [MiB]) of `sapga inspect PATH` in a fresh process."""
    return sapga_peak_rss(['inspect', str(path)])


def test_a_zstd_bomb_is_refused_before_it_expands(tmp_path):
    """A 33 KB chunk claiming 1 GiB is refused unopened: a one-line warning, a summary of
    what came before it (nothing), little memory."""
    path = bomb(tmp_path / 'bomb.mcap')
    assert path.stat().st_size < 40_000
    rc, err, rss_mib = max_rss_of_inspect(path)
    assert rc == 0 and err.count('\n') == 1 and 'decompression bomb' in err, err
    assert rss_mib < 400, rss_mib         # 1 GiB+ before the bound


def test_many_small_chunks_cannot_add_up_to_a_bomb(tmp_path):
    """Chunks each within the limit stop once what they expand to and the messages kept
    (each costing message_cost of its size) pass the budget: BUDGET_RATIO times the
    file plus BUDGET_FLOOR; the reading ends there with a warning, keeping what was read."""
    from sapga_ros.recording.chunks import BUDGET_FLOOR, BUDGET_RATIO, message_cost

    path = message_chunks(tmp_path / 'many.mcap', chunks=100, per_chunk=5_000)
    size = path.stat().st_size
    rec = read_recording(path)
    assert 'decompression bomb' in rec.error and not rec.complete
    assert 0 < len(rec.messages) * message_cost(12) <= BUDGET_FLOOR + BUDGET_RATIO * size


def test_a_fifo_is_refused_without_blocking(tmp_path):
    """A FIFO where a bag file or metadata.yaml should be: refused at once, never waited on."""
    bag = tmp_path / 'bag'
    write_episodes(bag, 1, 3).close()
    (bag / 'metadata.yaml').unlink()
    os.mkfifo(bag / 'metadata.yaml')
    fifo = tmp_path / 'f.mcap'
    os.mkfifo(fifo)
    result: dict = {}

    def read() -> None:
        result['bag'] = read_recording(bag)
        with pytest.raises(McapError, match='FIFO') as info:
            read_recording(fifo)
        result['fifo'] = str(info.value)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout=30)
    assert not reader.is_alive(), 'the reader blocked on a FIFO'
    assert len(result['bag'].messages) == 5 and 'FIFO' in result['bag'].error


@pytest.mark.parametrize('text, why', [
    ('[' * 100_000 + ']' * 100_000, 'nested deeper than 64'),
    ('a: &x [1, 2]\nb: *x\n', 'aliases'),
    ('rosbag2_bagfile_information: {relative_file_paths: 3}', 'relative_file_paths'),
    ('{' * 10, 'not YAML'),
    ('rosbag2_bagfile_information:\n  relative_file_paths: [bag_0.mcap, ./bag_0.mcap]\n',
     'twice'),
    ('#' * (2 << 20), 'larger than'),
])
def test_hostile_metadata_yaml_falls_back_on_the_storage_files(tmp_path, text, why):
    """A nested, aliased, mistyped, broken or oversized metadata.yaml, or one listing a file
    twice (its messages would count twice), is no metadata: the reading says why in one line
    and reads the storage files of the directory, each once."""
    bag = tmp_path / 'bag'
    write_episodes(bag, 2, 3).close()
    (bag / 'metadata.yaml').write_text(text)
    rec = read_recording(bag)
    assert len(rec.messages) == 10 and not rec.complete
    assert 'metadata.yaml' in rec.error and why in rec.error and '\n' not in rec.error
