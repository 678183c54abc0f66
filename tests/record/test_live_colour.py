"""Live colouring on a real log's records, one at a time as the recorder's log hands them
over (no recorder: the listener alone), against ``acq colorize``'s chunks on the same
log; its swath; its behaviour when it falls behind or takes garbage."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from acq.camera import calibfile
from acq.cloud import chunks, views
from acq.cloud.job import prepare
from acq.cloud.report import Report
from acq.log import schemas
from acq.log.drive_log import read_log
from acq.log.timebase import TimeBase
from acq.log.vehicle_log import ODOMETRY_TOPIC
from acq.motion import RollingTrajectory
from acq.record.listeners import Listeners, LogRecord
from acq.record.live_colour import SWATH_TOPIC, LiveColourer
from acq.record.swath import Swath
from acq.sim.drive_log import DriveTruth

CLOUD = schemas.SCHEMAS["foxglove.PointCloud"]


def _records(path: Path) -> tuple[list[LogRecord], int]:
    """The log's messages as the recorder's listeners get them, in log-time order, and
    the log's UTC offset."""
    with path.open("rb") as f:
        reader = make_reader(f)
        offset = TimeBase.of_metadata(
            {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        ).utc_offset_ns
        out = [
            LogRecord(ch.topic, schemas.Schema(s.name, s.encoding, s.data), m.data, m.log_time)
            for s, ch, m in reader.iter_messages(log_time_order=True)
            if s is not None
        ]
    return out, offset


def _cloud(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
    """A coloured scan's xyz (N,3) float32, rgb (N,3) and alpha (N,), and its message."""
    msg = schemas.decode("foxglove.PointCloud", data)
    assert [f.name for f in msg.fields] == ["x", "y", "z", "red", "green", "blue", "alpha"]
    raw = np.frombuffer(msg.data, np.uint8).reshape(-1, msg.point_stride)
    return raw[:, :12].copy().view("<f4"), raw[:, 12:15], raw[:, 15], msg


def _run_live(path: Path, calib_path: Path, **kw: Any) -> tuple[LiveColourer, list[LogRecord]]:
    records, offset = _records(path)
    increment = read_log(path, returns=False, jpegs=False).time_increment
    out: list[LogRecord] = []
    colourer = LiveColourer(
        calibfile.load(calib_path), "laser", emit=out.append,
        time_increment_s=lambda: increment, utc_offset_ns=lambda: offset, **kw,
    )  # fmt: skip
    for record in records:
        colourer.on_record(record)
    colourer.stop()
    return colourer, out


@pytest.mark.parametrize("moving", [False, True], ids=["still", "motion-compensated"])
def test_live_colours_agree_with_acq_colorize_scan_by_scan(
    short_drive: tuple[DriveTruth, Path], moving: bool
) -> None:
    """Without motion compensation, and with it: live from the odometry as it comes
    (a rolling trajectory), offline from the whole drive's."""
    truth, calib_path = short_drive
    path = truth.files[0]
    options = views.Options(view="nearest", balance=False, motion_compensation=moving)
    poses = RollingTrajectory(window_s=20.0, rebuild_s=0.0) if moving else None
    colourer, out = _run_live(
        path, calib_path, options=options, poses=poses, pose_topics=(ODOMETRY_TOPIC,)
    )
    coloured = [r for r in out if r.topic == "/laser/colored"]
    # offline, the same time model without re-timing: the same frames for the same points
    job, _ = prepare([path], calibfile.load(calib_path), Report(output=""), frame="laser",
                     options=options, retime_offline=False)  # fmt: skip
    [chunk] = chunks.plan(job.scan_new, 3600.0)
    offline = chunks.colour_chunk(job, chunk)
    n_scans = job.scan_new.size
    assert colourer.coloured == len(coloured) == n_scans  # the last ones when the log ends
    assert colourer.skipped == 0 and colourer.failed == 0
    same = total = agree = seen_offline = seen_both = 0
    for k, record in enumerate(coloured):
        xyz, rgb, alpha, msg = _cloud(record.data)
        stamp = msg.timestamp.seconds * 10**9 + msg.timestamp.nanos
        assert msg.frame_id == "laser"
        off = offline.scan == k
        order = np.argsort(offline.step[off], kind="stable")
        assert stamp == job.scan_new[k] + _records_offset(path)  # the scan's own stamp
        np.testing.assert_allclose(xyz, offline.xyz[off][order], atol=1e-4)
        live_c = alpha == 255
        off_c = offline.coloured[off][order]
        both = live_c & off_c
        total += xyz.shape[0]
        same += int(np.count_nonzero(live_c == off_c))
        diff = np.abs(rgb[both].astype(int) - offline.rgb[off][order][both].astype(int))
        agree += int(np.count_nonzero(diff.max(axis=1) <= 24))
        seen_offline += int(off_c.sum())
        seen_both += int(both.sum())
    assert seen_offline > 0.3 * total  # the camera sees a good part of each scan
    assert seen_both / seen_offline >= 0.99
    assert agree / seen_both >= 0.99
    assert same / total >= 0.99
    share, by_camera = colourer.shares()
    assert 0.3 < share <= 1 and list(by_camera) == list(calibfile.load(calib_path).cameras)
    figures = colourer.status()
    assert (figures.scans_coloured, figures.scans_skipped) == (n_scans, 0)
    assert figures.coloured_share == share and figures.camera_shares == by_camera


def _records_offset(path: Path) -> int:
    return _records(path)[1]


def test_a_swath_of_the_last_seconds_at_2_hz(short_drive: tuple[DriveTruth, Path]) -> None:
    truth, calib_path = short_drive
    swath = Swath(span_s=1.0, period_s=0.5, max_points=5_000)
    options = views.Options(view="nearest", balance=False, motion_compensation=False)
    _, out = _run_live(truth.files[0], calib_path, options=options, swath=swath)
    swaths = [r for r in out if r.topic == SWATH_TOPIC]
    assert 3 <= len(swaths) <= 5  # 2 s of scans at 2 Hz
    times = np.array([r.log_time_ns for r in swaths])
    assert np.all(np.diff(times) >= 0.5e9 - 30e6)  # a scan's period of slack
    xyz, _, alpha, msg = _cloud(swaths[-1].data)
    assert msg.frame_id == "laser"  # no trajectory given: the laser frame, said so
    assert 0 < xyz.shape[0] <= 5_000 and (alpha == 255).all()
    assert swath.points > 5_000  # held whole, decimated when sent


def test_swath_keeps_its_span_and_starts_again_in_a_new_frame() -> None:
    swath = Swath(span_s=1.0, period_s=0.5, max_points=10)
    pts, rgb = np.ones((4, 3)), np.full((4, 3), 7, np.uint8)
    for k in range(30):
        swath.add(k * 100_000_000, pts * k, rgb, "odometry")
    assert swath.points == 4 * 11  # scans 19..29: 1 s
    assert swath.due(0)
    xyz, _, _, msg = _cloud(swath.cloud(0, 5))
    assert xyz.shape[0] <= 10 and msg.frame_id == "odometry"
    assert not swath.due(400_000_000) and swath.due(500_000_000)
    swath.add(3_000_000_000, np.full((2, 3), np.nan), rgb[:2], "laser")
    assert swath.points == 0 and swath.frame_id == "laser"  # NaN points: none kept
    with pytest.raises(ValueError):
        Swath(span_s=0.0)


def test_colouring_that_falls_behind_skips_scans_and_garbage_is_ignored(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    truth, calib_path = short_drive
    records, offset = _records(truth.files[0])
    out: list[LogRecord] = []
    colourer = LiveColourer(
        calibfile.load(calib_path), "laser", emit=out.append,
        time_increment_s=lambda: None,  # the scanner's geometry never known: scans wait
        utc_offset_ns=lambda: offset,
    )  # fmt: skip
    scans = [r for r in records if r.topic == "/laser/scan"]
    for record in scans:
        colourer.on_record(record)
    colourer.on_record(LogRecord("/laser/scan", scans[0].schema, b"\xff\x00garbage", 0))
    colourer.on_record(LogRecord("/camera/image/compressed", scans[0].schema, b"\x01", 0))
    assert out == [] and colourer.coloured == 0
    assert colourer.skipped == len(scans) - 12  # all but the newest waiting


def test_with_odometry_the_swath_is_the_street_placed_in_the_odometry_frame(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    truth, calib_path = short_drive
    swath = Swath(span_s=1.5, period_s=0.5)
    poses = RollingTrajectory(window_s=20.0, rebuild_s=0.0)
    _, out = _run_live(
        truth.files[0], calib_path, swath=swath, poses=poses, pose_topics=(ODOMETRY_TOPIC,)
    )
    xyz, _, _, msg = _cloud([r for r in out if r.topic == SWATH_TOPIC][-1].data)
    assert msg.frame_id == "odometry"
    # 1.5 s of a drive at 20 km/h: the scans lie along 8 m of the odometry's x axis
    travelled = 20 / 3.6 * 1.5
    assert np.ptp(xyz[:, 0]) == pytest.approx(travelled, abs=1.0)
    # /tf: the vehicle in the odometry frame at 10 Hz (2 s of scans coloured with a pose)
    tfs = [schemas.decode("foxglove.FrameTransforms", r.data) for r in out if r.topic == "/tf"]
    assert 18 <= len(tfs) <= 21
    [first], [last] = tfs[0].transforms, tfs[-1].transforms
    assert (last.parent_frame_id, last.child_frame_id) == ("odometry", "vehicle")
    assert last.translation.x - first.translation.x == pytest.approx(20 / 3.6 * 2, abs=1.0)


def _still_colourer(
    short_drive: tuple[DriveTruth, Path],
) -> tuple[list[LogRecord], list[LogRecord], LiveColourer]:
    """The drive's records, a list of what is emitted, and a colourer of the drive's
    calibration without motion compensation emitting into it (records not yet given)."""
    truth, calib_path = short_drive
    records, offset = _records(truth.files[0])
    increment = read_log(truth.files[0], returns=False, jpegs=False).time_increment
    out: list[LogRecord] = []
    colourer = LiveColourer(
        calibfile.load(calib_path), "laser", emit=out.append,
        time_increment_s=lambda: increment, utc_offset_ns=lambda: offset,
        options=views.Options(view="nearest", balance=False, motion_compensation=False),
    )  # fmt: skip
    return records, out, colourer


def test_a_colourer_with_records_queued_behind_it_skips_scans_and_takes_the_frames(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    """Far behind (its feed's queue long), it skips the ready scans, counted, and keeps
    taking frames; caught up, it colours again."""
    records, _, colourer = _still_colourer(short_drive)
    queued = [100]
    colourer.backlog = lambda: queued[0]  # type: ignore[method-assign]
    half = len(records) // 2
    for record in records[:half]:
        colourer.on_record(record)
    assert colourer.coloured == 0 and colourer.skipped > 20
    assert all(c.frames for c in colourer.cameras.values())  # the frames still taken
    queued[0] = 0
    for record in records[half:]:
        colourer.on_record(record)
    assert colourer.coloured > 20
    scans = sum(r.topic == "/laser/scan" for r in records)
    assert colourer.coloured + colourer.skipped + len(colourer._waiting) == scans


def test_scans_its_full_queue_lost_are_counted_as_skipped(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    """The colourer's feed full (it is stuck colouring on a loaded machine): the scans the
    feed could not queue are in its status's skipped, the other records' losses are not."""
    truth, calib_path = short_drive
    records, offset = _records(truth.files[0])
    colourer = LiveColourer(
        calibfile.load(calib_path), "laser", emit=lambda _: None,
        time_increment_s=lambda: None, utc_offset_ns=lambda: offset,
    )  # fmt: skip
    gate = threading.Event()
    stuck = colourer.on_record
    colourer.on_record = lambda r: (gate.wait(), stuck(r))[1]  # type: ignore[method-assign]
    hub = Listeners(size=4)
    feed = hub.add(colourer)
    hub.publish(records[0])
    while feed.qsize():  # in the colourer's hand, stuck
        time.sleep(0.001)
    for record in records[1:]:
        hub.publish(record)
    lost = sum(r.topic == "/laser/scan" for r in records[5:])  # 4 queued, the rest lost
    assert feed.dropped == len(records) - 5 and lost > 0
    assert colourer.lost == lost
    assert colourer.status().scans_skipped == colourer.skipped + lost
    gate.set()
    hub.close()


def test_while_its_kernels_load_scans_wait_and_then_are_coloured(
    short_drive: tuple[DriveTruth, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The warm-up (numba compiling, seconds on a first recording) on its own thread: the
    records keep being taken meanwhile, the scans wait (the oldest skipped, counted), and
    colouring starts when it has ended. The warm-up itself is held here by a gate around
    the real one, which emits nothing."""
    records, out, colourer = _still_colourer(short_drive)
    gate = threading.Event()
    real = colourer.warm_up
    took: list[float] = []
    monkeypatch.setattr(colourer, "warm_up", lambda: (gate.wait(), took.append(real()))[1] or 0.0)
    thread = colourer.start_warm_up()
    half = len(records) // 2
    for record in records[:half]:
        colourer.on_record(record)
    assert out == [] and colourer.coloured == 0
    scans = sum(r.topic == "/laser/scan" for r in records[:half])
    assert colourer.skipped == scans - 12 and len(colourer._waiting) == 12
    assert all(c.frames for c in colourer.cameras.values())  # the frames still taken
    gate.set()
    thread.join(60)
    assert not thread.is_alive() and out == [] and took  # the warm-up emitted nothing
    for record in records[half:]:
        colourer.on_record(record)
    assert colourer.coloured > 20 and colourer.failed == 0
    assert len([r for r in out if r.topic == "/laser/colored"]) == colourer.coloured
