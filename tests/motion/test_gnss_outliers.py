"""GNSS fixes checked against each other and against the vehicle's speed: an outlier
does not move the track (whatever accuracy it claims), out-of-range fixes are dropped
with a note, a parked drive gives a clear answer. Simulated fixes (no receiver here);
the end-to-end cases write real MCAP logs with acq.sim.drive_log."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from acq import motion
from acq.camera import calibfile
from acq.cli.main import main as acq_main
from acq.cloud.colorize import ChunkResult, run
from acq.log.vehicle_log import read_vehicle
from acq.records import Fix
from acq.sim.drive_log import write_drive_log

S = 1_000_000_000
M_PER_DEG_LAT = 111_200.0


def _track(n: int = 60, hz: float = 10.0, noise_m: float = 0.02, seed: int = 0) -> motion.GnssTrack:
    """A vehicle at 6 m/s on a gentle curve, fixes of ``noise_m`` noise claiming 0.7 m."""
    rng = np.random.default_rng(seed)
    ts = np.arange(n) / hz
    xyz = np.c_[6.0 * ts, 0.3 * ts**2, np.zeros(n)] + rng.normal(0, noise_m, (n, 3))
    return motion.GnssTrack((ts * S).astype(np.int64), xyz, np.full(n, 0.7), "enu", (50, 8, 100))


def _with(track: motion.GnssTrack, k: int, offset: np.ndarray, sigma_m: float) -> motion.GnssTrack:
    xyz, sigma = track.xyz.copy(), track.sigma_m.copy()
    xyz[k] += offset
    sigma[k] = sigma_m
    return motion.GnssTrack(track.t_ns, xyz, sigma, track.frame, track.origin)


def _moved(a: motion.Trajectory, b: motion.Trajectory) -> float:
    t = np.arange(a.t_ns[0], a.t_ns[-1], S // 50)
    return float(np.linalg.norm(a.pose_at(t)[1] - b.pose_at(t)[1], axis=1).max())


@pytest.mark.parametrize(
    "offset",
    [np.array([30.0, 0.0, 0.0]), np.array([0.0, 9 * M_PER_DEG_LAT, 0.0]), np.array([0, 1.5, 0])],
    ids=["30m", "9deg", "1.5m"],
)
def test_an_outlier_claiming_2cm_is_rejected_and_moves_nothing(offset: np.ndarray) -> None:
    clean = _track()
    bad = _with(clean, 25, offset, sigma_m=0.02)
    screened = motion.screen_fixes(bad)
    assert screened.rejected.tolist() == [25]
    assert screened.note is not None and "1 of 60 fixes rejected" in screened.note
    moved = _moved(motion.from_gnss(clean), motion.from_gnss(screened.track))
    assert moved < 0.02, moved


def test_a_clean_track_keeps_every_fix() -> None:
    for seed in range(5):
        for noise in (0.02, 1.0):
            track = _track(n=300, noise_m=noise, seed=seed)
            screened = motion.screen_fixes(track)
            assert screened.rejected.size == 0 and screened.note is None, (seed, noise)


def test_a_run_of_jumped_fixes_is_cut_off_by_the_speed() -> None:
    """Eight fixes in a row 2 km away (more than the window's median can outvote)."""
    clean = _track(n=100)
    xyz = clean.xyz.copy()
    xyz[40:48] += [2000.0, 0.0, 0.0]
    bad = motion.GnssTrack(clean.t_ns, xyz, clean.sigma_m, "enu", clean.origin)
    screened = motion.screen_fixes(bad)
    assert screened.rejected.tolist() == list(range(40, 48))


def test_a_claimed_accuracy_weighs_at_most_nine_times_the_typical_fix() -> None:
    """A fix 0.4 m off (too little to reject) claiming 1 mm: the track is not drawn
    through it (trusted, it moves the track by its whole 0.4 m)."""
    clean = _track()
    bad = _with(clean, 25, np.array([0.0, 0.4, 0.0]), sigma_m=0.001)
    assert _moved(motion.from_gnss(clean), motion.from_gnss(bad)) < 0.25


def test_a_parked_drive_has_no_heading_and_says_so() -> None:
    parked = _track(noise_m=0.02)
    still = motion.GnssTrack(parked.t_ns, parked.xyz * 0.0 + parked.xyz[:1], parked.sigma_m,
                             "enu", parked.origin)  # fmt: skip
    with pytest.raises(motion.NoHeadingError, match=r"never moves faster than 1\.0 m/s"):
        motion.from_gnss(still)


def test_out_of_range_fixes_are_not_usable() -> None:
    ok = motion.gnss.usable_fixes([50.0, 95.0, 50.0, -91.0], [8.0, 8.0, 500.0, 8.0], [100.0] * 4)
    assert ok.tolist() == [True, False, False, False]
    with pytest.raises(motion.gnss.InputValueError, match="out of range"):
        motion.gnss_track(np.arange(2) * S, [95.0, 95.0], [8.0, 8.0], [0.0, 0.0])


# --- end to end: real logs through colorize ------------------------------------------


def _distances(truth, results: list[ChunkResult]) -> np.ndarray:  # type: ignore[no-untyped-def]
    f = read_vehicle(list(truth.files)).fixes
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    xyz = np.concatenate([r.xyz for r in results])
    d = truth.distances(scan, step, xyz, (f.lat[0], f.lon[0], f.alt[0]))
    return np.asarray(d[np.isfinite(d)])


def test_one_outlier_in_a_logged_drive_moves_no_point(tmp_path: Path) -> None:
    """GNSS alone, fix 15 of 32 30 m north claiming 2 cm: rejected, noted, and the cloud
    as close to the truth as without it (before: a quarter of the points moved by
    1-6.9 m)."""

    def outlier(k: int, fix: Fix) -> Fix:
        if k != 15:
            return fix
        return dataclasses.replace(fix, latitude=fix.latitude + 30 / M_PER_DEG_LAT, hdop=0.02)

    truth = write_drive_log(tmp_path, 3.0, pattern_at=12.0, vibration_rad=0.0, gnss_hz=10.0,
                            odometry_hz=0.0, gnss_edit=outlier)  # fmt: skip
    results: list[ChunkResult] = []
    report = run(truth.files, truth.calibration, tmp_path / "c.ply", results=results,
                 preview=None)  # fmt: skip
    d = _distances(truth, results)
    assert float(np.mean(d > 0.5)) == 0.0, float(np.mean(d > 0.5))
    assert any("1 of 32 fixes rejected as outliers" in n for n in report.notes), report.notes


def test_out_of_range_fixes_are_dropped_with_a_note(tmp_path: Path) -> None:
    def wild(k: int, fix: Fix) -> Fix:
        return dataclasses.replace(fix, latitude=95.0) if k == 3 else (
            dataclasses.replace(fix, longitude=500.0) if k == 7 else fix
        )  # fmt: skip

    truth = write_drive_log(tmp_path, 2.0, vibration_rad=0.0, gnss_hz=10.0, odometry_hz=0.0,
                            gnss_edit=wild)  # fmt: skip
    report = run(truth.files, truth.calibration, tmp_path / "c.ply", preview=None)
    assert report.frame == "world" and report.points > 0
    assert any("2 of 22 fixes out of range" in n for n in report.notes), report.notes


def test_a_parked_gnss_only_drive_gives_a_laser_cloud_and_a_note(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = write_drive_log(tmp_path, 2.0, speed_kmh=0.0, vibration_rad=0.0, gnss_hz=10.0,
                            odometry_hz=0.0)  # fmt: skip
    report = run(truth.files, truth.calibration, tmp_path / "c.ply", preview=None)
    assert report.frame == "laser" and report.points > 0
    assert any("never moves faster than 1.0 m/s" in n for n in report.notes), report.notes
    calib = tmp_path / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    argv = ["colorize", *map(str, truth.files), "--calib", str(calib), "-o",
            str(tmp_path / "w.ply"), "--no-preview", "--frame", "world"]  # fmt: skip
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert "--frame world needs a trajectory" in err and "a bug" not in err
