"""Bounded decompression of MCAP chunks: a small file never becomes a large allocation.

A chunk states its uncompressed size; a hostile file states a huge one (a 17 KB zstd bomb
expands to gigabytes).  ``chunk_records`` refuses a chunk above ``MAX_CHUNK_BYTES`` or above
what is left of the reading's ``Budget`` (``BUDGET_FLOOR`` plus ``BUDGET_RATIO`` times the
bytes on disk) before decompressing anything, decompresses with a hard output limit, checks
the size and CRC, and only then parses the records inside with the ``mcap`` library.

The budget also pays for what a reader keeps: each message costs ``message_cost`` bytes
(the Python objects that hold it and its decoded value), so chunks of millions of small
messages, which decompress within any byte limit, cannot turn a 1 MiB file into a gigabyte.

``MAX_CHUNK_BYTES`` is the one chunk limit of the package: the writer never makes a chunk
above it (``MAX_CHUNK_SIZE`` plus at most one ``MAX_MESSAGE_BYTES`` message, the writer
closes a chunk once it passes its size), and every reader refuses a chunk above it.
"""
from __future__ import annotations

import io
import json
import zlib

from mcap.records import Channel, Chunk, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from sapga_ros.errors import DataFileError, McapError
from sapga_ros.io.jsonfile import strict_loads

MAX_CHUNK_BYTES = 64 << 20      # rosbag2's largest preset chunk is 4 MiB
MAX_CHUNK_SIZE = 16 << 20       # [bytes] the largest chunk_size a writer accepts
MAX_MESSAGE_BYTES = 32 << 20    # [bytes] the largest message a writer records
CHUNK_SLACK = 1 << 20           # schemas and channels sharing a chunk with its messages
assert MAX_CHUNK_SIZE + MAX_MESSAGE_BYTES + CHUNK_SLACK <= MAX_CHUNK_BYTES
BUDGET_FLOOR = 16 << 20         # [bytes] decompressed and kept, whatever the file size
BUDGET_RATIO = 64               # ROS messages rarely compress 10:1; bombs do 10000:1
MESSAGE_COST = 512              # [bytes] a kept message's objects, decoded, besides its data
FIELD_COST = 16                 # [bytes] per byte of its first 64: small messages decode small


CHANNEL_RECORD = 'sapga_channel'     # a channel and its schema, outside the chunks


def channel_record(channel: Channel, schema: Schema) -> dict[str, str]:
    """The ``sapga_channel`` Metadata record of a channel and its schema."""
    return {'id': str(channel.id), 'topic': channel.topic,
            'message_encoding': channel.message_encoding,
            'metadata': json.dumps(dict(channel.metadata), sort_keys=True, allow_nan=False),
            'schema_id': str(schema.id), 'schema_name': schema.name,
            'schema_encoding': schema.encoding, 'schema_data': schema.data.decode('utf-8')}


def channel_from(record: Metadata) -> tuple[Channel, Schema] | None:
    """The channel and schema of a ``sapga_channel`` record (None if it is not one)."""
    m = record.metadata
    try:
        meta = strict_loads(m['metadata'], 'sapga_channel metadata')
        schema = Schema(id=int(m['schema_id']), name=m['schema_name'],
                        encoding=m['schema_encoding'], data=m['schema_data'].encode('utf-8'))
        return (Channel(id=int(m['id']), topic=m['topic'],
                        message_encoding=m['message_encoding'], schema_id=schema.id,
                        metadata={str(k): str(v) for k, v in meta.items()}), schema)
    except (KeyError, ValueError, TypeError, AttributeError, DataFileError):
        return None


def message_cost(size: int) -> int:
    """What keeping (and decoding) a message of ``size`` bytes costs in memory [bytes]:
    measured, a decoded JointState of 40 bytes takes some 1.2 KB, a Float64 some 0.5 KB."""
    return MESSAGE_COST + FIELD_COST * min(size, 64) + size


