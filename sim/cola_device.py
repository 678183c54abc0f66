"""A simulated SICK LMS1xx / LMS5xx / TiM7xx speaking CoLa-A or CoLa-B (a ``SimDevice``).

It answers the start-up telegrams the way the real LMS111 does in the capture in
``../shared/data/sick/`` (byte layouts checked there), switches encoding on
``sWN EIHstCola`` (0 = CoLa-A, 1 = CoLa-B; the answer still goes out in the old
encoding), and once ``sEN LMDscandata 1`` streams ``sSN LMDscandata`` at the model's
rate: scan counter, telegram counter and both µs clock fields from its own
:class:`SimClock`, DIST1 (mm, 16 bit) and, for models with intensity, RSSI1 (16 bit).
Every streamed scan is also kept in ``history`` so tests can compare what the driver
read with what was sent. Unknown requests get ``sFA`` with a SOPAS error code, as the
real devices answer them.
"""

from __future__ import annotations

import math
import struct
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from acq.drivers.cola_codec import ColaFramer, Telegram, build, frame
from acq.drivers.cola_scandata import Channel, ScanData, encode_scandata
from acq.drivers.scanner import ProtocolError
from acq.sim.device_clock import SimClock
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import ScannerModel

__all__ = ["PASSWORDS", "ColaDevice", "SentScan"]

# SetAccessMode password hashes by access level (SICK's documented defaults).
PASSWORDS = {2: 0xB21ACE26, 3: 0xF4724744, 4: 0x81BE23AA}


@dataclass(frozen=True)
class SentScan:
    """What the device sent for one scan: metres as quantised on the wire (+inf = 0)."""

    scan_counter: int
    telegram_counter: int
    ticks: tuple[int, int]  # time since start-up, time of transmission (µs)
    t0: float  # true (host monotonic) time of point 0, s
    ranges: np.ndarray  # float32 m
    intensities: np.ndarray  # float32, empty without RSSI1


