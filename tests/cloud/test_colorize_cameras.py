"""`acq colorize` from every camera of the simulated rig (left, right and rear fisheyes,
each its own exposure and white balance over the drive), on a drive with its truth.

The rear camera is what ties the others' colours together: the left and right cameras
see no laser point in common, so how their white balances differ cannot be seen
without it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

from acq.camera import calibfile
from acq.cli.main import main as acq_main
from acq.sim.drive_log import DriveTruth, write_drive_log
from acq.sim.world import default_rig
from tests.cli_calls import printed


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, Path]:
    d = tmp_path_factory.mktemp("drive3")
    truth = write_drive_log(d, 1.5, rig=default_rig(cameras=3), configured_camera_latency_s=None)
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    return truth, calib


@pytest.fixture(scope="module")
def coloured(
    drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, dict]:
    """`acq colorize --json` of the drive from all its cameras, balanced (the default):
    the cloud and the report."""
    truth, calib = drive
    out = tmp_path_factory.mktemp("coloured") / "c.ply"
    argv = ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
            "--no-preview", "--json"]  # fmt: skip
    code, stdout, _ = printed(acq_main, argv)
    assert code == 0
    return out, json.loads(stdout)


def _ply(path: Path) -> tuple[np.ndarray, list[str]]:
    ply = PlyData.read(str(path))
    return ply["vertex"].data, list(ply.comments)


def _truth_rgb(truth: DriveTruth, v: np.ndarray) -> np.ndarray:
    """The true surface colour (RGB) of each PLY vertex, by its scan and step."""
    scan = v["scalar_scan"].astype(np.int64)
    # the PLY holds valid points in scan order; their steps are the finite ranges'
    steps = [np.flatnonzero(np.isfinite(truth.points[s, :, 0])) for s in np.unique(scan)]
    step = np.concatenate(steps)
    assert step.size == len(v)
    return truth.colours[scan, step][:, ::-1].astype(np.int64)


def test_every_camera_colours_its_side_and_each_point_names_its_source(
    drive: tuple[DriveTruth, Path], coloured: tuple[Path, dict]
) -> None:
    truth, _ = drive
    out, report = coloured
    v, comments = _ply(out)
    cameras = [c for c in comments if c.startswith("camera ")]
    assert cameras == ["camera 0 left", "camera 1 right", "camera 2 rear"], comments
    seen = truth.visible.any(axis=-1)
    ok = v["scalar_coloured"].astype(bool)
    assert ok.mean() >= 0.97 * seen[np.isfinite(truth.points[..., 0])].mean()
    camera, frame = v["scalar_camera"], v["scalar_frame"]
    assert {0, 1} <= set(np.unique(camera[ok]).tolist())
    assert np.all(camera[~ok] == 255) and np.all(frame[~ok] == -1)
    # the vehicle drives +x in the lane at y = -1.5: the left camera colours what is left
    left, right = v["y"] > 2.0, v["y"] < -5.0
    assert np.mean(camera[left & ok] == 0) > 0.99
    assert np.mean(camera[right & ok] == 1) > 0.99
    # frames are each camera's own, in time order: 36 each in 1.5 s (108 over the three)
    assert 0 <= frame[ok].min() and frame[ok].max() < 42
    assert list(report["cameras"]) == ["left", "right", "rear"]
    assert sum(c["points"] for c in report["cameras"].values()) == int(ok.sum())
    assert report["balance"]["applied"] and report["balance"]["pairs"] > 1000


def test_balance_brings_each_camera_to_the_surface_colours(
    drive: tuple[DriveTruth, Path], coloured: tuple[Path, dict], tmp_path: Path
) -> None:
    truth, calib = drive
    unbalanced = tmp_path / "c.ply"
    argv = ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(unbalanced),
            "--no-preview", "--no-balance"]  # fmt: skip
    assert acq_main(argv) == 0
    errors = {}
    for flag, out in (("", coloured[0]), ("--no-balance", unbalanced)):
        v, _ = _ply(out)
        ok = v["scalar_coloured"].astype(bool)
        rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.int64)
        errors[flag] = np.median(np.abs(rgb - _truth_rgb(truth, v))[ok], axis=0)
    # the left and right cameras' white balances (5 % off neutral, either way): several
    # levels off the surface colours as taken, within 2 once balanced
    assert errors["--no-balance"].max() >= 4
    assert errors[""].max() <= 2


def test_camera_picks_some_and_blend_mixes(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = drive
    files = list(map(str, truth.files))
    one = tmp_path / "right.ply"
    assert acq_main(["colorize", *files, "--calib", str(calib), "-o", str(one),
                     "--no-preview", "--camera", "right"]) == 0  # fmt: skip
    v, comments = _ply(one)
    assert "camera 0 right" in comments and not any("left" in c for c in comments)
    assert 0.3 < v["scalar_coloured"].mean() < 0.7  # one side of the street
    blend = tmp_path / "blend.ply"
    assert acq_main(["colorize", *files, "--calib", str(calib), "-o", str(blend),
                     "--no-preview", "--blend"]) == 0  # fmt: skip
    assert _ply(blend)[0]["scalar_coloured"].mean() > 0.9
    capsys.readouterr()
    bad = tmp_path / "bad.ply"
    assert acq_main(["colorize", *files, "--calib", str(calib), "-o", str(bad),
                     "--camera", "front"]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "front" in err[0], err
    assert not bad.exists()


def test_a_calibration_without_laser_to_vehicle_is_said(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from acq.camera.calibfile import Calibration

    truth, _ = drive
    bare = tmp_path / "bare.yaml"
    calibfile.save(Calibration(cameras=dict(truth.calibration.cameras)), bare)
    out = tmp_path / "c.ply"
    assert acq_main(["colorize", *map(str, truth.files), "--calib", str(bare), "-o", str(out),
                     "--no-preview", "--json"]) == 0  # fmt: skip
    notes = json.loads(capsys.readouterr().out)["notes"]
    assert any("no laser_to_vehicle" in n for n in notes), notes
