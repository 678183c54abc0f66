"""`acq colorize` from every camera of a rig (issue 18): coverage, accuracy, seams, speed.

Data: ``acq.sim.drive_log.write_drive_log`` on the two-camera rig
(``acq.sim.world.default_rig(cameras=2)``: a left and a right 185-degree fisheye, each
its own lens, mounting, latency, exposure and white balance changing over the drive),
``--seconds`` (60) of the synthetic street at 20 km/h past the validation pattern, with
body vibration; every camera's frames stamped with a latency of 25 ms configured for
all (wrong for each by its own amount); CAN odometry.

Calibration from `acq calibrate`, not the truth: each camera's Kannala-Brandt fit of 14
simulated board images (``acq calibrate fisheye --board``), ``acq calibrate extrinsic``
for every camera at once on one simulated board recording in which the board is shown
to each camera in turn, then ``acq calibrate time-offset`` for each camera on another
drive (30 s, another street); ``laser_to_vehicle`` as mounted.

One JSON line per result:

- ``calibration``: per camera, how far it is from the truth, and the cameras'
  relative pose against the true one;
- ``coverage``: share of the points that at least one camera sees (ground truth,
  ``DriveTruth.visible``) that are coloured, and of all points;
- ``accuracy``: per variant and camera, each coloured point's pixel against its true
  pixel in the frame used (RMS, share within 1 px): ``nearest`` and ``best`` with the
  calibration above, ``nearest_true_calib`` with the truth;
- ``colour``: per channel, the median and 95th percentile of |colour - the true surface
  colour| in 8-bit levels over every coloured point, balanced (default) and not;
- ``seams``: on the three-camera rig (``cameras=3``: the rear camera sees both sides
  near its rim; the left and right cameras see no laser point together), on points two
  cameras see, the difference between the two cameras' samples before and after
  balancing and the balanced samples' difference from the truth;
- ``speed``: the whole `acq colorize` process with default flags (preview included), in
  a new process (median of 3), as a multiple of real time; beside it the decode limit
  measured alternately in new processes (``bench/colorize_speed.py``: read every frame,
  decode each once on all cores; the peaks here count this process's memory too, as a
  forked child's maxrss starts from its parent's: ``bench/colorize_speed.py`` gives them);
- ``targets``.

Run as a script: ``python bench/colorize_cameras.py [--seconds S] [--work DIR]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import math
import pickle
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from colorize import board_images  # bench/colorize.py, beside this script
from colorize_speed import compare  # bench/colorize_speed.py: the decode limit beside it

from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.cli import main as acq_main
from acq.cloud.colorize import ChunkResult, run
from acq.cloud.views import Options
from acq.geometry.rotations import rotation_angle
from acq.sim.board_log import write_board_log
from acq.sim.drive_log import DriveTruth, write_drive_log
from acq.sim.world import Rig, default_rig

CONFIGURED_LATENCY_S = 0.025


def _line(bench: str, **fields: Any) -> None:
    print(json.dumps({"bench": bench, **fields}), flush=True)


def _quiet_cli(argv: list[str]) -> None:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        rc = acq_main(argv)
    if rc != 0:
        raise RuntimeError(f"acq {' '.join(argv[:2])} failed ({rc}): {out.getvalue()[-2000:]}")


def calibrate(work: Path, rig: Rig, seed: int = 0) -> Path:
    """calib.yaml of every camera of ``rig`` from `acq calibrate`: fisheye per camera,
    extrinsic for all on one board recording, time offset per camera on another drive."""
    if work.exists():  # nothing of an unfinished run: a folder of logs is one session
        shutil.rmtree(work)
    work.mkdir(parents=True)
    intr = work / "intrinsics.yaml"
    first = rig.cameras[0].camera_to_laser
    for k, name in enumerate(rig.camera_names):
        # the lens's board images: the board held before the camera as before the first
        # camera (only the images count here; the rear camera's mount sees no laser)
        one = rig.only(name).with_camera(camera_to_laser=first)
        paths = board_images(one, work / f"intrinsics_{name}", seed + k)
        _quiet_cli(["calibrate", "fisheye", *map(str, paths), "--fov", "185", "-o", str(intr),
                    "--camera", name, "--board", "9x7x0.1"])  # fmt: skip
    board = write_board_log(work / "board", n_poses=15 * len(rig.cameras), seed=seed + 1,
                            hold_s=1.0, rig=rig)  # fmt: skip
    timed = work / "extrinsic.yaml"
    _quiet_cli(["calibrate", "extrinsic", *map(str, board.files), "--intrinsics", str(intr),
                "--board", board.spec, "-o", str(timed), "--force"])  # fmt: skip
    # laser_to_vehicle as mounted: the time offset needs the rig's motion at the laser
    placed = calibfile.load(timed)
    calibfile.save(Calibration(cameras=dict(placed.cameras),
                               laser_to_vehicle=rig.laser_to_vehicle), timed)  # fmt: skip
    drive = write_drive_log(work / "time_drive", 30.0, seed=1, pattern_at=None, rig=rig,
                            configured_camera_latency_s=CONFIGURED_LATENCY_S)  # fmt: skip
    for name in rig.camera_names:  # each camera's offset into the same file, in place
        _quiet_cli(["calibrate", "time-offset", *map(str, drive.files), "--calib", str(timed),
                    "--camera", name, "-o", str(timed), "--force"])  # fmt: skip
    out = work / "calib.yaml"
    timed.replace(out)
    calib = calibfile.load(out)
    errors: dict[str, Any] = {}
    for name in rig.camera_names:
        cam, true = calib.camera(name), rig.camera(name)
        T, truth = cam.camera_to_laser, true.camera_to_laser
        lat = drive.cameras[name]
        errors[name] = {
            "principal_point_px": round(math.hypot(cam.model.cx - true.lens.cx,
                                                   cam.model.cy - true.lens.cy), 3),
            "rotation_deg": round(math.degrees(rotation_angle(T.rotation @ truth.rotation.T)), 4),
            "translation_mm": round(float(np.linalg.norm(T.translation - truth.translation))
                                    * 1e3, 2),
            "time_offset_error_ms": round(
                (cam.time_offset_s - (lat.latency_true_s - lat.latency_configured_s)) * 1e3, 3),
        }  # fmt: skip
    relative = {}
    for a, b in itertools.combinations(rig.camera_names, 2):
        est = calib.camera(a).camera_to_laser.inverse() @ calib.camera(b).camera_to_laser
        true = rig.camera(a).camera_to_laser.inverse() @ rig.camera(b).camera_to_laser
        relative[f"{a}->{b}"] = {
            "rotation_deg": round(math.degrees(rotation_angle(est.rotation @ true.rotation.T)), 4),
            "translation_mm": round(float(np.linalg.norm(est.translation - true.translation))
                                    * 1e3, 2),
        }  # fmt: skip
    _line("calibration", cameras=errors, relative_poses=relative)
    return out


def _cat(results: list[ChunkResult], name: str) -> np.ndarray:
    return np.concatenate([getattr(r, name) for r in results])


def coverage(truth: DriveTruth, results: list[ChunkResult]) -> dict[str, float]:
    scan, step = _cat(results, "scan").astype(np.int64), _cat(results, "step").astype(np.int64)
    col = _cat(results, "coloured")
    seen = truth.visible[scan, step].any(axis=-1)
    return {
        "points": int(col.size),
        "visible_share": round(float(seen.mean()), 4),
        "coloured_of_visible": round(float(col[seen].mean()), 4),
        "coloured_of_all": round(float(col.mean()), 4),
    }


def accuracy(
    truth: DriveTruth, results: list[ChunkResult], names: list[str]
) -> dict[str, dict[str, float]]:
    """Per camera (by its index in ``names``): RMS and share within 1 px of the pixel
    used against the true one, and the points it coloured."""
    scan, step = _cat(results, "scan").astype(np.int64), _cat(results, "step").astype(np.int64)
    cam, stamp, uv = _cat(results, "camera"), _cat(results, "frame_stamp_ns"), _cat(results, "uv")
    out = {}
    for c, name in enumerate(names):
        sel = np.flatnonzero(cam == c)
        true_uv, ok = truth.true_pixels(scan[sel], step[sel], stamp[sel], camera=name)
        e = np.linalg.norm(uv[sel][ok] - true_uv[ok], axis=1)
        out[name] = {
            "points": int(sel.size),
            "checked": int(e.size),
            "rms_px": round(float(np.sqrt(np.mean(e**2))), 4) if e.size else math.nan,
            "within_1px": round(float(np.mean(e <= 1.0)), 4) if e.size else math.nan,
        }
    return out


def _levels(diff: np.ndarray) -> dict[str, list[float]]:
    return {"median": [float(v) for v in np.median(diff, axis=0)],
            "p95": [float(v) for v in np.percentile(diff, 95, axis=0)]}  # fmt: skip


def colour(truth: DriveTruth, results: list[ChunkResult]) -> dict[str, Any]:
    """|colour - true surface colour| per channel (RGB, 8-bit levels) of coloured points."""
    scan, step = _cat(results, "scan").astype(np.int64), _cat(results, "step").astype(np.int64)
    col = _cat(results, "coloured")
    true_rgb = truth.colours[scan, step][:, ::-1].astype(np.int64)
    diff = np.abs(_cat(results, "rgb").astype(np.int64) - true_rgb)[col]
    return _levels(diff)


def seams(truth: DriveTruth, results: list[ChunkResult]) -> dict[str, Any]:
    """On points two cameras both coloured: their samples' difference before and after
    balancing, and the balanced samples' difference from the truth."""
    scan, step = _cat(results, "scan").astype(np.int64), _cat(results, "step").astype(np.int64)
    true_rgb = truth.colours[scan, step][:, ::-1].astype(np.int64)
    samples = {
        name: tuple(np.concatenate([r.samples[name][k] for r in results if r.samples])
                    for k in range(3))
        for name in truth.camera_names
    }  # fmt: skip
    out: dict[str, Any] = {}
    for a, b in itertools.combinations(truth.camera_names, 2):
        (ra, ba, ca), (rb, bb, cb) = samples[a], samples[b]
        both = ca & cb
        if not both.any():
            out[f"{a}/{b}"] = {"points": 0}
            continue
        raw = np.abs(ra[both].astype(np.int64) - rb[both])
        bal = np.abs(ba[both].astype(np.int64) - bb[both])
        t = true_rgb[both]
        vs_truth = np.concatenate([np.abs(ba[both] - t), np.abs(bb[both] - t)])
        raw_truth = np.concatenate([np.abs(ra[both] - t), np.abs(rb[both] - t)])
        out[f"{a}/{b}"] = {
            "points": int(both.sum()),
            "between_cameras_before": _levels(raw),
            "between_cameras_after": _levels(bal),
            "from_truth_before": _levels(raw_truth),
            "from_truth_after": _levels(vs_truth),
        }
    return out


