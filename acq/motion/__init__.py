"""The vehicle's motion: a trajectory (poses on the host clock, interpolated on SE(3)) from
wheel odometry, GNSS, their fusion or a GNSS/INS file. The names below are those of its
modules: ``trajectory`` (the :class:`Trajectory` itself), ``odometry``, ``gnss``,
``gnss_outliers``, ``fusion``, ``ins`` (files), ``pose_source`` (what colouring needs of
a trajectory, and the choice of one from a log's vehicle data), ``rolling`` (the live
trajectory of a recording). The vehicle's log is read by :mod:`acq.log.vehicle_log`.
"""

from acq.motion.fusion import Fusion, fuse
from acq.motion.gnss import GnssTrack, NoHeadingError, from_gnss, gnss_from_fixes, gnss_track
from acq.motion.gnss_outliers import Screened, screen_fixes
from acq.motion.ins import TrajectoryFileError, from_csv, to_csv
from acq.motion.odometry import dead_reckon, from_odometry, speed_from_wheels, yaw_rate_from_wheels
from acq.motion.pose_source import Chosen, PoseSource, trajectory_from_vehicle
from acq.motion.rolling import RollingTrajectory
from acq.motion.trajectory import MAX_EXTRAPOLATION_S, OutOfSpanError, Trajectory, laser_poses

__all__ = [
    "MAX_EXTRAPOLATION_S",
    "Chosen",
    "Fusion",
    "GnssTrack",
    "NoHeadingError",
    "OutOfSpanError",
    "PoseSource",
    "RollingTrajectory",
    "Screened",
    "Trajectory",
    "TrajectoryFileError",
    "dead_reckon",
    "from_csv",
    "from_gnss",
    "from_odometry",
    "fuse",
    "gnss_from_fixes",
    "gnss_track",
    "laser_poses",
    "screen_fixes",
    "speed_from_wheels",
    "to_csv",
    "trajectory_from_vehicle",
    "yaw_rate_from_wheels",
]
