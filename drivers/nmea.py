"""GNSS fixes from NMEA 0183 over any pyserial URL (``/dev/ttyUSB0``, a pty, ``socket://``).

Three parts, the first two sans-I/O (any bytes give sentences, fixes, None or a typed
:class:`NmeaError`, never another exception, and every buffer is bounded):

- :class:`LineFramer` cuts the byte stream into sentences (``$`` up to CR LF), each
  with the receive time of its last byte; bytes before a ``$`` are line noise and are
  dropped, a line longer than :data:`MAX_LINE` is an error.
- :class:`NmeaDecoder` checks each sentence's checksum, parses it with pynmea2 and
  merges the GGA, RMC, VTG, GST and GSA of one epoch into one fix, in whatever order and
  grouping the receiver sends them. An epoch is the sentences with one UTC time of fix
  (GGA, RMC, GST); VTG and GSA carry no time and join the epoch they arrive in: the open
  one, unless it has one of their kind already (outside a run of GSA, one per
  constellation), then the next; after the open one was given out, the next, unless it
  is of a kind that epoch lacked or continues its run (then it was late). GGA gives the
  position, altitude, quality, satellites and HDOP; RMC the date (the latest one serves
  epochs without, the midnight rollover handled) and the speed and course, VTG them when
  RMC does not; GST the position's sigmas (covariance DIAGONAL_KNOWN), else HDOP and
  GSA's VDOP times :data:`UERE_M` (APPROXIMATED), else none (UNKNOWN). An epoch without
  GGA or without any date gives no fix.

  When a fix is given out: as soon as its epoch holds every kind of sentence the
  receiver's last whole epoch held (so, in steady state, with the epoch's last
  sentence: no latency), else when the next epoch's first timed sentence arrives (one
  epoch late: the first fix, and when a receiver stops sending a kind), else by
  :meth:`NmeaDecoder.flush` at the end of a stream. Waiting for a fixed list instead
  would lose GST or VTG from receivers that send them, or wait forever on those that
  do not. A sentence of an epoch already given out is dropped (counted in ``late``)
  and waited for from then on: a fix is never given out twice. :meth:`NmeaReceiver.
  read_fix` flushes when the receiver falls silent for its ``timeout``.
- :class:`NmeaReceiver` reads the port (one thread) and hands out sentences and fixes.

The fix time (:attr:`acq.records.Fix.utc_s`) is the receiver's measurement instant in
UTC, not the host's clock; :attr:`acq.records.Fix.recv_ns` is the receipt of the sentence
that completed the fix. The recorder stamps a fix from its fix time through the host's
UTC clock when that clock is disciplined, else maps the fix time to host monotonic time
like a device clock through the receipt times (see :class:`acq.record.adapters.GnssAdapter`).
"""

from __future__ import annotations

import datetime as dt
import math
import os
import re
import select
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, ClassVar

import serial

from acq.drivers.errors import ConnectionLost, ProtocolError, ReadTimeout
from acq.records import CovarianceType, DeviceInfo, Fix, Sentence

