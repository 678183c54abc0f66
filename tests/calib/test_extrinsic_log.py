"""acq calibrate extrinsic on a simulated calibration recording (sim/board_log.py)."""

from __future__ import annotations

import json
import logging
import math
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acq.calib.checkerboard import BoardSpec
from acq.calib.extrinsic_log import (
    average_corners,
    board_segment,
    parse_poses,
    poses_from_log,
    still_intervals,
)
from acq.calib.fisheye_calib import parse_board
from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CalibStd, CameraCalib
from acq.geometry.rotations import rotation_angle
from acq.geometry.transforms import Rigid
from acq.log import drive_log
from acq.log.locate import first_log_time
from acq.sim.board_log import BoardLog, write_board_log
from tests.cli_calls import calibrate_extrinsic, printed
from tests.log_rewrite import jpeg


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> tuple[BoardLog, Path]:
    d = tmp_path_factory.mktemp("board_log")
    log = write_board_log(d, n_poses=12, seed=0, hold_s=1.0, move_s=0.3)
    intr = d / "intrinsics.yaml"
    calibfile.save(log.calibration, intr)
    return log, intr


INTRINSICS_STD = CalibStd(fx=0.08, fy=0.09, cx=0.07, cy=0.07, k=(2e-3, 4e-3, 3e-3, 1e-3))
INTRINSICS_NOTE = "f = r / theta_max from the image circle alone, not checked"


@pytest.fixture(scope="module")
def calibrated(
    rec: tuple[BoardLog, Path], tmp_path_factory: pytest.TempPathFactory
) -> tuple[dict[str, Any], Path]:
    """`acq calibrate extrinsic --camera camera --json` into a new CALIB, run once, with
    intrinsics that carry their standard errors and a note: the report and CALIB."""
    log, _ = rec
    d = tmp_path_factory.mktemp("extrinsic")
    cam = replace(log.calibration.camera("camera"), std=INTRINSICS_STD, note=INTRINSICS_NOTE)
    intr = d / "intrinsics.yaml"
    calibfile.save(Calibration(cameras={"camera": cam}), intr)
    out = d / "calib.yaml"
    code, stdout, _ = printed(calibrate_extrinsic, log.files, "camera", intr, log.spec, out,
                              json_out=True)  # fmt: skip
    assert code == 0
    return json.loads(stdout), out


def _errors(got: Rigid, truth: Rigid) -> tuple[float, float]:
    """Rotation error (deg) and translation error (m)."""
    rot = math.degrees(rotation_angle(got.rotation @ truth.rotation.T))
    return rot, float(np.linalg.norm(got.translation - truth.translation))


def test_still_intervals_match_the_holds(rec: tuple[BoardLog, Path]) -> None:
    log, _ = rec
    found = still_intervals(drive_log.read_log(log.files))
    assert len(found) == len(log.holds)
    for (a, b), (ha, hb) in zip(found, log.holds, strict=True):
        assert ha <= a < b <= hb + 50_000_000


def test_calibration_recovers_the_truth(
    rec: tuple[BoardLog, Path], calibrated: tuple[dict[str, Any], Path]
) -> None:
    log, _ = rec
    report, out = calibrated
    assert len(report["poses"]) == 12
    assert all(p["problem"] == "" for p in report["poses"])
    assert all(p["frames"] >= 5 for p in report["poses"])  # 25 frames a pose, 10 asked
    cam = calibfile.load(out).camera("camera")
    assert cam.method == "zhang_pless"
    assert cam.model.to_dict() == log.calibration.camera("camera").model.to_dict()
    rot, trans = _errors(cam.camera_to_laser, log.truth)
    print(f"recovered camera_to_laser: {rot:.3f} deg, {trans * 1e3:.1f} mm from the truth")
    assert rot < 0.15 and trans < 0.003
    assert report["plot"] == str(out.parent / "calib_extrinsic.png")
    assert (out.parent / "calib_extrinsic.png").stat().st_size > 0


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
    assert calibrate_extrinsic(log.files, None, intr, log.spec, out, poses=spans, plot=png) == 0
    text = capsys.readouterr().out
    assert "camera_to_laser" in text and png.exists()
    rot, trans = _errors(calibfile.load(out).camera().camera_to_laser, log.truth)
    assert rot < 0.5 and trans < 0.02


