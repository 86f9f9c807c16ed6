"""Limits every reader and writer of recordings share: chunk sizes, memory, paths.

- One chunk limit: the writer refuses a chunk_size or a message that could make a chunk
  the readers refuse, and a bag written at the limits reads back whole, also after reindex.
- Memory: an MCAP file of small messages packed 1000:1 takes ``sapga inspect`` to a bounded
  peak (measured in a fresh process against a small bag, in the same run), and so does a
  metadata.yaml of some megabytes.
- An output directory that is a device is named as one, not as "exists already".
"""
from __future__ import annotations

import zlib

import numpy as np
import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Header, Message, Schema
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from process_helpers import sapga_peak_rss
from sapga_ros.errors import McapError
from sapga_ros.recording.chunks import MAX_CHUNK_SIZE, MAX_MESSAGE_BYTES
from sapga_ros.recording.metadata import TopicInfo, qos_profile
from sapga_ros.recording.reader import read_recording
from sapga_ros.recording.repair import reindex
from sapga_ros.recording.schemas import message_definition, type_hash
from sapga_ros.recording.writer import BagWriter
from test_recording_files import MAGIC, TYPES, write_episodes

BLOB = TopicInfo('/blob', 'std_msgs/msg/String', [qos_profile()],
                 type_hash('std_msgs/msg/String'))


def test_the_writer_makes_no_chunk_a_reader_refuses(tmp_path):
    """chunk_size above the limit and messages above theirs are refused; a bag at both
    limits reads back whole, and a cut copy reindexes with every complete chunk."""
    with pytest.raises(McapError, match='chunk_size'):
        BagWriter(tmp_path / 'a', chunk_size=MAX_CHUNK_SIZE + 1)
    big = BagWriter(tmp_path / 'b', chunk_size=MAX_CHUNK_SIZE, compression='none')
    big.add_topic(BLOB)
    with pytest.raises(McapError, match='not recorded'):
        big.write('/blob', bytes(MAX_MESSAGE_BYTES + 1), 1, 1)
    sizes = [MAX_CHUNK_SIZE - 100, MAX_MESSAGE_BYTES, 1000, 2000]
    for k, n in enumerate(sizes):
        big.write('/blob', bytes([k]) * n, k + 1, k + 1)
    big.close()
    rec = read_recording(tmp_path / 'b')
    assert rec.complete and [len(m.data) for m in rec.messages] == sizes
    path = tmp_path / 'b' / 'b_0.mcap'
    with open(path, 'rb') as f:
        last = make_reader(f).get_summary().chunk_indexes[-1]
    end = last.chunk_start_offset + last.chunk_length + last.message_index_length
    with open(path, 'r+b') as f:
        f.truncate(end)         # a killed writer: no metadata records, summary, footer
    assert reindex(tmp_path / 'b').messages == len(sizes)
    with open(path, 'rb') as f:
        got = [len(m.data) for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert got == sizes


def packed_states(path, size: int) -> int:
    """An MCAP file of about ``size`` bytes: zstd chunks of 100 000 small JointStates; returns
    how many messages it holds."""
    js, header = TYPES.types['sensor_msgs/msg/JointState'], TYPES.types['std_msgs/msg/Header']
    stamp = TYPES.types['builtin_interfaces/msg/Time'](1, 2)
    cdr = bytes(TYPES.serialize_cdr(js(header(stamp, 'acrobot'), [], np.zeros(0),
                                       np.zeros(0), np.zeros(0)), 'sensor_msgs/msg/JointState'))
    inner = RecordBuilder()
    Schema(id=1, name='sensor_msgs/msg/JointState', encoding='ros2msg',
           data=message_definition('sensor_msgs/msg/JointState').encode()).write(inner)
    Channel(id=1, topic='/joint_states', message_encoding='cdr', schema_id=1,
            metadata={}).write(inner)
    for k in range(100_000):
        Message(channel_id=1, log_time=k, publish_time=k, sequence=0, data=cdr).write(inner)
    raw = inner.end()
    packed = zstandard.compress(raw, 9)
    b = RecordBuilder()
    Header(profile='ros2', library='packed').write(b)
    chunks = 0
    while b.count < size:
        Chunk(compression='zstd', data=packed, message_start_time=0, message_end_time=0,
              uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw)).write(b)
        chunks += 1
    path.write_bytes(MAGIC + b.end())
    return chunks * 100_000


def test_inspect_memory_is_bounded_by_the_file_size(tmp_path):
    """512 KiB of packed messages (200 000, each decoded by inspect) are all read, streamed,
    within 200 MiB above a small bag's peak; the file, without a
    footer, gets one warning."""
    write_episodes(tmp_path / 'small', 1, 5).close()
    count = packed_states(tmp_path / 'packed.mcap', 1 << 19)
    assert count >= 200_000
    rc, err, small = sapga_peak_rss(['inspect', str(tmp_path / 'small')])
    assert rc == 0, err
    rc, err, peak = sapga_peak_rss(['inspect', str(tmp_path / 'packed.mcap')])
    assert rc == 0 and err.count('\n') == 1 and 'no footer' in err, err
    assert f'summarising the {count} messages read' in err, err
    assert peak - small < 200, (peak, small)     # MiB


