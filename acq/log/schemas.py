"""Protobuf message encoders for the MCAP logs (see ARCHITECTURE.md, "MCAP logs").

Two families of schemas:

- Foxglove's well-known schemas (``foxglove.LaserScan``, ``foxglove.CompressedImage``,
  ``foxglove.CameraCalibration``, ``foxglove.FrameTransforms``, ``foxglove.PointCloud``,
  ``foxglove.LocationFix``), so a log opens in Foxglove as it is.
- Our own versioned ``acq.*`` schemas (file ``acq/v1.proto``, package ``acq``), built at
  import time (:mod:`acq.log.acq_proto`): ``acq.RawTelegram``, ``acq.Timing``,
  ``acq.Clock``, ``acq.Status`` (``acq.DeviceStatus``, ``acq.Colouring``), ``acq.Odometry``,
  ``acq.CanFrame`` and ``acq.TimeBase`` (what the host knows about its clock).

Times: a Foxglove message's ``timestamp`` is on the log's clock, the same as MCAP
``log_time`` (UTC: host monotonic plus the session's offset, :mod:`acq.log.timebase`);
the encoders here write the stamp they are given, so the caller converts
(``writer.time_base.to_log``). Every ``acq.*`` ``timestamp`` and every field named
``*_ns`` hold host *monotonic* nanoseconds (``time.monotonic_ns()``), except
``acq.Clock.realtime_ns`` (``CLOCK_REALTIME``, ns since the Unix epoch); a log maps
them to UTC with the (realtime, monotonic) pairs on ``/acq/clock``.

Encoders return the serialized bytes; :func:`decode` turns bytes back into a message.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from google.protobuf import descriptor_pb2, timestamp_pb2
from google.protobuf.descriptor import FileDescriptor

from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import KannalaBrandt, Pinhole
from acq.geometry.rotations import quat_from_matrix
from acq.geometry.transforms import Rigid
from acq.log.acq_proto import (
    ACQ_PROTO,
    CanFrameMsg,
    ClockMsg,
    DeviceStatusMsg,
    OdometryMsg,
    RawTelegramMsg,
    StatusMsg,
    TimeBaseMsg,
    TimingMsg,
)
from acq.records import CanFrame, Fix, Frame, Odometry, Scan
from acq.time.absent import Absent
from acq.time.chrony import ChronyTracking
from acq.time.host_clock import GnssTime, HostClock
from acq.time.kernel_clock import KernelClock
from acq.time.pps import PpsSource
from acq.time.ptp import PtpTime

__all__ = [
    "ACQ_PROTO",
    "SCHEMAS",
    "ColouringStatus",
    "DeviceStatus",
    "Schema",
    "camera_calibration",
    "can_frame",
    "clock",
    "colouring_of",
    "compressed_image",
    "compressed_image_bytes",
    "decode",
    "frame_transforms",
    "host_clock_of",
    "laser_scan",
    "location_fix",
    "message_class",
    "odometry",
    "raw_telegram",
    "serialized",
    "set_stamp",
    "status",
    "time_base_record",
    "timing",
    "transform",
]


@dataclass(frozen=True)
class Schema:
    """An MCAP schema record: ``data`` is a serialized ``FileDescriptorSet`` holding the
    message's file and all its dependencies (what MCAP's ``protobuf`` encoding wants)."""

    name: str  # full message name, e.g. "foxglove.LaserScan"
    encoding: str  # always "protobuf"
    data: bytes


def serialized(msg: Any) -> bytes:
    """``msg``'s wire bytes (the protobuf classes are untyped: their methods return Any)."""
    data: bytes = msg.SerializeToString()
    return data


