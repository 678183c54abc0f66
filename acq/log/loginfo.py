"""Read, summarise and repair acq MCAP logs, including logs whose writer was killed.

A log whose footer and summary are present and valid is *closed*: it is read with
mcap's seeking reader, chunk by chunk from its index. Any other log (writer killed,
power lost, disk full, still being written) is read linearly, one record at a time,
until the first record that is cut short, zero-filled or garbled: every message of a
complete chunk before that point is returned, and the point is reported. A complete
chunk whose CRC or compression is bad is skipped and reported, and reading goes on
after it (its length is known, so the records after it are still framed).

All times are integer nanoseconds of the host monotonic clock (MCAP ``log_time``)
unless a name says otherwise (``_s`` seconds, ``_ms`` milliseconds, ``_hz`` hertz).
Messages are decoded from the schemas stored in the file, never from our own
generated classes, so older logs with fewer fields still read.
"""

from __future__ import annotations

import dataclasses
import io
import json as _json
import math
import os
import struct
import zlib
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import zstandard
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
    Metadata,
    Schema,
)
from mcap.stream_reader import CRCValidationError, StreamReader, breakup_chunk
from mcap.summary import Summary
from mcap_protobuf.decoder import DecoderFactory

from acq.errors import InputError

if TYPE_CHECKING:
    from mcap.writer import Writer

__all__ = [
    "ChannelInfo",
    "DeviceSync",
    "LogError",
    "LogInfo",
    "format_info",
    "info",
    "info_many",
    "read_messages",
    "repair",
]

MAGIC = b"\x89MCAP0\r\n"
_HEADER = 9  # opcode (1) + record length (8), bytes
_FOOTER = _HEADER + 8 + 8 + 4  # a whole Footer record, bytes
_MAX_CHUNK_BYTES = 4 * 2**30  # a larger uncompressed size in a chunk header is garbage
_KNOWN = frozenset(int(op) for op in Opcode)
_NO_SUMMARY = "no summary section"
_SLOW_PERIOD_S = 0.5  # topics at 2 Hz or slower (status, clock): gap = period + 0.5 s

# What mcap's record parsers raise on a cut or garbled record or chunk, and nothing else:
# EndOfFile / RecordLengthLimitExceeded / UnsupportedCompressionError are McapErrors, a short
# read of a fixed field is a struct.error, a cut string a UnicodeDecodeError.
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


def _chunk_messages(chunk: Chunk) -> list[McapRecord]:
    """The messages of a zstd or uncompressed chunk, its CRC checked: what mcap's
    ``breakup_chunk`` gives (less the schema and channel records, which a closed file's
    summary holds), parsed with struct (a 60 s drive's 13,000 messages: 0.2 s less)."""
    data = chunk.data
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise McapError(f"bad chunk CRC (expected {chunk.uncompressed_crc})")
    out: list[McapRecord] = []
    view = memoryview(data)
    pos, end = 0, len(data)
    head = _MESSAGE_HEAD.size
    while pos < end:
        if pos + 9 > end:
            raise McapError(f"a record cut at byte {pos} of the chunk")
        opcode = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        body = pos + 9
        pos = body + length
        if pos > end:
            raise McapError(f"a record of {length} bytes runs past the chunk's end")
        if opcode == Opcode.MESSAGE:
            if length < head:
                raise McapError(f"a message record of {length} bytes")
            channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(data, body)
            out.append(
                Message(
                    channel_id=channel_id,
                    log_time=log_time,
                    data=bytes(view[body + head : pos]),
                    publish_time=publish_time,
                    sequence=sequence,
                )
            )
    return out


_RECORD_ERRORS: tuple[type[BaseException], ...] = (
    McapError,
    CRCValidationError,
    struct.error,
    UnicodeDecodeError,
    zstandard.ZstdError,
)


class LogError(InputError, ValueError):
    """A file that is not an MCAP log at all (missing, unreadable, bad magic)."""

    def __init__(self, path: str | os.PathLike[str], offset: int, reason: str) -> None:
        self.path = Path(path)
        self.offset = offset
        self.reason = reason
        super().__init__(f"{self.path}: {reason} (byte {offset})")


