"""`acq record`: every device of a configuration into rolling MCAP files.

One thread per device (scanners, cameras, the vehicle's CAN bus, the GNSS receiver)
reads records through its driver (reconnecting with backoff), applies the device
clock, and hands them to one writer thread through a bounded queue:
a slow disk drops records (counted per device), it never blocks a reader. The writer
encodes (Foxglove protobuf schemas, the raw telegrams, the timing), writes, ends and
fsyncs the chunk every second, publishes ``/acq/status`` and ``/acq/clock`` at 1 Hz,
pings the systemd watchdog, and watches the disk: below the configured reserve it
closes the file and the recorder exits with :data:`EXIT_DISK_FULL`.

Vehicle topics (with ``can:`` / ``gnss:`` in the configuration): ``/vehicle/odometry``
(``acq.Odometry``, stamped with the CAN receive stamp mapped to the monotonic clock, see
:mod:`acq.drivers.can_odometry`), ``/vehicle/can`` (``acq.CanFrame``: every frame of the bus,
to re-decode with another DBC), ``/gnss/fix`` (``foxglove.LocationFix``), ``/gnss/raw``
(``acq.RawTelegram``: each NMEA sentence) and ``/acq/timing/gnss``. A fix is stamped
with its fix instant: the receiver's UTC fix time is a device clock like a scanner's,
mapped to host time by the one-way estimator (:class:`acq.time.clocksync.DeviceClock`) less
the configured ``latency_s``, so neither the host's wall clock nor its NTP steps enter.

Exit codes: 0 stopped (signal or ``--duration``), 1 runtime failure, 2 bad
configuration, 3 disk below its reserve (listed in the unit's ``RestartPreventExitStatus``).
"""

from __future__ import annotations

import functools
import logging
import math
import os
import queue
import shutil
import socket
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.errors import InputError
from acq.log import schemas
from acq.log.mcap_log import LogWriter
from acq.record.config import CameraConfig, CanConfig, Config, GnssConfig, ScannerConfig
from acq.record.sdnotify import Notifier
from acq.records import CanFrame, Fix, Frame, Odometry, Scan, Sentence
from acq.time.clocksync import DeviceClock, latency_bounds
from acq.time.sync import scan_start_ns

