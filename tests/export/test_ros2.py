"""`acq export ros2`: a small log written as a rosbag2 and read back with rosbags."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from acq.cli import main as acq_main
from acq.export import export_ros2
from acq.export.log_clock import LogClock
from acq.log import schemas
from acq.log.timebase import MONOTONIC, TimeBase
from acq.log.writer import LogWriter

MONO0 = 5_000_000_000_000  # host monotonic ns at the log's start
UTC0 = 1_800_000_000_123_456_789  # the wall clock then
SCANS, FRAMES, ODOMETRY, FIXES = 20, 5, 25, 5
STEP = 40_000_000  # ns between scans
GEOMETRY = {"time_increment": 1e-4, "scan_period": 0.025, "range_min": 0.1, "range_max": 30.0}
# a log of today (UTC, its offset fixed at the start) whose wall clock was later stepped 5 ms
# (its clock pair says so: its own times must win), and one of before (host monotonic)
UTC_LOG = TimeBase(True, UTC0 - MONO0)
PAIR_STEP = {UTC_LOG: 5_000_000, MONOTONIC: 0}


def _write_log(
    directory: Path, split_s: float = 600.0, time_base: TimeBase = UTC_LOG
) -> list[Path]:
    """1 s: scans, frames, calibration, /tf_static, odometry, fixes and one clock pair
    (UTC = monotonic + UTC0 - MONO0), each message received 3 ms after its stamp."""
    cls = schemas.message_class
    meta = {
        "device.laser": {"geometry": json.dumps(GEOMETRY)},
        "device.camera": {"driver": "sim"},
    }
    w = LogWriter(directory, metadata=meta, split_s=split_s, time_base=time_base)

    def _stamp(msg: object, mono_ns: int) -> None:  # a Foxglove stamp on the log's clock
        ns = time_base.to_log(mono_ns)
        msg.timestamp.seconds, msg.timestamp.nanos = divmod(ns, 10**9)  # type: ignore[attr-defined]

    for topic, name in (
        ("/acq/clock", "acq.Clock"),
        ("/tf_static", "foxglove.FrameTransforms"),
        ("/camera/calibration", "foxglove.CameraCalibration"),
        ("/laser/scan", "foxglove.LaserScan"),
        ("/camera/image/compressed", "foxglove.CompressedImage"),
        ("/vehicle/odometry", "acq.Odometry"),
        ("/gnss/fix", "foxglove.LocationFix"),
        ("/acq/timing/laser", "acq.Timing"),
    ):
        w.add_channel(topic, schemas.SCHEMAS[name])
    pair = schemas.clock(realtime_ns=UTC0 + PAIR_STEP[time_base], monotonic_ns=MONO0)
    w.write("/acq/clock", pair, MONO0, MONO0)
    tf = cls("foxglove.FrameTransforms")()
    for parent, child, z in (("vehicle", "laser", 2.2), ("laser", "camera", 0.1)):
        t = tf.transforms.add(parent_frame_id=parent, child_frame_id=child)
        _stamp(t, MONO0)
        t.translation.z, t.rotation.w = z, 1.0
    w.set_latched("/tf_static", tf.SerializeToString(), MONO0)
    cal = cls("foxglove.CameraCalibration")(
        frame_id="camera", width=640, height=480, distortion_model="kannala_brandt"
    )
    _stamp(cal, MONO0)
    cal.D.extend([0.1, -0.01, 0.001, 0.0])
    cal.K.extend([300.0, 0, 320, 0, 300, 240, 0, 0, 1])
    cal.R.extend([1.0, 0, 0, 0, 1, 0, 0, 0, 1])
    cal.P.extend([300.0, 0, 320, 0, 0, 300, 240, 0, 0, 0, 1, 0])
    w.set_latched("/camera/calibration", cal.SerializeToString(), MONO0)
    out: list[tuple[int, str, bytes, int]] = []  # written in log-time order, as recorded
    rng = np.random.default_rng(0)
    for i in range(SCANS):
        t = MONO0 + 1_000_000 + i * STEP
        scan = cls("foxglove.LaserScan")(frame_id="laser", start_angle=-2.0, end_angle=2.0)
        _stamp(scan, t)
        scan.ranges.extend(rng.uniform(1, 20, 101).tolist())
        scan.intensities.extend(rng.uniform(0, 1000, 101).tolist())
        out.append((t + 3_000_000, "/laser/scan", scan.SerializeToString(), t))
        out.append((t + 3_000_000, "/acq/timing/laser", b"", t))
    for i in range(FRAMES):
        t = MONO0 + 20_000_000 + i * 200_000_000
        img = cls("foxglove.CompressedImage")(frame_id="camera", format="jpeg")
        img.data = bytes([0xFF, 0xD8, i, 0xFF, 0xD9])
        _stamp(img, t)
        out.append((t + 3_000_000, "/camera/image/compressed", img.SerializeToString(), t))
    for i in range(ODOMETRY):
        t = MONO0 + i * 40_000_000  # 5 m/s, 0.1 rad/s
        odo = cls("acq.Odometry")(recv_ns=t, speed_mps=5.0, yaw_rate_rps=0.1)
        odo.timestamp.seconds, odo.timestamp.nanos = divmod(t, 10**9)  # acq.*: monotonic
        out.append((t, "/vehicle/odometry", odo.SerializeToString(), t))
    for i in range(FIXES):
        t = MONO0 + i * 200_000_000
        fix = cls("foxglove.LocationFix")(
            frame_id="gnss", latitude=48.0 + i * 1e-5, longitude=2.0, altitude=35.0
        )
        fix.position_covariance.extend([0.0] * 9)
        fix.metadata.add(key="quality", value="4")
        _stamp(fix, t)
        out.append((t + 3_000_000, "/gnss/fix", fix.SerializeToString(), t))
    for log_ns, topic, data, stamp in sorted(out):
        w.write(topic, data, log_ns, stamp)
    w.close()
    return w.files


@pytest.fixture(scope="module", params=[UTC_LOG, MONOTONIC], ids=["utc", "monotonic"])
def bag(
    tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> tuple[Path, dict[str, list[tuple[int, object]]]]:
    """The bag of a log of today (UTC) and of one written before (host monotonic): the
    same stamps."""
    d = tmp_path_factory.mktemp("ros2")
    (log,) = _write_log(d / "log", time_base=request.param)
    out = d / "bag"
    assert acq_main(["export", "ros2", str(log), "-o", str(out)]) == 0
    typestore = get_typestore(Stores.ROS2_JAZZY)
    read: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([out], default_typestore=typestore) as reader:
        assert reader.connections
        for conn, timestamp, raw in reader.messages():
            read.setdefault(conn.topic, []).append(
                (timestamp, reader.deserialize(raw, conn.msgtype))
            )
    return out, read


def _ns(header: object) -> int:
    return header.stamp.sec * 10**9 + header.stamp.nanosec  # type: ignore[attr-defined]


def utc(mono_ns: int) -> int:
    return mono_ns - MONO0 + UTC0


def test_every_message_with_its_type_counted(bag: tuple[Path, dict]) -> None:
    out, read = bag
    counts = {topic: len(msgs) for topic, msgs in read.items()}
    assert counts == {
        "/tf_static": 1, "/camera/camera_info": FRAMES, "/laser/scan": SCANS,
        "/camera/image/compressed": FRAMES, "/odom": ODOMETRY, "/tf": ODOMETRY,
        "/gnss/fix": FIXES,
    }  # fmt: skip
    meta = (out / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in meta and "serialization_format: cdr" in meta
    assert "durability: transient_local" in meta  # /tf_static latched for late joiners
    with (out / "bag.mcap").open("rb") as f:  # in time order, as a recorder writes
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert times == sorted(times) and len(times) == sum(counts.values())


def test_foxglove_decodes_the_bag_as_rosbags_does(bag: tuple[Path, dict]) -> None:
    """mcap-ros2-support (Foxglove's decoder) reads every message from the bag's MCAP
    schemas alone: the same topics, types, counts and stamps."""
    from mcap_ros2.decoder import DecoderFactory

    out, read = bag
    seen: dict[str, list[int]] = {}
    with (out / "bag.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _, msg in reader.iter_decoded_messages(log_time_order=False):
            assert schema is not None and schema.encoding == "ros2msg"
            assert channel.message_encoding == "cdr"
            header = msg.transforms[0].header if hasattr(msg, "transforms") else msg.header
            seen.setdefault(channel.topic, []).append(_ns(header))
    stamps = {}
    for topic, msgs in read.items():
        stamps[topic] = [
            _ns(m.transforms[0].header if hasattr(m, "transforms") else m.header) for _, m in msgs
        ]
    assert seen == stamps


def test_scans_stamped_at_their_first_point_in_utc_with_their_fields(
    bag: tuple[Path, dict],
) -> None:
    _, read = bag
    for i, (received, scan) in enumerate(read["/laser/scan"]):
        t = MONO0 + 1_000_000 + i * STEP
        assert _ns(scan.header) == utc(t) and received == utc(t + 3_000_000)
        assert scan.header.frame_id == "laser"
        assert scan.angle_min == pytest.approx(-2.0) and scan.angle_max == pytest.approx(2.0)
        assert scan.angle_increment == pytest.approx(0.04)
        assert scan.time_increment == pytest.approx(1e-4)
        assert scan.scan_time == pytest.approx(0.025)
        assert (scan.range_min, scan.range_max) == pytest.approx((0.1, 30.0))
        assert scan.ranges.dtype == np.float32 and scan.ranges.size == 101
        assert scan.intensities.dtype == np.float32 and scan.intensities.size == 101
    rng = np.random.default_rng(0)
    first = read["/laser/scan"][0][1]
    np.testing.assert_array_equal(first.ranges, rng.uniform(1, 20, 101).astype(np.float32))


def test_images_calibration_and_static_frames(bag: tuple[Path, dict]) -> None:
    _, read = bag
    for i, (_, img) in enumerate(read["/camera/image/compressed"]):
        assert _ns(img.header) == utc(MONO0 + 20_000_000 + i * 200_000_000)
        assert img.header.frame_id == "camera_optical" and img.format == "jpeg"
        assert bytes(img.data) == bytes([0xFF, 0xD8, i, 0xFF, 0xD9])
    infos = read["/camera/camera_info"]
    images = read["/camera/image/compressed"]
    assert len(infos) == len(images)  # each image with its camera_info, as image_proc pairs them
    for (received, info), (img_received, img) in zip(infos, images, strict=True):
        assert _ns(info.header) == _ns(img.header) and received == img_received
        assert info.header.frame_id == "camera_optical" and (info.width, info.height) == (640, 480)
        assert info.distortion_model == "equidistant"
        assert info.d.tolist() == [0.1, -0.01, 0.001, 0.0]
        assert info.k[0] == 300.0 and info.p[2] == 320.0
    tfs = read["/tf_static"][0][1].transforms
    pairs = [(t.header.frame_id, t.child_frame_id) for t in tfs]
    assert pairs == [("base_link", "laser"), ("laser", "camera_optical")]
    assert tfs[0].transform.translation.z == pytest.approx(2.2)
    assert _ns(tfs[0].header) == utc(MONO0)


def test_odometry_and_tf_dead_reckoned_and_fixes(bag: tuple[Path, dict]) -> None:
    _, read = bag
    odom, tf = read["/odom"], read["/tf"]
    for i in range(ODOMETRY):
        o = odom[i][1]
        t = tf[i][1].transforms[0]
        assert _ns(o.header) == utc(MONO0 + i * 40_000_000) == _ns(t.header)
        assert (o.header.frame_id, o.child_frame_id) == ("odom", "base_link")
        assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
        assert o.twist.twist.linear.x == 5.0 and o.twist.twist.angular.z == 0.1
        assert t.transform.translation.x == o.pose.pose.position.x
    last = odom[-1][1].pose.pose
    # 0.96 s at 5 m/s and 0.1 rad/s: an arc of 4.8 m turning 0.096 rad
    assert last.position.x == pytest.approx(10 * np.sin(0.096) * 5, rel=1e-6)
    assert 2 * np.arctan2(last.orientation.z, last.orientation.w) == pytest.approx(0.096)
    for i, (_, fix) in enumerate(read["/gnss/fix"]):
        assert _ns(fix.header) == utc(MONO0 + i * 200_000_000)
        assert fix.header.frame_id == "gnss" and fix.status.status == 2  # RTK: GBAS
        assert fix.latitude == 48.0 + i * 1e-5 and fix.altitude == 35.0


def test_an_existing_bag_is_kept_unless_acq_wrote_it_or_force(
    bag: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, _ = bag
    log = next((out.parent / "log").glob("*.mcap"))
    assert acq_main(["export", "ros2", str(log), "-o", str(out)]) == 0  # acq's own
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert acq_main(["export", "ros2", str(log), "-o", str(other)]) == 2
    assert "--force" in capsys.readouterr().err and (other / "notes.txt").exists()
    assert acq_main(["export", "ros2", str(log), "-o", str(other), "--force"]) == 0
    assert (other / "metadata.yaml").exists() and not (other / "notes.txt").exists()
    assert (tmp_path / "other.bak" / "notes.txt").read_text() == "mine"  # kept aside


def test_force_never_deletes_other_sessions_files(
    bag: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder of logs and a calibration given as BAG: refused naming them; --force
    keeps the folder whole beside (BAG.bak), and refuses when that name is taken."""
    out, _ = bag
    log = next((out.parent / "log").glob("*.mcap"))
    logs = tmp_path / "logs"
    logs.mkdir()
    mine = {"other.mcap": log.read_bytes(), "calib.yaml": b"cameras: {}\n"}
    for name, data in mine.items():
        (logs / name).write_bytes(data)
    capsys.readouterr()
    assert acq_main(["export", "ros2", str(log), "-o", str(logs)]) == 2
    err = capsys.readouterr().err
    assert "calib.yaml, other.mcap" in err and "acq did not write" in err
    assert len(err.strip().splitlines()) == 1
    (tmp_path / "logs.bak").mkdir()  # where --force would keep it: taken
    assert acq_main(["export", "ros2", str(log), "-o", str(logs), "--force"]) == 2
    assert "logs.bak exists" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in logs.iterdir()} == mine
    (tmp_path / "logs.bak").rmdir()
    assert acq_main(["export", "ros2", str(log), "-o", str(logs), "--force"]) == 0
    kept = tmp_path / "logs.bak"
    assert {p.name: p.read_bytes() for p in kept.iterdir()} == mine
    assert (logs / "metadata.yaml").exists() and (logs / "logs.mcap").exists()
    assert not (logs / "other.mcap").exists()


