"""The rolling, crash-safe MCAP writer of the recorder (see ARCHITECTURE.md, "MCAP logs").

Files are named ``<prefix>_<UTC start YYYYmmddTHHMMSSZ>_<NNN>.mcap``: the UTC time the
writer (the session) started, shared by all parts, and the part number from 000. They
are created with ``O_EXCL`` and never overwritten: if a name is taken (a restart within
the same second) the next free part number is used. The ``acq`` metadata record of every
part names the session (``session``: that UTC start and a random suffix), so a reader
tells the parts of one session from another's (:mod:`acq.log.inputs`), whatever the
files are renamed to. The open file holds an exclusive ``flock`` as long as its writer
lives (a killed one's goes with it): a reader tells a file being written from one whose
writer stopped (:mod:`acq.log.writer_lock`).

Each file stands alone: header and profile, then the metadata records, every channel
with its schema, and the latched messages (calibration, ``/tf_static``), then the data.
Chunks (:class:`acq.log.mcap_file.McapFile`) are zstd, but those 90 % image data or more
(``foxglove.CompressedImage``: JPEG, which zstd cannot shrink) are stored uncompressed,
the message bytes never copied on the way. :meth:`LogWriter.sync` ends the open chunk,
writes it and fsyncs, so a SIGKILL or a power cut loses only what came after the last
sync; the file is then readable by a linear reader (``mcap.stream_reader.StreamReader``)
up to the cut.

Bytes go to the file through an unbuffered :class:`_File`, so the writer always knows
the offset where the last complete record ends. After an I/O error (a full disk) the
error is raised by the call that hit it, the writer refuses further writes, and
:meth:`LogWriter.close` cuts the file back to that offset and, space permitting, ends it
with a DataEnd/Footer/magic trailer: a valid MCAP without index, readable by
``mcap.reader.make_reader`` (which then reads linearly) and by ``acq info``.

One LogWriter is used from one thread.
"""

from __future__ import annotations

import errno
import os
import secrets
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer
from mcap.writer import LIBRARY_IDENTIFIER, MCAP0_MAGIC

from acq import __version__
from acq.log import writer_lock
from acq.log.mcap_file import McapFile, Piece
from acq.log.schemas import Schema
from acq.log.timebase import TimeBase

__all__ = ["LatchedData", "LogWriter", "Tap"]

LIBRARY = f"acq/{__version__} {LIBRARY_IDENTIFIER}"

# A latched message: fixed bytes, or a function encoding it for a file's start time (ns),
# so that its protobuf timestamp can be the start of each file too.
LatchedData = bytes | Callable[[int], bytes]

# Called with each message once it is in the file: (topic, schema, data, log time in the
# log's time base, latched). A latched message is passed once, when it is set.
Tap = Callable[[str, Schema, bytes, int, bool], None]

_COMPRESSION = {"zstd": "zstd", "none": "", "": ""}
# schemas whose payloads are already compressed (JPEG): their chunks are not compressed
INCOMPRESSIBLE = frozenset({"foxglove.CompressedImage", "foxglove.CompressedVideo"})
_IOV_MAX = 512  # pieces per writev (Linux takes 1024)


class _File:
    """The stream handed to :class:`McapFile`: unbuffered writes on our own descriptor.

    McapFile writes whole records (a chunk, a batch of records) per ``write`` or
    ``write_pieces`` call, so after every call that returned, ``good`` is the offset where
    the last complete record ends.
    """

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.pos = 0  # bytes written to the file
        self.good = 0  # end of the last complete write, a record boundary

    def write(self, data: bytes) -> int:
        return self.write_pieces([data])

    def write_pieces(self, pieces: Sequence[Piece]) -> int:
        """Every piece, in order, with as few system calls as the kernel allows (writev)."""
        views = [memoryview(p) for p in pieces if len(p)]
        total, i = 0, 0
        while i < len(views):
            n = os.writev(self.fd, views[i : i + _IOV_MAX])
            self.pos += n
            total += n
            while n and i < len(views):  # past what went out, the rest of a piece
                if n >= len(views[i]):
                    n -= len(views[i])
                    i += 1
                else:
                    views[i], n = views[i][n:], 0
        self.good = self.pos
        return total

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        """Nothing is buffered here (durability is :meth:`LogWriter.sync`'s fsync)."""


