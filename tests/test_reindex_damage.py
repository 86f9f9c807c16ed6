"""`sapga bag reindex` on damaged bags: a flipped byte costs its own chunk, never the rest.

Real bags (this package's writer, a complete one and one whose writer was SIGKILLed) get one
byte flipped at many positions.  The reference is the ``mcap`` library's stream reader, run
independently of the package: it reads the damaged file record by record at the places the
intact file's records were (``layout``), validating CRCs, and skips every record that fails.
After reindex, ``mcap``'s random-access reader must find every message the reference still
decodes, and nothing that was not recorded; a file that is not rewritten is left byte for
byte as it was, and a rewritten damaged file is kept beside the repair.
"""
from __future__ import annotations

import io
import os
import shutil
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from sapga_ros.cli import main as cli
from test_recording_files import MAGIC, killed_bag, write_episodes


def layout(data: bytes) -> list[tuple[int, int, object]]:
    """(start, end, record) of each top-level record of an intact (or cut) file."""
    f = io.BytesIO(data)
    out, pos = [], len(MAGIC)
    try:
        for record in StreamReader(f, emit_chunks=True).records:
            out.append((pos, f.tell(), record))
            pos = f.tell()
    except Exception:  # noqa: BLE001 - a killed file ends without a footer
        pass
    return out


def decodable(data: bytes, places: list[tuple[int, int, object]]) -> Counter:
    """(topic, log_time, data) of every message the stream reader still decodes, record by
    record, skipping what fails."""
    channels, messages = {}, []
    for start, end, _ in places:
        got = []
        try:        # a record alone: the stream ends after it, without a footer
            for r in StreamReader(io.BytesIO(MAGIC + data[start:end]),
                                  validate_crcs=True).records:
                got.append(r)
        except Exception:  # noqa: BLE001 - a damaged record, or the end: skip the rest
            pass
        for r in got:
            if isinstance(r, Channel):
                channels.setdefault(r.id, r.topic)
            elif isinstance(r, Message):
                messages.append(r)
    return Counter((channels[m.channel_id], m.log_time, m.data) for m in messages
                   if m.channel_id in channels)