def test_frames_of_another_size_are_skipped_and_said(
    rec: tuple[BoardLog, Path], caplog: pytest.LogCaptureFixture
) -> None:
    """The first hold's frames all 640x480: that pose has no frame to use; the second is
    found as ever; one WARNING line names the count and the first frame's time and file."""
    board, _ = rec
    log = drive_log.read_log(board.files)
    (a, b), second = board.holds[0], board.holds[1]
    held = np.flatnonzero((log.frame_ns >= a) & (log.frame_ns <= b))
    odd = jpeg(640, 480)
    log = log.with_frames(jpegs=[odd if k in held else j for k, j in enumerate(log.jpegs)])
    model = board.calibration.camera("camera").model
    with caplog.at_level(logging.WARNING):
        first, ok = poses_from_log(log, model, parse_board(board.spec), [(a, b), second])
    assert first.pose is None and first.problem == "no frame of the camera model's size"
    assert ok.pose is not None and ok.problem == ""
    [line] = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    # 10 frames a pose are tried; this log has no timing records: the frames' stamps
    found = re.fullmatch(
        r"10 frames of another size \(640x480\) than the camera model's 780x582 skipped; "
        r"the first at log time (\d+\.\d{3}) s, (-?\d+\.\d{2}) s into (.+)",
        line,
    )
    assert found is not None, line
    t = float(found[1])
    assert min(abs(log.frame_ns[held] * 1e-9 - t)) < 1e-3
    start = (first_log_time(board.files[0]) or 0) * 1e-9
    assert float(found[2]) == pytest.approx(t - start, abs=0.01)
    assert found[3] == str(board.files[0])


def test_average_corners_aligns_and_drops_a_moved_board() -> None:
    rng = np.random.default_rng(1)
    truth = rng.uniform(0, 500, (63, 2))
    dets = [truth + rng.normal(0, 0.2, truth.shape) for _ in range(9)]
    dets[3] = dets[3][::-1]  # OpenCV reported this one reversed
    dets[5] = dets[5] + 4.0  # the board moved in this frame
    mean, n = average_corners(dets)
    assert n == 8
    one = np.sqrt(np.mean((dets[0] - truth) ** 2))
    assert np.sqrt(np.mean((mean - truth) ** 2)) < 0.6 * one  # ~1/sqrt(8)


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
    assert calibrate_extrinsic(log.files, None, intr, "9x7", out) == 2
    assert "--board" in capsys.readouterr().err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    assert calibrate_extrinsic([junk], None, intr, log.spec, out) == 2
    assert calibrate_extrinsic(log.files, None, tmp_path / "missing.yaml", log.spec, out) == 2
    assert calibrate_extrinsic(log.files, "nocam", intr, log.spec, out) == 2
    assert calibrate_extrinsic(log.files, None, intr, log.spec, out, poses="5:4") == 2
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
    assert calibrate_extrinsic(log.files, None, intr, log.spec, out, poses=spans) == 1
    assert "at least 5" in capsys.readouterr().err
    assert not out.exists()


def test_output_carries_the_std_of_the_result_and_keeps_the_intrinsics_std_and_note(
    calibrated: tuple[dict[str, Any], Path],
) -> None:
    report, out = calibrated
    std = calibfile.load(out).camera("camera").std
    assert std.rotation_deg is not None and std.translation_m is not None
    # the result's std: rotation about the laser axes (rad -> deg), then translation (m)
    np.testing.assert_allclose(std.rotation_deg, np.degrees(report["std"][:3]), rtol=5e-3)
    np.testing.assert_allclose(std.rotation_deg, report["std_rot_deg"], rtol=5e-3)
    np.testing.assert_allclose(std.translation_m, report["std"][3:], rtol=5e-3)
    assert std.merged(CalibStd(), CalibStd.EXTRINSICS) == INTRINSICS_STD
    assert calibfile.load(out).camera("camera").note == INTRINSICS_NOTE  # the intrinsics' own


