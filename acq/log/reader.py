"""Read acq MCAP logs, including logs whose writer was killed: one reader, a decoder
cached per channel.

A log whose footer and summary are present and valid is *closed*: it is read with
mcap's seeking reader, chunk by chunk from its index. Any other log (writer killed,
power lost, disk full, still being written) is read linearly, one record at a time,
until the first record that is cut short, zero-filled or garbled: every message of a
complete chunk before that point is returned, and the point is reported. A complete
chunk whose CRC or compression is bad is skipped and reported, and reading goes on
after it (its length is known, so the records after it are still framed). Skipped chunks
are also logged, one WARNING line per file naming their times and the messages lost, once
per process (a command that reads a file several times says it once); :func:`quiet`
leaves that to a caller that reports the damage itself (``acq info``); both in
:mod:`acq.log.skipped_chunks`. A file that is not MCAP at all raises :class:`LogError`
(:mod:`acq.log.mcap_magic`).

Messages are decoded from the schemas stored in the file, never from our own
generated classes, so older logs with fewer fields still read: :meth:`LogReader.decode`
makes one decoder per channel, the first time a message of that channel is decoded
(mcap's ``McapReader`` with a ``DecoderFactory`` does the same for closed files).

Times are integer nanoseconds of the host monotonic clock, whatever the log's clock
(:mod:`acq.log.timebase`): in a UTC log, :meth:`LogReader.messages` gives ``log_time``
and ``publish_time`` less the session's offset, and :meth:`LogReader.decode` the
Foxglove messages' timestamps likewise (:mod:`acq.log.stamp_shift`);
:meth:`LogReader.records` gives the records as they are in the file.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from collections import deque
from collections.abc import Callable, Generator, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import IO, Any, TypeVar

from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    Footer,
    Header,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from mcap_protobuf.decoder import DecoderFactory

from acq import progress
from acq.log import skipped_chunks, writer_lock
from acq.log.clock_source import ClockSource
from acq.log.mcap_magic import MAGIC, LogError, check_magic, zeros_or_garbage
from acq.log.mcap_records import (
    HEADER_BYTES,
    KNOWN_OPCODES,
    RECORD_ERRORS,
    chunk_records,
    indexed_messages,
    record_name,
)
from acq.log.rosbag_source import acq_records, is_bag, laser_channels
from acq.log.schema_match import mismatch
from acq.log.skipped_chunks import Skipped, quiet
from acq.log.stamp_shift import stamps_to_host
from acq.log.timebase import TimeBase

__all__ = [
    "LogError",
    "LogReader",
    "quiet",
    "read_messages",
    "read_metadata",
]

log = logging.getLogger(__name__)

_FOOTER = HEADER_BYTES + 8 + 8 + 4  # a whole Footer record, bytes
_NO_SUMMARY = "no summary section"


Decoder = Callable[[bytes], Any]
T = TypeVar("T")


class LogReader:
    """One pass over a log: :meth:`records` (every record, in file order), :meth:`messages`
    (each message with its schema and channel) or :meth:`decoded` (those of chosen
    channels, decoded), and :meth:`decode` (one message, by its channel's decoder).

    Raises :class:`LogError` at once (not on first iteration) for a missing file or one
    that is not MCAP. After the pass, ``closed``, ``bytes_read`` (where reading stopped,
    bytes; the file size when closed) and :meth:`problem` say how it went, and
    :meth:`messages` leaves the file's ``metadata`` records and its ``attachments`` count.
    ``log_time`` (first, last) host monotonic ns: a closed file's chunks whose messages all
    lie outside it are not read (others may still yield messages outside it: the caller
    filters). ``time_base``: the log's clock, from its ``acq`` metadata record once
    reading has passed it (the writer puts it first). ``writing``: its writer was alive
    when the pass began (:mod:`acq.log.writer_lock`). ``progress``: the bytes read move a
    progress bar (:mod:`acq.progress`); False for a glance at a file's start.

    A log whose ``acq`` record does not name its clock (none: a copy made without its
    metadata records; an unusable ``utc_offset_ns``) is read on the clock its messages
    show (:mod:`acq.log.clock_source`), said once with what is missing (also in
    :meth:`problem`). ``raw_times``: the times as in the file, whatever the metadata.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        log_time: tuple[int, int] | None = None,
        *,
        progress: bool = True,
        raw_times: bool = False,
    ) -> None:
        self.path = Path(path)
        self.log_time = log_time
        self.size = check_magic(self.path)
        self.progress = progress
        self.closed = False
        self.writing = False
        self.bytes_read = len(MAGIC)
        self._shown = 0  # bytes reported to a progress bar (acq.progress)
        self.stop: str | None = None  # why a linear pass stopped before a valid footer
        self.notes: list[str] = []  # damage that did not stop the pass
        self.expected_messages: int | None = None  # from the summary's statistics
        self.footer_at: int | None = None  # a footer the linear pass reached, byte offset
        self.metadata: list[Metadata] = []
        self._clock = ClockSource(self.path, LogReader, raw_times)
        self.attachments = 0
        self.skipped: list[Skipped] = []  # the corrupt chunks skipped
        self._start_ns: int | None = None  # the file's first log time, for the warning
        self._end_ns: int | None = None  # the last log time read, for the warning
        self._factory = DecoderFactory()  # per file: it caches message classes by schema id
        self._decoders: dict[int, Decoder | None] = {}  # by channel id; None: undecodable
        # messages not decoded, by topic, and why (the first failure's reason)
        self.undecodable: dict[str, int] = {}
        self._why: dict[str, tuple[str, str]] = {}  # topic -> (schema name, reason)

    @property
    def time_base(self) -> TimeBase:
        """The log's clock (:mod:`acq.log.clock_source`)."""
        return self._clock.time_base

    def problem(self) -> str | None:
        """One line: what is wrong with the file, or None."""
        parts = []
        if not self.closed and self.footer_at is not None:
            why = (
                " (as the recorder ends a file after a full disk)"
                if self.stop == _NO_SUMMARY
                else ""
            )
            parts.append(
                f"not indexed: a footer at byte {self.footer_at} but {self.stop}{why};"
                " read linearly, every record before it"
            )
        elif not self.closed and self.writing:
            rest = self.size - self.bytes_read
            tail = f" (the {rest} after them are still being written)" if rest > 0 else ""
            parts.append(
                f"being written: its recorder is running (it holds the file's lock); read"
                f" the {self.bytes_read} bytes written so far{tail}"
            )
        elif not self.closed:
            parts.append(
                f"not closed: the writer stopped at byte {self.bytes_read} of {self.size}"
                f" ({self.stop or 'no footer'}); read everything before it"
            )
        parts.extend(self.notes)
        if self._clock.note:
            parts.append(self._clock.note)
        return "; ".join(parts) or None

    def records(self) -> Generator[McapRecord, None, None]:
        """Header, Schema, Channel, Message, Metadata and Attachment records in file order
        (a closed file's schemas, channels, metadata and attachments first, from its
        summary and index)."""
        whole = False  # the pass reached the file's end: its span is known
        try:
            with self.path.open("rb") as f:
                self.writing = writer_lock.locked(f)
                summary = self._closed_summary(f)
                if summary is not None and summary.chunk_indexes:
                    self.closed = True
                    yield from self._indexed(f, summary)
                else:
                    self.closed = summary is not None
                    f.seek(len(MAGIC))
                    yield from self._linear(f)
            whole = True
        finally:  # also when the caller stops early: what was skipped until then
            self._report_skipped()
            if whole:
                self._report_cut()
            self._shown_to(self.size)

    def _shown_to(self, pos: int) -> None:
        """Reading has got to byte ``pos``: the bytes since the last call to a progress bar."""
        if pos > self._shown and self.progress:
            progress.advance(pos - self._shown)
            self._shown = pos

    def _report_skipped(self) -> None:
        """One WARNING line for the corrupt chunks skipped that this process has not
        reported yet (unless :func:`quiet`)."""
        new = skipped_chunks.unreported(self.path, self.skipped)
        if new:
            log.warning("%s: %s", self.path, skipped_chunks.describe(new, self._start_ns))

    def _report_cut(self) -> None:
        """One WARNING line, once per process and file (unless :func:`quiet`), for a file
        that is not closed: being written or cut, and the span of log time read."""
        if self.closed or not skipped_chunks.unreported_cut(self.path):
            return
        how = skipped_chunks.describe_cut(
            self.writing, self.footer_at, self.stop, self._start_ns, self._end_ns,
            self.time_base.utc_offset_ns, self.bytes_read,
        )  # fmt: skip
        log.warning("%s: %s", self.path, how)

    def messages(self) -> Generator[tuple[Schema | None, Channel, Message], None, None]:
        """(schema, channel, message) of every readable message, in file order. When the
        pass ends, one WARNING per channel whose messages did not decode (:meth:`decode`),
        with their count."""
        try:
            yield from self._messages()
        finally:
            self._report_undecodable()

    def _messages(self) -> Iterator[tuple[Schema | None, Channel, Message]]:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        orphans = 0
        for record in acq_records(self.records(), self.notes):  # a rosbag2 as a log
            if isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    orphans += 1
                    continue
                offset = self.time_base.utc_offset_ns
                if offset:
                    record.log_time -= offset
                    record.publish_time -= offset
                yield schemas.get(channel.schema_id), channel, record
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata):
                self.metadata.append(record)
            elif isinstance(record, Attachment):
                self.attachments += 1
        if orphans:
            self.notes.append(f"{orphans} messages on unknown channels skipped")

    def decode(self, schema: Schema | None, channel: Channel, message: Message) -> Any:
        """The message decoded by its channel's schema (a protobuf message), or None when
        the schema or the payload cannot be decoded (counted in ``undecodable``, by
        topic). A Foxglove message's timestamps are host monotonic ns (see the module
        docstring)."""
        try:
            decoder = self._decoders[channel.id]
        except KeyError:
            decoder = self._decoders[channel.id] = self._decoder_for(schema, channel)
        if decoder is None:
            self.undecodable[channel.topic] = self.undecodable.get(channel.topic, 0) + 1
            return None
        try:
            decoded = decoder(message.data)
        except DecodeError as e:  # a garbled payload
            self.undecodable[channel.topic] = self.undecodable.get(channel.topic, 0) + 1
            why = f"garbled payloads (DecodeError: {e or 'no reason given'})"
            self._why.setdefault(channel.topic, (_schema_name(schema), why))
            return None
        if schema is not None:
            stamps_to_host(decoded, schema.name, self.time_base.utc_offset_ns)
        return decoded

    def decoded(
        self, wanted: Callable[[Schema | None, Channel], T | None]
    ) -> Iterator[tuple[T, Channel, Message, Any]]:
        """The messages of the channels for which ``wanted`` gives a value (it is asked once
        per channel), in file order, as (that value, channel, message, decoded), decoded
        as by :meth:`decode`."""
        values: dict[int, T | None] = {}
        for schema, channel, message in self.messages():
            try:
                value = values[channel.id]
            except KeyError:
                value = values[channel.id] = wanted(schema, channel)
            if value is not None:
                yield value, channel, message, self.decode(schema, channel, message)

    def why_undecodable(self, topic: str) -> str:
        """Why the messages of ``topic`` did not decode (the first failure's reason)."""
        return self._why.get(topic, ("?", "unknown"))[1]

    def _decoder_for(self, schema: Schema | None, channel: Channel) -> Decoder | None:
        if schema is not None and channel.message_encoding == "protobuf":
            foreign = mismatch(schema.name, schema.encoding, schema.data)
            if foreign is not None:  # decoded, its fields would all read as unset
                why = f"its schema is not acq's {schema.name} ({foreign})"
                self._why[channel.topic] = (schema.name, why)
                return None
        try:
            decoder = self._factory.decoder_for(channel.message_encoding, schema)
        except Exception as e:  # a schema the file garbled: its messages counted, not decoded
            why = f"its schema: {type(e).__name__}: {e}"
            self._why[channel.topic] = (_schema_name(schema), why)
            return None
        if decoder is None:  # another encoding (json, ros2msg...) under whatever name
            why = f"its messages are {channel.message_encoding!r}, not acq's protobuf"
            self._why[channel.topic] = (_schema_name(schema), why)
        return decoder

    def _report_undecodable(self) -> None:
        """One WARNING per channel whose messages did not decode (this pass's count),
        once per process and file (unless :func:`quiet`)."""
        for topic, n in skipped_chunks.unreported_topics(self.path, self.undecodable).items():
            name, why = self._why.get(topic, ("?", "unknown"))
            log.warning("%s: %s (%s) cannot be decoded: %s; %d messages skipped",
                        self.path, topic, name, why, n)  # fmt: skip

    # -- closed files: mcap's seeking reader and the chunk index ----------------------

    def _closed_summary(self, f: IO[bytes]) -> Summary | None:
        """The summary when the footer and summary are present and valid, else None."""
        size = self.size
        if size < len(MAGIC) + _FOOTER + len(MAGIC):
            return None
        f.seek(size - _FOOTER - len(MAGIC))
        tail = f.read(_FOOTER + len(MAGIC))
        if tail[-len(MAGIC) :] != MAGIC:
            return None
        opcode, length, start, offsets_start, crc = struct.unpack("<BQQQI", tail[:_FOOTER])
        footer_at = size - _FOOTER - len(MAGIC)
        if opcode != Opcode.FOOTER or length != _FOOTER - HEADER_BYTES:
            return None
        if start == 0:
            self.stop = _NO_SUMMARY
            return None
        if not len(MAGIC) < start <= footer_at or offsets_start > footer_at:
            self.stop = f"the footer points outside the file (summary at byte {start})"
            return None
        if crc:
            f.seek(start)
            calculated = 0
            remaining = footer_at - start
            while remaining:
                block = f.read(min(remaining, 1 << 20))
                if not block:
                    break
                calculated = zlib.crc32(block, calculated)
                remaining -= len(block)
            calculated = zlib.crc32(tail[: HEADER_BYTES + 16], calculated)
            if calculated != crc:
                self.stop = f"bad summary CRC (summary at byte {start})"
                return None
        try:
            f.seek(0)  # SeekingReader checks the magic where the stream is, not at byte 0
            summary = SeekingReader(f, validate_crcs=True).get_summary()
        except RECORD_ERRORS as e:
            self.stop = f"unreadable summary at byte {start}: {e}"
            return None
        if summary is not None and summary.statistics is not None:
            self.expected_messages = summary.statistics.message_count
            if summary.statistics.message_count:
                self._start_ns = summary.statistics.message_start_time
        return summary

    def _indexed(self, f: IO[bytes], summary: Summary) -> Iterator[McapRecord]:
        f.seek(0)
        reader = SeekingReader(f, validate_crcs=True)
        header = reader.get_header()
        self._clock.header(header)
        yield header
        yield from summary.schemas.values()
        yield from summary.channels.values()
        try:
            extras: list[McapRecord] = [*reader.iter_metadata(), *reader.iter_attachments()]
        except RECORD_ERRORS as e:
            extras = []
            self.notes.append(f"unreadable metadata or attachments ({e})")
        self._clock.take(extras)
        if self._start_ns is None and summary.chunk_indexes:
            self._start_ns = min(i.message_start_time for i in summary.chunk_indexes)
        self._clock.first_message(self._start_ns, extras)
        yield from extras
        count = 0
        lo, hi = self.log_time or (-(2**63), 2**64)
        lo, hi = self.time_base.to_log(lo), self.time_base.to_log(hi)
        by_start = {index.chunk_start_offset: index for index in summary.chunk_indexes}
        starts = sorted(
            index.chunk_start_offset
            for index in summary.chunk_indexes
            if index.message_end_time >= lo and index.message_start_time <= hi
        )
        # each chunk read here, decompressed and parsed on a thread two chunks ahead of
        # the caller (the decompression and its CRC run without the GIL)
        with ThreadPoolExecutor(max_workers=1) as pool:

            def ahead(at: int) -> Future[list[McapRecord]]:
                try:
                    f.seek(at)
                    record = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
                    if not isinstance(record, Chunk):
                        raise McapError(f"expected a chunk, found {type(record).__name__}")
                    return pool.submit(chunk_records, record, True)
                except RECORD_ERRORS as e:
                    failed: Future[list[McapRecord]] = Future()
                    failed.set_exception(e)
                    return failed

            queued = deque(ahead(at) for at in starts[:2])
            for k, at in enumerate(starts):
                done = queued.popleft()
                if k + 2 < len(starts):
                    queued.append(ahead(starts[k + 2]))
                try:
                    inner = done.result()
                except RECORD_ERRORS as e:
                    self.notes.append(f"corrupt chunk at byte {at} skipped ({e})")
                    index = by_start[at]
                    self.skipped.append(
                        Skipped(
                            at,
                            index.message_start_time,
                            index.message_end_time,
                            indexed_messages(f, index),
                        )
                    )
                    continue
                self._shown_to(at + by_start[at].chunk_length)
                for rec in inner:
                    if isinstance(rec, Message):
                        count += 1
                        yield rec
        self.bytes_read = self.size
        damaged = bool(self.notes)
        whole = len(starts) == len(summary.chunk_indexes)
        if self.expected_messages not in (None, count) and whole and not damaged:
            self.notes.append(
                f"the summary counts {self.expected_messages} messages, the chunks hold {count}"
            )

    # -- anything else: a linear scan that stops at the cut ---------------------------

    def _linear(self, f: IO[bytes]) -> Iterator[McapRecord]:
        """Records one by one: check the framing ourselves (so a cut or a zero-filled tail
        is seen for what it is, and no garbage length makes us allocate), then let mcap's
        StreamReader parse each complete record."""
        pos = len(MAGIC)
        size = self.size
        lost: Skipped | None = None  # a corrupt chunk whose message index records follow
        while True:
            self.bytes_read = pos
            self._shown_to(pos)
            if pos == size:
                self.stop = "no footer after the last complete record"
                return
            head = f.read(HEADER_BYTES)
            if len(head) < HEADER_BYTES:
                self.stop = f"truncated record header at byte {pos}"
                return
            opcode, length = struct.unpack("<BQ", head)
            if opcode == 0:
                self.stop = zeros_or_garbage(f, pos, self.size)
                return
            present = size - pos - HEADER_BYTES
            if length > present:
                self.stop = (
                    f"truncated {record_name(opcode)} record at byte {pos}:"
                    f" {length} bytes declared, {present} present"
                )
                return
            body = f.read(length)
            # a private (0x80+) or newer record: skipped, as mcap does
            if opcode not in KNOWN_OPCODES:
                pos += HEADER_BYTES + length
                continue
            try:
                record = next(
                    StreamReader(
                        io.BytesIO(head + body),
                        skip_magic=True,
                        emit_chunks=True,
                        record_size_limit=None,
                    ).records,
                    None,
                )
            except RECORD_ERRORS as e:
                if opcode == Opcode.CHUNK:
                    self.notes.append(f"corrupt chunk at byte {pos} skipped ({e})")
                    self.skipped.append(Skipped(pos))
                    lost = None
                    pos += HEADER_BYTES + length
                    continue
                self.stop = f"corrupt {record_name(opcode)} record at byte {pos}: {e}"
                return
            if isinstance(record, Footer):
                end = pos + HEADER_BYTES + length
                trailer = f.read(len(MAGIC))
                if trailer != MAGIC:
                    self.bytes_read = end
                    how = "cut short" if MAGIC.startswith(trailer) else "bad"
                    self.stop = f"the closing magic after the footer at byte {pos} is {how}"
                    return
                self.bytes_read = end + len(MAGIC)
                if self.bytes_read < size:
                    self.notes.append(f"{size - self.bytes_read} bytes after the end ignored")
                if not self.closed:
                    self.footer_at = pos
                    self.stop = self.stop or "no valid summary"
                return
            if isinstance(record, MessageIndex):
                if lost is not None:
                    lost.messages = (lost.messages or 0) + len(record.records)
            else:
                lost = None
            if isinstance(record, Header):
                self._clock.header(record)
            elif isinstance(record, Chunk | Message):
                first = record.message_start_time if isinstance(record, Chunk) else record.log_time
                self._clock.first_message(first, self.metadata)
            if isinstance(record, Chunk):
                if self._start_ns is None:
                    self._start_ns = record.message_start_time
                try:
                    yield from chunk_records(record)
                    self._end_ns = max(self._end_ns or 0, record.message_end_time)
                except RECORD_ERRORS as e:
                    self.notes.append(f"corrupt chunk at byte {pos} skipped ({e})")
                    lost = Skipped(pos, record.message_start_time, record.message_end_time)
                    self.skipped.append(lost)
            elif isinstance(record, Header | Schema | Channel | Message | Metadata | Attachment):
                if isinstance(record, Message):
                    if self._start_ns is None:
                        self._start_ns = record.log_time
                    self._end_ns = max(self._end_ns or 0, record.log_time)
                if isinstance(record, Metadata):
                    self._clock.take([record])
                yield record
            pos += HEADER_BYTES + length


