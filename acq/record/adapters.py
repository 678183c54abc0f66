"""The device loop's adapters, one per device kind (python-can's ``Listener`` is the model).

:class:`ScannerAdapter`, :class:`CameraAdapter`, :class:`CanAdapter` and
:class:`GnssAdapter` each open their driver through the driver registry
(:mod:`acq.drivers.registry`), turn its records into what the writer needs (updating the
device's :class:`acq.record.device_loop.DeviceState`) and, on the writer's thread,
encode them into the device's topics. :func:`adapters_for` gives a configuration's.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from acq.camera.calibfile import Calibration
from acq.drivers.errors import DriverError, ProtocolError
from acq.drivers.reconnect import CameraLink, LinkEvent, Reconnecting, Relink
from acq.drivers.registry import REGISTRIES
from acq.log import schemas
from acq.log.writer import LogWriter
from acq.record.config import (
    GNSS,
    VEHICLE,
    CameraConfig,
    CanConfig,
    Config,
    GnssConfig,
    ScannerConfig,
)
from acq.record.device_loop import DeviceAdapter, finite
from acq.records import CanFrame, Fix, Frame, Odometry, Scan, Sentence
from acq.time import kernel_clock
from acq.time.clocksync import DeviceClock, latency_bounds
from acq.time.sync import stamp_scan
from acq.time.utc import host_ns_from_utc

__all__ = [
    "GNSS",
    "VEHICLE",
    "CameraAdapter",
    "CanAdapter",
    "GnssAdapter",
    "ScannerAdapter",
    "adapters_for",
]

log = logging.getLogger("acq.record")

GNSS_TICK_HZ = 1_000_000  # a fix time as a device tick: UTC microseconds since the epoch


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


TELEGRAM_LATENCY_SCANS = 40  # scans whose own stamp-to-sending times set latency_s


class ScannerAdapter(DeviceAdapter[Scan, _ScanItem]):
    """A laser scanner: ``/<name>/scan``, ``/<name>/raw``, ``/acq/timing/<name>``; scans
    stamped through the device clock less ``latency_s``. ``latency_s: auto`` is measured
    with the driver's time queries at each connection, bounded once the clock has
    scans to map them with (again after 40 and 400), or from the scans' own telegrams
    (the median of the first ``TELEGRAM_LATENCY_SCANS``)."""

    kind = "scanner"

    def __init__(self, cfg: ScannerConfig) -> None:
        super().__init__(cfg.name, cfg.driver)
        self.cfg = cfg
        self._tm_samples: tuple[tuple[int, int, int], ...] = ()
        self._tm_at = 0  # the clock's update count when they were taken
        self._telegram_latencies: list[float] = []

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
        on_connect = None
        if cfg.latency_s == "auto":
            state.latency_source = f"auto: {cls.latency_probe}, not yet measured (0 until then)"
            if hasattr(scanner, "measure_latency"):
                on_connect = self._measure_latency
        else:
            state.latency_s = float(cfg.latency_s)
        how = (f"auto, from {cls.latency_probe}" if cfg.latency_s == "auto"
               else f"{state.latency_s * 1e3:.2f} ms, configured")  # fmt: skip
        log.info("%s: latency_s %s", self.name, how)
        return Reconnecting(scanner, on_event=on_event, on_connect=on_connect)

    def identity(self) -> object:
        return self.device.geometry

    def receive(self, record: Scan) -> Iterable[_ScanItem]:
        scan, state, clock = record, self.state, self.state.clock
        assert clock is not None
        state.count(scan.recv_ns)
        counts = _Counts(state.received, state.dropped)
        if not scan.device_ticks:
            return (_ScanItem(scan, scan.recv_ns - round(state.latency_s * 1e9), 0, 0, counts),)
        clock.update(scan.device_ticks[0], scan.recv_ns)
        state.stamped(scan.device_ticks[0])
        if self._tm_samples and clock.updates - self._tm_at in (1, 40, 400):  # then refined
            self._apply_latency_bounds(clock)
        if self.cfg.latency_s == "auto" and len(self._telegram_latencies) < TELEGRAM_LATENCY_SCANS:
            self._telegram_latency(scan)
        geometry = self.device.geometry
        offset = geometry.stamp_offset_s if geometry is not None else 0.0
        stamp = stamp_scan(scan, clock, offset, state.latency_s).start_ns
        assert stamp is not None
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
            uncertainty_s=finite(clock.uncertainty_s) if clock else 0.0,
            sequence=scan.sequence,
            received=payload.counts.received,
            dropped=payload.counts.dropped,
        )
        raw = schemas.raw_telegram(
            device=name, data=scan.raw, device_ticks=scan.device_ticks,
            sequence=scan.sequence, recv_ns=scan.recv_ns, stamp_ns=stamp,
        )  # fmt: skip
        writer.write_group([
            (f"/{name}/scan", schemas.laser_scan(scan, name, writer.time_base.to_log(stamp)),
             scan.recv_ns, stamp),
            (f"/{name}/raw", raw, scan.recv_ns, stamp),
            (f"/acq/timing/{name}", timing, scan.recv_ns, stamp),
        ])  # fmt: skip

    def _measure_latency(self) -> None:
        """The driver's time queries, at a connection before streaming (a failure is
        logged: the latency keeps its last value)."""
        name, clock = self.name, self.state.clock
        try:
            est = self.device.measure_latency(20)
        except (DriverError, OSError) as e:
            log.warning("%s: latency_s auto: no time queries (%s); keeping %.2f ms", name, e,
                        self.state.latency_s * 1e3)  # fmt: skip
            return
        log.info("%s: 20 time queries, round trip %.2f-%.2f ms", name,
                 est.rtt_min * 1e3, est.rtt_max * 1e3)  # fmt: skip
        self._tm_samples = tuple(est.samples)
        self._tm_at = clock.updates if clock is not None else 0

    def _telegram_latency(self, scan: Scan) -> None:
        """One more scan's own stamp-to-sending time; the median once there are enough."""
        latency = self.device.telegram_latency_s(scan)
        if latency is None:
            return
        seen = self._telegram_latencies
        seen.append(latency)
        if len(seen) == TELEGRAM_LATENCY_SCANS:
            state = self.state
            state.latency_s = float(np.median(seen))
            state.latency_bounds_s = (min(seen), max(seen))
            state.latency_source = f"auto: {type(self.device).latency_probe}"
            log.info(
                "%s: latency from the stamp to sending %.2f ms (scans %.2f-%.2f ms)",
                state.name, state.latency_s * 1e3, min(seen) * 1e3, max(seen) * 1e3,
            )  # fmt: skip

    def _apply_latency_bounds(self, clock: DeviceClock) -> None:
        state = self.state
        try:
            lo, hi = latency_bounds(self._tm_samples, clock)
        except ValueError as e:
            log.warning("%s: latency_s auto: %s", state.name, e)
            return
        state.latency_bounds_s = (lo, hi)
        state.latency_s = (lo + hi) / 2
        state.latency_source = f"auto: {type(self.device).latency_probe}"
        log.info("%s: latency from the stamp to receipt %.2f ms (bounds %.2f-%.2f ms)",
                 state.name, state.latency_s * 1e3, lo * 1e3, hi * 1e3)  # fmt: skip