def test_an_existing_calib_is_updated_and_keeps_the_other_cameras(
    rec: tuple[BoardLog, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """-o names a calib.yaml holding another camera (and this one's old entry): this
    camera's entry replaced, the other kept as it was, the old file kept as .bak; the two
    cameras' relative pose printed. No --force needed (the file is updated, not replaced)."""
    log, intr = rec
    model = log.calibration.camera("camera").model
    other = Rigid(np.eye(3), np.array([0.1, 0.2, 0.3]))
    stale = Rigid(np.eye(3), np.array([9.0, 9.0, 9.0]))
    out = tmp_path / "calib.yaml"
    calibfile.save(
        Calibration(cameras={"right": CameraCalib(model, other, 0.004),
                             "camera": CameraCalib(model, stale)}),
        out,
    )  # fmt: skip
    before = out.read_text()
    assert calibrate_extrinsic(log.files, "camera", intr, log.spec, out) == 0
    text = capsys.readouterr().out
    assert "relative poses of the cameras" in text and "right -> camera: rotation" in text
    cal = calibfile.load(out)
    assert list(cal.cameras) == ["right", "camera"]
    assert calibfile.dump(Calibration(cameras={"right": cal.camera("right")})) == calibfile.dump(
        Calibration(cameras={"right": CameraCalib(model, other, 0.004)})
    )
    rot, trans = _errors(cal.camera("camera").camera_to_laser, log.truth)
    assert rot < 0.15 and trans < 0.003
    assert (tmp_path / "calib.yaml.bak").read_text() == before


def test_a_wrong_board_size_is_answered_with_the_boards(rec: tuple[BoardLog, Path]) -> None:
    """Corners counted as squares, or one short: the size the frames show is suggested
    (in the order given); the right size, either way round, gets no hint."""
    from acq.calib.extrinsic_log import board_size_hint

    log, _ = rec
    dl = drive_log.read_log(log.files)
    intervals = still_intervals(dl)
    model = log.calibration.camera().model
    assert board_size_hint(dl, model, intervals, parse_board("8x6x0.1")) == (
        "; the images show a board of 9x7 inner corners (not squares): try --board 9x7x0.1"
    )
    assert board_size_hint(dl, model, intervals, parse_board("8x10x0.1")).endswith(
        "try --board 7x9x0.1"
    )
    assert board_size_hint(dl, model, intervals, parse_board("7x9x0.1")) == ""


def _board_scan(
    rng: np.random.Generator, noise_m: float = 0.002
) -> tuple[np.ndarray, float, float, np.ndarray]:
    """A scan (0.25 degree steps) of a wall 3 m away with a flat board across it at
    x = 1 m, |y| <= 0.3 m (``noise_m`` range noise): ranges, angle_min, increment, and
    the board's beam indices."""
    inc = math.radians(0.25)
    a0 = math.radians(-135.0)
    a = a0 + inc * np.arange(1081)
    ranges = np.full(a.size, 3.0)
    on = np.flatnonzero((np.cos(a) > 0) & (np.abs(np.tan(a)) <= 0.3))
    ranges[on] = 1.0 / np.cos(a[on]) + rng.normal(0.0, noise_m, on.size)
    return ranges, a0, inc, on


def test_board_segment_drops_mixed_returns_at_the_ends_and_keeps_the_rest() -> None:
    spec = BoardSpec(5, 4, 0.1)
    plane = (np.array([0.0, 0.0, 1.0]), 1.0)  # the camera's: only its distance is used here
    ranges, a0, inc, on = _board_scan(np.random.default_rng(4))
    clean = board_segment(ranges, a0, inc, plane, spec)
    assert clean is not None and len(clean) == on.size  # the ends on the line are kept
    # the beams grazing the board's edges: ranges between the board's and the wall's,
    # within the 5 cm that still joins them to the board's segment
    mixed = ranges.copy()
    ends = [on[0], on[1], on[-2], on[-1]]
    mixed[ends] += [0.04, 0.025, 0.025, 0.04]
    got = board_segment(mixed, a0, inc, plane, spec)
    assert got is not None and len(got) == on.size - 4
    y = np.sort(got[:, 1])
    expected = np.sort(ranges[on[2:-2]] * np.sin(a0 + inc * on[2:-2]))
    np.testing.assert_allclose(y, expected, atol=1e-9)
    # exact ranges: rounding errors are not off the line
    exact, _, _, _ = _board_scan(np.random.default_rng(4), 0.0)
    got = board_segment(exact, a0, inc, plane, spec)
    assert got is not None and len(got) == on.size
    # a point off the line with points on it beyond: noise on the board, kept
    inner = mixed.copy()
    inner[on[4]] += 0.03
    got = board_segment(inner, a0, inc, plane, spec)
    assert got is not None and len(got) == on.size - 4
