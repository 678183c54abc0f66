"""`acq calibrate check` (acq/calib/pose_check.py) on a short simulated drive recorded as
the recorder writes it, its camera's latency configured right: the true calibration
holds, a camera turned or shifted from it is said to have moved, by about what the
simulator moved it, and a drive that cannot tell says why."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from acq.calib.information import depth_edges, mutual_information
from acq.calib.pose_search import Scorer, Swath, shifted
from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.cli import main as acq_main
from acq.cloud.colorize import Report, prepare
from acq.cloud.drive_window import read_window
from acq.geometry.transforms import Rigid
from acq.log.drive_log import read_log
from acq.sim.drive_log import DriveTruth, write_drive_log
from tests.cli_calls import printed

SECONDS = 5.0


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, Calibration]:
    """The drive, and its true calibration with the camera's true time offset after the
    re-timing (a fraction of a millisecond)."""
    d = tmp_path_factory.mktemp("drive")
    truth = write_drive_log(d, SECONDS, pattern_at=None, seed=3, configured_camera_latency_s=None)
    job, _ = prepare(truth.files, truth.calibration, Report(output="x"))
    offset = truth.time_offsets_s(job)["camera"]
    cam = replace(truth.calibration.camera(), time_offset_s=offset)
    return truth, replace(truth.calibration, cameras={"camera": cam})


def _moved(calib: Calibration, x: np.ndarray) -> Calibration:
    """``calib`` with its camera's camera_to_laser changed by ``x`` (7,) (rad, m)."""
    name, cam = next(iter(calib.cameras.items()))
    cam = replace(cam, extrinsics=shifted(cam.camera_to_laser, x))
    return replace(calib, cameras={name: cam})


@pytest.fixture(scope="module")
def calibs(
    drive: tuple[DriveTruth, Calibration], tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, Path]:
    """CALIB files: the true calibration, and the camera turned 1 deg about the laser's
    z axis from where it is."""
    _, true_calib = drive
    d = tmp_path_factory.mktemp("calibs")
    x = np.zeros(7)
    x[2] = np.radians(1.0)
    good, turned = d / "good.yaml", d / "turned.yaml"
    calibfile.save(true_calib, good)
    calibfile.save(_moved(true_calib, x), turned)
    return good, turned


@dataclass(frozen=True)
class Colorized:
    out: str
    err: str
    cloud: Path


@pytest.fixture(scope="module")
def colorized_turned(
    drive: tuple[DriveTruth, Calibration],
    calibs: tuple[Path, Path],
    tmp_path_factory: pytest.TempPathFactory,
) -> Colorized:
    """`acq colorize --check --json` to a LAS with the turned CALIB, run once: what it
    printed and the cloud (the check is the command's dearest part; two tests read it)."""
    truth, _ = drive
    las = tmp_path_factory.mktemp("colorized") / "turned.las"
    argv = ["colorize", *map(str, truth.files), "--calib", str(calibs[1]), "-o", str(las),
            "--no-preview", "--check", "--json"]  # fmt: skip
    code, out, err = printed(acq_main, argv)
    assert code == 0
    return Colorized(out, err, las)


def test_depth_edges_are_the_near_side_of_a_range_jump() -> None:
    scan = np.array([0, 0, 0, 0, 0, 1, 1])
    step = np.array([0, 1, 2, 3, 5, 0, 1])
    r = np.array([5.0, 5.1, 3.0, 3.05, 3.0, 2.0, 9.0])
    # 2 is nearer than 1 by 2.1 m; 3 and 4 have a missing beam between them; scan 1's
    # first beam is nearer than its second
    assert depth_edges(scan, step, r).tolist() == [False, False, True, True, True, True, False]


