"""acq.log.schemas: the Foxglove and acq.* encoders round trip and carry what they promise."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from google.protobuf import descriptor_pb2
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.records import Schema as McapSchema
from mcap_protobuf.decoder import DecoderFactory

from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import Equidistant, KannalaBrandt, Pinhole
from acq.geometry.rotations import matrix_from_quat, rotation_from_euler
from acq.geometry.transforms import Rigid
from acq.log import schemas
from acq.log.cloud_message import point_cloud
from acq.records import CanFrame, CovarianceType, Fix, Frame, Odometry, Scan
from acq.time.absent import Absent
from acq.time.chrony import ChronyTracking, parse_tracking
from acq.time.host_clock import GnssTime, HostClock
from acq.time.kernel_clock import KernelClock
from acq.time.pps import PpsSource
from acq.time.ptp import PtpTime

FOXGLOVE = [
    "foxglove.LaserScan",
    "foxglove.CompressedImage",
    "foxglove.CameraCalibration",
    "foxglove.FrameTransforms",
    "foxglove.PointCloud",
    "foxglove.LocationFix",
]
ACQ = [
    "acq.TimeBase",
    "acq.RawTelegram",
    "acq.Timing",
    "acq.Clock",
    "acq.Status",
    "acq.DeviceStatus",
    "acq.Odometry",
    "acq.CanFrame",
]
STAMP = 1_234_567_890_123  # host monotonic ns


def make_scan(n: int = 1081, intensities: bool = True) -> Scan:
    rng = np.random.default_rng(1)
    ranges = rng.uniform(0.1, 30.0, n).astype(np.float32)
    if n > 10:
        ranges[::50] = np.inf
        ranges[7] = -np.inf
        ranges[9] = np.nan
    return Scan(
        ranges=ranges,
        intensities=rng.uniform(0, 5000, n).astype(np.float32) if intensities else np.zeros(0),
        angle_min=-math.radians(135),
        angle_increment=math.radians(0.25),
        time_increment=25e-3 / 1440,
        scan_period=25e-3,
        recv_ns=STAMP,
    )


def decode_with_mcap(name: str, data: bytes) -> Any:
    """Decode through mcap_protobuf, which builds its own pool from the schema's data."""
    schema = schemas.SCHEMAS[name]
    record = McapSchema(id=1, name=schema.name, encoding=schema.encoding, data=schema.data)
    decoder = DecoderFactory().decoder_for("protobuf", record)
    assert decoder is not None
    return decoder(data)


def ts_ns(ts: object) -> int:
    return ts.seconds * 1_000_000_000 + ts.nanos  # type: ignore[attr-defined]


# --- the schemas ---------------------------------------------------------------------------


def test_schemas_are_named_and_self_contained() -> None:
    assert set(schemas.SCHEMAS) == set(FOXGLOVE + ACQ)
    for name, schema in schemas.SCHEMAS.items():
        assert schema.name == name and schema.encoding == "protobuf"
        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        files = [f.name for f in fds.file]
        assert len(files) == len(set(files))
        # every dependency comes before the file that needs it
        for i, f in enumerate(fds.file):
            assert set(f.dependency) <= set(files[:i]), (name, f.name)
    acq_files = descriptor_pb2.FileDescriptorSet.FromString(schemas.SCHEMAS["acq.Timing"].data)
    assert [f.name for f in acq_files.file] == ["google/protobuf/timestamp.proto", "acq/v1.proto"]
    assert acq_files.file[1].package == "acq"


def test_unknown_schema_is_a_clear_error() -> None:
    with pytest.raises(KeyError, match=r"unknown schema 'foxglove\.Nope'"):
        schemas.decode("foxglove.Nope", b"")


# --- Foxglove messages ---------------------------------------------------------------------


