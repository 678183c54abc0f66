"""GNSS fixes from NMEA 0183 over any pyserial URL (``/dev/ttyUSB0``, a pty, ``socket://``).

Three parts, the first two sans-I/O (any bytes give sentences, fixes, None or a typed
:class:`NmeaError`, never another exception, and every buffer is bounded):

- :class:`LineFramer` cuts the byte stream into sentences (``$`` up to CR LF), each
  with the receive time of its last byte; bytes before a ``$`` are line noise and are
  dropped, a line longer than :data:`MAX_LINE` is an error.
- :class:`NmeaDecoder` checks each sentence's checksum and parses it with pynmea2.
  ``RMC`` gives the date (and the speed and course of its epoch); ``GGA`` gives the fix:
  position, altitude, quality, satellites, HDOP, at a full UTC instant made of GGA's
  time of day and the date of the latest RMC (the midnight rollover handled). A GGA
  before any RMC has no date and is skipped (None, counted in ``undated``). Other
  sentences are None.
- :class:`NmeaReceiver` reads the port (one thread) and hands out sentences and fixes.

The fix time is the receiver's measurement instant in UTC, not the host's clock: the
recorder maps it to host monotonic time like a device clock (see :mod:`acq.record.recorder`).
"""

from __future__ import annotations

import datetime as dt
import math
import os
import re
import select
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar

import serial

from acq.drivers.errors import ConnectionLost, ProtocolError, ReadTimeout
from acq.records import DeviceInfo, Fix, Sentence

__all__ = [
    "MAX_LINE",
    "LineFramer",
    "NmeaChecksumError",
    "NmeaDecoder",
    "NmeaError",
    "NmeaReceiver",
    "checksum",
]

MAX_LINE = 256  # bytes; NMEA 0183 allows 82, proprietary sentences run longer
_POLL_S = 0.02  # pyserial read timeout; the driver's own deadline is ``timeout``
_KNOT = 1852.0 / 3600.0  # m/s

_TIME = re.compile(r"(\d\d)(\d\d)(\d\d(?:\.\d{1,9})?)")
_LAT = re.compile(r"(\d\d)(\d\d(?:\.\d{1,12})?)")
_LON = re.compile(r"(\d\d\d)(\d\d(?:\.\d{1,12})?)")
_DATE = re.compile(r"(\d\d)(\d\d)(\d\d)")
_NUMBER = re.compile(r"[+-]?(?:\d{1,12}(?:\.\d{0,12})?|\.\d{1,12})")
_INT = re.compile(r"\d{1,4}")
_ADDRESS = re.compile(r"[A-Z][A-Z0-9]{2,5}")


class NmeaError(ProtocolError):
    """A sentence that does not follow NMEA 0183 (or a field out of its range)."""


class NmeaChecksumError(NmeaError):
    """A sentence whose checksum is wrong or missing."""


def checksum(body: bytes) -> int:
    """XOR of the bytes between ``$`` and ``*``."""
    value = 0
    for b in body:
        value ^= b
    return value


class LineFramer:
    """Bytes in any split -> :class:`acq.records.Sentence` (``$...*hh``, no CR LF)."""

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self.max_line = max_line
        self._buf = bytearray()
        self._skipping = False  # inside an overlong line: drop until its end
        self._ready: deque[Sentence | NmeaError] = deque()
        self.noise_bytes = 0  # bytes that were not part of a sentence

    def feed(self, data: bytes, recv_ns: int) -> None:
        """Add bytes that arrived at ``recv_ns`` (host monotonic ns)."""
        start = 0
        while True:
            end = data.find(b"\n", start)
            if end < 0:
                break
            self._line(bytes(data[start:end]), recv_ns)
            start = end + 1
        rest = data[start:]
        if self._skipping:
            self.noise_bytes += len(rest)
            return
        self._buf += rest
        if len(self._buf) > self.max_line:
            self._ready.append(NmeaError(f"a line longer than {self.max_line} bytes: dropped"))
            self.noise_bytes += len(self._buf)
            self._buf.clear()
            self._skipping = True

    def _line(self, tail: bytes, recv_ns: int) -> None:
        if self._skipping:
            self._skipping = False
            self.noise_bytes += len(tail)
            return
        line = bytes(self._buf) + tail
        self._buf.clear()
        line = line.rstrip(b"\r")
        at = line.rfind(b"$")
        if at < 0:
            self.noise_bytes += len(line)
            if line.strip():
                self._ready.append(NmeaError(f"no sentence in a line of {len(line)} bytes"))
            return
        self.noise_bytes += at
        if len(line) - at > self.max_line:
            self._ready.append(NmeaError(f"a line longer than {self.max_line} bytes: dropped"))
            return
        self._ready.append(Sentence(recv_ns, line[at:]))

    def next(self) -> Sentence | None:
        """The next complete sentence, None when there is none yet; raises NmeaError
        for an overlong or sentence-less line (dropped)."""
        if not self._ready:
            return None
        item = self._ready.popleft()
        if isinstance(item, NmeaError):
            raise item
        return item


