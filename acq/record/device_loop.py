"""The recorder's device loop: one thread per device, every kind through the same loop.

:func:`run_device` is the loop (python-can's ``Notifier`` is the model): it reads a
device's records through its reconnecting link (:class:`acq.drivers.reconnect.Relink`),
describes the device once per (re)connection, and hands each record to the device's
adapter (the ``Listener``, a :class:`DeviceAdapter`), which updates the device's
:class:`DeviceState` (counters, clock) and returns what goes to the writer. The adapters
of each kind (scanner, camera, CAN, GNSS) are in :mod:`acq.record.adapters`. The adapter
also encodes its records for the writer thread (:meth:`DeviceAdapter.write`), so the
writer knows no kind.

No reader ever waits for the writer: records go through the :class:`Outbox`'s bounded
queue, and a full queue drops the record (counted in ``DeviceState.dropped``); a device's
description (its ``device.<name>`` metadata) is kept aside, the latest per device, so a
full queue can neither drop it nor block on it.

Whatever fails in a device's loop stays that device's: an exception from its driver, its
link or its adapter (a bug, bytes a parser was not written for) is a ``fault``, logged in
one line (its traceback at debug level), counted as a disconnection in the status; the
device is closed and opened again after a backoff while the other devices record on.
A device that delivers no record for :data:`SILENT_FIRST_S` (from the start, or since its
last record) is a warning naming it and why (:meth:`DeviceState.watch`), repeated after
5, 10, 20 s... up to every :data:`SILENT_CAP_S`. A device with an expected rate
(``DeviceState.expected_hz``: a camera's configured fps) that delivers more than
:data:`FAST_FACTOR` times it for :data:`FAST_FIRST_S` is a warning too, with the same
backoff, and the seconds it does are counted (``fast_s``).

Device URLs may carry a password: event texts and descriptions go through
:func:`acq.credentials.redact` before they are kept.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import queue
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, TypeVar

from acq.credentials import redact
from acq.drivers.reconnect import FAULTS_FORGOTTEN_S, Backoff, LinkEvent, Relink, describe
from acq.log.fast_devices import FAST_FACTOR
from acq.log.silent_devices import why_silent
from acq.log.writer import LogWriter
from acq.time.clocksync import DeviceClock

__all__ = [
    "FAST_FIRST_S",
    "SILENT_CAP_S",
    "SILENT_FIRST_S",
    "DeviceAdapter",
    "DeviceState",
    "Outbox",
    "device_metadata",
    "finite",
    "run_device",
]

log = logging.getLogger("acq.record")

R = TypeVar("R")  # what the driver reads (Scan, Frame, CanFrame, Sentence)
P = TypeVar("P")  # what goes through the queue to the writer

SILENT_FIRST_S = 4.0  # no record for this long: a warning (then after 5, 10, 20 s ...)
SILENT_REPEAT_S = 5.0
SILENT_CAP_S = 300.0  # the longest time between two warnings about one silence
FAST_FIRST_S = 2.0  # too fast for this long: a warning (then after 5, 10, 20 s ...)


@dataclass
class DeviceState:
    """What the status reports of one device; updated by its thread, read by the writer."""

    name: str
    kind: str  # scanner | camera | can | gnss
    connected: bool = False
    received: int = 0
    dropped: int = 0  # queue full: the writer could not keep up
    source_drops: int = 0  # lost before us (a camera's sequence gaps)
    corrupt: int = 0
    disconnects: int = 0
    protocol_errors: int = 0
    last_recv_ns: int = 0
    offset_ns: int = 0  # host ns minus device ns at the last stamp (see stamped)
    last_event: str = ""
    clock: DeviceClock | None = None
    latency_s: float = 0.0
    latency_bounds_s: tuple[float, float] | None = None
    latency_source: str = "configured"  # how latency_s was obtained
    times: deque[int] = field(default_factory=lambda: deque(maxlen=256))  # recent recv ns
    odd_size: int = 0  # frames of another size than expected (recorded, flagged)
    faults: int = 0
    expected_hz: float = 0.0  # the configured rate (a camera's fps); 0: not watched
    fast_s: float = 0.0  # seconds spent above FAST_FACTOR * expected_hz
    # the rate watch, on the writer's thread: too fast since (0: not), the next warning
    _fast_from_ns: int = field(default=0, init=False, repr=False)
    _fast_seen_ns: int = field(default=0, init=False, repr=False)
    _next_fast_s: float = field(default=FAST_FIRST_S, init=False, repr=False)
    _fast_warnings: int = field(default=0, init=False, repr=False)
    _counts: deque[tuple[int, int]] = field(default_factory=deque, init=False, repr=False)
    # the silence watch, on the writer's thread: since when, the next warning, how many
    _silent_from_ns: int = field(default=0, init=False, repr=False)
    _next_warning_s: float = field(default=SILENT_FIRST_S, init=False, repr=False)
    _warnings: int = field(default=0, init=False, repr=False)

    def clock_offset_ns(self) -> int:
        """Host ns minus device ns (unwrapped ticks) at the last stamp; 0 before any."""
        return self.offset_ns

    def stamped(self, tick: int) -> None:
        """The device's clock has just taken ``tick`` (on the device's thread): keep the
        offset at it for the writer's thread, which must not query the clock while the
        device's thread updates it (a reset leaves it without a line for a moment)."""
        clock = self.clock
        if clock is not None and clock.updates:
            device_ns = round(clock.unwrapper.nearest(tick) * 1e9 / clock.tick_hz)
            self.offset_ns = clock.to_host_ns(tick) - device_ns

    def rate_hz(self, now_ns: int) -> float:
        # a copy first: the device's thread appends while the writer's thread reads
        recent = [t for t in list(self.times) if now_ns - t <= 2_000_000_000]
        span_ns = recent[-1] - recent[0] if len(recent) >= 2 else 0
        # records that came in one read share a receive time: no rate from them alone
        return (len(recent) - 1) / (span_ns * 1e-9) if span_ns > 0 else 0.0

    def count(self, recv_ns: int) -> None:
        """One record received at ``recv_ns`` (host monotonic ns)."""
        self.received += 1
        self.last_recv_ns = recv_ns
        self.times.append(recv_ns)

    def event(self, kind: str, detail: str, error: BaseException | None = None) -> None:
        """A link event (:class:`acq.drivers.reconnect.LinkEvent`): state, counters, log;
        ``error`` is what was raised (a fault's traceback goes to the debug log)."""
        detail = redact(detail)
        self.last_event = f"{kind}: {detail}" if detail else kind
        if kind == "fault":
            self._fault(detail, error)
        elif kind == "connected":
            self.connected = True
            log.info("%s connected: %s", self.name, detail)
        elif kind == "connect_failed":
            self.connected = False
            log.debug("%s: connect failed: %s", self.name, detail)
        elif kind in ("disconnected", "stalled", "device_error"):
            self.connected = False
            self.disconnects += 1
            log.warning("%s %s: %s", self.name, kind, detail)
        elif kind == "protocol_error":
            self.protocol_errors += 1
            log.warning("%s: bad telegram: %s", self.name, detail)
        elif kind == "clock_reset":
            log.warning("%s: %s", self.name, detail)

    def _fault(self, detail: str, error: BaseException | None) -> None:
        """An unexpected exception (a bug): the device is closed and opened again; logged
        at the 1st, 2nd, 4th, 8th... so a device failing at every connection does not
        flood the journal (the silence warnings go on saying why it records nothing)."""
        if self.connected:
            self.connected = False
            self.disconnects += 1
        self.faults += 1
        n = self.faults
        if n & (n - 1) == 0:
            log.error("%s failed (%d so far), closed and reopened after a backoff: %s "
                      "(its traceback at debug level)", self.name, n, detail)  # fmt: skip
        if error is not None:
            log.debug("%s: the failure's traceback (a bug to report)", self.name,
                      exc_info=error)  # fmt: skip

    def why_silent(self) -> str:
        """Why no record comes: not connected and the last connect error, or what the
        connected device did last."""
        return why_silent(self.connected, self.last_event)

    def watch(self, now_ns: int, started_ns: int) -> None:
        """The silence watch (on the writer's thread): a warning when no record came for
        :data:`SILENT_FIRST_S` since the start or the last record, again after 5, 10,
        20 s... (at most :data:`SILENT_CAP_S` apart); a line when records come again."""
        since = self.last_recv_ns or started_ns
        if since != self._silent_from_ns:
            if self._warnings and self._silent_from_ns:
                log.info("%s: recording again after %.1f s without a record", self.name,
                         (since - self._silent_from_ns) * 1e-9)  # fmt: skip
            self._silent_from_ns, self._warnings = since, 0
            self._next_warning_s = SILENT_FIRST_S
        silent_s = (now_ns - since) * 1e-9
        if silent_s < self._next_warning_s:
            return
        self._warnings += 1
        step = min(SILENT_REPEAT_S * 2 ** (self._warnings - 1), SILENT_CAP_S)
        self._next_warning_s = silent_s + step
        after = "since the start" if not self.received else "since the last one"
        log.warning("%s: no record for %.0f s %s: %s", self.name, silent_s, after,
                    self.why_silent())  # fmt: skip

    def watch_rate(self, now_ns: int) -> None:
        """The rate watch (on the writer's thread): a warning when the device has been
        delivering more than :data:`FAST_FACTOR` times ``expected_hz`` for
        :data:`FAST_FIRST_S`, again after 5, 10, 20 s... (at most :data:`SILENT_CAP_S`
        apart); the time it does so is added to ``fast_s``. The rate is the records
        counted over the last 2 s (not :meth:`rate_hz`: a flood brings hundreds of
        records in one read, sharing a receive time, more than ``times`` holds)."""
        if self.expected_hz <= 0:
            return
        counts = self._counts
        counts.append((now_ns, self.received))
        while now_ns - counts[0][0] > 2_000_000_000:
            counts.popleft()
        span_ns = now_ns - counts[0][0]
        if span_ns < 500_000_000:
            return  # too short a look to call a rate
        rate = (self.received - counts[0][1]) / (span_ns * 1e-9)
        if rate <= FAST_FACTOR * self.expected_hz:
            if self._fast_warnings:
                log.info("%s: back to %.1f records/s (%g configured)", self.name, rate,
                         self.expected_hz)  # fmt: skip
            self._fast_from_ns = self._fast_warnings = 0
            self._next_fast_s = FAST_FIRST_S
            return
        if not self._fast_from_ns:
            self._fast_from_ns = self._fast_seen_ns = now_ns
        self.fast_s += (now_ns - self._fast_seen_ns) * 1e-9
        self._fast_seen_ns = now_ns
        fast_for_s = (now_ns - self._fast_from_ns) * 1e-9
        if fast_for_s < self._next_fast_s:
            return
        self._fast_warnings += 1
        step = min(SILENT_REPEAT_S * 2 ** (self._fast_warnings - 1), SILENT_CAP_S)
        self._next_fast_s = fast_for_s + step
        log.warning("%s: %.0f records/s for %.0f s, configured %g/s (over %g times): a "
                    "misconfigured or faulty device; recording every record",
                    self.name, rate, fast_for_s, self.expected_hz, FAST_FACTOR)  # fmt: skip

    def bad_record(self, what: str, detail: str) -> None:
        """A record that does not decode, from a stream that goes on (a CAN bus, NMEA):
        counted; logged at the 1st, 2nd, 4th, 8th... so a wrong DBC does not flood."""
        self.protocol_errors += 1
        detail = redact(detail)
        self.last_event = f"protocol_error: {detail}"
        n = self.protocol_errors
        if n & (n - 1) == 0:
            log.warning("%s: %s (%d so far): %s", self.name, what, n, detail)