def test_laser_scan_matches_a_plainly_built_message() -> None:
    scan = make_scan()
    data = schemas.laser_scan(scan, "laser", STAMP)
    msg = schemas.decode("foxglove.LaserScan", data)
    ref = LaserScan(frame_id="laser", start_angle=scan.angle_min)
    ref.timestamp.FromNanoseconds(STAMP)
    ref.pose.orientation.w = 1.0
    ref.end_angle = scan.angle_min + (scan.size - 1) * scan.angle_increment
    ref.ranges.extend(scan.ranges.tolist())
    ref.intensities.extend(scan.intensities.tolist())
    assert msg.SerializeToString() == ref.SerializeToString()
    assert ts_ns(msg.timestamp) == STAMP
    assert msg.pose.orientation.w == 1.0 and msg.pose.position.x == 0.0
    r = np.array(msg.ranges)
    np.testing.assert_array_equal(r, scan.ranges.astype(np.float64))  # inf/-inf/nan kept
    assert np.isposinf(r[0]) and np.isneginf(r[7]) and np.isnan(r[9])
    assert math.isclose(msg.end_angle, math.radians(135), abs_tol=1e-12)
    assert (
        decode_with_mcap("foxglove.LaserScan", data).SerializeToString() == msg.SerializeToString()
    )


def test_laser_scan_without_intensities_or_points() -> None:
    msg = schemas.decode("foxglove.LaserScan", schemas.laser_scan(make_scan(5, False), "l", 1))
    assert len(msg.ranges) == 5 and len(msg.intensities) == 0
    empty = Scan(np.zeros(0), np.zeros(0), 0.5, 0.01, 0.0, 0.0, recv_ns=0)
    msg = schemas.decode("foxglove.LaserScan", schemas.laser_scan(empty, "l", 1))
    assert len(msg.ranges) == 0 and msg.start_angle == msg.end_angle == 0.5


def test_compressed_image_keeps_the_jpeg() -> None:
    jpeg = b"\xff\xd8" + bytes(range(256)) * 200 + b"\xff\xd9"
    frame = Frame(recv_ns=STAMP + 9, stamp_ns=STAMP, sequence=3, width=780, height=582, jpeg=jpeg)
    msg = schemas.decode(
        "foxglove.CompressedImage", schemas.compressed_image(frame, "camera", STAMP)
    )
    assert msg.data == jpeg and msg.format == "jpeg" and msg.frame_id == "camera"
    assert ts_ns(msg.timestamp) == STAMP
    raw = Frame(0, 0, 0, 2, 1, image=np.zeros((1, 2, 3), np.uint8))
    with pytest.raises(ValueError, match="jpeg"):
        schemas.compressed_image(raw, "camera", 0)


def _library_compressed_image(jpeg: bytes, frame_id: str, stamp_ns: int) -> bytes:
    """The protobuf library's bytes of the same message (what the recorder wrote before)."""
    msg = CompressedImage(frame_id=frame_id, data=jpeg, format="jpeg")
    schemas.set_stamp(msg.timestamp, stamp_ns)
    return schemas.serialized(msg)


@settings(max_examples=300, deadline=None)
@given(
    jpeg=st.binary(min_size=1, max_size=300),
    frame_id=st.text(max_size=40),
    stamp_ns=st.integers(min_value=-(1 << 70), max_value=1 << 72),
)
def test_compressed_image_bytes_are_the_protobuf_librarys(
    jpeg: bytes, frame_id: str, stamp_ns: int
) -> None:
    try:
        expected = _library_compressed_image(jpeg, frame_id, stamp_ns)
    except ValueError:  # out of a Timestamp's int64 seconds: both refuse it
        with pytest.raises(ValueError):
            schemas.compressed_image_bytes(jpeg, frame_id, stamp_ns)
        return
    assert schemas.compressed_image_bytes(jpeg, frame_id, stamp_ns) == expected


def test_compressed_image_bytes_of_real_captures(shared_dir: Path) -> None:
    """Byte for byte the library's, for the real fisheye JPEGs and the stamps of a log
    (UTC ns, whole seconds, zero, a long frame name)."""
    paths = sorted((shared_dir / "data" / "fisheye").glob("*.jpg"))
    if not paths:
        pytest.skip("no fisheye JPEGs in ../shared/data/fisheye")
    for path in paths:
        jpeg = path.read_bytes()
        for stamp in (0, 1, 10**9, STAMP, 1_764_969_600_123_456_789, 2**62):
            for name in ("camera", "", "camera_2" * 40, "caméra"):
                got = schemas.compressed_image_bytes(jpeg, name, stamp)
                assert got == _library_compressed_image(jpeg, name, stamp)


