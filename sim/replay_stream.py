"""A replay's time axis and each device's records on it.

- :class:`ReplayClock` is the session's time axis, shared by all of its devices so that
  they keep their recorded timing relative to each other. It starts the first time a
  client asks any device for its time or its data (SCIP ``II``/``TM``/a scan command,
  CoLa ``LMDscandata``, an MJPEG stream request): that device's first record is then
  due ``lead_s`` later. It is a live device's time: a client that connects later, or
  reconnects, gets what is due from then on, not what it missed.
- :class:`ReplayStream` is one device's records on that axis: their times in memory,
  their bytes read from the log as they are due (:mod:`acq.sim.replay_records`).

Times are the host's ``time.monotonic()`` seconds; log times are the recording host's
monotonic nanoseconds.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from acq.sim.replay_records import Records

__all__ = ["MAX_BURST", "ReplayClock", "ReplayStream"]

MAX_BURST = 64  # records a stream hands out at once, however far behind its server is


class ReplayClock:
    """Log time (recorded host monotonic ns) -> replay time (monotonic s), for a session.

    ``at(log_ns) = origin + (log_ns - anchor_ns) / speed``; :meth:`start` fixes origin
    and anchor once. Thread-safe.
    """

    def __init__(self, speed: float = 1.0, lead_s: float = 0.05) -> None:
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive number, got {speed}")
        self.speed = speed
        self.lead_s = lead_s
        self._lock = threading.Lock()
        self._started = threading.Event()
        self._origin = 0.0  # s
        self._anchor_ns = 0

    @property
    def started(self) -> bool:
        return self._started.is_set()

    def start(self, now: float, first_ns: int) -> bool:
        """Start the clock unless it runs: log time ``first_ns`` is due at ``now + lead_s``.
        True when this call started it."""
        with self._lock:
            if self._started.is_set():
                return False
            self._origin = now + self.lead_s
            self._anchor_ns = first_ns
            self._started.set()
            return True

    def wait_started(self, timeout: float | None = None) -> bool:
        return self._started.wait(timeout)

    def at(self, log_ns: int) -> float:
        """Replay time (monotonic s) at which log time ``log_ns`` is due."""
        return self._origin + (log_ns - self._anchor_ns) * 1e-9 / self.speed

    def log_ns_at(self, t: float) -> int:
        """Log time (ns) due at replay time ``t`` (monotonic s)."""
        return self._anchor_ns + round((t - self._origin) * self.speed * 1e9)


class ReplayStream:
    """One device's records (:mod:`acq.sim.replay_records`: times in memory, bytes read
    when due) served on a :class:`ReplayClock`. Used by one server thread."""

    def __init__(self, name: str, records: Records, clock: ReplayClock) -> None:
        if not len(records):
            raise ValueError(f"{name}: no records")
        self.name = name
        self.records = records
        self.times_ns = records.times_ns  # receive times, log ns, ascending
        self.clock = clock
        self.active = False
        self.sent = 0  # records handed out so far
        self._k = 0  # next record
        self._cursor = records.cursor()

    def __len__(self) -> int:
        return len(self.times_ns)

    @property
    def first_ns(self) -> int:
        return int(self.times_ns[0])

    @property
    def last_ns(self) -> int:
        return int(self.times_ns[-1])

    def head(self, n: int) -> list[bytes]:
        """The first ``n`` records (what a device describes itself by)."""
        return self.records.head(n)

    def start_clock(self, now: float) -> None:
        """Start the shared clock here, unless it runs: this device's first record is due
        ``lead_s`` from now."""
        self.clock.start(now, self.first_ns)

    def begin(self, now: float) -> None:
        """A client starts streaming: serve from the first record due at or after ``now``."""
        self.start_clock(now)
        self._k = int(np.searchsorted(self.times_ns, self.clock.log_ns_at(now), side="left"))
        self.active = True

    def stop(self) -> None:
        self.active = False

    def due(self) -> float | None:
        """When the next record is due (monotonic s); None when stopped or at the end."""
        if not self.active or self._k >= len(self):
            return None
        return self.clock.at(int(self.times_ns[self._k]))

    def take(self, now: float) -> list[bytes]:
        """The records due by ``now``, in order (a burst when the server fell behind; at
        most ``MAX_BURST``: the next call takes the rest)."""
        out: list[bytes] = []
        if not self.active:
            return out
        n = len(self)
        while self._k < n and len(out) < MAX_BURST:
            if self.clock.at(int(self.times_ns[self._k])) > now:
                break
            data = self._cursor.get(self._k)
            if data is None:  # the files lost it: the device goes silent
                self._k = n
                break
            out.append(data)
            self._k += 1
        self.sent += len(out)
        return out

    def close(self) -> None:
        """Close the files the stream reads (once its server has stopped)."""
        self._cursor.close()

    def latest(self, now: float) -> bytes:
        """The last record due by ``now`` (the first one before it), for a polled scan."""
        k = int(np.searchsorted(self.times_ns, self.clock.log_ns_at(now), side="right")) - 1
        data = self._cursor.get(max(k, 0))
        return self.head(1)[0] if data is None else data