def device_metadata(driver: str, device: Any) -> dict[str, str]:
    """JSON strings describing a connected driver's device, for a ``device.<name>`` metadata
    record: ``driver``, ``info`` (identity), ``geometry`` (scanners: ScanGeometry, in
    rad, s, m), ``params`` (Hokuyo: the PP values), ``format`` (cameras); the
    credentials of URLs in them redacted."""
    out = {"driver": driver, "class": type(device).__name__}
    for key in ("info", "geometry", "params", "format"):
        value = getattr(device, key, None)
        if value is not None and dataclasses.is_dataclass(value):
            out[key] = redact(json.dumps(dataclasses.asdict(value)))  # type: ignore[arg-type]
    return out


def finite(x: float, cap: float = 1e9) -> float:
    """``x``, or ``cap`` when it is not finite (a clock's uncertainty before any estimate)."""
    return x if math.isfinite(x) else cap


class DeviceAdapter(ABC, Generic[R, P]):
    """One device kind's part of the device loop: it opens the driver (from the registry)
    and its link, turns each record into what the writer needs (updating ``state``), and,
    on the writer's thread, encodes that into the device's topics."""

    kind: ClassVar[str]

    def __init__(self, name: str, driver: str) -> None:
        self.name = name
        self.driver = driver  # the registry's name, recorded in the metadata
        self.state = DeviceState(name, self.kind)
        self.device: Any = None  # the driver instance, once opened

    @abstractmethod
    def channels(self) -> list[tuple[str, str]]:
        """The device's topics and their schema names, in the order they are registered."""

    @abstractmethod
    def open(self, on_event: Callable[[LinkEvent], None]) -> Relink[R]:
        """Make the driver (``self.device``) and the link that reads it, on the device's
        thread (it may talk to the device first)."""

    @abstractmethod
    def identity(self) -> object:
        """What the driver learnt at its last connection (a new object: it reconnected)."""

    @abstractmethod
    def receive(self, record: R) -> Iterable[P]:
        """What a record gives the writer, the state updated (on the device's thread)."""

    @abstractmethod
    def write(self, writer: LogWriter, payload: P) -> None:
        """Encode and write one payload (on the writer's thread)."""