def test_a_large_metadata_yaml_is_refused_before_it_is_parsed(tmp_path):
    """A 3.8 MB metadata.yaml listing one file 300 000 times: refused unparsed, the file
    read once."""
    bag = tmp_path / 'b'
    write_episodes(bag, 1, 5).close()
    rc, err, small = sapga_peak_rss(['inspect', str(bag)])
    assert rc == 0, err
    (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information:\n  relative_file_paths:\n'
                                       + '  - b_0.mcap\n' * 300_000)
    rc, err, peak = sapga_peak_rss(['inspect', '--json', str(bag)])
    assert rc == 0 and 'larger than' in err and err.count('\n') == 1, err
    assert peak - small < 50, (peak, small)


def test_an_output_directory_that_is_a_device_is_named_as_one(tmp_path):
    """/dev/null as the output directory: a device, not "exists already"; nothing made."""
    with pytest.raises(McapError, match='/dev/null: a device, not a directory'):
        BagWriter('/dev/null/bag')
    (tmp_path / 'file').write_text('x')
    with pytest.raises(McapError, match='a file, not a directory'):
        BagWriter(tmp_path / 'file' / 'bag')


def test_a_bag_the_writer_writes_compressed_beyond_any_ratio_reads_whole(tmp_path):
    """Three blank 30 MiB mono8 images in 16 MiB chunks (the writer's limits) compress to
    some 13 KB: inspect reads all three, the bag complete, as reindex does."""
    from sapga_ros.recording.inspect import inspect_path

    n = 30 << 20
    image = TYPES.types['sensor_msgs/msg/Image']
    header = TYPES.types['std_msgs/msg/Header']
    stamp = TYPES.types['builtin_interfaces/msg/Time'](0, 0)
    cdr = bytes(TYPES.serialize_cdr(image(header(stamp, 'c'), 1, n, 'mono8', 0, n,
                                          np.zeros(n, dtype=np.uint8)),
                                    'sensor_msgs/msg/Image'))
    bag = tmp_path / 'b'
    with BagWriter(bag, chunk_size=MAX_CHUNK_SIZE, custom_data={'problem': 'acrobot'}) as w:
        w.add_topic(TopicInfo('/image', 'sensor_msgs/msg/Image', [qos_profile()],
                              type_hash('sensor_msgs/msg/Image')))
        for k in range(3):
            w.write('/image', cdr, (k + 1) * 10**9, (k + 1) * 10**9)
    del cdr
    size = sum(p.stat().st_size for p in bag.glob('*.mcap'))
    assert 3 * n > 1000 * size
    summary, _, _ = inspect_path(str(bag))
    assert summary['complete'] and summary['message_count'] == 3, summary['error']
    assert reindex(bag).messages == 3


def joint_names_bomb(path, names: int, messages: int) -> None:
    """An MCAP file of zstd chunks of JointStates naming ``names`` two-letter joints each:
    some 2 MB on disk (mostly an uncompressed metadata record), some 7 times their CDR bytes
    when decoded."""
    body = bytearray(b'\x00\x01\x00\x00') + (1).to_bytes(4, 'little') + bytes(4)
    body += (8).to_bytes(4, 'little') + b'acrobot\x00' + names.to_bytes(4, 'little')
    body += ((3).to_bytes(4, 'little') + b'ab\x00\x00') * names + bytes(12)
    with open(path, 'wb') as f:
        w = McapWriter(f, chunk_size=48 << 20, compression=CompressionType.ZSTD)
        w.start('ros2', 'bomb')
        w.add_metadata('sapga', {'problem': 'acrobot'})
        w.add_metadata('pad', {'x': 'ab' * 900_000})      # a file size no ratio refuses
        s = w.register_schema('sensor_msgs/msg/JointState', 'ros2msg',
                              message_definition('sensor_msgs/msg/JointState').encode())
        c = w.register_channel('/joint_states', 'cdr', s)
        for k in range(messages):
            w.add_message(c, k * 1000, bytes(body), k * 1000)
        w.finish()


def test_inspect_memory_is_bounded_for_messages_that_decode_large(tmp_path):
    """170 JointStates of 100 000 joint names (136 MB of CDR in a file of some 2 MB): inspect
    decodes each alone and keeps none, within 200 MiB above a small bag's peak (the chunks'
    bound); a message above 1 MiB is not decoded, its topic said undecodable."""
    write_episodes(tmp_path / 'small', 1, 5).close()
    joint_names_bomb(tmp_path / 'bomb.mcap', 100_000, 170)
    assert (tmp_path / 'bomb.mcap').stat().st_size < 4 << 20
    rc, err, small = sapga_peak_rss(['inspect', str(tmp_path / 'small')])
    assert rc == 0, err
    rc, err, peak = sapga_peak_rss(['inspect', str(tmp_path / 'bomb.mcap')])
    assert rc == 0 and 'Traceback' not in err, err
    assert peak - small < 200, (peak, small)     # MiB
    from sapga_ros.recording.inspect import inspect_path

    joint_names_bomb(tmp_path / 'big.mcap', 200_000, 2)
    summary, _, _ = inspect_path(str(tmp_path / 'big.mcap'))
    assert summary['message_count'] == 2
    assert 'more than the 1048576 decoded' in summary['undecodable_topics']['/joint_states']
