"""The camera's time offset from a drive (acq/time_offset.py): `acq calibrate time-offset`
and `acq colorize --time-offset auto` on simulated drives whose camera latency the
configuration gets 10 ms wrong."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from acq.calib.information import joint_counts, mutual_information, quantile_bins
from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.cloud.colorize import run
from acq.log.locate import first_log_time
from acq.sim.drive_log import DriveTruth, write_drive_log
from tests.log_rewrite import corrupt_chunk, jpeg, rewrite


def _true_error(truth: DriveTruth) -> float:
    return truth.config["camera_latency_true_s"] - truth.config["camera_latency_configured_s"]


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, Path]:
    d = tmp_path_factory.mktemp("drive")
    truth = write_drive_log(d, 6.0, pattern_at=None, seed=2)
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)  # the true calibration: offset 0
    return truth, calib


def test_mutual_information_of_equal_and_independent_samples() -> None:
    rng = np.random.default_rng(0)
    a = rng.integers(0, 16, 200_000)
    assert mutual_information(a, a, 16) == pytest.approx(np.log(16), rel=1e-3)
    assert mutual_information(a, rng.integers(0, 16, a.size), 16) < 2e-3
    assert mutual_information(a, (a + rng.integers(0, 2, a.size)) % 16, 16) > 1.5


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_joint_counts_bin_as_quantile_bins_do(dtype: type) -> None:
    """The joint counts the curves are made of: the masked samples binned by the edges
    as quantile_bins bins them (a value on an edge, NaN and infinities included)."""
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 255, 50_000).astype(dtype)
    edges = np.quantile(x, np.linspace(0, 1, 17)[1:-1])
    x[:4] = [np.nan, np.inf, -np.inf, edges[5]]
    a = rng.integers(0, 16, x.size)
    mask = rng.random(x.size) < 0.8
    mask[:4] = True
    joint = np.zeros((16, 16), dtype=np.int64)
    joint_counts(a, x, edges, mask, joint)
    binned = quantile_bins(x[mask], 16, edges)
    assert (joint == np.bincount(a[mask] * 16 + binned, minlength=256).reshape(16, 16)).all()


def test_calibrate_time_offset_finds_the_latency_error(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = drive
    out = tmp_path / "calib.yaml"
    argv = ["calibrate", "time-offset", *map(str, truth.files), "--calib", str(calib),
            "-o", str(out), "--json"]  # fmt: skip
    assert acq_main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    cam = calibfile.load(out).camera("camera")
    err = _true_error(truth)
    assert abs(err) > 0.009  # the configuration is 10 ms wrong
    print(cam.time_offset_s, cam.std.time_offset_s, err)
    assert cam.time_offset_s == pytest.approx(err, abs=0.0015)
    assert cam.std.time_offset_s is not None and 0 < cam.std.time_offset_s < 0.002
    assert report["found"] and report["frames"] > 100 and report["contrast"] > 0.1
    # the curve peaks at the estimate, and the rest of CALIB is kept
    curve = report["curve"]
    assert abs(curve["offset_s"][int(np.argmax(curve["mi_nats"]))] - err) <= 0.003
    kept = truth.calibration.camera("camera").camera_to_laser
    np.testing.assert_allclose(cam.camera_to_laser.matrix(), kept.matrix(), atol=1e-12)
    # the method says the offset is the log's estimate, no longer the input's "truth"
    name = truth.files[0].name
    assert cam.method == (
        f"truth; time_offset_s: estimated from {name} ({report['frames']} frames, "
        f"{report['points']} laser points; mutual information of grey levels and return "
        "strengths)"
    )


def test_colorize_auto_uses_the_estimate_and_gets_the_pixels_right(
    drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    truth, calib = drive
    errors = {}
    for name, offset in (("configured", None), ("auto", "auto")):
        results: list = []
        report = run(truth.files, calibfile.load(calib), tmp_path / f"{name}.ply",
                     time_offset_s=offset, results=results, want_uv=True, preview=None)  # fmt: skip
        scan = np.concatenate([r.scan for r in results]).astype(np.int64)
        step = np.concatenate([r.step for r in results]).astype(np.int64)
        stamp = np.concatenate([r.frame_stamp_ns for r in results])
        uv = np.concatenate([r.uv for r in results])
        ok = stamp >= 0
        true_uv, valid = truth.true_pixels(scan[ok], step[ok], stamp[ok])
        e = np.linalg.norm(uv[ok][valid] - true_uv[valid], axis=1)
        errors[name] = float(np.sqrt(np.mean(e**2)))
        if offset == "auto":
            assert report.time_offset["found"]
            assert report.time_offset["used_s"] == pytest.approx(_true_error(truth), abs=0.0015)
            assert "time offset" in report.seconds
            # printed without --json too: the offset used and its standard error
            t = report.time_offset
            assert (
                f"time offset camera: {1e3 * t['used_s']:+.2f} ms +- {1e3 * t['std_s']:.2f} ms "
                f"(camera minus laser time), estimated from {t['frames']:,} frames of this log "
                "(--time-offset auto)"
            ) in report.lines()
        else:
            assert not any(ln.startswith("time offset") for ln in report.lines())
    print(errors)
    assert errors["configured"] > 1.5 and errors["auto"] < 0.5


def test_the_estimate_reads_its_window_itself_for_workers(drive: tuple[DriveTruth, Path]) -> None:
    """With workers or Dask the log's images are not in this process: the estimate reads
    the part it uses, and gets what it gets from the log read whole."""
    from acq.cloud.colorize import Report, estimate_offset, prepare

    truth, calib = drive
    job, whole = prepare(truth.files, calibfile.load(calib), Report(output="x"), jpegs=True)
    # 2.5 s of the middle (62 frames) are enough to find the offset: the property is
    # that the two reads agree, not the accuracy of a long window
    mine = estimate_offset(job, seconds=2.5)
    given = estimate_offset(job, whole=whole, seconds=2.5)
    assert mine.found and mine.frames == given.frames and mine.points == given.points
    assert mine.offset_s == given.offset_s
    assert mine.offset_s == pytest.approx(_true_error(truth), abs=0.003)


def test_the_standard_error_follows_the_offset_along_the_drive(
    drive: tuple[DriveTruth, Path],
) -> None:
    """The estimate's error comes from the scene, which neighbouring frames share: its
    standard error is a jackknife over blocks of consecutive frames, not the spread of
    sets of every k-th frame (those agree with each other while all being off together).
    Here the camera's stamps drift from -8 to +8 ms over the drive: the blocks' offsets
    spread over that, which the standard error shows (their mean's: about 1.3 ms), and
    leaving out an early block (stamps early) raises the estimate."""
    from dataclasses import replace

    from acq.cloud.colorize import Report, estimate_offset, prepare

    truth, calib = drive
    job, whole = prepare(truth.files, calibfile.load(calib), Report(output="x"), jpegs=True)
    cj = job.cameras[0]
    drift = np.linspace(-8e6, 8e6, cj.frame_new.size).astype(np.int64)
    drifting = replace(job, cameras=(replace(cj, frame_new=cj.frame_new + drift),))
    est = estimate_offset(drifting, whole=whole, threads=2)
    print(est.offset_s, est.std_s, est.folds_s)
    assert est.found and len(est.folds_s) == 12
    assert est.std_s > 0.0012
    early, late = np.mean(est.folds_s[:6]), np.mean(est.folds_s[6:])
    assert early > late + 0.0003


def test_no_estimate_without_motion_or_return_strengths(
    undecidable_drives: dict[str, tuple[list[Path], Path, str]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    for name, (files, calib, message) in undecidable_drives.items():
        out = tmp_path / f"{name}.yaml"
        argv = ["calibrate", "time-offset", *map(str, files), "--calib", str(calib),
                "-o", str(out)]  # fmt: skip
        assert acq_main(argv) == 1, name
        err = capsys.readouterr().err
        assert message in err and err.startswith("acq calibrate time-offset: no estimate"), err
        assert not out.exists()
        # colorize keeps CALIB's offset and says why
        report = run(files, calibfile.load(calib), tmp_path / f"{name}.ply",
                     time_offset_s="auto", preview=None,
                     frame="laser" if name == "no_odometry" else None)  # fmt: skip
        assert report.time_offset["used_s"] == 0.0 and not report.time_offset["found"]
        assert any(message in n for n in report.notes), report.notes


def test_bad_input_is_one_line_and_exit_2(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = drive
    missing = tmp_path / "nope.yaml"
    argv = ["calibrate", "time-offset", *map(str, truth.files), "--calib", str(missing),
            "-o", str(tmp_path / "o.yaml")]  # fmt: skip
    assert acq_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "nope.yaml" in err and len(err.splitlines()) == 1
    assert acq_main(["colorize", str(truth.files[0]), "--calib", str(calib), "-o", "x.ply",
                     "--time-offset", "soon"]) == 2  # fmt: skip
    assert "or 'auto', got 'soon'" in capsys.readouterr().err


def test_frames_of_another_size_and_a_corrupt_chunk_are_skipped_and_said(
    drive: tuple[DriveTruth, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """One WARNING line each: the corrupt chunk (the log is read twice: said once), the
    frames of another size with the first one's time and file; the estimate is made, its
    reading and its frames on progress bars (--progress)."""
    truth, calib = drive
    odd = jpeg(640, 480)
    files, times = rewrite(truth.files, tmp_path, frames={30: odd, 45: odd}, chunk_size=1 << 20)
    lo, hi, _ = corrupt_chunk(files[0], -1)  # after the odd frames
    assert times[45] < lo
    argv = ["calibrate", "time-offset", *map(str, files), "--calib", str(calib),
            "-o", str(tmp_path / "calib.yaml"), "--frames", "60", "--progress"]  # fmt: skip
    with caplog.at_level(logging.WARNING):
        assert acq_main(argv) == 0
    first = first_log_time(files[0]) or 0
    corrupt, sizes = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert corrupt.startswith(
        f"{files[0]}: 1 corrupt chunk skipped "
        f"({(lo - first) * 1e-9:.1f}..{(hi - first) * 1e-9:.1f} s into the file, "
    ) and corrupt.endswith(" messages lost)")
    assert sizes == (
        "time offset: 2 frames of another size (640x480) than the camera model's 780x582 "
        f"skipped; the first at log time {times[30] * 1e-9:.3f} s, "
        f"{(times[30] - first) * 1e-9:.2f} s into {files[0]}"
    )
    bars = [x for x in capsys.readouterr().err.replace("\r", "\n").splitlines() if x]
    assert any(x.startswith("reading: 100%") for x in bars)
    assert any(x.startswith("time offset (") and "100%" in x for x in bars), bars


def test_every_camera_of_a_rig_in_one_call(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Left and right cameras, the same latency configured for both (right for the left
    camera, 6 ms short for the right one): one call estimates each into one OUT."""
    from acq.sim.world import default_rig

    rig = default_rig(cameras=2)
    truth = write_drive_log(tmp_path / "d", 4.0, pattern_at=None, seed=2, rig=rig,
                            configured_camera_latency_s=0.025)  # fmt: skip
    calib = tmp_path / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    out = tmp_path / "out.yaml"
    argv = ["calibrate", "time-offset", *map(str, truth.files), "--calib", str(calib),
            "-o", str(out)]  # fmt: skip
    assert acq_main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split(":")[0] for ln in lines[:2]] == ["camera left", "camera right"]
    got = calibfile.load(out)
    for name in ("left", "right"):
        c = truth.cameras[name]
        err = c.latency_true_s - c.latency_configured_s
        assert got.camera(name).time_offset_s == pytest.approx(err, abs=0.0025), name
    assert acq_main([*argv[:-2], "-o", str(tmp_path / "x.yaml"), "--camera", "front"]) == 2
