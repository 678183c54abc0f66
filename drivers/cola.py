"""SICK LMS1xx / LMS5xx / TiM7xx over TCP with CoLa-B (default) or CoLa-A.

``ColaScanner("tcp://192.168.0.1:2112", protocol="cola-b")``: ``connect()`` logs in
(``SetAccessMode``), reads the identity (``DeviceIdent``, ``FirmwareVersion``,
``SerialNumber``, ``STlms`` or ``SCdevicestate``; each optional, as not every model knows
every one) and the geometry (``LMPoutputRange``, else one polled scan); ``start()`` sends
``LMCstartmeas``, ``Run`` and ``sEN LMDscandata 1``; ``read_scan()`` returns the next
streamed scan as an :class:`acq.records.Scan` in the REP-103 laser frame, with the two raw
32-bit µs device counters (time since start-up at scan start, time of transmission) in
``device_ticks`` and the scan counter in ``sequence``. The geometry is refined from the
first scan's own angles, which are exact where ``LMPoutputRange`` is rounded.
"""

from __future__ import annotations

import math
import socket
import time
from typing import Any

import numpy as np

from acq.drivers.cola_codec import (
    ArgReader,
    ColaFramer,
    Telegram,
    build,
    check_error,
    frame,
)
from acq.drivers.cola_scandata import ScanData, parse_scandata
from acq.drivers.errors import ProtocolError
from acq.drivers.scanner import ConnectionLost, DeviceError, ScanGeometry, Scanner, ScanTimeout
from acq.records import DeviceInfo, Scan

__all__ = ["DEFAULT_PORT", "ColaScanner", "parse_url"]

DEFAULT_PORT = 2112
ANSWER = {"sRN": "sRA", "sWN": "sWA", "sMN": "sAN", "sEN": "sEA"}
# Nominal range limits by product family (the telegrams do not carry them), metres.
RANGE_LIMITS = {
    "LMS1": (0.5, 20.0),
    "LMS5": (0.7, 80.0),
    "TIM7": (0.05, 25.0),
    "TIM5": (0.05, 10.0),
    "TIM2": (0.05, 10.0),
    "LMS4": (0.7, 3.0),
}
DEVICE_STATES = {
    0: "undefined",
    1: "initialisation",
    2: "configuration",
    3: "idle",
    4: "rotated",
    5: "in preparation",
    6: "ready",
    7: "ready for measurement",
}


def parse_url(url: str) -> tuple[str, int]:
    """``tcp://host:port``, ``socket://host:port``, ``host:port`` or ``host`` (port 2112)."""
    rest = url
    for scheme in ("tcp://", "socket://"):
        if rest.startswith(scheme):
            rest = rest[len(scheme) :]
            break
    else:
        if "://" in rest:
            raise ValueError(f"{url}: the SICK driver speaks tcp:// (or socket://) only")
    rest = rest.rstrip("/")
    host, sep, port = rest.rpartition(":")
    if not sep:
        return rest, DEFAULT_PORT
    try:
        return host.strip("[]"), int(port)
    except ValueError:
        raise ValueError(f"{url}: bad port {port!r}") from None


