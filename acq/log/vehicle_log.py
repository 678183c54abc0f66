"""The vehicle's odometry and GNSS fixes of a recorded session, as numpy arrays.

:func:`read_vehicle` reads ``/vehicle/odometry`` (``acq.Odometry``), ``/gnss/fix``
(``foxglove.LocationFix``) and ``/vehicle/pose`` (a ROS 2 bag's odom -> base_link
transforms, :mod:`acq.log.rosbag_source`) from one or several MCAP files of a session (files whose
writer was killed are read up to their last good record), sorted by time. Times are
host monotonic ns (the log's clock), the stamps the recorder gave: for odometry the
CAN receive stamp, for a fix its fix instant.

Each odometry row comes from one CAN message, which carries the wheel speeds or the
yaw rate, not both (see :mod:`acq.drivers.can_odometry`). ``speed`` and ``yaw_rate`` are
complete rows all the same: where a row's message did not carry a quantity, it is
linearly interpolated in time between the neighbouring rows that did (held constant
before the first and after the last), and ``speed_measured`` / ``yaw_rate_measured``
say which rows are measurements. ``wheel_speeds`` stays NaN where not measured.
:meth:`Odometry.at` interpolates both at any times, from the measurements only.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.records import Channel, Schema

from acq.log.reader import LogReader
from acq.log.rosbag_source import POSE_TOPIC

__all__ = [
    "FIX_TOPIC",
    "ODOMETRY_TOPIC",
    "POSE_TOPIC",
    "Fixes",
    "Odometry",
    "Poses",
    "VehicleLog",
    "VehicleReader",
    "read_vehicle",
]

ODOMETRY_TOPIC = "/vehicle/odometry"
FIX_TOPIC = "/gnss/fix"


@dataclass(frozen=True)
class Odometry:
    """Odometry rows sorted by ``t_ns``; m/s, rad/s (counter-clockwise, REP-103)."""

    t_ns: np.ndarray  # (N,) int64 host monotonic ns
    speed: np.ndarray  # (N,) float64 m/s, complete (see the module doc)
    yaw_rate: np.ndarray  # (N,) float64 rad/s, complete
    wheel_speeds: np.ndarray  # (N,4) float64 m/s FL, FR, RL, RR; NaN where not measured
    speed_measured: np.ndarray  # (N,) bool: the row's message carried the speed
    yaw_rate_measured: np.ndarray  # (N,) bool

    def __len__(self) -> int:
        return int(self.t_ns.size)

    def at(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(speed m/s, yaw rate rad/s) at host times ``t_ns``, linearly interpolated
        between measurements (held beyond them; NaN when there is none)."""
        t = np.asarray(t_ns, dtype=np.int64)
        return (
            _interp(t, self.t_ns, self.speed, self.speed_measured),
            _interp(t, self.t_ns, self.yaw_rate, self.yaw_rate_measured),
        )


@dataclass(frozen=True)
class Fixes:
    """GNSS fixes sorted by ``t_ns``: WGS-84 degrees, metres above the ellipsoid; NaN
    position where ``quality`` is 0 (no fix)."""

    t_ns: np.ndarray  # (M,) int64 host monotonic ns of the fix instant
    utc_s: np.ndarray  # (M,) float64 the receiver's fix time, UTC s since the epoch
    lat: np.ndarray  # (M,) float64 degrees
    lon: np.ndarray  # (M,) float64 degrees
    alt: np.ndarray  # (M,) float64 m above the WGS-84 ellipsoid
    quality: np.ndarray  # (M,) int16 GGA fix quality (0 none, 1 GPS, 2 DGPS, 4 RTK...)
    hdop: np.ndarray  # (M,) float64
    satellites: np.ndarray  # (M,) int16
    speed: np.ndarray  # (M,) float64 m/s over ground, NaN where not sent
    course: np.ndarray  # (M,) float64 rad clockwise from north, NaN where not sent

    def __len__(self) -> int:
        return int(self.t_ns.size)


