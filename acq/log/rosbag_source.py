"""A ROS 2 bag (rosbag2, MCAP storage, CDR) read as an acq log.

A rosbag2's storage file is an MCAP file whose header names the ``ros2`` profile and
whose messages are CDR, described by their ROS message definitions (``ros2msg``).
:func:`acq_records` turns its records into those of an acq log as they are read, so
:class:`acq.log.LogReader` and everything above it (``acq info``, ``acq colorize``)
read a bag as they read a log; the messages are deserialised with rosbags' typestore,
from the definitions the bag holds, then written as acq's own (:mod:`acq.log.schemas`):

- ``sensor_msgs/LaserScan`` -> ``/<laser>/scan`` (foxglove.LaserScan), stamped at
  ``header.stamp`` (the first point), ``time_increment`` s per point; the scanner's
  ``device.<laser>`` geometry record from its first scan;
- ``sensor_msgs/CompressedImage`` -> ``/<camera>/image/compressed``, at ``header.stamp``;
- ``nav_msgs/Odometry`` -> ``/vehicle/odometry`` (acq.Odometry: the twist's forward
  speed and yaw rate, which acq dead-reckons);
- ``sensor_msgs/NavSatFix`` -> ``/gnss/fix`` (foxglove.LocationFix);
- ``/tf``'s ``odom`` -> ``base_link`` (or ``base_footprint``) transforms, also on
  ``/vehicle/pose`` (foxglove.FrameTransforms): the vehicle's poses, which give the
  trajectory when the bag has no odometry;
- every other topic as it is (counted by ``acq info``, not decoded).

Devices are named by their topic's namespace (``/left/image/compressed`` and
``/left/image_raw/compressed``: ``left``; ``/laser/scan``: ``laser``), else by the
first message's ``frame_id``. A bag has no host monotonic clock: its stamps are taken
as UTC ns, and the log reads as a UTC log with a zero offset (one ``/acq/clock`` pair
of equal times says so to what maps times to UTC).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
from mcap.records import Channel, Header, McapRecord, Message, Metadata, Schema

from acq.errors import InputValueError
from acq.extras import needs
from acq.log import schemas
from acq.records import Fix, Frame, Odometry, Scan

__all__ = ["POSE_TOPIC", "PROFILE", "acq_records", "bag_files", "is_bag", "laser_channels"]

PROFILE: Final = "ros2"  # the MCAP profile rosbag2's storage plugin writes
_FIRST_ID: Final = 1 << 20  # ids of the channels and schemas made here, above the bag's

_LASER, _IMAGE, _ODOMETRY, _FIX = (
    "sensor_msgs/msg/LaserScan",
    "sensor_msgs/msg/CompressedImage",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/NavSatFix",
)
_TF = "tf2_msgs/msg/TFMessage"
POSE_TOPIC: Final = "/vehicle/pose"
_ODOM_FRAME, _VEHICLE_FRAMES = "odom", ("base_link", "base_footprint")
_SCHEMA_OF = {
    _LASER: "foxglove.LaserScan",
    _IMAGE: "foxglove.CompressedImage",
    _ODOMETRY: "acq.Odometry",
    _FIX: "foxglove.LocationFix",
}
_CLOCK_LINE = (
    "a ROS 2 bag: header stamps and receive times taken as UTC ns; no host monotonic clock"
)
# sensor_msgs/NavSatStatus -> GGA fix quality (no fix, fix, SBAS, ground-based augmentation)
_QUALITY = {-1: 0, 0: 1, 1: 2, 2: 4}


def is_bag(header: Any) -> bool:
    """Whether an MCAP Header record is a rosbag2 storage file's."""
    return isinstance(header, Header) and header.profile == PROFILE


def laser_channels(summary: Any) -> int | None:
    """How many LaserScan channels a rosbag2 storage file's MCAP summary lists (None:
    no summary)."""
    if summary is None:
        return None
    lasers = {s.id for s in summary.schemas.values() if s.name == _LASER}
    return sum(1 for c in summary.channels.values() if c.schema_id in lasers)


