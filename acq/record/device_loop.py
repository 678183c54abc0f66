"""The recorder's device loop: one thread per device, every kind through the same loop.

:func:`run_device` is the loop (python-can's ``Notifier`` is the model): it reads a
device's records through its reconnecting link (:class:`acq.drivers.reconnect.Relink`),
describes the device once per (re)connection, and hands each record to the device's
adapter (the ``Listener``), which updates the device's :class:`DeviceState` (counters,
clock) and returns what goes to the writer. One adapter per kind: :class:`ScannerAdapter`,
:class:`CameraAdapter`, :class:`CanAdapter`, :class:`GnssAdapter`, each opening its driver
through the driver registry (:mod:`acq.drivers.registry`). The adapter also encodes its
records for the writer thread (:meth:`DeviceAdapter.write`), so the writer knows no kind.

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
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, TypeVar

from acq.drivers.errors import DriverError, ProtocolError
from acq.drivers.reconnect import CameraLink, LinkEvent, Reconnecting, Relink
from acq.drivers.registry import REGISTRIES
from acq.log import schemas
from acq.log.mcap_log import LogWriter
from acq.record.config import CameraConfig, CanConfig, Config, GnssConfig, ScannerConfig
from acq.records import CanFrame, Fix, Frame, Odometry, Scan, Sentence
from acq.time.clocksync import DeviceClock, latency_bounds
from acq.time.sync import scan_start_ns

__all__ = [
    "GNSS",
    "VEHICLE",
    "CameraAdapter",
    "CanAdapter",
    "DeviceAdapter",
    "DeviceState",
    "GnssAdapter",
    "Outbox",
    "ScannerAdapter",
    "adapters_for",
    "device_metadata",
    "run_device",
]

log = logging.getLogger("acq.record")

VEHICLE = "vehicle"  # the CAN bus's device name: topics /vehicle/odometry, /vehicle/can
GNSS = "gnss"  # the GNSS receiver's: /gnss/fix, /gnss/raw, /acq/timing/gnss
GNSS_TICK_HZ = 1_000_000  # a fix time as a device tick: UTC microseconds since the epoch

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
    last_tick: int | None = None  # the last raw device tick
    last_event: str = ""
    clock: DeviceClock | None = None
    latency_s: float = 0.0
    latency_bounds_s: tuple[float, float] | None = None
    times: deque[int] = field(default_factory=lambda: deque(maxlen=256))  # recent recv ns

    def clock_offset_ns(self) -> int:
        """Host ns minus device ns (unwrapped ticks) at the last stamp; 0 before any."""
        clock, tick = self.clock, self.last_tick
        if clock is None or tick is None or clock.updates == 0:
            return 0
        device_ns = round(clock.unwrapper.nearest(tick) * 1e9 / clock.tick_hz)
        return clock.to_host_ns(tick) - device_ns

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


def _finite(x: float, cap: float = 1e9) -> float:
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


# --- scanners -------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Counts:
    """The device's counters when a record came in, for its timing message (read later, on
    the writer's thread, they would count the records received since)."""

    received: int
    dropped: int


@dataclass(frozen=True)
class _ScanItem:
    scan: Scan
    stamp_ns: int  # host ns of point 0
    unwrapped: int
    epoch: int
    counts: _Counts


