"""The simulated drive log: every camera of the rig on its own topics, with its truth."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from acq.camera import calibfile
from acq.log.reader import LogReader, read_metadata
from acq.sim.drive_log import DriveTruth, main, visibility_shares, write_drive_log
from acq.sim.raycast import cast
from acq.sim.sensors import camera_to_world, render_frame, render_frame_truth, seen_in_frame
from acq.sim.world import Box, Material, Street, Trajectory, default_rig


@pytest.fixture(scope="module")
def two(tmp_path_factory: pytest.TempPathFactory) -> DriveTruth:
    return write_drive_log(tmp_path_factory.mktemp("two"), 0.6, rig=default_rig(cameras=2))


@pytest.fixture(scope="module")
def one(tmp_path_factory: pytest.TempPathFactory) -> DriveTruth:
    return write_drive_log(tmp_path_factory.mktemp("one"), 0.5)


def _frames(truth: DriveTruth) -> dict[str, tuple[np.ndarray, np.ndarray, list[bytes]]]:
    """Per camera topic (images, timing): each message's receipt and stamp (ns), and the
    JPEGs (images only)."""
    got: dict[str, tuple[list[int], list[int], list[bytes]]] = {}
    for f in truth.files:
        reader = LogReader(f)
        for schema, channel, message in reader.messages():
            topic = channel.topic
            image = topic.endswith("/image/compressed")
            if not image and not (
                topic.startswith("/acq/timing/") and topic != "/acq/timing/laser"
            ):
                continue
            recv, stamp, jpegs = got.setdefault(topic, ([], [], []))
            msg = reader.decode(schema, channel, message)
            if image:
                recv.append(message.log_time)
                stamp.append(message.publish_time)
                jpegs.append(bytes(msg.data))
            else:
                recv.append(msg.recv_ns)
                stamp.append(msg.stamp_ns)
    return {
        t: (np.asarray(r, np.int64), np.asarray(st, np.int64), j) for t, (r, st, j) in got.items()
    }


def _calib(meta: dict[str, dict[str, str]]) -> calibfile.Calibration:
    return calibfile.parse(yaml.safe_load(meta["calibration"]["yaml"]))


def test_every_camera_on_its_own_topics_with_its_calibration(two: DriveTruth) -> None:
    frames = _frames(two)
    assert sorted(frames) == [
        "/acq/timing/left", "/acq/timing/right",
        "/left/image/compressed", "/right/image/compressed",
    ]  # fmt: skip
    for name in ("left", "right"):
        stamps = two.cameras[name].frame_stamp_ns
        assert np.array_equal(frames[f"/{name}/image/compressed"][1], stamps)
        assert np.array_equal(frames[f"/acq/timing/{name}"][1], stamps)
    meta = read_metadata(two.files[0])
    assert {"device.left", "device.right"} <= set(meta) and "device.camera" not in meta
    calib = _calib(meta)
    assert list(calib.cameras) == ["left", "right"] == list(two.camera_names)
    for name, cc in calib.cameras.items():
        cam = two.rig.camera(name)
        assert cc.model == cam.lens
        assert np.allclose(cc.camera_to_laser.matrix(), cam.camera_to_laser.matrix())
    # each camera its own clock phase, a few ms apart
    left, right = two.cameras["left"].frame_t_s, two.cameras["right"].frame_t_s
    assert 0.002 < right[0] - left[0] < 0.02
    assert np.array_equal(two.frame_t_s, left)  # the first camera's, as before


def test_each_frame_arrives_after_its_own_cameras_latency(two: DriveTruth) -> None:
    frames = _frames(two)
    for name in ("left", "right"):
        cam, truth = two.rig.camera(name), two.cameras[name]
        recv = frames[f"/{name}/image/compressed"][0]
        late_s = (recv - two.start_ns) * 1e-9 - truth.frame_t_s  # receipt - middle of exposure
        floor = cam.latency_s + cam.exposure / 2
        assert late_s.min() >= floor - 1e-9
        assert late_s.mean() == pytest.approx(floor + 0.003, abs=0.0015)  # + the jitter's mean
        assert truth.latency_true_s == pytest.approx(floor + 0.003)
        assert truth.latency_configured_s == 0.025  # one configured value for every camera
        assert np.all(recv - truth.frame_stamp_ns == 25_000_000)
    assert two.cameras["right"].latency_true_s - two.cameras["left"].latency_true_s == (
        pytest.approx(0.006)
    )


def test_configured_latency_per_camera(tmp_path: Path) -> None:
    rig = default_rig(cameras=2)
    exact = write_drive_log(tmp_path / "a", 0.25, rig=rig, configured_camera_latency_s=None)
    for cam in rig.cameras:
        truth = exact.cameras[cam.name]
        assert truth.latency_configured_s == truth.latency_true_s
        # stamps are the true middle of exposure, but for the jitter about its mean
        err = (truth.frame_stamp_ns - exact.start_ns) * 1e-9 - truth.frame_t_s
        assert abs(err.mean()) < 0.003 and err.min() > -0.004
    given = write_drive_log(tmp_path / "b", 0.2, rig=rig,
                            configured_camera_latency_s={"left": 0.02, "right": 0.03})  # fmt: skip
    assert given.cameras["left"].latency_configured_s == 0.02
    assert given.cameras["right"].latency_configured_s == 0.03
    with pytest.raises(ValueError, match="right"):
        write_drive_log(tmp_path / "c", 0.2, rig=rig, configured_camera_latency_s={"left": 0.02})
    with pytest.raises(ValueError, match="latency_s"):
        write_drive_log(tmp_path / "d", 0.2, rig=rig, camera_latency_s=0.04)


def test_frames_rendered_through_each_camera_with_its_gains(two: DriveTruth) -> None:
    frames = _frames(two)
    for name in ("left", "right"):
        truth = two.cameras[name]
        photometry = two.rig.camera(name).photometry
        assert np.allclose(truth.gains, photometry.gains(truth.frame_t_s))
        k = truth.frame_t_s.size // 2
        img = cv2.imdecode(
            np.frombuffer(frames[f"/{name}/image/compressed"][2][k], np.uint8),
            cv2.IMREAD_COLOR,
        )
        assert img is not None
        t = float(truth.frame_t_s[k])
        want = render_frame(two.street, two.trajectory, two.rig, t, name)
        other = render_frame(
            two.street, two.trajectory, two.rig, t, "right" if name == "left" else "left"
        )
        err = np.abs(img.astype(np.int16) - want).mean()
        assert err < 2.5 < np.abs(img.astype(np.int16) - other).mean()
    left, right = two.cameras["left"].gains, two.cameras["right"].gains
    assert np.abs(left[0] - right[0]).max() > 0.05  # each its own white balance


def test_seen_in_frame_hidden_behind_a_car() -> None:
    """A wall 8 m to the left and a car in front of part of it: the wall behind the car is
    hidden, the wall beside it and the car are seen, the right-hand side is not."""
    rig = default_rig(cameras=2)
    traj = Trajectory(speed=0.0, x0=0.0, y0=0.0)
    street = Street(length_m=40.0)
    street.add(
        Box(-20.0, 20.0, 8.0, 9.0, 0.0, 6.0, Material.SOLID, (200, 180, 160)),
        Box(-1.0, 1.5, 3.0, 4.8, 0.0, 1.5, Material.SOLID, (40, 40, 200)),
    )
    frame = render_frame_truth(street, traj, rig, 0.0, "left")
    eye = camera_to_world(traj, rig, 0.0, "left").translation
    car = np.array([0.2, 3.0, 1.4])
    behind_car = eye + (car - eye) * (8.0 - eye[1]) / (3.0 - eye[1])
    P = np.array([
        behind_car,  # hidden
        [6.0, 8.0, 1.0],  # on the wall beside the car
        [-4.0, 8.0, 4.0],  # above it
        car,  # the car's near face
        [0.0, -8.0, 1.0],  # on the right, in the air: outside the left camera's fov
        [math.nan] * 3,
    ])  # fmt: skip
    assert behind_car[1] == pytest.approx(8.0) and 0 < behind_car[2] < 1.5
    assert seen_in_frame(P, frame, traj, rig, "left").tolist() == [
        False, True, True, True, False, False,
    ]  # fmt: skip
    right = render_frame_truth(street, traj, rig, 0.0, "right")
    assert seen_in_frame(P, right, traj, rig, "right").tolist() == [False] * 4 + [True, False]


def test_visible_truth_by_side_and_against_exact_rays(two: DriveTruth) -> None:
    names = two.camera_names
    assert names == ("left", "right") and two.visible.shape == (*two.points.shape[:2], 2)
    hit = np.isfinite(two.points).all(axis=2)
    assert not two.visible[~hit].any()
    t = two.point_t_s()
    _, pos = two.trajectory.poses(t.ravel())
    y_rel = two.points[..., 1] - pos[:, 1].reshape(t.shape)  # + left of the vehicle
    for side, c in ((y_rel > 1.0, 0), (y_rel < -1.0, 1)):
        seen = two.visible[hit & side]
        assert seen[:, c].mean() > 0.95 and not seen[:, 1 - c].any()
    shares = visibility_shares(two)
    assert sum(shares.values()) == pytest.approx(1.0) and shares["none"] < 0.03
    # against a ray cast from the camera to each point in its nearest frame: no point the
    # camera really sees is called hidden; points within a pixel of an edge may count seen
    P = two.points.reshape(-1, 3).astype(np.float64)
    flat_t, flat_hit = t.ravel(), hit.ravel()
    for c, name in enumerate(names):
        ft = two.cameras[name].frame_t_s
        k = np.argmin(np.abs(flat_t[:, None] - ft[None, :]), axis=1)
        exact = np.zeros(flat_t.size, dtype=bool)
        for j in np.unique(k[flat_hit]):
            sel = np.flatnonzero(flat_hit & (k == j))
            pose = camera_to_world(two.trajectory, two.rig, float(ft[j]), name)
            _, in_view = two.rig.camera(name).lens.project(pose.inverse().apply(P[sel]))
            ray = P[sel] - pose.translation
            dist = np.linalg.norm(ray, axis=1)
            first = cast(two.street, pose.translation, ray / dist[:, None]).distance
            exact[sel] = in_view & (first >= dist - 0.01 - 0.002 * dist)
        ours = two.visible[..., c].ravel()
        assert not (exact & ~ours).any()
        assert (ours & ~exact).sum() <= 0.01 * flat_hit.sum()


def test_true_pixels_per_camera(two: DriveTruth) -> None:
    for c, name in enumerate(two.camera_names):
        truth = two.cameras[name]
        scan, step = np.nonzero(two.visible[..., c])
        t = two.point_t_s()[scan, step]
        k = np.argmin(np.abs(t[:, None] - truth.frame_t_s[None, :]), axis=1)
        uv, valid = two.true_pixels(scan, step, truth.frame_stamp_ns[k], camera=name)
        assert valid.all()  # what a camera sees lies in its frame
        for j in np.unique(k)[:3]:
            sel = k == j
            ft = render_frame_truth(
                two.street, two.trajectory, two.rig, float(truth.frame_t_s[j]), name
            )
            ui, vi = np.rint(uv[sel]).astype(int).T
            surface = two.colours[scan[sel], step[sel]].astype(np.float64) * truth.gains[j]
            diff = np.abs(ft.image[vi, ui].astype(np.float64) - np.clip(surface, 0, 255))
            assert np.median(diff) < 8
    _, valid = two.true_pixels(np.array([0]), np.array([0]), np.array([-1]), camera="right")
    assert not valid.any()  # an unknown stamp


def test_one_camera_rig_writes_as_before(one: DriveTruth, two: DriveTruth) -> None:
    frames = _frames(one)
    assert sorted(frames) == ["/acq/timing/camera", "/camera/image/compressed"]
    meta = read_metadata(one.files[0])
    assert "device.camera" in meta and list(_calib(meta).cameras) == ["camera"]
    assert one.camera_names == ("camera",) and one.visible.shape[2] == 1
    cam = one.cameras["camera"]
    assert np.array_equal(one.frame_stamp_ns, cam.frame_stamp_ns)
    assert one.frame_t_s[0] == pytest.approx(0.017)
    # the camera_latency_s argument (30 ms), not the rig camera's 20 ms, as before
    assert one.config["camera_latency_true_s"] == pytest.approx(0.030 + 0.002 + 0.003)
    assert one.config["camera_latency_configured_s"] == 0.025
    assert np.all(frames["/camera/image/compressed"][0] - cam.frame_stamp_ns == 25_000_000)
    # the scans (their random draws) do not depend on the cameras
    n = one.scan_t0_s.size
    assert np.array_equal(one.scan_stamp_ns, two.scan_stamp_ns[:n])


def test_main_writes_the_drive_and_every_cameras_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    main([str(tmp_path), "0.2", "--cameras", "2"])
    assert list(calibfile.load(tmp_path / "calib.yaml").cameras) == ["left", "right"]
    assert len(list(tmp_path.glob("drive_*.mcap"))) == 1
    assert "left+right" in capsys.readouterr().out


def test_host_trajectory_is_the_true_one_on_the_host_clock(one: DriveTruth) -> None:
    traj = one.host_trajectory()
    t_s = np.array([-0.9, 0.0, 0.1234567, 0.3, 1.4])  # a second either side of the drive
    R, p = traj.pose_at(one.start_ns + np.rint(t_s * 1e9).astype(np.int64))
    R0, p0 = one.trajectory.poses(t_s)
    assert np.abs(p - p0).max() < 1e-5
    assert np.abs(R - R0).max() < 1e-5
    assert not traj.covers([one.start_ns - 2 * 10**9]).any()
