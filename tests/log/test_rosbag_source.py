"""A ROS 2 bag read as an acq log: `acq export ros2`'s own bag through `acq info` and
`acq colorize` (the same cloud as the log's), a bag written by another tool (ROS names),
and broken bags (one line, exit 2; a bag cut short read up to the cut)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from acq.camera import calibfile
from acq.cli.main import main as acq_main
from acq.log.drive_log import read_log
from acq.log.vehicle_log import read_vehicle
from acq.sim.drive_log import write_drive_log
from acq.sim.world import default_rig

SECONDS = 1.5


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A short drive of the two-camera rig (left, right), its calib.yaml, and the bag
    `acq export ros2` made of it."""
    d = tmp_path_factory.mktemp("rosbag_drive")
    truth = write_drive_log(
        d / "log", SECONDS, rig=default_rig(cameras=2), configured_camera_latency_s=None
    )
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    (log,) = sorted((d / "log").glob("*.mcap"))
    bag = d / "bag"
    assert acq_main(["export", "ros2", str(log), "-o", str(bag)]) == 0
    return log, calib, bag


def _cloud(log: Path, calib: Path, out: Path, *options: str) -> np.ndarray:
    args = ["colorize", str(log), "--calib", str(calib), "-o", str(out), "--no-preview"]
    assert acq_main([*args, *options]) == 0
    return PlyData.read(str(out))["vertex"].data


def _rgb(v: np.ndarray) -> np.ndarray:
    return np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.int16)


def _xyz(v: np.ndarray) -> np.ndarray:
    return np.stack([v["x"], v["y"], v["z"]], axis=1)


def test_info_reads_the_export_as_a_log(
    drive: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    log, _, bag = drive
    original = read_log(log, cameras=["left", "right"], jpegs=False)
    assert acq_main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "a ROS 2 bag (rosbag2)" in out
    span = next(line for line in out.splitlines() if line.startswith("  span"))
    assert "monotonic" not in span and " UTC)" in span, span  # a bag's stamps are UTC
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith("  /")}
    assert rows["/laser/scan"][1:3] == ["foxglove.LaserScan", str(original.n_scans)]
    for camera in ("left", "right"):
        frames = original.cameras[camera].frame_ns.size
        assert rows[f"/{camera}/image/compressed"][2] == str(frames)
        assert rows[f"/{camera}/camera_info"][1:3] == ["sensor_msgs/msg/CameraInfo", str(frames)]
    assert rows["/vehicle/odometry"][1] == "acq.Odometry"


def test_colorize_gives_the_logs_cloud(drive: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """The same points; the log's scans are re-timed from their device ticks, which a
    bag does not carry: colours nearly equal. With the stamps as recorded for both, the
    same cloud."""
    log, calib, bag = drive
    a = _cloud(log, calib, tmp_path / "log.ply")
    b = _cloud(bag, calib, tmp_path / "bag.ply")
    assert a.size == b.size > 40_000
    d = np.abs(_rgb(a) - _rgb(b)).max(axis=1)
    assert np.mean(d <= 8) > 0.99
    assert np.mean(a["scalar_camera"] == b["scalar_camera"]) > 0.99
    a = _cloud(log, calib, tmp_path / "log_as_recorded.ply", "--no-retime")
    b = _cloud(bag, calib, tmp_path / "bag_as_recorded.ply", "--no-retime")
    assert a.size == b.size
    assert np.mean(np.abs(_rgb(a) - _rgb(b)).max(axis=1) <= 2) > 0.999
    assert np.nanmax(np.abs(_xyz(a) - _xyz(b))) < 1e-4  # m
    assert np.nanmax(np.abs(a["scalar_time"] - b["scalar_time"])) < 1e-5  # UTC s


def _without(bag: Path, topic: str, out: Path) -> None:
    """A copy of ``bag`` without ``topic`` (rosbags' reader and writer)."""
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader, Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {
            c.id: w.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, rihs01=c.digest)
            for c in reader.connections
            if c.topic != topic
        }
        for c, t, data in reader.messages():
            if c.id in conns:
                w.write(conns[c.id], t, data)