@dataclass(frozen=True)
class Queued:
    """A payload on its way to the writer, with the adapter that encodes it."""

    adapter: DeviceAdapter[Any, Any]
    payload: object


class Outbox:
    """What the device threads hand the writer: payloads through a bounded queue (a full
    queue drops, counted in the device's state: a reader never waits) and each device's
    latest description, kept aside."""

    def __init__(self, size: int) -> None:
        self.queue: queue.Queue[Queued] = queue.Queue(maxsize=size)
        self._descriptions: dict[str, dict[str, str]] = {}
        self._lock = threading.Lock()

    def put(self, adapter: DeviceAdapter[Any, Any], payload: object) -> None:
        try:
            self.queue.put_nowait(Queued(adapter, payload))
        except queue.Full:
            adapter.state.dropped += 1

    def describe(self, name: str, values: dict[str, str]) -> None:
        """Set the metadata record ``name``, for the writer to write before what follows."""
        with self._lock:
            self._descriptions[name] = values

    def descriptions(self) -> dict[str, dict[str, str]]:
        """The descriptions set since the last call (the latest of each name)."""
        with self._lock:
            out, self._descriptions = self._descriptions, {}
        return out

    def get(self, timeout: float) -> Queued | None:
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def qsize(self) -> int:
        return self.queue.qsize()


