"""`acq record`: every device of a configuration into rolling MCAP files.

One thread per device (scanners, cameras, the vehicle's CAN bus, the GNSS receiver),
each running the one device loop of :mod:`acq.record.device_loop` with its kind's
adapter (:mod:`acq.record.adapters`), reads records through its driver (reconnecting
with backoff), applies the device clock, and hands them to one writer thread through a
bounded queue: a slow disk drops records (counted per device), it never blocks a reader.
The writer encodes (Foxglove protobuf schemas, the raw telegrams, the timing), writes,
ends and fsyncs the chunk every second, publishes ``/acq/status``, ``/acq/clock`` and
``/acq/timebase`` (``acq.TimeBase``: what the host knows about its clock, read off the
writer's thread by :class:`acq.time.host_clock.HostClockPoller`) at 1 Hz, pings the
systemd watchdog, and watches the disk: below the configured reserve it closes the file
and the recorder exits with :data:`EXIT_DISK_FULL`. The ``time_base`` metadata sums the
time base up (:class:`acq.time.host_clock_summary.HostClockTally`): whether the log's
UTC can be trusted, and why not.

Vehicle topics (with ``can:`` / ``gnss:`` in the configuration): ``/vehicle/odometry``
(``acq.Odometry``, stamped with the CAN receive stamp mapped to the monotonic clock, see
:mod:`acq.drivers.can_odometry`), ``/vehicle/can`` (``acq.CanFrame``: every frame of the bus,
to re-decode with another DBC), ``/gnss/fix`` (``foxglove.LocationFix``), ``/gnss/raw``
(``acq.RawTelegram``: each NMEA sentence) and ``/acq/timing/gnss``. A fix is stamped
with its fix instant (``gnss.time``): from its UTC fix time through the host's UTC clock
while the kernel calls that clock synchronised, else as a device clock like a scanner's,
mapped to host time by the one-way estimator (:class:`acq.time.clocksync.DeviceClock`) less
the configured ``latency_s``, so neither the host's wall clock nor its NTP steps enter.

A device's failure is its own (:func:`acq.record.device_loop.run_device`): it is closed,
reported and opened again after a backoff while the others record on; a device with no
record for a few seconds is a warning, repeated with backoff. A *required* device
(``required: true`` in the configuration, or named in ``required``) that has delivered
no record :data:`REQUIRED_WITHIN_S` after the start (or by the end of a shorter
duration) stops the recorder: the file is closed, one error line names the device and
why, and the exit code is 1. Once it has recorded, a required device that goes away is
reconnected like any other. The credentials of device URLs are redacted in the log
lines (:func:`setup_logging`), the metadata and the status.

When it stops, the recorder says what each device recorded, names each that recorded
nothing or stopped recording well before the end (:mod:`acq.log.silent_devices`), and
exits 1 when a device recorded nothing, unless the configuration marks it optional
(``required: false``: then a warning).

Every signal that would end the process finishes the file first (SIGTERM, SIGINT, and
SIGHUP too: a dropped ssh link ends the recording with its file whole rather than leave
it unattended), but SIGKILL, the faults and the watchdog's SIGABRT
(:mod:`acq.stop_signals` says why).

Exit codes: 0 stopped (signal or ``--duration``), 1 runtime failure (a required device
absent, a device that recorded nothing), 2 bad configuration, 3 disk below its reserve
(listed in the unit's ``RestartPreventExitStatus``).
"""

from __future__ import annotations

import functools
import logging
import math
import os
import shutil
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from acq import __version__
from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.credentials import RedactingFilter, redact
from acq.drivers.can_odometry import DbcError, OdometryDecoder
from acq.drivers.reconnect import describe
from acq.errors import InputError, InputValueError
from acq.log import schemas
from acq.log.silent_devices import DeviceRecords, silent_devices
from acq.log.writer import LogWriter
from acq.record.adapters import GNSS, adapters_for
from acq.record.config import CanConfig, Config, dump, optional_devices, required_devices
from acq.record.device_loop import DeviceState, Outbox, Queued, finite, run_device
from acq.record.listeners import Listener, Listeners, LogRecord
from acq.record.sdnotify import JournalFormatter, Notifier, use_journal_format
from acq.stop_signals import finishing
from acq.time.absent import Absent
from acq.time.host_clock import NO_GNSS, GnssTime, HostClockPoller, gnss_time
from acq.time.host_clock_summary import HostClockTally

if TYPE_CHECKING:
    from acq.record.live_colour import ColourSettings

__all__ = [
    "EXIT_DISK_FULL",
    "REQUIRED_WITHIN_S",
    "Recorder",
    "RecorderError",
    "UnknownDevice",
]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_DISK_FULL = 3

