"""The live pose source (RollingTrajectory): fed message by message as the recorder logs
them, its builds agree with each other (the world frame does not jump) and with the
offline choice over the same data, on plain arrays and on a real MCAP log."""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acq.log.reader import LogReader
from acq.log.vehicle_log import ODOMETRY_TOPIC, read_vehicle
from acq.motion import RollingTrajectory, Trajectory, from_odometry, trajectory_from_vehicle
from acq.sim.drive_log import DriveTruth, write_drive_log
from acq.sim.vehicle_messages import ORIGIN, T0, drive, speeds, tf_poses, vehicle_log
from tests import bench_scripts


def _stream(
    rolling: RollingTrajectory, messages: list[tuple[str, Any]], every: int
) -> list[Trajectory]:
    """Feed the messages, asking for the trajectory after every ``every`` of them; the
    distinct builds seen."""
    builds: list[Trajectory] = []
    for i, (topic, msg) in enumerate(messages, 1):
        rolling.add(topic, msg)
        if i % every == 0 or i == len(messages):
            traj = rolling.current()
            if traj is not None and (not builds or traj is not builds[-1]):
                builds.append(traj)
    return builds


def _jumps_m(builds: list[Trajectory]) -> np.ndarray:
    """Per pair of successive builds, the largest distance (m) between their positions
    at the later build's sample times that the earlier covers."""
    out = []
    for a, b in itertools.pairwise(builds):
        t = b.t_ns[a.covers(b.t_ns)]
        out.append(np.linalg.norm(a.pose_at(t)[1] - b.pose_at(t)[1], axis=1).max())
    return np.array(out)


def _gap_m(a: Trajectory, b: Trajectory) -> float:
    """The largest distance (m) between two trajectories at b's sample times a covers."""
    t = b.t_ns[a.covers(b.t_ns)]
    assert t.size > 0.9 * len(b)
    return float(np.linalg.norm(a.pose_at(t)[1] - b.pose_at(t)[1], axis=1).max())


@pytest.mark.parametrize("split", [False, True], ids=["one-message", "speed-and-yaw-apart"])
def test_odometry_builds_hold_the_frame_and_agree_with_the_whole_drive(split: bool) -> None:
    messages = drive(30.0, odometry_hz=100.0, split=split)
    rolling = RollingTrajectory(window_s=5.0, rebuild_s=0.0)
    builds = _stream(rolling, messages, every=25)
    assert len(builds) == 120 and rolling.builds == 120 and rolling.error is None
    jumps = _jumps_m(builds)
    print(f"odometry: largest jump between builds {jumps.max() * 1e6:.3f} µm")
    assert jumps.max() < 0.01
    last = builds[-1]
    assert (last.end_ns - last.start_ns) * 1e-9 == 5.0  # the window, not the drive
    assert rolling.kept_rows() == 501
    whole = trajectory_from_vehicle(vehicle_log(messages)).trajectory
    assert whole is not None and _gap_m(whole, last) < 0.02
    np.testing.assert_allclose(last.rotation, whole.pose_at(last.t_ns)[0], atol=1e-5)
    chosen = rolling.chosen()
    assert chosen is not None and chosen.description == "CAN odometry (501 samples, dead reckoning)"


def test_rows_stay_bounded_without_builds_and_latest_says_how_far_data_reach() -> None:
    rolling = RollingTrajectory(window_s=2.0)
    assert rolling.latest_ns() is None and rolling.current() is None
    messages = drive(20.0, odometry_hz=100.0)
    for topic, msg in messages:
        rolling.add(topic, msg)
    assert rolling.kept_rows() <= 201 + 1024
    assert rolling.latest_ns() == messages[-1][1].timestamp.ToNanoseconds()
    rolling.add("/camera/image", object())  # not a vehicle topic: ignored
    rolling.add(ODOMETRY_TOPIC, None)  # undecodable: counted by the reader, no data
    assert rolling.latest_ns() == messages[-1][1].timestamp.ToNanoseconds()


def test_rebuilt_only_when_data_came_and_rebuild_s_passed() -> None:
    now = [0.0]
    rolling = RollingTrajectory(window_s=10.0, rebuild_s=0.2, clock=lambda: now[0])
    messages = drive(2.0, odometry_hz=50.0)
    for topic, msg in messages[:50]:
        rolling.add(topic, msg)
    first = rolling.current()
    assert first is not None and rolling.builds == 1
    for topic, msg in messages[50:]:
        rolling.add(topic, msg)
    now[0] = 0.1
    assert rolling.current() is first  # too soon
    now[0] = 0.25
    second = rolling.current()
    assert second is not first and rolling.builds == 2 and len(second or ()) == 100
    now[0] = 1.0
    assert rolling.current() is second and rolling.builds == 2  # no new data