def test_camera_calibration_equidistant_is_kannala_brandt_with_zero_d() -> None:
    cam = CameraCalib(Equidistant.from_f(169.3, 390.2, 291.1, 780, 582))
    data = schemas.camera_calibration(cam, "camera", STAMP)
    msg = schemas.decode("foxglove.CameraCalibration", data)
    assert msg.distortion_model == "kannala_brandt"
    assert list(msg.D) == [0.0] * 4
    assert (msg.width, msg.height, msg.frame_id) == (780, 582, "camera")
    np.testing.assert_allclose(
        np.reshape(msg.K, (3, 3)), np.array([[169.3, 0, 390.2], [0, 169.3, 291.1], [0, 0, 1]])
    )
    np.testing.assert_array_equal(np.reshape(msg.R, (3, 3)), np.eye(3))
    P = np.reshape(msg.P, (3, 4))
    np.testing.assert_array_equal(P[:, :3], np.reshape(msg.K, (3, 3)))
    np.testing.assert_array_equal(P[:, 3], 0.0)
    assert ts_ns(msg.timestamp) == STAMP
    assert (
        decode_with_mcap("foxglove.CameraCalibration", data).SerializeToString()
        == msg.SerializeToString()
    )


def test_camera_calibration_kannala_brandt_and_pinhole() -> None:
    kb = KannalaBrandt(640, 480, 300.0, 301.0, 320.0, 240.0, k=(0.01, -0.002, 0.0003, -0.00004))
    msg = schemas.decode(
        "foxglove.CameraCalibration", schemas.camera_calibration(CameraCalib(kb), "c", 0)
    )
    assert msg.distortion_model == "kannala_brandt"
    np.testing.assert_array_equal(msg.D, kb.k)
    assert msg.K[4] == 301.0
    ph = Pinhole(640, 480, 500.0, 500.0, 320.0, 240.0, dist=(-0.1, 0.01, 0.001, -0.002, 0.003))
    msg = schemas.decode(
        "foxglove.CameraCalibration", schemas.camera_calibration(CameraCalib(ph), "c", 0)
    )
    assert msg.distortion_model == "plumb_bob"
    np.testing.assert_array_equal(msg.D, ph.dist)


def test_frame_transforms_hold_each_cameras_pose_in_the_laser_frame() -> None:
    R = rotation_from_euler(0.1, -1.2, 2.5)
    t = np.array([0.12, -0.05, 0.3])
    ltv = Rigid(rotation_from_euler(0, 0, 0.3), np.array([1.0, 0.0, 1.8]))
    model = Equidistant.from_f(169.3, 390.2, 291.1, 780, 582)
    calib = Calibration(
        laser="lidar",
        cameras={"front": CameraCalib(model, Rigid(R, t)), "back": CameraCalib(model)},
        laser_to_vehicle=ltv,
    )
    data = schemas.frame_transforms(calib, STAMP, {"front": "front_optical"})
    msg = schemas.decode("foxglove.FrameTransforms", data)
    by_child = {tf.child_frame_id: tf for tf in msg.transforms}
    assert set(by_child) == {"front_optical", "back", "lidar"}
    for child, parent, pose in (
        ("front_optical", "lidar", Rigid(R, t)),
        ("back", "lidar", Rigid.identity()),
        ("lidar", "vehicle", ltv),
    ):
        tf = by_child[child]
        assert tf.parent_frame_id == parent and ts_ns(tf.timestamp) == STAMP
        q = (tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z)  # Foxglove: x, y, z, w
        # a parent -> child transform maps child-frame points into the parent frame
        P_child = np.array([[1.0, 2.0, 3.0], [-0.5, 0.2, 4.0]])
        P_parent = P_child @ matrix_from_quat(q).T + [
            tf.translation.x,
            tf.translation.y,
            tf.translation.z,
        ]
        np.testing.assert_allclose(P_parent, pose.apply(P_child), atol=1e-12)
    no_vehicle = Calibration(cameras={"camera": CameraCalib(model)})
    msg = schemas.decode("foxglove.FrameTransforms", schemas.frame_transforms(no_vehicle, 0))
    assert [(tf.parent_frame_id, tf.child_frame_id) for tf in msg.transforms] == [
        ("laser", "camera")
    ]


