"""What of a damaged or unfinished MCAP file can still be read, record by record.

A stream reader stops at the first record it cannot read; ``scan`` goes on.  It walks the
records one after the other, each parsed strictly (``mcap_records.py``: its fields fill its
stated length exactly) and each chunk checked (bounded decompression, size and CRC:
``chunks.py``).  A chunk whose contents are damaged but whose record is whole is skipped by
its length; a record that does not parse (a flipped length, opcode or string size) starts
a search for the next record that proves itself, byte by byte: a chunk that decompresses
to its size and CRC, or a metadata or message index record whose end is the start of
another record.
So one damaged chunk costs its own messages only, never those of the chunks after it.
A record that does not read as what its opcode says, or whose kind has no place in the data
section (a summary record, a footer, a private record), is first read as a chunk: a chunk
whose opcode byte (or a length field) is damaged but whose contents decompress to their
size and CRC is kept.  Where that fails, the message indexes that follow it (a chunk's,
which no other record has before it) or, in a finished file, the summary's chunk indexes say
that a chunk was lost there and what it held; a private record neither points to is skipped.
Every length field is checked against the bytes left before it is used.

Attachments and metadata records (the data this package's writer puts beside the messages,
and whatever a foreign writer puts there) are kept like messages, and a private record
(opcode 0x80 and above) byte for byte (``Private``) unless it proves to be a damaged chunk.
An attachment is whole only if it matches its CRC; one that does not, or that a damaged
region swallowed, is reported lost by name (``Scan.lost_records``), as is, in a finished
file, every attachment or metadata record the summary indexes that was not found whole.

The message indexes that follow a lost chunk say how many messages it held, per channel;
the loss is reported per topic (``Scan.lost``), or as unknown when they are lost too.  The
file's schemas and channels come from every intact chunk, for a finished file from the
summary, and from this package's ``sapga_channel`` records (a lost chunk may have held the
only definition of a channel).  Records after the data section (summary, footer) are read
for their schemas and channels only.

``scan`` reads twice: once to find the intact records and the channels, once (``records``)
to hand them over in file order, so a message whose channel is defined later (in the
summary) is kept too.  Memory: one chunk at a time, plus the record list.
"""
from __future__ import annotations

import io
import mmap
from dataclasses import dataclass, field
from typing import Any, Iterator

from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (Attachment, Channel, Chunk, DataEnd, Footer, Header, Message,
                          MessageIndex, Metadata, Schema)

from sapga_ros.errors import McapError
from sapga_ros.recording.chunks import CHANNEL_RECORD, Budget, channel_from, chunk_records
from sapga_ros.recording.mcap_records import (CUT_SHORT, MAGIC, attachment_check,
                                              attachment_name, chains, chunk_by_fields,
                                              chunk_by_length, parse_at, parse_span, resized)

_SYNC = (Opcode.CHUNK, Opcode.METADATA, Opcode.MESSAGE_INDEX,    # records that prove a resync
         Opcode.ATTACHMENT)
_DATA = (Header, Schema, Channel, Message, Metadata)
_ELSEWHERE = {Opcode.HEADER, Opcode.FOOTER, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX,
              Opcode.STATISTICS, Opcode.METADATA_INDEX, Opcode.SUMMARY_OFFSET}


@dataclass
class Damage:
    """Bytes ``start``..``end`` of a file that held nothing readable."""

    start: int
    end: int
    why: str
    lost: dict[int, int] = field(default_factory=dict)     # channel id -> messages
    counted: bool = False       # message indexes said what was lost


@dataclass
class Private:
    """A private record of the data section, kept byte for byte (opcode and length too)."""

    raw: bytes


