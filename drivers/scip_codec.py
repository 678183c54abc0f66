"""Pure SCIP 2.0 / 2.2 codec (Hokuyo URG, UTM, UST): framing, checksums, 6-bit encodings.

No I/O here: bytes in, values out. A SCIP reply is LF-terminated lines ending in an empty
line (LF LF): the echo of the command, a status line (2 chars + checksum), then data
lines, each followed by its 1-char checksum (``(sum of bytes & 0x3F) + 0x30``). Measured
values are 2/3/4-character encoded: 6 bits per character, ``char - 0x30``, big-endian.
Scan data lines hold at most 64 data characters and a value may continue on the next line.
Everything malformed raises :class:`acq.drivers.scanner.ProtocolError`; a status the device
sends as an error raises :class:`acq.drivers.scanner.DeviceError`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from acq.drivers.scanner import DeviceError, ProtocolError, ScanGeometry
from acq.records import Scan

__all__ = [
    "SCAN_COMMANDS",
    "RawScan",
    "Reply",
    "ScanEcho",
    "ScipParams",
    "checksum",
    "decode",
    "decode_int",
    "encode",
    "encode_lines",
    "error_table_for",
    "parse_info",
    "parse_reply",
    "parse_scan",
    "parse_scan_echo",
    "parse_scan_reply",
    "parse_time_field",
    "raise_for_status",
    "ranges_to_m",
    "status_message",
]

LF = 0x0A
AMP = 0x26  # '&' separates the echoes of one step in HD/ND/HE/NE data
LINE_DATA = 64  # data characters per scan data line

# command -> (characters per value, has intensity, multi-echo, continuous)
SCAN_COMMANDS: dict[str, tuple[int, bool, bool, bool]] = {
    "MD": (3, False, False, True),
    "MS": (2, False, False, True),
    "ME": (3, True, False, True),
    "ND": (3, False, True, True),
    "NE": (3, True, True, True),
    "GD": (3, False, False, False),
    "GS": (2, False, False, False),
    "GE": (3, True, False, False),
    "HD": (3, False, True, False),
    "HE": (3, True, True, False),
}


# --- checksums and the 6-bit encodings ------------------------------------------------


def checksum(data: bytes) -> int:
    """The SCIP checksum character of ``data``: ``(sum & 0x3F) + 0x30``."""
    return (sum(data) & 0x3F) + 0x30


def encode(values: np.ndarray | list[int], width: int) -> bytes:
    """Non-negative integers (< 64**width) -> ``width``-character SCIP encoding."""
    v = np.asarray(values, dtype=np.int64).reshape(-1)
    if v.size and (v.min() < 0 or v.max() >= 1 << (6 * width)):
        raise ValueError(f"value out of range for {width}-character encoding")
    shifts = np.arange(width - 1, -1, -1, dtype=np.int64) * 6
    chars = ((v[:, None] >> shifts[None, :]) & 0x3F) + 0x30
    return chars.astype(np.uint8).tobytes()


def decode(data: bytes | np.ndarray, width: int) -> np.ndarray:
    """``width``-character SCIP encoding -> (N,) int64; ProtocolError on bad characters."""
    arr = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes | bytearray) else data
    if arr.size % width:
        raise ProtocolError(f"{arr.size} data characters is not a multiple of {width}")
    if arr.size and (arr.min() < 0x30 or arr.max() > 0x6F):
        bad = int(np.flatnonzero((arr < 0x30) | (arr > 0x6F))[0])
        raise ProtocolError(f"invalid encoded character {bytes(arr[bad : bad + 1])!r} at {bad}")
    six = (arr.astype(np.int64) - 0x30).reshape(-1, width)
    out = six[:, 0].copy()
    for k in range(1, width):
        out = (out << 6) | six[:, k]
    return out


def decode_int(data: bytes) -> int:
    """One encoded value (e.g. the 4-character timestamp)."""
    if not data:
        raise ProtocolError("empty encoded value")
    return int(decode(data, len(data))[0])


def encode_lines(data: bytes, width: int = LINE_DATA) -> bytes:
    """Split encoded scan data into checksummed lines of ``width`` characters (each + LF)."""
    out = bytearray()
    for i in range(0, len(data), width):
        chunk = data[i : i + width]
        out += chunk
        out.append(checksum(chunk))
        out.append(LF)
    return bytes(out)


# --- replies ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Reply:
    """One reply: the echoed command, its status (2 chars), the data lines (checksums removed)."""

    echo: bytes
    status: str
    lines: tuple[bytes, ...]
    raw: bytes = b""


def parse_reply(block: bytes, *, info: bool = False, lenient_info: bool = False) -> Reply:
    """A complete reply (echo .. LF LF) -> :class:`Reply`, every checksum verified.

    ``info``: data lines are VV/PP/II ``KEY:value;C`` lines whose checksum covers
    ``KEY:value`` (without the ``;``). ``lenient_info`` accepts a wrong checksum on such a
    line (some URG-04LX firmware sums the ``;`` too, or worse).
    """
    if not block.endswith(b"\n\n"):
        raise ProtocolError("reply does not end with LF LF")
    parts = block[:-2].split(b"\n")
    if len(parts) < 2:
        raise ProtocolError(f"reply has no status line: {block[:40]!r}")
    echo, status_line = parts[0], parts[1]
    if len(status_line) != 3:
        raise ProtocolError(f"status line {status_line!r} of {echo[:16]!r} is not 2 chars + sum")
    if status_line[2] != checksum(status_line[:2]):
        raise ProtocolError(f"bad status checksum in reply to {echo[:16]!r}: {status_line!r}")
    try:
        status = status_line[:2].decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"non-ASCII status {status_line!r}") from None
    lines: list[bytes] = []
    for i, line in enumerate(parts[2:]):
        if len(line) < 2:
            raise ProtocolError(f"data line {i} of reply to {echo[:16]!r} is too short: {line!r}")
        body, cs = line[:-1], line[-1]
        if info:
            core = body[:-1] if body.endswith(b";") else body
            if cs != checksum(core) and not lenient_info:
                raise ProtocolError(f"bad checksum on line {i} of {echo[:16]!r}: {line!r}")
            lines.append(core)
        else:
            if cs != checksum(body):
                raise ProtocolError(f"bad checksum on data line {i} of {echo[:16]!r}")
            lines.append(body)
    return Reply(echo=echo, status=status, lines=tuple(lines), raw=block)


def parse_info(reply: Reply) -> dict[str, str]:
    """VV/PP/II data lines ``KEY:value`` -> {KEY: value}."""
    out: dict[str, str] = {}
    for line in reply.lines:
        key, sep, value = line.partition(b":")
        if not sep:
            raise ProtocolError(f"info line without ':' in {reply.echo!r}: {line!r}")
        out[key.decode("ascii", "replace")] = value.decode("ascii", "replace")
    return out


def parse_time_field(value: str) -> int:
    """II ``TIME``: 6 hex digits (UTM-30LX) or 4 SCIP characters -> ms ticks."""
    try:
        if len(value) == 6:
            return int(value, 16)
        if len(value) == 4:
            return decode_int(value.encode("ascii"))
    except (ValueError, ProtocolError, UnicodeEncodeError):
        pass
    raise ProtocolError(f"unreadable II TIME field {value!r}")


# --- status codes ----------------------------------------------------------------------

_COMMON = {
    "0A": "unable to create transmission data or reply command internally",
    "0B": "buffer shortage, or a command repeated that is already being processed",
    "0C": "command with insufficient parameters (1)",
    "0D": "undefined command (1)",
    "0E": "undefined command (2): not supported by this device or mode",
    "0F": "command with insufficient parameters (2)",
    "0G": "string characters in the command exceed 16 letters",
    "0H": "string characters have invalid letters",
    "0I": "sensor is in firmware update mode",
}
_SCAN_STATUS = {
    "01": "starting step has a non-numeric value",
    "02": "end step has a non-numeric value",
    "03": "cluster count has a non-numeric value",
    "04": "end step is out of range",
    "05": "end step is smaller than starting step",
    "06": "scan interval has a non-numeric value",
    "07": "number of scans has a non-numeric value",
    "10": "laser is off",
    "98": "resumption of process after confirming normal laser operation",
}
_BY_COMMAND: dict[str, dict[str, str]] = {
    "BM": {"01": "unable to control the laser (malfunction)", "02": "laser is already on"},
    "QT": {},
    "RS": {},
    "TM": {
        "01": "invalid control code",
        "02": "adjust mode is already on",
        "03": "adjust mode is already off",
        "04": "adjust mode is off when time was requested",
    },
    "SS": {
        "01": "bit rate has a non-numeric value",
        "02": "invalid bit rate",
        "03": "sensor already runs at this bit rate",
        "04": "not compatible with the sensor (e.g. USB or Ethernet)",
    },
    "RB": {"01": "reboot requested: send RB again to confirm"},
    "HS": {"01": "parameter error", "02": "already in this mode", "03": "not supported"},
}


def status_message(command: str, status: str) -> str:
    """Meaning of a SCIP status for ``command`` (two-letter code, e.g. "MD")."""
    cmd = command[:2]
    if status in _COMMON:
        return _COMMON[status]
    table = _SCAN_STATUS if cmd in SCAN_COMMANDS else _BY_COMMAND.get(cmd, {})
    if status in table:
        return table[status]
    if status.isdigit():
        code = int(status)
        if cmd in SCAN_COMMANDS and 21 <= code <= 49:
            return "processing stopped to verify an error"
        if 50 <= code <= 97:
            return "hardware trouble (laser, motor malfunction etc.)"
    return "unknown status"


def raise_for_status(command: str, status: str, ok: tuple[str, ...] = ("00",)) -> None:
    """DeviceError naming the command, the status and its meaning unless status is in ok."""
    if status not in ok:
        msg = status_message(command, status)
        raise DeviceError(f"{command[:16]}: status {status} ({msg})", status)


# --- device parameters, range conversion -------------------------------------------------


@dataclass(frozen=True)
class ScipParams:
    """PP answer: ranges in mm, angles in steps (ARES steps per turn), motor speed rpm."""

    model: str
    dmin: int
    dmax: int
    ares: int
    amin: int
    amax: int
    afrt: int
    scan_rpm: int

    @classmethod
    def from_info(cls, pp: Mapping[str, str]) -> ScipParams:
        try:
            vals = {k: int(pp[k].strip()) for k in ("DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT")}
            rpm = int(pp["SCAN"].strip())
        except KeyError as e:
            raise ProtocolError(f"PP reply lacks {e.args[0]}") from None
        except ValueError as e:
            raise ProtocolError(f"PP reply has a non-numeric value: {e}") from None
        if vals["ARES"] <= 0 or rpm <= 0 or not 0 <= vals["AMIN"] <= vals["AMAX"]:
            raise ProtocolError(f"PP reply is inconsistent: {dict(pp)}")
        return cls(
            model=pp.get("MODL", ""),
            dmin=vals["DMIN"],
            dmax=vals["DMAX"],
            ares=vals["ARES"],
            amin=vals["AMIN"],
            amax=vals["AMAX"],
            afrt=vals["AFRT"],
            scan_rpm=rpm,
        )

    @property
    def step_angle(self) -> float:
        """rad per step."""
        return 2 * math.pi / self.ares

    @property
    def scan_period(self) -> float:
        """s per turn."""
        return 60.0 / self.scan_rpm

    def angle_of_step(self, step: int) -> float:
        """REP-103 angle of a step, rad (counter-clockwise, 0 at AFRT)."""
        return (step - self.afrt) * self.step_angle

    def steps_for(self, angle_min: float | None, angle_max: float | None) -> tuple[int, int]:
        """(start, end) steps covering [angle_min, angle_max] rad, within AMIN..AMAX."""
        start, end = self.amin, self.amax
        if angle_min is not None:
            start = max(start, math.ceil(angle_min / self.step_angle + self.afrt - 1e-6))
        if angle_max is not None:
            end = min(end, math.floor(angle_max / self.step_angle + self.afrt + 1e-6))
        if start > end:
            raise ValueError(f"angle range [{angle_min}, {angle_max}] rad selects no step")
        return start, end

    @property
    def stamp_step(self) -> int:
        """The step a scan's time stamp refers to: straight behind the sensor (angle
        -pi), where the turn starts; urg_node and Hokuyo's URG library assume the same."""
        return self.afrt - self.ares // 2

    def geometry(self, start: int, end: int, cluster: int = 1, interval: int = 0) -> ScanGeometry:
        """The REP-103 geometry of the points of a scan from step start to end, clustered."""
        c = max(cluster, 1)
        step_dt = self.scan_period / self.ares
        return ScanGeometry(
            angle_min=self.angle_of_step(start),
            angle_increment=c * self.step_angle,
            n_points=-(-(end - start + 1) // c),
            scan_period=self.scan_period * (interval + 1),
            time_increment=c * step_dt,
            range_min=self.dmin / 1000.0,
            range_max=self.dmax / 1000.0,
            stamp_offset_s=(start - self.stamp_step) * step_dt,
        )


INF = math.inf
# values below DMIN are error codes: what each means in REP-117 (+inf no return, -inf
# too close); codes not listed are NaN (a measurement error).
URG_ERRORS: dict[int, float] = {0: INF, 1: INF, 2: INF, 3: INF, 4: INF, 5: INF}
UTM_ERRORS: dict[int, float] = {1: INF, 2: -INF, 4: -INF}


def error_table_for(model: str) -> dict[int, float]:
    """The error-code table of a model (PP MODL or VV PROD string)."""
    name = model.upper()
    if any(k in name for k in ("URG-04LX", "UBG-04LX", "UHG-08LX")):
        return URG_ERRORS
    return UTM_ERRORS


def ranges_to_m(
    mm: np.ndarray, dmin: int, dmax: int, errors: Mapping[int, float] | None = None
) -> np.ndarray:
    """Raw mm values -> float32 metres, REP-117: codes below dmin via ``errors``, > dmax +inf."""
    out = mm.astype(np.float32) * np.float32(0.001)
    low = mm < dmin
    if low.any():
        lut = np.full(max(dmin, 1), np.nan, dtype=np.float32)
        for code, value in (errors if errors is not None else UTM_ERRORS).items():
            if 0 <= code < lut.size:
                lut[code] = value
        out[low] = lut[np.clip(mm[low], 0, lut.size - 1)]
    out[mm > dmax] = np.inf
    return out


# --- scans -------------------------------------------------------------------------------


@dataclass(frozen=True)
class ScanEcho:
    """The echoed scan command: steps, cluster, and for MD/ME/ND/NE interval and scans left."""

    command: str
    start: int
    end: int
    cluster: int
    interval: int = 0
    remaining: int = 0
    text: str = ""  # the optional ";string" of the command

    @property
    def n_points(self) -> int:
        c = max(self.cluster, 1)
        return -(-(self.end - self.start + 1) // c)

    def prefix(self) -> bytes:
        """The echo up to (not including) the remaining-scans field: stable across a stream."""
        s = f"{self.command}{self.start:04d}{self.end:04d}{self.cluster:02d}"
        if SCAN_COMMANDS[self.command][3]:
            s += str(self.interval)
        return s.encode("ascii")


def parse_scan_echo(echo: bytes) -> ScanEcho:
    """``MD0000108001000`` / ``GD0000108001`` (+ optional ``;string``) -> ScanEcho."""
    body, _, text = echo.partition(b";")
    try:
        s = body.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError(f"non-ASCII scan echo {echo[:20]!r}") from None
    cmd = s[:2]
    if cmd not in SCAN_COMMANDS:
        raise ProtocolError(f"not a scan command echo: {echo[:20]!r}")
    continuous = SCAN_COMMANDS[cmd][3]
    if len(s) != (15 if continuous else 12) or not s[2:].isdigit():
        raise ProtocolError(f"malformed {cmd} echo {echo[:20]!r}")
    start, end, cluster = int(s[2:6]), int(s[6:10]), int(s[10:12])
    if end < start:
        raise ProtocolError(f"{cmd} echo has end step {end} < start step {start}")
    interval = int(s[12]) if continuous else 0
    remaining = int(s[13:15]) if continuous else 0
    return ScanEcho(cmd, start, end, cluster, interval, remaining, text.decode("ascii", "replace"))


@dataclass(frozen=True)
class RawScan:
    """A decoded scan reply, device units: mm (codes below DMIN kept), raw intensities.

    ``ranges_mm``/``intensities`` hold the first echo; ``echoes_mm``/``echo_intensities``
    (N, E) all echoes with -1 where a step has fewer (multi-echo commands only).
    """

    echo: ScanEcho
    status: str
    timestamp: int
    ranges_mm: np.ndarray
    intensities: np.ndarray | None = None
    echoes_mm: np.ndarray | None = None
    echo_intensities: np.ndarray | None = None


def _decode_multi_echo(
    data: np.ndarray, n: int, width: int, intensity: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    rec = width * (2 if intensity else 1)
    amp = data == AMP
    vals = data[~amp]
    if vals.size % rec:
        raise ProtocolError(f"multi-echo data of {vals.size} chars is not whole records")
    nrec = vals.size // rec
    if nrec == 0:
        raise ProtocolError("multi-echo scan has no data")
    pos = np.flatnonzero(~amp)[np.arange(nrec) * rec]
    cont = np.zeros(nrec, dtype=bool)
    cont[pos > 0] = amp[pos[pos > 0] - 1]
    if cont[0] or int(cont.sum()) != int(amp.sum()):
        raise ProtocolError("misplaced '&' in multi-echo data")
    firsts = np.flatnonzero(~cont)
    if firsts.size != n:
        raise ProtocolError(f"multi-echo scan has {firsts.size} steps, expected {n}")
    step = np.cumsum(~cont) - 1
    idx = np.arange(nrec) - firsts[step]
    n_echo = int(idx.max()) + 1
    decoded = decode(vals, width).reshape(nrec, 2 if intensity else 1)
    rng = np.full((n, n_echo), -1, dtype=np.int64)
    rng[step, idx] = decoded[:, 0]
    inten = None
    if intensity:
        inten = np.zeros((n, n_echo), dtype=np.int64)
        inten[step, idx] = decoded[:, 1]
    return rng, inten


def parse_scan_reply(block: bytes) -> RawScan:
    """A complete MD/MS/ME/ND/NE (status 99) or GD/GS/GE/HD/HE (status 00) reply -> RawScan.

    DeviceError for an error status, ProtocolError for anything malformed (checksums,
    lengths, characters); never another exception for any input bytes.
    """
    if not block.endswith(b"\n\n"):
        raise ProtocolError("scan telegram does not end with LF LF")
    parts = block[:-2].split(b"\n")
    echo = parse_scan_echo(parts[0])
    if len(parts) < 2 or len(parts[1]) != 3:
        raise ProtocolError(f"scan telegram {parts[0][:16]!r} has no status line")
    st = parts[1]
    if st[2] != checksum(st[:2]):
        raise ProtocolError(f"bad status checksum in scan telegram {parts[0][:16]!r}")
    status = st[:2].decode("ascii", "replace")
    width, intensity, multi, continuous = SCAN_COMMANDS[echo.command]
    expected = "99" if continuous else "00"
    if status != expected:
        if status == "00" and continuous:
            raise ProtocolError(f"{echo.command} acknowledgement (status 00) is not a scan")
        raise_for_status(echo.command, status, ok=(expected,))
    if len(parts) < 4:
        raise ProtocolError(f"scan telegram {parts[0][:16]!r} has no data")
    ts_line = parts[2]
    if len(ts_line) != 5 or ts_line[4] != checksum(ts_line[:4]):
        raise ProtocolError(f"bad timestamp line {ts_line!r}")
    timestamp = decode_int(ts_line[:4])
    chunks = []
    for i, line in enumerate(parts[3:]):
        if len(line) < 2 or len(line) > LINE_DATA + 1:
            raise ProtocolError(f"scan data line {i} has length {len(line)}")
        if line[-1] != checksum(line[:-1]):
            raise ProtocolError(f"bad checksum on scan data line {i}")
        chunks.append(line[:-1])
    data = np.frombuffer(b"".join(chunks), dtype=np.uint8)
    n = echo.n_points
    if multi:
        rng2, int2 = _decode_multi_echo(data, n, width, intensity)
        return RawScan(
            echo,
            status,
            timestamp,
            rng2[:, 0].copy(),
            None if int2 is None else int2[:, 0].copy(),
            rng2,
            int2,
        )
    rec = width * (2 if intensity else 1)
    if data.size != n * rec:
        raise ProtocolError(f"{echo.command} scan has {data.size} data chars, expected {n * rec}")
    vals = decode(data, width)
    if intensity:
        pairs = vals.reshape(n, 2)
        return RawScan(echo, status, timestamp, pairs[:, 0].copy(), pairs[:, 1].copy())
    return RawScan(echo, status, timestamp, vals)


def parse_scan(
    telegram: bytes,
    params: ScipParams,
    *,
    recv_ns: int = 0,
    sequence: int = 0,
    errors: Mapping[int, float] | None = None,
) -> Scan:
    """A complete scan telegram -> :class:`acq.records.Scan` (REP-103 angles, REP-117 m).

    Angles, point timing and period come from ``params`` (PP) and the echoed steps and
    cluster; ``device_ticks`` is the raw 24-bit ms timestamp; ``raw`` the telegram.
    """
    raw = parse_scan_reply(telegram)
    table = errors if errors is not None else error_table_for(params.model)
    e = raw.echo
    geo = params.geometry(e.start, e.end, e.cluster, e.interval)
    ranges = ranges_to_m(raw.ranges_mm, params.dmin, params.dmax, table)
    intens = (
        raw.intensities.astype(np.float32)
        if raw.intensities is not None
        else np.empty(0, np.float32)
    )
    extra = extra_i = None
    if raw.echoes_mm is not None:
        more = raw.echoes_mm[:, 1:]
        extra = ranges_to_m(more, params.dmin, params.dmax, table)
        extra[more < 0] = np.inf
        if raw.echo_intensities is not None:
            extra_i = raw.echo_intensities[:, 1:].astype(np.float32)
    return Scan(
        ranges=ranges,
        intensities=intens,
        angle_min=geo.angle_min,
        angle_increment=geo.angle_increment,
        time_increment=geo.time_increment,
        scan_period=geo.scan_period,
        recv_ns=recv_ns,
        device_ticks=(raw.timestamp,),
        sequence=sequence,
        raw=bytes(telegram),
        extra_echoes=extra,
        extra_intensities=extra_i,
    )
