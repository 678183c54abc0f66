"""A session's logs as a ROS 2 bag: rosbag2, MCAP storage, CDR, ROS 2 Jazzy's messages
(written with rosbags).

What goes in (:mod:`acq.export.ros_messages` for the frames and fields):

- ``/<laser>/scan``: sensor_msgs/LaserScan, stamped at the scan's first point;
- ``/<camera>/image/compressed``: sensor_msgs/CompressedImage, at mid-exposure;
- ``/<camera>/camera_info``: sensor_msgs/CameraInfo, from ``/<camera>/calibration``
  (else the log's ``calibration`` record), one with every image and stamped as it is
  (as ROS image pipelines pair them);
- ``/tf_static``: tf2_msgs/TFMessage, offered transient-local (as tf2's static
  broadcaster does, so a late subscriber of ``ros2 bag play`` gets it);
- ``/odom`` (nav_msgs/Odometry) and ``/tf`` (odom -> base_link), one of each per
  ``/vehicle/odometry`` message: the pose dead-reckoned from the speed and yaw rate;
- ``/gnss/fix``: sensor_msgs/NavSatFix.

Header stamps and the bag's receive times are UTC ns (:mod:`acq.export.log_clock`).
``/tf_static``, repeated at the start of each file of a split session, goes in once,
again only when it changes. The acq.* timing,
raw and status records have no ROS counterpart and are counted as left out.
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from acq.errors import AcqError, InputValueError
from acq.export.log_clock import LogClock
from acq.export.ros_messages import BASE_LINK, ODOM, Messages, ScanGeometry
from acq.extras import needs
from acq.log.reader import LogReader, read_metadata
from acq.log.timebase import MONOTONIC
from acq.log.vehicle_log import ODOMETRY_TOPIC, VehicleReader
from acq.motion.odometry import dead_reckon
from acq.provenance import SOFTWARE

__all__ = ["BAG_VERSION", "Ros2Report", "bag_files", "export_ros2", "made_by_acq"]

BAG_VERSION: Final = 9  # rosbag2's metadata version of ROS 2 Jazzy
_CLOCK_TOPIC = "/acq/clock"


@dataclass
class Ros2Report:
    """What a bag holds: messages per ROS topic; the log's topics left out (count);
    ``utc``: whether the log was UTC already (else mapped through its clock pairs)."""

    counts: dict[str, int] = field(default_factory=dict)
    left_out: dict[str, int] = field(default_factory=dict)
    utc: bool = False
    notes: list[str] = field(default_factory=list)


def made_by_acq(bag: Path) -> bool:
    """Whether the folder ``bag`` is a rosbag2 acq wrote (its metadata's custom data)."""
    try:
        text = (bag / "metadata.yaml").read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return False
    return f"software: {SOFTWARE.split()[0]} " in text


def bag_files(bag: Path) -> frozenset[str]:
    """The names of the files acq wrote in the folder ``bag``: its metadata.yaml and the
    storage files that metadata lists; none when acq did not write the bag."""
    import yaml

    if not made_by_acq(bag):
        return frozenset()
    try:
        info = yaml.safe_load((bag / "metadata.yaml").read_text(encoding="utf-8"))
        paths = info["rosbag2_bagfile_information"]["relative_file_paths"]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return frozenset()
    if not isinstance(paths, list):
        return frozenset()
    # a listed name that is a path (a/b, ..) is no file of this folder
    names = (p for p in paths if isinstance(p, str) and p == Path(p).name != "..")
    return frozenset({"metadata.yaml", *names})


def _latched_key(msg: Any) -> bytes:
    """A latched message's content without its stamps (they change with each file)."""
    copy = type(msg)()
    copy.CopyFrom(msg)
    if "timestamp" in copy.DESCRIPTOR.fields_by_name:
        copy.ClearField("timestamp")
    for tf in getattr(copy, "transforms", ()):
        tf.ClearField("timestamp")
    data: bytes = copy.SerializeToString(deterministic=True)
    return data


def _scan_geometry(metadata: dict[str, dict[str, str]], laser: str) -> ScanGeometry:
    try:
        g = json.loads(metadata.get(f"device.{laser}", {}).get("geometry", "{}"))
    except ValueError:
        g = {}
    return ScanGeometry(
        time_increment=float(g.get("time_increment", 0.0)),
        scan_time=float(g.get("scan_period", 0.0)),
        range_min=float(g.get("range_min", 0.0)),
        range_max=float(g.get("range_max", math.inf)),
    )


@dataclass
class _Session:
    metadata: dict[str, dict[str, str]]
    clock: LogClock
    odometry: VehicleReader
    cameras: list[str]  # from their image and calibration topics
    calibrations: dict[str, Any]  # each camera's first foxglove.CameraCalibration


def _first_pass(files: Sequence[Path]) -> _Session:
    """Metadata, clock pairs and odometry of the session's files."""
    metadata: dict[str, dict[str, str]] = {}
    pairs: list[tuple[int, int]] = []
    vehicle = VehicleReader()
    cameras: set[str] = set()
    calibrations: dict[str, Any] = {}

    def wanted(schema: Any, channel: Any) -> str | None:
        topic: str = channel.topic
        for suffix in ("/image/compressed", "/calibration"):
            if topic.endswith(suffix):
                cameras.add(_camera(topic, suffix))
        if schema is not None and schema.name == _CALIBRATION:
            return topic
        return topic if topic in (_CLOCK_TOPIC, ODOMETRY_TOPIC) else None

    time_base = MONOTONIC
    for path in files:
        metadata.update(read_metadata(path))
        reader = LogReader(path)
        for topic, _channel, _message, msg in reader.decoded(wanted):
            if topic == _CLOCK_TOPIC:
                if msg is not None:
                    pairs.append((int(msg.monotonic_ns), int(msg.realtime_ns)))
            elif topic.endswith("/calibration"):
                if msg is not None:
                    calibrations.setdefault(_camera(topic, "/calibration"), msg)
            else:
                vehicle.add(topic, msg)
        time_base = reader.time_base  # named by its metadata, else by its messages
    clock = LogClock(time_base, np.array(pairs, np.int64).reshape(-1, 2))
    missing = [c for c in cameras if c not in calibrations]
    calibrations.update(_recorded_calibrations(metadata, missing) if missing else {})
    return _Session(metadata, clock, vehicle, sorted(cameras), calibrations)


def _recorded_calibrations(
    metadata: dict[str, dict[str, str]], cameras: list[str]
) -> dict[str, Any]:
    """foxglove.CameraCalibration of ``cameras`` from the log's ``calibration`` record
    (the calib.yaml of the recording), for a log without calibration messages."""
    import yaml

    from acq.camera import calibfile
    from acq.errors import InputError
    from acq.log import schemas

    text = metadata.get("calibration", {}).get("yaml")
    if not text:
        return {}
    try:
        calib = calibfile.parse(yaml.safe_load(text), "the log's calibration record")
    except (InputError, yaml.YAMLError):
        return {}
    out = {}
    for name in cameras:
        if name in calib.cameras:
            try:
                data = schemas.camera_calibration(calib.cameras[name], name, 0)
            except ValueError:  # a camera model Foxglove's message cannot hold
                continue
            out[name] = schemas.decode(_CALIBRATION, data)
    return out


def _camera(topic: str, suffix: str) -> str:
    """The camera of ``/<camera><suffix>``."""
    return topic[1:].removesuffix(suffix)


def export_ros2(
    logs: Sequence[str | os.PathLike[str]],
    bag: str | os.PathLike[str],
    *,
    progress: Callable[[int], None] | None = None,
) -> Ros2Report:
    """Write the logs (the files of one session, in order) as a new rosbag2 folder
    ``bag`` (see the module doc); ``progress`` is called with the number of messages
    read so far. Raises InputValueError for a log that cannot be read or mapped to UTC,
    AcqError when the bag cannot be written."""
    with needs("ros2", "writing a rosbag2 bag"):
        from rosbags.interfaces import (
            Qos,
            QosDurability,
            QosHistory,
            QosLiveliness,
            QosReliability,
            QosTime,
        )
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
        from rosbags.typesys import Stores, get_typestore

    files = [Path(p) for p in logs]
    session = _first_pass(files)
    clock = session.clock
    typestore = get_typestore(Stores.ROS2_JAZZY)
    build = Messages(typestore, session.cameras)
    report = Ros2Report(utc=clock.utc)
    latched = QosTime(0, 0)
    static_qos = Qos(
        QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
        latched, latched, QosLiveliness.AUTOMATIC, latched, False,
    )  # fmt: skip
    bag_path = Path(bag)
    try:
        writer = Writer(bag_path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        writer.set_custom_data("software", SOFTWARE)
        writer.set_custom_data("source", " ".join(p.name for p in files))
        writer.open()
    except (WriterError, OSError) as e:
        raise AcqError(f"{bag_path}: cannot write the bag: {e}") from e
    connections: dict[str, Any] = {}
    counts: Counter[str] = Counter()

    def put(topic: str, msgtype: str, message: Any, log_ns: int, static: bool = False) -> None:
        conn = connections.get(topic)
        if conn is None:
            conn = connections[topic] = writer.add_connection(
                topic,
                msgtype,
                typestore=typestore,
                offered_qos_profiles=[static_qos] if static else [],
            )
        writer.write(conn, clock.to_utc(log_ns), typestore.serialize_cdr(message, msgtype))
        counts[topic] += 1

    left_out: Counter[str] = Counter()
    seen_latched: dict[str, bytes] = {}
    calibrations = dict(session.calibrations)  # the latest before an image, else the first
    uncalibrated: set[str] = set()
    geometry: dict[str, ScanGeometry] = {}
    read = 0
    try:
        odometry = _OdometryTrack(session, build, put)
        if odometry.note:
            report.notes.append(odometry.note)
        for path in files:
            reader = LogReader(path)
            for schema, channel, message in reader.messages():
                read += 1
                odometry.until(int(message.log_time))
                if progress is not None and read % 256 == 0:
                    progress(read)
                topic, name = channel.topic, schema.name if schema else ""
                if topic in (_CLOCK_TOPIC, ODOMETRY_TOPIC):
                    continue
                if name not in _CONVERTED:
                    left_out[topic] += 1
                    continue
                msg = reader.decode(schema, channel, message)
                if msg is None:  # counted: the reader warns once per channel
                    continue
                log_ns = int(message.log_time)
                if name in _LATCHED:
                    key = _latched_key(msg)
                    if seen_latched.get(topic) == key:
                        continue
                    seen_latched[topic] = key
                if name == "foxglove.LaserScan":
                    laser = topic[1:].removesuffix("/scan")
                    if laser not in geometry:
                        geometry[laser] = _scan_geometry(session.metadata, laser)
                    stamp = clock.to_utc(build.stamp_ns(msg))
                    ros = build.laser_scan(msg, stamp, geometry[laser])
                    put(topic, "sensor_msgs/msg/LaserScan", ros, log_ns)
                elif name == "foxglove.CompressedImage":
                    stamp = clock.to_utc(build.stamp_ns(msg))
                    ros = build.compressed_image(msg, stamp)
                    put(topic, "sensor_msgs/msg/CompressedImage", ros, log_ns)
                    camera = _camera(topic, "/image/compressed")
                    calibration = calibrations.get(camera)
                    if calibration is not None:  # each image with its camera_info
                        info = build.camera_info(calibration, stamp)
                        put(f"/{camera}/camera_info", "sensor_msgs/msg/CameraInfo", info, log_ns)
                    elif camera not in uncalibrated:
                        uncalibrated.add(camera)
                        report.notes.append(f"{camera}: no calibration in the log: no camera_info")
                elif name == _CALIBRATION:  # the one the next images go with
                    calibrations[_camera(topic, "/calibration")] = msg
                elif name == "foxglove.FrameTransforms":
                    ros = build.tf_static(msg, clock.to_utc)
                    put("/tf_static", "tf2_msgs/msg/TFMessage", ros, log_ns, static=True)
                elif name == "foxglove.LocationFix":
                    ros = build.nav_sat_fix(msg, clock.to_utc(build.stamp_ns(msg)))
                    put(topic, "sensor_msgs/msg/NavSatFix", ros, log_ns)
            if reader.notes:  # a file not closed the reader itself names, with its span
                report.notes.append(f"{path.name}: {'; '.join(reader.notes)}")
        odometry.until(2**63 - 1)  # what is after the last converted message
    except (WriterError, OSError) as e:
        raise AcqError(f"{bag_path}: cannot write the bag: {e}") from e
    finally:
        writer.close()
    report.counts = dict(counts)
    report.left_out = dict(left_out)
    if not counts:
        raise InputValueError("the logs hold nothing a ROS 2 bag carries")
    return report


_CALIBRATION = "foxglove.CameraCalibration"
_CONVERTED = frozenset(
    {
        "foxglove.LaserScan",
        "foxglove.CompressedImage",
        "foxglove.CameraCalibration",
        "foxglove.FrameTransforms",
        "foxglove.LocationFix",
    }
)
_LATCHED = frozenset({"foxglove.FrameTransforms"})


class _OdometryTrack:
    """/odom and /tf (odom -> base_link), one of each per odometry message: planar dead
    reckoning from the first one (speed and yaw rate, each interval's mean), stamped
    with the message's stamp; written in time order among the other messages
    (:meth:`until`)."""

    def __init__(self, session: _Session, build: Messages, put: Callable[..., None]) -> None:
        odo = session.odometry.result(()).odometry
        self.t = odo.t_ns.astype(np.int64)
        self.speed, self.yaw_rate = odo.speed, odo.yaw_rate
        self.clock, self.build, self.put = session.clock, build, put
        self.next = 0
        self.note = None
        if self.t.size and not (np.isfinite(self.speed).all() and np.isfinite(self.yaw_rate).all()):
            self.note = "the odometry lacks its speed or its yaw rate: no /odom nor /tf"
            self.t = self.t[:0]
        if self.t.size:
            self.x, self.y, self.psi = dead_reckon(
                np.diff(self.t) * 1e-9,
                0.5 * (self.speed[:-1] + self.speed[1:]),
                0.5 * (self.yaw_rate[:-1] + self.yaw_rate[1:]),
            )

    def until(self, log_ns: int) -> None:
        """Write the messages stamped at or before ``log_ns`` (log ns) not written yet."""
        build = self.build
        while self.next < self.t.size and self.t[self.next] <= log_ns:
            i = self.next
            self.next += 1
            t = int(self.t[i])
            stamp = self.clock.to_utc(t)
            half = 0.5 * float(self.psi[i])
            xyz, xyzw = (
                (float(self.x[i]), float(self.y[i]), 0.0),
                (0.0, 0.0, math.sin(half), math.cos(half)),
            )
            twist = (float(self.speed[i]), float(self.yaw_rate[i]))
            self.put("/odom", "nav_msgs/msg/Odometry", build.odometry(stamp, xyz, xyzw, *twist), t)
            tf = build.transform(stamp, ODOM, BASE_LINK, xyz, xyzw)
            self.put("/tf", "tf2_msgs/msg/TFMessage", build.tf([tf]), t)
