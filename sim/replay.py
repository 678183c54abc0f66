"""`acq replay`: serve a recorded session back through simulated devices on real transports.

Scanners are served from their raw telegrams (``/<scanner>/raw``: the bytes exactly as
received) by a SCIP or CoLa device on TCP (Hokuyo also on a pseudo-terminal), cameras from
their JPEG bytes (``/<camera>/image/compressed``) as MJPEG over HTTP, the vehicle's CAN
frames (``/vehicle/can``) on a python-can ``udp_multicast`` bus on this host and the GNSS
receiver's sentences (``/gnss/raw``) on TCP (:mod:`acq.sim.replay_vehicle`), each record
at its recorded receive time (MCAP ``log_time``) shifted to now and divided by ``speed``. A
recorder pointed at the replay (:meth:`Replay.config`) therefore records the same device
ticks, ranges and JPEG bytes; only the receive times are new (at speed 1 they keep the
recorded pace, within the host's scheduling jitter).

The devices share one clock, so they keep their recorded timing relative to each other.
It starts the first time a client asks any device for its time or its data (SCIP
``II``/``TM``/a scan command, CoLa ``LMDscandata``, an MJPEG stream request); from then
on the log plays like a live rig: a client that connects later, or reconnects, gets
what is due from then on. A client must ask for what was recorded: the same scan command,
steps and cluster (Hokuyo), the same CoLa encoding (SICK); anything else is refused, and
the reason is logged and kept in :attr:`Replay.errors`. When the log ends the devices go
silent (connections stay open, nothing is sent) until the replay is closed.

Only the records' receive times are held in memory; their bytes are read from the files
as they are due (:mod:`acq.sim.replay_records`), so memory does not grow with the drive.

:class:`ReplayError` (an InputError) for a missing or unreadable log, nothing to replay,
an unknown driver or a bad listen address, with one line naming the file; OSError for a
port in use. The command is :mod:`acq.cli.replay`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import yaml

from acq.drivers.scip_codec import parse_scan_echo
from acq.record import config as configfile
from acq.record.config import Config
from acq.sim.devices import parse_listen
from acq.sim.replay_devices import ColaReplayDevice, ReplayMjpegServer, ScipReplayDevice
from acq.sim.replay_session import (
    COLA,
    SCIP,
    DeviceLog,
    ReplayError,
    Session,
    load_session,
    scanner_wire,
)
from acq.sim.replay_stream import ReplayClock, ReplayStream
from acq.sim.replay_vehicle import NmeaReplayDevice, ReplayCanBus, vehicle_entries
from acq.sim.transport import PtyDeviceServer, TcpDeviceServer

__all__ = [
    "DeviceLog",
    "Replay",
    "ReplayError",
    "Session",
    "load_session",
]


log = logging.getLogger("acq.sim.replay")

DEFAULT_SCANNER_LISTEN = "tcp://127.0.0.1:0"
DEFAULT_CAMERA_LISTEN = "http://127.0.0.1:0/stream.mjpg"
LEAD_S = 0.05  # from the request that starts the clock to that device's first record, s
END_MARGIN_S = 0.1  # after the last record is due, s: it is on its way to the client


# --- serving --------------------------------------------------------------------------------


def _tcp_listen(listen: str) -> tuple[str, int]:

    return parse_listen(listen)


def _http_listen(listen: str) -> tuple[str, int, str]:
    parts = urlsplit(listen)
    try:
        port = parts.port if parts.port is not None else 80
    except ValueError:
        port = -1
    if parts.scheme != "http" or not parts.hostname or port < 0:
        raise ValueError(f"--camera-listen {listen!r}: expected http://HOST:PORT/PATH")
    return parts.hostname, port, parts.path or "/"


class Replay:
    """Serves a recorded session (see the module doc); :meth:`start` opens the servers.

    ``scanner_listen``: ``tcp://HOST:PORT`` for the first scanner, the next ones on the
    following ports (port 0: free ports); ``pty``: Hokuyo scanners on pseudo-terminals
    instead (SICK scanners stay on TCP). ``camera_listen``: ``http://HOST:PORT/PATH``
    likewise. ``speed``: 2 plays twice as fast. ``urls`` maps each device's name to what
    a client opens (a pyserial URL or pty path, ``tcp://``, ``http://``).
    """

    def __init__(
        self,
        logs: Sequence[str | Path],
        *,
        speed: float = 1.0,
        scanner_listen: str | None = None,
        pty: bool = False,
        camera_listen: str | None = None,
        lead_s: float = LEAD_S,
    ) -> None:
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive number, got {speed}")
        self.session = load_session(logs)
        self.speed = speed
        self.scanner_listen = scanner_listen or DEFAULT_SCANNER_LISTEN
        self.pty = pty
        self.camera_listen = camera_listen or DEFAULT_CAMERA_LISTEN
        self.lead_s = lead_s
        self.urls: dict[str, str] = {}
        self.errors: list[str] = []
        self._servers: list[Any] = []
        self._streams: dict[str, Any] = {}
        self._clock: ReplayClock | None = None
        self._can: ReplayCanBus | None = None
        self._closed = threading.Event()

    # --- life cycle -----------------------------------------------------------------------

    def start(self) -> Replay:
        """Open every device's server (ValueError: a bad listen address; OSError: a port
        that cannot be bound)."""
        if self._clock is not None:
            return self

        host, port = _tcp_listen(self.scanner_listen)
        chost, cport, cpath = _http_listen(self.camera_listen)
        self._clock = ReplayClock(self.speed, self.lead_s)
        try:
            for dev in self.session.devices.values():
                if dev.kind in ("scanner", "gnss"):
                    self._start_serial(dev, host, port)
                    port = port + 1 if port else 0
                elif dev.kind == "camera":
                    self._start_camera(dev, chost, cport, cpath)
                    cport = cport + 1 if cport else 0
                else:
                    self._can = ReplayCanBus(self._stream(dev)).start()
                    self._servers.append(self._can)
                    self.urls[dev.name] = self._can.url
        except BaseException:
            self.close()
            raise
        return self

    def _stream(self, dev: DeviceLog) -> Any:

        assert self._clock is not None
        stream = ReplayStream(dev.name, dev.records, self._clock)
        self._streams[dev.name] = stream
        return stream

    def _report(self, message: str) -> None:
        self.errors.append(message)
        log.error("%s", message)

    def _start_serial(self, dev: DeviceLog, host: str, port: int) -> None:
        """A scanner or the GNSS receiver (on TCP, a pyserial ``socket://`` URL)."""
        stream = self._stream(dev)
        meta = dev.metadata
        device: Any
        scip = dev.kind == "gnss" or scanner_wire(dev.driver) == SCIP
        if dev.kind == "gnss":
            device = NmeaReplayDevice(stream)
        elif scip:
            device = ScipReplayDevice(stream, meta["info"], meta["params"], self._report)
        else:
            device = ColaReplayDevice(stream, meta.get("info", {}), meta["geometry"], self._report)
        server: Any
        if self.pty and scip and dev.kind == "scanner":
            server = PtyDeviceServer(device)
            self._servers.append(server)
            self.urls[dev.name] = server.url
        else:
            server = TcpDeviceServer(device, host, port)
            self._servers.append(server)
            scheme = "socket" if scip else "tcp"
            self.urls[dev.name] = f"{scheme}://{server.host}:{server.port}"
        server.start()

    def _start_camera(self, dev: DeviceLog, host: str, port: int, path: str) -> None:

        server = ReplayMjpegServer(self._stream(dev), host, port, path)
        self._servers.append(server)
        self.urls[dev.name] = server.url
        server.start()

    def close(self) -> None:
        """Stop every server (clients see the link drop)."""
        self._closed.set()
        servers, self._servers = self._servers, []
        for server in servers:
            server.close()
        for stream in self._streams.values():
            with contextlib.suppress(ValueError):  # a server thread that did not stop
                stream.close()

    def __enter__(self) -> Replay:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- progress -------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        """True once a client has started the session's clock."""
        return self._clock is not None and self._clock.started

    def sent(self) -> dict[str, int]:
        """Records sent so far, per device."""
        return {name: s.sent for name, s in self._streams.items()}

    def served_s(self) -> float:
        """Seconds of the log served so far (log time, 0 before the clock starts)."""
        clock = self._clock
        if clock is None or not clock.started:
            return 0.0
        session = self.session
        served = (clock.log_ns_at(time.monotonic()) - session.start_ns) * 1e-9
        return min(max(served, 0.0), session.duration_s)

    def end_time(self) -> float | None:
        """When the last record is due (monotonic s); None before the clock starts."""
        if self._clock is None or not self._clock.started:
            return None
        return self._clock.at(self.session.end_ns)

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the log has been served to its end; False on timeout or close."""
        deadline = None if timeout is None else time.monotonic() + timeout
        clock = self._clock
        if clock is None:
            raise RuntimeError("start() first")
        while not clock.wait_started(0.1):
            if self._closed.is_set() or (deadline is not None and time.monotonic() >= deadline):
                return False
        end = clock.at(self.session.end_ns) + END_MARGIN_S
        while True:
            now = time.monotonic()
            left = end - now if deadline is None else min(end, deadline) - now
            if left <= 0:
                return now >= end
            if self._closed.wait(min(left, 0.5)):
                return False

    # --- the recorder's view --------------------------------------------------------------

    def config(self, *, out_dir: Path | None = None, calibration: Path | None = None) -> Config:
        """A recorder configuration for the replay: the recorded devices with their names,
        drivers, options and latencies, pointed at the replay's servers (cameras through the
        ``opencv`` driver, which reads MJPEG over HTTP byte for byte). ``out_dir``: the
        output folder (default ``replay-logs``); ``calibration``: the calibration file
        (default: the recorded one if that path exists here, else none)."""
        if not self.urls:
            raise RuntimeError("start() first")
        rec = self.session.config
        recorded: dict[str, Any] = (
            yaml.safe_load(configfile.dump(rec)) if rec is not None else {"version": 1}
        )
        entries = {
            e["name"]: e for e in [*recorded.get("scanners", []), *recorded.get("cameras", [])]
        }
        scanners: list[dict[str, Any]] = []
        cameras: list[dict[str, Any]] = []
        for dev in self.session.devices.values():
            entry = dict(entries.get(dev.name) or _derived_entry(dev))
            if dev.kind == "scanner":
                entry["driver"] = dev.driver
                entry["url"] = self.urls[dev.name]
                if scanner_wire(dev.driver) == COLA:
                    info = dev.metadata.get("info", {})
                    protocol = info.get("extra", {}).get("protocol")
                    entry["protocol"] = entry.get("protocol") or protocol or "cola-b"
                scanners.append(entry)
            elif dev.kind == "camera":
                if entry.get("driver") != "opencv":  # served as MJPEG over HTTP
                    entry = {k: v for k, v in entry.items() if k not in ("options", "fourcc")}
                    entry["driver"] = "opencv"
                entry["source"] = self.urls[dev.name]
                cameras.append(entry)
        data: dict[str, Any] = {"version": 1, "scanners": scanners, "cameras": cameras}
        data.update(vehicle_entries(recorded, self._can, self.urls.get("gnss")))
        calib = calibration
        if calib is None and rec is not None and rec.calibration is not None:
            calib = rec.calibration if rec.calibration.exists() else None
        if calib is not None:
            data["calibration"] = str(calib)
        output = dict(recorded.get("output", {}))
        output["dir"] = str(out_dir if out_dir is not None else "replay-logs")
        data["output"] = output
        return configfile.parse(data, "replay configuration")


def _derived_entry(dev: DeviceLog) -> dict[str, Any]:
    """A configuration entry for a device the recorded configuration does not list (or a
    log without one): for a Hokuyo, the options that ask for the recorded scans."""
    entry: dict[str, Any] = {"name": dev.name, "driver": dev.driver}
    if scanner_wire(dev.driver) != SCIP:
        return entry

    echo = parse_scan_echo(dev.records.head(1)[0].split(b"\n", 1)[0])
    p = dev.metadata["params"]
    options: dict[str, Any] = {}
    if echo.command in ("ME", "NE"):
        options["intensity"] = True
    if echo.command in ("ND", "NE"):
        options["multi_echo"] = True
    if echo.command == "MS":
        options["two_char"] = True
    if echo.cluster > 1:
        options["cluster"] = echo.cluster
    step = 2 * math.pi / int(p["ares"])
    if echo.start != int(p["amin"]):
        options["angle_min"] = (echo.start - int(p["afrt"])) * step
    if echo.end != int(p["amax"]):
        options["angle_max"] = (echo.end - int(p["afrt"])) * step
    if options:
        entry["options"] = options
    return entry