def run_device(
    adapter: DeviceAdapter[Any, Any],
    outbox: Outbox,
    stop: threading.Event,
    backoff: Backoff | None = None,
) -> None:
    """The device loop: records until ``stop``; each (re)connection describes the device.

    Any exception from opening the device or from the adapter's handling of a record is
    a fault of this device: reported (:meth:`DeviceState.event`), the link closed, and
    after ``backoff`` (0.5 s doubling to 5 s; afresh after a quiet half minute) the
    device opened again. The loop ends when its link does: once ``stop`` is set.
    """
    state = adapter.state
    backoff = backoff if backoff is not None else Backoff()
    last_fault = -math.inf

    def on_event(e: LinkEvent) -> None:
        state.event(e.kind, e.detail, e.error)

    link: Relink[Any] | None = None
    while not stop.is_set():
        try:
            if link is None:
                link = adapter.open(on_event)
            _pump(adapter, link, outbox, stop)
            return  # the link ends only when stopped
        except Exception as e:
            state.event("fault", describe(e), e)
            now = time.monotonic()
            if now - last_fault > FAULTS_FORGOTTEN_S:
                backoff.reset()
            last_fault = now
            stop.wait(backoff.next())


def _pump(
    adapter: DeviceAdapter[Any, Any], link: Relink[Any], outbox: Outbox, stop: threading.Event
) -> None:
    """Records from ``link`` to the outbox until ``stop``; the link is closed on the way
    out, whatever ends it."""
    described: object = None
    with contextlib.closing(link.records(stop)) as records:
        for record in records:
            identity = adapter.identity()
            if identity is not described:  # (re)connected: describe the device
                described = identity
                outbox.describe(
                    f"device.{adapter.name}", device_metadata(adapter.driver, adapter.device)
                )
            for payload in adapter.receive(record):
                outbox.put(adapter, payload)