# --- cameras --------------------------------------------------------------------------------


@dataclass(frozen=True)
class _FrameItem:
    frame: Frame
    counts: _Counts  # dropped: also those lost before us (sequence gaps)


class CameraAdapter(DeviceAdapter[Frame, _FrameItem]):
    """A camera: ``/<name>/image/compressed`` (the JPEG as sent), ``/acq/timing/<name>``.

    Every frame is written; one of another size than expected is also counted
    (``state.odd_size``) and logged at the 1st, 2nd, 4th... The expected (width, height)
    px: ``size`` (the calibration's camera model), else the format the camera announced
    when its first frame came, else that frame's."""

    kind = "camera"

    def __init__(self, cfg: CameraConfig, size: tuple[int, int] | None = None) -> None:
        super().__init__(cfg.name, cfg.driver)
        self.cfg = cfg
        self.state.expected_hz = cfg.fps  # a camera far faster is a warning
        self.size = size
        self._size_from = "the calibration's camera model"

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
        self._check_size(record)
        return (_FrameItem(record, _Counts(state.received, state.dropped + state.source_drops)),)

    def _check_size(self, frame: Frame) -> None:
        """Count and log a frame of another size than expected (see the class docstring)."""
        got = (frame.width, frame.height)
        if self.size is None:
            fmt = getattr(self.device, "format", None)
            if fmt is not None and fmt.width > 0 and fmt.height > 0:
                self.size, self._size_from = (fmt.width, fmt.height), "the camera's format"
            else:
                self.size, self._size_from = got, "its first frame"
        if got == self.size:
            return
        state = self.state
        state.odd_size += 1
        n = state.odd_size
        if n & (n - 1) == 0:  # 1, 2, 4, 8...: no flood
            log.warning("%s: a %dx%d frame, not %dx%d as %s: recorded, flagged (%d so far)",
                        self.name, *got, *self.size, self._size_from, n)  # fmt: skip

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
        image = schemas.compressed_image(frame, name, writer.time_base.to_log(frame.stamp_ns))
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
    epoch: int  # the clock's epoch when the fix came (the writer's turn may be later)
    counts: _Counts
    source: str  # what set stamp_ns: "fix" or "receipt" (GnssConfig.time)


