"""The paper's reprojection figure for facet vertices, on the simulated drive.

Each corner of a textured facet against its true pixel in the frame the facet is
textured from.

Data: the drive of ``bench/colorize_cameras.py`` — ``--seconds`` (60) of the synthetic
street at 20 km/h with the two-camera rig (``default_rig(cameras=2)``), every camera's
latency configured as 25 ms, CAN odometry — and its calibration from `acq calibrate`
(each camera's fisheye fit, `acq calibrate extrinsic` for both, `acq calibrate
time-offset` for each; ``laser_to_vehicle`` as mounted), both kept in ``--work``.

The drive is meshed as `acq mesh --texture -o OUT.glb` meshes it (:func:`acq.mesh.drive.
prepare_mesh`, default tiles and texels); :attr:`acq.mesh.drive.MeshJob.on_views` is
given each tile's facets, each facet's view (camera, frame) and its corners' pixels in
that view, as the atlas is sampled from them. Each corner with a pixel is checked
against where the noise-free hit of its vertex's (scan, step) falls in that frame
(:meth:`acq.sim.drive_log.DriveTruth.true_pixels`: the true lens, the camera's true pose
at the frame's true middle of exposure).

One JSON line per variant: ``calibrated`` (everything from `acq calibrate`) or ``true``
(the true lenses, poses and latency errors as time offsets: what the pipeline itself
adds), each with the log's own trajectory (``odometry``, as a user gets it) and the TRUE
trajectory (``true_trajectory``, as ``--trajectory`` would take it). For every corner,
and split into ``own`` (the vertex was coloured from that view: the colouring's pixel)
and ``projected`` (projected into it, :func:`acq.mesh.texture.corner_pixels`), and per
camera: |pixel - true pixel| px, its mean, standard deviation, median, 95th percentile,
and the shares within 0.5 and 1 px; ``by_time_gap``: the same by how far the frame's
middle of exposure is from the vertex's own time. Then a ``targets`` line (the
calibrated odometry variant: mean <= 0.3 px, standard deviation <= 0.3 px; the paper's
sigma for points was 0.53 px).

Run as a script: ``python bench/mesh_reprojection.py [--seconds S] [--work DIR]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from colorize_cameras import calibrate, drive, true_calibration  # beside this script

from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.mesh.drive import TileViews, prepare_mesh
from acq.motion import Trajectory
from acq.sim.drive_log import DriveTruth

TIME_GAPS_MS = (0.0, 10.0, 20.0, 40.0, 80.0, math.inf)  # bins of |frame time - vertex time|


@dataclass
class Corners:
    """Facet corners checked against the truth: ``error`` (N,) px, ``own`` (N,) bool
    (the vertex was coloured from its facet's view), ``camera`` (N,) int and ``gap_s``
    (N,) s, the frame's true middle of exposure minus the vertex's true time."""

    error: np.ndarray
    own: np.ndarray
    camera: np.ndarray
    gap_s: np.ndarray

    @staticmethod
    def join(parts: Sequence[Corners]) -> Corners:
        return Corners(*(np.concatenate([getattr(p, k) for p in parts] or [np.zeros(0)])
                         for k in ("error", "own", "camera", "gap_s")))  # fmt: skip

    def select(self, keep: np.ndarray) -> Corners:
        return Corners(self.error[keep], self.own[keep], self.camera[keep], self.gap_s[keep])


def corner_errors(
    truth: DriveTruth, views: TileViews, stamps: Sequence[np.ndarray], names: Sequence[str]
) -> Corners:
    """Each corner of ``views``' facets that has a pixel in its facet's view, against its
    true pixel there; ``stamps[c]`` (frames,) the recorded stamps of camera ``names[c]``'s
    session frames (the job's ``frame_old``). Corners without a true pixel (no hit, off
    the sensor) are left out."""
    has = (views.view_cam >= 0)[:, None] & np.isfinite(views.corner_px).all(axis=2)
    f, k = np.nonzero(has)
    v = views.faces[f, k]
    cam, frame = views.view_cam[f], views.view_frame[f]
    scan, step = views.scan[v], views.step[v]
    own = (views.camera[v].astype(np.int64) == cam) & (views.frame[v] == frame)
    error = np.full(f.size, np.nan)
    gap = np.full(f.size, np.nan)
    point_t = truth.scan_t0_s[scan] + truth.rig.time_increment * step
    for c, name in enumerate(names):
        sel = np.flatnonzero(cam == c)
        stamp = stamps[c][frame[sel]]
        uv, ok = truth.true_pixels(scan[sel], step[sel], stamp, camera=name)
        error[sel[ok]] = np.linalg.norm(views.corner_px[f[sel], k[sel]][ok] - uv[ok], axis=1)
        cams = truth.cameras[name]
        j = np.clip(np.searchsorted(cams.frame_stamp_ns, stamp), 0, cams.frame_t_s.size - 1)
        gap[sel] = cams.frame_t_s[j] - point_t[sel]
    keep = np.isfinite(error)
    return Corners(error[keep], own[keep], cam[keep], gap[keep])


def figures(e: np.ndarray) -> dict[str, Any]:
    """Mean, standard deviation, median, 95th percentile (px) and shares within 0.5 and
    1 px of the errors ``e`` (N,) px."""
    if not e.size:
        return {"corners": 0}
    return {
        "corners": int(e.size),
        "mean_px": round(float(e.mean()), 4),
        "std_px": round(float(e.std()), 4),
        "median_px": round(float(np.median(e)), 4),
        "p95_px": round(float(np.percentile(e, 95)), 4),
        "within_0_5px": round(float(np.mean(e <= 0.5)), 4),
        "within_1px": round(float(np.mean(e <= 1.0)), 4),
    }


def summary(c: Corners, names: Sequence[str]) -> dict[str, Any]:
    """:func:`figures` of all corners, of ``own`` and ``projected`` ones, per camera and
    by time gap."""
    gap_ms = np.abs(c.gap_s) * 1e3
    bins = {
        f"{lo:g}-{hi:g}ms": figures(c.error[(gap_ms >= lo) & (gap_ms < hi)])
        for lo, hi in itertools.pairwise(TIME_GAPS_MS)
    }
    return {
        "all": figures(c.error),
        "own": figures(c.error[c.own]),
        "projected": figures(c.error[~c.own]),
        "cameras": {n: figures(c.error[c.camera == i]) for i, n in enumerate(names)},
        "by_time_gap": bins,
    }


def measure(
    truth: DriveTruth, calib: Calibration, trajectory: Trajectory | None, out: Path
) -> tuple[Corners, dict[str, Any]]:
    """Mesh the drive textured (as `acq mesh --texture -o out`) and check every corner."""
    from acq.cli.mesh import TEXELS

    parts: list[Corners] = []
    mj = prepare_mesh(truth.files, calib, out, trajectory=trajectory, texels=TEXELS)
    names = [cj.name for cj in mj.job.cameras]
    stamps = [cj.frame_old for cj in mj.job.cameras]
    mj.on_views = lambda views: parts.append(corner_errors(truth, views, stamps, names))
    t0 = time.perf_counter()
    rep = mj.run()
    info = {"facets": rep.facets, "textured": rep.textured, "tiles": len(rep.files),
            "mesh_s": round(time.perf_counter() - t0, 1)}  # fmt: skip
    return Corners.join(parts), info


def run(work: Path, seconds: float) -> None:
    """The drive and its calibration (made in ``work`` unless kept there), the four
    variants measured; the JSON lines printed."""
    work.mkdir(parents=True, exist_ok=True)
    truth = drive(work, seconds, 2)
    calib_path = work / "calibration2" / "calib.yaml"
    if not calib_path.exists():
        calib_path = calibrate(work / "calibration2", truth.rig)
    names = list(truth.camera_names)
    calibrations = {"calibrated": calibfile.load(calib_path), "true": true_calibration(truth)}
    trajectories = {"odometry": None, "true_trajectory": truth.host_trajectory()}
    results: dict[str, dict[str, Any]] = {}
    for cal_name, cal in calibrations.items():
        for traj_name, traj in trajectories.items():
            variant = f"{cal_name}_{traj_name}"
            corners, info = measure(truth, cal, traj, work / f"{variant}.glb")
            results[variant] = summary(corners, names)
            print(json.dumps({"bench": "mesh_reprojection", "variant": variant,
                              "seconds": seconds, **info, **results[variant]}),
                  flush=True)  # fmt: skip
    head = results["calibrated_odometry"]["all"]
    print(json.dumps({"bench": "targets", "variant": "calibrated_odometry",
                      "mean_px": head["mean_px"], "mean_ok": head["mean_px"] <= 0.3,
                      "std_px": head["std_px"], "std_ok": head["std_px"] <= 0.3}))  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="the drive's length, s")
    ap.add_argument(
        "--work", type=Path,
        help="keep the drive, its calibration and the meshes here, and reuse them in a later "
        "run (default: a temporary folder)",
    )  # fmt: skip
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        run(args.work or Path(tmp), args.seconds)


if __name__ == "__main__":
    main()