__all__ = [
    "MAX_LINE",
    "UERE_M",
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
# The user equivalent range error (1-sigma, m) of a single-frequency code solution, for
# sigmas from DOPs when the receiver sends no GST: the 4 m that ROS's nmea_navsat_driver
# takes for a plain GPS fix (Kaplan & Hegarty, Understanding GPS, budget ~4-5 m).
UERE_M = 4.0

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
    date: dt.date | None
    time_of_day: float
    speed: float  # m/s
    course: float  # rad


@dataclass(frozen=True)
class _Gga:
    time_of_day: float
    latitude: float
    longitude: float
    altitude: float
    quality: int
    satellites: int
    hdop: float
    geoid_separation: float


@dataclass(eq=False)
class _Epoch:
    """The sentences of one fix epoch gathered so far."""

    time_of_day: float | None = None  # None until a timed sentence (GGA, RMC, GST)
    kinds: Counter[str] = field(default_factory=Counter)  # sentences of each kind
    recv_ns: int = 0  # receipt of its latest sentence
    gga: _Gga | None = None
    rmc: _Rmc | None = None
    vtg: tuple[float, float] | None = None  # speed m/s, course rad
    gst: tuple[float, float, float] | None = None  # sigma north, east, up, m
    gsa: tuple[float, float] | None = None  # HDOP, VDOP


_KINDS = frozenset({"GGA", "RMC", "GST", "VTG", "GSA"})
_SAME_S = 1e-3  # two times of day closer than this are one epoch


class NmeaDecoder:
    """Sentences -> :class:`acq.records.Fix`: the GGA, RMC, VTG, GST and GSA of one epoch
    merged into one fix, whatever their order (see the module doc). ``require_checksum``:
    a sentence without ``*hh`` is an error (receivers send one on every sentence).
    ``uere_m``: the user equivalent range error (1-sigma, m) that turns DOPs into sigmas
    when the receiver sends no GST (:data:`UERE_M`)."""

    def __init__(self, require_checksum: bool = True, uere_m: float = UERE_M) -> None:
        self.require_checksum = require_checksum
        self.uere_m = uere_m
        self._date: tuple[dt.date, float] | None = None  # the latest RMC's date, time of day
        self._open = _Epoch()
        self._held = _Epoch()  # untimed sentences after the open epoch's: the next one's
        self._expected: Counter[str] = Counter()  # what a whole epoch holds
        self._last: tuple[str, _Epoch] | None = None  # the last sentence filed: kind, epoch
        self._emitted: float | None = None  # time of day of the last epoch given out
        self._out: _Epoch | None = None  # the last epoch, if given out once complete
        self._ready: deque[Fix] = deque()
        self.undated = 0  # fixes skipped for want of a date
        self.late = 0  # timed sentences of an epoch already given out (dropped)

    def decode(self, sentence: Sentence) -> Fix | None:
        """The fix this sentence completes, None when none is complete; raises
        :class:`NmeaChecksumError` or :class:`NmeaError` (the epoch is kept)."""
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
        if address.startswith("P") or kind not in _KINDS:
            return self._next_ready()  # proprietary, or a sentence fixes do not use
        try:
            msg = pynmea2.parse(text, check=self.require_checksum)
        except pynmea2.ChecksumError as e:
            raise NmeaChecksumError(str(e.args[0])) from None
        except (pynmea2.ParseError, ValueError, TypeError, IndexError) as e:
            raise NmeaError(f"{kind}: {e.args[0] if e.args else e}") from None
        self._file(kind, msg, sentence.recv_ns)
        return self._next_ready()

    def flush(self) -> list[Fix]:
        """The fixes still held, the open epoch's even if incomplete (at the end of a
        stream, or when it pauses); decoding may go on after."""
        if self._open.time_of_day is not None:
            self._close()
        out = list(self._ready)
        self._ready.clear()
        return out

    def _next_ready(self) -> Fix | None:
        return self._ready.popleft() if self._ready else None

    # --- epochs -------------------------------------------------------------------------

    def _file(self, kind: str, msg: Any, recv_ns: int) -> None:
        """Parse one sentence (raising before any state changes), add it to its epoch,
        give out the epochs it completes."""
        value: Any
        tod: float | None = None
        if kind == "GGA":
            value = self._parse_gga(msg)
            tod = None if value is None else value.time_of_day
        elif kind == "RMC":
            value = self._parse_rmc(msg)
            tod = None if value is None else value.time_of_day
        elif kind == "GST":
            value = self._parse_gst(msg)
            tod = None if value is None else value[0]
            value = None if value is None else value[1]
        elif kind == "VTG":
            value = self._parse_vtg(msg)
        else:
            value = self._parse_gsa(msg)
        if kind == "RMC" and value is not None and value.date is not None:
            self._date = (value.date, value.time_of_day)
        if value is None:
            return  # a receiver without time yet
        epoch = self._open
        if tod is not None:
            if self._emitted is not None and abs(tod - self._emitted) < _SAME_S:
                self.late += 1  # its epoch is out: wait for this kind from now on
                self._expected[kind] = max(self._expected[kind], 1)
                return
            if epoch.time_of_day is not None and abs(tod - epoch.time_of_day) >= _SAME_S:
                self._expected = Counter(epoch.kinds)  # a whole epoch, as this receiver sends
                self._close()
                self._out = None
                epoch = self._open
            epoch.time_of_day = tod
        elif self._straggler(kind):
            return
        elif self._held.kinds or epoch.kinds[kind]:
            # after the next epoch's, or of a kind the open epoch has and not in a run of
            # its kind (one GSA per constellation in a row): the next epoch's
            in_run = self._last is not None and self._last[0] == kind and self._last[1] is epoch
            epoch = epoch if in_run and not self._held.kinds else self._held
        setattr(epoch, kind.lower(), value)
        epoch.kinds[kind] += 1
        epoch.recv_ns = recv_ns
        self._last = (kind, epoch)
        epoch = self._open
        if self._expected and epoch.gga is not None and self._expected <= epoch.kinds:
            self._close()
            self._out = epoch

    def _straggler(self, kind: str) -> bool:
        """Whether an untimed sentence that comes after its epoch was given out (and
        before any of the next epoch) belongs to it: one more of a run of its kind, or
        a kind that epoch lacked. It is dropped (counted in ``late``) and waited for
        from then on; any other is the next epoch's."""
        out = self._out
        if out is None or self._open.kinds:
            return False
        run = self._last is not None and self._last[0] == kind and self._last[1] is out
        if not (run or out.kinds[kind] == 0):
            return False
        self.late += 1
        out.kinds[kind] += 1
        self._expected[kind] = max(self._expected[kind], out.kinds[kind])
        self._last = (kind, out)
        return True

    def _close(self) -> None:
        """Give out the open epoch's fix (if it has a GGA); the next epoch starts with
        what was held for it."""
        epoch, self._open, self._held = self._open, self._held, _Epoch()
        self._emitted = epoch.time_of_day
        fix = self._fix(epoch)
        if fix is not None:
            self._ready.append(fix)

    def _fix(self, epoch: _Epoch) -> Fix | None:
        gga = epoch.gga
        if gga is None:
            return None  # no position
        tod = gga.time_of_day
        if epoch.rmc is not None and epoch.rmc.date is not None:
            date, date_tod = epoch.rmc.date, epoch.rmc.time_of_day
        elif self._date is not None:
            date, date_tod = self._date
        else:
            self.undated += 1
            return None
        days = date.toordinal() - _EPOCH_ORDINAL
        if tod < date_tod - 43200:  # GGA after midnight, RMC before it
            days += 1
        elif tod > date_tod + 43200:
            days -= 1
        speed = course = math.nan
        if epoch.rmc is not None:
            speed, course = epoch.rmc.speed, epoch.rmc.course
        if epoch.vtg is not None:
            speed = speed if math.isfinite(speed) else epoch.vtg[0]
            course = course if math.isfinite(course) else epoch.vtg[1]
        hdop, vdop = gga.hdop, math.nan
        if epoch.gsa is not None:
            hdop = hdop if math.isfinite(hdop) else epoch.gsa[0]
            vdop = epoch.gsa[1]
        north = east = up = math.nan
        kind = CovarianceType.UNKNOWN
        if gga.quality == 0:
            pass  # no position, no accuracy
        elif epoch.gst is not None and all(math.isfinite(s) for s in epoch.gst):
            (north, east, up), kind = epoch.gst, CovarianceType.DIAGONAL_KNOWN
        elif math.isfinite(hdop):
            # HDOP^2 = (sigma_e^2 + sigma_n^2) / UERE^2, shared equally by the two axes
            north = east = hdop * self.uere_m / math.sqrt(2)
            # without VDOP: twice HDOP, as ROS's nmea_navsat_driver assumes
            up = (vdop if math.isfinite(vdop) else 2 * hdop) * self.uere_m
            kind = CovarianceType.APPROXIMATED
        return Fix(
            recv_ns=epoch.recv_ns,
            utc_s=days * 86400.0 + tod,
            latitude=gga.latitude,
            longitude=gga.longitude,
            altitude=gga.altitude,
            quality=gga.quality,
            satellites=gga.satellites,
            hdop=hdop,
            speed=speed,
            course=course,
            geoid_separation=gga.geoid_separation,
            vdop=vdop,
            sigma_east=east,
            sigma_north=north,
            sigma_up=up,
            covariance_type=int(kind),
        )

    # --- sentences ----------------------------------------------------------------------

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
        if not time_text:
            return None  # a receiver without time yet
        tod = _time_of_day(time_text)
        date = _date(date_text) if date_text else None
        speed = _optional(self._field(msg, "spd_over_grnd"), "speed") * _KNOT
        course = math.radians(_optional(self._field(msg, "true_course"), "course"))
        if self._field(msg, "status") != "A":  # void: no fix, no motion either
            speed = course = math.nan
        return _Rmc(date, tod, speed, course)

    def _parse_vtg(self, msg: Any) -> tuple[float, float] | None:
        f = self._field
        course = math.radians(_optional(f(msg, "true_track"), "course"))
        speed = _optional(f(msg, "spd_over_grnd_kts"), "speed") * _KNOT
        if math.isnan(speed):
            speed = _optional(f(msg, "spd_over_grnd_kmph"), "speed") / 3.6
        if f(msg, "faa_mode") == "N":  # not valid
            speed = course = math.nan
        return speed, course

    def _parse_gst(self, msg: Any) -> tuple[float, tuple[float, float, float]] | None:
        f = self._field
        time_text = f(msg, "timestamp")
        if not time_text:
            return None
        tod = _time_of_day(time_text)
        sigmas = tuple(
            _optional(f(msg, name), "GST sigma")
            for name in ("std_dev_latitude", "std_dev_longitude", "std_dev_altitude")
        )
        if any(s < 0 for s in sigmas):
            raise NmeaError(f"GST: a negative sigma {sigmas}")
        return tod, (sigmas[0], sigmas[1], sigmas[2])

    def _parse_gsa(self, msg: Any) -> tuple[float, float]:
        f = self._field
        hdop, vdop = _optional(f(msg, "hdop"), "hdop"), _optional(f(msg, "vdop"), "vdop")
        if hdop < 0 or vdop < 0:
            raise NmeaError(f"GSA: a negative DOP ({hdop}, {vdop})")
        return hdop, vdop

    def _parse_gga(self, msg: Any) -> _Gga | None:
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
        sats = int(sats_text) if sats_text else 0
        return _Gga(tod, lat, lon, alt, quality, sats, hdop, sep)


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
        self._flushed: deque[Fix] = deque()  # fixes flushed when the receiver fell silent
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
        late = False  # past the deadline, what has already arrived is still read once
        while True:
            sentence = self.framer.next()
            if sentence is not None:
                self.sentences += 1
                return sentence
            if late:
                raise ReadTimeout(f"{self.url}: no NMEA sentence within {self.timeout} s")
            late = time.monotonic() >= deadline
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
        :meth:`decode`. When the receiver falls silent, the epoch it was sending is given
        out before ReadTimeout is raised."""
        while True:
            if self._flushed:
                return self._flushed.popleft()
            try:
                sentence = self.read_sentence()
            except ReadTimeout:
                self._flushed.extend(self.decoder.flush())
                if not self._flushed:
                    raise
                continue
            fix = self.decoder.decode(sentence)
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