@dataclass
class _Channel:
    schema: Schema
    metadata: dict[str, str]


def _fsync_dir(directory: Path) -> None:
    """Make a directory's entries (new files) durable."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _trailer() -> bytes:
    """DataEnd + Footer without summary + magic: ends a file cut at a record boundary."""
    rb = RecordBuilder()
    DataEnd(data_section_crc=0).write(rb)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(rb)
    return bytes(rb.end()) + MCAP0_MAGIC


class LogWriter:
    """Writes a session as a series of standalone MCAP files (see the module docstring).

    Sizes in bytes, durations in seconds, times given in host monotonic ns. A file rolls
    over before a message when it holds ``split_bytes`` or more (the open chunk counted
    uncompressed) or the message's ``log_time`` is ``split_s`` or more after the file's
    first message; every message lands in exactly one file. ``metadata`` (name -> string
    map, e.g. the config, the calibration, versions) is written at the start of every file.

    ``time_base`` (default: UTC, its offset measured now, at the session start) is the
    clock of the files' ``log_time`` and ``publish_time``: the times given are written
    through :meth:`TimeBase.to_log`, and the ``acq`` metadata record names it. Whoever
    encodes a Foxglove message's ``timestamp`` does the same (``writer.time_base``).

    ``tap`` (see :data:`Tap`), when set, sees every message written, on the writer's
    thread: it must return at once (the recorder's :class:`acq.record.listeners.Listeners`).
    """

    def __init__(
        self,
        directory: Path,
        *,
        prefix: str = "acq",
        split_bytes: int = 2 << 30,
        split_s: float = 600.0,
        chunk_size: int = 8 << 20,
        compression: str = "zstd",
        sync_interval_s: float = 1.0,
        metadata: dict[str, dict[str, str]] | None = None,
        profile: str = "",
        time_base: TimeBase | None = None,
        tap: Tap | None = None,
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(f"unknown compression {compression!r}; expected one of zstd, none")
        if split_bytes <= 0 or split_s <= 0 or chunk_size <= 0:
            raise ValueError("split_bytes, split_s and chunk_size must be > 0")
        self.directory = Path(directory)
        self.prefix = prefix
        self.split_bytes = int(split_bytes)
        self.split_ns = int(split_s * 1e9)
        self.chunk_size = int(chunk_size)
        self.compression = _COMPRESSION[compression]
        self.sync_interval_ns = int(sync_interval_s * 1e9)
        self.profile = profile
        self.tap = tap
        self.time_base = TimeBase.session_start() if time_base is None else time_base
        self._stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        self.session = f"{self._stamp}-{secrets.token_hex(4)}"
        given = {name: dict(values) for name, values in (metadata or {}).items()}
        # the ``acq`` record first: a reader knows the time base before any message
        self._metadata: dict[str, dict[str, str]] = {
            "acq": {**given.pop("acq", {}), "session": self.session, **self.time_base.metadata()},
            **given,
        }
        self._channels: dict[str, _Channel] = {}
        self._latched: dict[str, tuple[LatchedData, int]] = {}
        self._part = 0
        self._files: list[Path] = []
        self._messages = 0
        self._closed_bytes = 0  # sizes of the finished files
        self._last_sync_ns: int | None = None
        self._error: OSError | None = None
        self._closed = False
        self._report: str | None = None
        # the open file
        self._path: Path | None = None
        self._out: _File | None = None
        self._writer: McapFile | None = None
        self._chan_ids: dict[str, int] = {}
        self._schema_ids: dict[str, int] = {}
        self._file_start_ns: int | None = None  # log_time of the file's first message
        self._data_limit: int | None = None  # where the data section ends, once finishing
        self._finished = False  # the open file's summary and footer are written
        self._header_end = 0  # where the open file's magic and header end
        self.directory.mkdir(parents=True, exist_ok=True)
        try:
            self._open_file(None)
        except OSError as e:  # leave no descriptor open nor a headerless file behind
            self._error, self._closed = e, True
            opened = self._out is not None
            self._report = self._salvage()
            if opened:
                e.add_note(self._report)
            raise

    # --- public properties ---------------------------------------------------------------

    @property
    def path(self) -> Path | None:
        """The file being written (None once closed, or after an error closed it)."""
        return self._path

    @property
    def files(self) -> list[Path]:
        """Every file opened, in order."""
        return list(self._files)

    @property
    def messages(self) -> int:
        """Messages accepted by :meth:`write` (latched copies are not counted)."""
        return self._messages

    @property
    def bytes_written(self) -> int:
        """Bytes written to all files so far (the open chunk not included)."""
        return self._closed_bytes + (self._out.pos if self._out is not None else 0)

    @property
    def error(self) -> OSError | None:
        """The I/O error that stopped the writer, if any."""
        return self._error

    # --- public methods ------------------------------------------------------------------

    def add_channel(
        self, topic: str, schema: Schema, metadata: dict[str, str] | None = None
    ) -> None:
        """Register ``topic`` (protobuf messages of ``schema``) in this and every later file."""
        self._check_usable()
        if topic in self._channels:
            raise ValueError(f"channel {topic!r} is already registered")
        self._channels[topic] = _Channel(schema, dict(metadata or {}))
        self._guard(lambda: self._register(topic))

    def set_latched(self, topic: str, data: LatchedData, publish_time_ns: int) -> None:
        """The message of ``topic`` that every file carries at its start (calibration,
        ``/tf_static``); written now to the current file too, at ``publish_time_ns``.

        In a later file it is stamped (log and publish time) with the file's start, the
        first message's log time; ``data`` may be a function of that time (in the log's
        time base) returning the encoded message, so that the protobuf timestamp says the
        same.
        """
        self._check_usable()
        self._channel_id(topic)  # must be registered
        self._latched[topic] = (data, publish_time_ns)
        self._guard(lambda: self._write_latched(topic, None))
        if self.tap is not None:
            stamp = self.time_base.to_log(publish_time_ns)
            payload = data(stamp) if callable(data) else data
            self.tap(topic, self._channels[topic].schema, payload, stamp, True)

    def update_metadata(self, name: str, values: dict[str, str]) -> None:
        """Set metadata ``name``: written now to the current file (a reader takes the last
        record of a name) and at the start of every later file."""
        self._check_usable()
        if name == "acq":  # the time base stays named
            values = {**values, **self.time_base.metadata()}
        self._metadata[name] = dict(values)
        writer = self._require_writer()
        self._guard(lambda: writer.add_metadata(name, dict(values)))

    def write(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        """Append one message; rolls over to a new file first when the current one is full
        or old enough. Raises OSError (e.g. ENOSPC) when the file cannot be written."""
        self._check_usable()
        self._maybe_roll(log_time_ns)
        self._append(topic, data, log_time_ns, publish_time_ns)

    def write_group(self, messages: Sequence[tuple[str, bytes, int, int]]) -> None:
        """Append (topic, data, log_time_ns, publish_time_ns) messages that belong together
        (a scan, its raw telegram and its timing) to one file: a roll-over comes before
        the group, never inside it."""
        self._check_usable()
        if messages:
            self._maybe_roll(messages[0][2])
        for topic, data, log_time_ns, publish_time_ns in messages:
            self._append(topic, data, log_time_ns, publish_time_ns)

    def _maybe_roll(self, log_time_ns: int) -> None:
        start = self._file_start_ns
        if start is not None and (
            self._size() >= self.split_bytes or log_time_ns - start >= self.split_ns
        ):
            self._guard(lambda: self._roll(log_time_ns))

    def _append(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        channel_id = self._channel_id(topic)
        writer = self._require_writer()
        out = self._out
        assert out is not None
        if self._file_start_ns is None:
            self._file_start_ns = log_time_ns
        to_log = self.time_base.to_log
        self._guard(
            lambda: writer.add_message(
                channel_id, to_log(log_time_ns), data, to_log(publish_time_ns)
            )
        )
        self._messages += 1
        if self.tap is not None:
            self.tap(topic, self._channels[topic].schema, data, to_log(log_time_ns), False)

    def sync(self) -> None:
        """End the open chunk, write it and fsync: everything written so far survives a
        SIGKILL or a power cut. Raises OSError when the file cannot be written."""
        self._check_usable()
        self._guard(self._sync_file)

    def maybe_sync(self, now_ns: int) -> None:
        """:meth:`sync` if ``sync_interval_s`` has passed since the last one (or on the
        first call); ``now_ns`` on the host monotonic clock."""
        last = self._last_sync_ns
        if last is None or now_ns - last >= self.sync_interval_ns:
            self.sync()
            self._last_sync_ns = now_ns

    def close(self) -> str | None:
        """Finish the current file (last chunk, summary, indexes, footer), fsync it and the
        directory. Idempotent.

        Returns None when every file was finished normally. After an I/O error already
        raised by :meth:`write` or :meth:`sync` it does not raise again: it cuts the file
        back to its last complete record, adds an end marker if the disk takes it, and
        returns a one-line description of what was kept. An error hit by ``close()``
        itself is handled the same way and then raised (with the description as a note).
        """
        if self._closed:
            return self._report
        self._closed = True
        if self._error is not None:
            self._report = self._salvage()
            return self._report
        try:
            self._finish_file()
        except OSError as e:
            self._error = e
            self._report = self._salvage()
            e.add_note(self._report)
            raise
        return None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- internals -----------------------------------------------------------------------

    def _guard(self, action: Callable[[], object]) -> None:
        """Run an I/O action; an OSError stops the writer (and is raised)."""
        try:
            action()
        except OSError as e:
            self._error = e
            raise

    def _check_usable(self) -> None:
        if self._error is not None:
            e = self._error
            raise OSError(
                e.errno or errno.EIO,
                f"log writer stopped after an earlier error ({e}); close it",
                str(self._path) if self._path else None,
            )
        if self._closed:
            raise ValueError("the log writer is closed")

    def _require_writer(self) -> McapFile:
        if self._writer is None:  # only after a failed rollover, which set _error
            raise OSError(errno.EIO, "no log file is open")
        return self._writer

    def _channel_id(self, topic: str) -> int:
        if topic not in self._channels:
            raise KeyError(
                f"no channel {topic!r}; registered: {', '.join(self._channels) or 'none'}"
            )
        return self._chan_ids[topic]

    def _size(self) -> int:
        """Bytes in the current file, the open chunk counted uncompressed."""
        pending = self._writer.open_chunk_bytes if self._writer is not None else 0
        return (self._out.pos if self._out is not None else 0) + pending

    def _open_file(self, start_ns: int | None) -> None:
        """Create the next part and write its start; ``start_ns`` stamps latched messages
        (None: each at its own publish time)."""
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC
        while True:
            path = self.directory / f"{self.prefix}_{self._stamp}_{self._part:03d}.mcap"
            self._part += 1
            try:
                fd = os.open(path, flags, 0o644)
                break
            except FileExistsError:
                continue
        writer_lock.hold(fd)
        self._path = path
        self._files.append(path)
        self._out = _File(fd)
        self._chan_ids = {}
        self._schema_ids = {}
        self._file_start_ns = None
        self._data_limit = None
        self._finished = False
        self._header_end = 1 << 62  # not written yet
        _fsync_dir(self.directory)
        writer = McapFile(self._out, self.chunk_size, self.compression)
        self._writer = writer
        writer.start(profile=self.profile, library=LIBRARY)
        self._header_end = self._out.good
        for name, values in self._metadata.items():
            writer.add_metadata(name, values)
        for topic in self._channels:
            self._register(topic)
        for topic in self._latched:
            self._write_latched(topic, start_ns)
        self._sync_file()

    def _register(self, topic: str) -> None:
        writer = self._require_writer()
        ch = self._channels[topic]
        schema_id = self._schema_ids.get(ch.schema.name)
        if schema_id is None:
            schema_id = writer.register_schema(ch.schema.name, ch.schema.encoding, ch.schema.data)
            self._schema_ids[ch.schema.name] = schema_id
        self._chan_ids[topic] = writer.register_channel(
            topic, ch.schema.encoding, schema_id, ch.metadata, ch.schema.name not in INCOMPRESSIBLE
        )

    def _write_latched(self, topic: str, start_ns: int | None) -> None:
        writer = self._require_writer()
        data, publish_ns = self._latched[topic]
        stamp = self.time_base.to_log(publish_ns if start_ns is None else start_ns)
        payload = data(stamp) if callable(data) else data
        writer.add_message(self._chan_ids[topic], stamp, payload, stamp)

    def _sync_file(self) -> None:
        if self._writer is None or self._out is None:
            return
        self._writer.flush()
        os.fsync(self._out.fd)

    def _finish_file(self) -> None:
        """Finish the open file normally: summary, footer, fsync, close, fsync the dir."""
        writer, out = self._writer, self._out
        if writer is None or out is None:
            return
        writer.flush()
        self._data_limit = out.good  # finish() writes DataEnd here (no chunk is left)
        writer.finish()
        self._finished = True
        os.fsync(out.fd)
        os.close(out.fd)
        self._writer = self._out = self._path = None
        self._closed_bytes += out.pos
        _fsync_dir(self.directory)

    def _roll(self, start_ns: int) -> None:
        self._finish_file()
        self._open_file(start_ns)

    def _salvage(self) -> str:
        """After an I/O error: keep the open file up to its last complete record, end it
        with a trailer if the disk takes it, and say what was kept."""
        err = self._error
        reason = err.strerror if err is not None and err.strerror else str(err)
        out, path = self._out, self._path
        self._writer = self._out = self._path = None
        if out is None or path is None:
            return f"log writer stopped: {reason}; no file was open"
        if self._finished:  # only the final fsync or close failed
            _quietly(lambda: os.close(out.fd))
            self._closed_bytes += out.pos
            return f"{path.name}: {reason}; finished but may not be on disk"
        good = out.good if self._data_limit is None else min(out.good, self._data_limit)
        if good < self._header_end:
            good = 0
        trailer = _trailer()
        ended = good > 0 and _quietly(lambda: os.ftruncate(out.fd, good))
        if ended and not _quietly(lambda: _pwrite_all(out.fd, trailer, good)):
            _quietly(lambda: os.ftruncate(out.fd, good))
            ended = False
        _quietly(lambda: os.fsync(out.fd))
        _quietly(lambda: os.close(out.fd))
        if good == 0:  # not even a header: do not leave an empty .mcap behind
            if _quietly(path.unlink):
                self._files.remove(path)
            _quietly(lambda: _fsync_dir(self.directory))
            return f"{path.name}: {reason}; nothing was written, the file is removed"
        _quietly(lambda: _fsync_dir(self.directory))
        self._closed_bytes += good + (len(trailer) if ended else 0)
        how = (
            "and ended without index (`acq info --repair` rebuilds it)"
            if ended
            else "without end marker (a linear reader reads it up to the cut)"
        )
        return f"{path.name}: {reason}; kept {good} bytes up to the last complete record {how}"


def _pwrite_all(fd: int, data: bytes, offset: int) -> None:
    if os.pwrite(fd, data, offset) != len(data):
        raise OSError(errno.ENOSPC, "short write")


def _quietly(action: Callable[[], object]) -> bool:
    """Run a best-effort clean-up step; False if it raised OSError."""
    try:
        action()
    except OSError:
        return False
    return True
