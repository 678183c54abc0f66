"""Which clock a log's times are on (:mod:`acq.log.timebase`): as its ``acq`` metadata
record names it, or, when that record does not (a copy made without its metadata
records, as ``mcap filter`` writes without ``--include-metadata``; a ``utc_offset_ns``
that is not an integer within int64, or that puts the first message before the host's
boot), as its messages show (:func:`inferred_clock`), said in one WARNING line per file
and process (:class:`ClockSource`).

acq writes each ``acq.Timing`` and ``acq.Status`` message with the log time of a host
monotonic time the message holds (``recv_ns``, ``timestamp_ns``), through the log's
clock (:mod:`acq.log.timebase`): their difference is the session's offset, exactly (0: a
host monotonic log). An ``acq.Clock`` pair gives it to a few microseconds. A log with
none of these is taken as UTC when its first log time is after 2001 (host monotonic
time is the time since boot), else as host monotonic.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from mcap.records import Header, Metadata

from acq.errors import InputValueError
from acq.log import skipped_chunks
from acq.log.rosbag_source import is_bag
from acq.log.timebase import MONOTONIC, TimeBase

__all__ = ["ClockSource", "InferredClock", "RawOpener", "inferred_clock"]

log = logging.getLogger(__name__)


class _RawPass(Protocol):
    """What the clock is found with: a pass over a log with its times as in the file
    (:class:`acq.log.reader.LogReader` with ``raw_times``, given by the reader, so that
    this module need not import it)."""

    def messages(self) -> Generator[tuple[Any, Any, Any], None, None]: ...

    def decode(self, schema: Any, channel: Any, message: Any) -> Any: ...


RawOpener = Callable[..., _RawPass]
"""The reader's class: ``open_raw(path, progress=False, raw_times=True)``."""

_HOST_FIELDS = {"acq.Timing": "recv_ns", "acq.Status": "timestamp_ns", "acq.Clock": "monotonic_ns"}
_EXACT = ("acq.Timing", "acq.Status")  # log time = the field through the log's clock
_MAX_MESSAGES = 20_000  # read at most this many messages looking for one
_UTC_AFTER_NS = 10**18  # 2001-09-09 UTC: later log times are not a host's uptime
_NEAR_ZERO_NS = 10**9  # an acq.Clock pair's offset this small: a host monotonic log


@dataclass(frozen=True)
class InferredClock:
    """A log's time base found from its messages, and how (for the warning line)."""

    time_base: TimeBase
    how: str
    acq_messages: bool = True  # found from acq's messages (else: the log has none)

    def describe(self) -> str:
        """``its times taken as ...``, for the warning line."""
        if self.time_base.utc:
            clock = f"UTC, host monotonic + {self.time_base.utc_offset_ns / 1e9:.6f} s"
        else:
            clock = "host monotonic"
        return f"its times taken as {clock} ({self.how})"


def inferred_clock(path: str | os.PathLike[str], open_raw: RawOpener) -> InferredClock:
    """The clock of the log at ``path`` from its messages (see the module docstring),
    read by ``open_raw``; found once per process while the file keeps its size and time."""
    p = Path(path)
    st = p.stat()
    return _cached(p.absolute(), st.st_size, st.st_mtime_ns, open_raw)


@functools.lru_cache(maxsize=64)
def _cached(path: Path, size: int, mtime_ns: int, open_raw: RawOpener) -> InferredClock:
    reader = open_raw(path, progress=False, raw_times=True)
    first: int | None = None
    approximate: tuple[int, str] | None = None
    messages = reader.messages()
    with skipped_chunks.quiet():  # the file's damage is for the command's own pass to say
        try:
            for n, (schema, channel, message) in enumerate(messages):
                first = message.log_time if first is None else first
                if n >= _MAX_MESSAGES:
                    break
                field = _HOST_FIELDS.get(schema.name if schema is not None else "")
                if field is None:
                    continue
                decoded = reader.decode(schema, channel, message)
                host = int(getattr(decoded, field, 0) or 0)
                if host <= 0:
                    continue
                offset = message.log_time - host
                how = f"{channel.topic}'s log times against their {field}"
                if schema is not None and schema.name in _EXACT:
                    return _clock(offset, how)
                if abs(offset) < _NEAR_ZERO_NS:  # its two clocks read microseconds apart
                    offset = 0
                approximate = approximate or (offset, how)
        finally:
            messages.close()
    if approximate is not None:
        return _clock(*approximate)
    if first is not None and first >= _UTC_AFTER_NS:
        return InferredClock(TimeBase(True, 0), "no acq.* message holds the host clock", False)
    return InferredClock(MONOTONIC, "no acq.* message holds the host clock", False)


