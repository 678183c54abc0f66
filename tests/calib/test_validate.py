"""acq calibrate validate on a simulated validation recording (sim/validation_log.py):
the paper's pattern in the synthetic street, seen by the parked vehicle."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from acq.calib.validate import DEFAULT_COLOURS, validate
from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CameraCalib
from acq.geometry.rotations import matrix_from_rotvec
from acq.geometry.transforms import Rigid
from acq.log import drive_log
from acq.sim.raycast import NO_RAY
from acq.sim.validation_log import (
    LABELS,
    PARK_Y,
    PATTERN_AT,
    ValidationLog,
    labels,
    write_validation_log,
)
from acq.sim.world import (
    PATTERN_BACK_Y,
    PATTERN_CLEAR_M,
    PATTERN_FRONT_Y,
    Material,
    Street,
    default_rig,
    validation_pattern,
)
from tests.cli_calls import calibrate_validate, printed


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> tuple[ValidationLog, Path]:
    d = tmp_path_factory.mktemp("validation_log")
    log = write_validation_log(d, duration_s=1.0)
    calib = d / "calib.yaml"
    calibfile.save(log.calibration, calib)
    return log, calib


@pytest.fixture(scope="module")
def truth_report(
    rec: tuple[ValidationLog, Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[dict[str, Any], Path]:
    """`acq calibrate validate --json -o DIR` with the true calibration, run once: its
    report (the ValidationResult's figures) and DIR; the tests below read it."""
    log, calib = rec
    out = tmp_path_factory.mktemp("validate_out")
    code, stdout, _ = printed(calibrate_validate, log.files, calib, json_out=True, out=out)
    assert code == 0
    return json.loads(stdout), out


def _perturbed(cam: CameraCalib, deg: float) -> CameraCalib:
    """``cam`` with camera_to_laser turned by ``deg`` about the laser z axis (the scan
    plane's normal: the projections move along the laser line)."""
    R = matrix_from_rotvec([0.0, 0.0, math.radians(deg)])
    T = cam.camera_to_laser
    return CameraCalib(cam.model, Rigid(R @ T.rotation, T.translation))


def test_truth_sees_both_sets(rec: tuple[ValidationLog, Path]) -> None:
    log, _ = rec
    names = log.beam_colour()
    for colour in ("red", "green", "blue", "yellow"):
        assert names.count(colour) > 20, colour
    assert set(names) <= set(LABELS)


def test_true_calibration_colours_right(
    rec: tuple[ValidationLog, Path], truth_report: tuple[dict[str, Any], Path]
) -> None:
    log, _ = rec
    res, out = truth_report
    print(res)
    assert res["points"] > 5000 and res["front"][0] > 0 and res["back"][0] > 0
    assert res["share_right"] >= 0.95
    assert res["n_edges"] > 100 and res["sigma_px"] < 1.0
    assert abs(res["edge_mean_px"]) < 0.3
    assert sum(res["histogram"].values()) == res["points"]
    assert res["histogram"]["0"] == res["right"]
    assert sum(f[1] for f in res["frames"]) == res["points"]
    img = cv2.imread(str(out / "validate_overlay.png"))
    model = log.calibration.camera().model
    assert img is not None and img.shape[:2] == (model.height, model.width)


def test_perturbed_calibration_is_clearly_worse(
    rec: tuple[ValidationLog, Path], truth_report: tuple[dict[str, Any], Path]
) -> None:
    log, _ = rec
    good, _ = truth_report
    bad = validate(drive_log.read_log(log.files), _perturbed(log.calibration.camera(), 1.0))
    print(good["share_right"], good["sigma_px"], bad.share_right, bad.sigma_px)
    assert bad.share_right <= good["share_right"] - 0.10
    assert bad.sigma_px > 2 * good["sigma_px"]
    assert sum(bad.histogram[2:]) > 0.05 * bad.points


def test_main_json_and_overlay(
    rec: tuple[ValidationLog, Path], truth_report: tuple[dict[str, Any], Path]
) -> None:
    _, calib = rec
    report, out = truth_report
    assert report["camera"] == "camera" and report["share_right"] >= 0.95
    assert report["calib"] == str(calib)
    assert set(report["histogram"]) == {"0", "1", "2", "3", ">3"}
    assert report["overlay"] == str(out / "validate_overlay.png")
    assert (out / "validate_overlay.png").is_file()


def test_main_bad_input_exits_2(
    rec: tuple[ValidationLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, calib = rec
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    assert calibrate_validate([junk], calib) == 2
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncameras: {camera: {model: nonsense}}\n")
    assert calibrate_validate(log.files, bad) == 2
    assert calibrate_validate(log.files, tmp_path / "missing.yaml") == 2
    assert calibrate_validate(log.files, calib, camera="left") == 2
    err = capsys.readouterr().err
    assert err.count("acq calibrate validate:") == 4


def test_no_pattern_exits_1(
    rec: tuple[ValidationLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the log's calibration in an empty street (the ground only): no two parallel sets
    log = write_validation_log(tmp_path, duration_s=0.2, street=Street())
    assert set(log.beam_colour()) <= {"ground", "sky"}
    calib = tmp_path / "c.yaml"
    calibfile.save(Calibration(cameras={"camera": log.calibration.camera()}), calib)
    assert calibrate_validate(log.files, calib) == 1
    assert "no pattern" in capsys.readouterr().err


# --- the pattern in the street ------------------------------------------------------------


def test_pattern_stands_in_the_street(rec: tuple[ValidationLog, Path]) -> None:
    log, _ = rec
    assert log.street.quads == validation_pattern(PATTERN_AT)
    # the beams' truth comes from the street's caster: the bars 1.8 m across from the
    # scanner (laser -y), the panel 2.8 m; every bar and, through the gaps, the panel
    a = default_rig().angles
    across = -np.where(np.isfinite(log.beam_range), log.beam_range, 0.0) * np.sin(a)  # m
    names = np.array(log.beam_colour())
    for colour, y in (("red", PATTERN_FRONT_Y), ("green", PATTERN_FRONT_Y),
                      ("blue", PATTERN_BACK_Y), ("yellow", PATTERN_BACK_Y)):  # fmt: skip
        assert np.allclose(across[names == colour], y - PARK_Y, atol=1e-6), colour
    # six bars: six runs of front beams, alternately red and green from the bottom
    front = np.isin(names, ["red", "green"])
    starts = np.flatnonzero(np.diff(np.r_[0, front.astype(int)]) == 1)
    assert [names[i] for i in starts] == ["red", "green"] * 3
    assert np.all(
        np.isin(names[~front & (across > 0) & (across < 3.5)], ["blue", "yellow", "ground"])
    )


def test_labels_come_from_material_and_colour() -> None:
    red = DEFAULT_COLOURS["red"][::-1]
    mat = np.array([Material.SOLID, Material.FACADE, Material.CHECKER, Material.SKY, NO_RAY,
                    Material.SIDEWALK, Material.SOLID], np.uint8)  # fmt: skip
    col = np.array([red, red, DEFAULT_COLOURS["yellow"][::-1], (0, 0, 0), (0, 0, 0),
                    (1, 2, 3), (1, 2, 3)], np.uint8)  # fmt: skip
    got = [LABELS[i] for i in labels(mat, col)]
    assert got == ["red", "other", "yellow", "sky", "none", "ground", "other"]


def _fingerprint(street: Street) -> str:
    rows = [[b.xmin, b.xmax, b.ymin, b.ymax, b.zmin, b.zmax, b.material, *b.params]
            for b in street.boxes]  # fmt: skip
    rows += [[c.x, c.y, c.radius, c.zmin, c.zmax, 0.0, c.material, *c.params]
             for c in street.cylinders]  # fmt: skip
    return hashlib.sha256(np.array(rows, "<f8").tobytes()).hexdigest()[:16]


def test_street_without_pattern_is_unchanged() -> None:
    # recorded before Street.generate had pattern_at: other tests and the demo rely on it
    street = Street.generate(seed=1, length_m=120.0)
    assert (len(street.boxes), len(street.cylinders), len(street.quads)) == (102, 16, 0)
    assert street.version == 1
    assert _fingerprint(street) == "b15e757dd461c7ad"


def test_pattern_stretch_is_cleared_and_the_rest_kept() -> None:
    x = 60.0
    plain = Street.generate(seed=4, length_m=120.0)
    street = Street.generate(seed=4, length_m=120.0, pattern_at=x)
    assert street.quads == validation_pattern(x)
    lo, hi = x - PATTERN_CLEAR_M, x + PATTERN_CLEAR_M

    def in_stretch(xmin: float, xmax: float, ymin: float) -> bool:
        return ymin >= 0.0 and xmax > lo and xmin < hi

    for b in street.boxes:
        if b.material != Material.SIDEWALK:
            assert not in_stretch(b.xmin, b.xmax, b.ymin), b
    for c in street.cylinders:
        assert not in_stretch(c.x, c.x, c.y), c
    # everything elsewhere is the street without the pattern
    kept = [b for b in plain.boxes if not in_stretch(b.xmin, b.xmax, b.ymin)]
    assert all(b in street.boxes for b in kept)
    assert [c for c in plain.cylinders if not in_stretch(c.x, c.x, c.y)] == street.cylinders
    assert plain.boxes != street.boxes  # something stood there (seed 4: a building at least)