class ColaDevice:
    """SICK scanner protocol state machine; serve it with ``acq.sim.transport.TcpDeviceServer``."""

    def __init__(
        self,
        model: ScannerModel,
        source: StreetSource | None = None,
        clock: SimClock | None = None,
        protocol: str = "cola-b",
        history: int = 512,
    ) -> None:
        if protocol not in ("cola-a", "cola-b"):
            raise ValueError(f"protocol must be cola-a or cola-b, not {protocol!r}")
        self.model = model
        self.source = source if source is not None else StreetSource(model)
        self.clock = (
            clock
            if clock is not None
            else SimClock(
                tick_hz=model.clock_hz,
                wrap_bits=model.clock_bits,
                epoch=time.monotonic() - 42.0,  # powered up a while ago
            )
        )
        self.power_on_binary = protocol == "cola-b"
        self.history: deque[SentScan] = deque(maxlen=history)
        # Distances are uint16 mm * scale: a scale factor large enough for range_max.
        self.dist_scale = float(max(model.dist_scale, math.ceil(model.range_max * 1000 / 65535)))
        self.start_angle = round(model.start_deg * 10000)
        self.step = round(model.step_deg * 10000)
        self.scan_frequency = round(model.scan_hz * 100)
        self.measurement_frequency = round(model.scan_hz * 360.0 / model.step_deg / 100)
        try:
            self.serial_number = int(model.serial) & 0xFFFFFFFF
        except ValueError:
            self.serial_number = 0
        self._reset()

    # --- state ------------------------------------------------------------------------

    def _reset(self) -> None:
        self.binary = self.power_on_binary
        self.framer = ColaFramer("auto")
        self.access_level = 0
        self.measuring = True
        self.streaming = False
        self.telegram_counter = 0
        self._next_k: int | None = None
        self._corrupt = False

    @property
    def protocol(self) -> str:
        return "cola-b" if self.binary else "cola-a"

    def _scan_start(self, k: int) -> float:
        return self.clock.epoch + k * self.model.scan_period

    def _frame(self, payload: bytes) -> bytes:
        corrupt, self._corrupt = self._corrupt, False
        return frame(payload, self.binary, corrupt=corrupt)

    # --- SimDevice --------------------------------------------------------------------

    def handle(self, data: bytes, now: float) -> bytes:
        self.framer.feed(data)
        out = []
        for item in self.framer.items():
            if isinstance(item, ProtocolError):
                continue  # the real device ignores what it cannot frame
            out.append(self._answer(item, now))
        return b"".join(out)

    def poll(self, now: float) -> bytes:
        if not (self.streaming and self.measuring) or self._next_k is None:
            return b""
        period = self.model.scan_period
        latest = math.floor((now - self.clock.epoch) / period) - 1  # last fully sent scan
        # far behind (the host was busy for over a second): the device moved on
        if (latest - self._next_k) * period > 1.0:
            self._next_k = latest
        out = []
        while self._scan_start(self._next_k) + period <= now:
            out.append(self._frame(self._scan_payload(self._next_k, "sSN")))
            self._next_k += 1
        return b"".join(out)

    def next_due(self, now: float) -> float | None:
        if not (self.streaming and self.measuring) or self._next_k is None:
            return None
        return self._scan_start(self._next_k) + self.model.scan_period

    def on_disconnect(self) -> None:
        self.streaming = False
        self.access_level = 0
        self.framer = ColaFramer("auto")

    def reboot(self, now: float) -> None:
        self.clock.reboot(now)
        self._reset()

    def corrupt_next(self) -> None:
        self._corrupt = True

    # --- telegrams --------------------------------------------------------------------

    def scan_data(self, k: int, command: str = "sSN") -> tuple[ScanData, SentScan]:
        """Scan number ``k`` since power-up (point 0 at ``clock.epoch + k * period``)."""
        m = self.model
        t0 = self._scan_start(k)
        ranges, intens = self.source.scan(t0)
        with np.errstate(invalid="ignore"):
            mm = np.rint(ranges * 1000.0 / self.dist_scale)
        ok = np.isfinite(mm) & (mm >= 1) & (mm <= 65535)
        dist = np.where(ok, mm, 0).astype(np.uint16)
        chans = [Channel("DIST1", self.dist_scale, 0.0, self.start_angle, self.step, dist)]
        rssi = np.zeros(0, np.uint16)
        if m.intensity:
            rssi = np.where(ok, np.clip(np.rint(intens), 0, 65535), 0).astype(np.uint16)
            chans.append(Channel("RSSI1", 1.0, 0.0, self.start_angle, self.step, rssi))
        self.telegram_counter = (self.telegram_counter + 1) & 0xFFFF
        ticks = (self.clock.ticks(t0), self.clock.ticks(t0 + m.scan_period))
        wall = time.time()
        tm = time.gmtime(wall)
        stamp = (tm.tm_year, tm.tm_mon, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, 0)
        sd = ScanData(
            command=command,
            version=1,
            device_number=1,
            serial=self.serial_number,
            device_status=(0, 0),
            telegram_counter=self.telegram_counter,
            scan_counter=k & 0xFFFF,
            time_since_startup=ticks[0],
            time_of_transmission=ticks[1],
            inputs=(0, 0),
            outputs=(0, 0),
            reserved=0,
            scan_frequency=self.scan_frequency,
            measurement_frequency=self.measurement_frequency,
            channels16=tuple(chans),
            timestamp=stamp,
        )
        metres = dist.astype(np.float32) * np.float32(self.dist_scale * 0.001)
        metres[dist == 0] = np.inf
        sent = SentScan(
            k & 0xFFFF,
            self.telegram_counter,
            ticks,
            t0,
            metres,
            rssi.astype(np.float32) if m.intensity else np.zeros(0, np.float32),
        )
        return sd, sent

    def _scan_payload(self, k: int, command: str) -> bytes:
        sd, sent = self.scan_data(k, command)
        self.history.append(sent)
        return encode_scandata(sd, self.binary, command)

    def _error(self, code: int) -> bytes:
        if self.binary:
            return self._frame(b"sFA " + struct.pack(">H", code))
        return self._frame(b"sFA %X" % code)

    def _reply(self, kind: str, name: str, args: list[tuple[str, object]] | None = None) -> bytes:
        return self._frame(build(kind, name, args or (), binary=self.binary))

    def _answer(self, tg: Telegram, now: float) -> bytes:
        kind, name = tg.kind, tg.name
        m = self.model
        try:
            r = tg.reader()
            if kind == "sMN":
                if name == "SetAccessMode":
                    level, password = r.u8(), r.u32()
                    ok = PASSWORDS.get(level) == password
                    if ok:
                        self.access_level = level
                    return self._reply("sAN", name, [("u8", int(ok))])
                if name in ("LMCstartmeas", "LMCstopmeas"):
                    if self.access_level < 3:
                        return self._error(1)
                    self.measuring = name == "LMCstartmeas"
                    return self._reply("sAN", name, [("u8", 0)])
                if name == "Run":
                    self.access_level = 0
                    return self._reply("sAN", name, [("u8", 1)])
                return self._error(2)
            if kind == "sRN":
                if name == "DeviceIdent":
                    return self._reply("sRA", name, [("str", m.product), ("str", m.firmware)])
                if name == "FirmwareVersion":
                    return self._reply("sRA", name, [("str", m.firmware)])
                if name == "SerialNumber":
                    return self._reply("sRA", name, [("str", m.serial)])
                if name == "STlms":
                    tm = time.gmtime()
                    return self._reply(
                        "sRA",
                        name,
                        [
                            ("u16", 7 if self.measuring else 6),
                            ("u8", 0),
                            ("str", time.strftime("%H:%M:%S", tm)),
                            ("str", time.strftime("%d.%m.%Y", tm)),
                            ("u16", 0),
                            ("u16", 0),
                            ("u16", 0),
                        ],
                    )
                if name == "SCdevicestate":
                    return self._reply("sRA", name, [("u8", 0)])  # as the real LMS111
                if name == "LMPoutputRange":
                    stop = self.start_angle + (m.n_points - 1) * self.step
                    args: list[tuple[str, object]] = [
                        ("u16", 1),
                        ("u32", self.step),
                        ("i32", self.start_angle),
                        ("i32", stop),
                    ]
                    return self._reply("sRA", name, args)
                if name == "LMPscancfg":
                    stop = self.start_angle + (m.n_points - 1) * self.step
                    cfg: list[tuple[str, object]] = [
                        ("u32", self.scan_frequency),
                        ("u16", 1),
                        ("u32", self.step),
                        ("i32", self.start_angle),
                        ("i32", stop),
                    ]
                    return self._reply("sRA", name, cfg)
                if name == "LMDscandata":
                    if not self.measuring:
                        return self._error(4)
                    k = max(0, math.floor((now - self.clock.epoch) / m.scan_period) - 1)
                    return self._frame(self._scan_payload(k, "sRA"))
                return self._error(3)
            if kind == "sEN":
                if name == "LMDscandata":
                    on = r.u8()
                    self.streaming = bool(on)
                    if on:
                        self._next_k = max(0, math.floor((now - self.clock.epoch) / m.scan_period))
                    return self._reply("sEA", name, [("u8", on)])
                return self._error(15)
            if kind == "sWN":
                if name == "EIHstCola":
                    value = r.u8()
                    if self.access_level < 3:
                        return self._error(10)
                    out = self._frame(b"sWA EIHstCola ")  # the LMS111 sends the space
                    self.binary = bool(value)
                    return out
                return self._error(3)
        except ProtocolError:
            return self._error(5)
        return self._error(12)
