"""acq calibrate extrinsic for every camera of a two-camera rig, from one simulated board
recording (sim/board_log.py with default_rig(cameras=2)): one calib.yaml, the cameras'
relative pose, a bad camera name. The calibration of both cameras (a 27 s fixture on a busy
2-core machine) is marked slow (`make test-slow`); the rest costs about a second."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from acq.calib.relative_pose import difference, relative_poses
from acq.camera import calibfile
from acq.camera.calibfile import CalibStd
from acq.geometry.transforms import Rigid
from acq.log import drive_log
from acq.sim.board_log import BoardLog, write_board_log
from acq.sim.world import default_rig
from tests.cli_calls import calibrate_extrinsic


def _rig_log(d: Path, n_poses: int) -> tuple[BoardLog, Path]:
    log = write_board_log(d, n_poses=n_poses, seed=0, hold_s=1.0, move_s=0.3,
                          rig=default_rig(cameras=2))  # fmt: skip
    intr = d / "intrinsics.yaml"
    calibfile.save(log.calibration, intr)
    return log, intr


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[BoardLog, Path]:
    """Two poses a camera: the recording's make-up, not a calibration."""
    return _rig_log(tmp_path_factory.mktemp("rig_small_log"), 2)


@pytest.fixture(scope="module")
def rig_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[BoardLog, Path]:
    return _rig_log(tmp_path_factory.mktemp("rig_board_log"), 8)


@pytest.fixture(scope="module")
def both(
    rig_log: tuple[BoardLog, Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, dict[str, object]]:
    """Both cameras calibrated in one call (the default: every camera of --intrinsics)."""
    log, intr = rig_log
    out = tmp_path_factory.mktemp("rig_calib") / "calib.yaml"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert calibrate_extrinsic(log.files, None, intr, log.spec, out, json_out=True) == 0
    return out, json.loads(buf.getvalue())


def test_every_camera_films_the_recording_with_its_timing(
    small_log: tuple[BoardLog, Path],
) -> None:
    log, _ = small_log
    assert log.cameras == ("left", "right")
    assert log.placed_for == ("left", "left", "right", "right")
    rig = default_rig(cameras=2)
    for name in log.cameras:
        truth = rig.camera(name).camera_to_laser
        np.testing.assert_array_equal(log.truths[name].rotation, truth.rotation)
        np.testing.assert_array_equal(log.truths[name].translation, truth.translation)
        dl = drive_log.read_log(log.files, camera=name, jpegs=False)
        assert dl.camera == name and dl.n_frames >= 25 * 4
        assert (dl.frame_seq == np.arange(dl.n_frames)).all()  # its timing records
        latency = rig.camera(name).latency_s + rig.camera(name).exposure / 2
        np.testing.assert_allclose((dl.frame_recv_ns - dl.frame_ns) * 1e-9, latency, atol=1e-6)
    left, right = (drive_log.read_log(log.files, camera=n, jpegs=False) for n in log.cameras)
    assert left.frame_ns[0] != right.frame_ns[0]  # each at its own phase


@pytest.mark.slow
def test_both_cameras_in_one_calib_and_their_relative_pose(
    rig_log: tuple[BoardLog, Path], both: tuple[Path, dict[str, object]]
) -> None:
    """Each camera's camera_to_laser near its truth, and camera left -> right near the
    rig's: within 3 times the spread the two calibrations' std predict (8 poses a camera,
    1 s each: about 0.3 deg and 7 mm; here 0.25 deg and 4.2 mm off, 0.8 and 0.6 of it)
    and within 0.6 deg and 15 mm. Why 3: the std is the fit's, which does not see the
    image chain's small systematic errors (JPEG, blur, corner bias); on 15-pose
    recordings of seeds 0-2 (bench/extrinsic.py --rig) the relative pose was up to 1.3
    times its spread off in rotation and 2.1 times in translation."""
    log, _ = rig_log
    out, report = both
    cal = calibfile.load(out)
    assert list(cal.cameras) == ["left", "right"]
    cameras = report["cameras"]
    assert isinstance(cameras, list) and [c["camera"] for c in cameras] == ["left", "right"]
    for name in log.cameras:
        rot, trans = difference(cal.camera(name).camera_to_laser, log.truths[name])
        print(f"{name}: {rot:.3f} deg, {trans * 1e3:.1f} mm from the truth")
        assert rot < 0.3 and trans < 0.01
    [rel] = report["relative"]  # type: ignore[misc]
    assert (rel["from"], rel["to"]) == ("left", "right")
    got = cal.camera("right").camera_to_laser.inverse() @ cal.camera("left").camera_to_laser
    truth = log.truths["right"].inverse() @ log.truths["left"]
    np.testing.assert_allclose(got.to_dict()["translation"], rel["transform"]["translation"])
    rot, trans = difference(got, truth)
    print(f"left -> right: {rot:.3f} deg, {trans * 1e3:.1f} mm from the truth "
          f"(std {rel['std_deg']:.3f} deg, {rel['std_m'] * 1e3:.1f} mm)")  # fmt: skip
    assert rot < min(3 * rel["std_deg"], 0.6)
    assert trans < min(3 * rel["std_m"], 0.015)


def test_a_bad_camera_name_is_one_line_and_exit_2(
    small_log: tuple[BoardLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, intr = small_log
    out = tmp_path / "calib.yaml"
    assert calibrate_extrinsic(log.files, "rear", intr, log.spec, out) == 2
    err = capsys.readouterr().err
    assert err.startswith("acq calibrate extrinsic: --camera rear: in neither the log nor "), err
    assert "(the log has left, right; " in err and err.count("\n") == 1, err
    assert not out.exists()


def test_the_relative_pose_of_two_cameras_and_its_spread() -> None:
    """left -> right of the simulated rig, from the truths: P_right = R P_left + t; the
    std of the two calibrations added in quadrature."""
    rig = default_rig(cameras=2)
    left, right = (rig.camera(n).camera_to_laser for n in ("left", "right"))
    std = {
        "left": CalibStd(rotation_deg=(0.1, 0.2, 0.2), translation_m=(0.001, 0.002, 0.002)),
        "right": CalibStd(rotation_deg=(0.2, 0.1, 0.2), translation_m=(0.002, 0.001, 0.002)),
    }
    [rel] = relative_poses({"left": left, "right": right}, std)
    assert (rel.a, rel.b) == ("left", "right")
    P = np.array([[1.0, 2.0, 3.0], [-0.5, 0.2, 4.0]])  # points in the left camera's frame
    np.testing.assert_allclose(rel.transform.apply(P), right.inverse().apply(left.apply(P)))
    assert rel.angle_deg == pytest.approx(difference(rel.transform, Rigid.identity())[0])
    assert 170 < rel.angle_deg < 180  # looking the opposite way, each tilted a little
    assert rel.translation_m == pytest.approx(np.linalg.norm(left.translation - right.translation))
    assert rel.std_deg == pytest.approx(np.sqrt(0.09 + 0.09))
    assert rel.std_m == pytest.approx(np.sqrt(9e-6 + 9e-6))
    assert "left -> right: rotation" in rel.line()
    [alone] = relative_poses({"left": left, "right": right})
    assert np.isnan(alone.std_deg) and alone.to_dict()["std_deg"] is None
