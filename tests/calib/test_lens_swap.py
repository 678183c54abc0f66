"""The paper's way (§3.2): the extrinsic calibration with a regular lens on the camera,
then the fisheye mounted (`acq calibrate extrinsic --lens-swap`).

The simulated regular lens (a pinhole, f = 600 px) has its projection centre 20 mm
behind the fisheye's, as swapping lenses does: the calibration recovers the regular
lens's pose, so the fisheye's translation is 20 mm off unless ``--pupil-shift`` says
by how much the centre moved.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import Pinhole
from acq.geometry.rotations import rotation_angle
from acq.geometry.transforms import Rigid
from acq.sim.board_log import BoardLog, write_board_log
from acq.sim.world import default_rig
from tests.cli_calls import calibrate_extrinsic

SHIFT_M = 0.02  # the fisheye's projection centre, ahead of the regular lens's


@pytest.fixture(scope="module")
def swap(tmp_path_factory: pytest.TempPathFactory) -> tuple[BoardLog, Path, Path, Rigid]:
    d = tmp_path_factory.mktemp("lens_swap")
    fisheye = default_rig()
    pinhole = Pinhole(width=780, height=582, fx=600.0, fy=600.0, cx=390.0, cy=291.0)
    behind = Rigid(np.eye(3), np.array([0.0, 0.0, -SHIFT_M]))
    rig = fisheye.with_camera(lens=pinhole, camera_to_laser=fisheye.camera_to_laser @ behind)
    log = write_board_log(d, n_poses=10, seed=3, hold_s=1.0, move_s=0.3, rig=rig,
                          distance=(1.5, 2.5))  # fmt: skip
    regular = d / "regular.yaml"
    calibfile.save(log.calibration, regular)  # the pinhole's intrinsics
    fish = d / "fisheye.yaml"
    calibfile.save(Calibration(cameras={"camera": CameraCalib(fisheye.lens)}), fish)
    return log, regular, fish, fisheye.camera_to_laser


def _errors(got: Rigid, truth: Rigid) -> tuple[float, float]:
    rot = math.degrees(rotation_angle(got.rotation @ truth.rotation.T))
    return rot, float(np.linalg.norm(got.translation - truth.translation))


@pytest.mark.parametrize("shift", [0.0, SHIFT_M])
def test_lens_swap_writes_the_fisheye_entry(
    swap: tuple[BoardLog, Path, Path, Rigid],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    shift: float,
) -> None:
    log, regular, fish, truth = swap
    out = tmp_path / "calib.yaml"
    rc = calibrate_extrinsic(
        log.files, "camera", regular, log.spec, out, lens_swap=fish, pupil_shift_m=shift
    )
    text = capsys.readouterr()
    assert rc == 0, text.err
    assert "lens swap" in text.out
    cam = calibfile.load(out).camera("camera")
    assert cam.model == calibfile.load(fish).camera("camera").model  # the fisheye's model
    assert "lens_swap" in cam.method
    rot, trans = _errors(cam.camera_to_laser, truth)
    print(f"pupil shift {shift * 1e3:.0f} mm: {rot:.3f} deg, {trans * 1e3:.1f} mm off")
    assert rot < 0.15
    if shift == 0.0:  # the paper's assumption: the error is the unknown shift
        assert abs(trans - SHIFT_M) < 0.004
    else:
        assert trans < 0.004


def test_lens_swap_needs_the_camera_in_the_fisheye_file(
    swap: tuple[BoardLog, Path, Path, Rigid], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, regular, _, _ = swap
    other = tmp_path / "other.yaml"
    model = calibfile.load(regular).camera().model
    calibfile.save(Calibration(cameras={"left": CameraCalib(model)}), other)
    rc = calibrate_extrinsic(log.files, "camera", regular, log.spec, tmp_path / "o.yaml",
                        lens_swap=other)  # fmt: skip
    assert rc == 2
    assert "no camera 'camera'" in capsys.readouterr().err
