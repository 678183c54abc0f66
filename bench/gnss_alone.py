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

Outliers (``--outliers``): the GNSS-alone drive again with one fix in its middle made
an outlier that claims 2 cm (hdop 0.02): 30 m north, or 9° of latitude north. Per case,
the cloud against the clean drive's (the same points by scan and step): the share of
points moved more than 10 cm and the largest move, m; with the fixes screened as
``acq colorize`` does (:func:`acq.motion.screen_fixes`, the rejected fixes counted) and
unscreened (every fix used and its claimed sigma trusted: the code before screening,
reproduced by replacing the screen and the sigma floor for that run).

Run as a script: ``python bench/gnss_alone.py [--seconds S] [--outliers]``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import re
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from acq.cloud import job
from acq.cloud.colorize import ChunkResult, run
from acq.log.vehicle_log import read_vehicle
from acq.motion import Screened, gnss
from acq.records import Fix
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


OUTLIERS = {"30m_north": 30.0 / 111_200.0, "9deg_north": 9.0}  # name: latitude shift, °


@contextlib.contextmanager
def _unscreened() -> Iterator[None]:
    """Colorize as before screening: every fix kept, each one's claimed sigma trusted."""
    screen, trusted = job.screen_fixes, gnss._trusted_sigma
    job.screen_fixes = lambda track, **_: Screened(track, np.zeros(0, np.int64), 0.0)
    gnss._trusted_sigma = lambda sigma_m: sigma_m
    try:
        yield
    finally:
        job.screen_fixes, gnss._trusted_sigma = screen, trusted


def _cloud(work: Path, seconds: float, edit: Callable[[int, Fix], Fix] | None) -> Any:
    """The GNSS-alone cloud (points by (scan, step)) and the report of ``edit``'s drive."""
    truth = write_drive_log(work, seconds, pattern_at=12.0, configured_camera_latency_s=None,
                            gnss_hz=10.0, odometry_hz=0.0, gnss_edit=edit)  # fmt: skip
    results: list[ChunkResult] = []
    report = run(truth.files, truth.calibration, work / "c.ply", results=results, preview=None)
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    xyz = np.concatenate([r.xyz for r in results])
    return dict(zip(zip(scan.tolist(), step.tolist(), strict=True), xyz, strict=True)), report


def _moved(clean: dict[Any, np.ndarray], other: dict[Any, np.ndarray]) -> dict[str, float]:
    common = sorted(clean.keys() & other.keys())
    d = np.linalg.norm(np.array([clean[k] for k in common]) - [other[k] for k in common], axis=1)
    return {"moved_over_10cm": round(float(np.mean(d > 0.1)), 4),
            "moved_max_m": round(float(d.max()), 3)}  # fmt: skip


def outliers(seconds: float) -> Iterator[dict[str, Any]]:
    """One line per outlier case (module docstring)."""
    middle = int(seconds * 10.0) // 2
    with tempfile.TemporaryDirectory() as work:
        clean, _ = _cloud(Path(work) / "clean", seconds, None)
    for name, dlat in OUTLIERS.items():

        def edit(k: int, fix: Fix, dlat: float = dlat) -> Fix:
            if k != middle:
                return fix
            return dataclasses.replace(fix, latitude=fix.latitude + dlat, hdop=0.02)

        line: dict[str, Any] = {"outlier": name, "fix": middle}
        for screened in (False, True):
            with tempfile.TemporaryDirectory() as work:
                with contextlib.nullcontext() if screened else _unscreened():
                    cloud, report = _cloud(Path(work), seconds, edit)
            key = "screened" if screened else "unscreened"
            rejected = [n for n in report.notes if "rejected as outliers" in n]
            found = re.match(r"GNSS: (\d+) of", rejected[0]) if rejected else None
            line[key] = _moved(clean, cloud) | {"rejected_fixes": int(found[1]) if found else 0}
        yield line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--outliers", action="store_true", help="the outlier cases only")
    args = ap.parse_args()
    if args.outliers:
        for line in outliers(args.seconds):
            print(json.dumps({"bench": "gnss_alone", "variant": "gnss_outlier",
                              "seconds": args.seconds, **line}), flush=True)  # fmt: skip
        return
    for name, (gnss_hz, odometry_hz) in VARIANTS.items():
        with tempfile.TemporaryDirectory() as work:
            line = measure(Path(work), args.seconds, gnss_hz, odometry_hz)
        print(json.dumps({"bench": "gnss_alone", "variant": name, "seconds": args.seconds,
                          "gnss_noise_m": 0.02, **line}), flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
