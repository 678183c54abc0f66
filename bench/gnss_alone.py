"""A cloud placed by GNSS alone against one placed with CAN odometry, one JSON line each.

Data: ``acq.sim.drive_log.write_drive_log`` (one camera, ``--seconds`` of the synthetic
street at 20 km/h, body vibration of 2 mrad as default), written three times with one
seed (one street, one drive): with 10 Hz fixes of 2 cm noise and no CAN odometry (the
trajectory from :func:`acq.motion.from_gnss`); with 50 Hz CAN odometry and no fixes
(dead reckoning); with both (:func:`acq.motion.fuse`). `acq colorize`'s defaults
otherwise, calibration the truth (the trajectory is what is compared).

Per trajectory: each placed point's distance to its noise-free hit (p50/p95/p99, m; the
cloud, in ENU at its first fix, put back into the street's frame; none for dead
reckoning, whose frame is its own), and the same inside the drive (one second from
either end, where GNSS alone has fixes on one side only); each coloured point's pixel
against its true pixel in the frame used (RMS px, share within 1 px).

Run as a script: ``python bench/gnss_alone.py [--seconds S]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from acq.cloud.colorize import ChunkResult, run
from acq.log.vehicle_log import read_vehicle
from acq.sim.drive_log import write_drive_log

VARIANTS = {  # name: (GNSS rate Hz, odometry rate Hz)
    "gnss_alone": (10.0, 0.0),
    "can_alone": (0.0, 50.0),
    "can_and_gnss": (10.0, 50.0),
}


def _stats(d: np.ndarray) -> dict[str, float]:
    return {f"p{q}_m": round(float(np.percentile(d, q)), 4) for q in (50, 95, 99)}


def measure(work: Path, seconds: float, gnss_hz: float, odometry_hz: float) -> dict[str, Any]:
    truth = write_drive_log(work, seconds, pattern_at=12.0, configured_camera_latency_s=None,
                            gnss_hz=gnss_hz, odometry_hz=odometry_hz)  # fmt: skip
    results: list[ChunkResult] = []
    report = run(truth.files, truth.calibration, work / "c.ply", results=results,
                 want_uv=True, preview=None)  # fmt: skip
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    xyz = np.concatenate([r.xyz for r in results])
    out: dict[str, Any] = {"trajectory": report.trajectory, "points": int(scan.size)}
    if gnss_hz > 0:
        f = read_vehicle(list(truth.files)).fixes
        d = truth.distances(scan, step, xyz, (float(f.lat[0]), float(f.lon[0]), float(f.alt[0])))
        t = truth.scan_t0_s[scan]
        ok = np.isfinite(d)
        inner = ok & (t > 1.0) & (t < seconds - 1.0)
        out |= {"distance": _stats(d[ok]), "distance_inside": _stats(d[inner])}
    stamp = np.concatenate([r.frame_stamp_ns for r in results])
    uv = np.concatenate([r.uv for r in results if r.uv is not None])
    used = stamp >= 0
    true_uv, valid = truth.true_pixels(scan[used], step[used], stamp[used])
    e = np.linalg.norm(uv[used][valid] - true_uv[valid], axis=1)
    return out | {
        "pixel_rms": round(float(np.sqrt(np.mean(e**2))), 3),
        "pixel_within_1px": round(float(np.mean(e < 1.0)), 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    for name, (gnss_hz, odometry_hz) in VARIANTS.items():
        with tempfile.TemporaryDirectory() as work:
            line = measure(Path(work), args.seconds, gnss_hz, odometry_hz)
        print(json.dumps({"bench": "gnss_alone", "variant": name, "seconds": args.seconds,
                          "gnss_noise_m": 0.02, **line}), flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