@dataclass(frozen=True)
class Poses:
    """The vehicle's poses in the odometry frame, sorted by ``t_ns`` (unique)."""

    t_ns: np.ndarray  # (K,) int64 host ns (a ROS 2 bag's: its stamps)
    translation: np.ndarray  # (K,3) float64 m
    quaternion: np.ndarray  # (K,4) float64 w, x, y, z

    def __len__(self) -> int:
        return int(self.t_ns.size)


def _no_poses() -> Poses:
    return Poses(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))


@dataclass(frozen=True)
class VehicleLog:
    """What :func:`read_vehicle` found; ``notes`` lists what was skipped."""

    files: tuple[Path, ...]
    odometry: Odometry
    fixes: Fixes
    notes: list[str] = field(default_factory=list)
    poses: Poses = field(default_factory=_no_poses)


def _interp(
    t: npt.NDArray[np.int64],
    ts: npt.NDArray[np.int64],
    values: npt.NDArray[np.float64],
    measured: npt.NDArray[np.bool_],
) -> npt.NDArray[np.float64]:
    ok = measured & np.isfinite(values)
    if not ok.any():
        return np.full(t.shape, np.nan)
    t0 = int(ts[ok][0])  # interpolate relative to the first: float64 keeps ns over days
    return np.interp((t - t0).astype(np.float64), (ts[ok] - t0).astype(np.float64), values[ok])


def _stamp(msg: Any) -> int:
    return int(msg.timestamp.seconds) * 1_000_000_000 + int(msg.timestamp.nanos)


def _odometry(rows: list[tuple[int, int, float, float, tuple[float, ...]]]) -> Odometry:
    unique = {(r[0], r[1]): r for r in rows}  # a file given twice: once
    rows = [unique[k] for k in sorted(unique)]
    n = len(rows)
    t = np.array([r[0] for r in rows], dtype=np.int64)
    speed = np.array([r[2] for r in rows], dtype=np.float64)
    yaw = np.array([r[3] for r in rows], dtype=np.float64)
    wheels = np.full((n, 4), np.nan)
    for i, r in enumerate(rows):
        if len(r[4]) == 4:
            wheels[i] = r[4]
    speed_ok, yaw_ok = np.isfinite(speed), np.isfinite(yaw)
    return Odometry(
        t_ns=t,
        speed=_interp(t, t, speed, speed_ok) if n else speed,
        yaw_rate=_interp(t, t, yaw, yaw_ok) if n else yaw,
        wheel_speeds=wheels,
        speed_measured=speed_ok,
        yaw_rate_measured=yaw_ok,
    )


def _fix_row(msg: Any) -> tuple[Any, ...]:
    meta = {kv.key: kv.value for kv in msg.metadata}

    def number(key: str) -> float:
        try:
            return float(meta[key])
        except (KeyError, ValueError):
            return math.nan

    def whole(key: str) -> int:
        try:
            return int(meta[key])
        except (KeyError, ValueError):
            return 0

    course = float(msg.heading) if msg.HasField("heading") else math.nan
    if msg.HasField("velocity"):
        speed = math.hypot(msg.velocity.x, msg.velocity.y)
    else:
        speed = math.nan
    return (_stamp(msg), number("utc_s"), float(msg.latitude), float(msg.longitude),
            float(msg.altitude), whole("quality"), number("hdop"), whole("satellites"),
            speed, course)  # fmt: skip


