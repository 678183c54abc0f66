"""Follow a log while its writer appends to it, reading only what is new: each
:meth:`LogTail.poll` goes on from the byte where the last one stopped, up to the last
complete record, and decodes the messages of the topics asked for from the newest
chunks only.

:class:`acq.log.LogReader` reads a whole file in one pass, from its start (or, closed,
from its index); a view refreshed every second of a 10 GB file being written cannot.
Here the first poll hops over the records already in the file (9 bytes read per record,
the bodies skipped), opening chunks only until the channels are known (the channels of
the wanted topics, or a first chunk of messages: acq's writer registers every channel
before its first message) and then the last ``back_chunks``; later polls read the chunks
written since. A closed file (footer and summary valid) is read from its index: its last
chunks.

The chunks' headers also give the write rate (:meth:`LogTail.write_rate`): the bytes
between chunks over the log time between their last messages.
"""

from __future__ import annotations

import io
import os
import struct
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

from acq.log.mcap_magic import MAGIC, check_magic
from acq.log.mcap_records import HEADER_BYTES, KNOWN_OPCODES, RECORD_ERRORS, chunk_records

__all__ = ["LogTail", "Tailed"]

_CHUNK_TIMES = struct.Struct("<QQ")  # a chunk's first and last message log time, ns
RATE_WINDOW_S = 30.0  # the write rate is measured over the chunks of this much log time


@dataclass(frozen=True)
class Tailed:
    """One message of a wanted topic: its topic, log time (ns, as in the file) and the
    decoded protobuf message (None: it did not decode)."""

    topic: str
    log_time: int
    decoded: Any