def _clock(offset: int, how: str) -> InferredClock:
    return InferredClock(TimeBase(True, offset) if offset else MONOTONIC, how)


class ClockSource:
    """The clock of one pass over the log at ``path``: ``time_base``, from its ``acq``
    record (:meth:`take`) or its messages; ``note``: why and what its metadata lacks,
    when it came from its messages (a WARNING when the log is acq's: an ``acq`` record
    or ``acq.*`` messages; a wholly foreign MCAP file is not warned of). ``raw``: the
    times as in the file, whatever its metadata (for :func:`inferred_clock` itself).
    ``open_raw``: how :func:`inferred_clock` reads the log."""

    def __init__(self, path: Path, open_raw: RawOpener, raw: bool = False) -> None:
        self.path = path
        self.open_raw = open_raw
        self.raw = raw
        self.time_base: TimeBase = MONOTONIC
        self.note: str | None = None
        self._named = False  # an acq record was read (its offset usable or not)
        self._started = False  # a message has come

    def header(self, record: Header) -> None:
        """The file's header: a ROS 2 bag's times are its stamps (UTC, as they are;
        :mod:`acq.log.rosbag_source` names its clock), no acq record expected."""
        if is_bag(record):
            self._named = True

    def take(self, records: Sequence[object]) -> None:
        """The time base of the ``acq`` metadata record among ``records``, if any; from
        the messages when its ``utc_offset_ns`` is unusable."""
        for record in records:
            if isinstance(record, Metadata) and record.name == "acq" and not self.raw:
                self._named = True
                try:
                    self.time_base = TimeBase.of_acq_record(record.metadata)
                except InputValueError as e:
                    self._infer(f"{e}: ignored", warn=True)

    def first_message(self, first_ns: int | None, metadata: Sequence[object]) -> None:
        """Messages come, the first at log time ``first_ns`` (as in the file; None:
        unknown), after the ``metadata`` records (a closed file's every one, else those
        read so far): the recorded offset checked against it, or, when no ``acq`` record
        named the clock, the clock from the messages. Only the first call counts."""
        if self._started:
            return
        self._started = True
        offset = self.time_base.utc_offset_ns
        if first_ns is not None and self.time_base.utc and first_ns - offset < 0:
            self._infer(
                f"metadata acq.utc_offset_ns: {offset} puts the first message (log time"
                f" {first_ns}) before the host's boot: ignored",
                warn=True,
            )
        if self._named or self.raw:
            return
        self._named = True
        names = [r.name for r in metadata if isinstance(r, Metadata)]
        lacks = ["no acq record (clock, session)"]
        if not any(n.startswith("device.") for n in names):
            lacks.append("no device records (scanner geometry, drivers)")
        if "calibration" not in names:
            lacks.append("no calibration record")
        none = "no metadata records" if not names else "metadata without acq's"
        self._infer(
            f"{none} (as `mcap filter` copies a log without --include-metadata): "
            + ", ".join(lacks)
        )

    def _infer(self, why: str, warn: bool = False) -> None:
        """The time base from the log's messages; ``why`` and it said once (``warn``, or
        when the log holds acq's messages)."""
        clock = inferred_clock(self.path, self.open_raw)
        self.time_base = clock.time_base
        self.note = f"{why}; {clock.describe()}"
        if (warn or clock.acq_messages) and skipped_chunks.unreported_note(self.path, "clock"):
            log.warning("%s: %s", self.path, self.note)