# --- fields ------------------------------------------------------------------------------


def _number(text: str, what: str) -> float:
    if not _NUMBER.fullmatch(text):
        raise NmeaError(f"{what}: not a number: {text[:20]!r}")
    return float(text)


def _optional(text: str, what: str) -> float:
    return math.nan if text == "" else _number(text, what)


def _time_of_day(text: str) -> float:
    m = _TIME.fullmatch(text)
    if m is None:
        raise NmeaError(f"time: expected hhmmss.ss, got {text[:20]!r}")
    h, mi, s = int(m[1]), int(m[2]), float(m[3])
    if h > 23 or mi > 59 or s >= 61:
        raise NmeaError(f"time: {text!r} is not a time of day")
    return h * 3600 + mi * 60 + s


def _date(text: str) -> dt.date:
    m = _DATE.fullmatch(text)
    if m is None:
        raise NmeaError(f"date: expected ddmmyy, got {text[:20]!r}")
    yy = int(m[3])
    try:
        return dt.date(2000 + yy if yy < 80 else 1900 + yy, int(m[2]), int(m[1]))
    except ValueError:
        raise NmeaError(f"date: {text!r} is not a date") from None


def _angle(
    value: str, hemisphere: str, pattern: re.Pattern[str], limit: float, hemis: str
) -> float:
    """Degrees from ``(d)ddmm.mmmm`` and N/S or E/W (S and W negative)."""
    m = pattern.fullmatch(value)
    if m is None:
        raise NmeaError(f"position: expected (d)ddmm.mmmm, got {value[:20]!r}")
    degrees, minutes = int(m[1]), float(m[2])
    if minutes >= 60 or degrees + minutes / 60 > limit:
        raise NmeaError(f"position: {value!r} is out of range")
    if hemisphere not in hemis:
        raise NmeaError(
            f"position: hemisphere {hemisphere[:5]!r}, expected {hemis[0]} or {hemis[1]}"
        )
    sign = -1.0 if hemisphere == hemis[1] else 1.0
    return sign * (degrees + minutes / 60)


@dataclass(frozen=True)
class _Rmc:
    date: dt.date
    time_of_day: float
    speed: float  # m/s
    course: float  # rad


