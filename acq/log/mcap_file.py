"""One MCAP file written record by record, each chunk compressed only where it pays.

mcap's own ``Writer`` compresses every chunk alike and copies each message several times
(into the chunk, the chunk into its record, the record into the stream); a JPEG costs
zstd (which cannot shrink it) and the copies at every byte, the recorder's main cost at
100+ MB/s. :class:`McapFile` writes the same records (header; schemas and channels in
the chunks as they come; metadata between chunks; each chunk followed by its message
indexes; data end; the summary: schemas, channels, statistics, chunk, attachment and
metadata indexes, summary offsets; footer) with mcap's record classes, except for the
messages and their chunk, built here:

- a message's bytes are not copied: a chunk is a list of pieces (the small records
  joined, each large payload kept as given) handed to ``out.write_pieces`` in one call;
- a chunk at least :data:`STORED_SHARE` (90 %) of whose bytes are the data of
  *incompressible* channels (JPEG images) is stored uncompressed (compression ``""``):
  zstd could save a few percent of it at the cost of running over all of it. The others
  are compressed with ``compression`` (zstd: scans, telegrams and status shrink 2-3x, so
  a rig of small frames, about 60 % JPEG, keeps files a fifth smaller this way).

Times in ns, sizes in bytes. ``out`` needs ``write(bytes)``, ``write_pieces(list)``
(every piece written, in order, as one write) and ``tell()``.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from typing import Protocol

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC

__all__ = ["STORED_SHARE", "McapFile", "Out"]

Piece = bytes | bytearray | memoryview

# a message record's head: opcode, record length, channel, sequence, log and publish time
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
# a chunk record up to its records: opcode, length, start and end time, uncompressed size
# and CRC, then the compression string and the records' length (packed apart)
_CHUNK_HEAD = struct.Struct("<BQQQQI")
_LARGE = 64 * 1024  # a payload this large is a piece of its own, not copied
STORED_SHARE = 0.9  # a chunk this much incompressible payload is stored uncompressed
_COMPRESSORS = {"zstd": zstandard.compress, "": None}


class Out(Protocol):
    """Where the file goes (:class:`acq.log.writer` hands an unbuffered descriptor)."""

    def write(self, data: bytes) -> int: ...

    def write_pieces(self, pieces: Sequence[Piece]) -> int: ...

    def tell(self) -> int: ...


class _Chunk:
    """The open chunk: its records as pieces, its message indexes and times."""

    def __init__(self) -> None:
        self.pieces: list[Piece] = []
        self.small = bytearray()  # small records not yet a piece
        self.size = 0  # bytes of records
        self.incompressible = 0  # bytes of incompressible payloads
        self.messages = 0
        self.start = 0
        self.end = 0
        self.index: dict[int, list[tuple[int, int]]] = {}  # channel -> (log time, offset)

    def add(self, record: Piece) -> None:
        if len(record) >= _LARGE:
            if self.small:
                self.pieces.append(self.small)
                self.small = bytearray()
            self.pieces.append(record)
        else:
            self.small += record
        self.size += len(record)

    def records(self) -> list[Piece]:
        if self.small:
            self.pieces.append(self.small)
            self.small = bytearray()
        return self.pieces


class McapFile:
    """Writes one MCAP file to ``out`` (see the module docstring); chunks end when their
    records pass ``chunk_size`` bytes, or at :meth:`flush`."""

    def __init__(self, out: Out, chunk_size: int, compression: str = "zstd") -> None:
        if compression not in _COMPRESSORS:
            raise ValueError(f"unknown chunk compression {compression!r}")
        self.out = out
        self.chunk_size = chunk_size
        self.compression = compression
        self._builder = RecordBuilder()
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._incompressible: set[int] = set()
        self._chunk = _Chunk()
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._stats = Statistics(
            attachment_count=0,
            channel_count=0,
            channel_message_counts={},
            chunk_count=0,
            message_count=0,
            metadata_count=0,
            message_start_time=0,
            message_end_time=0,
            schema_count=0,
        )

    @property
    def open_chunk_bytes(self) -> int:
        """Bytes of records in the open chunk (not yet in the file)."""
        return self._chunk.size

    def start(self, profile: str, library: str) -> None:
        self.out.write(MCAP0_MAGIC)
        Header(profile=profile, library=library).write(self._builder)
        self._flush_builder()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = len(self._schemas) + 1
        schema = Schema(id=schema_id, data=data, encoding=encoding, name=name)
        self._schemas[schema_id] = schema
        self._stats.schema_count += 1
        self._chunk.add(_record(schema))
        return schema_id

    def register_channel(
        self,
        topic: str,
        encoding: str,
        schema_id: int,
        metadata: dict[str, str],
        compressible: bool = True,
    ) -> int:
        """A channel; ``compressible`` False: its payloads are already compressed (JPEG)."""
        channel_id = len(self._channels) + 1
        channel = Channel(
            id=channel_id, topic=topic, message_encoding=encoding, schema_id=schema_id,
            metadata=metadata,
        )  # fmt: skip
        self._channels[channel_id] = channel
        if not compressible:
            self._incompressible.add(channel_id)
        self._stats.channel_count += 1
        self._chunk.add(_record(channel))
        return channel_id

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int) -> None:
        chunk, stats = self._chunk, self._stats
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        stats.message_end_time = max(log_time, stats.message_end_time)
        counts = stats.channel_message_counts
        counts[channel_id] = counts.get(channel_id, 0) + 1
        stats.message_count += 1
        if chunk.messages == 0 or log_time < chunk.start:
            chunk.start = log_time
        chunk.end = max(log_time, chunk.end)
        chunk.messages += 1
        chunk.index.setdefault(channel_id, []).append((log_time, chunk.size))
        n = len(data)
        chunk.add(_MESSAGE_HEAD.pack(Opcode.MESSAGE, 22 + n, channel_id, 0, log_time, publish_time))
        chunk.add(data)
        if channel_id in self._incompressible:
            chunk.incompressible += n
        if chunk.size > self.chunk_size:
            self._end_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record, between chunks: the open one ends first if it holds a message
        (mcap's writer would write the record before it), so the file holds the records in
        the order they were given."""
        self._end_chunk()
        offset = self.out.tell()
        self._stats.metadata_count += 1
        Metadata(name=name, metadata=data).write(self._builder)
        self._metadata_indexes.append(
            MetadataIndex(offset=offset, length=self._builder.count, name=name)
        )
        self._flush_builder()

    def flush(self) -> None:
        """End the open chunk now (if it holds a message) and write it."""
        self._end_chunk()

    def finish(self) -> None:
        """The last chunk, data end, summary, footer and magic."""
        self._end_chunk()
        DataEnd(data_section_crc=0).write(self._builder)
        self._flush_builder()
        summary_start = self.out.tell()
        summary = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(
            opcode: Opcode,
            records: Sequence[Schema | Channel | Statistics | ChunkIndex | MetadataIndex],
        ) -> None:
            start = summary.count
            for record in records:
                record.write(summary)
            offsets.append(
                SummaryOffset(
                    group_opcode=opcode,
                    group_start=summary_start + start,
                    group_length=summary.count - start,
                )
            )

        group(Opcode.SCHEMA, list(self._schemas.values()))
        group(Opcode.CHANNEL, list(self._channels.values()))
        group(Opcode.STATISTICS, [self._stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        offset_start = summary_start + summary.count
        for offset in offsets:
            offset.write(summary)
        data = summary.end()
        start = 0 if len(data) == 0 else summary_start
        crc = zlib.crc32(data)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, start, offset_start), crc)
        self.out.write(data)
        Footer(summary_start=start, summary_offset_start=offset_start, summary_crc=crc).write(
            self._builder
        )
        self._flush_builder()
        self.out.write(MCAP0_MAGIC)

    # --- internals -----------------------------------------------------------------------

    def _flush_builder(self) -> None:
        self.out.write(self._builder.end())

    def _end_chunk(self) -> None:
        chunk = self._chunk
        if chunk.messages == 0:
            return
        self._chunk = _Chunk()
        records = chunk.records()
        crc = 0
        for piece in records:
            crc = zlib.crc32(piece, crc)
        compress = _COMPRESSORS[self.compression]
        if compress is None or chunk.incompressible >= STORED_SHARE * chunk.size:
            compression, body = "", records
        else:
            compression, body = self.compression, [compress(b"".join(records))]
        body_size = sum(len(p) for p in body)
        name = compression.encode()
        head = (
            _CHUNK_HEAD.pack(
                Opcode.CHUNK,
                8 + 8 + 8 + 4 + 4 + len(name) + 8 + body_size,
                chunk.start,
                chunk.end,
                chunk.size,
                crc,
            )
            + struct.pack("<I", len(name))
            + name
            + struct.pack("<Q", body_size)
        )
        chunk_start = self.out.tell()
        chunk_length = len(head) + body_size
        index = RecordBuilder()
        offsets: dict[int, int] = {}
        message_index_start = chunk_start + chunk_length
        for channel_id, entries in chunk.index.items():
            offsets[channel_id] = message_index_start + index.count
            MessageIndex(channel_id=channel_id, records=entries).write(index)
        indexes = index.end()
        self.out.write_pieces([head, *body, indexes])
        self._stats.chunk_count += 1
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.start,
                message_end_time=chunk.end,
                chunk_start_offset=chunk_start,
                chunk_length=chunk_length,
                message_index_offsets=offsets,
                message_index_length=len(indexes),
                compression=compression,
                compressed_size=body_size,
                uncompressed_size=chunk.size,
            )
        )


def _record(record: Schema | Channel) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())