def bag_files(folder: Path) -> list[Path] | None:
    """A rosbag2 folder's storage files in the bag's order (its ``metadata.yaml``), None
    when ``folder`` is no bag. InputValueError, naming the file, for a metadata.yaml that
    cannot be read, a bag whose storage is not MCAP, or a storage file that is missing."""
    import yaml

    meta = folder / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        storage = str(info.get("storage_identifier", ""))
        names = [str(p) for p in info["relative_file_paths"]]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError, AttributeError):
        raise InputValueError(
            f"{meta}: not a rosbag2 metadata file (no rosbag2_bagfile_information with "
            "relative_file_paths)"
        ) from None
    if storage != "mcap":
        raise InputValueError(
            f"{folder}: a rosbag2 with {storage or 'unnamed'} storage; acq reads MCAP storage "
            f"(convert it: ros2 bag convert -i {folder} -o OPTIONS.yaml, storage_id: mcap)"
        )
    files = [folder / name for name in names]
    for f in files:
        if not f.is_file():
            raise InputValueError(f"{meta}: lists {f.name}, which is not in {folder}")
    if not files:
        raise InputValueError(f"{meta}: the bag lists no storage files")
    return files


def acq_records(records: Iterable[McapRecord], notes: list[str]) -> Iterator[McapRecord]:
    """``records`` (an MCAP file's, in file order) as they are when the file is not a
    rosbag2 storage file, else as an acq log's (the module doc). Messages that cannot be
    deserialised are skipped and counted in ``notes``."""
    it = iter(records)
    first = next(it, None)
    if first is None:
        return
    if not is_bag(first):
        yield first
        yield from it
        return
    bag = _Translator()
    yield from bag.start()
    try:
        for record in it:
            yield from bag.translate(record)
    finally:
        if bag.bad:
            notes.append(f"{bag.bad} ROS messages that cannot be deserialised skipped")


@dataclass
class _Device:
    """A bag channel acq reads: its message type, the acq channel it becomes (made at
    its first message, when its name is known) and that device's name."""

    msgtype: str
    topic: str
    schema_id: int
    channel: Channel | None = None
    name: str = ""
    geometry_sent: bool = False  # a laser's device.<laser> record


def _device_name(topic: str, suffixes: tuple[str, ...]) -> str:
    """The namespace of ``topic`` without one of ``suffixes`` and an ``image*`` level
    (``/left/image_raw/compressed`` -> ``left``); "" for a topic at the root."""
    path = topic.strip("/")
    for suffix in suffixes:
        if path == suffix or path.endswith("/" + suffix):
            path = path[: -len(suffix)].rstrip("/")
            break
    if path.rsplit("/", 1)[-1].startswith("image"):
        path = path.rsplit("/", 1)[0] if "/" in path else ""
    return path


def _frame_device(frame_id: str) -> str:
    """A device name from a message's ``frame_id`` (``left_optical`` -> ``left``)."""
    for suffix in ("_optical_frame", "_optical", "_frame", "_link"):
        if frame_id.endswith(suffix) and len(frame_id) > len(suffix):
            return frame_id[: -len(suffix)]
    return frame_id


def _ns(stamp: Any) -> int:
    return int(stamp.sec) * 10**9 + int(stamp.nanosec)