class NmeaDecoder:
    """Sentences -> :class:`acq.records.Fix` (see the module doc). ``require_checksum``:
    a sentence without ``*hh`` is an error (receivers send one on every sentence)."""

    def __init__(self, require_checksum: bool = True) -> None:
        self.require_checksum = require_checksum
        self._rmc: _Rmc | None = None
        self.undated = 0  # GGA fixes skipped for want of a date

    def decode(self, sentence: Sentence) -> Fix | None:
        """The fix a sentence completes (GGA), None for any other sentence; raises
        :class:`NmeaChecksumError` or :class:`NmeaError`."""
        import pynmea2

        try:
            text = sentence.data.decode("ascii")
        except UnicodeDecodeError as e:
            raise NmeaError(f"not ASCII (byte {e.start})") from None
        if not text.isprintable():
            raise NmeaError("a control character in the sentence")
        self._check(text)
        address = text[1:].split(",", 1)[0].split("*", 1)[0]
        if not _ADDRESS.fullmatch(address):
            raise NmeaError(f"bad address field {address[:10]!r}")
        kind = address[-3:]
        if address.startswith("P") or kind not in ("GGA", "RMC"):
            return None  # proprietary, or a sentence fixes do not use
        try:
            msg = pynmea2.parse(text, check=self.require_checksum)
        except pynmea2.ChecksumError as e:
            raise NmeaChecksumError(str(e.args[0])) from None
        except (pynmea2.ParseError, ValueError, TypeError, IndexError) as e:
            raise NmeaError(f"{kind}: {e.args[0] if e.args else e}") from None
        if kind == "RMC":
            rmc = self._parse_rmc(msg)
            if rmc is not None:  # one without date or time keeps the last date
                self._rmc = rmc
            return None
        return self._parse_gga(msg, sentence.recv_ns)

    def _check(self, text: str) -> None:
        body, star, given = text[1:].rpartition("*")
        if not star:
            if self.require_checksum:
                raise NmeaChecksumError("no checksum")
            return
        if len(given) != 2 or any(c not in "0123456789ABCDEFabcdef" for c in given):
            raise NmeaChecksumError(f"checksum {given[:4]!r} is not two hex digits")
        computed = checksum(body.encode("ascii"))
        if computed != int(given, 16):
            raise NmeaChecksumError(f"checksum {given.upper()}, computed {computed:02X}")

    @staticmethod
    def _field(msg: Any, name: str) -> str:
        index = type(msg).name_to_idx[name]
        data = msg.data
        return str(data[index]).strip() if index < len(data) else ""

    def _parse_rmc(self, msg: Any) -> _Rmc | None:
        date_text, time_text = self._field(msg, "datestamp"), self._field(msg, "timestamp")
        if not (date_text and time_text):
            return None  # a receiver without time yet
        tod = _time_of_day(time_text)
        speed = _optional(self._field(msg, "spd_over_grnd"), "speed") * _KNOT
        course = math.radians(_optional(self._field(msg, "true_course"), "course"))
        if self._field(msg, "status") != "A":  # void: no fix, no motion either
            speed = course = math.nan
        return _Rmc(_date(date_text), tod, speed, course)

    def _parse_gga(self, msg: Any, recv_ns: int) -> Fix | None:
        f = self._field
        quality_text = f(msg, "gps_qual")
        quality = int(quality_text) if _INT.fullmatch(quality_text) else -1
        if not 0 <= quality <= 9:
            raise NmeaError(f"GGA: fix quality {quality_text[:10]!r}")
        time_text = f(msg, "timestamp")
        if not time_text and quality == 0:
            return None  # no fix and no time yet: nothing to report
        tod = _time_of_day(time_text)
        sats_text = f(msg, "num_sats")
        if sats_text and not _INT.fullmatch(sats_text):
            raise NmeaError(f"GGA: satellites {sats_text[:10]!r}")
        hdop = _optional(f(msg, "horizontal_dil"), "hdop")
        sep = _optional(f(msg, "geo_sep"), "geoid separation")
        if quality == 0:
            lat = lon = alt = math.nan
        else:
            lat = _angle(f(msg, "lat"), f(msg, "lat_dir"), _LAT, 90.0, "NS")
            lon = _angle(f(msg, "lon"), f(msg, "lon_dir"), _LON, 180.0, "EW")
            alt = _number(f(msg, "altitude"), "altitude") + (0.0 if math.isnan(sep) else sep)
        rmc = self._rmc
        if rmc is None:
            self.undated += 1
            return None
        days = rmc.date.toordinal() - _EPOCH_ORDINAL
        if tod < rmc.time_of_day - 43200:  # GGA after midnight, RMC before it
            days += 1
        elif tod > rmc.time_of_day + 43200:
            days -= 1
        same_epoch = abs(tod - rmc.time_of_day) < 1e-3
        return Fix(
            recv_ns=recv_ns,
            utc_s=days * 86400.0 + tod,
            latitude=lat,
            longitude=lon,
            altitude=alt,
            quality=quality,
            satellites=int(sats_text) if sats_text else 0,
            hdop=hdop,
            speed=rmc.speed if same_epoch else math.nan,
            course=rmc.course if same_epoch else math.nan,
            geoid_separation=sep,
        )