def test_a_file_added_to_acqs_bag_survives_a_new_export(
    bag: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bag acq wrote is replaced only while it holds acq's files alone."""
    out, _ = bag
    log = next((out.parent / "log").glob("*.mcap"))
    again = tmp_path / "again"
    assert acq_main(["export", "ros2", str(log), "-o", str(again)]) == 0
    (again / "notes.txt").write_text("mine")
    (again / "extra").mkdir()
    before = {p.name for p in again.iterdir()}
    capsys.readouterr()
    assert acq_main(["export", "ros2", str(log), "-o", str(again)]) == 2
    err = capsys.readouterr().err
    assert "extra, notes.txt" in err and "metadata.yaml" not in err
    assert {p.name for p in again.iterdir()} == before
    assert (again / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("given", [".", "..", "sub/..", "/"])
def test_the_current_folder_or_one_holding_it_is_refused_in_one_line(
    bag: tuple[Path, dict],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    given: str,
) -> None:
    out, _ = bag
    log = next((out.parent / "log").glob("*.mcap"))
    here = tmp_path / "here"
    (here / "sub").mkdir(parents=True)
    (here / "mine.txt").write_text("mine")
    monkeypatch.chdir(here)
    capsys.readouterr()
    assert acq_main(["export", "ros2", str(log), "-o", given, "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "current folder" in err[0] and f"-o {given}" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["here"]
    assert sorted(p.name for p in here.iterdir()) == ["mine.txt", "sub"]


def test_a_utc_log_keeps_its_own_times() -> None:
    assert LogClock(TimeBase(True, 7), np.zeros((0, 2))).to_utc(123) == 130
    pairs = np.array([[10, 1_000_010], [1_000, 1_001_010]])  # the wall clock gained 10 ns
    assert LogClock(MONOTONIC, pairs).to_utc(505) == 1_000_510


def test_a_log_without_clock_pairs_is_refused(tmp_path: Path) -> None:
    from acq.errors import InputValueError

    with pytest.raises(InputValueError, match="/acq/clock"):
        LogClock(MONOTONIC, np.zeros((0, 2)))


def test_a_split_sessions_latched_messages_go_in_once(tmp_path: Path) -> None:
    """Each file of a split session starts with /tf_static and the calibration again:
    /tf_static goes in once, camera_info once per image."""
    files = _write_log(tmp_path / "log", split_s=0.3)
    assert len(files) >= 3
    report = export_ros2(files, tmp_path / "bag")
    assert report.counts == {
        "/tf_static": 1, "/camera/camera_info": FRAMES, "/laser/scan": SCANS,
        "/camera/image/compressed": FRAMES, "/odom": ODOMETRY, "/tf": ODOMETRY,
        "/gnss/fix": FIXES,
    }  # fmt: skip
    assert report.left_out == {"/acq/timing/laser": SCANS} and report.utc