def true_calibration(truth: DriveTruth) -> Calibration:
    """The truth as a calibration: each camera's lens and pose, and its latency error
    (true minus configured) as its time offset."""
    return Calibration(
        cameras={
            n: replace(c, time_offset_s=truth.cameras[n].latency_true_s
                       - truth.cameras[n].latency_configured_s)
            for n, c in truth.calibration.cameras.items()
        },
        laser_to_vehicle=truth.rig.laser_to_vehicle,
    )  # fmt: skip


def drive(work: Path, seconds: float, cameras: int, seed: int = 0) -> DriveTruth:
    """The drive of ``cameras`` cameras (``seconds``, the pattern at 60 m, every camera's
    latency configured as CONFIGURED_LATENCY_S) in ``work``, or the one kept there."""
    cached = work / f"truth_{seconds:g}s_{cameras}.pickle"
    if cached.exists():
        truth: DriveTruth = pickle.loads(cached.read_bytes())
        return truth
    truth = write_drive_log(work / f"drive{cameras}", seconds, pattern_at=60.0, seed=seed,
                            rig=default_rig(cameras=cameras),
                            configured_camera_latency_s=CONFIGURED_LATENCY_S)  # fmt: skip
    cached.write_bytes(pickle.dumps(truth))
    return truth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seam-seconds", type=float, default=30.0)
    ap.add_argument("--work", type=Path, help="keep the logs here (default: a temporary folder)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        truth = drive(work, args.seconds, 2)
        _line("simulation", seconds=args.seconds, cameras=list(truth.camera_names),
              wall_s=round(time.perf_counter() - t0, 1), scans=int(truth.scan_t0_s.size),
              frames={n: int(c.frame_t_s.size) for n, c in truth.cameras.items()})  # fmt: skip
        calib_path = work / "calibration2" / "calib.yaml"
        if not calib_path.exists():
            calib_path = calibrate(work / "calibration2", truth.rig)
        calib = calibfile.load(calib_path)
        names = list(truth.camera_names)
        summary: dict[str, Any] = {}
        known = true_calibration(truth)
        variants = [
            ("nearest", calib, Options()),
            ("best", calib, Options(view="best")),
            ("nearest_no_balance", calib, Options(balance=False)),
            ("nearest_true_calib", known, Options()),
        ]
        for name, cal, options in variants:
            results: list[ChunkResult] = []
            run(truth.files, cal, work / f"{name}.ply", options=options, results=results,
                want_uv=True, preview=None)  # fmt: skip
            summary[name] = {
                "coverage": coverage(truth, results),
                "accuracy": accuracy(truth, results, names),
                "colour": colour(truth, results),
            }
            _line("variant", variant=name, **summary[name])
        # seams: the three-camera rig (the rear camera sees both sides)
        seam_truth = drive(work, args.seam_seconds, 3, seed=2)
        seam_calib_path = work / "calibration3" / "calib.yaml"
        if not seam_calib_path.exists():
            seam_calib_path = calibrate(work / "calibration3", seam_truth.rig, seed=10)
        results = []
        run(seam_truth.files, calibfile.load(seam_calib_path), work / "seams.ply",
            results=results, want_uv=True, preview=None)  # fmt: skip
        seam = seams(seam_truth, results)
        _line("seams", seconds=args.seam_seconds, cameras=list(seam_truth.camera_names),
              pairs=seam, colour=colour(seam_truth, results))  # fmt: skip
        duration = float(truth.scan_t0_s[-1] - truth.scan_t0_s[0])
        sp = compare(truth.files, calib_path, work / "speed.ply", duration, repeat=3)
        _line("speed", **sp)
        n = summary["nearest"]
        b = summary["best"]
        after = [p["from_truth_after"]["median"] for p in seam.values() if p.get("points")]
        _line(
            "targets",
            coverage_of_visible=n["coverage"]["coloured_of_visible"],
            coverage_ok=n["coverage"]["coloured_of_visible"] >= 0.99,
            rms_px={v: {c: s["accuracy"][c]["rms_px"] for c in names}
                    for v, s in (("nearest", n), ("best", b))},
            accuracy_ok=all(s["accuracy"][c]["rms_px"] <= 0.3
                            and s["accuracy"][c]["within_1px"] >= 0.99
                            for s in (n, b) for c in names),
            seam_from_truth_median=after,
            seams_ok=bool(after) and max(max(m) for m in after) <= 4,
            process_real_time_multiple=sp["colorize_real_time_multiple"],
            speed_ok=sp["colorize_real_time_multiple"] >= 20.0,
            decode_limit_multiple=sp["decode_limit_real_time_multiple"],
            decode_limit_ratio=sp["ratio"],
        )  # fmt: skip


if __name__ == "__main__":
    main()