@dataclass
class Scan:
    """What ``scan`` found in one file."""

    path: str
    size: int
    header: Header | None = None
    spans: list[tuple[int, int]] = field(default_factory=list)   # intact data records
    damage: list[Damage] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    per_channel: dict[int, int] = field(default_factory=dict)   # intact messages
    compression: str = ''
    footer: bool = False
    skipped: list[tuple[int, int]] = field(default_factory=list)   # private data records
    attachments: int = 0        # intact attachment records
    metadata: int = 0           # intact metadata records
    lost_records: dict[int, str] = field(default_factory=dict)   # start -> "attachment 'x'"

    def topic(self, channel_id: int) -> str:
        channel = self.channels.get(channel_id)
        return channel.topic if channel else f'channel {channel_id} (definition lost)'

    def lost(self) -> tuple[dict[str, int], bool]:
        """Messages lost per topic, and whether every loss could be counted."""
        out: dict[str, int] = {}
        for d in self.damage:
            for cid, n in d.lost.items():
                out[self.topic(cid)] = out.get(self.topic(cid), 0) + n
        for cid, n in self.orphans.items():
            out[self.topic(cid)] = out.get(self.topic(cid), 0) + n
        return out, all(d.counted for d in self.damage if d.why != CUT_SHORT)

    @property
    def orphans(self) -> dict[int, int]:
        """Intact messages of channels no intact record defines: they cannot be kept."""
        return {c: n for c, n in self.per_channel.items() if c not in self.channels}

    @property
    def kept(self) -> int:
        """The messages a rewrite keeps."""
        return sum(n for c, n in self.per_channel.items() if c in self.channels)

    def count(self, message: Message) -> None:
        self.per_channel[message.channel_id] = self.per_channel.get(message.channel_id, 0) + 1


def _proves(mem: Any, pos: int, size: int, budget: Budget, where: str) -> int | None:
    """The end of the record at ``pos`` if it proves a resynchronisation, else None."""
    if mem[pos] not in _SYNC:
        return None
    try:
        record, end = parse_at(mem, pos, size)
        if isinstance(record, Chunk):
            if record.compression not in ('', 'zstd', 'lz4') or not record.data:
                return None
            chunk_records(record, budget, where)
            return end
    except (ValueError, McapError):
        return None
    if isinstance(record, Attachment):
        check = attachment_check(mem, pos, end)
        if check is not None:
            return end if check else None
    if end in (size, size - len(MAGIC)) or chains(mem, end, size):
        return end
    return None


def _resync(mem: Any, start: int, size: int, budget: Budget, where: str) -> int | None:
    """The position of the next record after ``start`` that proves itself, or None."""
    hits = {op: mem.find(bytes([op]), start) for op in _SYNC}
    while True:
        live = [i for i in hits.values() if 0 <= i <= size - 9]
        if not live:
            return None
        pos = min(live)
        if _proves(mem, pos, size, budget, where) is not None:
            return pos
        op = mem[pos]
        hits[op] = mem.find(bytes([op]), pos + 1)