class _Translator:
    """The records of one rosbag2 storage file as an acq log's (see the module doc)."""

    def __init__(self) -> None:
        with needs("ros2", "reading a rosbag2 bag"):
            from rosbags.typesys import Stores, get_typestore

        self.typestore = get_typestore(Stores.EMPTY)
        self.registered: set[str] = set()
        self.msgtypes: dict[int, tuple[str, str]] = {}  # schema id -> (name, definition)
        self.devices: dict[int, _Device] = {}  # by the bag's channel id
        self.schema_ids: dict[str, int] = {}  # acq schema name -> id given
        self.names: dict[str, set[str]] = {}  # msgtype -> device names given
        self.odometry_channel: int | None = None
        self.tf_channels: dict[int, int] = {}  # /tf channel id -> its schema id
        self.pose_channel: Channel | None = None
        self.clock_sent = False
        self.next_id = _FIRST_ID
        self.bad = 0

    def start(self) -> Iterator[McapRecord]:
        """The records an acq log starts with: its time base."""
        yield Metadata(
            name="acq", metadata={"clock": _CLOCK_LINE, "utc_offset_ns": "0", "source": "rosbag2"}
        )

    def _id(self) -> int:
        self.next_id += 1
        return self.next_id

    def _schema(self, name: str) -> Iterator[McapRecord]:
        """acq's schema ``name``, once."""
        if name not in self.schema_ids:
            self.schema_ids[name] = sid = self._id()
            s = schemas.SCHEMAS[name]
            yield Schema(id=sid, name=s.name, encoding=s.encoding, data=s.data)

    def translate(self, record: McapRecord) -> Iterator[McapRecord]:
        if isinstance(record, Schema):
            self.msgtypes[record.id] = (record.name, record.data.decode("utf-8", "replace"))
            yield record
        elif isinstance(record, Channel):
            msgtype = self.msgtypes.get(record.schema_id, ("", ""))[0]
            if msgtype == _ODOMETRY and self.odometry_channel not in (None, record.id):
                msgtype = ""  # one odometry: a second one stays as it is
            if msgtype in _SCHEMA_OF and record.message_encoding == "cdr":
                if msgtype == _ODOMETRY:
                    self.odometry_channel = record.id
                self.devices[record.id] = _Device(msgtype, record.topic, record.schema_id)
            else:
                if msgtype == _TF and record.topic == "/tf" and record.message_encoding == "cdr":
                    self.tf_channels[record.id] = record.schema_id
                yield record
        elif isinstance(record, Message) and record.channel_id in self.devices:
            yield from self._message(self.devices[record.channel_id], record)
        elif isinstance(record, Message) and record.channel_id in self.tf_channels:
            yield record
            yield from self._poses(self.tf_channels[record.channel_id], record)
        elif not isinstance(record, Header | Metadata):  # the bag's own metadata left out
            yield record

    def _deserialise(self, msgtype: str, schema_id: int, data: bytes) -> Any:
        """A CDR message by the definition of its type the bag holds."""
        if msgtype not in self.registered:
            from rosbags.typesys import get_types_from_msg

            name, text = self.msgtypes[schema_id]
            self.typestore.register(get_types_from_msg(text, name))
            self.registered.add(msgtype)
        return self.typestore.deserialize_cdr(data, msgtype)

    def _poses(self, schema_id: int, record: Message) -> Iterator[McapRecord]:
        """A /tf message's odom -> vehicle transforms on /vehicle/pose, if it has any."""
        try:
            tfs = self._deserialise(_TF, schema_id, bytes(record.data)).transforms
            ours = [
                tf for tf in tfs
                if tf.header.frame_id.lstrip("/") == _ODOM_FRAME
                and tf.child_frame_id.lstrip("/") in _VEHICLE_FRAMES
            ]  # fmt: skip
        except Exception:  # a garbled payload: that message is lost
            self.bad += 1
            return
        if not ours:
            return
        msg = schemas.message_class("foxglove.FrameTransforms")()
        for tf in ours:
            out = msg.transforms.add(parent_frame_id=_ODOM_FRAME, child_frame_id="vehicle")
            out.timestamp.FromNanoseconds(_ns(tf.header.stamp))
            tr, rot = tf.transform.translation, tf.transform.rotation
            out.translation.x, out.translation.y, out.translation.z = tr.x, tr.y, tr.z
            out.rotation.x, out.rotation.y, out.rotation.z, out.rotation.w = (
                rot.x, rot.y, rot.z, rot.w,
            )  # fmt: skip
        if self.pose_channel is None:
            yield from self._schema("foxglove.FrameTransforms")
            self.pose_channel = Channel(
                id=self._id(), schema_id=self.schema_ids["foxglove.FrameTransforms"],
                topic=POSE_TOPIC, message_encoding="protobuf", metadata={"ros_topic": "/tf"},
            )  # fmt: skip
            yield self.pose_channel
        yield Message(
            channel_id=self.pose_channel.id, sequence=record.sequence,
            log_time=record.log_time, publish_time=_ns(ours[0].header.stamp),
            data=msg.SerializeToString(),
        )  # fmt: skip

    def _message(self, device: _Device, record: Message) -> Iterator[McapRecord]:
        try:
            msg = self._deserialise(device.msgtype, device.schema_id, bytes(record.data))
            stamp = _ns(msg.header.stamp)
        except Exception:  # a garbled payload or definition: that message is lost
            self.bad += 1
            return
        if device.channel is None:
            yield from self._open(device, msg)
        assert device.channel is not None
        if not self.clock_sent:
            self.clock_sent = True
            yield from self._clock(record.log_time)
        try:
            data, extra = self._encode(device, msg, stamp, int(record.log_time))
        except (ValueError, TypeError, AttributeError):
            self.bad += 1
            return
        yield from extra
        yield Message(
            channel_id=device.channel.id,
            sequence=record.sequence,
            log_time=record.log_time,
            publish_time=stamp,  # where the recorder puts a message's stamp
            data=data,
        )

    def _open(self, device: _Device, msg: Any) -> Iterator[McapRecord]:
        """The acq channel of ``device``, named from its topic or first message."""
        acq_schema = _SCHEMA_OF[device.msgtype]
        yield from self._schema(acq_schema)
        if device.msgtype == _LASER:
            name = _device_name(device.topic, ("scan",))
            topic = "/{}/scan"
        elif device.msgtype == _IMAGE:
            name = _device_name(device.topic, ("compressed",))
            topic = "/{}/image/compressed"
        else:
            name, topic = "", "/vehicle/odometry" if device.msgtype == _ODOMETRY else "/gnss/fix"
        if device.msgtype in (_LASER, _IMAGE):
            taken = self.names.setdefault(device.msgtype, set())
            if not name or name in taken:
                name = _frame_device(str(msg.header.frame_id)) or device.topic.strip("/")
            taken.add(name)
            topic = topic.format(name)
        device.name = name
        device.channel = Channel(
            id=self._id(),
            schema_id=self.schema_ids[acq_schema],
            topic=topic,
            message_encoding="protobuf",
            metadata={"ros_topic": device.topic},
        )
        yield device.channel

    def _clock(self, t_ns: int) -> Iterator[McapRecord]:
        """One /acq/clock pair of equal times: the log's times are UTC."""
        yield from self._schema("acq.Clock")
        channel = Channel(
            id=self._id(),
            schema_id=self.schema_ids["acq.Clock"],
            topic="/acq/clock",
            message_encoding="protobuf",
            metadata={},
        )
        yield channel
        yield Message(
            channel_id=channel.id, sequence=0, log_time=t_ns, publish_time=t_ns,
            data=schemas.clock(realtime_ns=t_ns, monotonic_ns=t_ns),
        )  # fmt: skip

    def _encode(
        self, device: _Device, msg: Any, stamp: int, recv_ns: int
    ) -> tuple[bytes, list[McapRecord]]:
        """acq's message of ``msg`` and any record to go before it."""
        if device.msgtype == _LASER:
            scan = Scan(
                ranges=np.asarray(msg.ranges, np.float32),
                intensities=np.asarray(msg.intensities, np.float32),
                angle_min=float(msg.angle_min),
                angle_increment=float(msg.angle_increment),
                time_increment=max(float(msg.time_increment), 0.0),
                scan_period=max(float(msg.scan_time), 0.0),
                recv_ns=recv_ns,
                start_ns=stamp,
            )
            extra: list[McapRecord] = []
            if not device.geometry_sent:
                device.geometry_sent = True
                extra.append(_geometry(device.name, scan, msg))
            return schemas.laser_scan(scan, device.name, stamp), extra
        if device.msgtype == _IMAGE:
            frame = Frame(
                recv_ns=recv_ns, stamp_ns=stamp, sequence=0, width=0, height=0,
                jpeg=bytes(msg.data),
            )  # fmt: skip
            return schemas.compressed_image(frame, device.name, stamp), []
        if device.msgtype == _ODOMETRY:
            twist = msg.twist.twist
            odo = Odometry(
                recv_ns=recv_ns, stamp_ns=stamp, speed=float(twist.linear.x),
                yaw_rate=float(twist.angular.z),
            )  # fmt: skip
            return schemas.odometry(odo), []
        return schemas.location_fix(_fix(msg, stamp, recv_ns), stamp, str(msg.header.frame_id)), []