# --- results ------------------------------------------------------------------------


@dataclass(frozen=True)
class ChannelInfo:
    """One topic of a log.

    ``rate_hz`` is ``(count - 1) / (last_ns - first_ns)``; ``max_gap_s`` the longest
    interval between consecutive messages, seconds; ``gaps`` the intervals
    ``(start_ns, end_ns)`` longer than 3x the median period, or, for topics at 2 Hz or
    slower (1 Hz status and clock), longer than the median period + 0.5 s (one missed
    beat). ``bytes`` is the sum of the message payloads.
    """

    topic: str
    schema: str
    count: int
    first_ns: int
    last_ns: int
    rate_hz: float
    max_gap_s: float
    gaps: list[tuple[int, int]]
    bytes: int


@dataclass(frozen=True)
class DeviceSync:
    """Clock-sync quality of one device, from its ``/acq/timing/<device>`` records.

    ``epochs`` counts distinct estimator epochs (a reset or re-sync starts a new one);
    ``drift_ppm`` is the last estimate; ``offset_spread_ms`` is max - min of the
    device-to-host offset over the log; ``uncertainty_s_*`` the estimator's own
    uncertainty, seconds; ``residual_ms_*`` receive time minus mapped stamp
    (``recv_ns - stamp_ns``), milliseconds. ``None`` where the log has no such values.
    """

    name: str
    records: int
    epochs: int
    drift_ppm: float | None
    offset_spread_ms: float | None
    uncertainty_s_median: float | None
    uncertainty_s_max: float | None
    residual_ms_p50: float | None
    residual_ms_p95: float | None
    residual_ms_max: float | None


@dataclass(frozen=True)
class LogInfo:
    """Summary of one log file, or (``len(files) > 1``) of a session of split files.

    ``closed`` is True when the footer and the summary are present and valid.
    ``bytes_read`` is where reading stopped (the end of the last good record; the file
    size when closed). ``readable_until_ns`` is the latest ``log_time`` read.
    ``start_realtime_ns`` is UTC ns of ``start_ns``, from the ``/acq/clock`` pairs.
    ``drops`` and ``disconnects`` come from the last ``/acq/status`` (the counters of
    ``/acq/timing`` for devices it does not list). ``problem`` says, in one line, what is
    wrong with the file (not closed, corrupt chunks), or is None.
    """

    path: Path
    files: tuple[Path, ...]
    closed: bool
    bytes_read: int
    bytes_total: int
    readable_until_ns: int | None
    messages: int
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    start_realtime_ns: int | None
    channels: list[ChannelInfo]
    devices: list[DeviceSync]
    drops: dict[str, int]
    disconnects: dict[str, int]
    metadata: dict[str, dict[str, str]]
    attachments: int
    problem: str | None


# --- reading ------------------------------------------------------------------------


def _check_magic(path: Path) -> int:
    """File size in bytes, after checking that ``path`` starts with the MCAP magic."""
    try:
        with path.open("rb") as f:
            head = f.read(len(MAGIC))
            size = os.fstat(f.fileno()).st_size
    except FileNotFoundError:
        raise LogError(path, 0, "no such file") from None
    except IsADirectoryError:
        raise LogError(path, 0, "is a directory, not an MCAP file") from None
    except OSError as e:
        raise LogError(path, 0, f"cannot read: {e.strerror or e}") from None
    if not head:
        raise LogError(path, 0, "empty file, not an MCAP file")
    if head != MAGIC and MAGIC.startswith(head):
        raise LogError(path, len(head), f"cut inside the MCAP magic, {len(head)} bytes long")
    if head != MAGIC:
        raise LogError(path, 0, f"not an MCAP file: bad magic {head!r}")
    return size


def _record_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower().replace("_", " ")
    except ValueError:
        return f"opcode 0x{opcode:02x}"