__all__ = ["EXIT_DISK_FULL", "Recorder", "RecorderError"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_DISK_FULL = 3

log = logging.getLogger("acq.record")

QUEUE_SIZE = 512  # records; at 25 frames/s of ~60 kB that is 20 s of a stalled disk
VEHICLE = "vehicle"  # the CAN bus's device name: topics /vehicle/odometry, /vehicle/can
GNSS = "gnss"  # the GNSS receiver's: /gnss/fix, /gnss/raw, /acq/timing/gnss
GNSS_TICK_HZ = 1_000_000  # a fix time as a device tick: UTC microseconds since the epoch
STATUS_PERIOD_S = 1.0
DRAIN_S = 1.0  # on stop: the time left to write what is queued before the file closes


class RecorderError(InputError, RuntimeError):
    """The recorder cannot start (a calibration that cannot be read, an output folder
    that cannot be written)."""


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
        recent = [t for t in self.times if now_ns - t <= 2_000_000_000]
        span_ns = recent[-1] - recent[0] if len(recent) >= 2 else 0
        # records that came in one read share a receive time: no rate from them alone
        return (len(recent) - 1) / (span_ns * 1e-9) if span_ns > 0 else 0.0


@dataclass(frozen=True)
class _ScanItem:
    device: str
    scan: Scan
    stamp_ns: int  # host ns of point 0
    unwrapped: int
    epoch: int


@dataclass(frozen=True)
class _FrameItem:
    device: str
    frame: Frame


@dataclass(frozen=True)
class _CanItem:
    """A CAN frame and the odometry decoded from it (None: not an odometry message)."""

    device: str
    frame: CanFrame
    odometry: Odometry | None


@dataclass(frozen=True)
class _SentenceItem:
    device: str
    sentence: Sentence


@dataclass(frozen=True)
class _FixItem:
    device: str
    fix: Fix
    stamp_ns: int  # the fix instant on the host clock
    tick: int  # the fix time as UTC µs (GNSS_TICK_HZ)


@dataclass(frozen=True)
class _MetaItem:
    """A device's description (identity, geometry, parameters) for the log's metadata."""

    name: str
    values: dict[str, str]


_Item = _ScanItem | _FrameItem | _MetaItem | _CanItem | _SentenceItem | _FixItem


def device_metadata(driver: str, device: Any) -> dict[str, str]:
    """JSON strings describing a connected driver's device, for a ``device.<name>`` metadata
    record: ``driver``, ``info`` (identity), ``geometry`` (scanners: ScanGeometry, in
    rad, s, m), ``params`` (Hokuyo: the PP values), ``format`` (cameras)."""
    import dataclasses
    import json

    out = {"driver": driver, "class": type(device).__name__}
    for key in ("info", "geometry", "params", "format"):
        value = getattr(device, key, None)
        if value is not None and dataclasses.is_dataclass(value):
            out[key] = json.dumps(dataclasses.asdict(value))  # type: ignore[arg-type]
    return out


class Recorder:
    """Records ``config``'s devices until :meth:`stop` (or ``duration_s``).

    ``out_dir`` overrides ``config.output.dir``; ``calibration`` overrides the file the
    config names. :meth:`run` returns the exit code.
    """

    def __init__(
        self,
        config: Config,
        *,
        out_dir: Path | None = None,
        duration_s: float | None = None,
        calibration: Calibration | None = None,
        notifier: Notifier | None = None,
        queue_size: int = QUEUE_SIZE,
    ) -> None:
        self.config = config
        self.out_dir = Path(out_dir if out_dir is not None else config.output.dir)
        self.duration_s = duration_s
        self.notifier = notifier if notifier is not None else Notifier()
        self.calibration = calibration if calibration is not None else self._load_calibration()
        self.queue: queue.Queue[_Item] = queue.Queue(maxsize=queue_size)
        self.devices: dict[str, DeviceState] = {}
        for s in config.scanners:
            self.devices[s.name] = DeviceState(s.name, "scanner")
        for c in config.cameras:
            self.devices[c.name] = DeviceState(c.name, "camera")
        if config.can is not None:
            self._check_dbc(config.can)
            self.devices[VEHICLE] = DeviceState(VEHICLE, "can")
        if config.gnss is not None:
            self.devices[GNSS] = DeviceState(GNSS, "gnss")
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.writer: LogWriter | None = None
        self.exit_code = EXIT_OK
        self.started_ns = 0
        self._bytes_hist: deque[tuple[int, int]] = deque(maxlen=30)  # (mono ns, bytes)

    # --- set-up ------------------------------------------------------------------------

    def _load_calibration(self) -> Calibration | None:
        path = self.config.calibration
        if path is None:
            log.warning("no calibration in the configuration: /tf_static and camera "
                        "calibrations are not recorded")  # fmt: skip
            return None
        try:
            return calibfile.load(path)
        except FileNotFoundError:
            raise RecorderError(f"{path}: no such calibration file") from None
        except calibfile.CalibFileError as e:
            raise RecorderError(str(e)) from None

    @staticmethod
    def _check_dbc(cfg: CanConfig) -> None:
        """The DBC must hold the configured signals, with units (RecorderError if not)."""
        from acq.drivers.can_odometry import DbcError, OdometryDecoder

        try:
            OdometryDecoder.from_file(
                cfg.dbc, wheel_speeds=cfg.wheel_speeds, yaw_rate=cfg.yaw_rate, speed=cfg.speed
            )
        except DbcError as e:
            raise RecorderError(str(e)) from None

    def _open_writer(self) -> LogWriter:
        out = self.config.output
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise RecorderError(f"{self.out_dir}: cannot create the output folder: {e}") from None
        if not os.access(self.out_dir, os.W_OK):
            raise RecorderError(f"{self.out_dir}: the output folder is not writable")
        writer = LogWriter(
            self.out_dir,
            prefix=out.prefix,
            split_bytes=int(out.split_megabytes * 1e6),
            split_s=out.split_minutes * 60.0,
            metadata=self._metadata(),
            profile="acq",
        )
        for s in self.config.scanners:
            writer.add_channel(f"/{s.name}/scan", schemas.SCHEMAS["foxglove.LaserScan"])
            writer.add_channel(f"/{s.name}/raw", schemas.SCHEMAS["acq.RawTelegram"])
            writer.add_channel(f"/acq/timing/{s.name}", schemas.SCHEMAS["acq.Timing"])
        for c in self.config.cameras:
            writer.add_channel(
                f"/{c.name}/image/compressed", schemas.SCHEMAS["foxglove.CompressedImage"]
            )
            writer.add_channel(f"/acq/timing/{c.name}", schemas.SCHEMAS["acq.Timing"])
        if self.config.can is not None:
            writer.add_channel(f"/{VEHICLE}/odometry", schemas.SCHEMAS["acq.Odometry"])
            writer.add_channel(f"/{VEHICLE}/can", schemas.SCHEMAS["acq.CanFrame"])
        if self.config.gnss is not None:
            writer.add_channel(f"/{GNSS}/fix", schemas.SCHEMAS["foxglove.LocationFix"])
            writer.add_channel(f"/{GNSS}/raw", schemas.SCHEMAS["acq.RawTelegram"])
            writer.add_channel(f"/acq/timing/{GNSS}", schemas.SCHEMAS["acq.Timing"])
        writer.add_channel("/acq/status", schemas.SCHEMAS["acq.Status"])
        writer.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
        now = time.monotonic_ns()
        calib = self.calibration
        if calib is not None:
            writer.add_channel("/tf_static", schemas.SCHEMAS["foxglove.FrameTransforms"])
            writer.set_latched("/tf_static", lambda t: schemas.frame_transforms(calib, t), now)
            for c in self.config.cameras:
                if c.name in calib.cameras:
                    topic = f"/{c.name}/calibration"
                    writer.add_channel(topic, schemas.SCHEMAS["foxglove.CameraCalibration"])
                    writer.set_latched(topic, functools.partial(
                        _camera_calibration, calib.cameras[c.name], c.name), now)  # fmt: skip
                else:
                    log.warning("camera %s has no entry in the calibration", c.name)
        return writer

    def _metadata(self) -> dict[str, dict[str, str]]:
        from acq import __version__
        from acq.record.config import dump

        meta = {
            "acq": {
                "version": __version__,
                "host": socket.gethostname(),
                "python": sys.version.split()[0],
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "clock": "log_time and timestamps are host CLOCK_MONOTONIC ns; "
                "/acq/clock maps them to UTC",
            },
            "config": {"yaml": dump(self.config)},
        }
        if self.calibration is not None:
            meta["calibration"] = {"yaml": calibfile.dump(self.calibration)}
        return meta

    # --- device threads ------------------------------------------------------------------

    def _event(self, state: DeviceState, kind: str, detail: str) -> None:
        state.last_event = f"{kind}: {detail}" if detail else kind
        if kind == "connected":
            state.connected = True
            log.info("%s connected: %s", state.name, detail)
        elif kind == "connect_failed":
            state.connected = False
            log.debug("%s: connect failed: %s", state.name, detail)
        elif kind in ("disconnected", "stalled", "device_error"):
            state.connected = False
            state.disconnects += 1
            log.warning("%s %s: %s", state.name, kind, detail)
        elif kind == "protocol_error":
            state.protocol_errors += 1
            log.warning("%s: bad telegram: %s", state.name, detail)
        elif kind == "clock_reset":
            log.warning("%s: %s", state.name, detail)

    def _bad_record(self, state: DeviceState, what: str, detail: str) -> None:
        """A record that does not decode, from a stream that goes on (a CAN bus, NMEA):
        counted; logged at the 1st, 2nd, 4th, 8th... so a wrong DBC does not flood."""
        state.protocol_errors += 1
        state.last_event = f"protocol_error: {detail}"
        n = state.protocol_errors
        if n & (n - 1) == 0:
            log.warning("%s: %s (%d so far): %s", state.name, what, n, detail)

    def _put(self, state: DeviceState, item: _Item) -> None:
        try:
            self.queue.put_nowait(item)
        except queue.Full:
            state.dropped += 1

    def _scanner_thread(self, cfg: ScannerConfig) -> None:
        from acq.drivers.reconnect import LinkEvent, Reconnecting
        from acq.drivers.scanner import scanner_for

        state = self.devices[cfg.name]
        options: dict[str, Any] = dict(cfg.options)
        if cfg.protocol is not None:
            options["protocol"] = cfg.protocol
        scanner = scanner_for(cfg.driver, cfg.url, name=cfg.name, **options)
        cls = type(scanner)
        clock = DeviceClock(cls.tick_hz, cls.tick_bits)
        state.clock = clock
        tm_samples: tuple[tuple[int, int, int], ...] = ()
        if cfg.latency_s == "auto":
            tm_samples = self._measure_latency(scanner, state)
        else:
            state.latency_s = float(cfg.latency_s)

        def on_event(e: LinkEvent) -> None:
            self._event(state, e.kind, e.detail)

        link = Reconnecting(scanner, on_event=on_event)
        described: object = None
        for scan in link.scans(self._stop):
            if scanner.geometry is not described:  # (re)connected: describe the device
                described = scanner.geometry
                self.queue.put(
                    _MetaItem(f"device.{cfg.name}", device_metadata(cfg.driver, scanner))
                )
            state.received += 1
            state.last_recv_ns = scan.recv_ns
            if scan.device_ticks:
                state.last_tick = scan.device_ticks[0]
            state.times.append(scan.recv_ns)
            if not scan.device_ticks:
                stamp = scan.recv_ns - round(state.latency_s * 1e9)
                self._put(state, _ScanItem(cfg.name, scan, stamp, 0, 0))
                continue
            clock.update(scan.device_ticks[0], scan.recv_ns)
            if tm_samples and clock.updates in (1, 40, 400):  # at once, then refined
                self._apply_latency_bounds(state, tm_samples, clock)
            geometry = scanner.geometry
            offset = geometry.stamp_offset_s if geometry is not None else 0.0
            stamp = scan_start_ns(clock.to_host_ns(scan.device_ticks[0]), offset, state.latency_s)
            unwrapped = clock.unwrapper.nearest(scan.device_ticks[0])
            self._put(state, _ScanItem(cfg.name, scan, stamp, unwrapped, clock.epoch))

    def _measure_latency(
        self, scanner: Any, state: DeviceState
    ) -> tuple[tuple[int, int, int], ...]:
        """SCIP TM round trips before streaming; () if the device cannot be reached yet."""
        from acq.drivers.errors import DriverError

        try:
            scanner.connect()
            est = scanner.measure_latency(20)
        except (DriverError, OSError) as e:
            log.warning("%s: latency_s auto: no time queries (%s); using 0 until then",
                        state.name, e)  # fmt: skip
            return ()
        finally:
            try:
                scanner.close()
            except (DriverError, OSError):
                pass
        log.info("%s: 20 time queries, round trip %.2f-%.2f ms", state.name,
                 est.rtt_min * 1e3, est.rtt_max * 1e3)  # fmt: skip
        return tuple(est.samples)

    def _apply_latency_bounds(
        self, state: DeviceState, samples: tuple[tuple[int, int, int], ...], clock: DeviceClock
    ) -> None:
        try:
            lo, hi = latency_bounds(samples, clock)
        except ValueError as e:
            log.warning("%s: latency_s auto: %s", state.name, e)
            return
        state.latency_bounds_s = (lo, hi)
        state.latency_s = (lo + hi) / 2
        log.info("%s: latency from the stamp to receipt %.2f ms (bounds %.2f-%.2f ms)",
                 state.name, state.latency_s * 1e3, lo * 1e3, hi * 1e3)  # fmt: skip

    def _camera_thread(self, cfg: CameraConfig) -> None:
        from acq.drivers.camera import camera_for
        from acq.drivers.reconnect import CameraLink, LinkEvent

        state = self.devices[cfg.name]
        options: dict[str, Any] = dict(cfg.options)
        for key in ("width", "height", "fourcc"):
            value = getattr(cfg, key)
            if value is not None:
                options[key] = value
        camera = camera_for(
            cfg.driver, cfg.source, name=cfg.name, fps=cfg.fps, latency_s=cfg.latency_s, **options
        )

        def on_event(e: LinkEvent) -> None:
            self._event(state, e.kind, e.detail)

        link = CameraLink(camera, on_event=on_event)
        described: object = None
        for frame in link.frames(self._stop):
            if camera.format is not described:
                described = camera.format
                self.queue.put(_MetaItem(f"device.{cfg.name}", device_metadata(cfg.driver, camera)))
            state.received += 1
            state.last_recv_ns = frame.recv_ns
            state.times.append(frame.recv_ns)
            state.source_drops = camera.drops
            state.corrupt = camera.corrupt
            self._put(state, _FrameItem(cfg.name, frame))

    def _can_thread(self, cfg: CanConfig) -> None:
        """The vehicle's CAN bus: every frame to /vehicle/can, odometry decoded from the
        configured messages to /vehicle/odometry; a frame that does not decode is a
        protocol error (counted, logged), never the end of the thread."""
        from acq.drivers.can_odometry import CanDecodeError, CanOdometry
        from acq.drivers.reconnect import LinkEvent, Relink

        state = self.devices[VEHICLE]
        bus = CanOdometry(
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

        def on_event(e: LinkEvent) -> None:
            self._event(state, e.kind, e.detail)

        link = Relink(bus, bus.read_frame, on_event=on_event, reachable=bus.reachable)
        described: object = None
        bad_stamps = 0
        for frame in link.records(self._stop):
            if bus.info is not described:  # (re)connected
                described = bus.info
                self.queue.put(_MetaItem(f"device.{VEHICLE}", device_metadata("can", bus)))
            try:
                odometry = bus.decode(frame)
            except CanDecodeError as e:
                self._bad_record(state, "bad CAN frame", str(e))
                odometry = None
            if odometry is not None:
                state.received += 1
                state.last_recv_ns = frame.recv_ns
                state.times.append(frame.recv_ns)
            if bus.bad_stamps > bad_stamps:
                bad_stamps = bus.bad_stamps
                if bad_stamps & (bad_stamps - 1) == 0:  # 1, 2, 4, 8...: no flood
                    log.warning("%s: %d CAN frames without a usable interface stamp (none, "
                                "or the wall clock stepped): their receive time is used",
                                VEHICLE, bad_stamps)  # fmt: skip
            self._put(state, _CanItem(VEHICLE, frame, odometry))

    def _gnss_thread(self, cfg: GnssConfig) -> None:
        """The GNSS receiver: every sentence to /gnss/raw, each fix to /gnss/fix stamped
        with its fix time mapped to the host clock (see the module doc)."""
        from acq.drivers.nmea import NmeaError, NmeaReceiver
        from acq.drivers.reconnect import LinkEvent, Relink

        state = self.devices[GNSS]
        receiver = NmeaReceiver(cfg.url, baudrate=cfg.baudrate, name=GNSS)
        clock = DeviceClock(GNSS_TICK_HZ, 62, periodic=False)
        state.clock = clock
        state.latency_s = cfg.latency_s

        def on_event(e: LinkEvent) -> None:
            self._event(state, e.kind, e.detail)

        link = Relink(receiver, receiver.read_sentence, on_event=on_event)
        described: object = None
        for sentence in link.records(self._stop):
            if receiver.info is not described:
                described = receiver.info
                self.queue.put(_MetaItem(f"device.{GNSS}", device_metadata("nmea", receiver)))
            self._put(state, _SentenceItem(GNSS, sentence))
            try:
                fix = receiver.decode(sentence)
            except NmeaError as e:
                self._bad_record(state, "bad NMEA sentence", str(e))
                continue
            if fix is None:
                continue
            tick = round(fix.utc_s * GNSS_TICK_HZ)
            if fix.quality > 0:  # without a fix a receiver's time may be its RTC's guess
                epoch = clock.epoch
                clock.update(tick, fix.recv_ns)
                state.last_tick = tick
                if clock.epoch != epoch:
                    self._event(state, "clock_reset", "the receiver's UTC jumped: "
                                "its mapping to host time starts afresh")  # fmt: skip
            state.received += 1
            state.last_recv_ns = fix.recv_ns
            state.times.append(fix.recv_ns)
            mapped = clock.to_host_ns(tick) if clock.updates else fix.recv_ns
            stamp = mapped - round(state.latency_s * 1e9)
            self._put(state, _FixItem(GNSS, fix, stamp, tick))

    def _guard(self, target: Any, cfg: Any, name: str) -> None:
        """Run a device thread; an unexpected error stops the recorder (exit 1)."""
        try:
            target(cfg)
        except Exception:
            log.exception("%s: device thread failed", name)
            self.exit_code = EXIT_FAILURE
            self._stop.set()

    # --- the writer ----------------------------------------------------------------------

    def _write(self, writer: LogWriter, item: _Item) -> None:
        if isinstance(item, _MetaItem):
            writer.update_metadata(item.name, item.values)
            return
        if isinstance(item, _CanItem | _SentenceItem | _FixItem):
            self._write_vehicle(writer, item)
            return
        state = self.devices[item.device]
        name = item.device
        clock = state.clock
        if isinstance(item, _ScanItem):
            scan, stamp = item.scan, item.stamp_ns
            timing = schemas.timing(
                recv_ns=scan.recv_ns,
                device_ticks=scan.device_ticks,
                unwrapped_tick=item.unwrapped,
                epoch=item.epoch,
                stamp_ns=stamp,
                offset_ns=stamp - scan.recv_ns,
                drift_ppm=clock.drift_ppm if clock else 0.0,
                uncertainty_s=_finite(clock.uncertainty_s) if clock else 0.0,
                sequence=scan.sequence,
                received=state.received,
                dropped=state.dropped,
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
        else:
            frame = item.frame
            timing = schemas.timing(
                recv_ns=frame.recv_ns,
                stamp_ns=frame.stamp_ns,
                offset_ns=frame.stamp_ns - frame.recv_ns,
                sequence=frame.sequence,
                received=state.received,
                dropped=state.dropped + state.source_drops,
            )
            image = schemas.compressed_image(frame, name)
            writer.write_group([
                (f"/{name}/image/compressed", image, frame.recv_ns, frame.stamp_ns),
                (f"/acq/timing/{name}", timing, frame.recv_ns, frame.stamp_ns),
            ])  # fmt: skip

    def _write_vehicle(self, writer: LogWriter, item: _CanItem | _SentenceItem | _FixItem) -> None:
        name = item.device
        if isinstance(item, _CanItem):
            frame = item.frame
            group = [(f"/{name}/can", schemas.can_frame(frame), frame.recv_ns, frame.stamp_ns)]
            if item.odometry is not None:
                odo = item.odometry
                group.append(
                    (f"/{name}/odometry", schemas.odometry(odo), odo.recv_ns, odo.stamp_ns)
                )
            writer.write_group(group)
        elif isinstance(item, _SentenceItem):
            sentence = item.sentence
            raw = schemas.raw_telegram(device=name, data=sentence.data, recv_ns=sentence.recv_ns)
            writer.write(f"/{name}/raw", raw, sentence.recv_ns, sentence.recv_ns)
        else:
            fix, stamp = item.fix, item.stamp_ns
            state = self.devices[name]
            clock = state.clock
            timing = schemas.timing(
                recv_ns=fix.recv_ns,
                device_ticks=(item.tick,),
                unwrapped_tick=item.tick,
                epoch=clock.epoch if clock else 0,
                stamp_ns=stamp,
                offset_ns=stamp - fix.recv_ns,
                drift_ppm=clock.drift_ppm if clock else 0.0,
                uncertainty_s=_finite(clock.uncertainty_s) if clock else 0.0,
                received=state.received,
                dropped=state.dropped,
            )
            writer.write_group([
                (f"/{name}/fix", schemas.location_fix(fix, stamp, name), fix.recv_ns, stamp),
                (f"/acq/timing/{name}", timing, fix.recv_ns, stamp),
            ])  # fmt: skip

    def _write_rate(self) -> float:
        """Bytes per second written over the last half minute (0 until known)."""
        if len(self._bytes_hist) < 2:
            return 0.0
        (t0, b0), (t1, b1) = self._bytes_hist[0], self._bytes_hist[-1]
        return max(b1 - b0, 0) / max((t1 - t0) * 1e-9, 1e-3)

    def _disk(self, writer: LogWriter, now_ns: int) -> tuple[int, float]:
        """(free bytes, minutes left above the reserve at the recent write rate)."""
        free = shutil.disk_usage(self.out_dir).free
        self._bytes_hist.append((now_ns, writer.bytes_written))
        reserve = self.config.output.reserve_megabytes * 1e6
        rate = self._write_rate()
        minutes = max(free - reserve, 0.0) / rate / 60.0 if rate > 0 else math.inf
        return free, minutes

    def _clock_metadata(self) -> dict[str, str]:
        """Per device: clock offset (host minus device ns), drift, epoch, latency; and a
        realtime/monotonic pair."""
        out = {"realtime_ns": str(time.time_ns()), "monotonic_ns": str(time.monotonic_ns())}
        for d in self.devices.values():
            if d.clock is None:
                continue
            out[f"{d.name}.offset_ns"] = str(d.clock_offset_ns())
            out[f"{d.name}.drift_ppm"] = f"{d.clock.drift_ppm:.3f}"
            out[f"{d.name}.epoch"] = str(d.clock.epoch)
            out[f"{d.name}.latency_s"] = f"{d.latency_s:.6f}"
            if d.latency_bounds_s is not None:
                out[f"{d.name}.latency_bounds_s"] = "{:.6f} {:.6f}".format(*d.latency_bounds_s)
        return out

    def _status(self, writer: LogWriter, now_ns: int, free: int, minutes: float) -> None:
        devices = []
        for d in self.devices.values():
            clock = d.clock
            # seconds since its last record (a record may land while this runs: >= 0)
            since = d.last_recv_ns if d.last_recv_ns else self.started_ns
            gap = max(now_ns - since, 0) * 1e-9
            devices.append(
                schemas.DeviceStatus(
                    name=d.name,
                    kind=d.kind,
                    connected=d.connected,
                    rate_hz=d.rate_hz(now_ns),
                    received=d.received,
                    dropped=d.dropped + d.source_drops,
                    corrupt=d.corrupt,
                    disconnects=d.disconnects,
                    protocol_errors=d.protocol_errors,
                    gap_s=gap,
                    last_event=d.last_event,
                    clock_offset_ns=d.clock_offset_ns(),
                    clock_drift_ppm=clock.drift_ppm if clock else 0.0,
                    clock_uncertainty_s=_finite(clock.uncertainty_s) if clock else 0.0,
                    epoch=clock.epoch if clock else 0,
                )
            )
        path = writer.path
        data = schemas.status(
            timestamp_ns=now_ns,
            uptime_s=(now_ns - self.started_ns) * 1e-9,
            file=path.name if path else "",
            disk_free_bytes=free,
            disk_minutes_left=_finite(minutes, 1e9),
            writer_queue=self.queue.qsize(),
            devices=devices,
        )
        writer.write("/acq/status", data, now_ns, now_ns)
        writer.write(
            "/acq/clock",
            schemas.clock(realtime_ns=time.time_ns(), monotonic_ns=time.monotonic_ns()),
            now_ns,
            now_ns,
        )
        summary = ", ".join(
            f"{d.name} {d.rate_hz(now_ns):.1f} Hz" + ("" if d.connected else " (down)")
            for d in self.devices.values()
        )
        drops = sum(d.dropped + d.source_drops for d in self.devices.values())
        disk = "" if math.isinf(minutes) else f", disk {minutes:.0f} min"
        self.notifier.status(f"{summary}; drops {drops}{disk}")

    def _writer_loop(self, writer: LogWriter) -> None:
        reserve = self.config.output.reserve_megabytes * 1e6
        next_status = time.monotonic_ns()
        next_clock_meta = next_status + 2_000_000_000  # once the clocks have some data
        deadline = (
            self.started_ns + round(self.duration_s * 1e9) if self.duration_s is not None else None
        )
        drain_until: int | None = None
        while True:
            now = time.monotonic_ns()
            if deadline is not None and now >= deadline:
                self._stop.set()
            if self._stop.is_set() and drain_until is None:
                drain_until = now + round(DRAIN_S * 1e9)
            try:
                item = self.queue.get(timeout=0.05)
            except queue.Empty:
                item = None
                if drain_until is not None:
                    return  # stopping, and everything queued is written
            if item is not None:
                self._write(writer, item)
            now = time.monotonic_ns()
            if drain_until is not None and now >= drain_until:
                left = self.queue.qsize()
                if left:
                    log.warning("stopping: %d queued records not written", left)
                return
            if now >= next_status:
                next_status = now + round(STATUS_PERIOD_S * 1e9)
                writer.sync()
                free, minutes = self._disk(writer, now)
                self._status(writer, now, free, minutes)
                if now >= next_clock_meta:
                    next_clock_meta = now + 60_000_000_000
                    writer.update_metadata("clock", self._clock_metadata())
                self.notifier.watchdog()
                # stop while the next seconds of data still fit above the reserve
                if free - 2 * self._write_rate() < reserve:
                    log.error(
                        "%s: %.1f MB free, at the reserve of %.1f MB: closing the file "
                        "and stopping", self.out_dir, free / 1e6, reserve / 1e6,
                    )  # fmt: skip
                    self.exit_code = EXIT_DISK_FULL
                    self._stop.set()
                    return
            else:
                writer.maybe_sync(now)

    # --- running -------------------------------------------------------------------------

    def stop(self) -> None:
        """Ask the recorder to finish (safe from a signal handler)."""
        self._stop.set()

    def run(self) -> int:
        """Record until stopped; returns the exit code."""
        sys.setswitchinterval(0.001)  # readers stamp receipt: do not let them wait 5 ms
        writer = self._open_writer()
        self.writer = writer
        self.started_ns = time.monotonic_ns()
        for cfg in self.config.scanners:
            self._start(self._scanner_thread, cfg, cfg.name)
        for ccfg in self.config.cameras:
            self._start(self._camera_thread, ccfg, ccfg.name)
        if self.config.can is not None:
            self._start(self._can_thread, self.config.can, VEHICLE)
        if self.config.gnss is not None:
            self._start(self._gnss_thread, self.config.gnss, GNSS)
        log.info("recording %s to %s", ", ".join(self.devices), self.out_dir)
        self.notifier.ready(f"recording {', '.join(self.devices)}")
        try:
            self._writer_loop(writer)
        except OSError as e:
            if e.errno in (28, 122):  # ENOSPC, EDQUOT
                log.error("%s: the disk is full: %s; closing the file", self.out_dir, e)
                self.exit_code = EXIT_DISK_FULL
            else:
                log.error("%s: cannot write the log: %s", self.out_dir, e)
                self.exit_code = EXIT_FAILURE
        except Exception:
            log.exception("the writer failed")
            self.exit_code = EXIT_FAILURE
        finally:
            self._stop.set()
            self.notifier.stopping()
            self._close(writer)
            for t in self._threads:
                t.join(timeout=1.0)
        return self.exit_code

    def _start(self, target: Any, cfg: Any, name: str) -> None:
        t = threading.Thread(target=self._guard, args=(target, cfg, name), name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def _close(self, writer: LogWriter) -> None:
        path = writer.path
        try:
            report = writer.close()
        except OSError as e:
            log.error("%s: the last file could not be finished (%s): it is readable up to "
                      "its last second; `acq info --repair` indexes it", path, e)  # fmt: skip
            if self.exit_code == EXIT_OK:
                self.exit_code = EXIT_FAILURE
        else:
            if report:
                log.error("%s: %s", path, report)
        for path in writer.files:
            log.info("wrote %s", path)


def _camera_calibration(cam: calibfile.CameraCalib, name: str, stamp_ns: int) -> bytes:
    return schemas.camera_calibration(cam, name, stamp_ns)


def _finite(x: float, cap: float = 1e9) -> float:
    return x if math.isfinite(x) else cap


def setup_logging(verbose: bool = False) -> None:
    """Log lines for the journal (priority prefixes, no time) or for a terminal."""
    from acq.record.sdnotify import JournalFormatter, use_journal_format

    handler = logging.StreamHandler(sys.stderr)
    if use_journal_format():
        handler.setFormatter(JournalFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(logging.DEBUG if verbose else logging.INFO)


def record(
    config: Config,
    *,
    out_dir: Path | None = None,
    duration_s: float | None = None,
    notifier: Notifier | None = None,
) -> int:
    """Run a :class:`Recorder` with SIGTERM and SIGINT finishing the file; the exit code."""
    import signal

    recorder = Recorder(config, out_dir=out_dir, duration_s=duration_s, notifier=notifier)

    def finish(signum: int, _frame: object) -> None:
        log.info("%s: finishing the file", signal.Signals(signum).name)
        recorder.stop()

    old = {s: signal.signal(s, finish) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        return recorder.run()
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