def _schema_name(schema: Schema | None) -> str:
    return schema.name if schema is not None else "no schema"


def read_messages(
    path: str | os.PathLike[str], log_time: tuple[int, int] | None = None
) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Every readable message of a log as (schema, channel, message), in file order
    (:meth:`LogReader.messages`); raises :class:`LogError` at once for a file that is
    missing or not MCAP."""
    return LogReader(path, log_time).messages()


def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, str]]:
    """A log's metadata records by name, the last of each name winning (the recorder
    writes a newer record when a device reconnects): from the summary's index when the
    file is closed, else from everything before the cut."""
    check_magic(Path(path))  # LogError naming a file that is no log (a FIFO never opened)
    out: dict[str, dict[str, str]] = {}
    lasers = None  # a rosbag2's: its scanners' records come with their first scans
    try:
        with open(path, "rb") as f:
            seeking = SeekingReader(f)
            if is_bag(seeking.get_header()):
                lasers = laser_channels(seeking.get_summary())
            else:
                for m in seeking.iter_metadata():
                    out[m.name] = dict(m.metadata)
                return out
    except Exception:  # no usable summary (a killed writer): read linearly
        pass
    reader = LogReader(path)
    scans = set()
    for _schema, channel, _message in reader.messages():
        if lasers is not None and channel.topic.endswith("/scan"):
            scans.add(channel.id)
            if len(scans) >= lasers:
                break
    return {m.name: dict(m.metadata) for m in reader.metadata}