class _Walk:
    """One pass over a mapped file: the records that read, the damage between them."""

    def __init__(self, scan: Scan, mem: Any, budget: Budget) -> None:
        self.scan, self.mem, self.budget = scan, mem, budget
        self.open: Damage | None = None     # the damage whose message indexes may follow
        self.backups: list[Metadata] = []   # sapga_channel records
        self.after_chunk = False            # the last record was a chunk (or its indexes)
        self.skipped: tuple[int, int] | None = None    # the record skipped last, unread

    def run(self) -> None:
        scan, mem, size = self.scan, self.mem, self.scan.size
        pos = len(MAGIC)
        if bytes(mem[:len(MAGIC)]) != MAGIC:
            pos = self._damaged(0, 'bad magic bytes')
        data = True             # in the data section (before DataEnd)
        while pos is not None and pos + 9 <= size:
            try:
                record, end = parse_at(mem, pos, size)
            except ValueError as exc:
                fixed = self._as_chunk(pos) if data else None
                pos = fixed if fixed is not None else self._damaged(pos, str(exc))
                self.after_chunk = fixed is not None
                continue
            if data and (record is None or isinstance(record, Footer)):
                fixed = self._as_chunk(pos)     # a chunk whose opcode byte is damaged?
                if fixed is not None:
                    pos, self.after_chunk = fixed, True
                    continue
                self._stray(pos, end)
                pos = end
                continue
            elif isinstance(record, Chunk) and data:
                self._chunk(record, pos, end)
            elif isinstance(record, MessageIndex):
                self._index(record, pos)
            elif isinstance(record, (Schema, Channel)):
                self._define(record)
                if data:
                    scan.spans.append((pos, end))
            elif isinstance(record, Attachment) and data:
                if attachment_check(mem, pos, end) is False:
                    fixed = self._as_chunk(pos)     # a chunk whose opcode byte is damaged?
                    if fixed is not None:
                        pos, self.after_chunk = fixed, True
                        continue
                    scan.lost_records[pos] = f'attachment {record.name!r}'
                    scan.damage.append(Damage(pos, end, f'attachment {record.name!r} does '
                                              'not match its CRC', counted=True))
                else:
                    scan.attachments += 1
                    scan.spans.append((pos, end))
            elif isinstance(record, _DATA) and data:
                if isinstance(record, Metadata):
                    scan.metadata += 1
                    if record.name == CHANNEL_RECORD:
                        self.backups.append(record)
                if isinstance(record, Header):
                    scan.header = scan.header or record
                elif isinstance(record, Message):
                    scan.count(record)
                scan.spans.append((pos, end))
            elif isinstance(record, DataEnd):
                data = False
            elif isinstance(record, Footer):
                scan.footer = True
            if not isinstance(record, MessageIndex):
                self.after_chunk = isinstance(record, Chunk) and data
                self.skipped = None
            pos = end
        if pos is not None and pos < size and not (scan.footer and size - pos == len(MAGIC)):
            self.scan.damage.append(Damage(pos, size, CUT_SHORT))
        for record in self.backups:     # definitions lost with the chunk that held them
            found = channel_from(record)
            if found is not None and found[0].id not in scan.channels:
                scan.channels[found[0].id] = found[0]
                scan.schemas.setdefault(found[1].id, found[1])

    def _define(self, record: Schema | Channel) -> None:
        table = self.scan.schemas if isinstance(record, Schema) else self.scan.channels
        table.setdefault(record.id, record)

    def _chunk(self, chunk: Chunk, pos: int, end: int) -> None:
        try:
            records = chunk_records(chunk, self.budget, f'{self.scan.path}: byte {pos}')
        except McapError as exc:
            fixed = resized(chunk, self.budget)
            if fixed is not None:
                self.scan.damage.append(Damage(pos, pos + 9 + 28, 'wrong uncompressed size; '
                                               'its messages are kept', counted=True))
                self._chunk(fixed, pos, end)
                return
            self.open = Damage(pos, end, str(exc).split(': ', 2)[-1])
            self.scan.damage.append(self.open)
            return
        self.open = None
        self.scan.compression = self.scan.compression or chunk.compression
        self.scan.spans.append((pos, end))
        for r in records:
            if isinstance(r, (Schema, Channel)):
                self._define(r)
            elif isinstance(r, Message):
                self.scan.count(r)

    def _as_chunk(self, pos: int) -> int | None:
        """The record at ``pos`` that did not read as what its opcode says (or is of a kind
        that has no place in the data section) read as a chunk: a chunk whose record length
        or opcode byte is wrong but whose contents decompress and check is kept (and the
        file rewritten); where reading goes on, or None."""
        opcode = self.mem[pos]
        why = ('a wrong length field in a chunk record' if opcode == Opcode.CHUNK else
               f'a chunk record whose opcode byte reads {opcode:#04x}')
        for read in (chunk_by_fields, chunk_by_length):
            try:
                chunk, end = read(self.mem, pos, self.scan.size)
            except ValueError:
                continue
            known = len(self.scan.damage)
            self._chunk(chunk, pos, end)
            if len(self.scan.damage) > known:       # its contents are damaged too
                del self.scan.damage[known:]
                self.open = None
                self.scan.spans = [s for s in self.scan.spans if s[0] != pos]
                continue
            self.scan.damage.append(Damage(pos, pos + 9 + 28, f'{why}; its messages are '
                                           'kept', counted=True))
            return end
        return None

    def _stray(self, pos: int, end: int) -> None:
        """A record the data section has no use for, not a chunk either: a summary record
        or footer there is damage (a chunk's opcode, most likely: the message indexes after
        it count what it held); a private record or attachment is skipped, unless message
        indexes follow it (``_index``) or the summary indexes a chunk at it."""
        opcode = self.mem[pos]
        if opcode in _ELSEWHERE:
            self.open = Damage(pos, end, f'a record of opcode {opcode:#04x} inside the data '
                               'section (a damaged opcode byte?)')
            self.scan.damage.append(self.open)
            self.after_chunk = True         # its message indexes may follow
        else:
            self.skipped = (pos, end)
            self.scan.skipped.append((pos, end))
            self.after_chunk = False

    def _index(self, record: MessageIndex, pos: int) -> None:
        """A message index: it counts the messages of the chunk before it, lost if that
        chunk was (or if there is no chunk before it: a chunk whose opcode byte is
        damaged was skipped as another record)."""
        if self.open is None and not self.after_chunk:
            start, end = self.skipped or (pos, pos)
            if self.skipped in self.scan.skipped:
                self.scan.skipped.remove(self.skipped)
            self.open = Damage(start, end, 'message indexes of a chunk that is not there (a '
                               'damaged opcode byte?)')
            self.scan.damage.append(self.open)
            self.skipped = None
            self.after_chunk = True
        if self.open is not None:
            self.open.counted = True
            self.open.lost[record.channel_id] = len(record.records)

    def _damaged(self, pos: int, why: str) -> int | None:
        """Record damage from ``pos``; where reading resumes (None: nowhere)."""
        nxt = _resync(self.mem, pos + 1, self.scan.size, self.budget, self.scan.path)
        if nxt is None and (why == CUT_SHORT or 'past the end' in why):
            why = CUT_SHORT         # the record a killed writer left unfinished
        name = attachment_name(self.mem, pos, self.scan.size)
        if name is not None and why != CUT_SHORT:
            self.scan.lost_records[pos] = f'attachment {name!r}'
            why = f'attachment {name!r}: {why}'
        if nxt is None:
            self.scan.damage.append(Damage(pos, self.scan.size, why))
            return None
        self.open = Damage(pos, nxt, why)
        self.scan.damage.append(self.open)
        return nxt


