"""Reading one MCAP record at a byte position, strictly: a damaged field is never guessed.

``parse_at`` reads the record at a position and checks that its fields fill its stated
length exactly (``_Exact`` refuses every short read).  A chunk whose record length or data
length field is wrong but whose contents are whole is read by its other length
(``chunk_by_fields``, ``chunk_by_length``) and one whose stated uncompressed size is wrong
by its CRC (``resized``): ``salvage.py`` keeps such a chunk only once it decompresses and
checks.  An attachment is whole only if it matches its CRC (``attachment_check``).
``chains`` says whether a plausible record header starts at a position.
"""
from __future__ import annotations

import dataclasses
import io
import struct
import zlib
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import (Attachment, Channel, Chunk, DataEnd, Footer, Header, Message,
                          MessageIndex, Metadata, Schema)

from sapga_ros.errors import McapError
from sapga_ros.recording.chunks import DECOMPRESSORS, MAX_CHUNK_BYTES, Budget

MAGIC = b'\x89MCAP0\r\n'
CUT_SHORT = 'cut short'
PARSERS: dict[int, Any] = {Opcode.HEADER: Header, Opcode.FOOTER: Footer,
                           Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
                           Opcode.MESSAGE: Message, Opcode.CHUNK: Chunk,
                           Opcode.MESSAGE_INDEX: MessageIndex, Opcode.METADATA: Metadata,
                           Opcode.DATA_END: DataEnd, Opcode.ATTACHMENT: Attachment}
KNOWN_OPCODES = {int(op) for op in Opcode}


class _Exact(io.BytesIO):
    """Bytes that refuse a short read: a field longer than its record is damage.  A length
    is checked against the bytes left before anything is read or allocated, so a length
    field of any value (up to 2**64 - 1) is damage, never an overflow."""

    def read(self, n: int | None = -1) -> bytes:
        if n is not None and n > len(self.getbuffer()) - self.tell():
            raise EndOfFile()
        data = super().read(n)
        if n is not None and n >= 0 and len(data) != n:
            raise EndOfFile()
        return data


def parse_at(mem: Any, pos: int, size: int) -> tuple[Any, int]:
    """The record at ``pos`` (None for a skippable one) and its end; ValueError if damaged."""
    if pos + 9 > size:
        raise ValueError(CUT_SHORT)
    opcode = mem[pos]
    length = struct.unpack_from('<Q', mem, pos + 1)[0]
    end = pos + 9 + length
    if end > size:
        raise ValueError(f'record length {length} runs past the end of the file')
    if opcode not in PARSERS:
        if opcode in KNOWN_OPCODES or opcode >= 0x80:
            return None, end                 # summary records, private records
        raise ValueError(f'unknown record opcode {opcode:#04x}')
    content = _Exact(mem[pos + 9:end])
    stream = ReadDataStream(content)
    try:
        if opcode == Opcode.MESSAGE:
            record = Message.read(stream, length)
        else:
            record = PARSERS[opcode].read(stream)
    except (EndOfFile, UnicodeDecodeError, struct.error, OverflowError) as exc:
        raise ValueError(f'damaged {Opcode(opcode).name.lower()} record') from exc
    if content.tell() != length:
        raise ValueError(f'{Opcode(opcode).name.lower()} record longer than its fields')
    return record, end


def chunk_by_fields(mem: Any, pos: int, size: int) -> tuple[Chunk, int]:
    """The chunk at ``pos`` read by its fields, its record length ignored (as the ``mcap``
    stream reader reads it), and its end; ValueError if it does not parse."""
    head = pos + 9 + 28             # start, end, uncompressed size and CRC
    if head + 4 > size:
        raise ValueError(CUT_SHORT)
    name = struct.unpack_from('<I', mem, head)[0]
    if head + 4 + name + 8 > size:
        raise ValueError('damaged chunk record')
    data = struct.unpack_from('<Q', mem, head + 4 + name)[0]
    end = head + 4 + name + 8 + data
    if end > size:
        raise ValueError('damaged chunk record')
    content = _Exact(mem[pos + 9:end])
    try:
        return Chunk.read(ReadDataStream(content)), end
    except (EndOfFile, UnicodeDecodeError, struct.error, OverflowError) as exc:
        raise ValueError('damaged chunk record') from exc