def test_a_build_the_data_refuse_keeps_the_last_trajectory_and_says_why() -> None:
    rolling = RollingTrajectory(rebuild_s=0.0)
    messages = drive(1.0, odometry_hz=20.0)
    for topic, msg in messages:
        rolling.add(topic, msg)
    good = rolling.current()
    assert good is not None
    twin = type(messages[-1][1])()
    twin.CopyFrom(messages[-1][1])
    twin.arbitration_id = 7  # another CAN message with the same stamp: times not increasing
    rolling.add(ODOMETRY_TOPIC, twin)
    assert rolling.current() is good
    assert rolling.error is not None and "increase strictly" in rolling.error


def test_fed_and_read_on_two_threads() -> None:
    messages = drive(20.0, odometry_hz=100.0)
    rolling = RollingTrajectory(window_s=4.0, rebuild_s=0.0)
    done = threading.Event()
    seen: list[Trajectory] = []

    def read() -> None:
        while not done.is_set():
            traj = rolling.current()
            if traj is not None and (not seen or traj is not seen[-1]):
                seen.append(traj)

    reader = threading.Thread(target=read)
    reader.start()
    for i, (topic, msg) in enumerate(messages, 1):
        rolling.add(topic, msg)
        if i % 400 == 0:  # let the reader build from what came so far
            builds = rolling.builds
            for _ in range(1000):
                if rolling.builds > builds:
                    break
                time.sleep(0.005)
    done.set()
    reader.join()
    last = rolling.current()
    assert last is not None and len(seen) >= 5 and rolling.error is None
    assert _jumps_m([*seen, last]).max() < 0.01
    whole = trajectory_from_vehicle(vehicle_log(messages)).trajectory
    assert whole is not None and _gap_m(whole, last) < 0.02


def test_gnss_keeps_the_first_fix_as_enu_origin_and_fused_builds_stay_close() -> None:
    """Odometry fused with 5 Hz fixes of 2 cm noise, a 30 s window rebuilt each 2 s: the
    frame's origin is the first fix throughout; successive fits move the track by the
    fixes' noise, not by a jump."""
    messages = drive(70.0, odometry_hz=50.0, gnss_hz=5.0)
    rolling = RollingTrajectory(window_s=30.0, rebuild_s=0.0)
    builds = _stream(rolling, messages, every=110)  # 2 s of messages
    assert all(b.frame == "enu" for b in builds)
    origins = {b.origin for b in builds}
    assert len(origins) == 1
    np.testing.assert_allclose(origins.pop(), ORIGIN, atol=1e-5)
    jumps = _jumps_m(builds[3:])  # once the window holds a few fixes
    whole = trajectory_from_vehicle(vehicle_log(messages)).trajectory
    assert whole is not None
    gap = _gap_m(whole, builds[-1])
    print(
        f"fusion: jump between builds median {np.median(jumps) * 100:.1f} cm, "
        f"max {jumps.max() * 100:.1f} cm; last build vs whole drive {gap * 100:.1f} cm"
    )
    assert jumps.max() < 0.1 and gap < 0.1


def _vehicle_messages(files: tuple[Path, ...]) -> list[tuple[str, Any]]:
    """The vehicle topics' messages of a log as the recorder's listener sees them."""
    out = []
    for path in files:
        for topic, _channel, _message, msg in LogReader(path).decoded(
            lambda _s, channel: channel.topic if channel.topic in RollingTrajectory.TOPICS else None
        ):
            out.append((topic, msg))
    return out