def _mapped(f: Any) -> Any:
    size = f.seek(0, io.SEEK_END)
    return mmap.mmap(f.fileno(), size, access=mmap.ACCESS_READ) if size else b''


def _summary(f: Any) -> Any:
    """The summary section of the finished file ``f``, or None (a damaged summary indexes
    nothing)."""
    try:
        f.seek(0)
        return make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - a damaged summary indexes nothing
        return None


def _indexed_chunks(summary: Any, found: Scan, mem: Any) -> None:
    """Damage where the summary of a finished file indexes a chunk at a record the walk
    skipped as another kind (its opcode byte damaged, no message indexes after it)."""
    index = {c.chunk_start_offset: c for c in summary.chunk_indexes}
    for pos, end in list(found.skipped):
        if pos not in index:
            continue
        d = Damage(pos, end, 'a chunk the summary indexes, its opcode byte damaged',
                   counted=True)
        for cid, at in index[pos].message_index_offsets.items():
            try:
                record = parse_at(mem, at, found.size)[0]
            except ValueError:
                record = None
            if isinstance(record, MessageIndex) and record.channel_id == cid:
                d.lost[cid] = len(record.records)
            else:
                d.counted = False
        found.damage.append(d)
        found.skipped.remove((pos, end))


def _indexed_records(summary: Any, found: Scan) -> None:
    """Name the attachments and metadata records the summary of a finished file indexes
    where no intact record starts (damaged, or swallowed by a damaged region), by the name
    the index gives (a damaged attachment's own name field may be what was damaged)."""
    starts = {pos for pos, _ in found.spans}
    for kind, index in (('attachment', summary.attachment_indexes),
                        ('metadata', summary.metadata_indexes)):
        for entry in index:
            if entry.offset not in starts:      # its index names it, whatever it reads
                found.lost_records[entry.offset] = f'{kind} {entry.name!r}'


def scan(f: Any, path: str, budget: Budget) -> Scan:
    """Find the intact records of the open binary file ``f`` (named ``path``)."""
    mem = _mapped(f)
    try:
        result = Scan(path=path, size=len(mem))
        _Walk(result, mem, budget).run()
        summary = _summary(f) if result.footer and (result.skipped or result.damage) \
            else None
        if summary is not None and result.skipped:
            _indexed_chunks(summary, result, mem)
        if summary is not None and result.damage:
            _indexed_records(summary, result)
        return result
    finally:
        if isinstance(mem, mmap.mmap):
            mem.close()


def records(f: Any, found: Scan, budget: Budget) -> Iterator[Any]:
    """The data records of ``found``'s intact spans, in file order, chunks opened, and its
    private records (``Private``)."""
    mem = _mapped(f)
    private = set(found.skipped)
    try:
        for pos, end in sorted(found.spans + found.skipped):
            if (pos, end) in private:
                yield Private(bytes(mem[pos:end]))
                continue
            record = parse_span(mem, pos, end)
            if isinstance(record, Chunk):
                where = f'{found.path}: byte {pos}'
                try:
                    inside = chunk_records(record, budget, where)
                except McapError:       # a wrong stated size: scan found it whole
                    inside = chunk_records(resized(record, budget) or record, budget, where)
                for r in inside:
                    if isinstance(r, Message) and r.channel_id not in found.channels:
                        continue
                    yield r
            elif not (isinstance(record, Message) and record.channel_id not in found.channels):
                yield record
    finally:
        if isinstance(mem, mmap.mmap):
            mem.close()
