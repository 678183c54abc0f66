"""A simulated SICK LMS1xx / LMS5xx / TiM7xx speaking CoLa-A or CoLa-B (a ``SimDevice``).

It answers the start-up telegrams the way the real LMS111 does in the capture in
``../shared/data/sick/`` (byte layouts checked there), switches encoding on
``sWN EIHstCola`` (0 = CoLa-A, 1 = CoLa-B; the answer still goes out in the old
encoding), and once ``sEN LMDscandata 1`` streams ``sSN LMDscandata`` at the configured
rate: scan counter, telegram counter and both µs clock fields from its own
:class:`SimClock`, DIST (mm, 16 bit) and RSSI channels as configured.

What a client writes is honoured as the SICK telegram listings for LMS1xx/LMS5xx/TiM
describe it (and SICK's driver sick_scan_xd expects it):

- ``sWN LMPoutputRange`` (1 sector, resolution, start, stop in 1/10000 degree): scans
  carry only the beams inside it, snapped to the beam grid, with that start angle.
- ``sWN LMDscandatacfg`` (output channels, RSSI on/off and 8/16 bit, encoder, position,
  name, comment, time, output rate): which channels and blocks ``LMDscandata`` carries.
- ``sMN mLMPsetscancfg`` (frequency, sectors, resolution, start, stop): the scan
  frequency and resolution among those the model allows; the answer's status code is
  0 ok, 1 frequency, 2 resolution, 3 resolution and area, 4 area error.
- ``sWN FREchoFilter`` (LMS5xx; 0 first, 1 all, 2 last echo): with all echoes every
  enabled output channel is sent (DIST1..5; the street gives one echo, the rest are 0).

The device is busy (``SCdevicestate`` 0) while a client is logged in or measurement is
stopped, and ready (1) once ``sMN Run`` returns it to measuring. Every streamed scan is
kept in ``history`` so tests can compare what a driver read with what was sent.
Unknown requests get ``sFA`` with a SOPAS error code, as the real devices answer them.
"""

from __future__ import annotations

import copy
import math
import struct
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from acq.drivers.cola_codec import ArgReader, ColaFramer, Telegram, build, frame
from acq.drivers.cola_scandata import Channel, ScanData, encode_scandata
from acq.drivers.scanner import ProtocolError
from acq.sim.device_clock import SimClock
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import ScannerModel

__all__ = ["PASSWORDS", "ColaDevice", "DataConfig", "ScanShape", "SentScan"]

# SetAccessMode password hashes by access level (SICK's documented defaults).
PASSWORDS = {2: 0xB21ACE26, 3: 0xF4724744, 4: 0x81BE23AA}

RSSI8_DIVISOR = 40.0  # the street's return strength (16-bit scale) -> 8-bit RSSI
LOCATION_NAME = "not defined"  # as the LMS111 in the capture


class Source(Protocol):
    def scan(self, t0: float) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass(frozen=True)
class SentScan:
    """What the device sent for one scan: metres as quantised on the wire (+inf = 0)."""

    scan_counter: int
    telegram_counter: int
    ticks: tuple[int, int]  # time since start-up (first point sent), time of transmission, µs
    t0: float  # true (host monotonic) time of the first point sent, s
    ranges: np.ndarray  # float32 m, DIST1
    intensities: np.ndarray  # float32, RSSI1; empty without it
    t_sent: float = 0.0  # host monotonic s the telegram was made (then written at once)


@dataclass(frozen=True)
class DataConfig:
    """``LMDscandatacfg``: what ``LMDscandata`` carries (SICK telegram listing; the 13
    bytes sick_scan_xd writes: channel LSB/MSB, remission, resolution, unit, encoder
    LSB/MSB, position, name, comment, time, output rate uint16)."""

    channels: int = 1  # output channel bits: bit n = echo n+1 (DIST/RSSI n+1)
    channels_hi: int = 0
    remission: bool = True
    remission_16bit: bool = True
    unit: int = 0
    encoder: tuple[int, int] = (0, 0)
    position: bool = False
    name: bool = False
    comment: bool = False
    time: bool = True
    output_rate: int = 1  # every n-th scan

    def args(self) -> list[tuple[str, object]]:
        u8 = [
            self.channels,
            self.channels_hi,
            int(self.remission),
            int(self.remission_16bit),
            self.unit,
            *self.encoder,
            int(self.position),
            int(self.name),
            int(self.comment),
            int(self.time),
        ]
        return [*(("u8", v) for v in u8), ("u16", self.output_rate)]


