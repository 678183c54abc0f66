"""`acq replay` serves the vehicle's buses too: a log of the scanner, the car (CAN) and the
GNSS receiver (NMEA on TCP), replayed (the CAN frames on udp_multicast, the sentences on
TCP) and recorded again from the replay's configuration, keeps the CAN frames, the
odometry decoded from them and the fixes, at the recorded pace."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acq.log.vehicle_log import read_vehicle
from acq.record.recorder import Recorder
from acq.sim.replay import Replay
from tests.sim_rig import Rig, read_log, record_replay

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

RECORD_S = 3.0


def _can(path: Path) -> list[tuple[int, int, bytes]]:
    """(receive ns, identifier, data) of every recorded CAN frame."""
    return [(t, m.arbitration_id, bytes(m.data)) for t, _, m in read_log(path)["/vehicle/can"]]


def test_a_replay_serves_can_and_gnss_and_its_recording_keeps_odometry_and_fixes(
    tmp_path: Path,
) -> None:
    rig = Rig(cameras=(), vehicle=True)
    try:
        assert Recorder(rig.config(tmp_path), duration_s=RECORD_S).run() == 0
    finally:
        rig.close()
    (first,) = sorted((tmp_path / "logs").glob("*.mcap"))
    one = read_vehicle([first])
    assert len(one.odometry) > 0.9 * RECORD_S * 100 and len(one.fixes) > 0.9 * RECORD_S * 10

    with Replay([first]) as replay:
        assert replay.urls["vehicle"].startswith("udp_multicast:")
        assert replay.urls["gnss"].startswith("socket://127.0.0.1:")
        cfg = replay.config(out_dir=tmp_path / "again")
        assert cfg.can is not None and cfg.can.interface == "udp_multicast"
        assert cfg.gnss is not None and cfg.gnss.url == replay.urls["gnss"]
        assert cfg.gnss.time == "receipt"  # the sentences' UTC is the recording's
        record_replay(replay, cfg, RECORD_S + 8.0)
        sent = replay.sent()
    (second,) = sorted((tmp_path / "again").glob("*.mcap"))

    # the CAN frames: identifiers and data as recorded, a contiguous run, at the same pace
    can1, can2 = _can(first), _can(second)
    assert len(can2) >= 0.85 * len(can1) and len(can2) <= sent["vehicle"]
    body1 = [f[1:] for f in can1]
    k = next(i for i in range(len(can1)) if body1[i : i + 20] == [f[1:] for f in can2[:20]])
    assert body1[k : k + len(can2)] == [f[1:] for f in can2]
    dt1 = np.diff([f[0] for f in can1[k : k + len(can2)]])
    dt2 = np.diff([f[0] for f in can2])
    assert np.median(np.abs(dt2 - dt1)) < 1e6  # ns

    # the odometry decoded from them and the fixes: the recorded values again
    two = read_vehicle([second])
    assert len(two.odometry) >= 0.85 * len(one.odometry)
    speeds = one.odometry.speed[one.odometry.speed_measured]
    again = two.odometry.speed[two.odometry.speed_measured]
    assert any(
        np.array_equal(speeds[j : j + len(again)], again)
        for j in range(len(speeds) - len(again) + 1)
    )
    assert len(two.fixes) >= 0.85 * len(one.fixes)
    m = int(np.flatnonzero(one.fixes.utc_s == two.fixes.utc_s[0])[0])
    assert np.array_equal(one.fixes.lat[m : m + len(two.fixes)], two.fixes.lat)
    assert np.array_equal(one.fixes.lon[m : m + len(two.fixes)], two.fixes.lon)
    fix_dt = np.diff(two.fixes.t_ns) - np.diff(one.fixes.t_ns[m : m + len(two.fixes)])
    assert np.median(np.abs(fix_dt)) < 5e6  # ns: stamped from the replay's receipt