def _geometry(laser: str, scan: Scan, msg: Any) -> Metadata:
    """The ``device.<laser>`` record the scans' first gives (what acq's drivers record)."""
    geometry = {
        "time_increment": scan.time_increment,
        "scan_period": scan.scan_period,
        "range_min": float(msg.range_min),
        "range_max": float(msg.range_max),
        "angle_min": scan.angle_min,
        "angle_increment": scan.angle_increment,
        "points": scan.size,
    }
    return Metadata(
        name=f"device.{laser}",
        metadata={"driver": "rosbag2", "class": "LaserScan", "geometry": json.dumps(geometry)},
    )


def _fix(msg: Any, stamp: int, recv_ns: int) -> Fix:
    """acq's Fix of a sensor_msgs/NavSatFix (no fix: NaN position)."""
    quality = _QUALITY.get(int(msg.status.status), 1)
    lat, lon, alt = float(msg.latitude), float(msg.longitude), float(msg.altitude)
    if quality == 0:
        lat = lon = alt = math.nan
    cov = np.asarray(msg.position_covariance, np.float64)
    kind = int(msg.position_covariance_type)
    sigmas = np.sqrt(np.abs(cov[[0, 4, 8]])) if cov.size == 9 and kind else np.full(3, np.nan)
    return Fix(
        recv_ns=recv_ns, utc_s=stamp * 1e-9, latitude=lat, longitude=lon, altitude=alt,
        quality=quality, sigma_east=float(sigmas[0]), sigma_north=float(sigmas[1]),
        sigma_up=float(sigmas[2]), covariance_type=kind,
    )  # fmt: skip
