"""The clock of a log's times: UTC, or (logs written before acq 0.1.0's UTC logs) the
host monotonic clock.

An acq log's MCAP ``log_time``, ``publish_time`` and every Foxglove message's
``timestamp`` are UTC nanoseconds: the host monotonic clock plus one offset measured
when the session started, so they never jump when NTP steps the wall clock. The
``acq.*`` messages (timing, status, odometry, CAN frames, clock pairs) keep their times
on the host monotonic clock. The ``acq`` metadata record says which: ``clock`` (a line
for people) and ``utc_offset_ns`` (UTC minus host monotonic, ns). A log without
``utc_offset_ns`` is host monotonic throughout.

:class:`acq.log.LogReader` undoes the offset, so every command works on host monotonic
times whatever the log: ``log_time``, ``publish_time`` and the decoded Foxglove
timestamps it gives are host monotonic ns, as in the ``acq.*`` messages.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass

from acq.errors import InputValueError

__all__ = ["MONOTONIC", "TimeBase", "measure_utc_offset_ns"]

_UTC_LINE = (
    "log_time, publish_time and Foxglove timestamps are UTC ns: host CLOCK_MONOTONIC plus "
    "utc_offset_ns, fixed at the session start; acq.* messages keep host CLOCK_MONOTONIC ns"
)
_MONOTONIC_LINE = "log_time and timestamps are host CLOCK_MONOTONIC ns; /acq/clock maps them to UTC"


def measure_utc_offset_ns(samples: int = 5) -> int:
    """UTC (the wall clock) minus host monotonic, ns: of a few readings of the wall clock
    between two of the monotonic clock, the one read in the shortest interval."""
    best: tuple[int, int] | None = None
    for _ in range(max(samples, 1)):
        before = time.monotonic_ns()
        wall = time.time_ns()
        after = time.monotonic_ns()
        if best is None or after - before < best[0]:
            best = (after - before, wall - (before + after) // 2)
    assert best is not None
    return best[1]


@dataclass(frozen=True)
class TimeBase:
    """A log's clock: ``utc`` (its times are host monotonic + ``utc_offset_ns``) or not
    (host monotonic, offset 0)."""

    utc: bool
    utc_offset_ns: int = 0

    @classmethod
    def session_start(cls) -> TimeBase:
        """A UTC time base whose offset is measured now."""
        return cls(True, measure_utc_offset_ns())

    @classmethod
    def of_metadata(cls, metadata: Mapping[str, Mapping[str, str]]) -> TimeBase:
        """The time base a log's metadata (name -> map) names; host monotonic when its
        ``acq`` record has no ``utc_offset_ns``. Raises InputValueError for one that is not
        an integer within int64 (MCAP's times are 64-bit)."""
        return cls.of_acq_record(metadata.get("acq", {}))

    @classmethod
    def of_acq_record(cls, record: Mapping[str, str]) -> TimeBase:
        """As :meth:`of_metadata`, from the ``acq`` metadata record alone."""
        text = record.get("utc_offset_ns")
        if text is None:
            return MONOTONIC
        try:
            offset = int(text)
        except ValueError:
            offset = None
        if offset is None or not -(2**63) <= offset < 2**63:
            shown = text if len(text) <= 40 else f"{text[:40]}..."
            raise InputValueError(
                f"metadata acq.utc_offset_ns: {shown!r} is not an integer within int64 (ns)"
            )
        return cls(True, offset)

    def to_log(self, host_ns: int) -> int:
        """The log's time (ns) of host monotonic ``host_ns``."""
        return host_ns + self.utc_offset_ns

    def to_host(self, log_ns: int) -> int:
        """Host monotonic ns of the log's time ``log_ns``."""
        return log_ns - self.utc_offset_ns

    def metadata(self) -> dict[str, str]:
        """The entries of the ``acq`` metadata record that name this time base."""
        if not self.utc:
            return {"clock": _MONOTONIC_LINE}
        return {"clock": _UTC_LINE, "utc_offset_ns": str(self.utc_offset_ns)}


MONOTONIC = TimeBase(False)
