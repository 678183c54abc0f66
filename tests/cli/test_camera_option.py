"""`--camera NAME` on every command that works per camera, on a two-camera log (left,
right) of the simulated rig: one option, and one answer listing the log's and the
calibration's names when a name is missing or wrong."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from acq.camera import calibfile
from acq.camera.selection import CameraChoiceError, choose_cameras
from acq.cli.main import main as acq_main
from acq.sim.drive_log import DriveTruth, write_drive_log
from acq.sim.world import default_rig


@pytest.fixture(scope="module")
def two(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, Path]:
    d = tmp_path_factory.mktemp("two")
    truth = write_drive_log(d, 0.4, rig=default_rig(cameras=2))
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    return truth, calib


def _commands(log: list[str], calib: Path, out: Path) -> dict[str, list[str]]:
    """Each per-camera command on the log, without --camera."""
    c = str(calib)
    return {
        "analyze sensitivity": ["analyze", "sensitivity", *log, "--calib", c, "-o", str(out)],
        "calibrate validate": ["calibrate", "validate", *log, "--calib", c],
        "calibrate extrinsic": [
            "calibrate",
            "extrinsic",
            *log,
            "--intrinsics",
            c,
            "--board",
            "8x6x0.1",
            "-o",
            str(out / "x.yaml"),
        ],
        "calibrate time-offset": [
            "calibrate",
            "time-offset",
            *log,
            "--calib",
            c,
            "-o",
            str(out / "t.yaml"),
        ],
        "calibrate check": ["calibrate", "check", *log, "--calib", c],
        "colorize": ["colorize", *log, "--calib", c, "-o", str(out / "c.ply")],
    }


@pytest.mark.parametrize(
    "command",
    ["analyze sensitivity", "calibrate validate", "calibrate extrinsic",
     "calibrate time-offset", "calibrate check", "colorize"],
)  # fmt: skip
def test_a_wrong_camera_name_lists_the_logs_and_the_calibrations_names(
    two: tuple[DriveTruth, Path], tmp_path: Path, command: str,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    truth, calib = two
    argv = _commands(list(map(str, truth.files)), calib, tmp_path)[command]
    assert acq_main([*argv, "--camera", "front"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"acq {command}: --camera front: in neither the log nor {calib} (the log has left, "
        f"right; {calib} has left, right)\n"
    ), err
    assert not (tmp_path / "x.yaml").exists() and not (tmp_path / "c.ply").exists()


@pytest.mark.parametrize("command", ["analyze sensitivity", "calibrate validate"])
def test_a_one_camera_command_on_two_cameras_asks_for_one_by_its_option(
    two: tuple[DriveTruth, Path], tmp_path: Path, command: str,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    truth, calib = two
    assert acq_main(_commands(list(map(str, truth.files)), calib, tmp_path)[command]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"acq {command}: the log has several cameras (left, right); name one with --camera "
        f"({calib} has left, right)\n"
    ), err


def test_analyze_sensitivity_takes_camera_on_a_two_camera_log(
    two: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = two
    argv = _commands(list(map(str, truth.files)), calib, tmp_path)["analyze sensitivity"]
    assert acq_main([*argv, "--camera", "right", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["camera"] == "right"
    assert (tmp_path / "sensitivity.json").exists()


def test_a_calibration_whose_names_are_not_the_logs_says_so(
    two: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, _ = two
    cal = truth.calibration
    other = tmp_path / "renamed.yaml"
    renamed = dict(zip(("cam0", "cam1"), cal.cameras.values(), strict=True))
    calibfile.save(calibfile.Calibration(cal.laser, renamed, cal.laser_to_vehicle), other)
    out = tmp_path / "c.ply"
    argv = ["colorize", *map(str, truth.files), "--calib", str(other), "-o", str(out)]
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        f"acq colorize: the log's camera names and {other}'s do not match (the log has "
        f"left, right; {other} has cam0, cam1); rename the cameras in {other} to the "
        "log's names\n"
    ), err
    assert not out.exists()


def test_an_option_is_taken_by_its_whole_name_only(
    two: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A prefix once took `--camera left` as --camera-height; no prefix is an option now."""
    truth, calib = two
    argv = _commands(list(map(str, truth.files)), calib, tmp_path)["analyze sensitivity"]
    assert acq_main([*argv, "--camera-h", "3"]) == 2
    assert "unrecognized arguments: --camera-h 3" in capsys.readouterr().err
    assert not (tmp_path / "sensitivity.json").exists()