class BudgetExceeded(McapError):
    """The reading has used up its budget: reading on would only be refused too.
    ``records``: those of the chunk that fit in what was left, in order."""

    def __init__(self, message: str, records: list[McapRecord] | None = None) -> None:
        super().__init__(message)
        self.records = records or []


class Budget:
    """How many decompressed bytes one reading may still produce (and keep).

    A reading that keeps its messages (``keeps``) pays for them too; one that streams them
    on (``Budget.streaming``: inspect, reindex, recounts) holds one chunk at a time and is
    bounded by ``MAX_CHUNK_BYTES`` a chunk only, so it reads every bag the writer writes
    (three 30 MiB blank images compress to 13 KB: 7000 times the file size)."""

    def __init__(self, size_on_disk: int, keeps: bool = True) -> None:
        self.left: float = BUDGET_FLOOR + BUDGET_RATIO * max(0, size_on_disk)
        self.keeps = keeps

    @classmethod
    def streaming(cls) -> Budget:
        budget = cls(0, keeps=False)
        budget.left = float('inf')
        return budget

    def take(self, n: int, where: str) -> None:
        if n > MAX_CHUNK_BYTES:
            raise McapError(f'{where}: chunk states {n} uncompressed bytes, more than the '
                            f'limit of {MAX_CHUNK_BYTES >> 20} MiB (a decompression bomb?)')
        if n > self.left:
            raise BudgetExceeded(f'{where}: chunks expand beyond {BUDGET_RATIO} times the '
                                 'file size (a decompression bomb?)')
        self.left -= n


def _zstd(data: bytes, limit: int) -> bytes:
    import zstandard

    out = bytearray()
    source = io.BytesIO(data)
    with zstandard.ZstdDecompressor().stream_reader(source, read_across_frames=True) as reader:
        while len(out) <= limit:
            block = reader.read(min(1 << 20, limit + 1 - len(out)))
            if not block:
                break
            out += block
    return bytes(out)


def _lz4(data: bytes, limit: int) -> bytes:
    import lz4.frame

    return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=limit)


DECOMPRESSORS = {'zstd': _zstd, 'lz4': _lz4}


def chunk_records(chunk: Chunk, budget: Budget, where: str) -> list[McapRecord]:
    """The Schema, Channel and Message records of a chunk, decompressed within ``budget``."""
    size = chunk.uncompressed_size
    budget.take(size, where)
    if chunk.compression == '':
        raw = chunk.data
    elif chunk.compression in DECOMPRESSORS:
        try:
            raw = DECOMPRESSORS[chunk.compression](chunk.data, size + 1)
        except Exception as exc:  # noqa: BLE001 - any codec error means a damaged chunk
            raise McapError(f'{where}: {chunk.compression} chunk does not decompress '
                            f'({type(exc).__name__})') from exc
    else:
        raise McapError(f'{where}: unknown chunk compression {chunk.compression[:20]!r}')
    if len(raw) != size:
        raise McapError(f'{where}: chunk holds {len(raw)}{"+" if len(raw) > size else ""} '
                        f'bytes, its record says {size}')
    if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
        raise McapError(f'{where}: corrupt chunk (CRC mismatch)')
    plain = Chunk(compression='', data=raw, message_end_time=chunk.message_end_time,
                  message_start_time=chunk.message_start_time, uncompressed_crc=0,
                  uncompressed_size=size)
    try:
        records = breakup_chunk(plain)
    except Exception as exc:  # noqa: BLE001 - any parse failure means damaged data
        raise McapError(f'{where}: damaged records inside a chunk ({type(exc).__name__})'
                        ) from exc
    if budget.keeps:
        for i, r in enumerate(records):
            if isinstance(r, Message):
                budget.left -= message_cost(len(r.data))
                if budget.left < 0:
                    raise BudgetExceeded(f'{where}: the messages read would take more than '
                                         f'{BUDGET_RATIO} times the file size in memory (a '
                                         'decompression bomb?)', records[:i])
    return records
