"""Where the vehicle's poses come from: what colouring needs of any trajectory
(:class:`PoseSource`, which a finished :class:`~acq.motion.trajectory.Trajectory` and the
live :class:`acq.motion.rolling.RollingTrajectory`'s builds satisfy), and the choice of
trajectory from a log's vehicle data (:func:`trajectory_from_vehicle`, :class:`Chosen`).

The choice, best first: a ROS 2 bag's odom -> base_link poses (``/vehicle/pose``) when
there is no CAN odometry; CAN odometry fused with GNSS fixes (at least 5 usable);
GNSS alone (heading from the track); CAN odometry alone (dead reckoning); else none.
Times are host monotonic ns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from acq.geometry.geodesy import WorldFrame
from acq.geometry.rotations import matrix_from_quat
from acq.geometry.transforms import Rigid
from acq.log.vehicle_log import Fixes, VehicleLog
from acq.motion.fusion import fuse
from acq.motion.gnss import NoHeadingError, from_gnss, gnss_track, usable_fixes
from acq.motion.gnss_outliers import screen_fixes
from acq.motion.odometry import from_odometry
from acq.motion.trajectory import Trajectory

__all__ = ["MIN_FIXES", "POSE_GAP_S", "Chosen", "Kind", "PoseSource", "trajectory_from_vehicle"]

POSE_GAP_S = 0.5  # s: no pose inside a longer interval between two poses, as for odometry
MIN_FIXES = 5  # usable GNSS fixes for GNSS to count (alone or fused)

Kind = Literal["poses", "fused", "gnss", "odometry", "none"]


@runtime_checkable
class PoseSource(Protocol):
    """Vehicle -> world poses at host ns, as colouring uses them."""

    @property
    def frame(self) -> str:
        """The world frame's name ("odometry", "enu" or a CRS such as "EPSG:25832")."""
        ...

    @property
    def world(self) -> WorldFrame:
        """The world frame with its origin."""
        ...

    def covers(self, t_ns: npt.ArrayLike) -> np.ndarray:
        """Bool mask (shape of ``t_ns``): True where :meth:`pose_at` gives a pose."""
        ...

    def pose_at(self, t_ns: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Rotations S+(3,3) and translations S+(3,) m at host ns of shape S; raises
        :class:`acq.motion.trajectory.OutOfSpanError` for a time not covered."""
        ...

    def transform(self, t_ns: npt.ArrayLike, points: npt.ArrayLike) -> np.ndarray:
        """Vehicle-frame points (N,3) m, each at its host ns (N,), into the world."""
        ...


@dataclass(frozen=True)
class Chosen:
    """The trajectory :func:`trajectory_from_vehicle` chose (None: none could be made),
    one line saying which and from what (empty when none), the notes on the data
    (skipped messages, dropped fixes), and its kind: the log's ``"poses"``, odometry
    ``"fused"`` with GNSS, ``"gnss"`` alone, ``"odometry"`` alone, or ``"none"``."""

    trajectory: Trajectory | None
    description: str = ""
    notes: tuple[str, ...] = ()
    kind: Kind = "none"


def trajectory_from_vehicle(
    vehicle: VehicleLog,
    crs: str | None = None,
    *,
    enu_origin: tuple[float, float, float] | None = None,
    start: Rigid | None = None,
) -> Chosen:
    """The best trajectory the vehicle data give (module docstring): in ``crs`` when
    given (GNSS fixes projected into it), else GNSS in the ENU frame at ``enu_origin``
    (lat °, lon °, ellipsoidal height m; default the first usable fix). ``start``: the
    first pose of odometry dead reckoning (identity by default). Raises as
    :func:`acq.motion.fusion.fuse` and :func:`acq.motion.odometry.from_odometry` do for
    data they cannot use (e.g. repeated odometry times)."""
    notes = list(vehicle.notes)
    odo, fixes, poses = vehicle.odometry, vehicle.fixes, vehicle.poses

    def chosen(traj: Trajectory | None, kind: Kind = "none", description: str = "") -> Chosen:
        return Chosen(traj, description, tuple(notes), kind)

    if len(odo) < 2 and len(poses) >= 2:  # a ROS 2 bag's /tf, when it has no odometry
        traj = Trajectory(
            poses.t_ns, matrix_from_quat(poses.quaternion), poses.translation,
            max_gap_s=POSE_GAP_S,
        )  # fmt: skip
        return chosen(traj, "poses", f"the log's odom -> base_link poses ({len(poses)}, /tf)")
    usable = _usable_fixes(fixes, notes)
    gnss = int(usable.sum()) >= MIN_FIXES
    if len(odo) < 2 and not gnss:
        return chosen(None)
    if gnss:
        track = gnss_track(
            fixes.t_ns, fixes.lat, fixes.lon, fixes.alt, hdop=fixes.hdop, quality=fixes.quality,
            frame=crs or "enu", origin=None if crs else enu_origin,
        )  # fmt: skip
        screened = screen_fixes(track)
        track = screened.track
        if screened.note:
            notes.append(screened.note)
    if len(odo) < 2:
        course = fixes.course[np.searchsorted(fixes.t_ns, track.t_ns)]  # NaN where not sent
        try:
            traj = from_gnss(track, course_rad=course)
        except NoHeadingError as e:
            notes.append(f"{e}: no trajectory")
            return chosen(None)
        return chosen(
            traj,
            "gnss",
            f"GNSS alone ({len(track)} fixes; heading from the track, no CAN odometry)",
        )
    if gnss:
        fusion = fuse(odo.t_ns, odo.speed, odo.yaw_rate, track, on_gap="flag")
        return chosen(
            fusion.trajectory,
            "fused",
            f"CAN odometry ({len(odo)} samples) fused with {len(track)} GNSS fixes "
            f"(residual {fusion.residual_rms_m:.2f} m RMS)",
        )
    traj = from_odometry(odo.t_ns, odo.speed, odo.yaw_rate, start=start, on_gap="flag")
    return chosen(traj, "odometry", f"CAN odometry ({len(odo)} samples, dead reckoning)")


def _usable_fixes(fixes: Fixes, notes: list[str]) -> np.ndarray:
    """Which fixes are usable (bool); a note in ``notes`` for those out of range
    (latitude beyond ±90°, longitude beyond ±180°)."""
    if not len(fixes):
        return np.zeros(0, dtype=bool)
    valid = np.isfinite(fixes.lat) & np.isfinite(fixes.lon) & (fixes.quality > 0)
    usable = valid & usable_fixes(fixes.lat, fixes.lon, fixes.alt)
    if n := int((valid & ~usable).sum()):
        notes.append(
            f"GNSS: {n} of {len(fixes)} fixes out of range (latitude beyond ±90°, longitude "
            "beyond ±180° or height not finite) dropped"
        )
    return np.asarray(usable, dtype=bool)