def _fixes(rows: list[tuple[Any, ...]]) -> Fixes:
    # a file given twice: once; two fixes stamped alike (the clock's envelope dropped by
    # a period, the first fixes held up) both kept, told apart by their UTC fix time
    unique = {(r[0], r[1]): r for r in rows}
    rows = [unique[k] for k in sorted(unique)]
    cols = list(zip(*rows, strict=True)) if rows else [()] * 10

    def f64(i: int) -> np.ndarray:
        return np.array(cols[i], dtype=np.float64)

    return Fixes(
        t_ns=np.array(cols[0], dtype=np.int64),
        utc_s=f64(1),
        lat=f64(2),
        lon=f64(3),
        alt=f64(4),
        quality=np.array(cols[5], dtype=np.int16),
        hdop=f64(6),
        satellites=np.array(cols[7], dtype=np.int16),
        speed=f64(8),
        course=f64(9),
    )


class VehicleReader:
    """Collects the vehicle topics' decoded messages (one pass over a log can feed it
    beside other readers, as :func:`acq.log.drive_log.read_log` does)."""

    TOPICS = (ODOMETRY_TOPIC, FIX_TOPIC, POSE_TOPIC)

    def __init__(self) -> None:
        self.odometry: list[tuple[int, int, float, float, tuple[float, ...]]] = []
        self.fixes: list[tuple[Any, ...]] = []
        self.poses: dict[int, tuple[float, ...]] = {}  # stamp -> x, y, z, qw, qx, qy, qz
        self.bad = 0

    def add(self, topic: str, msg: Any) -> int | None:
        """One decoded message of :attr:`TOPICS` (None: undecodable); a garbled one is
        counted, not raised. Returns the host ns of the newest row it added (None: none)."""
        if msg is None:
            self.bad += 1
            return None
        newest: int | None = None
        try:
            if topic == ODOMETRY_TOPIC:
                speed, yaw = float(msg.speed_mps), float(msg.yaw_rate_rps)
                wheels = tuple(float(w) for w in msg.wheel_speeds_mps)
                newest = _stamp(msg)
                self.odometry.append((newest, int(msg.arbitration_id), speed, yaw, wheels))
            elif topic == FIX_TOPIC:
                self.fixes.append(_fix_row(msg))
                newest = int(self.fixes[-1][0])
            elif topic == POSE_TOPIC:
                for tf in msg.transforms:
                    tr, q = tf.translation, tf.rotation
                    stamp = _stamp(tf)
                    self.poses[stamp] = (tr.x, tr.y, tr.z, q.w, q.x, q.y, q.z)
                    newest = stamp if newest is None else max(newest, stamp)
        except Exception:  # a payload that decoded to something else: that message is lost
            self.bad += 1
        return newest

    def result(self, files: tuple[Path, ...]) -> VehicleLog:
        notes = [f"{self.bad} undecodable vehicle messages skipped"] if self.bad else []
        if not self.odometry:
            notes.append(f"no {ODOMETRY_TOPIC} messages")
        if not self.fixes:
            notes.append(f"no {FIX_TOPIC} messages")
        poses = _no_poses()
        if self.poses:
            t = np.array(sorted(self.poses), dtype=np.int64)
            rows = np.array([self.poses[int(k)] for k in t], dtype=np.float64)
            poses = Poses(t, rows[:, :3], rows[:, 3:])
        return VehicleLog(files, _odometry(self.odometry), _fixes(self.fixes), notes, poses)


def read_vehicle(paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str]) -> VehicleLog:
    """Odometry and fixes of one log or of the files of a session (any order).

    Raises :class:`acq.log.LogError` for a file that is not MCAP. A log without
    the topics gives empty arrays (and a note); undecodable messages are skipped.
    """
    if isinstance(paths, str | os.PathLike):
        files: tuple[Path, ...] = (Path(paths),)
    else:
        files = tuple(Path(p) for p in paths)
    vehicle = VehicleReader()
    for path in files:
        reader = LogReader(path)
        for topic, _channel, _message, msg in reader.decoded(_vehicle_topic):
            vehicle.add(topic, msg)
    return vehicle.result(files)


def _vehicle_topic(_schema: Schema | None, channel: Channel) -> str | None:
    return channel.topic if channel.topic in VehicleReader.TOPICS else None