def _file_descriptor_set(file: FileDescriptor) -> bytes:
    """``file`` and its dependencies, dependencies first, as a serialized FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(f: FileDescriptor) -> None:
        if f.name in seen:
            return
        seen.add(f.name)
        for dep in f.dependencies:
            add(dep)
        f.CopyToProto(fds.file.add())

    add(file)
    return serialized(fds)


_CLASSES: dict[str, Any] = {
    cls.DESCRIPTOR.full_name: cls
    for cls in (
        LaserScan,
        CompressedImage,
        CameraCalibration,
        FrameTransforms,
        PointCloud,
        LocationFix,
        RawTelegramMsg,
        TimingMsg,
        ClockMsg,
        StatusMsg,
        DeviceStatusMsg,
        OdometryMsg,
        CanFrameMsg,
        TimeBaseMsg,
    )
}

SCHEMAS: dict[str, Schema] = {
    name: Schema(name, "protobuf", _file_descriptor_set(cls.DESCRIPTOR.file))
    for name, cls in _CLASSES.items()
}


def message_class(schema_name: str) -> Any:
    """The protobuf message class of a schema in :data:`SCHEMAS`."""
    try:
        return _CLASSES[schema_name]
    except KeyError:
        raise KeyError(
            f"unknown schema {schema_name!r}; expected one of {', '.join(_CLASSES)}"
        ) from None


def decode(schema_name: str, data: bytes) -> Any:
    """Parse ``data`` as a message of ``schema_name`` (for readers and tests)."""
    return message_class(schema_name).FromString(data)


# --- helpers ------------------------------------------------------------------------------


def set_stamp(ts: timestamp_pb2.Timestamp, ns: int) -> None:
    """A Timestamp from integer ns (floor division, so nanos stay in [0, 1e9))."""
    ts.seconds, ts.nanos = divmod(int(ns), 1_000_000_000)


def _varint(n: int) -> bytes:
    out = bytearray()
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _packed_doubles(field_number: int, values: np.ndarray) -> bytes:
    """A packed ``repeated double`` field as protobuf wire bytes (empty when no values).

    Parsers merge fields appended after a message's own serialization, so this lets the
    hot path skip building a 1081-element Python list (12x faster than ``extend``).
    """
    if values.size == 0:
        return b""
    payload = np.ascontiguousarray(values, dtype="<f8").tobytes()
    return _varint(field_number << 3 | 2) + _varint(len(payload)) + payload


# --- Foxglove messages --------------------------------------------------------------------


def laser_scan(scan: Scan, frame_id: str, stamp_ns: int) -> bytes:
    """``foxglove.LaserScan``: ``stamp_ns`` is the first point's time (the log's clock, ns).

    Angles follow REP-103 (``start_angle = angle_min``, ``end_angle`` the last point's);
    ranges keep ``+inf``/``-inf``/``nan`` (REP-117); intensities are omitted when the
    device sends none; the pose is the identity (the scan is in ``frame_id``'s origin).
    """
    msg = LaserScan(frame_id=frame_id, start_angle=scan.angle_min)
    set_stamp(msg.timestamp, stamp_ns)
    msg.pose.orientation.w = 1.0
    msg.end_angle = scan.angle_min + max(scan.size - 1, 0) * scan.angle_increment
    return b"".join(
        (
            msg.SerializeToString(),
            _packed_doubles(LaserScan.RANGES_FIELD_NUMBER, scan.ranges),
            _packed_doubles(LaserScan.INTENSITIES_FIELD_NUMBER, scan.intensities),
        )
    )


def compressed_image(frame: Frame, frame_id: str, stamp_ns: int) -> bytes:
    """``foxglove.CompressedImage``: the JPEG exactly as the camera sent it, stamped
    ``stamp_ns``: the middle of the exposure (``frame.stamp_ns``) on the log's clock."""
    if not frame.jpeg:
        raise ValueError("compressed_image needs a Frame with jpeg bytes (encode it first)")
    return compressed_image_bytes(frame.jpeg, frame_id, stamp_ns)


_JPEG_FORMAT = b"\x1a\x04jpeg"  # field 3 (format), length 4


def compressed_image_bytes(jpeg: bytes, frame_id: str, stamp_ns: int) -> bytes:
    """The wire bytes the protobuf library gives ``CompressedImage(timestamp=stamp_ns,
    frame_id, data=jpeg, format="jpeg")``, built with one copy of the JPEG (the library
    makes two): the few header fields in field-number order around the data."""
    seconds, nanos = divmod(int(stamp_ns), 1_000_000_000)
    if not -(1 << 63) <= seconds < 1 << 63:
        raise ValueError(f"timestamp {stamp_ns} ns is out of a Timestamp's range")
    stamp = (b"\x08" + _varint(seconds & 0xFFFF_FFFF_FFFF_FFFF) if seconds else b"") + (
        b"\x10" + _varint(nanos) if nanos else b""
    )
    name = frame_id.encode()
    tail = _JPEG_FORMAT + (b"\x22" + _varint(len(name)) + name if name else b"")
    head = b"\x0a" + _varint(len(stamp)) + stamp + b"\x12" + _varint(len(jpeg))
    return b"".join((head, jpeg, tail))


def camera_calibration(calib: CameraCalib, frame_id: str, stamp_ns: int) -> bytes:
    """``foxglove.CameraCalibration`` of one camera.

    Fisheye models (``equidistant``, ``kannala_brandt``) go as ``kannala_brandt`` with
    ``D = k`` (4 coefficients, OpenCV fisheye; zero for the equidistant model); the
    pinhole model as ``plumb_bob`` with ``D = (k1, k2, p1, p2, k3)``. ``R`` is the
    identity, ``P = [K | 0]``.
    """
    model = calib.model
    msg = CameraCalibration(frame_id=frame_id, width=model.width, height=model.height)
    set_stamp(msg.timestamp, stamp_ns)
    if isinstance(model, KannalaBrandt):
        msg.distortion_model = "kannala_brandt"
        msg.D.extend(model.k)
    elif isinstance(model, Pinhole):
        msg.distortion_model = "plumb_bob"
        msg.D.extend(model.dist)
    else:
        raise ValueError(f"no Foxglove distortion model for camera model {model.name!r}")
    fx, fy, cx, cy = model.fx, model.fy, model.cx, model.cy
    msg.K.extend([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    msg.R.extend([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    msg.P.extend([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    return serialized(msg)


def _add_transform(
    msg: FrameTransforms, parent: str, child: str, pose: Rigid, stamp_ns: int
) -> None:
    tf = msg.transforms.add(parent_frame_id=parent, child_frame_id=child)
    set_stamp(tf.timestamp, stamp_ns)
    tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in pose.translation)
    w, x, y, z = (float(v) for v in quat_from_matrix(pose.rotation))
    tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = x, y, z, w  # Foxglove's order


def transform(parent: str, child: str, pose: Rigid, stamp_ns: int) -> bytes:
    """``foxglove.FrameTransforms`` of one ``parent`` -> ``child`` transform (``pose``
    takes the child's points into the parent's frame), e.g. the vehicle's pose on ``/tf``."""
    msg = FrameTransforms()
    _add_transform(msg, parent, child, pose, stamp_ns)
    return serialized(msg)


def frame_transforms(
    calib: Calibration, stamp_ns: int, camera_frames: dict[str, str] | None = None
) -> bytes:
    """``foxglove.FrameTransforms`` for ``/tf_static``.

    One transform per camera, parent ``calib.laser``, child the camera's optical frame
    (``camera_frames[name]``, default the camera's name), from ``camera_to_laser``
    (``P_laser = R P_cam + t`` is the camera's pose in the laser frame, which is what a
    parent -> child transform holds). With ``laser_to_vehicle`` set, also parent
    ``"vehicle"``, child the laser.
    """
    frames = camera_frames or {}
    msg = FrameTransforms()
    if calib.laser_to_vehicle is not None:
        _add_transform(msg, "vehicle", calib.laser, calib.laser_to_vehicle, stamp_ns)
    for name, cam in calib.cameras.items():
        _add_transform(msg, calib.laser, frames.get(name, name), cam.camera_to_laser, stamp_ns)
    return serialized(msg)


def location_fix(fix: Fix, stamp_ns: int, frame_id: str = "gnss") -> bytes:
    """``foxglove.LocationFix`` for ``/gnss/fix``, stamped ``stamp_ns`` (the fix instant
    on the log's clock).

    Latitude and longitude in degrees, altitude above the ellipsoid (NaN without a fix);
    ``heading`` (rad clockwise from north) and ENU ``velocity`` from RMC's course and
    speed where the receiver sent them; the position covariance (m², east, north, up,
    row-major: diagonal) and its type from the fix's sigmas (:class:`acq.records.
    CovarianceType`, the same values). ``metadata`` holds the fix time (``utc``, ISO
    8601, and ``utc_s``), ``quality``, ``satellites``, ``hdop``, ``vdop`` and
    ``geoid_separation_m``.
    """
    import datetime as dt

    msg = LocationFix(
        frame_id=frame_id,
        latitude=fix.latitude,
        longitude=fix.longitude,
        altitude=fix.altitude,
    )
    set_stamp(msg.timestamp, stamp_ns)
    sigmas = (fix.sigma_east, fix.sigma_north, fix.sigma_up)
    known = fix.covariance_type != 0 and all(math.isfinite(s) for s in sigmas)
    covariance = [0.0] * 9
    if known:
        msg.position_covariance_type = fix.covariance_type  # type: ignore[assignment]
        covariance[0], covariance[4], covariance[8] = (s * s for s in sigmas)
    msg.position_covariance.extend(covariance)
    if math.isfinite(fix.course):
        msg.heading = fix.course
        if math.isfinite(fix.speed):
            msg.velocity.x = fix.speed * math.sin(fix.course)
            msg.velocity.y = fix.speed * math.cos(fix.course)
            msg.velocity.z = 0.0
    try:
        utc = dt.datetime.fromtimestamp(fix.utc_s, dt.UTC).isoformat(timespec="milliseconds")
    except (ValueError, OverflowError, OSError):
        utc = ""
    values = {
        "utc": utc.replace("+00:00", "Z"),
        "utc_s": f"{fix.utc_s:.3f}",
        "quality": str(fix.quality),
        "satellites": str(fix.satellites),
        "hdop": f"{fix.hdop:g}",
        "vdop": f"{fix.vdop:g}",
        "geoid_separation_m": f"{fix.geoid_separation:g}",
    }
    msg.metadata.extend(KeyValuePair(key=k, value=v) for k, v in values.items())
    return serialized(msg)


# --- acq.* messages -----------------------------------------------------------------------


def raw_telegram(
    *,
    device: str,
    data: bytes,
    recv_ns: int,
    stamp_ns: int | None = None,
    device_ticks: Sequence[int] = (),
    sequence: int = 0,
) -> bytes:
    """``acq.RawTelegram``: the telegram bytes as received; ``timestamp`` is ``stamp_ns``
    (the record's time, e.g. a scan's first point) or ``recv_ns`` when there is none."""
    msg = RawTelegramMsg(
        device=device, data=data, device_ticks=device_ticks, sequence=sequence, recv_ns=recv_ns
    )
    set_stamp(msg.timestamp, recv_ns if stamp_ns is None else stamp_ns)
    return serialized(msg)


def timing(
    *,
    recv_ns: int,
    stamp_ns: int,
    device_ticks: Sequence[int] = (),
    unwrapped_tick: int = 0,
    epoch: int = 0,
    offset_ns: int = 0,
    drift_ppm: float = 0.0,
    uncertainty_s: float = math.nan,
    sequence: int = 0,
    received: int = 0,
    dropped: int = 0,
    stamp_source: str = "",
) -> bytes:
    """``acq.Timing``, one per record on ``/acq/timing/<device>``: receipt time, raw and
    unwrapped ticks, the clock's estimate (``stamp_ns``, ``offset_ns`` host minus device,
    drift in ppm, uncertainty in s), the device's received/dropped counters and what set
    the stamp (``stamp_source``: ``fix`` or ``receipt``, empty for the device clock)."""
    msg = TimingMsg(
        recv_ns=recv_ns,
        device_ticks=device_ticks,
        unwrapped_tick=unwrapped_tick,
        epoch=epoch,
        stamp_ns=stamp_ns,
        offset_ns=offset_ns,
        drift_ppm=drift_ppm,
        uncertainty_s=uncertainty_s,
        sequence=sequence,
        received=received,
        dropped=dropped,
        stamp_source=stamp_source,
    )
    return serialized(msg)


def clock(*, realtime_ns: int, monotonic_ns: int) -> bytes:
    """``acq.Clock``: one (CLOCK_REALTIME, CLOCK_MONOTONIC) pair in ns, for ``/acq/clock``."""
    return serialized(ClockMsg(realtime_ns=realtime_ns, monotonic_ns=monotonic_ns))


@dataclass(frozen=True)
class DeviceStatus:
    """One device's line in ``acq.Status`` (counts since start; times in s unless ``_ns``)."""

    name: str
    kind: str  # "scanner" | "camera" | "can" | "gnss"
    connected: bool = False
    rate_hz: float = 0.0
    received: int = 0
    dropped: int = 0
    corrupt: int = 0
    disconnects: int = 0
    protocol_errors: int = 0
    gap_s: float = 0.0  # since the last record, or the length of the current outage
    last_event: str = ""
    clock_offset_ns: int = 0
    clock_drift_ppm: float = 0.0
    clock_uncertainty_s: float = math.nan
    epoch: int = 0
    odd_size: int = 0  # frames of another size than expected, recorded and flagged (cameras)
    fast_s: float = 0.0  # time delivering over 1.5 times the configured rate (cameras)
    required: bool = False  # its loss fails the recording


@dataclass(frozen=True)
class ColouringStatus:
    """The live colourer's figures in ``acq.Status``: scans coloured and skipped (it fell
    behind) since the start; the share (0..1) of the last scans' points coloured, by camera."""

    scans_coloured: int
    scans_skipped: int
    coloured_share: float
    camera_shares: dict[str, float]


def colouring_of(msg: Any) -> ColouringStatus | None:
    """A decoded ``acq.Status``'s colouring (None: no live colouring, or an older log)."""
    if "colouring" not in msg.DESCRIPTOR.fields_by_name or not msg.HasField("colouring"):
        return None
    c = msg.colouring
    shares = {s.camera: s.share for s in c.cameras}
    return ColouringStatus(c.scans_coloured, c.scans_skipped, c.coloured_share, shares)


_DEVICE_STATUS_KEYS = frozenset(f.name for f in fields(DeviceStatus))


def _device_status(d: DeviceStatus | Mapping[str, Any]) -> DeviceStatus:
    if isinstance(d, DeviceStatus):
        return d
    unknown = sorted(set(d) - _DEVICE_STATUS_KEYS)
    if unknown:
        raise ValueError(f"unknown DeviceStatus field(s): {', '.join(unknown)}")
    return DeviceStatus(**d)


def status(
    *,
    timestamp_ns: int,
    uptime_s: float,
    file: str = "",
    disk_free_bytes: int = 0,
    disk_minutes_left: float = math.inf,
    writer_queue: int = 0,
    devices: Iterable[DeviceStatus | Mapping[str, Any]] = (),
    colouring: ColouringStatus | None = None,
) -> bytes:
    """``acq.Status`` for ``/acq/status`` (1 Hz); ``devices`` as :class:`DeviceStatus` or
    plain dicts with the same keys; ``colouring`` when the recorder colours live."""
    msg = StatusMsg(
        uptime_s=uptime_s,
        file=file,
        disk_free_bytes=disk_free_bytes,
        disk_minutes_left=disk_minutes_left,
        writer_queue=writer_queue,
    )
    set_stamp(msg.timestamp, timestamp_ns)
    for d in devices:
        ds = _device_status(d)
        msg.devices.add(**{k: getattr(ds, k) for k in _DEVICE_STATUS_KEYS})
    if colouring is not None:
        msg.colouring.SetInParent()  # present even when every figure is 0
        for k in ("scans_coloured", "scans_skipped", "coloured_share"):
            setattr(msg.colouring, k, getattr(colouring, k))
        for camera, share in colouring.camera_shares.items():
            msg.colouring.cameras.add(camera=camera, share=share)
    return serialized(msg)


def odometry(odo: Odometry) -> bytes:
    """``acq.Odometry`` for ``/vehicle/odometry``: ``timestamp`` is ``odo.stamp_ns`` (the
    CAN receive stamp on the host monotonic clock); m/s, rad/s; NaN for what the CAN
    message does not carry."""
    msg = OdometryMsg(
        recv_ns=odo.recv_ns,
        speed_mps=odo.speed,
        yaw_rate_rps=odo.yaw_rate,
        wheel_speeds_mps=odo.wheel_speeds,
        arbitration_id=odo.arbitration_id,
    )
    set_stamp(msg.timestamp, odo.stamp_ns)
    return serialized(msg)


def can_frame(frame: CanFrame) -> bytes:
    """``acq.CanFrame`` for ``/vehicle/can``: the frame as received (re-decodable with any
    DBC), ``timestamp`` its receive stamp on the host monotonic clock, ``wall_ns`` the
    interface's own stamp."""
    msg = CanFrameMsg(
        recv_ns=frame.recv_ns,
        wall_ns=frame.wall_ns,
        arbitration_id=frame.arbitration_id,
        is_extended=frame.is_extended,
        is_remote=frame.is_remote,
        is_error=frame.is_error,
        is_fd=frame.is_fd,
        data=frame.data,
        channel=frame.channel,
    )
    set_stamp(msg.timestamp, frame.stamp_ns)
    return serialized(msg)


_HOST_CLOCK_PARTS: dict[str, type[Any]] = {
    "kernel": KernelClock,
    "chrony": ChronyTracking,
    "ptp": PtpTime,
    "pps": PpsSource,
    "gnss": GnssTime,
}


def time_base_record(reading: HostClock) -> bytes:
    """``acq.TimeBase`` for ``/acq/timebase``: one reading of the host clock's sources,
    stamped with its monotonic time; a source that is absent is left unset and its
    reason listed in ``absent`` ("chrony: chronyc not installed"), as is a source whose
    value the record cannot hold (a reading from outside: never an error of the writer)."""
    msg = TimeBaseMsg(
        realtime_ns=reading.realtime_ns,
        monotonic_ns=reading.monotonic_ns,
        synchronised=reading.synchronised,
    )
    set_stamp(msg.timestamp, reading.monotonic_ns)
    for name in _HOST_CLOCK_PARTS:
        part = getattr(reading, name)
        if isinstance(part, Absent):
            msg.absent.append(f"{name}: {part.why}")
            continue
        sub = getattr(msg, name)
        for f in fields(part):
            try:
                setattr(sub, f.name, getattr(part, f.name))
            except (ValueError, TypeError):
                msg.ClearField(name)
                msg.absent.append(f"{name}: {f.name} {getattr(part, f.name)!r:.40} out of range")
                break
    return serialized(msg)


def host_clock_of(msg: Any) -> HostClock:
    """The :class:`acq.time.host_clock.HostClock` an ``acq.TimeBase`` message holds."""
    why = dict(a.split(": ", 1) for a in msg.absent if ": " in a)
    parts: dict[str, Any] = {}
    for name, cls in _HOST_CLOCK_PARTS.items():
        if msg.HasField(name):
            sub = getattr(msg, name)
            parts[name] = cls(**{f.name: getattr(sub, f.name) for f in fields(cls)})
        else:
            parts[name] = Absent(why.get(name, "not recorded"))
    return HostClock(realtime_ns=int(msg.realtime_ns), monotonic_ns=int(msg.monotonic_ns), **parts)