class _Scan:
    """One pass over a log; ``records()`` yields its Header, Schema, Channel, Message,
    Metadata and Attachment records in file order and fills in how the pass went."""

    def __init__(
        self, path: str | os.PathLike[str], log_time: tuple[int, int] | None = None
    ) -> None:
        self.path = Path(path)
        self.log_time = log_time  # a closed file's chunks wholly outside it are not read
        self.size = _check_magic(self.path)
        self.closed = False
        self.bytes_read = len(MAGIC)
        self.stop: str | None = None  # why a linear pass stopped before a valid footer
        self.notes: list[str] = []  # damage that did not stop the pass
        self.expected_messages: int | None = None  # from the summary's statistics
        self.footer_at: int | None = None  # a footer the linear pass reached, byte offset

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
        elif not self.closed:
            parts.append(
                f"not closed: the writer stopped at byte {self.bytes_read} of {self.size}"
                f" ({self.stop or 'no footer'}); read everything before it"
            )
        parts.extend(self.notes)
        return "; ".join(parts) or None

    def records(self) -> Iterator[McapRecord]:
        with self.path.open("rb") as f:
            summary = self._closed_summary(f)
            if summary is not None and summary.chunk_indexes:
                self.closed = True
                yield from self._indexed(f, summary)
            else:
                self.closed = summary is not None
                f.seek(len(MAGIC))
                yield from self._linear(f)

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
        if opcode != Opcode.FOOTER or length != _FOOTER - _HEADER:
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
            calculated = zlib.crc32(tail[: _HEADER + 16], calculated)
            if calculated != crc:
                self.stop = f"bad summary CRC (summary at byte {start})"
                return None
        try:
            f.seek(0)  # SeekingReader checks the magic where the stream is, not at byte 0
            summary = SeekingReader(f, validate_crcs=True).get_summary()
        except _RECORD_ERRORS as e:
            self.stop = f"unreadable summary at byte {start}: {e}"
            return None
        if summary is not None and summary.statistics is not None:
            self.expected_messages = summary.statistics.message_count
        return summary

    def _indexed(self, f: IO[bytes], summary: Summary) -> Iterator[McapRecord]:
        f.seek(0)
        reader = SeekingReader(f, validate_crcs=True)
        header = reader.get_header()
        yield header
        yield from summary.schemas.values()
        yield from summary.channels.values()
        try:
            extras: list[McapRecord] = [*reader.iter_metadata(), *reader.iter_attachments()]
        except _RECORD_ERRORS as e:
            extras = []
            self.notes.append(f"unreadable metadata or attachments ({e})")
        yield from extras
        count = 0
        lo, hi = self.log_time or (-1, 2**64)
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
                    return pool.submit(self._chunk_records, record, True)
                except _RECORD_ERRORS as e:
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
                except _RECORD_ERRORS as e:
                    self.notes.append(f"corrupt chunk at byte {at} skipped ({e})")
                    continue
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

    @staticmethod
    def _chunk_records(chunk: Chunk, messages_only: bool = False) -> list[McapRecord]:
        """A chunk's records; ``messages_only`` (a closed file, whose summary holds the
        schemas and channels): only its messages, by the faster parser."""
        if chunk.uncompressed_size > _MAX_CHUNK_BYTES:
            raise McapError(f"implausible uncompressed size {chunk.uncompressed_size}")
        if messages_only and chunk.compression in ("zstd", ""):
            return _chunk_messages(chunk)
        return breakup_chunk(chunk, validate_crc=True)

    # -- anything else: a linear scan that stops at the cut ---------------------------

    def _linear(self, f: IO[bytes]) -> Iterator[McapRecord]:
        """Records one by one: check the framing ourselves (so a cut or a zero-filled tail
        is seen for what it is, and no garbage length makes us allocate), then let mcap's
        StreamReader parse each complete record."""
        pos = len(MAGIC)
        size = self.size
        while True:
            self.bytes_read = pos
            if pos == size:
                self.stop = "no footer after the last complete record"
                return
            head = f.read(_HEADER)
            if len(head) < _HEADER:
                self.stop = f"truncated record header at byte {pos}"
                return
            opcode, length = struct.unpack("<BQ", head)
            if opcode == 0:
                self.stop = self._zeros_or_garbage(f, pos)
                return
            present = size - pos - _HEADER
            if length > present:
                self.stop = (
                    f"truncated {_record_name(opcode)} record at byte {pos}:"
                    f" {length} bytes declared, {present} present"
                )
                return
            body = f.read(length)
            if opcode not in _KNOWN:  # a private (0x80+) or newer record: skip it, as mcap does
                pos += _HEADER + length
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
            except _RECORD_ERRORS as e:
                if opcode == Opcode.CHUNK:
                    self.notes.append(f"corrupt chunk at byte {pos} skipped ({e})")
                    pos += _HEADER + length
                    continue
                self.stop = f"corrupt {_record_name(opcode)} record at byte {pos}: {e}"
                return
            if isinstance(record, Footer):
                end = pos + _HEADER + length
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
            if isinstance(record, Chunk):
                try:
                    yield from self._chunk_records(record)
                except _RECORD_ERRORS as e:
                    self.notes.append(f"corrupt chunk at byte {pos} skipped ({e})")
            elif isinstance(record, Header | Schema | Channel | Message | Metadata | Attachment):
                yield record
            pos += _HEADER + length

    def _zeros_or_garbage(self, f: IO[bytes], pos: int) -> str:
        f.seek(pos)
        while block := f.read(1 << 20):
            if block.count(0) != len(block):
                return f"invalid record (opcode 0x00) at byte {pos}"
        return f"zero-filled tail from byte {pos}, {self.size - pos} bytes, as after a power loss"