def test_point_cloud_layout() -> None:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(100, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(100, 3), dtype=np.uint8)
    data = point_cloud(points, rgb, "laser", STAMP)
    msg = schemas.decode("foxglove.PointCloud", data)
    assert msg.point_stride == 16 and msg.frame_id == "laser" and ts_ns(msg.timestamp) == STAMP
    assert [(f.name, f.offset) for f in msg.fields] == [
        ("x", 0), ("y", 4), ("z", 8), ("red", 12), ("green", 13), ("blue", 14), ("alpha", 15)
    ]  # fmt: skip
    assert msg.pose.orientation.w == 1.0
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(100, 16)
    np.testing.assert_array_equal(raw[:, :12].copy().view("<f4"), points)
    np.testing.assert_array_equal(raw[:, 12:15], rgb)
    assert np.all(raw[:, 15] == 255)
    alpha = (np.arange(100) % 2 * 255).astype(np.uint8)
    see_through = schemas.decode(
        "foxglove.PointCloud", point_cloud(points, rgb, "laser", STAMP, alpha)
    )
    np.testing.assert_array_equal(np.frombuffer(see_through.data, np.uint8)[15::16], alpha)
    assert (
        decode_with_mcap("foxglove.PointCloud", data).SerializeToString() == msg.SerializeToString()
    )
    empty = schemas.decode(
        "foxglove.PointCloud", point_cloud(np.zeros((0, 3)), np.zeros((0, 3)), "l", 0)
    )
    assert empty.data == b""
    with pytest.raises(ValueError, match=r"\(N,3\)"):
        point_cloud(np.zeros((4, 2)), np.zeros((4, 3)), "l", 0)
    with pytest.raises(ValueError, match="rgb"):
        point_cloud(np.zeros((4, 3)), np.zeros((3, 3)), "l", 0)


# --- acq.* messages ------------------------------------------------------------------------


def test_raw_telegram() -> None:
    telegram = b"MD0044072501000\n\x00\x01\xff"
    data = schemas.raw_telegram(
        device="laser",
        data=telegram,
        recv_ns=STAMP + 5,
        stamp_ns=STAMP,
        device_ticks=(2**24 - 1, 12),
        sequence=7,
    )
    msg = schemas.decode("acq.RawTelegram", data)
    assert msg.data == telegram and msg.device == "laser" and msg.sequence == 7
    assert list(msg.device_ticks) == [2**24 - 1, 12]
    assert msg.recv_ns == STAMP + 5 and ts_ns(msg.timestamp) == STAMP
    assert decode_with_mcap("acq.RawTelegram", data).SerializeToString() == msg.SerializeToString()
    only_recv = schemas.decode(
        "acq.RawTelegram", schemas.raw_telegram(device="d", data=b"", recv_ns=99)
    )
    assert ts_ns(only_recv.timestamp) == 99


def test_timing_and_clock() -> None:
    data = schemas.timing(
        recv_ns=STAMP,
        stamp_ns=STAMP - 3_000_000,
        device_ticks=[4_000_000_000],
        unwrapped_tick=2**40,
        epoch=2,
        offset_ns=-17,
        drift_ppm=12.5,
        uncertainty_s=2e-4,
        sequence=9,
        received=100,
        dropped=3,
    )
    msg = schemas.decode("acq.Timing", data)
    assert (msg.recv_ns, msg.stamp_ns, msg.unwrapped_tick, msg.epoch) == (
        STAMP,
        STAMP - 3_000_000,
        2**40,
        2,
    )
    assert list(msg.device_ticks) == [4_000_000_000]
    assert (msg.offset_ns, msg.drift_ppm, msg.uncertainty_s) == (-17, 12.5, 2e-4)
    assert (msg.sequence, msg.received, msg.dropped) == (9, 100, 3)
    assert decode_with_mcap("acq.Timing", data).SerializeToString() == msg.SerializeToString()
    clock = schemas.decode(
        "acq.Clock", schemas.clock(realtime_ns=1_700_000_000 * 10**9, monotonic_ns=STAMP)
    )
    assert clock.realtime_ns == 1_700_000_000 * 10**9 and clock.monotonic_ns == STAMP


