"""SICK ``LMDscandata``: the scan telegram of CoLa-A and CoLa-B, parsed and encoded.

``LMDscandata`` values: distances are ``raw * scale + offset`` millimetres, returned in
metres; a raw 0 (no echo, or a measurement the device rejected: dazzled, too close,
filtered) becomes ``+inf`` (REP-117; the telegram does not tell these cases apart, so
no ``-inf`` or ``nan`` is produced). Angles are 1/10000 degree with 90 degrees straight
ahead; :class:`ScanData` converts them to the REP-103 laser frame (device minus 90°).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import numpy as np

from acq.drivers.cola_codec import STX4, ArgReader, ArgWriter, unframe
from acq.drivers.scanner import ProtocolError

__all__ = ["Channel", "ScanData", "encode_scandata", "parse_scandata"]


@dataclass(frozen=True, slots=True)
class Channel:
    """One output channel of ``LMDscandata`` (DIST1..5, RSSI1..5, ANGL1, ...).

    ``start_angle`` and ``step`` are in 1/10000 degree, SICK convention (90° ahead).
    ``data`` holds the raw values (uint16 or uint8).
    """

    name: str
    scale: float
    offset: float
    start_angle: int
    step: int
    data: np.ndarray

    def values(self) -> np.ndarray:
        """float32 ``raw * scale + offset`` (device units: mm for DIST)."""
        v = self.data.astype(np.float32)
        if self.scale != 1.0:
            v *= np.float32(self.scale)
        if self.offset != 0.0:
            v += np.float32(self.offset)
        return v


@dataclass(frozen=True, slots=True)
class ScanData:
    """A parsed ``LMDscandata`` telegram (answer ``sRA`` or event ``sSN``).

    Times ``time_since_startup`` / ``time_of_transmission`` are the device's raw 32-bit
    µs counters; ``scan_frequency`` is in 1/100 Hz, ``measurement_frequency`` in 100 Hz.
    """

    command: str
    version: int
    device_number: int
    serial: int
    device_status: tuple[int, int]
    telegram_counter: int
    scan_counter: int
    time_since_startup: int
    time_of_transmission: int
    inputs: tuple[int, int]
    outputs: tuple[int, int]
    reserved: int  # layer angle on multi-layer devices, else 0
    scan_frequency: int
    measurement_frequency: int
    encoders: tuple[tuple[int, int], ...] = ()  # (position ticks, speed ticks/mm)
    channels16: tuple[Channel, ...] = ()
    channels8: tuple[Channel, ...] = ()
    position: tuple[float, ...] | None = None  # x y z rx ry rz rotation_type name_flag
    name: str | None = None
    comment: str | None = None
    timestamp: tuple[int, int, int, int, int, int, int] | None = None  # Y M D h m s µs
    event: tuple[str, int, int, int] | None = None  # type, encoder pos, time µs, angle
    binary: bool = True
    raw: bytes = field(default=b"", repr=False)

    @property
    def channels(self) -> tuple[Channel, ...]:
        return self.channels16 + self.channels8

    def channel(self, name: str) -> Channel | None:
        for ch in self.channels16 + self.channels8:
            if ch.name == name:
                return ch
        return None

    def distance_channels(self) -> list[Channel]:
        return [c for c in self.channels16 + self.channels8 if c.name.startswith("DIST")]

    def ranges(self, name: str = "DIST1") -> np.ndarray:
        """(N,) float32 metres of a DIST channel; raw 0 -> +inf (REP-117)."""
        ch = self.channel(name)
        if ch is None:
            raise ProtocolError(f"LMDscandata has no {name} channel")
        return _to_metres(ch)

    def intensities(self, name: str = "RSSI1") -> np.ndarray:
        """(N,) float32 device units of an RSSI channel; empty when absent."""
        ch = self.channel(name)
        return np.zeros(0, np.float32) if ch is None else ch.values()

    def _first(self) -> Channel:
        d = self.distance_channels()
        if not d:
            raise ProtocolError("LMDscandata has no DIST channel")
        return d[0]

    @property
    def n_points(self) -> int:
        return int(self._first().data.size)

    @property
    def angle_min(self) -> float:
        """REP-103 angle of point 0, rad (SICK start angle minus 90°)."""
        return math.radians(self._first().start_angle / 10000.0 - 90.0)

    @property
    def angle_increment(self) -> float:
        """rad between points."""
        return math.radians(self._first().step / 10000.0)

    @property
    def scan_period(self) -> float:
        """s; 0 when the device reports no scan frequency."""
        return 100.0 / self.scan_frequency if self.scan_frequency > 0 else 0.0

    @property
    def time_increment(self) -> float:
        """s between points: from the measurement frequency when it agrees (±10 %) with
        the scan frequency and step, else from those two (some firmware misreports it)."""
        geometric = self.scan_period * self._first().step / 3_600_000.0
        mf = self.measurement_frequency
        if mf > 10000:  # some firmware sends Hz instead of 100 Hz
            mf //= 100
        if mf > 0:
            ti = 1.0 / (mf * 100.0)
            if geometric == 0.0 or abs(ti - geometric) <= 0.1 * geometric:
                return ti
        return geometric


def _to_metres(ch: Channel) -> np.ndarray:
    mm = ch.values()
    out = mm * np.float32(0.001)
    out[ch.data == 0] = np.inf
    return out


_HEAD = struct.Struct(">HHIBBHHIIBBBBhIIH")  # version .. encoder count (38 bytes)
_CHAN = struct.Struct(">5sffiHH")  # name, scale, offset, start, step, amount (21 bytes)


def parse_scandata(data: bytes, binary: bool | None = None) -> ScanData:
    """Parse an ``LMDscandata`` telegram: a framed telegram (CoLa-B or CoLa-A, as read
    from the wire) or its bare payload (``sSN LMDscandata ...`` / ``sRA LMDscandata ...``).

    ``binary`` None detects the encoding. Raises :class:`ProtocolError` on malformed
    input. The channel arrays of a CoLa-B telegram are views of ``data``.
    """
    raw = data
    if data[:4] == STX4 or data[:2] == b"\x02s":
        tg = unframe(data)
        data, binary = tg.payload, tg.binary
    kind = data[:3]
    if kind not in (b"sSN", b"sRA") or data[3:16] != b" LMDscandata ":
        raise ProtocolError(f"not an LMDscandata telegram: {data[:24]!r}")
    if binary is None:
        binary = len(data) > 16 and data[16] < 0x20
    try:
        if binary:
            return _parse_scandata_b(data, raw)
        return _parse_scandata_a(data, raw)
    except (struct.error, ValueError, IndexError, UnicodeDecodeError) as exc:
        raise ProtocolError(f"malformed LMDscandata: {exc}") from None


def _parse_scandata_b(p: bytes, raw: bytes) -> ScanData:
    off = 16
    if len(p) < off + _HEAD.size:
        raise ProtocolError(f"LMDscandata too short ({len(p)} bytes)")
    h = _HEAD.unpack_from(p, off)
    off += _HEAD.size
    n_enc = h[16]
    if n_enc > 16:
        raise ProtocolError(f"LMDscandata: {n_enc} encoders")
    encoders = []
    for _ in range(n_enc):
        encoders.append(struct.unpack_from(">IH", p, off))
        off += 6
    chans: list[tuple[Channel, ...]] = []
    for size, dtype in ((2, ">u2"), (1, np.uint8)):
        (count,) = struct.unpack_from(">H", p, off)
        off += 2
        if count > 16:
            raise ProtocolError(f"LMDscandata: {count} channels of {8 * size} bits")
        group = []
        for _ in range(count):
            name, scale, offset, start, step, amount = _CHAN.unpack_from(p, off)
            off += _CHAN.size
            if off + amount * size > len(p):
                raise ProtocolError(f"LMDscandata: {name!r} has {amount} values past the end")
            values = np.frombuffer(p, dtype, amount, off)
            off += amount * size
            group.append(Channel(name.decode("latin-1"), scale, offset, start, step, values))
        chans.append(tuple(group))
    r = ArgReader(p, True, off)
    position, name, comment, stamp, event = _optional_blocks(r)
    return ScanData(
        "sSN" if p[1] == 0x53 else "sRA",
        h[0],
        h[1],
        h[2],
        (h[3], h[4]),
        h[5],
        h[6],
        h[7],
        h[8],
        (h[9], h[10]),
        (h[11], h[12]),
        h[13],
        h[14],
        h[15],
        tuple((int(a), int(b)) for a, b in encoders),
        chans[0],
        chans[1],
        position,
        name,
        comment,
        stamp,
        event,
        True,
        raw,
    )


def _optional_blocks(
    r: ArgReader,
) -> tuple[
    tuple[float, ...] | None,
    str | None,
    str | None,
    tuple[int, int, int, int, int, int, int] | None,
    tuple[str, int, int, int] | None,
]:
    """Position, name, comment, time and event blocks; each absent when the telegram
    ends before its flag (some firmware stops after the channels)."""
    position = name = comment = stamp = event = None
    if not r.at_end() and r.u16():
        position = (*(r.f32() for _ in range(6)), float(r.u8()), float(r.u8()))
    if not r.at_end() and r.u16():
        name = r.string("u8")
    if not r.at_end() and r.u16():
        comment = r.string("u8")
    if not r.at_end() and r.u16():
        stamp = (r.u16(), r.u8(), r.u8(), r.u8(), r.u8(), r.u8(), r.u32())
    if not r.at_end() and r.u16():
        event = (r.fixed(4), r.u32(), r.u32(), r.i32())
    return position, name, comment, stamp, event


def _parse_scandata_a(p: bytes, raw: bytes) -> ScanData:
    r = ArgReader(p, False, 16)
    version, device, serial = r.u16(), r.u16(), r.u32()
    status = (r.u8(), r.u8())
    tcount, scount, t_start, t_tx = r.u16(), r.u16(), r.u32(), r.u32()
    inputs = (r.u8(), r.u8())
    outputs = (r.u8(), r.u8())
    reserved = r.i16()
    sfreq, mfreq = r.u32(), r.u32()
    n_enc = r.u16()
    if n_enc > 16:
        raise ProtocolError(f"LMDscandata: {n_enc} encoders")
    encoders = tuple((r.u32(), r.u16()) for _ in range(n_enc))
    groups: list[tuple[Channel, ...]] = []
    for kind in ("u16", "u8"):
        count = r.u16()
        if count > 16:
            raise ProtocolError(f"LMDscandata: {count} {kind} channels")
        group = []
        for _ in range(count):
            name = r.fixed(5)
            scale, offset = r.f32(), r.f32()
            start, step, amount = r.i32(), r.u16(), r.u16()
            group.append(Channel(name, scale, offset, start, step, r.array(amount, kind)))
        groups.append(tuple(group))
    position, dname, comment, stamp, event = _optional_blocks(r)
    return ScanData(
        p[:3].decode(),
        version,
        device,
        serial,
        status,
        tcount,
        scount,
        t_start,
        t_tx,
        inputs,
        outputs,
        reserved,
        sfreq,
        mfreq,
        encoders,
        groups[0],
        groups[1],
        position,
        dname,
        comment,
        stamp,
        event,
        False,
        raw,
    )


def encode_scandata(sd: ScanData, binary: bool, command: str | None = None) -> bytes:
    """The payload of an ``LMDscandata`` telegram (inverse of :func:`parse_scandata`)."""
    w = ArgWriter(binary)
    w.num("u16", sd.version).num("u16", sd.device_number).num("u32", sd.serial)
    w.num("u8", sd.device_status[0]).num("u8", sd.device_status[1])
    w.num("u16", sd.telegram_counter).num("u16", sd.scan_counter)
    w.num("u32", sd.time_since_startup).num("u32", sd.time_of_transmission)
    w.num("u8", sd.inputs[0]).num("u8", sd.inputs[1])
    w.num("u8", sd.outputs[0]).num("u8", sd.outputs[1])
    w.num("i16", sd.reserved).num("u32", sd.scan_frequency).num("u32", sd.measurement_frequency)
    w.num("u16", len(sd.encoders))
    for pos, speed in sd.encoders:
        w.num("u32", pos).num("u16", speed)
    for group, kind in ((sd.channels16, "u16"), (sd.channels8, "u8")):
        w.num("u16", len(group))
        for ch in group:
            w.fixed(ch.name).f32(ch.scale).f32(ch.offset)
            w.num("i32", ch.start_angle).num("u16", ch.step).num("u16", ch.data.size)
            w.array(ch.data, kind)
    if sd.position is None:
        w.num("u16", 0)
    else:
        w.num("u16", 1)
        for v in sd.position[:6]:
            w.f32(v)
        w.num("u8", int(sd.position[6])).num("u8", int(sd.position[7]))
    for text in (sd.name, sd.comment):
        if text is None:
            w.num("u16", 0)
        else:
            w.num("u16", 1).string(text, "u8")
    if sd.timestamp is None:
        w.num("u16", 0)
    else:
        y, mo, d, hh, mm, ss, us = sd.timestamp
        w.num("u16", 1).num("u16", y)
        for v in (mo, d, hh, mm, ss):
            w.num("u8", v)
        w.num("u32", us)
    if sd.event is None:
        w.num("u16", 0)
    else:
        w.num("u16", 1).fixed(sd.event[0]).num("u32", sd.event[1]).num("u32", sd.event[2])
        w.num("i32", sd.event[3])
    head = f"{command or sd.command} LMDscandata ".encode()
    return head + w.getvalue()