class ScannerAdapter(DeviceAdapter[Scan, _ScanItem]):
    """A laser scanner: ``/<name>/scan``, ``/<name>/raw``, ``/acq/timing/<name>``; scans
    stamped through the device clock, ``latency_s: auto`` measured with the driver's
    time queries before streaming."""

    kind = "scanner"

    def __init__(self, cfg: ScannerConfig) -> None:
        super().__init__(cfg.name, cfg.driver)
        self.cfg = cfg
        self._tm_samples: tuple[tuple[int, int, int], ...] = ()

    def channels(self) -> list[tuple[str, str]]:
        name = self.name
        return [
            (f"/{name}/scan", "foxglove.LaserScan"),
            (f"/{name}/raw", "acq.RawTelegram"),
            (f"/acq/timing/{name}", "acq.Timing"),
        ]

    def open(self, on_event: Callable[[LinkEvent], None]) -> Relink[Scan]:
        cfg, state = self.cfg, self.state
        options: dict[str, Any] = dict(cfg.options)
        if cfg.protocol is not None:
            options["protocol"] = cfg.protocol
        scanner = REGISTRIES["scanner"].create(cfg.driver, cfg.url, name=cfg.name, **options)
        self.device = scanner
        cls = type(scanner)
        state.clock = DeviceClock(cls.tick_hz, cls.tick_bits)
        if cfg.latency_s == "auto":
            self._tm_samples = self._measure_latency(scanner)
        else:
            state.latency_s = float(cfg.latency_s)
        return Reconnecting(scanner, on_event=on_event)

    def identity(self) -> object:
        return self.device.geometry

    def receive(self, record: Scan) -> Iterable[_ScanItem]:
        scan, state, clock = record, self.state, self.state.clock
        assert clock is not None
        state.count(scan.recv_ns)
        counts = _Counts(state.received, state.dropped)
        if not scan.device_ticks:
            return (_ScanItem(scan, scan.recv_ns - round(state.latency_s * 1e9), 0, 0, counts),)
        state.last_tick = scan.device_ticks[0]
        clock.update(scan.device_ticks[0], scan.recv_ns)
        if self._tm_samples and clock.updates in (1, 40, 400):  # at once, then refined
            self._apply_latency_bounds(clock)
        geometry = self.device.geometry
        offset = geometry.stamp_offset_s if geometry is not None else 0.0
        stamp = scan_start_ns(clock.to_host_ns(scan.device_ticks[0]), offset, state.latency_s)
        unwrapped = clock.unwrapper.nearest(scan.device_ticks[0])
        return (_ScanItem(scan, stamp, unwrapped, clock.epoch, counts),)

    def write(self, writer: LogWriter, payload: _ScanItem) -> None:
        name, clock = self.name, self.state.clock
        scan, stamp = payload.scan, payload.stamp_ns
        timing = schemas.timing(
            recv_ns=scan.recv_ns,
            device_ticks=scan.device_ticks,
            unwrapped_tick=payload.unwrapped,
            epoch=payload.epoch,
            stamp_ns=stamp,
            offset_ns=stamp - scan.recv_ns,
            drift_ppm=clock.drift_ppm if clock else 0.0,
            uncertainty_s=_finite(clock.uncertainty_s) if clock else 0.0,
            sequence=scan.sequence,
            received=payload.counts.received,
            dropped=payload.counts.dropped,
        )
        raw = schemas.raw_telegram(
            device=name, data=scan.raw, device_ticks=scan.device_ticks,
            sequence=scan.sequence, recv_ns=scan.recv_ns, stamp_ns=stamp,
        )  # fmt: skip
        writer.write_group([
            (f"/{name}/scan", schemas.laser_scan(scan, name, stamp), scan.recv_ns, stamp),
            (f"/{name}/raw", raw, scan.recv_ns, stamp),
            (f"/acq/timing/{name}", timing, scan.recv_ns, stamp),
        ])  # fmt: skip

    def _measure_latency(self, scanner: Any) -> tuple[tuple[int, int, int], ...]:
        """The driver's time queries before streaming; () if the device cannot be reached
        yet."""
        name = self.name
        try:
            scanner.connect()
            est = scanner.measure_latency(20)
        except (DriverError, OSError) as e:
            log.warning("%s: latency_s auto: no time queries (%s); using 0 until then", name, e)
            return ()
        finally:
            try:
                scanner.close()
            except (DriverError, OSError):
                pass
        log.info("%s: 20 time queries, round trip %.2f-%.2f ms", name,
                 est.rtt_min * 1e3, est.rtt_max * 1e3)  # fmt: skip
        return tuple(est.samples)

    def _apply_latency_bounds(self, clock: DeviceClock) -> None:
        state = self.state
        try:
            lo, hi = latency_bounds(self._tm_samples, clock)
        except ValueError as e:
            log.warning("%s: latency_s auto: %s", state.name, e)
            return
        state.latency_bounds_s = (lo, hi)
        state.latency_s = (lo + hi) / 2
        log.info("%s: latency from the stamp to receipt %.2f ms (bounds %.2f-%.2f ms)",
                 state.name, state.latency_s * 1e3, lo * 1e3, hi * 1e3)  # fmt: skip


# --- cameras --------------------------------------------------------------------------------


@dataclass(frozen=True)
class _FrameItem:
    frame: Frame
    counts: _Counts  # dropped: also those lost before us (sequence gaps)