def test_status_from_dataclasses_and_dicts() -> None:
    laser = schemas.DeviceStatus(
        name="laser",
        kind="scanner",
        connected=True,
        rate_hz=40.0,
        received=4000,
        dropped=2,
        corrupt=1,
        disconnects=1,
        protocol_errors=3,
        gap_s=0.025,
        last_event="reconnected",
        clock_offset_ns=-123456,
        clock_drift_ppm=-3.5,
        clock_uncertainty_s=1e-4,
        epoch=1,
    )
    data = schemas.status(
        timestamp_ns=STAMP,
        uptime_s=100.5,
        file="logs/acq_x_000.mcap",
        disk_free_bytes=10**12,
        disk_minutes_left=600.0,
        writer_queue=4,
        devices=[laser, {"name": "camera", "kind": "camera", "gap_s": 3.0}],
    )
    msg = schemas.decode("acq.Status", data)
    assert ts_ns(msg.timestamp) == STAMP and msg.uptime_s == 100.5
    assert (msg.file, msg.disk_free_bytes, msg.disk_minutes_left, msg.writer_queue) == (
        "logs/acq_x_000.mcap",
        10**12,
        600.0,
        4,
    )
    d0, d1 = msg.devices
    assert (d0.name, d0.kind, d0.connected, d0.rate_hz, d0.received, d0.dropped) == (
        "laser",
        "scanner",
        True,
        40.0,
        4000,
        2,
    )
    assert (d0.corrupt, d0.disconnects, d0.protocol_errors, d0.gap_s, d0.last_event) == (
        1,
        1,
        3,
        0.025,
        "reconnected",
    )
    assert (d0.clock_offset_ns, d0.clock_drift_ppm, d0.clock_uncertainty_s, d0.epoch) == (
        -123456,
        -3.5,
        1e-4,
        1,
    )
    assert (d1.name, d1.kind, d1.connected, d1.gap_s) == ("camera", "camera", False, 3.0)
    assert math.isnan(d1.clock_uncertainty_s)  # unknown, not "perfect"
    assert decode_with_mcap("acq.Status", data).SerializeToString() == msg.SerializeToString()
    with pytest.raises(ValueError, match=r"unknown DeviceStatus field.*ratee_hz"):
        schemas.status(
            timestamp_ns=0, uptime_s=0, devices=[{"name": "x", "kind": "camera", "ratee_hz": 1}]
        )


# --- vehicle messages ----------------------------------------------------------------------


def test_odometry_keeps_nan_for_what_the_message_lacks() -> None:
    odo = Odometry(STAMP + 200_000, STAMP, 5.5, math.nan, (5.4, 5.6, 5.4, 5.6), 0x1A0)
    data = schemas.odometry(odo)
    for msg in (schemas.decode("acq.Odometry", data), decode_with_mcap("acq.Odometry", data)):
        assert ts_ns(msg.timestamp) == STAMP and msg.recv_ns == STAMP + 200_000
        assert msg.speed_mps == 5.5 and math.isnan(msg.yaw_rate_rps)
        assert list(msg.wheel_speeds_mps) == [5.4, 5.6, 5.4, 5.6]
        assert msg.arbitration_id == 0x1A0
    yaw = schemas.decode("acq.Odometry", schemas.odometry(Odometry(1, 1, math.nan, -0.25)))
    assert math.isnan(yaw.speed_mps) and yaw.yaw_rate_rps == -0.25 and not yaw.wheel_speeds_mps


def test_can_frame_keeps_the_frame_as_received() -> None:
    frame = CanFrame(STAMP + 90_000, STAMP, 1_795_000_000_123_456_789, 0x18FEF100,
                     bytes(range(8)), is_extended=True, channel="can0")  # fmt: skip
    data = schemas.can_frame(frame)
    for msg in (schemas.decode("acq.CanFrame", data), decode_with_mcap("acq.CanFrame", data)):
        assert ts_ns(msg.timestamp) == STAMP and msg.recv_ns == STAMP + 90_000
        assert msg.wall_ns == frame.wall_ns and msg.arbitration_id == 0x18FEF100
        assert msg.is_extended and not (msg.is_remote or msg.is_error or msg.is_fd)
        assert msg.data == bytes(range(8)) and msg.channel == "can0"


