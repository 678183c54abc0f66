"""acq's logged messages (Foxglove's protobuf schemas, acq.Odometry) as ROS 2 messages
of a rosbags typestore, ready for CDR.

Frames follow REP-103/105: ``base_link`` is the vehicle (acq's ``vehicle``), ``odom``
the dead-reckoned world, the laser keeps its name; a camera's images and calibration are
in ``<camera>_optical``, the OpenCV camera frame acq calibrates (z forward, x right,
y down: REP-103's optical frame). Stamps are UTC ns given by the caller.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "BASE_LINK",
    "ODOM",
    "Messages",
    "ScanGeometry",
    "frame_name",
]

BASE_LINK = "base_link"
ODOM = "odom"
_RENAMED = {"vehicle": BASE_LINK}

# foxglove.CameraCalibration's distortion models by ROS's names (image_geometry's:
# "equidistant" is the OpenCV fisheye model, four coefficients)
_DISTORTION = {"kannala_brandt": "equidistant", "plumb_bob": "plumb_bob"}

# NavSatStatus by the GGA fix quality in a fix's metadata
_NO_FIX, _FIX, _SBAS_FIX, _GBAS_FIX = -1, 0, 1, 2
_STATUS_BY_QUALITY = {0: _NO_FIX, 1: _FIX, 2: _SBAS_FIX, 4: _GBAS_FIX, 5: _GBAS_FIX}
_SERVICE_GPS = 1


def frame_name(frame_id: str, cameras: Sequence[str]) -> str:
    """The ROS frame of an acq frame id: ``vehicle`` -> ``base_link``, a camera ->
    ``<camera>_optical``, others unchanged."""
    if frame_id in cameras:
        return f"{frame_id}_optical"
    return _RENAMED.get(frame_id, frame_id)


@dataclass(frozen=True)
class ScanGeometry:
    """What foxglove.LaserScan does not carry, from the scanner's ``device.<laser>``
    metadata: s per point, s per scan, metres."""

    time_increment: float = 0.0
    scan_time: float = 0.0
    range_min: float = 0.0
    range_max: float = math.inf


def _ns(stamp: Any) -> int:
    return int(stamp.seconds) * 10**9 + int(stamp.nanos)


class Messages:
    """Builds ROS 2 messages with the classes of ``typestore`` (rosbags)."""

    def __init__(self, typestore: Any, cameras: Sequence[str]) -> None:
        self.types = typestore.types
        self.cameras = tuple(cameras)

    def stamp_ns(self, msg: Any) -> int:
        """A Foxglove message's ``timestamp`` in ns (the log's clock)."""
        return _ns(msg.timestamp)

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        sec, nanosec = divmod(int(stamp_ns), 10**9)
        t = self.types
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id
        )

    def laser_scan(self, msg: Any, stamp_ns: int, geometry: ScanGeometry) -> Any:
        """sensor_msgs/LaserScan of a foxglove.LaserScan: stamped at its first point."""
        ranges = np.asarray(msg.ranges, dtype=np.float32)
        n = ranges.size
        increment = (msg.end_angle - msg.start_angle) / (n - 1) if n > 1 else 0.0
        return self.types["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp_ns, frame_name(msg.frame_id, self.cameras)),
            angle_min=float(msg.start_angle),
            angle_max=float(msg.end_angle),
            angle_increment=float(increment),
            time_increment=geometry.time_increment,
            scan_time=geometry.scan_time,
            range_min=geometry.range_min,
            range_max=geometry.range_max,
            ranges=ranges,
            intensities=np.asarray(msg.intensities, dtype=np.float32),
        )

    def compressed_image(self, msg: Any, stamp_ns: int) -> Any:
        """sensor_msgs/CompressedImage of a foxglove.CompressedImage (mid-exposure)."""
        return self.types["sensor_msgs/msg/CompressedImage"](
            header=self.header(stamp_ns, frame_name(msg.frame_id, self.cameras)),
            format=msg.format or "jpeg",
            data=np.frombuffer(msg.data, dtype=np.uint8),
        )

    def camera_info(self, msg: Any, stamp_ns: int) -> Any:
        """sensor_msgs/CameraInfo of a foxglove.CameraCalibration."""
        t = self.types
        return t["sensor_msgs/msg/CameraInfo"](
            header=self.header(stamp_ns, frame_name(msg.frame_id, self.cameras)),
            height=int(msg.height),
            width=int(msg.width),
            distortion_model=_DISTORTION.get(msg.distortion_model, msg.distortion_model),
            d=np.asarray(msg.D, dtype=np.float64),
            k=np.asarray(msg.K, dtype=np.float64),
            r=np.asarray(msg.R, dtype=np.float64),
            p=np.asarray(msg.P, dtype=np.float64),
            binning_x=0,
            binning_y=0,
            roi=t["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )

    def transform(
        self,
        stamp_ns: int,
        parent: str,
        child: str,
        xyz: Sequence[float],
        xyzw: Sequence[float],
    ) -> Any:
        """geometry_msgs/TransformStamped: ``child``'s pose in ``parent`` (m, quaternion)."""
        t = self.types
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=t["geometry_msgs/msg/Quaternion"](
                    x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3]
                ),
            ),
        )

    def tf_static(self, msg: Any, to_utc: Any) -> Any:
        """tf2_msgs/TFMessage of a foxglove.FrameTransforms, each transform's stamp
        mapped by ``to_utc`` (log ns -> UTC ns)."""
        transforms = []
        for tf in msg.transforms:
            tr, rot = tf.translation, tf.rotation
            transforms.append(
                self.transform(
                    to_utc(_ns(tf.timestamp)),
                    frame_name(tf.parent_frame_id, self.cameras),
                    frame_name(tf.child_frame_id, self.cameras),
                    (tr.x, tr.y, tr.z),
                    (rot.x, rot.y, rot.z, rot.w),
                )
            )
        return self.types["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def tf(self, transforms: Sequence[Any]) -> Any:
        return self.types["tf2_msgs/msg/TFMessage"](transforms=list(transforms))

    def odometry(
        self,
        stamp_ns: int,
        xyz: Sequence[float],
        xyzw: Sequence[float],
        speed: float,
        yaw_rate: float,
    ) -> Any:
        """nav_msgs/Odometry: base_link's pose in odom, its twist (m/s along x, rad/s
        about z) in base_link; covariances unknown (zero)."""
        t = self.types
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
            orientation=t["geometry_msgs/msg/Quaternion"](
                x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3]
            ),
        )
        vec = t["geometry_msgs/msg/Vector3"]
        twist = t["geometry_msgs/msg/Twist"](
            linear=vec(x=speed, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=yaw_rate)
        )
        return t["nav_msgs/msg/Odometry"](
            header=self.header(stamp_ns, ODOM),
            child_frame_id=BASE_LINK,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose, covariance=np.zeros(36, np.float64)
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.zeros(36, np.float64)
            ),
        )

    def nav_sat_fix(self, msg: Any, stamp_ns: int) -> Any:
        """sensor_msgs/NavSatFix of a foxglove.LocationFix: the status from the fix
        quality in its metadata (no fix without one), the covariance and its type as
        they are (the two enums agree)."""
        meta = {kv.key: kv.value for kv in msg.metadata}
        try:
            quality = int(meta.get("quality", "1"))
        except ValueError:
            quality = 1
        status = _STATUS_BY_QUALITY.get(quality, _FIX)
        if not math.isfinite(msg.latitude):
            status = _NO_FIX
        t = self.types
        cov = np.zeros(9, np.float64)
        if len(msg.position_covariance) == 9:
            cov[:] = msg.position_covariance
        return t["sensor_msgs/msg/NavSatFix"](
            header=self.header(stamp_ns, frame_name(msg.frame_id or "gnss", self.cameras)),
            status=t["sensor_msgs/msg/NavSatStatus"](status=status, service=_SERVICE_GPS),
            latitude=float(msg.latitude),
            longitude=float(msg.longitude),
            altitude=float(msg.altitude),
            position_covariance=cov,
            position_covariance_type=int(msg.position_covariance_type),
        )