@dataclass(frozen=True)
class ScanShape:
    """What a stream's scans look like: frequency (1/100 Hz), first angle and step
    (1/10000 degree), points, DIST and RSSI channels, RSSI bits (0 without), output rate."""

    frequency: int
    start: int
    step: int
    n_points: int
    n_dist: int
    n_rssi: int
    rssi_bits: int
    output_rate: int


class ColaDevice:
    """SICK scanner protocol state machine; serve it with ``acq.sim.transport.TcpDeviceServer``."""

    def __init__(
        self,
        model: ScannerModel,
        source: Source | None = None,
        clock: SimClock | None = None,
        protocol: str = "cola-b",
        history: int = 512,
    ) -> None:
        if protocol not in ("cola-a", "cola-b"):
            raise ValueError(f"protocol must be cola-a or cola-b, not {protocol!r}")
        self.model = model
        self.source: Source = source if source is not None else StreetSource(model)
        self._sources: dict[tuple[int, int, int, int], Source] = {}
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
        # The beam grid of the full aperture at the model's resolution (1/10000 degree).
        self.model_start = round(model.start_deg * 10000)
        self.model_step = round(model.step_deg * 10000)
        self.model_stop = self.model_start + (model.n_points - 1) * self.model_step
        self.model_frequency = round(model.scan_hz * 100)
        self.scan_configs = set(model.scan_configs) | {(self.model_frequency, self.model_step)}
        try:
            self.serial_number = int(model.serial) & 0xFFFFFFFF
        except ValueError:
            self.serial_number = 0
        self.default_data = DataConfig(
            remission=model.intensity, remission_16bit=model.rssi_bits == 16
        )
        self.default_echo_filter = 0  # FREchoFilter: 0 first, 1 all, 2 last echo
        self._reset()

    # --- state ------------------------------------------------------------------------

    def _reset(self) -> None:
        """Power-up: the connection state and the (RAM) configuration."""
        self.binary = self.power_on_binary
        self.framer = ColaFramer("auto")
        self.access_level = 0
        self.measuring = True
        self.streaming = False
        self.telegram_counter = 0
        self._next_k: int | None = None
        self._corrupt = False
        self.scan_frequency = self.model_frequency  # 1/100 Hz
        self.step = self.model_step  # 1/10000 degree
        self.sector = (self.model_start, self.model_stop)
        self.output_range = self.sector
        self.data = self.default_data
        self.echo_filter = self.default_echo_filter

    @property
    def protocol(self) -> str:
        return "cola-b" if self.binary else "cola-a"

    @property
    def scan_period(self) -> float:
        """s per revolution at the configured frequency."""
        return 100.0 / self.scan_frequency

    @property
    def measurement_frequency(self) -> int:
        """Beams per second over a full turn, in 100 Hz (as LMDscandata carries it)."""
        return round(self.scan_frequency / 100 * 3_600_000 / self.step / 100)

    @property
    def ready(self) -> bool:
        """``SCdevicestate`` 1: measuring and not held in configuration by a login."""
        return self.measuring and self.access_level == 0

    def beams(self) -> tuple[int, int]:
        """(index of the first beam sent on the sector's grid, number of beams sent)."""
        lo, hi = self.sector
        last = (hi - lo) // self.step
        start, stop = self.output_range
        first = min(max(round((start - lo) / self.step), 0), last)
        end = min(max(round((stop - lo) / self.step), 0), last)
        return first, max(end - first + 1, 0)

    def shape(self) -> ScanShape:
        """What the scans streamed now look like."""
        first, n = self.beams()
        echoes = self.echoes()
        rssi = echoes if self.data.remission else 0
        return ScanShape(
            self.scan_frequency,
            self.sector[0] + first * self.step,
            self.step,
            n,
            echoes,
            rssi,
            (16 if self.data.remission_16bit else 8) if rssi else 0,
            max(self.data.output_rate, 1),
        )

    def echoes(self) -> int:
        """DIST channels sent: one, or every enabled one with FREchoFilter 1 (all echoes)."""
        enabled = bin(self.data.channels & ((1 << self.model.echoes) - 1)).count("1")
        if self.echo_filter == 1 and self.model.echoes > 1:
            return max(enabled, 1)
        return 1

    def _scan_start(self, k: int) -> float:
        return self.clock.epoch + k * self.scan_period

    def _frame(self, payload: bytes) -> bytes:
        corrupt, self._corrupt = self._corrupt, False
        return frame(payload, self.binary, corrupt=corrupt)

    def _restart_stream(self, now: float) -> None:
        """After a change of scan frequency: the next scan is the next full one."""
        if self._next_k is not None:
            self._next_k = max(0, math.floor((now - self.clock.epoch) / self.scan_period) + 1)

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
        period = self.scan_period
        latest = math.floor((now - self.clock.epoch) / period) - 1  # last fully sent scan
        # far behind (the host was busy for over a second): the device moved on
        if (latest - self._next_k) * period > 1.0:
            self._next_k = latest
        rate = max(self.data.output_rate, 1)
        out = []
        while self._scan_start(self._next_k) + period <= now:
            if self._next_k % rate == 0:
                out.append(self._frame(self._scan_payload(self._next_k, "sSN")))
            self._next_k += 1
        return b"".join(out)

    def next_due(self, now: float) -> float | None:
        if not (self.streaming and self.measuring) or self._next_k is None:
            return None
        return self._scan_start(self._next_k) + self.scan_period

    def on_disconnect(self) -> None:
        self.streaming = False
        self.access_level = 0
        self.framer = ColaFramer("auto")

    def reboot(self, now: float) -> None:
        self.clock.reboot(now)
        self._reset()

    def corrupt_next(self) -> None:
        self._corrupt = True

    # --- scans ------------------------------------------------------------------------

    def _source(self, first: int, n: int) -> tuple[Source, bool]:
        """A source rendering exactly the beams sent, and whether it does (else it renders
        the model's own beams, to be cut)."""
        m = self.model
        default = (self.scan_frequency, self.step, self.sector[0]) == (
            self.model_frequency,
            self.model_step,
            self.model_start,
        ) and (first, n) == (0, m.n_points)
        if default:
            return self.source, True
        rig = getattr(self.source, "rig", None)
        if rig is None:
            return self.source, False
        key = (self.scan_frequency, self.step, self.sector[0] + first * self.step, n)
        src = self._sources.get(key)
        if src is None:
            src = copy.copy(self.source)
            period = self.scan_period
            inc = math.radians(self.step / 10000)
            src.rig = replace(  # type: ignore[attr-defined]
                rig,
                angle_min=math.radians(key[2] / 10000 - 90.0),
                angle_increment=inc,
                n_steps=n,
                scan_period=period,
                time_increment=period * inc / (2 * math.pi),
            )
            self._sources[key] = src
        return src, True

    def scan_data(self, k: int, command: str = "sSN") -> tuple[ScanData, SentScan]:
        """Scan number ``k`` since power-up (its sector's first beam at ``clock.epoch +
        k * period``), as configured."""
        m = self.model
        shape = self.shape()
        first, n = self.beams()
        t_first = self._scan_start(k) + first * self.step / 3_600_000 * self.scan_period
        source, exact = self._source(first, n)
        ranges, intens = source.scan(t_first)
        if not exact:
            ranges, intens = ranges[first : first + n], intens[first : first + n]
        with np.errstate(invalid="ignore"):
            mm = np.rint(ranges * 1000.0 / self.dist_scale)
        ok = np.isfinite(mm) & (mm >= 1) & (mm <= 65535)
        dist = np.where(ok, mm, 0).astype(np.uint16)
        zeros16 = np.zeros(n, np.uint16)
        chans16 = [Channel("DIST1", self.dist_scale, 0.0, shape.start, self.step, dist)]
        chans16 += [
            Channel(f"DIST{e + 1}", self.dist_scale, 0.0, shape.start, self.step, zeros16)
            for e in range(1, shape.n_dist)
        ]
        chans8: list[Channel] = []
        rssi = np.zeros(0, np.float32)
        if shape.n_rssi:
            strength = np.where(ok, intens, 0.0)
            if shape.rssi_bits == 16:
                raw: np.ndarray = np.clip(np.rint(strength), 0, 65535).astype(np.uint16)
            else:
                raw = np.clip(np.rint(strength / RSSI8_DIVISOR), 0, 255).astype(np.uint8)
            rssi = raw.astype(np.float32)
            group = chans16 if shape.rssi_bits == 16 else chans8
            group.append(Channel("RSSI1", 1.0, 0.0, shape.start, self.step, raw))
            group += [
                Channel(f"RSSI{e + 1}", 1.0, 0.0, shape.start, self.step, np.zeros_like(raw))
                for e in range(1, shape.n_rssi)
            ]
        self.telegram_counter = (self.telegram_counter + 1) & 0xFFFF
        ticks = (self.clock.ticks(t_first), self.clock.ticks(self._scan_start(k + 1)))
        stamp = None
        if self.data.time:
            tm = time.gmtime(time.time())
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
            encoders=((0, 0),) if any(self.data.encoder) else (),
            channels16=tuple(chans16),
            channels8=tuple(chans8),
            position=(0.0,) * 8 if self.data.position else None,
            name=m.product if self.data.name else None,
            comment="" if self.data.comment else None,
            timestamp=stamp,
        )
        metres = dist.astype(np.float32) * np.float32(self.dist_scale * 0.001)
        metres[dist == 0] = np.inf
        sent = SentScan(
            k & 0xFFFF, self.telegram_counter, ticks, t_first, metres, rssi, time.monotonic()
        )
        return sd, sent

    def _scan_payload(self, k: int, command: str) -> bytes:
        sd, sent = self.scan_data(k, command)
        self.history.append(sent)
        return encode_scandata(sd, self.binary, command)

    # --- telegrams --------------------------------------------------------------------

    def _error(self, code: int) -> bytes:
        if self.binary:
            return self._frame(b"sFA " + struct.pack(">H", code))
        return self._frame(b"sFA %X" % code)

    def _reply(
        self, kind: str, name: str, args: Sequence[tuple[str, object]] | None = None
    ) -> bytes:
        return self._frame(build(kind, name, args or (), binary=self.binary))

    def _written(self, name: str) -> bytes:
        """``sWA name``: the LMS111 sends a space after the name in CoLa-B (capture)."""
        return self._frame(f"sWA {name}{' ' if self.binary else ''}".encode())

    def _sector_args(self, start: int, stop: int) -> list[tuple[str, object]]:
        return [("u16", 1), ("u32", self.step), ("i32", start), ("i32", stop)]

    def _field(self, index: int) -> list[tuple[str, object]]:
        """``sRA fieldNNN``: an evaluation field with no shape configured, laid out as the
        LMS111's unused fields in the capture (scale 1.0, offset 0, angle scale and
        offset, type 2, no segmented/rectangular/radial/dynamic part, empty name); past
        the fields the device evaluates, a single 0 byte as the LMS111 sends."""
        # the LMS1xx/5xx evaluate 10 of their 30 fields (capture; sick_scan_xd's emulator)
        defined = 10 if self.model.eval_fields == 30 else self.model.eval_fields
        if index >= defined:
            return [("u8", 0)]
        return [
            ("f32", 1.0),
            ("f32", 0.0),
            ("u32", self.model_step),
            ("i32", self.model_start),
            ("u8", 2),
            ("u8", 0),
            *(("u16", 0) for _ in range(4)),
            ("u16", 1),
            ("str", ""),
            ("u16", 0),
        ]

    def _lferec(self, now: float) -> list[tuple[str, object]]:
        """``LFErec``: the results of the active field set's three fields, all free (sick_scan_xd
        SickScanMessages::parseLFErecMsg layout: count, then per field version, index,
        system counter, distance scale/offset, angle scale/offset, result, 3 reserved
        uint16, time flag)."""
        args: list[tuple[str, object]] = [("u16", 3)]
        for i in range(3):
            args += [
                ("u16", 0),
                ("u8", i + 1),  # 1..3 within the field set
                ("u32", self.clock.ticks(now)),
                ("f32", 1.0),
                ("f32", 0.0),
                ("u32", self.model_step),
                ("i32", self.model_start),
                ("u8", 1),  # free
                ("u16", 0),
                ("u16", 0),
                ("u16", 0),
                ("u16", 0),  # no time block
            ]
        return args

    def _answer(self, tg: Telegram, now: float) -> bytes:
        kind, name = tg.kind, tg.name
        try:
            handler = {
                "sMN": self._method,
                "sRN": self._read,
                "sEN": self._event,
                "sWN": self._write,
            }.get(kind)
            if handler is None:
                return self._error(12)
            return handler(name, tg, now)
        except ProtocolError:
            return self._error(5)

    def _method(self, name: str, tg: Telegram, now: float) -> bytes:
        r = tg.reader()
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
        if name == "mLMPsetscancfg":
            if self.access_level < 3:
                return self._error(1)
            return self._set_scan_config(r, now)
        return self._error(2)

    def _set_scan_config(self, r: ArgReader, now: float) -> bytes:
        """``sMN mLMPsetscancfg``: frequency u32, sectors u16, then per sector resolution
        u32, start i32, stop i32 (1/100 Hz, 1/10000 degree); one sector on these models.

        The answer (LMS500 operating instructions 8013796, 10.2.8) is a status code (0 no
        error, 1 invalid frequency, 2 invalid resolution, 3 invalid frequency and
        resolution, 4 invalid scan area) and the configuration then in use."""
        frequency, sectors = r.u32(), r.u16()
        res, start, stop = r.u32(), r.i32(), r.i32()
        frequency_ok = frequency in {f for f, _ in self.scan_configs}
        if frequency_ok:
            resolution_ok = (frequency, res) in self.scan_configs
        else:
            resolution_ok = res in {r for _, r in self.scan_configs}
        area_ok = sectors == 1 and self.model_start <= start < stop <= self.model_stop + res
        if not (frequency_ok or resolution_ok):
            status = 3
        elif not frequency_ok:
            status = 1
        elif not resolution_ok:
            status = 2
        elif not area_ok:
            status = 4
        else:
            status = 0
            if frequency != self.scan_frequency:
                self.scan_frequency = frequency
                self._restart_stream(now)
            self.step = res
            stop = start + round((stop - start) / res) * res
            self.sector = (start, stop)
            self.output_range = (
                max(self.output_range[0], start),
                min(self.output_range[1], stop),
            )
            if self.output_range[0] >= self.output_range[1]:
                self.output_range = self.sector
        args: list[tuple[str, object]] = [("u8", status), ("u32", self.scan_frequency)]
        args += self._sector_args(*self.sector)
        return self._reply("sAN", "mLMPsetscancfg", args)

    def _read(self, name: str, tg: Telegram, now: float) -> bytes:
        m = self.model
        if name == "DeviceIdent":
            return self._reply("sRA", name, [("str", m.product), ("str", m.firmware)])
        if name == "FirmwareVersion":
            return self._reply("sRA", name, [("str", m.firmware)])
        if name == "SerialNumber":
            return self._reply("sRA", name, [("str", m.serial)])
        if name == "LocationName":
            return self._reply("sRA", name, [("str", LOCATION_NAME)])
        if name == "ODoprh":  # operating hours, 1/10 h
            return self._reply("sRA", name, [("u32", int((now - self.clock.epoch) / 360))])
        if name == "ODpwrc":  # power-on count
            return self._reply("sRA", name, [("u32", 1 + self.clock.reboots)])
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
        if name == "SCdevicestate":  # 0 busy, 1 ready, 2 error
            return self._reply("sRA", name, [("u8", int(self.ready))])
        if name == "LMPoutputRange":
            first, n = self.beams()
            start = self.sector[0] + first * self.step
            return self._reply("sRA", name, self._sector_args(start, start + (n - 1) * self.step))
        if name == "LMPscancfg":
            cfg: list[tuple[str, object]] = [("u32", self.scan_frequency)]
            return self._reply("sRA", name, cfg + self._sector_args(*self.sector))
        if name == "LMDscandatacfg":
            return self._reply("sRA", name, self.data.args())
        if name == "FREchoFilter" and m.echoes > 1:
            return self._reply("sRA", name, [("u8", self.echo_filter)])
        if name.startswith("field") and name[5:].isdigit() and len(name) == 8:
            index = int(name[5:])
            if index < m.eval_fields:
                return self._reply("sRA", name, self._field(index))
            return self._error(3)
        if name == "LIDinputstate":
            # version, system counter, 4 inputs (2 = not used), no time: the LMS111's answer
            args = [("u16", 1), ("u32", 0), *(("u8", 2) for _ in range(4)), ("u16", 0)]
            return self._reply("sRA", name, args)
        if name == "LFErec" and m.eval_fields:
            return self._reply("sRA", name, self._lferec(now))
        if name == "LMDscandata":
            if not self.measuring:
                return self._error(4)
            k = max(0, math.floor((now - self.clock.epoch) / self.scan_period) - 1)
            return self._frame(self._scan_payload(k, "sRA"))
        return self._error(3)

    def _event(self, name: str, tg: Telegram, now: float) -> bytes:
        r = tg.reader()
        if name == "LMDscandata":
            on = r.u8()
            self.streaming = bool(on)
            if on:
                self._next_k = max(0, math.floor((now - self.clock.epoch) / self.scan_period))
            return self._reply("sEA", name, [("u8", on)])
        if name in ("LFErec", "LIDoutputstate", "LIDinputstate") and self.model.eval_fields:
            # subscriptions to field and I/O events: acknowledged; nothing changes on the
            # simulated street, so no event follows
            return self._reply("sEA", name, [("u8", r.u8())])
        return self._error(15)

    def _write(self, name: str, tg: Telegram, now: float) -> bytes:
        r = tg.reader()
        if name == "EIHstCola":
            value = r.u8()
            if self.access_level < 3:
                return self._error(10)
            out = self._frame(b"sWA EIHstCola ")  # the LMS111 sends the space
            self.binary = bool(value)
            return out
        if name == "LMPoutputRange":
            sectors, res, start, stop = r.u16(), r.u32(), r.i32(), r.i32()
            if self.access_level < 3:
                return self._error(10)
            lo, hi = self.sector
            if sectors != 1 or res != self.step or start > stop or stop < lo or start > hi:
                return self._error(4)
            self.output_range = (start, stop)
            return self._written(name)
        if name == "LMDscandatacfg":
            v = [r.u8() for _ in range(11)]
            rate = r.u16()
            if self.access_level < 3:
                return self._error(10)
            if rate < 1 or v[3] > 1 or not (v[0] or v[1]):
                return self._error(4)
            self.data = DataConfig(
                channels=v[0],
                channels_hi=v[1],
                remission=bool(v[2]),
                remission_16bit=bool(v[3]),
                unit=v[4],
                encoder=(v[5], v[6]),
                position=bool(v[7]),
                name=bool(v[8]),
                comment=bool(v[9]),
                time=bool(v[10]),
                output_rate=rate,
            )
            return self._written(name)
        if name == "FREchoFilter" and self.model.echoes > 1:
            value = r.u8()
            if self.access_level < 3:
                return self._error(10)
            if value > 2:
                return self._error(4)
            self.echo_filter = value
            return self._written(name)
        return self._error(3)