def test_location_fix_carries_the_fix_and_its_time() -> None:
    fix = Fix(STAMP + 50_000_000, 1_795_337_897.4, 48.8584, 2.2945, 81.5, 4, 14, 0.7,
              speed=10.0, course=math.radians(90.0), geoid_separation=44.6)  # fmt: skip
    data = schemas.location_fix(fix, STAMP)
    for msg in (
        schemas.decode("foxglove.LocationFix", data),
        decode_with_mcap("foxglove.LocationFix", data),
    ):
        assert ts_ns(msg.timestamp) == STAMP and msg.frame_id == "gnss"
        assert (msg.latitude, msg.longitude, msg.altitude) == (48.8584, 2.2945, 81.5)
        assert msg.heading == pytest.approx(math.pi / 2)
        assert msg.velocity.x == pytest.approx(10.0) and msg.velocity.y == pytest.approx(0.0)
        meta = {kv.key: kv.value for kv in msg.metadata}
        assert meta["utc"] == "2026-11-22T08:58:17.400Z" and meta["utc_s"] == "1795337897.400"
        assert (meta["quality"], meta["satellites"], meta["hdop"]) == ("4", "14", "0.7")
    no_fix = Fix(1, 1_795_337_897.5, math.nan, math.nan, math.nan)
    msg = schemas.decode("foxglove.LocationFix", schemas.location_fix(no_fix, 1))
    assert math.isnan(msg.latitude) and not msg.HasField("heading")
    assert not msg.HasField("velocity")


@pytest.mark.parametrize("kind", [CovarianceType.APPROXIMATED, CovarianceType.DIAGONAL_KNOWN])
def test_location_fix_carries_the_position_covariance(kind: CovarianceType) -> None:
    fix = Fix(1, 1_795_337_897.4, 48.8584, 2.2945, 81.5, 4, 14, 0.7, vdop=1.1,
              sigma_east=0.02, sigma_north=0.01, sigma_up=0.03, covariance_type=kind)  # fmt: skip
    msg = decode_with_mcap("foxglove.LocationFix", schemas.location_fix(fix, STAMP))
    assert msg.position_covariance_type == int(kind)
    expected = [0.0] * 9
    expected[0], expected[4], expected[8] = 0.02**2, 0.01**2, 0.03**2  # east, north, up
    assert list(msg.position_covariance) == pytest.approx(expected)
    assert {kv.key: kv.value for kv in msg.metadata}["vdop"] == "1.1"
    unknown = schemas.decode("foxglove.LocationFix", schemas.location_fix(Fix(1, 0.0, 1, 2, 3), 1))
    assert unknown.position_covariance_type == 0 and list(unknown.position_covariance) == [0] * 9


def test_a_time_base_record_keeps_every_source_and_why_one_is_absent() -> None:
    kernel = KernelClock(True, "ok", 0.012, 0.001, 2e-6, -3.5, True, False, 37)
    chrony = parse_tracking(
        "C0A80001,ntp.example,2,1796194607.25,0.0000012,-0.0000034,0.0000021,"
        "-12.345,0.001,0.002,0.004,0.0012,64.0,Normal"
    )
    reading = HostClock(
        realtime_ns=1_796_194_607_250_000_123,
        monotonic_ns=STAMP,
        kernel=kernel,
        chrony=chrony,
        ptp=PtpTime(-1.5e-7, True, "001122.fffe.334455"),
        pps=Absent("no PPS source"),
        gnss=GnssTime(0.0004, 0.05, 0.08),
    )
    data = schemas.time_base_record(reading)
    msg = decode_with_mcap("acq.TimeBase", data)  # a reader with only the schema's data
    assert ts_ns(msg.timestamp) == STAMP and msg.synchronised
    assert list(msg.absent) == ["pps: no PPS source"] and not msg.HasField("pps")
    assert schemas.host_clock_of(schemas.decode("acq.TimeBase", data)) == reading
    with_pps = HostClock(
        1, 2, Absent("adjtimex not available"), Absent("chronyc not installed"),
        Absent("ptp4l not running"), PpsSource("pps0", 7, 12.000001, 7, 12.1),
    )  # fmt: skip
    back = schemas.host_clock_of(schemas.decode("acq.TimeBase", schemas.time_base_record(with_pps)))
    assert back == with_pps and not back.synchronised


def test_a_time_base_source_the_record_cannot_hold_is_absent_not_an_error() -> None:
    chrony = ChronyTracking(2**40, "x", 2**33, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, "Normal")
    reading = HostClock(1, 2, Absent("adjtimex not available"), chrony,
                        Absent("ptp4l not running"), Absent("no PPS source"))  # fmt: skip
    msg = schemas.decode("acq.TimeBase", schemas.time_base_record(reading))
    assert not msg.HasField("chrony")
    assert list(msg.absent)[1] == "chrony: reference_id 1099511627776 out of range"
