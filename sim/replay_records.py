"""One device's recorded records for a replay, read from the log files as they are served.

A session's records can be far larger than memory (an hour of the demo rig is some
13 GB of log), so a replay holds, per device, only their receive times (log time, host
monotonic ns, an int64 array in time order) and reads the bytes from the files when they
are due: :meth:`Records.cursor` gives a :class:`Cursor` that hands out record ``k``,
``k + 1``, ... reading each file with :class:`acq.log.reader.LogReader` from the time of
the record asked for (a closed file's chunks before it are not read; its read-ahead is
two chunks), so a stream can start at any record and memory does not grow with the
drive. Records held at once: the cursor's last one, the chunks read ahead, and, for a file
whose records of the device are not in time order, those within its largest lateness.

- :class:`LogRecords`: a device's records in the files of one session (in the given
  order; files that overlap in time are merged, each opened when the merge reaches it).
- :class:`MemoryRecords`: records given as lists (tests).

The records are in time order, ties in file order (a stable sort of every file's records
in the given order), as a replay serves them.
"""

from __future__ import annotations

import contextlib
import heapq
import logging
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from acq.errors import AcqError
from acq.log.reader import LogReader

__all__ = ["Cursor", "LogRecords", "MemoryRecords", "Records", "Select"]

log = logging.getLogger("acq.sim.replay")

# whether a channel holds the device's records; the bytes a replay serves of one, decoded
Select = Callable[[Any, Any], bool]
ToBytes = Callable[[Any], bytes]
SKIP_MAX = 256  # further ahead than this, a cursor reopens the files at the record's time
_END = 2**63 - 1
_Timed = Generator[tuple[int, int, bytes], None, None]  # (log ns, place in file, bytes)


class Cursor(Protocol):
    def get(self, k: int) -> bytes | None:
        """Record ``k`` (None: the files no longer hold it). Fast for ``k`` at or just
        after the last one asked for."""
        ...

    def close(self) -> None: ...


class Records(Protocol):
    """A device's records: ``times_ns`` (int64, ascending) and their bytes on demand."""

    times_ns: np.ndarray

    def __len__(self) -> int: ...

    def cursor(self) -> Cursor: ...

    def head(self, n: int) -> list[bytes]:
        """The first ``n`` records (fewer when there are fewer)."""
        ...


class MemoryRecords:
    """Records held as a list (a short test log)."""

    def __init__(self, times_ns: Sequence[int], data: Sequence[bytes]) -> None:
        if len(times_ns) != len(data):
            raise ValueError("need as many record times as records")
        order = np.argsort(np.asarray(times_ns, dtype=np.int64), kind="stable")
        self.times_ns = np.asarray(times_ns, dtype=np.int64)[order]
        self.data = [data[i] for i in order]

    def __len__(self) -> int:
        return len(self.data)

    def cursor(self) -> Cursor:
        return _ListCursor(self.data)

    def head(self, n: int) -> list[bytes]:
        return self.data[:n]


class _ListCursor:
    def __init__(self, data: list[bytes]) -> None:
        self.data = data

    def get(self, k: int) -> bytes | None:
        return self.data[k] if 0 <= k < len(self.data) else None

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class _Part:
    """The device's records in one file: where, when, and how far out of time order."""

    index: int  # the file's place in the session
    path: Path
    first_ns: int
    last_ns: int
    lateness_ns: int  # the most a record comes after a later one in the file, ns