def _messages(scan: _Scan) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """(schema, channel, message) of every readable message of ``scan``, in file order."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    orphans = 0
    for record in scan.records():
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is None:
                orphans += 1
                continue
            yield schemas.get(channel.schema_id), channel, record
    if orphans:
        scan.notes.append(f"{orphans} messages on unknown channels skipped")


def read_messages(
    path: str | os.PathLike[str], log_time: tuple[int, int] | None = None
) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """Every readable message of a log as (schema, channel, message), in file order.

    The seeking reader is used when the file is closed, a linear scan otherwise; the scan
    stops cleanly at a cut, a zero-filled tail or garbage. ``log_time`` (first, last)
    ns: a closed file's chunks whose messages all lie outside it are not read (others
    may still yield messages outside it: the caller filters). Raises :class:`LogError`
    at once (not on first iteration) for a missing file or one that is not MCAP.
    """
    return _messages(_Scan(path, log_time))


# --- summarising --------------------------------------------------------------------


def _field(message: Any, name: str) -> Any:
    """``message.name``, or None when this version of the schema has no such field."""
    descriptor = getattr(message, "DESCRIPTOR", None)
    if descriptor is None or name not in descriptor.fields_by_name:
        return None
    return getattr(message, name)


def _gaps(times: list[int]) -> tuple[float, list[tuple[int, int]]]:
    """(max interval s, gaps) of sorted times, ns; gaps as in :class:`ChannelInfo`."""
    if len(times) < 2:
        return 0.0, []
    t = np.asarray(times, dtype=np.int64)
    d = np.diff(t)
    # the pace: the median interval, ignoring those far below the mean (records logged
    # in bursts, as several CAN messages sent together, would otherwise set it)
    positive = d[d > max((t[-1] - t[0]) / (len(t) - 1) / 10, 0)]
    if positive.size == 0:
        return 0.0, []
    period = float(np.median(positive))
    if period >= _SLOW_PERIOD_S * 1e9:
        threshold = period + _SLOW_PERIOD_S * 1e9
    else:
        threshold = 3.0 * period
    idx = np.flatnonzero(d > threshold)
    gaps = [(int(t[i]), int(t[i + 1])) for i in idx]
    return float(d.max()) / 1e9, gaps


@dataclass
class _Timing:
    records: int = 0
    epochs: set[int] = field(default_factory=set)
    drift_ppm: float | None = None
    offsets: list[int] = field(default_factory=list)
    uncertainties: list[float] = field(default_factory=list)
    residuals: list[int] = field(default_factory=list)
    dropped: int | None = None


@dataclass
class _Acc:
    """Running totals over the messages of one file or of a session."""

    times: dict[str, list[int]] = field(default_factory=dict)
    schemas: dict[str, str] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)
    timing: dict[str, _Timing] = field(default_factory=dict)
    status: Any = None
    realtime_offset_ns: int | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: int = 0

    def add(self, schema: Schema | None, channel: Channel, message: Message, decoded: Any) -> None:
        topic = channel.topic
        self.times.setdefault(topic, []).append(message.log_time)
        self.schemas.setdefault(topic, schema.name if schema is not None else "")
        self.sizes[topic] = self.sizes.get(topic, 0) + len(message.data)
        if decoded is None:
            return
        if topic.startswith("/acq/timing/"):
            self._add_timing(topic.removeprefix("/acq/timing/"), decoded)
        elif topic == "/acq/status":
            self.status = decoded
        elif topic == "/acq/clock" and self.realtime_offset_ns is None:
            realtime, monotonic = _field(decoded, "realtime_ns"), _field(decoded, "monotonic_ns")
            if realtime and monotonic:
                self.realtime_offset_ns = int(realtime) - int(monotonic)

    def _add_timing(self, device: str, msg: Any) -> None:
        t = self.timing.setdefault(device, _Timing())
        t.records += 1
        epoch = _field(msg, "epoch")
        if epoch is not None:
            t.epochs.add(int(epoch))
        drift = _field(msg, "drift_ppm")
        if drift is not None and math.isfinite(drift):
            t.drift_ppm = float(drift)
        offset = _field(msg, "offset_ns")
        if offset is not None:
            t.offsets.append(int(offset))
        uncertainty = _field(msg, "uncertainty_s")
        if uncertainty is not None and math.isfinite(uncertainty):  # NaN: no estimate yet
            t.uncertainties.append(float(uncertainty))
        recv, stamp = _field(msg, "recv_ns"), _field(msg, "stamp_ns")
        if recv and stamp:
            t.residuals.append(int(recv) - int(stamp))
        dropped = _field(msg, "dropped")
        if dropped is not None:
            t.dropped = int(dropped)

    def add_record(self, record: McapRecord) -> None:
        if isinstance(record, Metadata):
            self.metadata.setdefault(record.name, dict(record.metadata))
        elif isinstance(record, Attachment):
            self.attachments += 1

    def channels(self) -> list[ChannelInfo]:
        out = []
        for topic in sorted(self.times):
            times = sorted(self.times[topic])
            span = times[-1] - times[0]
            max_gap_s, gaps = _gaps(times)
            out.append(
                ChannelInfo(
                    topic=topic,
                    schema=self.schemas[topic],
                    count=len(times),
                    first_ns=times[0],
                    last_ns=times[-1],
                    rate_hz=(len(times) - 1) / (span / 1e9) if span > 0 else 0.0,
                    max_gap_s=max_gap_s,
                    gaps=gaps,
                    bytes=self.sizes[topic],
                )
            )
        return out

    def devices(self) -> tuple[list[DeviceSync], dict[str, int], dict[str, int]]:
        drops: dict[str, int] = {}
        disconnects: dict[str, int] = {}
        listed: list[str] = []
        status_devices = _field(self.status, "devices") if self.status is not None else None
        for dev in status_devices or []:
            name = str(_field(dev, "name") or "")
            if not name:
                continue
            listed.append(name)
            dropped, disc = _field(dev, "dropped"), _field(dev, "disconnects")
            if dropped is not None:
                drops[name] = int(dropped)
            if disc is not None:
                disconnects[name] = int(disc)
        for name, t in self.timing.items():
            if name not in drops and t.dropped is not None:
                drops[name] = t.dropped
        devices = [_device_sync(name, self.timing.get(name, _Timing())) for name in listed]
        devices += [_device_sync(n, t) for n, t in sorted(self.timing.items()) if n not in listed]
        return devices, drops, disconnects


def _device_sync(name: str, t: _Timing) -> DeviceSync:
    res = np.asarray(t.residuals, dtype=np.float64) / 1e6
    unc = np.asarray(t.uncertainties, dtype=np.float64)
    return DeviceSync(
        name=name,
        records=t.records,
        epochs=len(t.epochs),
        drift_ppm=t.drift_ppm,
        offset_spread_ms=(max(t.offsets) - min(t.offsets)) / 1e6 if t.offsets else None,
        uncertainty_s_median=float(np.median(unc)) if unc.size else None,
        uncertainty_s_max=float(unc.max()) if unc.size else None,
        residual_ms_p50=float(np.percentile(res, 50)) if res.size else None,
        residual_ms_p95=float(np.percentile(res, 95)) if res.size else None,
        residual_ms_max=float(res.max()) if res.size else None,
    )


def _decode_topic(topic: str) -> bool:
    return topic in ("/acq/status", "/acq/clock") or topic.startswith("/acq/timing/")


def _result(
    acc: _Acc,
    path: Path,
    files: tuple[Path, ...],
    closed: bool,
    bytes_read: int,
    bytes_total: int,
    problem: str | None,
) -> LogInfo:
    channels = acc.channels()
    devices, drops, disconnects = acc.devices()
    start = min((c.first_ns for c in channels), default=None)
    end = max((c.last_ns for c in channels), default=None)
    return LogInfo(
        path=path,
        files=files,
        closed=closed,
        bytes_read=bytes_read,
        bytes_total=bytes_total,
        readable_until_ns=end,
        messages=sum(c.count for c in channels),
        start_ns=start,
        end_ns=end,
        duration_s=(end - start) / 1e9 if start is not None and end is not None else 0.0,
        start_realtime_ns=(
            start + acc.realtime_offset_ns
            if start is not None and acc.realtime_offset_ns is not None
            else None
        ),
        channels=channels,
        devices=devices,
        drops=drops,
        disconnects=disconnects,
        metadata=acc.metadata,
        attachments=acc.attachments,
        problem=problem,
    )


def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, str]]:
    """A log's metadata records by name, the last of each name winning (the recorder
    writes a newer record when a device reconnects): from the summary's index when the
    file is closed, else from everything before the cut (as :func:`info` reads it)."""
    from mcap.reader import SeekingReader

    out: dict[str, dict[str, str]] = {}
    try:
        with open(path, "rb") as f:
            for m in SeekingReader(f).iter_metadata():
                out[m.name] = dict(m.metadata)
        return out
    except Exception:  # no usable summary (a killed writer): read linearly
        return info(path).metadata


def info(path: str | os.PathLike[str]) -> LogInfo:
    """Summary of one log; reads everything before a cut when the file was not closed."""
    return info_many([path])[0]


def info_many(paths: Iterable[str | os.PathLike[str]]) -> list[LogInfo]:
    """One :class:`LogInfo` per file, in the given order, and, for more than one file
    (the split files of a session), a last one for the whole session: its ``files`` lists
    them, its ``path`` is their common directory, its channels and gaps span them all."""
    files = [Path(p) for p in paths]
    scans = [_Scan(p) for p in files]  # every LogError before any long read
    session = _Acc()
    out: list[LogInfo] = []
    for scan in scans:
        acc = _Acc()
        decoders: dict[int, Any] = {}
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        factory = DecoderFactory()
        for record in scan.records():
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None:
                    continue
                schema = schemas.get(channel.schema_id)
                decoded = None
                if _decode_topic(channel.topic):
                    decoded = _decode(factory, decoders, schema, channel, record)
                acc.add(schema, channel, record, decoded)
                session.add(schema, channel, record, decoded)
            else:
                acc.add_record(record)
                session.add_record(record)
        out.append(
            _result(
                acc,
                scan.path,
                (scan.path,),
                scan.closed,
                scan.bytes_read,
                scan.size,
                scan.problem(),
            )
        )
    if len(out) > 1:
        problems = [f"{i.path.name}: {i.problem}" for i in out if i.problem]
        out.append(
            _result(
                session,
                Path(os.path.commonpath([p.resolve() for p in files])),
                tuple(files),
                all(i.closed for i in out),
                sum(i.bytes_read for i in out),
                sum(i.bytes_total for i in out),
                " | ".join(problems) or None,
            )
        )
    return out


def _decode(
    factory: DecoderFactory,
    decoders: dict[int, Any],
    schema: Schema | None,
    channel: Channel,
    message: Message,
) -> Any:
    """The decoded protobuf message, or None when it cannot be decoded."""
    if channel.id not in decoders:
        try:
            decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
        except Exception:  # a broken schema in the file: count the messages, decode none
            decoders[channel.id] = None
    decoder = decoders[channel.id]
    if decoder is None:
        return None
    try:
        return decoder(message.data)
    except Exception:  # protobuf's DecodeError, or anything a garbled payload causes
        return None


# --- output -------------------------------------------------------------------------


def _bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GiB"


def _opt(value: float | None, fmt: str) -> str:
    return "-" if value is None or math.isnan(value) else format(value, fmt)


def _utc(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, tz=UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def _meta_item(key: str, value: str) -> str:
    short = value.strip()
    if len(short) <= 32 and "\n" not in short:
        return f"{key}={short}"
    return f"{key} ({len(value.encode())} B)"


def _format_one(i: LogInfo) -> list[str]:
    title = str(i.path) if len(i.files) == 1 else f"session {i.path} ({len(i.files)} files)"
    state = "closed" if i.closed else "NOT CLOSED"
    lines = [f"{title}: {state}"]
    if i.problem:
        lines.append(f"  warning: {i.problem}")
    if i.start_ns is not None and i.end_ns is not None:
        where = f"monotonic {i.start_ns / 1e9:.3f} s .. {i.end_ns / 1e9:.3f} s"
        if i.start_realtime_ns is not None:
            where += f", from {_utc(i.start_realtime_ns)}"
        lines.append(f"  span      {i.duration_s:.3f} s ({where})")
    lines.append(
        f"  messages  {i.messages} in {len(i.channels)} channels, attachments {i.attachments};"
        f" read {_bytes(i.bytes_read)} of {_bytes(i.bytes_total)}"
    )
    for name, data in i.metadata.items():
        keys = ", ".join(_meta_item(k, v) for k, v in data.items())
        lines.append(f"  metadata  {name}: {keys}")
    if i.channels:
        width = max(24, *(len(c.topic) for c in i.channels))
        swidth = max(12, *(len(c.schema) for c in i.channels))
        lines.append(
            f"  {'topic':<{width}}  {'schema':<{swidth}}  {'count':>7}  {'rate Hz':>8}"
            f"  {'max gap s':>9}  {'gaps':>4}  {'size':>10}"
        )
        for c in i.channels:
            lines.append(
                f"  {c.topic:<{width}}  {c.schema:<{swidth}}  {c.count:>7}  {c.rate_hz:>8.2f}"
                f"  {c.max_gap_s:>9.3f}  {len(c.gaps):>4}  {_bytes(c.bytes):>10}"
            )
        start = i.start_ns or 0
        for c in i.channels:
            if c.gaps:
                shown = ", ".join(
                    f"{(a - start) / 1e9:.3f}..{(b - start) / 1e9:.3f} s" for a, b in c.gaps[:5]
                )
                more = f" and {len(c.gaps) - 5} more" if len(c.gaps) > 5 else ""
                lines.append(f"  gaps on {c.topic} (s from start): {shown}{more}")
    names = [d.name for d in i.devices] + sorted(
        (set(i.drops) | set(i.disconnects)) - {d.name for d in i.devices}
    )
    if names:
        by_name = {d.name: d for d in i.devices}
        lines.append(
            f"  {'device':<12}  {'drops':>6}  {'disconn':>7}  {'timing':>7}  {'epochs':>6}"
            f"  {'drift ppm':>9}  {'offset spread ms':>16}  {'uncert. s med/max':>19}"
            f"  {'recv-stamp ms p50/p95/max':>25}"
        )
        for name in names:
            d = by_name.get(name)
            drops = str(i.drops.get(name, "-"))
            disc = str(i.disconnects.get(name, "-"))
            if d is None:
                lines.append(f"  {name:<12}  {drops:>6}  {disc:>7}")
                continue
            unc = f"{_opt(d.uncertainty_s_median, '.2e')}/{_opt(d.uncertainty_s_max, '.2e')}"
            res = (
                f"{_opt(d.residual_ms_p50, '.2f')}/{_opt(d.residual_ms_p95, '.2f')}"
                f"/{_opt(d.residual_ms_max, '.2f')}"
            )
            lines.append(
                f"  {name:<12}  {drops:>6}  {disc:>7}  {d.records:>7}  {d.epochs:>6}"
                f"  {_opt(d.drift_ppm, '.2f'):>9}  {_opt(d.offset_spread_ms, '.3f'):>16}"
                f"  {unc:>19}  {res:>25}"
            )
    return lines


def _jsonable(i: LogInfo) -> dict[str, Any]:
    d = dataclasses.asdict(i)
    d["path"] = str(i.path)
    d["files"] = [str(p) for p in i.files]
    for c in d["channels"]:
        c["gaps"] = [list(g) for g in c["gaps"]]
    return d


def format_info(infos: LogInfo | Iterable[LogInfo], *, json: bool = False) -> str:
    """Human-readable tables (channels, devices, the "not closed" warning) or, with
    ``json=True``, a JSON list with one object per :class:`LogInfo`."""
    items = [infos] if isinstance(infos, LogInfo) else list(infos)
    if json:
        return _json.dumps([_jsonable(i) for i in items], indent=2)
    blocks = ["\n".join(_format_one(i)) for i in items]
    return "\n\n".join(blocks)


# --- repair -------------------------------------------------------------------------


def repair(
    src: str | os.PathLike[str], dst: str | os.PathLike[str], *, chunk_size: int = 1 << 20
) -> int:
    """Write every readable message of ``src`` (with its schemas, channels, metadata and
    attachments) to a new, indexed, zstd-chunked MCAP ``dst``; returns the message count.

    Raises FileExistsError rather than overwrite ``dst``, :class:`LogError` when ``src``
    is not an MCAP log. ``chunk_size`` is the uncompressed chunk size, bytes.
    """
    scan = _Scan(src)
    dst = Path(dst)
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    schemas: dict[int, Schema] = {}
    pending: dict[int, Channel] = {}
    count = 0
    with dst.open("xb") as out:
        from mcap.writer import CompressionType, Writer  # here: it imports importlib.metadata

        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        started = False
        try:
            for record in scan.records():
                if isinstance(record, Header):
                    if not started:
                        writer.start(profile=record.profile, library=record.library)
                        started = True
                    continue
                if not started:
                    writer.start()
                    started = True
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    pending.setdefault(record.id, record)
                elif isinstance(record, Message):
                    new_id = channel_ids.get(record.channel_id)
                    if new_id is None:
                        channel = pending.get(record.channel_id)
                        if channel is None:
                            continue
                        new_id = _register(writer, channel, schemas, schema_ids)
                        channel_ids[record.channel_id] = new_id
                    writer.add_message(
                        channel_id=new_id,
                        log_time=record.log_time,
                        data=record.data,
                        publish_time=record.publish_time,
                        sequence=record.sequence,
                    )
                    count += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                elif isinstance(record, Attachment):
                    writer.add_attachment(
                        record.create_time,
                        record.log_time,
                        record.name,
                        record.media_type,
                        record.data,
                    )
            if not started:
                writer.start()
            for old_id, channel in pending.items():  # channels without messages, too
                if old_id not in channel_ids:
                    channel_ids[old_id] = _register(writer, channel, schemas, schema_ids)
            writer.finish()
        except BaseException:
            out.close()
            dst.unlink(missing_ok=True)
            raise
    return count


def _register(
    writer: Writer, channel: Channel, schemas: dict[int, Schema], schema_ids: dict[int, int]
) -> int:
    """Register ``channel`` (and its schema, once) with ``writer``; its new id."""
    new_schema = 0
    schema = schemas.get(channel.schema_id)
    if schema is not None:
        if schema.id not in schema_ids:
            schema_ids[schema.id] = writer.register_schema(
                schema.name, schema.encoding, schema.data
            )
        new_schema = schema_ids[schema.id]
    return writer.register_channel(
        channel.topic, channel.message_encoding, new_schema, dict(channel.metadata)
    )
