"""A synthetic drive's vehicle messages (CAN odometry, GNSS fixes) encoded as the recorder
logs them (acq.log.schemas) and decoded back, in time order: for the pose sources' tests
and bench/rolling_trajectory.py."""

from __future__ import annotations

from typing import Any

import numpy as np

from acq.geometry.geodesy import WorldFrame
from acq.geometry.rotations import quat_from_matrix
from acq.log import schemas
from acq.log.vehicle_log import FIX_TOPIC, ODOMETRY_TOPIC, POSE_TOPIC, VehicleLog, VehicleReader
from acq.motion import from_odometry
from acq.records import Fix, Odometry

T0 = 5_000_000_000_000  # host ns of the drive's start
ORIGIN = (48.1, 11.5, 520.0)  # lat °, lon °, ellipsoidal height m of the drive's start


def speeds(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The drive's speed (m/s) and yaw rate (rad/s) at ``t_s`` s: a winding street."""
    return 5.0 + np.sin(0.3 * t_s), 0.1 * np.sin(0.2 * t_s)


def drive(
    seconds: float,
    odometry_hz: float = 100.0,
    gnss_hz: float = 0.0,
    noise_m: float = 0.02,
    *,
    split: bool = False,
) -> list[tuple[str, Any]]:
    """(topic, decoded message) of the drive in time order: odometry at ``odometry_hz``
    and fixes of the true position (the dead-reckoned truth put in ENU at :data:`ORIGIN`
    heading east) with ``noise_m`` horizontal noise at ``gnss_hz``. ``split``: each
    odometry message carries the speed or the yaw rate in turn (NaN the other), as two
    CAN messages do."""
    out: list[tuple[int, str, Any]] = []
    if odometry_hz:
        t_s = np.arange(0.0, seconds, 1.0 / odometry_hz)
        v, w = speeds(t_s)
        if split:
            v[1::2], w[0::2] = np.nan, np.nan
        t_ns = T0 + np.round(t_s * 1e9).astype(np.int64)
        for i, (t, vi, wi) in enumerate(zip(t_ns, v, w, strict=True)):
            odo = Odometry(
                int(t), int(t), float(vi), float(wi), arbitration_id=i % 2 if split else 0
            )
            data = schemas.odometry(odo)
            out.append((int(t), ODOMETRY_TOPIC, schemas.decode("acq.Odometry", data)))
    if gnss_hz:
        fine = np.arange(0.0, seconds + 0.01, 0.005)
        truth = from_odometry(T0 + np.round(fine * 1e9).astype(np.int64), *speeds(fine))
        t_fix = T0 + np.round(np.arange(0.0, seconds, 1.0 / gnss_hz) * 1e9).astype(np.int64)
        _, xyz = truth.pose_at(t_fix)
        xyz[:, :2] += np.random.default_rng(1).normal(0.0, noise_m, (len(t_fix), 2))
        lat, lon, alt = WorldFrame("enu", ORIGIN).to_geodetic(xyz)
        for t, la, lo, al in zip(t_fix, lat, lon, alt, strict=True):
            fix = Fix(int(t), 1.7e9, float(la), float(lo), float(al), quality=4, hdop=0.02)
            data = schemas.location_fix(fix, int(t))
            out.append((int(t), FIX_TOPIC, schemas.decode("foxglove.LocationFix", data)))
    out.sort(key=lambda m: m[0])
    return [(topic, msg) for _, topic, msg in out]


def tf_poses(seconds: float, hz: float = 20.0, per_message: int = 2) -> list[tuple[str, Any]]:
    """The drive's poses (dead-reckoned truth, odom -> base_link) as a ROS 2 bag's /tf
    comes out of :mod:`acq.log.rosbag_source`: ``foxglove.FrameTransforms`` on
    ``/vehicle/pose``, ``per_message`` transforms in each."""
    t_s = np.arange(0.0, seconds, 1.0 / hz)
    truth = from_odometry(T0 + np.round(t_s * 1e9).astype(np.int64), *speeds(t_s))
    cls = schemas.message_class("foxglove.FrameTransforms")
    out: list[tuple[str, Any]] = []
    for i in range(0, t_s.size, per_message):
        msg = cls()
        for k in range(i, min(i + per_message, t_s.size)):
            tf = msg.transforms.add(parent_frame_id="odom", child_frame_id="base_link")
            tf.timestamp.FromNanoseconds(int(truth.t_ns[k]))
            tf.translation.x, tf.translation.y, tf.translation.z = truth.translation[k]
            q = quat_from_matrix(truth.rotation[k])
            tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z = q
        out.append(
            (POSE_TOPIC, schemas.decode("foxglove.FrameTransforms", msg.SerializeToString()))
        )
    return out


def vehicle_log(messages: list[tuple[str, Any]]) -> VehicleLog:
    """The messages read as a log's vehicle data."""
    reader = VehicleReader()
    for topic, msg in messages:
        reader.add(topic, msg)
    return reader.result(())