def test_choose_cameras_pairs_a_lone_camera_whatever_its_name() -> None:
    assert choose_cameras(None, ["front"], ["camera"], one=True) == [("front", "camera")]
    assert choose_cameras(None, ["left", "right"], ["right"], one=True) == [("right", "right")]
    assert choose_cameras(None, ["left", "right"], ["left", "right", "rear"], one=False) == [
        ("left", "left"), ("right", "right"),
    ]  # fmt: skip
    with pytest.raises(CameraChoiceError, match=r"--camera rear: not in the log \(the log has"):
        choose_cameras(["rear"], ["left", "right"], ["left", "right", "rear"], one=False)
    with pytest.raises(CameraChoiceError, match="the log has no camera frames"):
        choose_cameras(None, [], ["left"], one=True)


def test_sim_render_takes_camera_and_lists_the_rigs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "r"
    assert acq_main(["sim", "render", "--out", str(out), "--camera", "front"]) == 2
    assert capsys.readouterr().err == (
        "acq sim render: --camera front: the simulated rig has no such camera (has camera, "
        "left, right, rear)\n"
    )
    assert not out.exists()
    assert acq_main(["sim", "render", "--out", str(out), "--camera", "right"]) == 0
    assert list(calibfile.load(out / "calib.yaml").cameras) == ["right"]
    assert "pixel error against the truth: RMS 0.0" in capsys.readouterr().out


@pytest.mark.parametrize("command", ["colorize", "calibrate extrinsic"])
def test_a_camera_named_twice_is_refused_naming_it(
    two: tuple[DriveTruth, Path], tmp_path: Path, command: str,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """Once coloured twice into one cloud, its header naming "camera 0 left" and "camera 1
    left"; then merged without a word: a repeated name is a slip, refused before work."""
    truth, calib = two
    argv = _commands(list(map(str, truth.files)), calib, tmp_path)[command]
    assert acq_main([*argv, "--camera", "left", "--camera", "right", "--camera", "left"]) == 2
    err = capsys.readouterr().err
    assert err == f"acq {command}: --camera left: named twice; give each camera once\n", err
    assert sorted(tmp_path.iterdir()) == []
    with pytest.raises(CameraChoiceError, match="--camera right: named twice"):
        choose_cameras(["right", "right"], ["left", "right"], ["left", "right"], one=False)


@pytest.mark.parametrize("command", ["analyze sensitivity", "calibrate validate"])
def test_a_one_camera_command_refuses_a_second_camera(
    two: tuple[DriveTruth, Path], tmp_path: Path, command: str,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """argparse's ``store`` kept the last of two ``--camera`` silently: the work was done
    for one camera when two were asked for."""
    truth, calib = two
    argv = _commands(list(map(str, truth.files)), calib, tmp_path)[command]
    assert acq_main([*argv, "--camera", "left", "--camera", "right"]) == 2
    err = capsys.readouterr().err
    assert err == (f"acq {command}: argument --camera: given twice (left, right): this "
                   "command works on one camera; run it once for each\n"), err  # fmt: skip
    assert sorted(tmp_path.iterdir()) == []


def test_colorize_one_camera_of_two_does_not_call_the_other_missing(
    two: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The right camera has frames; it was only not asked for."""
    truth, calib = two
    argv = _commands(list(map(str, truth.files)), calib, tmp_path)["colorize"]
    assert acq_main([*argv, "--camera", "left", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert not any("right" in note for note in report["notes"]), report["notes"]
    assert list(report["cameras"]) == ["left"]