def chunk_by_length(mem: Any, pos: int, size: int) -> tuple[Chunk, int]:
    """The chunk at ``pos`` with the data its record length leaves for it, its data length
    field ignored, and its end; ValueError if it does not parse."""
    length = struct.unpack_from('<Q', mem, pos + 1)[0]
    end, head = pos + 9 + length, pos + 9 + 28
    if end > size or head + 4 > end:
        raise ValueError('damaged chunk record')
    start, stop, usize, crc, name = struct.unpack_from('<QQQII', mem, pos + 9)
    if head + 4 + name + 8 > end:
        raise ValueError('damaged chunk record')
    try:
        compression = bytes(mem[head + 4:head + 4 + name]).decode('utf-8')
    except UnicodeDecodeError as exc:
        raise ValueError('damaged chunk record') from exc
    return Chunk(compression=compression, data=bytes(mem[head + 4 + name + 8:end]),
                 message_start_time=start, message_end_time=stop, uncompressed_crc=crc,
                 uncompressed_size=usize), end


def resized(chunk: Chunk, budget: Budget) -> Chunk | None:
    """``chunk`` with its true uncompressed size, if only its stated size is wrong: its
    contents decompress (within the limits) to data of its CRC."""
    if not chunk.uncompressed_crc or chunk.compression not in DECOMPRESSORS:
        return None
    limit = min(MAX_CHUNK_BYTES, budget.left)
    try:
        raw = DECOMPRESSORS[chunk.compression](chunk.data, limit + 1)
    except Exception:  # noqa: BLE001 - any codec error: the contents are damaged
        return None
    if len(raw) > limit or len(raw) == chunk.uncompressed_size \
            or zlib.crc32(raw) != chunk.uncompressed_crc:
        return None
    return dataclasses.replace(chunk, uncompressed_size=len(raw))


def attachment_check(mem: Any, pos: int, end: int) -> bool | None:
    """Whether the attachment record ``pos``..``end`` matches its CRC (None: it has none)."""
    crc = struct.unpack_from('<I', mem, end - 4)[0]
    return None if crc == 0 else zlib.crc32(mem[pos + 9:end - 4]) == crc


def attachment_name(mem: Any, pos: int, size: int) -> str | None:
    """The name field of a damaged attachment record at ``pos``, if it still reads."""
    at = pos + 9 + 16
    if mem[pos] != Opcode.ATTACHMENT or at + 4 > size:
        return None
    n = struct.unpack_from('<I', mem, at)[0]
    if not 0 < n <= 256 or at + 4 + n > size:
        return None
    try:
        name = bytes(mem[at + 4:at + 4 + n]).decode('utf-8')
    except UnicodeDecodeError:
        return None
    return name if name.isprintable() else None


def chains(mem: Any, pos: int, size: int) -> bool:
    """Whether a plausible record header starts at ``pos``."""
    if pos + 9 > size or mem[pos] not in KNOWN_OPCODES:
        return False
    return pos + 9 + struct.unpack_from('<Q', mem, pos + 1)[0] <= size


def parse_span(mem: Any, pos: int, end: int) -> Any:
    """The record scan found intact at ``pos``..``end``, however its lengths (or, for a
    chunk, its opcode byte) were read."""
    for read in (parse_at, chunk_by_fields, chunk_by_length):
        try:
            record, stop = read(mem, pos, len(mem))
        except ValueError:
            continue
        if stop == end and record is not None and (
                read is not parse_at or mem[pos] != Opcode.CHUNK or isinstance(record, Chunk)):
            return record
    raise McapError(f'byte {pos}: the record found intact does not read again')
