"""What a rebuild of the live trajectory (acq.motion.rolling.RollingTrajectory) costs over
a long drive: the messages of a synthetic drive fed one by one, a rebuild asked for each
``--every-s`` of data; the time of each rebuild at the start and at the end of the drive
(flat: the window bounds it) and the rows kept.

``python bench/rolling_trajectory.py [--seconds 600] [--odometry-hz 100] [--gnss-hz 0]
[--window-s 120]`` prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from acq.motion import RollingTrajectory
from acq.sim.vehicle_messages import drive


def measure(
    seconds: float, odometry_hz: float, gnss_hz: float, window_s: float, every_s: float
) -> dict[str, object]:
    """Rebuild times (ms) of a ``seconds`` drive, the rows kept, the kind chosen."""
    messages = drive(seconds, odometry_hz=odometry_hz, gnss_hz=gnss_hz)
    rolling = RollingTrajectory(window_s=window_s, rebuild_s=0.0)
    every = max(1, round(every_s * (odometry_hz or gnss_hz)))
    times: list[float] = []
    for i, (topic, msg) in enumerate(messages, 1):
        rolling.add(topic, msg)
        if i % every == 0:
            t0 = time.perf_counter()
            rolling.current()
            times.append((time.perf_counter() - t0) * 1e3)
    ms = np.array(times)
    tenth = max(1, ms.size // 10)
    chosen = rolling.chosen()
    return {
        "seconds": seconds,
        "odometry_hz": odometry_hz,
        "gnss_hz": gnss_hz,
        "window_s": window_s,
        "rebuilds": int(ms.size),
        "rebuild_ms_median": round(float(np.median(ms)), 2),
        "rebuild_ms_p99": round(float(np.percentile(ms, 99)), 2),
        "rebuild_ms_median_first_tenth": round(float(np.median(ms[:tenth])), 2),
        "rebuild_ms_median_last_tenth": round(float(np.median(ms[-tenth:])), 2),
        "rows_kept": rolling.kept_rows(),
        "trajectory": chosen.description if chosen else "",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="drive length (default 600)")
    ap.add_argument("--odometry-hz", type=float, default=100.0, help="CAN odometry rate")
    ap.add_argument("--gnss-hz", type=float, default=0.0, help="GNSS fix rate (0: none)")
    ap.add_argument("--window-s", type=float, default=120.0, help="the rolling window")
    ap.add_argument("--every-s", type=float, default=1.0, help="data between two rebuilds")
    args = ap.parse_args()
    result = measure(args.seconds, args.odometry_hz, args.gnss_hz, args.window_s, args.every_s)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