class CameraAdapter(DeviceAdapter[Frame, _FrameItem]):
    """A camera: ``/<name>/image/compressed`` (the JPEG as sent), ``/acq/timing/<name>``."""

    kind = "camera"

    def __init__(self, cfg: CameraConfig) -> None:
        super().__init__(cfg.name, cfg.driver)
        self.cfg = cfg

    def channels(self) -> list[tuple[str, str]]:
        return [
            (f"/{self.name}/image/compressed", "foxglove.CompressedImage"),
            (f"/acq/timing/{self.name}", "acq.Timing"),
        ]

    def open(self, on_event: Callable[[LinkEvent], None]) -> Relink[Frame]:
        cfg = self.cfg
        options: dict[str, Any] = dict(cfg.options)
        for key in ("width", "height", "fourcc"):
            value = getattr(cfg, key)
            if value is not None:
                options[key] = value
        camera = REGISTRIES["camera"].create(
            cfg.driver, cfg.source, name=cfg.name, fps=cfg.fps, latency_s=cfg.latency_s, **options
        )
        self.device = camera
        return CameraLink(camera, on_event=on_event)

    def identity(self) -> object:
        return self.device.format

    def receive(self, record: Frame) -> Iterable[_FrameItem]:
        state = self.state
        state.count(record.recv_ns)
        state.source_drops = self.device.drops
        state.corrupt = self.device.corrupt
        return (_FrameItem(record, _Counts(state.received, state.dropped + state.source_drops)),)

    def write(self, writer: LogWriter, payload: _FrameItem) -> None:
        frame, name = payload.frame, self.name
        timing = schemas.timing(
            recv_ns=frame.recv_ns,
            stamp_ns=frame.stamp_ns,
            offset_ns=frame.stamp_ns - frame.recv_ns,
            sequence=frame.sequence,
            received=payload.counts.received,
            dropped=payload.counts.dropped,
        )
        image = schemas.compressed_image(frame, name)
        writer.write_group([
            (f"/{name}/image/compressed", image, frame.recv_ns, frame.stamp_ns),
            (f"/acq/timing/{name}", timing, frame.recv_ns, frame.stamp_ns),
        ])  # fmt: skip


# --- the vehicle's CAN bus ------------------------------------------------------------------


@dataclass(frozen=True)
class _CanItem:
    """A CAN frame and the odometry decoded from it (None: not an odometry message)."""

    frame: CanFrame
    odometry: Odometry | None


class CanAdapter(DeviceAdapter[CanFrame, _CanItem]):
    """The vehicle's CAN bus: every frame to ``/vehicle/can``, odometry decoded from the
    configured messages to ``/vehicle/odometry``; a frame that does not decode is a protocol
    error (counted, logged), never the end of the thread."""

    kind = "can"

    def __init__(self, cfg: CanConfig) -> None:
        super().__init__(VEHICLE, cfg.driver)
        self.cfg = cfg
        self._bad_stamps = 0

    def channels(self) -> list[tuple[str, str]]:
        return [(f"/{VEHICLE}/odometry", "acq.Odometry"), (f"/{VEHICLE}/can", "acq.CanFrame")]

    def open(self, on_event: Callable[[LinkEvent], None]) -> Relink[CanFrame]:
        cfg = self.cfg
        bus = REGISTRIES["can"].create(
            cfg.driver,
            cfg.interface,
            cfg.channel,
            cfg.dbc,
            bitrate=cfg.bitrate,
            wheel_speeds=cfg.wheel_speeds,
            yaw_rate=cfg.yaw_rate,
            speed=cfg.speed,
            name=VEHICLE,
            bus_options=cfg.options,
        )
        self.device = bus
        return Relink(bus, bus.read_frame, on_event=on_event, reachable=bus.reachable)

    def identity(self) -> object:
        return self.device.info

    def receive(self, record: CanFrame) -> Iterable[_CanItem]:
        state, bus = self.state, self.device
        try:
            odometry = bus.decode(record)
        except ProtocolError as e:
            state.bad_record("bad CAN frame", str(e))
            odometry = None
        if odometry is not None:
            state.count(record.recv_ns)
        if bus.bad_stamps > self._bad_stamps:
            self._bad_stamps = n = bus.bad_stamps
            if n & (n - 1) == 0:  # 1, 2, 4, 8...: no flood
                log.warning("%s: %d CAN frames without a usable interface stamp (none, "
                            "or the wall clock stepped): their receive time is used",
                            VEHICLE, n)  # fmt: skip
        return (_CanItem(record, odometry),)

    def write(self, writer: LogWriter, payload: _CanItem) -> None:
        frame = payload.frame
        group = [(f"/{VEHICLE}/can", schemas.can_frame(frame), frame.recv_ns, frame.stamp_ns)]
        if payload.odometry is not None:
            odo = payload.odometry
            group.append((f"/{VEHICLE}/odometry", schemas.odometry(odo), odo.recv_ns, odo.stamp_ns))
        writer.write_group(group)