def test_without_odometry_tf_gives_the_trajectory(
    drive: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bag with /tf (odom -> base_link) and no /odom: placed with its poses, the same
    cloud as with the odometry they were dead-reckoned from."""
    _, calib, bag = drive
    tf_only = tmp_path / "tf_only"
    _without(bag, "/odom", tf_only)
    a = _cloud(bag, calib, tmp_path / "odom.ply", "--no-retime")
    b = _cloud(tf_only, calib, tmp_path / "tf.ply", "--no-retime")
    assert "trajectory: the log's odom -> base_link poses" in capsys.readouterr().out
    assert a.size == b.size
    assert np.nanmax(np.abs(_xyz(a) - _xyz(b))) < 1e-6  # m
    assert np.mean(np.abs(_rgb(a) - _rgb(b)).max(axis=1) == 0) > 0.999


def test_calib_camera_names_that_the_bag_lacks_are_named(
    drive: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, calib, bag = drive
    text = calib.read_text().replace("\n  left:", "\n  front:").replace("\n  right:", "\n  back:")
    renamed = tmp_path / "renamed.yaml"
    renamed.write_text(text)
    out = tmp_path / "cloud.ply"
    args = ["colorize", str(bag), "--calib", str(renamed), "-o", str(out), "--no-preview"]
    assert acq_main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "the log has left, right" in err
    assert not out.exists()


def _foreign_bag(path: Path, garbled: bool = False) -> None:
    """A bag as a ROS 2 recorder names things: /scan, /camera/image_raw/compressed, /odom
    (nav_msgs/Odometry), /fix; ``garbled``: one scan's payload cut short."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    t = store.types
    t0 = 1_800_000_000_000_000_000

    def header(ns: int, frame: str) -> object:
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id=frame,
        )

    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        kinds = {
            "/scan": "sensor_msgs/msg/LaserScan",
            "/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
            "/odom": "nav_msgs/msg/Odometry",
            "/fix": "sensor_msgs/msg/NavSatFix",
        }
        conns = {k: w.add_connection(k, v, typestore=store) for k, v in kinds.items()}
        vec, zero36 = t["geometry_msgs/msg/Vector3"], np.zeros(36)
        for i in range(10):
            ns = t0 + i * 25_000_000
            scan = t["sensor_msgs/msg/LaserScan"](
                header=header(ns, "laser_frame"), angle_min=-1.0, angle_max=1.0,
                angle_increment=0.02, time_increment=2e-5, scan_time=0.025, range_min=0.1,
                range_max=30.0, ranges=np.full(101, 5.0 + i, np.float32),
                intensities=np.zeros(0, np.float32),
            )  # fmt: skip
            data = store.serialize_cdr(scan, "sensor_msgs/msg/LaserScan")
            w.write(conns["/scan"], ns, data[:20] if garbled and i == 3 else data)
            odo = t["nav_msgs/msg/Odometry"](
                header=header(ns, "odom"), child_frame_id="base_link",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](
                    pose=t["geometry_msgs/msg/Pose"](
                        position=t["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    ),
                    covariance=zero36,
                ),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](
                        linear=vec(x=4.0, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=0.05)
                    ),
                    covariance=zero36,
                ),
            )  # fmt: skip
            w.write(conns["/odom"], ns, store.serialize_cdr(odo, "nav_msgs/msg/Odometry"))
            if i % 2 == 0:
                img = t["sensor_msgs/msg/CompressedImage"](
                    header=header(ns + 5_000_000, "camera_optical_frame"), format="jpeg",
                    data=np.frombuffer(b"\xff\xd8" + bytes([i]) + b"\xff\xd9", np.uint8),
                )  # fmt: skip
                w.write(
                    conns["/camera/image_raw/compressed"], ns + 6_000_000,
                    store.serialize_cdr(img, "sensor_msgs/msg/CompressedImage"),
                )  # fmt: skip
                fix = t["sensor_msgs/msg/NavSatFix"](
                    header=header(ns, "gps"),
                    status=t["sensor_msgs/msg/NavSatStatus"](status=2, service=1),
                    latitude=48.0 + i * 1e-6, longitude=2.0, altitude=50.0,
                    position_covariance=np.array([0.01, 0, 0, 0, 0.01, 0, 0, 0, 0.04]),
                    position_covariance_type=2,
                )  # fmt: skip
                w.write(conns["/fix"], ns, store.serialize_cdr(fix, "sensor_msgs/msg/NavSatFix"))


