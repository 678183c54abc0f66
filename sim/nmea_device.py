"""A simulated GNSS receiver: NMEA 0183 from the vehicle's true trajectory, on a pty.

The receiver's antenna rides on the vehicle of a :class:`acq.sim.world.Trajectory` (from
``t_origin``, host monotonic s, like the other simulated devices; looping every
``loop_s`` when given). The street's world frame (x along the street, y left, z up)
lies on the local tangent plane at ``origin`` (WGS-84 latitude, longitude in degrees,
height above mean sea level in m; the geoid lies ``geoid_separation`` m above the
ellipsoid there), with +x pointing ``bearing_deg`` clockwise from north. ENU -> WGS-84
is exact (:class:`acq.geometry.geodesy.WorldFrame`, pyproj's topocentric conversion).

Fix epochs fall on whole multiples of ``1 / rate_hz`` of UTC (as a receiver's do);
UTC is host monotonic time plus ``utc_offset_s`` (by default what the host's wall
clock says at start; a test can make the receiver's time disagree with the host's).
Each epoch's sentences go out ``latency_s`` plus an exponential jitter of mean
``jitter_s`` after the epoch, in the order ``sentences`` names them (any of RMC, VTG,
GGA, GST, GSA; RMC, VTG, GGA by default); ``rmc_motion=False`` leaves RMC's speed and
course empty (a receiver that sends them in VTG only). GST reports ``gst_sigma`` (m,
latitude, longitude, altitude 1-sigma), GSA ``hdop`` and ``vdop``. Optional Gaussian
noise (``noise_m`` east and north, ``noise_up_m`` up) is added to the reported position,
not to the truth.

:class:`NmeaPtyServer` serves it on a pseudo-terminal (``acq.sim.transport``'s
machinery); output that no client reads is dropped, as a UART overruns, rather than
queued, so a client that opens the port gets current fixes.
"""

from __future__ import annotations

import fcntl
import math
import struct
import termios
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acq.geometry.geodesy import WorldFrame
from acq.sim.transport import PtyDeviceServer
from acq.sim.world import Trajectory

__all__ = ["DEFAULT_ORIGIN", "FixTruth", "NmeaDevice", "NmeaPtyServer"]

DEFAULT_ORIGIN = (48.8584, 2.2945, 35.0)  # Paris, Champ de Mars: lat, lon deg, m above MSL
DEFAULT_GEOID_SEPARATION = 44.6  # m, EGM96 near Paris
_KNOT = 1852.0 / 3600.0  # m/s
_H = 1e-3  # s, central differences


@dataclass(frozen=True)
class FixTruth:
    """One epoch the receiver reported, and the truth behind it."""

    t: float  # host monotonic s of the epoch (the fix instant)
    utc_s: float  # the fix time the sentences carry
    latitude: float  # true antenna position, degrees
    longitude: float
    altitude: float  # m above the ellipsoid
    speed: float  # m/s over ground
    course: float  # rad clockwise from north
    reported: tuple[float, float, float]  # latitude, longitude, altitude sent (noise added)
    t_sent: float = 0.0  # host monotonic s its sentences were made, then written


def _geodetic(frame: WorldFrame, e: float, n: float, u: float) -> tuple[float, float, float]:
    """(lat deg, lon deg, h m above the ellipsoid) of one point of an ENU ``frame``."""
    lat, lon, h = frame.to_geodetic([e, n, u])
    return float(lat[0]), float(lon[0]), float(h[0])


def _ddmm(value: float, degree_digits: int, decimals: int, hemis: str) -> tuple[str, str]:
    hemi = hemis[0] if value >= 0 else hemis[1]
    value = abs(value)
    scale = 10**decimals
    total = round(value * 60 * scale)  # minutes, in units of the last digit
    degrees, minutes = divmod(total, 60 * scale)
    text = f"{degrees:0{degree_digits}d}{minutes // scale:02d}.{minutes % scale:0{decimals}d}"
    return text, hemi


def sentence(body: str, corrupt: bool = False) -> bytes:
    """``$body*hh`` CR LF (a wrong checksum with ``corrupt``)."""
    value = 0
    for b in body.encode("ascii"):
        value ^= b
    if corrupt:
        value ^= 0x5A
    return f"${body}*{value:02X}\r\n".encode("ascii")


