"""acq calibrate validate on a simulated validation recording (sim/validation_log.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq import calibfile, cloud
from acq.calibfile import Calibration, CameraCalib
from acq.transforms import Rigid
from acq.validate import main_validate, validate
from sim.validation_log import LABELS, ValidationLog, write_validation_log


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> tuple[ValidationLog, Path]:
    d = tmp_path_factory.mktemp("validation_log")
    log = write_validation_log(d, duration_s=1.0)
    calib = d / "calib.yaml"
    calibfile.save(log.calibration, calib)
    return log, calib


def _perturbed(cam: CameraCalib, deg: float) -> CameraCalib:
    """``cam`` with camera_to_laser turned by ``deg`` about the laser z axis (the scan
    plane's normal: the projections move along the laser line)."""
    R, _ = cv2.Rodrigues(np.array([0.0, 0.0, math.radians(deg)]))
    T = cam.camera_to_laser
    return CameraCalib(cam.model, Rigid(R @ T.rotation, T.translation))


def test_truth_sees_both_sets(rec: tuple[ValidationLog, Path]) -> None:
    log, _ = rec
    names = log.beam_colour()
    for colour in ("red", "green", "blue", "yellow"):
        assert names.count(colour) > 20, colour
    assert set(names) <= set(LABELS)


def test_true_calibration_colours_right(rec: tuple[ValidationLog, Path], tmp_path: Path) -> None:
    log, _ = rec
    png = tmp_path / "overlay.png"
    res = validate(cloud.read_log(log.files), log.calibration.camera(), overlay=png)
    print(res.to_dict())
    assert res.points > 5000 and res.front[0] > 0 and res.back[0] > 0
    assert res.share_right >= 0.95
    assert res.n_edges > 100 and res.sigma_px < 1.0
    assert abs(res.edge_mean_px) < 0.3
    assert sum(res.histogram) == res.points and res.histogram[0] == res.right
    assert sum(f[1] for f in res.frames) == res.points
    img = cv2.imread(str(png))
    assert img is not None and img.shape[:2] == (log.calibration.camera().model.height,
                                                 log.calibration.camera().model.width)  # fmt: skip


def test_perturbed_calibration_is_clearly_worse(rec: tuple[ValidationLog, Path]) -> None:
    log, _ = rec
    drive = cloud.read_log(log.files)
    good = validate(drive, log.calibration.camera())
    bad = validate(drive, _perturbed(log.calibration.camera(), 1.0))
    print(good.share_right, good.sigma_px, bad.share_right, bad.sigma_px)
    assert bad.share_right <= good.share_right - 0.10
    assert bad.sigma_px > 2 * good.sigma_px
    assert sum(bad.histogram[2:]) > 0.05 * bad.points


def test_main_json_and_overlay(
    rec: tuple[ValidationLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, calib = rec
    assert main_validate(log.files, calib, json_out=True, out=tmp_path) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["camera"] == "camera" and report["share_right"] >= 0.95
    assert set(report["histogram"]) == {"0", "1", "2", "3", ">3"}
    assert (tmp_path / "validate_overlay.png").is_file()


def test_main_bad_input_exits_2(
    rec: tuple[ValidationLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, calib = rec
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    assert main_validate([junk], calib) == 2
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncameras: {camera: {model: nonsense}}\n")
    assert main_validate(log.files, bad) == 2
    assert main_validate(log.files, tmp_path / "missing.yaml") == 2
    assert main_validate(log.files, calib, camera="left") == 2
    err = capsys.readouterr().err
    assert err.count("acq calibrate validate:") == 4


def test_no_pattern_exits_1(
    rec: tuple[ValidationLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the log's calibration with an empty scene: write a log whose scans see nothing
    from sim.validation_log import PatternScene

    log = write_validation_log(
        tmp_path, duration_s=0.2, scene=PatternScene(n_strips=0, back_m=50.0, ground_m=50.0)
    )
    calib = tmp_path / "c.yaml"
    calibfile.save(Calibration(cameras={"camera": log.calibration.camera()}), calib)
    assert main_validate(log.files, calib) == 1
    assert "no pattern" in capsys.readouterr().err