class ColaScanner(Scanner):
    """One SICK 2D scanner on TCP (CoLa-A or CoLa-B); blocking, one thread."""

    driver = "sick"
    tick_hz = 1e6  # SICK's time since start-up, µs
    tick_bits = 32
    wire = "CoLa"
    url_kind = "tcp"
    protocols = ("cola-b", "cola-a")
    # LMDscandata carries both the scan's time since start-up and its time of
    # transmission, µs (SICK telegram listing, "TimeSinceStartUp"/"TimeOfTransmission")
    latency_probe = "each scan's time of transmission"

    def __init__(
        self,
        url: str,
        *,
        name: str = "laser",
        timeout: float = 1.0,
        protocol: str = "cola-b",
        login: tuple[int, int] = (0x03, 0xF4724744),
        intensity: bool = True,
        stop_laser: bool = False,
        **_ignored: Any,
    ) -> None:
        """``login``: (access level, password hash) for SetAccessMode (3 = authorized
        client); ``intensity``: deliver RSSI1 when the device sends it; ``stop_laser``:
        ``stop()`` also sends LMCstopmeas (the laser goes to standby)."""
        super().__init__(url, name=name, timeout=timeout)
        proto = protocol.lower().replace("_", "-")
        if proto not in self.protocols:
            raise ValueError(f"protocol must be cola-b or cola-a, not {protocol!r}")
        self.protocol = proto
        self.binary = proto == "cola-b"
        self.login = login
        self.intensity = intensity
        self.stop_laser = stop_laser
        self.host, self.port = parse_url(url)
        self._sock: socket.socket | None = None
        self._framer = ColaFramer(mode="b" if self.binary else "a")
        # While waiting for an answer, also look for the other encoding: a device set to
        # the other protocol then gives a clear error instead of a timeout.
        self._probe: ColaFramer | None = None
        self._streaming = False
        self._geom_key: tuple[int, int, int, int, int] | None = None
        self.range_min = 0.0
        self.range_max = 0.0
        self.scans = 0
        self.protocol_errors = 0

    # --- transport --------------------------------------------------------------------

    def _open(self) -> socket.socket:
        if self._sock is not None:
            return self._sock
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as exc:
            raise ConnectionLost(f"{self.url}: cannot connect: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        self._framer.reset()
        return sock

    def _send(self, payload: bytes) -> None:
        sock = self._open()
        try:
            sock.sendall(frame(payload, self.binary))
        except OSError as exc:
            self._drop()
            raise ConnectionLost(f"{self.url}: send failed: {exc}") from exc

    def _drop(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None
                self._streaming = False

    def _next(self, deadline: float) -> Telegram:
        """The next telegram before ``deadline`` (monotonic s). Past it, what has already
        arrived is still read once before ScanTimeout: a host that held this thread up (a
        loaded machine) is not a device gone quiet."""
        late = False
        while True:
            try:
                tg = self._framer.pop()
            except ProtocolError:
                self.protocol_errors += 1
                raise
            if tg is not None:
                return tg
            sock = self._sock
            if sock is None:
                raise ConnectionLost(f"{self.url}: not connected")
            if late:
                raise ScanTimeout(f"{self.url}: nothing complete within {self.timeout:g} s")
            remaining = deadline - time.monotonic()
            late = remaining <= 0
            sock.settimeout(max(remaining, 0.0))  # 0: what has arrived, without waiting
            try:
                data = sock.recv(65536)
            except (TimeoutError, BlockingIOError):
                raise ScanTimeout(
                    f"{self.url}: nothing complete within {self.timeout:g} s"
                ) from None
            except OSError as exc:
                self._drop()
                raise ConnectionLost(f"{self.url}: {exc}") from exc
            if not data:
                self._drop()
                raise ConnectionLost(f"{self.url}: the device closed the connection")
            self._framer.feed(data, time.monotonic_ns())
            if self._probe is not None:
                self._probe.feed(data)
                if any(isinstance(t, Telegram) for t in self._probe.items()):
                    self.protocol_errors += 1
                    other = "cola-a" if self.binary else "cola-b"
                    raise ProtocolError(
                        f"{self.url}: device answers in {other.upper()}, driver set to "
                        f"{self.protocol}; set protocol: {other}"
                    )

    def request(self, kind: str, name: str, args: tuple[tuple[str, Any], ...] = ()) -> ArgReader:
        """Send one request, wait for its answer (streamed scans meanwhile are dropped);
        the answer's arguments. ``sFA`` raises DeviceError."""
        self._send(build(kind, name, args, binary=self.binary))
        want = ANSWER[kind]
        deadline = time.monotonic() + self.timeout
        self._probe = ColaFramer(mode="a" if self.binary else "b")
        try:
            while True:
                try:
                    tg = self._next(deadline)
                except ScanTimeout:
                    raise ScanTimeout(f"{self.url}: no answer to {kind} {name}") from None
                if tg.payload[:3] == b"sFA":
                    try:
                        check_error(tg)
                    except DeviceError as exc:
                        raise DeviceError(f"{kind} {name}: {exc}", exc.status) from None
                if tg.kind == want and tg.name == name:
                    return tg.reader()
                # sMA (method accepted, answer follows), sSN events, stale answers: skip
        finally:
            self._probe = None

    def _optional(self, kind: str, name: str) -> ArgReader | None:
        try:
            return self.request(kind, name)
        except DeviceError:
            return None

    # --- Scanner API ------------------------------------------------------------------

    def connect(self) -> DeviceInfo:
        self._open()
        self.set_access_mode()
        extra: dict[str, str] = {"protocol": self.protocol}
        model = version = firmware = serial = ""
        r = self._optional("sRN", "DeviceIdent")
        if r is not None:
            model, version = r.string().strip(), r.string().strip()
            extra["ident_version"] = version
        r = self._optional("sRN", "FirmwareVersion")
        if r is not None:
            firmware = r.string().strip()
        r = self._optional("sRN", "SerialNumber")
        if r is not None:
            serial = r.string().strip()
        r = self._optional("sRN", "STlms")
        if r is not None:
            state = r.u16()
            extra["device_state"] = DEVICE_STATES.get(state, str(state))
        else:
            r = self._optional("sRN", "SCdevicestate")
            if r is not None:
                extra["device_state"] = f"SCdevicestate {r.u8()}"  # meaning model-specific
        self.info = DeviceInfo(
            name=self.name,
            driver=self.driver,
            vendor="SICK",
            model=model,
            serial=serial,
            firmware=firmware or version,
            extra=extra,
        )
        family = model.upper().replace("_", "")[:4]
        self.range_min, self.range_max = RANGE_LIMITS.get(family, (0.0, 65.535))
        self.geometry = self._scan_config()
        if self.geometry is None or self.geometry.scan_period == 0:
            try:
                self._update_geometry(self._poll_scan())
            except DeviceError:
                if self.geometry is None:
                    raise
        return self.info

    def set_access_mode(self) -> None:
        level, password = self.login
        r = self.request("sMN", "SetAccessMode", (("u8", level), ("u32", password)))
        if not r.u8():
            raise DeviceError(f"{self.url}: SetAccessMode refused (wrong password?)", "0")

    def _scan_config(self) -> ScanGeometry | None:
        """Geometry from LMPscancfg (frequency) and LMPoutputRange (the output sector)."""
        frequency = 0
        geometry = None
        r = self._optional("sRN", "LMPscancfg")
        if r is not None:
            frequency = r.u32()
            geometry = self._sector(r, frequency)
        r = self._optional("sRN", "LMPoutputRange")
        if r is not None:
            geometry = self._sector(r, frequency) or geometry
        return geometry

    def _sector(self, r: ArgReader, frequency: int) -> ScanGeometry | None:
        """The first sector of an LMPscancfg / LMPoutputRange answer."""
        sectors = r.u16()
        if sectors < 1:
            return None
        res, start, stop = r.u32(), r.i32(), r.i32()
        if res <= 0 or stop < start:
            return None
        n = math.floor((stop - start) / res + 0.5) + 1
        return self._geometry(start, res, n, frequency)

    def _geometry(self, start: int, step: int, n: int, scan_frequency: int) -> ScanGeometry:
        old = self.geometry
        period = 100.0 / scan_frequency if scan_frequency > 0 else (old.scan_period if old else 0)
        inc = math.radians(step / 10000.0)
        return ScanGeometry(
            angle_min=math.radians(start / 10000.0 - 90.0),
            angle_increment=inc,
            n_points=n,
            scan_period=period,
            time_increment=period * inc / (2 * math.pi),
            range_min=self.range_min,
            range_max=self.range_max,
        )

    def _update_geometry(self, sd: ScanData) -> None:
        ch = sd.distance_channels()
        if not ch:
            return
        d = ch[0]
        key = (d.start_angle, d.step, int(d.data.size), sd.scan_frequency, sd.measurement_frequency)
        if key == self._geom_key:
            return
        self._geom_key = key
        g = self._geometry(d.start_angle, d.step, int(d.data.size), sd.scan_frequency)
        self.geometry = ScanGeometry(
            g.angle_min,
            g.angle_increment,
            g.n_points,
            g.scan_period,
            sd.time_increment,
            g.range_min,
            g.range_max,
            0.0,  # LMDscandata's time stamp is that of the first point
        )

    def _poll_scan(self) -> ScanData:
        r = self.request("sRN", "LMDscandata")
        return parse_scandata(b"sRA LMDscandata " + r.rest(), self.binary)

    def start(self) -> None:
        self.set_access_mode()
        r = self.request("sMN", "LMCstartmeas")
        if r.u8() != 0:
            raise DeviceError(f"{self.url}: LMCstartmeas refused", "LMCstartmeas")
        r = self.request("sMN", "Run")
        if r.u8() != 1:
            raise DeviceError(f"{self.url}: Run refused", "Run")
        self.request("sEN", "LMDscandata", (("u8", 1),))
        self._streaming = True

    def read_scan(self) -> Scan:
        if self._sock is None:
            raise ConnectionLost(f"{self.url}: not connected")
        deadline = time.monotonic() + self.timeout
        while True:
            tg = self._next(deadline)
            if tg.name != "LMDscandata" or tg.kind not in ("sSN", "sRA"):
                continue
            return self.to_scan(tg)

    def to_scan(self, tg: Telegram) -> Scan:
        """A received LMDscandata telegram -> Scan (updates ``geometry``)."""
        try:
            sd = parse_scandata(tg.payload, tg.binary)
            dist = sd.distance_channels()
            if not dist:
                raise ProtocolError("LMDscandata without a DIST channel")
            ranges = sd.ranges(dist[0].name)
            n = ranges.size
            intens = np.zeros(0, np.float32)
            if self.intensity:
                rssi = [c for c in sd.channels if c.name.startswith("RSSI")]
                if rssi and rssi[0].data.size == n:
                    intens = rssi[0].values()
            extra = None
            more = [sd.ranges(c.name) for c in dist[1:] if c.data.size == n]
            if more:
                extra = np.stack(more, axis=1)
        except ProtocolError as exc:
            self.protocol_errors += 1
            raise ProtocolError(f"{self.url}: {exc}") from None
        self._update_geometry(sd)
        self.scans += 1
        return Scan(
            ranges=ranges,
            intensities=intens,
            angle_min=sd.angle_min,
            angle_increment=sd.angle_increment,
            time_increment=sd.time_increment,
            scan_period=sd.scan_period,
            recv_ns=tg.stamp_ns or time.monotonic_ns(),
            device_ticks=(sd.time_since_startup, sd.time_of_transmission),
            sequence=sd.scan_counter,
            raw=tg.raw,
            extra_echoes=extra,
        )

    def telegram_latency_s(self, scan: Scan) -> float | None:
        """Time of transmission minus time since start-up (the scan's stamp), s."""
        if len(scan.device_ticks) < 2:
            return None
        start, sent = scan.device_ticks[0], scan.device_ticks[1]
        return ((sent - start) % (1 << self.tick_bits)) / self.tick_hz

    def stop(self) -> None:
        if self._sock is None:
            return
        self.request("sEN", "LMDscandata", (("u8", 0),))
        self._streaming = False
        if self.stop_laser:
            self.set_access_mode()
            self.request("sMN", "LMCstopmeas")
            self.request("sMN", "Run")

    def close(self) -> None:
        sock = self._sock
        if sock is None:
            return
        if self._streaming:
            try:
                sock.sendall(
                    frame(
                        build("sEN", "LMDscandata", (("u8", 0),), binary=self.binary), self.binary
                    )
                )
            except OSError:
                pass
        self._drop()