def _random_scorer(calib: Calibration, channels: int, speed_mps: float = 0.0) -> Scorer:
    """A scorer of random images (3 frames of ``channels``) and 4000 random points in
    view, 8 bins, the edges' term weighed 0.5; the rig driving at ``speed_mps`` along x."""
    cam = calib.camera()
    rng = np.random.default_rng(1)
    frames, n, bins = 3, 4000, 8
    model = cam.model
    features = rng.integers(0, 256, (frames, model.height, model.width, channels), np.uint8)
    rays = model.unproject(rng.uniform([0, 0], [model.width - 1, model.height - 1], (n, 2)))
    P_laser = cam.camera_to_laser.apply(rng.uniform(3, 12, (n, 1)) * rays)
    at_rest = Rigid(np.eye(3), np.zeros(3))
    sw = Swath(
        P_laser, np.linspace(0, n, frames + 1).astype(np.int64), np.arange(frames) * 10**8,
        features, rng.integers(0, bins, n), rng.random(n) < 0.3,
        rng.integers(0, bins, (frames, 256)), rng.integers(0, bins, (frames, 256)), bins, 0.5,
    )  # fmt: skip

    def driving(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        along = np.zeros((t.size, 3))
        along[:, 0] = speed_mps * 1e-9 * t
        return np.broadcast_to(np.eye(3), (t.size, 3, 3)), along

    return Scorer(sw, model, cam.camera_to_laser, 0.0, at_rest, driving)


@pytest.mark.parametrize("channels", [1, 2])
def test_the_score_is_the_information_of_what_the_points_sample(
    drive: tuple[DriveTruth, Calibration], channels: int
) -> None:
    """The search's score, counted in one pass over the images, is the mutual
    information of the points' return strengths' bins and the grey levels' bins they
    sample (plus the weighted depth edges' with the gradients' when there is a gradient
    channel), at CALIB's pose and at a changed one."""
    score = _random_scorer(drive[1], channels)
    sw, n = score.swath, score.swath.points
    for x in (np.zeros(7), np.array([0.01, -0.02, 0.005, 0.03, 0.0, -0.02, 0.0])):
        values, ok = score.samples(x)
        f = score.frame_of[ok]
        want = mutual_information(sw.s_bins[ok], sw.grey_lut[f, values[ok, 0]], sw.bins)
        if channels == 2:
            e = sw.grad_lut[f, values[ok, 1]]
            want += 0.5 * mutual_information(sw.edge[ok].astype(np.int64), e, sw.bins)
        assert ok.sum() > 0.5 * n and score(x) == pytest.approx(want, rel=1e-12)


def test_candidates_scored_together_score_as_each_alone(
    drive: tuple[DriveTruth, Calibration],
) -> None:
    """Batches of candidates (the search's and the fit's) give each candidate the score
    a scorer of its own gives it, also when they ask for more time offsets than the
    scorer keeps points for (the rig moving, so each offset places the points anew)."""
    rng = np.random.default_rng(2)
    X = np.zeros((2 * Scorer.SLOTS + 3, 7))
    X[:, :6] = rng.normal(0, [0.005] * 3 + [0.01] * 3, (X.shape[0], 6))
    X[:, 6] = rng.choice(np.arange(12) * 0.002, X.shape[0])  # 12 offsets, some repeated
    many = _random_scorer(drive[1], 1, speed_mps=8.0)
    together = np.concatenate([many.many(X[a : a + 7]) for a in range(0, X.shape[0], 7)])
    alone = [_random_scorer(drive[1], 1, speed_mps=8.0)(x) for x in X]
    assert np.unique(X[:, 6]).size > Scorer.SLOTS
    np.testing.assert_array_equal(together, alone)
    assert many.evaluations == X.shape[0]
    assert np.ptp(alone) > 0  # the candidates differ


def test_every_kth_point_of_each_frame_is_kept() -> None:
    """The search's thinned swath: every k-th point of each frame, counted from the
    frame's first, with its own bins; the frames and their images the same."""
    starts = np.array([0, 5, 5, 12], dtype=np.int64)
    n = int(starts[-1])
    images, luts = np.zeros((3, 4, 4, 1), np.uint8), np.zeros((3, 256), np.int64)
    sw = Swath(np.arange(3 * n, dtype=float).reshape(n, 3), starts, np.arange(3), images,
               np.arange(n), np.arange(n) % 2 == 0, luts, luts, 4, 0.0)  # fmt: skip
    thin = sw.every(2)
    np.testing.assert_array_equal(thin.starts, [0, 3, 3, 7])
    np.testing.assert_array_equal(thin.s_bins, [0, 2, 4, 5, 7, 9, 11])
    np.testing.assert_array_equal(thin.P_world[:, 0], 3 * thin.s_bins)
    np.testing.assert_array_equal(thin.edge, thin.s_bins % 2 == 0)
    assert thin.frames == 3 and thin.features is sw.features


def test_a_turned_camera_has_moved_by_what_it_was_turned(
    drive: tuple[DriveTruth, Calibration], colorized_turned: Colorized
) -> None:
    """CALIB says the camera is turned 1 deg about the laser's z axis from where it is:
    the check (here `acq colorize --check`'s, in its JSON) says it moved, by about 1 deg,
    and its estimate is the truth's pose."""
    _, calib = drive
    c = json.loads(colorized_turned.out)["calibration_check"]["camera"]
    print(c)
    assert c["verdict"] == "moved" and "rotation" in c["reason"]
    true = calib.camera().camera_to_laser
    rotation = np.array(c["camera_to_laser"]["rotation"])
    translation = np.array(c["camera_to_laser"]["translation"])
    err = np.degrees(np.arccos(np.clip((np.trace(rotation @ true.rotation.T) - 1) / 2, -1, 1)))
    assert err < 0.15
    assert np.linalg.norm(translation - true.translation) < 0.02
    assert 0.8 < c["rotation_deg"] < 1.2 and c["px_at_10m"] > 2


def test_cli_verdict_json_and_write(
    drive: tuple[DriveTruth, Calibration], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A camera 4 cm off along the laser's y axis: moved (the text line), the refined
    calibration written with its standard errors, CALIB never overwritten without
    --force; the true calibration holds (--json); bad input one line and exit 2."""
    truth, true_calib = drive
    x = np.zeros(7)
    x[4] = 0.04
    calib = tmp_path / "calib.yaml"
    calibfile.save(_moved(true_calib, x), calib)
    before = calib.read_bytes()
    out = tmp_path / "refined.yaml"
    logs = [str(f) for f in truth.files]
    assert acq_main(["calibrate", "check", *logs, "--calib", str(calib), "--write", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    print(lines)
    assert lines[0].startswith("camera camera: moved by ") and "px at 10 m" in lines[0]
    assert lines[-1] == f"wrote {out}"
    refined = calibfile.load(out).camera()
    true = true_calib.camera().camera_to_laser
    assert np.linalg.norm(refined.camera_to_laser.translation - true.translation) < 0.02
    assert refined.std.translation_m is not None and max(refined.std.translation_m) < 0.02
    assert "acq calibrate check on " in refined.method
    # over CALIB: refused without --force, CALIB untouched
    argv = ["calibrate", "check", *logs, "--calib", str(calib), "--write", str(calib)]
    assert acq_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--write" in err, err
    assert calib.read_bytes() == before
    # the true calibration: holds, in JSON
    good = tmp_path / "good.yaml"
    calibfile.save(true_calib, good)
    assert acq_main(["calibrate", "check", *logs, "--calib", str(good), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["verdict"] == "holds" and report["camera"] == "camera", report["reason"]
    assert report["rotation_deg"] < 0.15 and report["translation_mm"] < 15
    assert abs(report["time_offset_ms"]) < 1.0
    assert report["frames"] >= 40 and report["points"] > 50_000
    # the estimate is the fitted quadratic's top: within the measure's noise of CALIB's
    assert abs(report["score_nats"]["estimate"] - report["score_nats"]["calib"]) < 0.002
    assert set(report["std"]) == {"rx", "ry", "rz", "tx", "ty", "tz", "dt"}
    assert len(report["blocks"]) >= 4
    # bad input
    assert acq_main(["calibrate", "check", *logs, "--calib", str(tmp_path / "no.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no.yaml" in err
    assert acq_main(["calibrate", "check", *logs, "--calib", str(good), "--frames", "3"]) == 2
    assert "--frames" in capsys.readouterr().err


def test_a_drive_that_cannot_tell_says_why(
    undecidable_drives: dict[str, tuple[list[Path], Path, str]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    for name, (files, calib, message) in undecidable_drives.items():
        out = tmp_path / f"{name}.yaml"
        argv = ["calibrate", "check", *map(str, files), "--calib", str(calib),
                "--write", str(out)]  # fmt: skip
        assert acq_main(argv) == 1, name
        captured = capsys.readouterr()
        assert captured.out.startswith("camera camera: cannot tell: "), captured.out
        assert message in captured.out, captured.out
        assert "nothing written" in captured.err and not out.exists()


def test_colorize_and_info_check_the_drive_and_warn_when_the_calibration_moved(
    drive: tuple[DriveTruth, Calibration],
    calibs: tuple[Path, Path],
    colorized_turned: Colorized,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`acq colorize --check` and `acq info --calib`: a camera turned 1 deg from CALIB is
    warned about in one line on stderr, its figures in the report (text and JSON) and in
    the cloud's metadata (a LAS VLR, a PLY comment); the true calibration holds, no
    warning."""
    import laspy

    from acq.cloud.las import CALIBRATION_CHECK_VLR

    truth, _ = drive
    good, moved = calibs
    logs = [str(f) for f in truth.files]

    (warning,) = colorized_turned.err.splitlines()
    assert warning.startswith(
        "acq colorize: warning: the calibration of camera camera has moved: camera camera: "
        "moved by "
    ), warning
    assert "acq calibrate check" in warning
    check = json.loads(colorized_turned.out)["calibration_check"]["camera"]
    assert check["verdict"] == "moved" and 0.8 < check["rotation_deg"] < 1.2, check
    vlrs = laspy.read(colorized_turned.cloud).header.vlrs
    (vlr,) = [v for v in vlrs if (v.user_id, v.record_id) == CALIBRATION_CHECK_VLR[:2]]
    assert vlr.record_data.decode().startswith("calibration check: camera camera: moved by ")

    ply = tmp_path / "good.ply"
    argv = ["colorize", *logs, "--calib", str(good), "-o", str(ply), "--no-preview", "--check"]
    assert acq_main(argv) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    said = [line for line in captured.out.splitlines() if line.startswith("calibration check")]
    assert len(said) == 1 and "camera camera: the calibration holds" in said[0], said
    header = ply.read_bytes()[:4000].split(b"end_header")[0].decode()
    assert f"comment {said[0]}" in header.splitlines()

    assert acq_main(["info", *logs, "--calib", str(moved)]) == 0
    captured = capsys.readouterr()
    out = captured.out.splitlines()
    at = out.index("calibration check:")
    assert out[at + 1].startswith("  camera camera: moved by "), out[at:]
    assert captured.err.startswith("acq info: warning: the calibration of camera camera has")
    # --json: each log's object carries its session's checks (the true calibration: holds)
    assert acq_main(["info", *logs, "--calib", str(good), "--json"]) == 0
    captured = capsys.readouterr()
    objects = json.loads(captured.out)
    assert objects and captured.err == ""
    assert all(o["calibration_check"]["camera"]["verdict"] == "holds" for o in objects)


def test_only_the_frames_the_check_picks_are_read_with_their_images(
    drive: tuple[DriveTruth, Calibration],
) -> None:
    """The check picks its frames from the job's stamps before reading the log: the
    window read then holds those frames, with the same bytes as a whole read, and the
    log reader keeps the images of the stamps asked for and no other."""
    truth, calib = drive
    job, _ = prepare(truth.files, calib, Report(output="x"))
    (cj,) = job.cameras
    whole = read_window(job, cj, seconds=SECONDS)
    some = read_window(job, cj, seconds=SECONDS, pick=lambda c, ns: np.arange(0, ns.size, 3))
    assert whole.frame_ns.size > 6
    np.testing.assert_array_equal(some.frame_ns, whole.frame_ns[::3])
    assert some.jpegs == whole.jpegs[::3]
    log = read_log(truth.files).with_camera(cj.name)
    wanted = {int(log.frame_ns[1]), int(log.frame_ns[4])}
    light = read_log(truth.files, jpegs_at={cj.name: wanted}).with_camera(cj.name)
    np.testing.assert_array_equal(light.frame_ns, log.frame_ns)
    assert [i for i, j in enumerate(light.jpegs) if j] == [1, 4]
    assert [light.jpegs[1], light.jpegs[4]] == [log.jpegs[1], log.jpegs[4]]
