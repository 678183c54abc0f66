"""acq calibrate extrinsic on a simulated calibration recording (sim/board_log.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from acq import calibfile, cloud
from acq.calibfile import Calibration, CameraCalib
from acq.extrinsic import rotation_angle
from acq.extrinsic_log import main_extrinsic, parse_poses, still_intervals
from acq.transforms import Rigid
from sim.board_log import BoardLog, write_board_log


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> tuple[BoardLog, Path]:
    d = tmp_path_factory.mktemp("board_log")
    log = write_board_log(d, n_poses=12, seed=0, hold_s=1.0, move_s=0.3)
    intr = d / "intrinsics.yaml"
    calibfile.save(log.calibration, intr)
    return log, intr


def _errors(got: Rigid, truth: Rigid) -> tuple[float, float]:
    """Rotation error (deg) and translation error (m)."""
    rot = math.degrees(rotation_angle(got.rotation @ truth.rotation.T))
    return rot, float(np.linalg.norm(got.translation - truth.translation))


def test_still_intervals_match_the_holds(rec: tuple[BoardLog, Path]) -> None:
    log, _ = rec
    found = still_intervals(cloud.read_log(log.files))
    assert len(found) == len(log.holds)
    for (a, b), (ha, hb) in zip(found, log.holds, strict=True):
        assert ha <= a < b <= hb + 50_000_000


def test_calibration_recovers_the_truth(
    rec: tuple[BoardLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, intr = rec
    out = tmp_path / "calib.yaml"
    assert main_extrinsic(log.files, "camera", intr, log.spec, out, json_out=True) == 0
    report = json.loads(capsys.readouterr().out)
    assert len(report["poses"]) == 12
    assert all(p["problem"] == "" for p in report["poses"])
    cam = calibfile.load(out).camera("camera")
    assert cam.method == "zhang_pless"
    assert cam.model.to_dict() == log.calibration.camera("camera").model.to_dict()
    rot, trans = _errors(cam.camera_to_laser, log.truth)
    print(f"recovered camera_to_laser: {rot:.3f} deg, {trans * 1e3:.1f} mm from the truth")
    assert rot < 0.5 and trans < 0.02
    assert (tmp_path / "calib_extrinsic.png").stat().st_size > 0


def test_given_poses_and_a_coarse_extrinsic(
    rec: tuple[BoardLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--poses instead of the stillness detection; a rough camera_to_laser in CALIB picks
    the laser segment by the camera's plane."""
    log, _ = rec
    rough = Rigid(log.truth.rotation, log.truth.translation + 0.05)
    intr = tmp_path / "rough.yaml"
    model = log.calibration.camera("camera").model
    calibfile.save(Calibration(cameras={"camera": CameraCalib(model, rough)}), intr)
    t0 = log.start_ns
    spans = ",".join(
        f"{(a - t0) * 1e-9 + 0.2:.2f}:{(b - t0) * 1e-9 - 0.2:.2f}" for a, b in log.holds
    )
    out, png = tmp_path / "out.yaml", tmp_path / "res.png"
    assert main_extrinsic(log.files, None, intr, log.spec, out, poses=spans, plot=png) == 0
    text = capsys.readouterr().out
    assert "camera_to_laser" in text and png.exists()
    rot, trans = _errors(calibfile.load(out).camera().camera_to_laser, log.truth)
    assert rot < 0.5 and trans < 0.02


def test_parse_poses() -> None:
    assert parse_poses("1:2, 3.5:4", 10) == [
        (10 + 10**9, 10 + 2 * 10**9),
        (10 + 35 * 10**8, 10 + 4 * 10**9),
    ]
    for bad in ("1-2", "2:1", ""):
        with pytest.raises(ValueError):
            parse_poses(bad, 0)


def test_bad_input_exits_2(
    rec: tuple[BoardLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, intr = rec
    out = tmp_path / "calib.yaml"
    assert main_extrinsic(log.files, None, intr, "9x7", out) == 2
    assert "--board" in capsys.readouterr().err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    assert main_extrinsic([junk], None, intr, log.spec, out) == 2
    assert main_extrinsic(log.files, None, tmp_path / "missing.yaml", log.spec, out) == 2
    assert main_extrinsic(log.files, "nocam", intr, log.spec, out) == 2
    assert main_extrinsic(log.files, None, intr, log.spec, out, poses="5:4") == 2
    assert not out.exists()


def test_too_few_poses_exits_1(
    rec: tuple[BoardLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, intr = rec
    t0 = log.start_ns
    spans = ",".join(
        f"{(a - t0) * 1e-9 + 0.2:.2f}:{(b - t0) * 1e-9 - 0.2:.2f}" for a, b in log.holds[:3]
    )
    out = tmp_path / "calib.yaml"
    assert main_extrinsic(log.files, None, intr, log.spec, out, poses=spans) == 1
    assert "at least 5" in capsys.readouterr().err
    assert not out.exists()