log = logging.getLogger("acq.record")

QUEUE_SIZE = 512  # records; at 25 frames/s of ~60 kB that is 20 s of a stalled disk
STATUS_PERIOD_S = 1.0
DRAIN_S = 1.0  # on stop: the time left to write what is queued before the file closes
REQUIRED_WITHIN_S = 10.0  # a required device's first record must come within this, s


class RecorderError(InputError, RuntimeError):
    """The recorder cannot start (a calibration that cannot be read, an output folder
    that cannot be written)."""


class UnknownDevice(InputValueError):
    """A device asked for by name (``required``) that the configuration does not have."""


class Recorder:
    """Records ``config``'s devices until :meth:`stop` (or ``duration_s``).

    ``out_dir`` overrides ``config.output.dir``; ``calibration`` overrides the file the
    config names; ``required`` names devices that must deliver a record within
    ``required_within_s`` of the start (besides those the configuration marks
    ``required``; :class:`UnknownDevice` for a name it does not have). ``listeners``
    get every record written, each through its own bounded queue and thread
    (:mod:`acq.record.listeners`; :attr:`listeners` takes more). :meth:`run` returns the
    exit code.
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
        required: Iterable[str] = (),
        required_within_s: float = REQUIRED_WITHIN_S,
        listeners: Iterable[Listener] = (),
    ) -> None:
        self.config = config
        self.listeners = Listeners(listeners)
        self.out_dir = Path(out_dir if out_dir is not None else config.output.dir)
        self.duration_s = duration_s
        self.notifier = notifier if notifier is not None else Notifier()
        self.calibration = calibration if calibration is not None else self._load_calibration()
        self.outbox = Outbox(queue_size)
        if config.can is not None:
            self._check_dbc(config.can)
        self.adapters = adapters_for(config, self.calibration)
        self.devices: dict[str, DeviceState] = {a.name: a.state for a in self.adapters}
        self.required = list(dict.fromkeys([*required_devices(config), *required]))
        for name in self.required:
            if name not in self.devices:
                raise UnknownDevice(
                    f"no device named {name!r}; the configuration's devices: "
                    + ", ".join(self.devices)
                )
        self.required_within_s = required_within_s
        self.optional = [n for n in optional_devices(config) if n not in self.required]
        self._said_missing: set[str] = set()  # required devices an error line named
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.writer: LogWriter | None = None
        self.exit_code = EXIT_OK
        self.started_ns = 0
        self._bytes_hist: deque[tuple[int, int]] = deque(maxlen=30)  # (mono ns, bytes)
        self.host_clock = HostClockPoller()
        self.host_clock_tally = HostClockTally()

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
            tap=lambda *message: self.listeners.publish(LogRecord(*message)),
        )
        for adapter in self.adapters:
            for topic, schema in adapter.channels():
                writer.add_channel(topic, schemas.SCHEMAS[schema])
        writer.add_channel("/acq/status", schemas.SCHEMAS["acq.Status"])
        writer.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
        writer.add_channel("/acq/timebase", schemas.SCHEMAS["acq.TimeBase"])
        now = time.monotonic_ns()
        calib = self.calibration
        if calib is not None:
            writer.add_channel("/tf_static", schemas.SCHEMAS["foxglove.FrameTransforms"])
            writer.set_latched("/tf_static", lambda t: schemas.frame_transforms(calib, t), now)
            for c in self.config.cameras:
                if c.name in calib.cameras:
                    topic = f"/{c.name}/calibration"
                    writer.add_channel(topic, schemas.SCHEMAS["foxglove.CameraCalibration"])
                    calibration = functools.partial(
                        schemas.camera_calibration, calib.cameras[c.name], c.name
                    )
                    writer.set_latched(topic, calibration, now)
                else:
                    log.warning("camera %s has no entry in the calibration", c.name)
        return writer

    def _metadata(self) -> dict[str, dict[str, str]]:

        meta = {
            "acq": {
                "version": __version__,
                "host": socket.gethostname(),
                "python": sys.version.split()[0],
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            },
            "config": {"yaml": redact(dump(self.config))},
        }
        if self.calibration is not None:
            meta["calibration"] = {"yaml": calibfile.dump(self.calibration)}
        return meta

    # --- the device threads and the writer ---------------------------------------------

    def _write(self, writer: LogWriter, item: Queued) -> None:
        """Encode and write one record; one that cannot be encoded (a device's bytes that
        an encoder cannot take: a bug) is counted as that device's bad record, not the
        end of the recording. A write that fails (OSError: the disk) goes up."""
        try:
            item.adapter.write(writer, item.payload)
        except OSError:
            raise
        except Exception as e:
            state = item.adapter.state
            state.bad_record("record not written", describe(e))
            log.debug("%s: the failure's traceback (a bug to report)", state.name, exc_info=e)

    def _check_required(self, now_ns: int) -> bool:
        """False (after one error line) when a required device has no record yet."""
        missing = [self.devices[n] for n in self.required if not self.devices[n].received]
        if not missing:
            return True
        waited = (now_ns - self.started_ns) * 1e-9
        log.error(
            "required %s without a record %.0f s after the start: %s; closing the file",
            "device" if len(missing) == 1 else "devices",
            waited,
            "; ".join(f"{d.name} {d.why_silent()}" for d in missing),
        )
        self._said_missing = {d.name for d in missing}
        return False

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
        """Per device: clock offset (host minus device ns), drift, epoch, latency (and how
        it was obtained), tick rate (Hz); and a realtime/monotonic pair."""
        out = {"realtime_ns": str(time.time_ns()), "monotonic_ns": str(time.monotonic_ns())}
        for d in self.devices.values():
            if d.clock is None:
                continue
            out[f"{d.name}.offset_ns"] = str(d.clock_offset_ns())
            out[f"{d.name}.drift_ppm"] = f"{d.clock.drift_ppm:.3f}"
            out[f"{d.name}.epoch"] = str(d.clock.epoch)
            out[f"{d.name}.tick_hz"] = f"{d.clock.tick_hz:g}"
            out[f"{d.name}.latency_s"] = f"{d.latency_s:.6f}"
            out[f"{d.name}.latency_source"] = d.latency_source
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
                    odd_size=d.odd_size,
                    fast_s=d.fast_s,
                    disconnects=d.disconnects,
                    protocol_errors=d.protocol_errors,
                    gap_s=gap,
                    last_event=d.last_event,
                    clock_offset_ns=d.clock_offset_ns(),
                    clock_drift_ppm=clock.drift_ppm if clock else 0.0,
                    clock_uncertainty_s=finite(clock.uncertainty_s) if clock else 0.0,
                    epoch=clock.epoch if clock else 0,
                    required=d.name in self.required,
                )
            )
        path = writer.path
        data = schemas.status(
            timestamp_ns=now_ns,
            uptime_s=(now_ns - self.started_ns) * 1e-9,
            file=path.name if path else "",
            disk_free_bytes=free,
            disk_minutes_left=finite(minutes, 1e9),
            writer_queue=self.outbox.qsize(),
            devices=devices,
            colouring=self.listeners.colouring(),
        )
        writer.write("/acq/status", data, now_ns, now_ns)
        pair = schemas.clock(realtime_ns=time.time_ns(), monotonic_ns=time.monotonic_ns())
        writer.write("/acq/clock", pair, now_ns, now_ns)
        self._time_base(writer, now_ns)
        summary = ", ".join(
            f"{d.name} {d.rate_hz(now_ns):.1f} Hz" + ("" if d.connected else " (down)")
            for d in self.devices.values()
        )
        drops = sum(d.dropped + d.source_drops for d in self.devices.values())
        disk = "" if math.isinf(minutes) else f", disk {minutes:.0f} min"
        self.notifier.status(f"{summary}; drops {drops}{disk}")

    def _gnss_time(self, now_ns: int) -> GnssTime | Absent:
        """The GNSS receiver's time against the host clock at its last fix."""
        state = self.devices.get(GNSS)
        if state is None:
            return NO_GNSS
        if state.clock is None or not state.clock.updates or not state.offset_ns:
            return Absent("no fix yet")
        wall_minus_mono = time.time_ns() - time.monotonic_ns()
        age = max(now_ns - state.last_recv_ns, 0) * 1e-9
        return gnss_time(state.offset_ns, state.latency_s, age, wall_minus_mono)

    def _time_base(self, writer: LogWriter, now_ns: int) -> None:
        """The host clock's newest reading, when there is one, to ``/acq/timebase``."""
        reading = self.host_clock.take(self._gnss_time(now_ns))
        if reading is not None:
            self.host_clock_tally.add(reading)
            writer.write("/acq/timebase", schemas.time_base_record(reading), now_ns, now_ns)

    def _writer_loop(self, writer: LogWriter) -> None:
        reserve = self.config.output.reserve_megabytes * 1e6
        next_status = time.monotonic_ns()
        next_clock_meta = next_status + 2_000_000_000  # once the clocks have some data
        deadline = (
            self.started_ns + round(self.duration_s * 1e9) if self.duration_s is not None else None
        )
        # the required devices are checked once: at the timeout, or at a shorter duration's end
        within_ns = round(self.required_within_s * 1e9)
        if deadline is not None:
            within_ns = min(within_ns, deadline - self.started_ns)
        check_required = self.started_ns + within_ns if self.required else None
        drain_until: int | None = None
        while True:
            now = time.monotonic_ns()
            if check_required is not None and now >= check_required and drain_until is None:
                check_required = None
                if not self._check_required(now):
                    self.exit_code = EXIT_FAILURE
                    self._stop.set()
            if deadline is not None and now >= deadline:
                self._stop.set()
            if self._stop.is_set() and drain_until is None:
                drain_until = now + round(DRAIN_S * 1e9)
            item = self.outbox.get(timeout=0.05)
            for name, values in self.outbox.descriptions().items():
                writer.update_metadata(name, values)  # before the device's records
            if item is not None:
                self._write(writer, item)
            elif drain_until is not None:
                return  # stopping, and everything queued is written
            now = time.monotonic_ns()
            if drain_until is not None and now >= drain_until:
                left = self.outbox.qsize()
                if left:
                    log.warning("stopping: %d queued records not written", left)
                return
            if drain_until is None:
                for state in self.devices.values():
                    state.watch(now, self.started_ns)
                    state.watch_rate(now)
            if now >= next_status:
                next_status = now + round(STATUS_PERIOD_S * 1e9)
                writer.sync()
                free, minutes = self._disk(writer, now)
                self._status(writer, now, free, minutes)
                if now >= next_clock_meta:
                    next_clock_meta = now + 60_000_000_000
                    writer.update_metadata("clock", self._clock_metadata())
                    writer.update_metadata("time_base", self.host_clock_tally.metadata())
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
        self.host_clock.start()
        for adapter in self.adapters:
            t = threading.Thread(target=run_device, args=(adapter, self.outbox, self._stop),
                                 name=adapter.name, daemon=True)  # fmt: skip
            t.start()
            self._threads.append(t)
        log.info("recording %s to %s", ", ".join(self.devices), self.out_dir)
        if self.required:
            log.info("required: %s (each must record within %.0f s)", ", ".join(self.required),
                     min(self.required_within_s, self.duration_s or math.inf))  # fmt: skip
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
            ended_ns = time.monotonic_ns()
            self.host_clock.stop()
            self.notifier.stopping()
            self._close(writer)
            self.listeners.close()
            self._report_devices(ended_ns)
            for t in self._threads:
                t.join(timeout=1.0)
        return self.exit_code

    def _report_devices(self, end_ns: int) -> None:
        """The closing lines: what each device recorded; an error line for each that
        recorded nothing (exit status 1, unless it is optional: a warning) and a warning
        for each that stopped recording well before the end."""
        counts = ", ".join(f"{d.name} {d.received}" for d in self.devices.values())
        log.info("stopped after %.1f s; records: %s", (end_ns - self.started_ns) * 1e-9, counts)
        records = [
            DeviceRecords(d.name, d.kind, d.received, d.last_recv_ns or None, d.why_silent())
            for d in self.devices.values()
        ]
        for silent in silent_devices(records, end_ns):
            if silent.name in self._said_missing:
                continue
            if not silent.recorded_nothing:
                log.warning("%s", silent.line())
            elif silent.name in self.optional:
                log.warning("%s (optional: required: false)", silent.line())
            else:
                log.error("%s; exit status 1 (`required: false` makes a device optional)",
                          silent.line())  # fmt: skip
                if self.exit_code == EXIT_OK:
                    self.exit_code = EXIT_FAILURE

    def _close(self, writer: LogWriter) -> None:
        path = writer.path
        try:
            writer.update_metadata("clock", self._clock_metadata())  # the final estimates
            writer.update_metadata("time_base", self.host_clock_tally.metadata())
        except (OSError, ValueError):
            pass  # a writer an error stopped: close() below keeps what it has
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


def setup_logging(verbose: bool = False) -> None:
    """Log lines for the journal (priority prefixes, no time) or for a terminal, the
    credentials of any URL in them redacted."""

    handler = logging.StreamHandler(sys.stderr)
    handler.addFilter(RedactingFilter())
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
    required: Iterable[str] = (),
    listeners: Iterable[Listener] = (),
    calibration: Calibration | None = None,
    colouring: ColourSettings | None = None,
) -> int:
    """Run a :class:`Recorder` with every signal that would end the process finishing the
    file (SIGTERM, SIGINT, SIGHUP...: :mod:`acq.stop_signals`); the exit code.
    ``colouring``: colour the scans live (:mod:`acq.record.live_colour`)."""
    recorder = Recorder(
        config,
        out_dir=out_dir,
        duration_s=duration_s,
        notifier=notifier,
        required=required,
        listeners=listeners,
        calibration=calibration,
    )
    if colouring is not None:
        from acq.record.live_colour import attach

        attach(recorder, colouring)
    with finishing(recorder.stop):
        return recorder.run()