class LogTail:
    """Follows the log at ``path``; :meth:`poll` gives the messages of ``topics`` from the
    chunks completed since the last poll (of many, the newest ``back_chunks``: a view
    wants the newest state, not every message). ``metadata``: the file's metadata
    records by name (the last of each name); ``finished``: its footer was read (the
    writer closed it); ``offset``: the byte after the last complete record read.

    Raises :class:`acq.log.mcap_magic.LogError` at once for a file that is missing or
    not MCAP."""

    def __init__(self, path: str | os.PathLike[str], topics: Iterable[str], back_chunks: int = 2):
        self.path = Path(path)
        check_magic(self.path)
        self.topics = frozenset(topics)
        self.back_chunks = max(int(back_chunks), 1)
        self.offset = len(MAGIC)
        self.finished = False
        self.metadata: dict[str, dict[str, str]] = {}
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._factory = DecoderFactory()
        self._decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self._chunk_ends: deque[tuple[int, int]] = deque()  # (end byte, last log time ns)
        self._first = True
        self._messages_seen = False  # a chunk with messages was opened

    def poll(self) -> list[Tailed]:
        """The wanted messages completed since the last call, in file order."""
        with self.path.open("rb") as f:
            size = os.fstat(f.fileno()).st_size
            if self._first:
                self._first = False
                indexed = self._closed(f, size)
                if indexed is not None:
                    return indexed
            if self.finished:
                return []
            chunks = self._hop(f, size)
            out: list[Tailed] = []
            for k, (at, length) in enumerate(chunks):
                if k >= len(chunks) - self.back_chunks or not self._known():
                    f.seek(at)
                    out += self._chunk(f.read(length))
            return out

    def write_rate(self) -> float | None:
        """Bytes per second of log time over the last :data:`RATE_WINDOW_S` of chunks
        (None: fewer than two chunks, or no time between them)."""
        if len(self._chunk_ends) < 2:
            return None
        (b0, t0), (b1, t1) = self._chunk_ends[0], self._chunk_ends[-1]
        return (b1 - b0) / ((t1 - t0) * 1e-9) if t1 > t0 else None

    def _known(self) -> bool:
        """Whether the channels are known: every wanted topic's seen, or a chunk of
        messages read (acq's writer registers its channels at the file's start, before
        any message: later chunks need not be opened to learn them)."""
        return self._messages_seen or self.topics <= {c.topic for c in self._channels.values()}

    def _hop(self, f: Any, size: int) -> list[tuple[int, int]]:
        """Walk the complete records from :attr:`offset`: top-level schemas, channels and
        metadata parsed, chunks only noted (byte, length) and their times kept for the
        write rate; stops before a record not yet whole, or at the footer."""
        chunks: list[tuple[int, int]] = []
        pos = self.offset
        while pos + HEADER_BYTES <= size:
            f.seek(pos)
            opcode, length = struct.unpack("<BQ", f.read(HEADER_BYTES))
            end = pos + HEADER_BYTES + length
            if opcode == 0 or end > size:  # not yet written (or a zero-filled tail)
                break
            if opcode == Opcode.CHUNK:
                chunks.append((pos, HEADER_BYTES + length))
                _, last_ns = _CHUNK_TIMES.unpack(f.read(_CHUNK_TIMES.size))
                self._note_chunk(end, last_ns)
            elif opcode == Opcode.FOOTER:
                self.finished = True
                self.offset = end
                break
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA):
                self._take(_parse(f.read(length), opcode, length))
            pos = self.offset = end
        return chunks

    def _note_chunk(self, end: int, last_ns: int) -> None:
        self._chunk_ends.append((end, last_ns))
        while len(self._chunk_ends) > 2 and last_ns - self._chunk_ends[1][1] > RATE_WINDOW_S * 1e9:
            self._chunk_ends.popleft()

    def _take(self, record: Any) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channels[record.id] = record
        elif isinstance(record, Metadata):
            self.metadata[record.name] = dict(record.metadata)

    def _chunk(self, data: bytes) -> list[Tailed]:
        """The wanted messages of one whole chunk record (``data``: header and body); a
        corrupt chunk gives none."""
        record = _parse(data[HEADER_BYTES:], Opcode.CHUNK, len(data) - HEADER_BYTES)
        if not isinstance(record, Chunk):
            return []
        try:
            inner = chunk_records(record)
        except RECORD_ERRORS:
            return []
        out = []
        for r in inner:
            if isinstance(r, Message):
                self._messages_seen = True
                one = self._message(r)
                if one is not None:
                    out.append(one)
            else:
                self._take(r)
        return out

    def _message(self, message: Message) -> Tailed | None:
        channel = self._channels.get(message.channel_id)
        if channel is None or channel.topic not in self.topics:
            return None
        try:
            decoder = self._decoders[channel.id]
        except KeyError:
            schema = self._schemas.get(channel.schema_id)
            try:
                decoder = self._factory.decoder_for(channel.message_encoding, schema)
            except Exception:  # a schema the file garbled: its messages are None
                decoder = None
            self._decoders[channel.id] = decoder
        try:
            decoded = decoder(message.data) if decoder is not None else None
        except Exception:  # a garbled payload
            decoded = None
        return Tailed(channel.topic, message.log_time, decoded)

    def _closed(self, f: Any, size: int) -> list[Tailed] | None:
        """A closed file read from its index: its metadata and last chunks (None: not
        closed, or its summary is unreadable)."""
        tail = size - HEADER_BYTES - 20 - len(MAGIC)
        if tail <= len(MAGIC):
            return None
        f.seek(tail)
        if f.read(1) != bytes([Opcode.FOOTER]):
            return None
        try:
            f.seek(0)
            reader = SeekingReader(f, validate_crcs=True)
            summary = reader.get_summary()
            metadata = list(reader.iter_metadata())
        except RECORD_ERRORS:
            return None
        if summary is None:
            return None
        self.finished = True
        self.offset = size
        self._schemas.update(summary.schemas)
        self._channels.update(summary.channels)
        for m in metadata:
            self._take(m)
        indexes = sorted(summary.chunk_indexes, key=lambda i: i.chunk_start_offset)
        for i in indexes:
            self._note_chunk(i.chunk_start_offset + i.chunk_length, i.message_end_time)
        # the last chunks holding a wanted topic (the index says which channels a chunk
        # holds): the very last may hold none, ended early by a metadata record
        wanted = {c.id for c in self._channels.values() if c.topic in self.topics}
        holding = [i for i in indexes if wanted & i.message_index_offsets.keys()]
        out: list[Tailed] = []
        for i in holding[-self.back_chunks :]:
            f.seek(i.chunk_start_offset)
            out += self._chunk(f.read(i.chunk_length))
        return out


def _parse(body: bytes, opcode: int, length: int) -> Any:
    """One record from its body (None: garbled or of an unknown kind)."""
    if opcode not in KNOWN_OPCODES:
        return None
    head = struct.pack("<BQ", opcode, length)
    try:
        return next(
            StreamReader(
                io.BytesIO(head + body), skip_magic=True, emit_chunks=True, record_size_limit=None
            ).records,
            None,
        )
    except RECORD_ERRORS:
        return None
