"""GPS time and UTC: leap seconds, GPS week and seconds of week, and the Adjusted
Standard GPS time that LAS 1.4 files carry (global encoding bit 0 set).

UTC instants are POSIX seconds (float64, seconds since 1970-01-01 UTC without leap
seconds, what ``time.time()`` and ``acq.time.utc.utc_seconds`` give). GPS time runs
without leap seconds from 1980-01-06 00:00:00 UTC; ``GPS - UTC`` grows by one second at
each leap second (18 s since 2017-01-01). Adjusted Standard GPS time is GPS seconds
minus 1e9.

The table :data:`LEAP_SECONDS` ends with the leap second of 2016-12-31; IERS Bulletin C
had announced none after it when this was written. A new one needs a line here: times
after it would otherwise be one second off.
"""

from __future__ import annotations

import calendar

import numpy as np
import numpy.typing as npt

__all__ = [
    "GPS_EPOCH_UNIX",
    "LEAP_SECONDS",
    "SECONDS_PER_WEEK",
    "gps_adjusted_standard_time",
    "gps_minus_utc",
    "gps_to_utc",
    "gps_week_sow_to_utc",
    "utc_from_adjusted_standard_time",
    "utc_to_gps",
    "utc_to_gps_week_sow",
]

GPS_EPOCH_UNIX = 315_964_800  # 1980-01-06T00:00:00Z, POSIX seconds
SECONDS_PER_WEEK = 604_800
ADJUSTED_OFFSET_S = 1e9  # Adjusted Standard GPS time = GPS seconds - 1e9

# (first UTC day with the new offset, GPS - UTC from then on, s)
LEAP_SECONDS: tuple[tuple[str, int], ...] = (
    ("1981-07-01", 1),
    ("1982-07-01", 2),
    ("1983-07-01", 3),
    ("1985-07-01", 4),
    ("1988-01-01", 5),
    ("1990-01-01", 6),
    ("1991-01-01", 7),
    ("1992-07-01", 8),
    ("1993-07-01", 9),
    ("1994-07-01", 10),
    ("1996-01-01", 11),
    ("1997-07-01", 12),
    ("1999-01-01", 13),
    ("2006-01-01", 14),
    ("2009-01-01", 15),
    ("2012-07-01", 16),
    ("2015-07-01", 17),
    ("2017-01-01", 18),
)

_UTC_STEPS = np.array(
    [calendar.timegm((int(d[:4]), int(d[5:7]), int(d[8:10]), 0, 0, 0)) for d, _ in LEAP_SECONDS],
    dtype=np.float64,
)
_OFFSETS = np.array([0] + [n for _, n in LEAP_SECONDS], dtype=np.float64)
# the first GPS second (since the GPS epoch) that carries each new offset
_GPS_STEPS = _UTC_STEPS - GPS_EPOCH_UNIX + _OFFSETS[1:]


def gps_minus_utc(utc_s: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """GPS - UTC, whole seconds (float64), at UTC instants (POSIX s); 0 before 1981-07."""
    u = np.asarray(utc_s, dtype=np.float64)
    return _OFFSETS[np.searchsorted(_UTC_STEPS, u, side="right")]


def utc_to_gps(utc_s: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """UTC (POSIX s) -> GPS seconds since the GPS epoch (float64)."""
    u = np.asarray(utc_s, dtype=np.float64)
    return u - GPS_EPOCH_UNIX + gps_minus_utc(u)


def gps_to_utc(gps_s: npt.ArrayLike) -> np.ndarray:
    """GPS seconds since the GPS epoch -> UTC (POSIX s), the inverse of :func:`utc_to_gps`
    (a leap second itself, which POSIX time cannot name, maps onto the second after it)."""
    g = np.asarray(gps_s, dtype=np.float64)
    return g + GPS_EPOCH_UNIX - _OFFSETS[np.searchsorted(_GPS_STEPS, g, side="right")]


def gps_week_sow_to_utc(week: npt.ArrayLike, sow: npt.ArrayLike) -> np.ndarray:
    """Full GPS week number (not modulo 1024) and seconds of week -> UTC (POSIX s)."""
    w = np.asarray(week, dtype=np.float64)
    return gps_to_utc(w * SECONDS_PER_WEEK + np.asarray(sow, dtype=np.float64))


def utc_to_gps_week_sow(utc_s: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """UTC (POSIX s) -> (full GPS week number (int64), seconds of week (float64))."""
    g = utc_to_gps(utc_s)
    week = np.floor(g / SECONDS_PER_WEEK)
    return week.astype(np.int64), g - week * SECONDS_PER_WEEK


def gps_adjusted_standard_time(utc_s: npt.ArrayLike) -> np.ndarray:
    """UTC (POSIX s) -> Adjusted Standard GPS time (GPS seconds - 1e9), the LAS 1.4
    point time when the header's global encoding bit 0 is set."""
    return utc_to_gps(utc_s) - ADJUSTED_OFFSET_S


def utc_from_adjusted_standard_time(t: npt.ArrayLike) -> np.ndarray:
    """Adjusted Standard GPS time -> UTC (POSIX s)."""
    return gps_to_utc(np.asarray(t, dtype=np.float64) + ADJUSTED_OFFSET_S)