GNSS_CLOCK_CHECK_S = 10.0  # how often gnss.time auto asks the kernel about the host clock
# receipt minus the fix time through the host's UTC clock beyond which that clock (or the
# receiver's UTC) cannot be right: the fix is stamped from its receipt instead
GNSS_RECEIPT_BOUNDS_S = (-0.05, 2.0)


def _host_clock_disciplined() -> tuple[bool, str]:
    """Whether the kernel says the host clock is synchronised to UTC, and in words."""
    k = kernel_clock.read_kernel_clock()
    if k is None:
        return False, "the kernel's clock status is unknown on this system"
    if not k.synchronised:
        return False, f"the host clock is not synchronised (kernel: {k.state})"
    return True, f"the host clock is synchronised (kernel maxerror {k.maxerror_s * 1e3:.1f} ms)"


class GnssAdapter(DeviceAdapter[Sentence, Sentence | _FixItem]):
    """The GNSS receiver: every sentence to ``/gnss/raw``, each fix to ``/gnss/fix`` and
    ``/acq/timing/gnss``. A fix is stamped (``gnss.time``, :class:`GnssConfig`) from its
    own UTC fix time through the host's UTC clock (``fix``), or from its fix time mapped
    through the receipt times like a device clock, less ``latency_s`` (``receipt``);
    ``auto`` takes ``fix`` while the kernel says the host clock is synchronised, asked at
    the start and every :data:`GNSS_CLOCK_CHECK_S`."""

    kind = "gnss"

    def __init__(self, cfg: GnssConfig) -> None:
        super().__init__(GNSS, cfg.driver)
        self.cfg = cfg
        self.source = "receipt"  # how fixes are stamped now: "fix" or "receipt"
        self._checked_ns = 0  # host monotonic ns of the last look at the host clock
        self._implausible = False  # the last fix's UTC time was off its receipt

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
        why = self._choose(time.monotonic_ns())
        log.info("%s: %s", GNSS, self._stamping(why))
        return Relink(receiver, receiver.read_sentence, on_event=on_event)

    def _choose(self, now_ns: int) -> str:
        """Set :attr:`source` as ``gnss.time`` says; why, in words."""
        self._checked_ns = now_ns
        if self.cfg.time != "auto":
            self.source = self.cfg.time
            why = f"gnss.time {self.cfg.time}"
        else:
            disciplined, why = _host_clock_disciplined()
            self.source = "fix" if disciplined else "receipt"
            why = f"gnss.time auto: {why}"
        state = self.state
        state.latency_source = (
            f"configured; not subtracted: fixes stamped from their UTC fix time ({why})"
            if self.source == "fix"
            else f"configured; fixes stamped from their receipt ({why})"
        )
        return why

    def _stamping(self, why: str) -> str:
        """How fixes are stamped now, for the log."""
        if self.source == "fix":
            return f"fixes stamped from their UTC fix time through the host clock ({why})"
        return (f"fixes stamped from their receipt, less latency_s "
                f"{self.cfg.latency_s * 1e3:.2f} ms ({why})")  # fmt: skip

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
            state.stamped(tick)
            if clock.epoch != epoch:
                state.event("clock_reset", "the receiver's UTC jumped: "
                            "its mapping to host time starts afresh")  # fmt: skip
        state.count(fix.recv_ns)
        if self.cfg.time == "auto" and fix.recv_ns - self._checked_ns >= GNSS_CLOCK_CHECK_S * 1e9:
            before = self.source
            why = self._choose(fix.recv_ns)
            if self.source != before:
                state.event("time_source", self._stamping(why))
                log.warning("%s: from now on %s", GNSS, self._stamping(why))
        counts = _Counts(state.received, state.dropped)
        stamp = self._fix_stamp(fix) if self.source == "fix" and fix.quality > 0 else None
        if stamp is not None:
            return (record, _FixItem(fix, stamp, tick, clock.epoch, counts, "fix"))
        mapped = clock.to_host_ns(tick) if clock.updates else fix.recv_ns
        stamp = mapped - round(state.latency_s * 1e9)
        return (record, _FixItem(fix, stamp, tick, clock.epoch, counts, "receipt"))

    def _fix_stamp(self, fix: Fix) -> int | None:
        """The fix's UTC time as host monotonic ns, through the host's UTC clock now; None
        (logged once) when its receipt is not within :data:`GNSS_RECEIPT_BOUNDS_S` after
        it: a host clock or a receiver's UTC that cannot be right."""
        pair = (time.monotonic_ns(), time.time_ns())  # as /acq/clock pairs
        stamp = int(host_ns_from_utc(fix.utc_s, pair))
        delay_s = (fix.recv_ns - stamp) * 1e-9
        lo, hi = GNSS_RECEIPT_BOUNDS_S
        plausible = lo <= delay_s <= hi
        if plausible == self._implausible:
            self._implausible = not plausible
            if plausible:
                log.info("%s: fix times and receipts agree again: fixes stamped from their "
                         "UTC fix time", GNSS)  # fmt: skip
            else:
                log.warning("%s: a fix received %.3f s after its UTC fix time by the host "
                            "clock (expected %g to %g s): stamped from its receipt until "
                            "they agree", GNSS, delay_s, lo, hi)  # fmt: skip
        return stamp if plausible else None

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
            epoch=payload.epoch,
            stamp_ns=stamp,
            offset_ns=stamp - fix.recv_ns,
            drift_ppm=clock.drift_ppm if clock else 0.0,
            uncertainty_s=finite(clock.uncertainty_s) if clock else 0.0,
            received=payload.counts.received,
            dropped=payload.counts.dropped,
            stamp_source=payload.source,
        )
        writer.write_group([
            (f"/{GNSS}/fix", schemas.location_fix(fix, writer.time_base.to_log(stamp), GNSS),
             fix.recv_ns, stamp),
            (f"/acq/timing/{GNSS}", timing, fix.recv_ns, stamp),
        ])  # fmt: skip


def adapters_for(
    config: Config, calibration: Calibration | None = None
) -> Sequence[DeviceAdapter[Any, Any]]:
    """The adapters of a configuration's devices: scanners, cameras, CAN bus, GNSS; a
    camera in ``calibration`` expects frames of its model's size."""
    adapters: list[DeviceAdapter[Any, Any]] = [ScannerAdapter(s) for s in config.scanners]
    for c in config.cameras:
        cam = calibration.cameras.get(c.name) if calibration is not None else None
        adapters.append(CameraAdapter(c, (cam.model.width, cam.model.height) if cam else None))
    if config.can is not None:
        adapters.append(CanAdapter(config.can))
    if config.gnss is not None:
        adapters.append(GnssAdapter(config.gnss))
    return adapters