class NmeaDevice:
    """The receiver's protocol side (a :class:`acq.sim.transport.SimDevice`): it streams, it
    ignores what it is sent. :attr:`truth` keeps the last ``truth_limit`` epochs."""

    def __init__(
        self,
        trajectory: Trajectory | None = None,
        *,
        rate_hz: float = 10.0,
        origin: tuple[float, float, float] = DEFAULT_ORIGIN,
        geoid_separation: float = DEFAULT_GEOID_SEPARATION,
        bearing_deg: float = 90.0,
        antenna: tuple[float, float, float] = (0.0, 0.0, 1.9),
        noise_m: float = 0.0,
        noise_up_m: float = 0.0,
        latency_s: float = 0.040,
        jitter_s: float = 0.003,
        quality: int = 1,
        satellites: int = 14,
        hdop: float = 0.7,
        vdop: float = 1.1,
        sentences: tuple[str, ...] = ("RMC", "VTG", "GGA"),
        rmc_motion: bool = True,
        gst_sigma: tuple[float, float, float] = (0.012, 0.009, 0.025),
        talker: str = "GN",
        decimals: int = 7,
        t_origin: float | None = None,
        utc_offset_s: float | None = None,
        loop_s: float | None = None,
        seed: int = 0,
        truth_limit: int = 100_000,
    ) -> None:
        if not 0 < rate_hz <= 20:
            raise ValueError(f"rate_hz must be in (0, 20], got {rate_hz}")
        self.trajectory = trajectory if trajectory is not None else Trajectory()
        self.rate_hz = rate_hz
        self.origin = origin
        self.geoid_separation = geoid_separation
        self.bearing = math.radians(bearing_deg)
        self.antenna = np.asarray(antenna, dtype=np.float64)
        self.noise_m = noise_m
        self.noise_up_m = noise_up_m
        self.latency_s = latency_s
        self.jitter_s = jitter_s
        self.quality = quality
        self.satellites = satellites
        self.hdop = hdop
        self.vdop = vdop
        unknown = set(sentences) - {"RMC", "VTG", "GGA", "GST", "GSA"}
        if unknown:
            raise ValueError(f"sentences: unknown {sorted(unknown)}")
        self.sentences = sentences
        self.rmc_motion = rmc_motion
        self.gst_sigma = gst_sigma
        self.talker = talker
        self.decimals = decimals
        self.t_origin = time.monotonic() if t_origin is None else t_origin
        if utc_offset_s is None:
            utc_offset_s = time.time() - time.monotonic()
        self.utc_offset_s = utc_offset_s
        self.loop_s = loop_s
        self._truth: deque[FixTruth] = deque(maxlen=truth_limit)
        self._truth_lock = threading.Lock()  # the serving thread appends, tests read
        self._enu = WorldFrame("enu", (origin[0], origin[1], origin[2] + geoid_separation))
        self._rng = np.random.default_rng(seed)
        self._k = math.floor((self.t_origin + utc_offset_s) * rate_hz) + 1  # next epoch
        self._due = self._due_of(self._k)
        self._corrupt = 0
        self._no_fix_until = -math.inf

    # --- the truth -------------------------------------------------------------------

    @property
    def truth(self) -> list[FixTruth]:
        """The epochs reported so far (the last ``truth_limit``), oldest first."""
        with self._truth_lock:
            return list(self._truth)

    def _due_of(self, k: int) -> float:
        jitter = (
            min(self._rng.exponential(self.jitter_s), 4 * self.jitter_s) if self.jitter_s else 0
        )
        return self._utc(k) - self.utc_offset_s + self.latency_s + float(jitter)

    def _enu_at(self, t: float) -> np.ndarray:
        """Antenna position (E, N, U) in m at host time t."""
        dt = t - self.t_origin
        td = dt % self.loop_s if self.loop_s else dt
        R, tr = self.trajectory.poses(np.array([td]))
        x, y, z = R[0] @ self.antenna + tr[0]
        sb, cb = math.sin(self.bearing), math.cos(self.bearing)
        return np.array([x * sb - y * cb, x * cb + y * sb, z])

    def truth_at(self, t: float) -> FixTruth:
        """The true fix at host monotonic time t (nothing reported)."""
        p = self._enu_at(t)
        v = (self._enu_at(t + _H) - self._enu_at(t - _H)) / (2 * _H)
        lat, lon, h = _geodetic(self._enu, *p)
        course = math.atan2(v[0], v[1]) % (2 * math.pi)
        return FixTruth(t, t + self.utc_offset_s, lat, lon, h, float(math.hypot(v[0], v[1])),
                        course, (lat, lon, h))  # fmt: skip

    # --- sentences -------------------------------------------------------------------

    def _utc(self, k: int) -> float:
        """UTC s of epoch k (to the hundredth NMEA times carry)."""
        return round(k * 100 / self.rate_hz) / 100

    def _epoch(self, k: int, now: float) -> bytes:
        utc = self._utc(k)
        t = utc - self.utc_offset_s
        truth = self.truth_at(t)
        fix = now >= self._no_fix_until and self.quality > 0
        e, n, u = self._enu_at(t)
        if self.noise_m or self.noise_up_m:
            de, dn = self._rng.normal(0.0, self.noise_m, 2)
            e, n, u = e + de, n + dn, u + self._rng.normal(0.0, self.noise_up_m)
        lat, lon, h = _geodetic(self._enu, e, n, u)
        truth = FixTruth(truth.t, utc, truth.latitude, truth.longitude, truth.altitude,
                         truth.speed, truth.course, (lat, lon, h), now)  # fmt: skip
        stamp = time.gmtime(math.floor(utc + 1e-9))
        frac = round((utc - math.floor(utc + 1e-9)) * 100)
        hms = f"{stamp.tm_hour:02d}{stamp.tm_min:02d}{stamp.tm_sec:02d}.{frac:02d}"
        date = f"{stamp.tm_mday:02d}{stamp.tm_mon:02d}{stamp.tm_year % 100:02d}"
        la, ns = _ddmm(lat, 2, self.decimals, "NS")
        lo, ew = _ddmm(lon, 3, self.decimals, "EW")
        knots = truth.speed / _KNOT
        course = math.degrees(truth.course)
        msl = h - self.geoid_separation
        tk = self.talker
        sn, se, su = self.gst_sigma
        motion = f"{knots:.3f},{course:.2f}" if self.rmc_motion else ","
        if fix:
            bodies = {
                "RMC": f"RMC,{hms},A,{la},{ns},{lo},{ew},{motion},{date},,,A",
                "VTG": f"VTG,{course:.2f},T,,M,{knots:.3f},N,{knots * 1.852:.3f},K,A",
                "GGA": (f"GGA,{hms},{la},{ns},{lo},{ew},{self.quality},{self.satellites:02d},"
                        f"{self.hdop:.2f},{msl:.3f},M,{self.geoid_separation:.3f},M,,"),
                "GST": f"GST,{hms},0.1,,,,{sn:.3f},{se:.3f},{su:.3f}",
                "GSA": f"GSA,A,3,01,02,03,04,,,,,,,,,{self.hdop * 1.5:.2f},{self.hdop:.2f},"
                       f"{self.vdop:.2f}",
            }  # fmt: skip
            with self._truth_lock:
                self._truth.append(truth)
        else:
            bodies = {
                "RMC": f"RMC,{hms},V,,,,,,,{date},,,N",
                "VTG": "VTG,,T,,M,,N,,K,N",
                "GGA": f"GGA,{hms},,,,,0,00,99.99,,,,,,",
                "GST": f"GST,{hms},,,,,,,",
                "GSA": "GSA,A,1,,,,,,,,,,,,,99.99,99.99,99.99",
            }
        out = b""
        for kind in self.sentences:
            out += sentence(tk + bodies[kind], corrupt=self._corrupt > 0)
            self._corrupt = max(self._corrupt - 1, 0)
        return out

    # --- SimDevice -------------------------------------------------------------------

    def handle(self, data: bytes, now: float) -> bytes:
        return b""  # configuration commands are not simulated

    def poll(self, now: float) -> bytes:
        out = b""
        if now - self._due > 1.0:  # fell behind (a stall): resume with the current epoch
            self._k = math.floor((now + self.utc_offset_s) * self.rate_hz)
            self._due = self._due_of(self._k)
        while self._due <= now:
            out += self._epoch(self._k, now)
            self._k += 1
            self._due = self._due_of(self._k)
        return out

    def next_due(self, now: float) -> float | None:
        return self._due

    def on_disconnect(self) -> None:
        pass  # a receiver streams whether anyone listens or not

    def reboot(self, now: float) -> None:
        """A restart: no fix for 2 s after ``now`` (a warm start)."""
        self._no_fix_until = now + 2.0

    def corrupt_next(self) -> None:
        """The next sentence gets a wrong checksum."""
        self._corrupt += 1


class NmeaPtyServer(PtyDeviceServer):
    """:class:`NmeaDevice` on a pty; output is dropped while more than ``backlog`` bytes
    wait unread (nobody has the port open), and counted in ``overruns``."""

    def __init__(
        self,
        device: NmeaDevice,
        link: str | Path | None = None,
        seed: int = 0,
        backlog: int = 1024,
    ) -> None:
        super().__init__(device, link, seed)
        self.backlog = backlog
        self.overruns = 0

    def _write(self, fd: int, data: bytes) -> None:
        slave = self._slave
        if slave is not None:
            try:
                raw = fcntl.ioctl(slave, termios.FIONREAD, b"\0" * 4)
                if struct.unpack("i", raw)[0] > self.backlog:
                    self.overruns += 1
                    return
            except OSError:
                pass
        super()._write(fd, data)
