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
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import queue
import threading
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, TypeVar

from acq.drivers.reconnect import LinkEvent, Relink
from acq.log.writer import LogWriter
from acq.time.clocksync import DeviceClock

__all__ = [
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
    times: deque[int] = field(default_factory=lambda: deque(maxlen=256))  # recent recv ns
    odd_size: int = 0  # frames of another size than expected (recorded, flagged)

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

    def event(self, kind: str, detail: str) -> None:
        """A link event (:class:`acq.drivers.reconnect.LinkEvent`): state, counters, log."""
        self.last_event = f"{kind}: {detail}" if detail else kind
        if kind == "connected":
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

    def bad_record(self, what: str, detail: str) -> None:
        """A record that does not decode, from a stream that goes on (a CAN bus, NMEA):
        counted; logged at the 1st, 2nd, 4th, 8th... so a wrong DBC does not flood."""
        self.protocol_errors += 1
        self.last_event = f"protocol_error: {detail}"
        n = self.protocol_errors
        if n & (n - 1) == 0:
            log.warning("%s: %s (%d so far): %s", self.name, what, n, detail)


def device_metadata(driver: str, device: Any) -> dict[str, str]:
    """JSON strings describing a connected driver's device, for a ``device.<name>`` metadata
    record: ``driver``, ``info`` (identity), ``geometry`` (scanners: ScanGeometry, in
    rad, s, m), ``params`` (Hokuyo: the PP values), ``format`` (cameras)."""
    out = {"driver": driver, "class": type(device).__name__}
    for key in ("info", "geometry", "params", "format"):
        value = getattr(device, key, None)
        if value is not None and dataclasses.is_dataclass(value):
            out[key] = json.dumps(dataclasses.asdict(value))  # type: ignore[arg-type]
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


def run_device(adapter: DeviceAdapter[Any, Any], outbox: Outbox, stop: threading.Event) -> None:
    """The device loop: records until ``stop``; each (re)connection describes the device."""
    state = adapter.state

    def on_event(e: LinkEvent) -> None:
        state.event(e.kind, e.detail)

    link = adapter.open(on_event)
    described: object = None
    for record in link.records(stop):
        identity = adapter.identity()
        if identity is not described:  # (re)connected: describe the device
            described = identity
            outbox.describe(
                f"device.{adapter.name}", device_metadata(adapter.driver, adapter.device)
            )
        for payload in adapter.receive(record):
            outbox.put(adapter, payload)