def test_a_real_logs_odometry_streamed_agrees_with_the_offline_choice(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    truth, _calib = short_drive
    messages = _vehicle_messages(truth.files)
    assert len(messages) >= 90
    rolling = RollingTrajectory(window_s=1.0, rebuild_s=0.0)
    builds = _stream(rolling, messages, every=1)
    assert len(builds) >= 80
    jumps = _jumps_m(builds[1:])
    offline = trajectory_from_vehicle(read_vehicle(list(truth.files)))
    assert offline.trajectory is not None
    gap = _gap_m(offline.trajectory, builds[-1])
    print(f"real log: jump max {jumps.max() * 1e6:.3f} µm, vs offline {gap * 1e6:.3f} µm")
    assert jumps.max() < 0.01 and gap < 0.02
    assert rolling.kept_rows() <= 51


def test_dead_reckoning_bridges_a_gnss_outage_in_the_gnss_frame() -> None:
    """Fixes for 0-20 s and 35-60 s of a drive (a tunnel between), a 10 s window: once
    the last fix is gnss_outage_s old, odometry alone carries on from the fused pose at
    the last fix, in the same ENU frame; when 5 fixes have come back, they are fused
    from their return on. No jump beyond the fit's own noise (2 cm fixes)."""

    def kept(t_ns: int) -> bool:
        return t_ns < T0 + 20 * 10**9 or t_ns > T0 + 35 * 10**9

    messages = [
        (topic, msg)
        for topic, msg in drive(60.0, odometry_hz=50.0, gnss_hz=5.0)
        if topic == ODOMETRY_TOPIC or kept(msg.timestamp.ToNanoseconds())
    ]
    rolling = RollingTrajectory(window_s=10.0, rebuild_s=0.0)
    builds, kinds = [], []
    for i, (topic, msg) in enumerate(messages, 1):
        rolling.add(topic, msg)
        if i % 50 == 0:  # 1 s of odometry
            builds.append(rolling.current())
            chosen = rolling.chosen()
            assert chosen is not None
            kinds.append((chosen.kind, chosen.description, builds[-1].start_ns))
    tunnel = [k for k in kinds if k[0] == "odometry"]
    assert len(tunnel) >= 14
    assert all(
        d.endswith("dead reckoning), continued in the enu frame of GNSS") for _, d, _ in tunnel
    )
    back = [k for k in kinds if k[0] == "fused" and k[2] > T0 + 30 * 10**9]
    assert back and back[0][2] >= T0 + 35 * 10**9  # fused from the fixes' return on
    enu = [b for b in builds if b.frame == "enu"]
    assert builds[-1].frame == "enu" and len({b.origin for b in enu}) == 1
    jumps = _jumps_m(enu[3:])
    print(f"tunnel: largest jump between builds {jumps.max() * 100:.2f} cm")
    assert jumps.max() < 0.15
    fine = np.arange(0.0, 60.0, 0.005)
    truth = from_odometry(T0 + np.round(fine * 1e9).astype(np.int64), *speeds(fine))
    in_tunnel = [b for b, k in zip(builds, kinds, strict=True) if k[0] == "odometry"]
    drift, end = _gap_m(truth, in_tunnel[-1]), _gap_m(truth, builds[-1])
    print(f"tunnel: {drift * 100:.1f} cm off after 15 s; {end * 100:.1f} cm once fused again")
    assert drift < 0.2 and end < 0.05


def test_a_real_logs_odometry_and_fixes_streamed_agree_with_the_offline_fusion(
    tmp_path: Path,
) -> None:
    """A 4 s drive log with CAN odometry and 10 Hz fixes of 2 cm noise, streamed through
    a 2 s window: once 5 fixes have come, every build is in the ENU frame at the log's
    first fix, close to the fusion of the whole log."""
    truth = write_drive_log(tmp_path, 4.0, gnss_hz=10.0, pattern_at=12.0)
    messages = _vehicle_messages(truth.files)
    rolling = RollingTrajectory(window_s=2.0, rebuild_s=0.0)
    builds = _stream(rolling, messages, every=10)
    fixes = read_vehicle(list(truth.files)).fixes
    first_fix = (fixes.lat[0], fixes.lon[0], fixes.alt[0])
    frames = [b.frame for b in builds]  # dead reckoning until 5 fixes have come
    first = frames.index("enu")
    assert set(frames[:first]) == {"odometry"} and set(frames[first:]) == {"enu"}
    builds = builds[first:]
    for b in builds:
        np.testing.assert_allclose(b.origin, first_fix, atol=1e-9)
    offline = trajectory_from_vehicle(read_vehicle(list(truth.files)))
    assert offline.kind == "fused" and offline.trajectory is not None
    jumps = _jumps_m(builds[2:])
    gap = _gap_m(offline.trajectory, builds[-1])
    print(f"real log fused: jump max {jumps.max() * 100:.2f} cm, vs offline {gap * 100:.2f} cm")
    assert jumps.max() < 0.05 and gap < 0.05


def test_the_bench_measures_rebuilds_over_a_bounded_window() -> None:
    result = bench_scripts.load("rolling_trajectory").measure(20.0, 100.0, 0.0, 5.0, 1.0)
    assert result["rebuilds"] == 20 and result["rows_kept"] == 501
    assert result["trajectory"] == "CAN odometry (501 samples, dead reckoning)"
    assert 0 < float(result["rebuild_ms_median"]) < 1000  # type: ignore[arg-type]


def test_a_bags_poses_roll_and_latest_is_their_newest_stamp() -> None:
    messages = tf_poses(6.0, per_message=2)  # two poses in each message
    rolling = RollingTrajectory(window_s=2.0, rebuild_s=0.0)
    builds = _stream(rolling, messages, every=5)
    chosen = rolling.chosen()
    assert chosen is not None and chosen.kind == "poses" and builds[-1].frame == "odometry"
    last_stamp = messages[-1][1].transforms[-1].timestamp.ToNanoseconds()
    assert rolling.latest_ns() == last_stamp == builds[-1].end_ns
    assert rolling.kept_rows() == 41 and _jumps_m(builds).max() < 1e-9