_EPOCH_ORDINAL = dt.date(1970, 1, 1).toordinal()


class NmeaReceiver:
    """One GNSS receiver sending NMEA on a pyserial URL (blocking, one thread).

    ``timeout`` (s) is how long :meth:`read_sentence` waits for a complete sentence
    before raising :class:`ReadTimeout` (a 1 Hz receiver needs more than 1 s).
    """

    driver: ClassVar[str] = "nmea"

    def __init__(
        self, url: str, *, baudrate: int = 9600, name: str = "gnss", timeout: float = 3.0
    ) -> None:
        self.url = url
        self.baudrate = baudrate
        self.name = name
        self.timeout = timeout
        self.info: DeviceInfo | None = None
        self.framer = LineFramer()
        self.decoder = NmeaDecoder()
        self.sentences = 0
        self._ser: serial.SerialBase | None = None
        self._fd: int | None = None

    def connect(self) -> DeviceInfo:
        """Open the port (NMEA has no identification to ask for)."""
        self.close()
        try:
            self._ser = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=_POLL_S)
        except (serial.SerialException, OSError, ValueError) as e:
            raise ConnectionLost(f"{self.url}: cannot open: {e}") from e
        # a socket or a POSIX serial port: read the descriptor directly (as acq.drivers.scip)
        fd = getattr(self._ser, "fd", None) if "://" not in self.url else None
        self._fd = self._ser.fileno() if self.url.startswith("socket://") else fd
        self.framer = LineFramer()
        self.decoder = NmeaDecoder()
        self.info = DeviceInfo(
            name=self.name,
            driver=self.driver,
            model="NMEA 0183",
            extra={"url": self.url, "baudrate": str(self.baudrate)},
        )
        return self.info

    def start(self) -> None:
        """Nothing to start: a receiver streams once powered."""
        if self._ser is None:
            raise RuntimeError("connect() first")

    def read_sentence(self) -> Sentence:
        """The next sentence as received; raises ReadTimeout, ConnectionLost, NmeaError
        (an overlong or sentence-less line)."""
        deadline = time.monotonic() + self.timeout
        while True:
            sentence = self.framer.next()
            if sentence is not None:
                self.sentences += 1
                return sentence
            if time.monotonic() >= deadline:
                raise ReadTimeout(f"{self.url}: no NMEA sentence within {self.timeout} s")
            try:
                chunk = self._read_chunk(deadline)
            except (serial.SerialException, OSError) as e:
                raise ConnectionLost(f"{self.url}: {e}") from e
            if chunk:
                self.framer.feed(chunk, time.monotonic_ns())

    def _read_chunk(self, deadline: float) -> bytes:
        if self._ser is None:
            raise ConnectionLost("not connected")
        if self._fd is None:  # other URL handlers
            # types-pyserial types serial_for_url as SerialBase; every handler it returns has
            # in_waiting
            waiting = self._ser.in_waiting  # type: ignore[attr-defined]
            return bytes(self._ser.read(max(1, waiting)))
        wait = min(_POLL_S, max(0.0, deadline - time.monotonic()))
        ready, _, _ = select.select([self._fd], [], [], wait)
        if not ready:
            return b""
        try:
            chunk = os.read(self._fd, 4096)
        except BlockingIOError:
            return b""
        if not chunk:
            raise ConnectionLost(f"{self.url}: closed by the device")
        return chunk

    def decode(self, sentence: Sentence) -> Fix | None:
        """See :meth:`NmeaDecoder.decode`."""
        return self.decoder.decode(sentence)

    def read_fix(self) -> Fix:
        """The next fix (other sentences skipped); raises as :meth:`read_sentence` and
        :meth:`decode`."""
        while True:
            fix = self.decoder.decode(self.read_sentence())
            if fix is not None:
                return fix

    def stop(self) -> None:
        """Nothing to stop (the port stays open)."""

    def close(self) -> None:
        """Close the port; safe to call twice and after a failure."""
        ser, self._ser = self._ser, None
        self._fd = None
        if ser is not None:
            try:
                ser.close()
            except (serial.SerialException, OSError):
                pass

    def __enter__(self) -> NmeaReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