def random_access(path: Path) -> Counter:
    with open(path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        return Counter((c.topic, m.log_time, m.data)
                       for _, c, m in reader.iter_messages(log_time_order=False))


def positions(places: list[tuple[int, int, object]], size: int, n: int) -> list[int]:
    """``n`` positions spread over the file, and every field of the first and last chunk's
    record header (opcode, length, times, size, CRC, compression name)."""
    chunks = [start for start, _, r in places if isinstance(r, Chunk)]
    fields = (0, 1, 4, 9, 17, 25, 29, 33, 37, 41, 43, 47)
    special = {c + k for c in (chunks[0], chunks[-1]) for k in fields}
    return sorted(special | {len(MAGIC) + (size - len(MAGIC)) * i // n for i in range(n)})


def check_flips(bag: Path, tmp_path: Path, n: int) -> dict[str, int]:
    """Flip one byte of the bag's last storage file at each position; what reindex did."""
    target = sorted(bag.glob('*.mcap'))[-1]
    intact = target.read_bytes()
    places = layout(intact)
    recorded = decodable(intact, places)
    outcomes: Counter = Counter()
    for pos in positions(places, len(intact), n):
        work = tmp_path / f'flip{pos}'
        shutil.copytree(bag, work)
        damaged = bytearray(intact)
        damaged[pos] ^= 0xFF if pos % 3 == 0 else 1 << (pos % 8)
        path = work / target.name
        path.write_bytes(bytes(damaged))
        expected = decodable(bytes(damaged), places)
        code = cli.main(['bag', 'reindex', str(work)])
        assert code in (0, 1), pos
        now = path.read_bytes()
        if now == bytes(damaged):
            outcomes['left as it was'] += 1
            assert code == 0 or not expected, pos
            continue
        got = random_access(path)
        assert not expected - got, (pos, sum((expected - got).values()))
        assert not got - recorded, pos          # nothing that was not recorded
        kept = work / f'{target.name}.damaged'
        if code == 1:
            assert kept.read_bytes() == bytes(damaged), pos
            outcomes['repaired, loss reported'] += 1
        else:
            outcomes['repaired, nothing lost'] += 1
            assert got == recorded or not kept.exists(), pos
    return outcomes


def test_a_flipped_byte_in_a_complete_bag_costs_its_chunk_only(tmp_path, capsys):
    """Every intact chunk's messages survive reindex, wherever the damage is."""
    write_episodes(tmp_path / 'b', 3, 200, chunk_size=1024).close()
    outcomes = check_flips(tmp_path / 'b', tmp_path, 60)
    assert outcomes['repaired, loss reported'] >= 10, outcomes
    err = capsys.readouterr().err
    assert 'messages lost (/episode_event' in err or 'messages lost (/reward' in err, err


@pytest.mark.parametrize('split', ['run', 'episode'])
def test_a_flipped_byte_in_a_killed_bag_costs_its_chunk_only(tmp_path, split):
    """The same after SIGKILL: no footer, no summary, no metadata.yaml."""
    bag = killed_bag(tmp_path, split)
    outcomes = check_flips(bag, tmp_path, 30)
    assert outcomes['repaired, loss reported'] >= 5, outcomes


def test_a_file_with_nothing_readable_is_left_as_it_was(tmp_path, capsys):
    """A file whose every chunk is damaged is not replaced by an empty one: exit 1, the
    bytes unchanged, no temporary file left."""
    write_episodes(tmp_path / 'b', 1, 50, chunk_size=100_000).close()
    path = tmp_path / 'b' / 'b_0.mcap'
    data = bytearray(path.read_bytes())
    chunk = next(start for start, _, r in layout(bytes(data)) if isinstance(r, Chunk))
    data[chunk + 60] ^= 0xFF
    path.write_bytes(bytes(data))
    assert cli.main(['bag', 'reindex', str(path)]) == 1
    assert path.read_bytes() == bytes(data)
    assert 'left unchanged: nothing readable to keep' in capsys.readouterr().err
    assert sorted(p.name for p in path.parent.iterdir()) == ['b_0.mcap', 'metadata.yaml']


def test_reindex_never_follows_a_link(tmp_path, capsys):
    """A planted link named like a temporary file is neither followed nor removed; a bag or
    storage file that is a link is refused in one line."""
    bag = killed_bag(tmp_path, 'run')
    outside = tmp_path / 'outside.txt'
    outside.write_text('precious')
    storage = sorted(bag.glob('*.mcap'))[-1]
    planted = bag / f'.{storage.name}.reindex'
    planted.symlink_to(outside)
    assert cli.main(['bag', 'reindex', str(bag)]) == 0
    assert outside.read_text() == 'precious' and planted.is_symlink()
    assert random_access(storage)
    capsys.readouterr()
    link = tmp_path / 'link'
    link.symlink_to(bag)
    moved = tmp_path / 'moved.mcap'
    os.replace(storage, moved)
    storage.symlink_to(moved)
    for path in (link, bag, storage):
        assert cli.main(['bag', 'reindex', str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and 'symbolic link' in err, err
    assert storage.is_symlink() and outside.read_text() == 'precious'


def test_reading_goes_on_past_a_chunk_with_damaged_contents(tmp_path):
    """`sapga inspect`'s reader skips a chunk whose data is damaged and reads the rest: every
    message the stream reader decodes, the file called incomplete with the byte named."""
    from sapga_ros.recording.reader import read_recording

    write_episodes(tmp_path / 'b', 3, 200, chunk_size=1024).close()
    path = tmp_path / 'b' / 'b_0.mcap'
    data = bytearray(path.read_bytes())
    places = layout(bytes(data))
    start, end, _ = [p for p in places if isinstance(p[2], Chunk)][1]
    data[(start + end) // 2] ^= 0x04
    path.write_bytes(bytes(data))
    rec = read_recording(tmp_path / 'b')
    got = Counter((m.topic, m.log_time, m.data) for m in rec.messages)
    assert got == decodable(bytes(data), places) and 0 < len(rec.messages) < 606
    assert not rec.complete and f'byte {start}' in rec.error and 'skipped' in rec.error


def test_a_killed_bag_keeps_its_messages_when_the_chunk_defining_its_channels_is_lost(
        tmp_path):
    """The first chunk holds the channel definitions and a killed file has no summary; the
    writer's sapga_channel records still name every channel, so reindex keeps every message
    of the other chunks (the stream reader alone decodes none of them)."""
    bag = killed_bag(tmp_path, 'run')
    path = sorted(bag.glob('*.mcap'))[-1]
    intact = path.read_bytes()
    places = layout(intact)
    first = next(p for p in places if isinstance(p[2], Chunk))
    damaged = bytearray(intact)
    damaged[(first[0] + first[1]) // 2] ^= 0x08
    path.write_bytes(bytes(damaged))
    assert not decodable(bytes(damaged), places)
    assert cli.main(['bag', 'reindex', str(bag)]) == 1
    others = decodable(intact, places) - decodable(intact, [first])
    assert others and random_access(path) == others


def small_bag(tmp_path: Path, killed: bool) -> tuple[Path, Path, bytes]:
    """A bag of small chunks, finished or SIGKILLed: (bag, its last file, that file's bytes)."""
    if killed:
        bag = killed_bag(tmp_path, 'run')
    else:
        bag = tmp_path / 'b'
        write_episodes(bag, 3, 200, chunk_size=1024).close()
    path = sorted(bag.glob('*.mcap'))[-1]
    return bag, path, path.read_bytes()


def chunk_places(data: bytes) -> list[tuple[int, int, object]]:
    return [p for p in layout(data) if isinstance(p[2], Chunk)]


@pytest.mark.parametrize('killed', [False, True])
@pytest.mark.parametrize('bit', range(8))
def test_a_chunk_whose_opcode_byte_is_damaged_keeps_its_messages(tmp_path, capsys, bit,
                                                                 killed):
    """One bit of every chunk's opcode byte flipped (0x06 reads as another record kind, a
    summary record, a private one or no known one): each chunk is recognised by its
    structure and every message the intact chunks hold is kept; the original is kept."""
    bag, path, intact = small_bag(tmp_path, killed)
    places = layout(intact)
    damaged = bytearray(intact)
    for start, _, _ in chunk_places(intact):
        damaged[start] ^= 1 << bit
    path.write_bytes(bytes(damaged))
    assert cli.main(['bag', 'reindex', str(bag)]) == 0
    assert random_access(path) == decodable(intact, places)
    assert (bag / f'{path.name}.damaged').read_bytes() == bytes(damaged)
    assert 'opcode byte reads' in ''.join(capsys.readouterr())


@pytest.mark.parametrize('killed', [False, True])
@pytest.mark.parametrize('opcode', [0x0E, 0x86, 0x16])
def test_a_lost_chunk_behind_a_damaged_opcode_is_counted(tmp_path, capsys, opcode, killed):
    """A chunk whose opcode byte and contents are both damaged cannot be read: its messages
    are counted lost per topic (from the message indexes after it), exit 1, the damaged
    original kept; every other chunk is kept."""
    bag, path, intact = small_bag(tmp_path, killed)
    places = layout(intact)
    victim = chunk_places(intact)[2]
    damaged = bytearray(intact)
    damaged[victim[0]] = opcode
    damaged[(victim[0] + victim[1]) // 2] ^= 0xFF
    path.write_bytes(bytes(damaged))
    assert cli.main(['bag', 'reindex', str(bag)]) == 1
    lost = decodable(intact, places) - decodable(intact, [p for p in places if p != victim])
    assert lost and random_access(path) == decodable(intact, places) - lost
    topics = Counter(topic for topic, _, _ in lost.elements())
    err = ''.join(capsys.readouterr())
    assert f'{sum(topics.values())} messages lost (' in err, err
    assert all(f'{t} {n}' in err for t, n in topics.items()), err
    assert (bag / f'{path.name}.damaged').read_bytes() == bytes(damaged)


def test_a_huge_length_field_is_damage_not_a_traceback(tmp_path, capsys):
    """The top bit of any length field of a chunk record flipped (the record's length, the
    compression name's, the records'): one line; every message the stream reader still
    decodes is kept, and exit 1 exactly when some were lost."""
    write_episodes(tmp_path / 'b', 3, 200, chunk_size=1024).close()
    path = tmp_path / 'b' / 'b_0.mcap'
    intact = path.read_bytes()
    places = layout(intact)
    start, _, chunk = chunk_places(intact)[1]
    name = len(chunk.compression)
    for field_end in (9, 9 + 28 + 4, 9 + 28 + 4 + name + 8):      # each u32/u64's top byte
        work = tmp_path / f'f{field_end}'
        shutil.copytree(tmp_path / 'b', work)
        damaged = bytearray(intact)
        damaged[start + field_end - 1] ^= 0x80
        (work / 'b_0.mcap').write_bytes(bytes(damaged))
        code = cli.main(['bag', 'reindex', str(work)])
        got, recorded = random_access(work / 'b_0.mcap'), decodable(intact, places)
        assert not decodable(bytes(damaged), places) - got and not got - recorded
        assert code == (0 if got == recorded else 1), field_end
        err = ''.join(capsys.readouterr())
        assert 'Traceback' not in err and 'Error' not in err, err


@pytest.mark.parametrize('opcode', [0x0E, 0x86])
def test_reading_names_a_chunk_skipped_behind_a_damaged_opcode(tmp_path, opcode):
    """`sapga inspect`'s stream reader cannot read a chunk whose opcode byte is damaged; it
    calls the file incomplete and names the byte instead of skipping it in silence."""
    from sapga_ros.recording.reader import read_recording

    write_episodes(tmp_path / 'b', 3, 200, chunk_size=1024).close()
    path = tmp_path / 'b' / 'b_0.mcap'
    data = bytearray(path.read_bytes())
    start = chunk_places(bytes(data))[2][0]
    data[start] = opcode
    path.write_bytes(bytes(data))
    rec = read_recording(tmp_path / 'b')
    assert not rec.complete and f'byte {start}' in rec.error, rec.error
    assert 'where a chunk was expected' in rec.error


PRIVATE = bytes([0x80]) + (11).to_bytes(8, 'little') + b'foreign\x00\x01\x02\x03'


def with_attachments(tmp_path: Path) -> tuple[Path, Path, bytes]:
    """A bag whose file a foreign writer (``mcap``'s ``Writer``) rewrote with this package's
    schemas, channels, messages and metadata records (``rosbag2``, ``sapga``,
    ``sapga_channel``) in small chunks, an attachment and a metadata record of its own
    after every 40 messages and a private record: (bag, file, its bytes)."""
    bag = tmp_path / 'b'
    write_episodes(bag, 3, 200, chunk_size=1024).close()
    path = bag / 'b_0.mcap'
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        metadata = list(reader.iter_metadata())
        messages = list(reader.iter_messages(log_time_order=False))
    out = io.BytesIO()
    writer = Writer(out, chunk_size=1024, compression=CompressionType.ZSTD)
    writer.start(profile='ros2', library='foreign')
    for s in summary.schemas.values():
        assert writer.register_schema(s.name, s.encoding, s.data) == s.id
    for c in summary.channels.values():
        assert writer.register_channel(c.topic, c.message_encoding, c.schema_id,
                                       dict(c.metadata)) == c.id
    for m in metadata[:len(metadata) // 2]:
        writer.add_metadata(m.name, dict(m.metadata))
    for k, (_, channel, m) in enumerate(messages):
        writer.add_message(channel.id, m.log_time, m.data, m.publish_time, m.sequence)
        if k % 40 == 39:
            writer.add_attachment(k, k + 1, f'scene{k}.png', 'image/png', bytes([k % 251]) * k)
            writer.add_metadata(f'note{k}', {'k': str(k)})
        if k == 100:    # a private record: the writer has written all but its open chunk
            out.write(PRIVATE)
    for m in metadata[len(metadata) // 2:]:
        writer.add_metadata(m.name, dict(m.metadata))
    writer.finish()
    path.write_bytes(out.getvalue())
    return bag, path, out.getvalue()


def held(path: Path) -> tuple[list, list]:
    """The attachments and metadata records ``mcap``'s random-access reader finds through the
    summary's indexes."""
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert len(summary.attachment_indexes) == summary.statistics.attachment_count
        assert len(summary.metadata_indexes) == summary.statistics.metadata_count
        return list(reader.iter_attachments()), list(reader.iter_metadata())


def whole(places: list[tuple[int, int, object]], end: int, kind: type) -> list:
    return [r for _, stop, r in places if isinstance(r, kind) and stop <= end]


@pytest.mark.parametrize('damage', ['cut', 'chunk'])
def test_reindex_keeps_every_intact_attachment_and_metadata_record(tmp_path, capsys, damage):
    """A file cut short (a killed writer) or with a damaged chunk is rewritten with every
    intact attachment and metadata record (``sapga``'s own included), indexed in the summary,
    and the report counts them."""
    bag, path, intact = with_attachments(tmp_path)
    places = layout(intact)
    chunks = chunk_places(intact)
    if damage == 'cut':
        end = (chunks[-4][0] + chunks[-4][1]) // 2
        damaged = intact[:end]
    else:
        end = len(intact)
        start, stop, _ = chunks[len(chunks) // 2]
        damaged = bytearray(intact)
        damaged[(start + stop) // 2] ^= 0x10
        damaged = bytes(damaged)
    path.write_bytes(damaged)
    attachments, metadata = whole(places, end, Attachment), whole(places, end, Metadata)
    assert len(attachments) >= 10 and {'sapga', 'rosbag2'} <= {m.name for m in metadata}
    assert cli.main(['bag', 'reindex', str(bag)]) == (0 if damage == 'cut' else 1)
    got_attachments, got_metadata = held(path)
    assert got_attachments == attachments
    assert got_metadata == metadata
    out = ''.join(capsys.readouterr())
    assert f'{len(attachments)} attachments, {len(metadata)} metadata records, 1 private ' \
        'record' in out, out
    assert path.read_bytes().count(PRIVATE) == 1


@pytest.mark.parametrize('where', ['data', 'length'])
def test_a_damaged_attachment_is_reported_lost_by_name(tmp_path, capsys, where):
    """An attachment that does not match its CRC (a byte of its data flipped) or does not
    parse (its length field) is lost and named; every other attachment, metadata record and
    message is kept, the original kept beside the repair."""
    bag, path, intact = with_attachments(tmp_path)
    places = layout(intact)
    victim = [p for p in places if isinstance(p[2], Attachment)][3]
    damaged = bytearray(intact)
    damaged[(victim[0] + victim[1]) // 2 if where == 'data' else victim[0] + 8] ^= 0x40
    path.write_bytes(bytes(damaged))
    assert cli.main(['bag', 'reindex', str(bag)]) == 1
    err = ''.join(capsys.readouterr())
    assert f"lost attachment '{victim[2].name}'" in err, err
    got_attachments, got_metadata = held(path)
    assert got_attachments == [r for _, _, r in places
                               if isinstance(r, Attachment) and r != victim[2]]
    assert got_metadata == whole(places, len(intact), Metadata)
    assert random_access(path) == decodable(intact, places)
    assert (bag / f'{path.name}.damaged').read_bytes() == bytes(damaged)


@pytest.mark.parametrize('split', ['run', 'episode'])
def test_the_writers_own_metadata_records_survive_reindex(tmp_path, split):
    """The ``rosbag2``, ``sapga`` and ``sapga_channel`` records this package's writer puts in
    each file are all in the file reindex completes after SIGKILL, in the summary's index."""
    from mcap.reader import NonSeekingReader

    bag = killed_bag(tmp_path, split)
    path = sorted(bag.glob('*.mcap'))[-1]
    with open(path, 'rb') as f:
        before = []
        try:
            for m in NonSeekingReader(f).iter_metadata():
                before.append(m)
        except Exception:  # noqa: BLE001 - the stream ends without a footer
            pass
    assert {'rosbag2', 'sapga', 'sapga_channel'} <= {m.name for m in before}
    assert cli.main(['bag', 'reindex', str(bag)]) == 0
    assert held(path) == ([], before)
