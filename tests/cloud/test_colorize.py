"""acq colorize on a simulated drive (sim/drive_log.py): outputs, views, scale-out."""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from pathlib import Path

import laspy
import numpy as np
import pytest
from mcap.reader import make_reader
from plyfile import PlyData

from acq import cloud
from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.cloud import colorize
from acq.cloud.colorize import plan, run
from acq.cloud.views import Options
from acq.log import drive_log, info
from acq.log.locate import first_log_time
from acq.log.reader import read_metadata
from acq.log.timebase import MONOTONIC
from acq.log.vehicle_log import read_vehicle
from acq.sim.drive_log import DriveTruth, write_drive_log
from tests.cli_calls import printed
from tests.log_rewrite import corrupt_chunk, jpeg, rewrite


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, Path]:
    d = tmp_path_factory.mktemp("drive")
    truth = write_drive_log(d, 4.0, pattern_at=15.0)
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    return truth, calib


def _args(*argv: str) -> list[str]:
    return ["colorize", *argv]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_ply_and_las_carry_every_point_with_its_time(
    drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    truth, calib = drive
    ply, las = tmp_path / "c.ply", tmp_path / "c.las"
    for out in (ply, las):
        args = _args(*map(str, truth.files), "--calib", str(calib), "-o", str(out),
                     "--frame", "laser")  # fmt: skip
        assert acq_main(args) == 0
    v = PlyData.read(str(ply))["vertex"].data
    n_valid = int(np.isfinite(drive_log.read_log(truth.files).ranges).sum())
    assert len(v) == n_valid
    assert 0.2 < v["scalar_coloured"].mean() < 0.9  # the camera looks to one side
    assert np.all(np.diff(v["scalar_time"]) >= -1e-9)  # UTC seconds, in time order
    assert (tmp_path / "c_preview.png").stat().st_size > 0
    pc = laspy.read(str(las))
    assert pc.header.version == "1.4" and pc.header.point_format.id >= 7
    assert pc.header.global_encoding.gps_time_type == laspy.header.GpsTimeType.STANDARD
    assert pc.header.parse_crs() is None  # the laser frame has no CRS
    assert len(pc.points) == len(v)
    np.testing.assert_allclose(pc.x, v["x"], atol=6e-4)  # millimetres kept
    # Adjusted Standard GPS time = UTC + leap seconds - GPS epoch - 1e9
    gps = v["scalar_time"] - 315_964_800 + 18 - 1e9
    np.testing.assert_allclose(pc.gps_time, gps, atol=1e-6)
    assert np.array_equal(np.asarray(pc.coloured), v["scalar_coloured"])
    assert np.array_equal(np.asarray(pc.red) // 257, v["red"])
    assert np.all(np.asarray(pc.return_number) == 1) and pc.header.point_count == len(v)
    np.testing.assert_allclose(pc.header.mins, [v["x"].min(), v["y"].min(), v["z"].min()],
                               atol=1e-3)  # fmt: skip


def test_a_log_from_before_utc_logs_gives_the_same_cloud_and_info(
    drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    """A log written before log times became UTC (host monotonic throughout, its metadata
    without an offset) is known by its metadata and reads the same in every command."""
    truth, calib = drive
    old, _ = rewrite(truth.files, tmp_path / "old", time_base=MONOTONIC)
    assert "utc_offset_ns" not in read_metadata(old[0])["acq"]
    with old[0].open("rb") as f:  # host monotonic in the file: 1000 s after boot
        first = next(m for _, _, m in make_reader(f).iter_messages())
    assert first.log_time < 10**13 < truth.files[0].stat().st_mtime_ns
    clouds = []
    for files, name in ((truth.files, "new.ply"), (old, "old.ply")):
        out = tmp_path / name
        args = _args(*map(str, files), "--calib", str(calib), "-o", str(out), "--no-preview")
        assert acq_main(args) == 0
        clouds.append(PlyData.read(str(out))["vertex"].data)
    assert clouds[0].dtype == clouds[1].dtype and np.array_equal(clouds[0], clouds[1])
    assert clouds[0]["scalar_time"][0] > 1.8e9  # UTC seconds, 2027 in the simulation
    new_info, old_info = info(truth.files[0]), info(old[0])
    assert new_info.time_base.utc and not old_info.time_base.utc
    assert new_info.start_ns == old_info.start_ns
    assert new_info.start_realtime_ns == old_info.start_realtime_ns


def test_offline_retiming_brings_stamps_to_the_truth(
    drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    truth, calib = drive
    results: list = []
    report = run(truth.files, calibfile.load(calib), tmp_path / "c.ply", frame="laser",
                 results=results, want_uv=True, preview=None)  # fmt: skip
    assert report.retiming["frame_residual_rms_ms"] > 1.0  # the receipt jitter removed
    stamps = np.concatenate([r.frame_stamp_ns for r in results])
    used = stamps[stamps >= 0]
    assert np.isin(used, truth.frame_stamp_ns).all()


class _Chunked:
    """The drive coloured by `acq colorize --chunk 1.5` (3 chunks) in the laser frame, in
    this process, each way run once per module when a test first asks for it (a run on
    workers or dask is the costly part): "here" (the log read once), "parts" (a log too
    long to hold its images: each chunk reads its part), "workers" (--workers 2) and
    "dask" (a LocalCluster of 2 processes); those two with --progress, the frame
    reports their chunks send (_ChunkShares.frames_done) kept."""

    def __init__(self, truth: DriveTruth, calib: Path, folder: Path) -> None:
        self.truth, self.calib, self.folder = truth, calib, folder
        self.runs: dict[str, tuple[str, dict, list[tuple[int, int, int]]]] = {}

    def __call__(self, way: str) -> tuple[str, dict, list[tuple[int, int, int]]]:
        """``way``'s output digest, its --json report and its chunks' frame reports."""
        if way not in self.runs:
            with pytest.MonkeyPatch.context() as mp:
                self.runs[way] = self._run(way, mp)
        return self.runs[way]

    def _run(self, way: str, mp: pytest.MonkeyPatch) -> tuple[str, dict, list]:
        from acq.cloud.colorize import _ChunkShares

        reports: list[tuple[int, int, int]] = []
        real = _ChunkShares.frames_done

        def seen(shares: _ChunkShares, index: int, done: int, total: int) -> None:
            reports.append((index, done, total))
            real(shares, index, done, total)

        mp.setattr(_ChunkShares, "frames_done", seen)
        if way == "parts":
            mp.setattr(colorize, "READ_ONCE_BYTES", 0)
        out = self.folder / f"{way}.ply"
        argv = _args(*map(str, self.truth.files), "--calib", str(self.calib), "-o", str(out),
                     "--frame", "laser", "--no-preview", "--chunk", "1.5", "--json")  # fmt: skip
        with contextlib.ExitStack() as stack:
            if way == "workers":
                argv += ["--workers", "2", "--progress"]
            elif way == "dask":
                from dask.distributed import LocalCluster

                cluster = stack.enter_context(
                    LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                 dashboard_address=None)
                )  # fmt: skip
                argv += ["--dask", cluster.scheduler_address, "--progress"]
            code, stdout, _ = printed(acq_main, argv)
        assert code == 0
        return _digest(out), json.loads(stdout), reports


@pytest.fixture(scope="module")
def chunked(drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory) -> _Chunked:
    return _Chunked(*drive, tmp_path_factory.mktemp("chunked"))


def test_same_bytes_with_workers_and_chunks(chunked: _Chunked) -> None:
    here, parts, workers = chunked("here")[0], chunked("parts")[0], chunked("workers")[0]
    assert here == workers == parts
    assert len(plan(np.arange(0, 4_000_000_000, 25_000_000), 1.5)) == 3


def test_dask_local_cluster_gives_the_same_bytes(chunked: _Chunked) -> None:
    assert chunked("dask")[0] == chunked("here")[0]


@pytest.mark.parametrize("where", ["workers", "dask"])
def test_chunks_run_elsewhere_report_their_frames_as_they_go(where: str, chunked: _Chunked) -> None:
    """With --workers or --dask each chunk reports its frames done through a queue (its
    first frame at once, then at most every 0.25 s, and its last), so the bar moves
    within chunks there too; the reports reach the bar in this process."""
    _, report, reports = chunked(where)
    assert report["chunks"] == 3
    within = 0
    for index in range(report["chunks"]):
        mine = [(d, t) for i, d, t in reports if i == index]
        assert mine and (mine[0][1],) * 2 in mine  # the last frame reported
        within += min(d for d, _ in mine) < mine[0][1]
    assert within  # and before (all of a chunk's frames done at once only if starved)


def test_a_long_logs_preview_thins_its_scans_not_the_cloud(
    drive: tuple[DriveTruth, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    truth, calib = drive
    monkeypatch.setattr(colorize, "PREVIEW_POINTS", 20_000)
    out, png = tmp_path / "c.ply", tmp_path / "c.png"
    report = run(truth.files, calibfile.load(calib), out, frame="laser", preview=png)
    every = [n for n in report.notes if n.startswith("the preview shows one scan in")]
    assert every and png.stat().st_size > 0
    assert len(PlyData.read(str(out))["vertex"]) == report.points > 20_000


@pytest.mark.parametrize("read_once", [True, False])
def test_the_preview_from_what_the_run_holds_is_the_whole_clouds(
    drive: tuple[DriveTruth, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    read_once: bool,
) -> None:  # fmt: skip
    """The preview is drawn from the fields the run keeps of each chunk, joined at the
    end: pixel for pixel the one drawn from every chunk's whole result."""
    import cv2

    from acq.cloud.preview import preview_png

    truth, calib = drive
    if not read_once:  # each chunk reads its own part
        monkeypatch.setattr(colorize, "READ_ONCE_BYTES", 0)
    out, png, whole = tmp_path / "c.ply", tmp_path / "c.png", tmp_path / "whole.png"
    results: list[colorize.ChunkResult] = []
    run(truth.files, calibfile.load(calib), out, preview=png, results=results, chunk_s=1.5)
    assert len(results) == 3
    index = drive_log.read_log(truth.files, cameras=list(truth.camera_names), jpegs=False)
    cloud = colorize.cloud_of(results, index, list(truth.camera_names))
    preview_png(whole, cloud, title=f"acq colorize {out.name}")
    held, drawn = cv2.imread(str(png)), cv2.imread(str(whole))
    assert held is not None and drawn is not None and held.shape == drawn.shape
    np.testing.assert_array_equal(held, drawn)


def test_a_started_chunk_leaves_its_jpegs_to_its_queued_frames(
    drive: tuple[DriveTruth, Path],
) -> None:
    """Once a chunk is read, placed and its frames queued, only the queued tasks hold
    its JPEGs (each let go when decoded); its result is the one colour_chunk gives."""
    from concurrent.futures import ThreadPoolExecutor

    from acq.camera.jpeg import SharedDecodes
    from acq.cloud.chunks import start_chunk
    from acq.cloud.report import Report

    truth, calib = drive
    job, _ = colorize.prepare(truth.files, calibfile.load(calib), Report(output="x.ply"))
    chunk = colorize.plan(np.sort(job.scan_new), 1.5)[1]
    with ThreadPoolExecutor(max_workers=2) as pool:
        started = start_chunk(job, chunk, None, pool, SharedDecodes(pool))
        assert sum(len(f.frame_ns) for f in started.log.cameras.values()) > 50
        assert all(not f.jpegs for f in started.log.cameras.values())
        assert all(not c.jpegs for c in started.cameras)
        got = started.result()
    want = colorize.colour_chunk(job, chunk)
    assert got.frames_used == want.frames_used > 0
    np.testing.assert_array_equal(got.rgb, want.rgb)
    np.testing.assert_array_equal(got.xyz, want.xyz)


def test_a_long_log_read_with_its_first_chunks_images_gives_the_same_bytes(
    drive: tuple[DriveTruth, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A log too long to hold its images is read once with those of its first chunks
    (cut from that read), the later chunks reading their own part: the same bytes as
    read whole, and the light read holds the images of its first span only."""
    truth, calib = drive
    cal = calibfile.load(calib)
    run(truth.files, cal, tmp_path / "whole.ply", chunk_s=0.5, preview=None)
    monkeypatch.setattr(colorize, "READ_ONCE_BYTES", 0)
    monkeypatch.setattr(colorize, "HELD_SLACK_S", 3.0)  # 4 s held: 2 of the 8 chunks
    run(truth.files, cal, tmp_path / "parts.ply", chunk_s=0.5, preview=None)
    assert _digest(tmp_path / "parts.ply") == _digest(tmp_path / "whole.ply")
    log = drive_log.read_log(truth.files, cameras=list(truth.camera_names), jpegs_for_s=1.0)
    frames = log.cameras[truth.camera_names[0]]
    held = [bool(j) for j in frames.jpegs]
    assert log.jpegs_until_ns is not None and 0 < sum(held) < len(held)
    assert held == sorted(held, reverse=True)  # the first ones, by receipt
    assert all(r < log.jpegs_until_ns for r, h in zip(frames.frame_recv_ns, held, strict=True) if h)


def test_a_full_disk_midway_is_one_line_and_leaves_the_old_output(
    drive: tuple[DriveTruth, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    truth, calib = drive
    out = tmp_path / "c.ply"
    earlier = b"ply\nformat ascii 1.0\ncomment acq 0.1.0: an earlier cloud\nend_header\n"
    out.write_bytes(earlier)
    real, calls = cloud.PlyStream.write, []

    def write(self: cloud.PlyStream, *columns: np.ndarray) -> None:
        calls.append(1)
        if len(calls) == 2:  # the second chunk
            raise OSError(28, "No space left on device", str(out) + ".tmp")
        real(self, *columns)

    monkeypatch.setattr(cloud.PlyStream, "write", write)
    args = _args(*map(str, truth.files), "--calib", str(calib), "-o", str(out), "--frame",
                 "laser", "--no-preview", "--chunk", "1.5")  # fmt: skip
    assert acq_main(args) == 3  # the disk full, as `acq record` at its reserve
    err = capsys.readouterr().err
    assert err.startswith(f"acq colorize: {out}: no space left on the disk of {tmp_path} (")
    assert err.endswith(" MB free)\n") and err.count("\n") == 1
    assert out.read_bytes() == earlier and sorted(tmp_path.iterdir()) == [out]


def test_bad_input_is_one_line_and_exit_2(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = drive
    files = list(map(str, truth.files))
    cases = [
        (["--calib", str(calib), "-o", str(tmp_path / "x.xyz")], "expected a .ply"),
        (["--calib", str(tmp_path / "none.yaml"), "-o", str(tmp_path / "x.ply")], "none.yaml"),
        (["--calib", str(calib), "-o", str(tmp_path / "x.las"), "--crs", "EPSG:0"], "--crs"),
    ]
    for argv, expect in cases:
        assert acq_main(_args(*files, *argv)) == 2
        err = capsys.readouterr().err
        assert expect in err and err.count("\n") == 1, err
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file")
    assert acq_main(_args(str(junk), "--calib", str(calib), "-o", str(tmp_path / "j.ply"))) == 2
    assert "junk.mcap" in capsys.readouterr().err


def test_frames_of_another_size_are_skipped_with_a_count_naming_the_first(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two frames of a camera that sent 640x480 among its 780x582 ones: the others colour
    the cloud, and the report says how many were skipped and where the first is."""
    truth, calib = drive
    odd = jpeg(640, 480)
    files, times = rewrite(truth.files, tmp_path, frames={20: odd, 41: odd})
    out = tmp_path / "c.ply"
    argv = _args(*map(str, files), "--calib", str(calib), "-o", str(out), "--no-preview")
    assert acq_main(argv) == 0
    text = capsys.readouterr().out
    v = PlyData.read(str(out))["vertex"].data
    assert len(v) > 10_000 and 0.2 < v["scalar_coloured"].mean() < 0.9
    into = (times[20] - (first_log_time(files[0]) or 0)) * 1e-9
    assert 0.5 < into < 1.0  # frame 20 at 25 Hz
    assert (
        "note: 2 frames of another size (640x480) than the camera model's 780x582 skipped; "
        f"the first at log time {times[20] * 1e-9:.3f} s, {into:.2f} s into {files[0]}"
    ) in text.splitlines(), text


def test_a_corrupt_chunk_is_skipped_with_one_warning(
    drive: tuple[DriveTruth, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    truth, calib = drive
    files, _ = rewrite(truth.files, tmp_path, chunk_size=1 << 20)
    *_, chunks = corrupt_chunk(files[0], 1)
    assert chunks >= 3
    out = tmp_path / "c.ply"
    with caplog.at_level(logging.WARNING):
        argv = _args(*map(str, files), "--calib", str(calib), "-o", str(out), "--no-preview")
        assert acq_main(argv) == 0
    assert len(PlyData.read(str(out))["vertex"].data) > 10_000
    [line] = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert line.startswith(f"{files[0]}: 1 corrupt chunk skipped (") and "messages lost)" in line


def _pixel_errors(truth: DriveTruth, results: list) -> np.ndarray:
    """Each coloured point's pixel minus its true pixel in the frame used, px."""
    scan = np.concatenate([r.scan for r in results])
    step = np.concatenate([r.step for r in results])
    stamp = np.concatenate([r.frame_stamp_ns for r in results])
    uv = np.concatenate([r.uv for r in results])
    ok = stamp >= 0
    true_uv, valid = truth.true_pixels(scan[ok], step[ok], stamp[ok])
    return np.linalg.norm(uv[ok][valid] - true_uv[valid], axis=1)


def test_world_frame_with_odometry_is_right_to_the_pixel(tmp_path: Path) -> None:
    """The true calibration and the camera's true latency: what is left is the
    pipeline's (re-timing, dead reckoning, motion compensation, JPEG, float32)."""
    truth = write_drive_log(tmp_path, 3.0, pattern_at=12.0, configured_camera_latency_s=None,
                            vibration_rad=0.0)  # fmt: skip
    calib = truth.calibration
    errors = {}
    for name, options in (
        ("nearest", Options()),
        ("still", Options(motion_compensation=False)),
        ("best", Options(view="best")),
    ):
        results: list = []
        report = run(truth.files, calib, tmp_path / f"{name}.ply", options=options,
                     results=results, want_uv=True, preview=None)  # fmt: skip
        assert report.frame == "world" and "odometry" in report.trajectory
        e = _pixel_errors(truth, results)
        errors[name] = (float(np.sqrt(np.mean(e**2))), float(np.mean(e < 1.0)), e.size)
        if name == "best":
            assert report.hidden > 0
    print(errors)
    assert errors["nearest"][0] < 0.5 and errors["nearest"][1] > 0.97
    assert errors["still"][0] > 3 * errors["nearest"][0]  # 20 km/h: motion matters
    assert errors["best"][0] < 0.8


def test_points_outside_the_trajectory_are_left_out_not_fatal(tmp_path: Path) -> None:
    """Odometry that starts late and stops early (a CAN reader stopped before the last
    scan): those points have no pose; the rest is placed and the preview drawn."""
    truth = write_drive_log(tmp_path, 2.0, odometry_span_s=(0.4, 1.5))
    out = tmp_path / "c.ply"
    report = run(truth.files, truth.calibration, out, preview=tmp_path / "p.png")
    assert report.frame == "world" and (tmp_path / "p.png").stat().st_size > 0
    assert any("outside the trajectory" in n for n in report.notes)
    n_valid = int(np.isfinite(drive_log.read_log(truth.files).ranges).sum())
    assert 0.4 * n_valid < report.points < 0.7 * n_valid


def test_best_view_needs_a_trajectory(tmp_path: Path) -> None:
    truth = write_drive_log(tmp_path, 0.5, odometry_hz=0.0)
    with pytest.raises(ValueError, match="trajectory"):
        run(truth.files, truth.calibration, tmp_path / "c.ply", frame="laser",
            options=Options(view="best"), preview=None)  # fmt: skip


def test_gnss_fixes_are_fused_and_place_the_cloud_in_their_frame(tmp_path: Path) -> None:
    """CAN odometry and 10 Hz RTK-like fixes: the trajectory is their fusion, the cloud
    lies in the ENU frame at the first fix (the street's own axes here) and the colours
    stay right to the pixel."""
    truth = write_drive_log(tmp_path, 3.0, pattern_at=12.0, configured_camera_latency_s=None,
                            vibration_rad=0.0, gnss_hz=10.0)  # fmt: skip
    results: list = []
    report = run(truth.files, truth.calibration, tmp_path / "c.ply", results=results,
                 want_uv=True, preview=None)  # fmt: skip
    assert "fused with 32 GNSS fixes" in report.trajectory, report.trajectory  # 0 to 3.1 s
    e = _pixel_errors(truth, results)
    assert float(np.sqrt(np.mean(e**2))) < 0.5 and float(np.mean(e < 1.0)) > 0.97
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    xyz = np.concatenate([r.xyz for r in results])
    _, start = truth.trajectory.poses(np.array([0.0]))
    true_xyz = truth.points[scan, step].astype(np.float64) - start[0]
    ok = np.isfinite(true_xyz).all(axis=1)
    d = np.linalg.norm(xyz[ok] - true_xyz[ok], axis=1)
    print(np.median(d), np.percentile(d, 99))
    assert np.median(d) < 0.05 and np.percentile(d, 99) < 0.1


def _distances_to_truth(truth: DriveTruth, results: list) -> tuple[np.ndarray, np.ndarray]:
    """Each placed point's distance (m) to its true hit point (the cloud's ENU frame is
    at the log's first fix), and its scan's time, s."""
    f = read_vehicle(list(truth.files)).fixes
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    xyz = np.concatenate([r.xyz for r in results])
    d = truth.distances(scan, step, xyz, (f.lat[0], f.lon[0], f.alt[0]))
    ok = np.isfinite(d)
    return d[ok], truth.scan_t0_s[scan[ok]]


def test_gnss_alone_places_the_cloud_and_colours_it_right(tmp_path: Path) -> None:
    """No CAN bus: 10 Hz fixes of 2 cm noise alone give the trajectory (heading from the
    track); the cloud lies within 5 cm (p95) of the true points, colours right to the
    pixel as with CAN odometry. The first and last second, where the fixes are on one
    side only, are looser (bench/gnss_alone.py measures a whole drive)."""
    truth = write_drive_log(tmp_path, 4.0, pattern_at=12.0, configured_camera_latency_s=None,
                            vibration_rad=0.0, gnss_hz=10.0, odometry_hz=0.0)  # fmt: skip
    results: list = []
    report = run(truth.files, truth.calibration, tmp_path / "c.ply", results=results,
                 want_uv=True, preview=None)  # fmt: skip
    assert report.trajectory.startswith("GNSS alone (42 fixes"), report.trajectory
    assert report.frame == "world"
    e = _pixel_errors(truth, results)
    assert float(np.sqrt(np.mean(e**2))) < 0.5 and float(np.mean(e < 1.0)) > 0.97
    d, t = _distances_to_truth(truth, results)
    inner = (t > 1.0) & (t < 3.0)
    assert inner.sum() > 40_000 and np.percentile(d[inner], 95) < 0.05, np.percentile(d, 95)
    assert np.percentile(d, 95) < 0.15


def test_undecodable_frames_are_none_not_an_error() -> None:
    from acq.camera.jpeg import decode_jpeg

    assert decode_jpeg(b"") is None and decode_jpeg(b"\xff\xd8 not a jpeg") is None


def test_progress_reads_in_bytes_and_colours_in_scans(
    drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = drive
    argv = _args(*map(str, truth.files), "--calib", str(calib), "-o", str(tmp_path / "c.ply"),
                 "--no-preview", "--chunk", "1", "--progress", "--json")  # fmt: skip
    assert acq_main(argv) == 0
    out, err = capsys.readouterr()
    scans = json.loads(out)["scans"]
    lines = [x for x in err.replace("\r", "\n").splitlines() if x]
    colouring = [x for x in lines if x.startswith("colouring:")]
    assert any(x.startswith("reading: 100%") for x in lines), err
    assert colouring[-1].startswith("colouring: 100%") and f" {scans}/{scans} " in colouring[-1]


def test_the_bar_moves_as_a_chunks_frames_are_done(capsys: pytest.CaptureFixture[str]) -> None:
    """In one process a chunk's scans go on the bar frame by frame (90 % shared among its
    frames), the rest when it is written: whole numbers, never past the chunk."""
    from concurrent.futures import Future

    from acq import progress
    from acq.cloud.colorize import _ChunkShares

    shares = _ChunkShares({0: 10, 1: 7})
    frames: list[Future[None]] = [Future() for _ in range(3)]
    with progress.bar(17, "scan", "colouring", shown=True):
        shares.watch(0, frames)
        counted = progress._bars["scan"]
        for f in frames:
            f.set_result(None)
        assert counted.n == 9  # 3 x 3 of the chunk's 10, the rest when written
        shares.finish(0)
        assert counted.n == 10
        shares.watch(1, [])
        shares.finish(1)
    assert "17/17" in capsys.readouterr().err