# --- the GNSS receiver ----------------------------------------------------------------------


@dataclass(frozen=True)
class _FixItem:
    fix: Fix
    stamp_ns: int  # the fix instant on the host clock
    tick: int  # the fix time as UTC µs (GNSS_TICK_HZ)
    counts: _Counts


class GnssAdapter(DeviceAdapter[Sentence, Sentence | _FixItem]):
    """The GNSS receiver: every sentence to ``/gnss/raw``, each fix to ``/gnss/fix`` and
    ``/acq/timing/gnss``, stamped with its fix time (the receiver's UTC, a device clock)
    mapped to the host clock less ``latency_s``."""

    kind = "gnss"

    def __init__(self, cfg: GnssConfig) -> None:
        super().__init__(GNSS, cfg.driver)
        self.cfg = cfg

    def channels(self) -> list[tuple[str, str]]:
        return [
            (f"/{GNSS}/fix", "foxglove.LocationFix"),
            (f"/{GNSS}/raw", "acq.RawTelegram"),
            (f"/acq/timing/{GNSS}", "acq.Timing"),
        ]

    def open(self, on_event: Callable[[LinkEvent], None]) -> Relink[Sentence]:
        cfg, state = self.cfg, self.state
        receiver = REGISTRIES["gnss"].create(cfg.driver, cfg.url, baudrate=cfg.baudrate, name=GNSS)
        self.device = receiver
        state.clock = DeviceClock(GNSS_TICK_HZ, 62, periodic=False)
        state.latency_s = cfg.latency_s
        return Relink(receiver, receiver.read_sentence, on_event=on_event)

    def identity(self) -> object:
        return self.device.info

    def receive(self, record: Sentence) -> Iterable[Sentence | _FixItem]:
        state, clock = self.state, self.state.clock
        assert clock is not None
        try:
            fix = self.device.decode(record)
        except ProtocolError as e:
            state.bad_record("bad NMEA sentence", str(e))
            return (record,)
        if fix is None:
            return (record,)
        tick = round(fix.utc_s * GNSS_TICK_HZ)
        if fix.quality > 0:  # without a fix a receiver's time may be its RTC's guess
            epoch = clock.epoch
            clock.update(tick, fix.recv_ns)
            state.last_tick = tick
            if clock.epoch != epoch:
                state.event("clock_reset", "the receiver's UTC jumped: "
                            "its mapping to host time starts afresh")  # fmt: skip
        state.count(fix.recv_ns)
        mapped = clock.to_host_ns(tick) if clock.updates else fix.recv_ns
        counts = _Counts(state.received, state.dropped)
        return (record, _FixItem(fix, mapped - round(state.latency_s * 1e9), tick, counts))

    def write(self, writer: LogWriter, payload: Sentence | _FixItem) -> None:
        if isinstance(payload, Sentence):
            raw = schemas.raw_telegram(device=GNSS, data=payload.data, recv_ns=payload.recv_ns)
            writer.write(f"/{GNSS}/raw", raw, payload.recv_ns, payload.recv_ns)
            return
        fix, stamp, clock = payload.fix, payload.stamp_ns, self.state.clock
        timing = schemas.timing(
            recv_ns=fix.recv_ns,
            device_ticks=(payload.tick,),
            unwrapped_tick=payload.tick,
            epoch=clock.epoch if clock else 0,
            stamp_ns=stamp,
            offset_ns=stamp - fix.recv_ns,
            drift_ppm=clock.drift_ppm if clock else 0.0,
            uncertainty_s=_finite(clock.uncertainty_s) if clock else 0.0,
            received=payload.counts.received,
            dropped=payload.counts.dropped,
        )
        writer.write_group([
            (f"/{GNSS}/fix", schemas.location_fix(fix, stamp, GNSS), fix.recv_ns, stamp),
            (f"/acq/timing/{GNSS}", timing, fix.recv_ns, stamp),
        ])  # fmt: skip


def adapters_for(config: Config) -> Sequence[DeviceAdapter[Any, Any]]:
    """The adapters of a configuration's devices: scanners, cameras, CAN bus, GNSS."""
    adapters: list[DeviceAdapter[Any, Any]] = [ScannerAdapter(s) for s in config.scanners]
    adapters += [CameraAdapter(c) for c in config.cameras]
    if config.can is not None:
        adapters.append(CanAdapter(config.can))
    if config.gnss is not None:
        adapters.append(GnssAdapter(config.gnss))
    return adapters