def test_a_bag_of_another_tool_reads_with_ros_names(tmp_path: Path) -> None:
    bag = tmp_path / "foreign"
    _foreign_bag(bag)
    files = sorted(bag.glob("*.mcap"))
    log = read_log(files, vehicle=True)
    assert (log.laser, log.camera) == ("laser", "camera")  # frame_id; the topic's namespace
    assert log.n_scans == 10 and log.n_frames == 5
    assert log.time_increment == pytest.approx(2e-5)  # the scans' own, not assumed
    t0 = 1_800_000_000_000_000_000
    assert log.scan_ns.tolist() == [t0 + i * 25_000_000 for i in range(10)]  # header stamps
    assert log.frame_ns[0] == t0 + 5_000_000
    assert log.jpegs[1] == b"\xff\xd8\x02\xff\xd9"
    np.testing.assert_array_equal(log.ranges[:, 0], 5.0 + np.arange(10))
    assert log.vehicle is not None
    odo, fixes = log.vehicle.odometry, log.vehicle.fixes
    assert len(odo) == 10 and np.all(odo.speed == 4.0) and np.all(odo.yaw_rate == 0.05)
    assert len(fixes) == 5 and np.all(fixes.quality == 4)  # GBAS: RTK
    assert fixes.lat[2] == pytest.approx(48.0 + 4e-6)
    assert read_vehicle(files).odometry.t_ns.tolist() == odo.t_ns.tolist()


def test_a_garbled_message_is_skipped_and_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "garbled"
    _foreign_bag(bag, garbled=True)
    log = read_log(sorted(bag.glob("*.mcap")))
    assert log.n_scans == 9
    assert acq_main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "1 ROS messages that cannot be deserialised skipped" in out


def test_broken_bags_one_line_exit_2(
    drive: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, _, bag = drive

    def broken(name: str) -> Path:
        copy = tmp_path / name
        shutil.copytree(bag, copy)
        return copy

    cut = broken("cut_in_magic")
    (storage,) = cut.glob("*.mcap")
    storage.write_bytes(storage.read_bytes()[:5])
    garbage = broken("garbage_metadata")
    (garbage / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    sqlite = broken("sqlite")
    meta = sqlite / "metadata.yaml"
    meta.write_text(
        meta.read_text().replace("storage_identifier: mcap", "storage_identifier: sqlite3")
    )
    missing = broken("missing_file")
    next(missing.glob("*.mcap")).unlink()
    for folder, expected in (
        (cut, "cut inside the MCAP magic"),
        (garbage, "metadata.yaml: not a rosbag2 metadata file"),
        (sqlite, "sqlite3 storage; acq reads MCAP storage"),
        (missing, "which is not in"),
    ):
        for command in (["info"], ["colorize"]):
            args = [*command, str(folder)]
            if command == ["colorize"]:
                args += ["--calib", str(drive[1]), "-o", str(tmp_path / "c.ply"), "--no-preview"]
            assert acq_main(args) == 2, (folder, command)
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and expected in err, err
    assert not (tmp_path / "c.ply").exists()


def test_a_bag_cut_short_is_read_up_to_the_cut(
    drive: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As an acq log whose writer was killed: what was recorded is read, and said."""
    log, _, bag = drive
    copy = tmp_path / "cut"
    shutil.copytree(bag, copy)
    (storage,) = copy.glob("*.mcap")
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) // 2])
    assert acq_main(["info", str(copy)]) == 0
    out = capsys.readouterr().out
    assert "NOT CLOSED" in out
    scans = read_log(sorted(copy.glob("*.mcap")), camera="left").n_scans
    assert 0 < scans < read_log(log, camera="left").n_scans