class LogRecords:
    """A device's records in a session's files (``parts``: each file with its records'
    receive times in file order, as read by a first pass), read back lazily: the records
    of the channels ``select`` accepts whose messages decode, as ``to_bytes`` makes them
    of the decoded message. ``name`` names the device in messages."""

    def __init__(
        self,
        name: str,
        parts: Sequence[tuple[Path, np.ndarray]],
        select: Select,
        to_bytes: ToBytes,
    ) -> None:
        self.name = name
        self.select = select
        self.to_bytes = to_bytes
        self.parts: list[_Part] = []
        for index, (path, times) in enumerate(parts):
            if len(times):
                late = int(np.max(np.maximum.accumulate(times) - times))
                self.parts.append(_Part(index, path, int(times.min()), int(times.max()), late))
        merged = np.concatenate([t for _, t in parts]) if parts else np.zeros(0, np.int64)
        self.times_ns = np.sort(merged.astype(np.int64), kind="stable")
        self._head: list[bytes] = []

    def __len__(self) -> int:
        return len(self.times_ns)

    def cursor(self) -> Cursor:
        return _FileCursor(self)

    def head(self, n: int) -> list[bytes]:
        n = min(n, len(self))
        if len(self._head) < n:
            cursor = self.cursor()
            try:
                got = [cursor.get(k) for k in range(n)]
            finally:
                cursor.close()
            self._head = [g for g in got if g is not None]
        return self._head[:n]

    def records_from(self, start_ns: int) -> Generator[bytes, None, None]:
        """Every record at or after ``start_ns`` (log ns), in order: the files merged by
        time, each opened once the merge reaches its first record."""
        waiting = sorted(
            (p for p in self.parts if p.last_ns >= start_ns), key=lambda p: (p.first_ns, p.index)
        )
        heap: list[tuple[int, int, int, bytes, _Timed]] = []
        opened: list[_Timed] = []
        try:
            while True:
                while waiting and (not heap or waiting[0].first_ns <= heap[0][0]):
                    part = waiting.pop(0)
                    it = self._file_records(part, start_ns)
                    opened.append(it)
                    first = next(it, None)
                    if first is not None:
                        heapq.heappush(heap, (first[0], part.index, first[1], first[2], it))
                if not heap:
                    return
                _t, index, _seq, data, it = heapq.heappop(heap)
                yield data
                nxt = next(it, None)
                if nxt is not None:
                    heapq.heappush(heap, (nxt[0], index, nxt[1], nxt[2], it))
        finally:
            for it in opened:
                it.close()

    def _file_records(self, part: _Part, start_ns: int) -> _Timed:
        """(time, place in the file, bytes) of the part's records at or after
        ``start_ns``, in time order: those a later record overtook wait, until no record
        still to come can be earlier (the part's lateness)."""
        reader = LogReader(part.path, (start_ns, _END), progress=False)
        pending: list[tuple[int, int, bytes]] = []
        latest = -(2**63)
        seq = 0
        # the file's damage was warned of by the first pass, once per process
        messages: Any = reader.decoded(self._wanted)  # a generator: closed when done
        with contextlib.closing(messages):
            for _value, _channel, message, decoded in messages:
                if decoded is None:  # garbled: not among the times either
                    continue
                seq += 1
                t = message.log_time
                if t < start_ns:
                    continue
                heapq.heappush(pending, (t, seq, self.to_bytes(decoded)))
                latest = max(latest, t)
                while pending and pending[0][0] <= latest - part.lateness_ns:
                    yield heapq.heappop(pending)
        while pending:
            yield heapq.heappop(pending)

    def _wanted(self, schema: Any, channel: Any) -> bool | None:
        return True if self.select(schema, channel) else None


class _FileCursor:
    """Reads a :class:`LogRecords` forward from the record asked for; reopens the files
    at a record's time when asked for an earlier one or one far ahead."""

    def __init__(self, records: LogRecords) -> None:
        self.records = records
        self._it: Generator[bytes, None, None] | None = None
        self._next = 0  # the index of the record ``_it`` yields next
        self._last: tuple[int, bytes] | None = None
        self._lost = False

    def get(self, k: int) -> bytes | None:
        if not 0 <= k < len(self.records):
            return None
        if self._last is not None and self._last[0] == k:
            return self._last[1]
        try:
            if self._it is None or k < self._next or k - self._next > SKIP_MAX:
                self._open(k)
            assert self._it is not None
            while self._next <= k:
                data = next(self._it, None)
                if data is None:
                    self._gone(k, "no longer in the log files (changed since they were read?)")
                    return None
                self._last = (self._next, data)
                self._next += 1
        except (OSError, AcqError) as e:  # a file removed or damaged since the first pass
            self.close()
            self._gone(k, f"cannot be read: {e}")
            return None
        return self._last[1] if self._last is not None else None

    def _open(self, k: int) -> None:
        self.close()
        times = self.records.times_ns
        t = int(times[k])
        first = int(np.searchsorted(times, t, side="left"))  # ties before k: skipped
        self._it = self.records.records_from(t)
        self._next = first

    def _gone(self, k: int, why: str) -> None:
        if not self._lost:
            self._lost = True
            log.error("%s: record %d of %d %s; the device goes silent",
                      self.records.name, k, len(self.records), why)  # fmt: skip

    def close(self) -> None:
        it, self._it = self._it, None
        if it is not None:
            it.close()
