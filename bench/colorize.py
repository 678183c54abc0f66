"""Accuracy and speed of `acq colorize` on a simulated drive (issue 8).

Data: ``sim.drive_log.write_drive_log`` — ``--seconds`` (60) of the synthetic street at
20 km/h in the lane nearest the camera's side, past the validation pattern, with body
vibration; scans re-timed from their logged ticks (not the true clocks); frames stamped
with a camera latency the configuration gets wrong by 10 ms; odometry on the CAN topic.

Calibration from `acq calibrate`, not the truth: the Kannala–Brandt fit of 12 simulated
board images (``acq calibrate fisheye --board``), then ``acq calibrate extrinsic`` on a
simulated board recording (15 still poses); ``laser_to_vehicle`` as mounted.

One JSON line per result:

- ``calibration``: how far the calibration is from the truth;
- ``accuracy``: per variant, (a) each coloured point's pixel against its true pixel in
  the frame used (RMS, shares within 0.5 and 1 px) and (b) on the validation pattern the
  share of points given their set's colour (the paper's Table 4 criterion: the set whose
  two colours, or a blend of them, the point's colour is nearest). Variants:
  ``nearest`` (the configured, wrong camera latency), ``nearest_time_offset_known``
  (the latency error given as the calibration's time offset), ``best_time_offset_known``,
  without motion compensation, with a 10 ms clock error on top, and with the true
  calibration;
- ``speed``: the whole command on the log (decoding included) as a multiple of real
  time, with 1 and 2 workers, and where the time goes;
- ``targets`` (with the camera's time offset known): RMS <= 0.3 px, >= 99 % within
  1 px, >= 99 % right colour on the pattern, >= 20x real time.

Run as a script: ``python bench/colorize.py [--seconds S] [--work DIR]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import pickle
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from acq import calibfile
from acq.calibfile import Calibration
from acq.colorize import ChunkResult, run
from acq.extrinsic import rotation_angle
from acq.extrinsic_log import main_extrinsic
from acq.fisheye_calib import main_fisheye
from acq.validate import DEFAULT_COLOURS
from acq.views import Options
from sim.board_log import BOARD, render_frame, write_board_log
from sim.board_poses import simulate
from sim.drive_log import DriveTruth, write_drive_log
from sim.world import Material, default_rig

FRONT = ("red", "green")
BACK = ("blue", "yellow")


def _line(bench: str, **fields: Any) -> None:
    print(json.dumps({"bench": bench, **fields}), flush=True)


def calibrate(work: Path, seed: int = 0) -> Path:
    """calib.yaml from `acq calibrate fisheye --board` and `acq calibrate extrinsic`."""
    rig = default_rig()
    out = work / "calib.yaml"
    images = work / "intrinsics"
    images.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    data = simulate(14, seed, rig=rig, board=BOARD, true_planes=True, range_noise=0.0,
                    distance=(0.7, 1.4), bearing_spread_deg=60.0, max_tilt_deg=35.0,
                    min_laser_points=0)  # fmt: skip
    paths = []
    for i, board in enumerate(data.boards):
        img = render_frame(rig.lens, rig.camera_to_laser, BOARD, board)
        img = cv2.GaussianBlur(img, (0, 0), 0.6) + rng.normal(0.0, 1.5, img.shape)
        path = images / f"board{i:02d}.png"
        cv2.imwrite(str(path), np.clip(np.rint(img), 0, 255).astype(np.uint8))
        paths.append(path)
    intr = work / "intrinsics.yaml"
    quiet = io.StringIO()
    with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
        assert main_fisheye(paths, 185.0, intr, camera="camera", board="9x7x0.1") == 0
        log = write_board_log(work / "board", n_poses=15, seed=seed + 1, hold_s=1.0)
        assert main_extrinsic(log.files, "camera", intr, log.spec, out) == 0
    cam = calibfile.load(out).camera("camera")
    calibfile.save(Calibration(cameras={"camera": cam}, laser_to_vehicle=rig.laser_to_vehicle),
                   out)  # fmt: skip
    T, truth = cam.camera_to_laser, rig.camera_to_laser
    th = np.linspace(0.0, rig.lens.theta_max, 100)
    gap = np.abs(cam.model.fx * cam.model.distort_theta(th) - rig.lens.fx *
                 rig.lens.distort_theta(th)).max()  # fmt: skip
    _line(
        "calibration",
        board_images=len(paths),
        principal_point_px=round(
            math.hypot(cam.model.cx - rig.lens.cx, cam.model.cy - rig.lens.cy), 3
        ),
        radius_gap_max_px=round(float(gap), 3),
        rotation_deg=round(math.degrees(rotation_angle(T.rotation @ truth.rotation.T)), 4),
        translation_mm=round(float(np.linalg.norm(T.translation - truth.translation)) * 1e3, 2),
    )
    return out


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (RGB units) of colours ``p`` (N,3) from the segment a-b."""
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def evaluate(truth: DriveTruth, results: list[ChunkResult]) -> dict[str, float]:
    """(a) pixel errors against the truth and (b) right colour on the pattern."""
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    stamp = np.concatenate([r.frame_stamp_ns for r in results if r.frame_stamp_ns is not None])
    uv = np.concatenate([r.uv for r in results if r.uv is not None])
    rgb = np.concatenate([r.rgb for r in results])
    coloured = np.concatenate([r.coloured for r in results])
    ok = coloured & (stamp >= 0)
    true_uv, valid = truth.true_pixels(scan[ok], step[ok], stamp[ok])
    e = np.linalg.norm(uv[ok][valid] - true_uv[valid], axis=1)
    # the pattern: true hits on its bars (SOLID: the front set) or on its panel
    # (CHECKER: the back set); a point's colour goes to the set whose colours (or a blend
    # of them: JPEG's half-resolution chroma blends neighbouring squares and bars) it is
    # nearest, as the RGB segment between the set's two colours
    mat = truth.materials[scan, step]
    on_pattern = coloured & np.isin(mat, [Material.SOLID, Material.CHECKER])
    got = rgb[on_pattern].astype(np.float64)
    d = {name: _segment_distance(got, *(np.array(DEFAULT_COLOURS[c], float) for c in cols))
         for name, cols in (("front", FRONT), ("back", BACK))}  # fmt: skip
    front = mat[on_pattern] == Material.SOLID
    right = np.where(front, d["front"] < d["back"], d["back"] < d["front"])
    # interior points: the true scene 2 px around the true pixel is the same set (no
    # colour edge within the JPEG's chroma blur)
    interior = _interior(truth, scan[on_pattern], step[on_pattern],
                         stamp[on_pattern], 2.0)  # fmt: skip
    return {
        "points": int(coloured.size),
        "coloured": int(coloured.sum()),
        "checked": int(e.size),
        "rms_px": round(float(np.sqrt(np.mean(e**2))), 4),
        "median_px": round(float(np.median(e)), 4),
        "within_0_5px": round(float(np.mean(e <= 0.5)), 4),
        "within_1px": round(float(np.mean(e <= 1.0)), 4),
        "p99_px": round(float(np.percentile(e, 99)), 3),
        "pattern_points": int(on_pattern.sum()),
        "pattern_right": round(float(right.mean()) if right.size else math.nan, 4),
        "pattern_interior_points": int(interior.sum()),
        "pattern_right_interior": round(
            float(right[interior].mean()) if interior.any() else math.nan, 4
        ),
    }


def _interior(
    truth: DriveTruth, scan: np.ndarray, step: np.ndarray, stamp: np.ndarray, px: float
) -> np.ndarray:
    """Whether the true scene ``px`` pixels left, right, up and down of each point's true
    pixel (in its frame, at the frame's true time) lies on the point's own set."""
    from sim.raycast import cast
    from sim.sensors import camera_to_world

    uv, valid = truth.true_pixels(scan, step, stamp)
    k = np.clip(np.searchsorted(truth.frame_stamp_ns, stamp), 0, truth.frame_t_s.size - 1)
    own = truth.materials[scan, step]
    out = valid.copy()
    lens = truth.rig.lens
    for j in np.unique(k[valid]):
        sel = np.flatnonzero(valid & (k == j))
        pose = camera_to_world(truth.trajectory, truth.rig, float(truth.frame_t_s[j]))
        for du, dv in ((px, 0.0), (-px, 0.0), (0.0, px), (0.0, -px)):
            rays = lens.unproject(uv[sel] + [du, dv])
            hit = cast(truth.street, pose.translation, rays @ pose.rotation.T)
            out[sel] &= hit.material == own[sel]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--work", type=Path, help="keep the logs here (default: a temporary folder)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        cached = work / "drive" / f"truth_{args.seconds:g}s.pickle"
        if cached.exists():  # --work kept from an earlier run
            truth = pickle.loads(cached.read_bytes())
        else:
            truth = write_drive_log(work / "drive", args.seconds, pattern_at=60.0)
            cached.write_bytes(pickle.dumps(truth))
        _line("simulation", seconds=args.seconds, wall_s=round(time.perf_counter() - t0, 1),
              scans=int(truth.scan_t0_s.size), frames=int(truth.frame_t_s.size),
              camera_latency_true_ms=round(truth.config["camera_latency_true_s"] * 1e3, 2),
              camera_latency_configured_ms=round(
                  truth.config["camera_latency_configured_s"] * 1e3, 2))  # fmt: skip
        calib_path = work / "calibration" / "calib.yaml"
        if not calib_path.exists():
            calib_path = calibrate(work / "calibration")
        calib = calibfile.load(calib_path)
        true_calib = truth.calibration
        latency_error = (
            truth.config["camera_latency_true_s"] - truth.config["camera_latency_configured_s"]
        )
        known = latency_error
        variants: list[tuple[str, Calibration, Options, float | None]] = [
            ("nearest", calib, Options(), None),
            ("nearest_time_offset_known", calib, Options(), known),
            ("best_time_offset_known", calib, Options(view="best"), known),
            ("nearest_known_no_motion_compensation", calib,
             Options(motion_compensation=False), known),
            ("nearest_known_plus_10ms_clock_error", calib, Options(), known + 0.010),
            ("nearest_true_calib_known", true_calib, Options(), known),
        ]  # fmt: skip
        summary: dict[str, dict[str, float]] = {}
        for name, cal, options, offset in variants:
            results: list[ChunkResult] = []
            report = run(truth.files, cal, work / f"{name}.ply", options=options,
                         results=results, want_uv=True, preview=None,
                         time_offset_s=offset)  # fmt: skip
            summary[name] = evaluate(truth, results)
            _line("accuracy", variant=name, time_offset_s=offset,
                  time_offset_used_s=report.time_offset.get("used_s"), **summary[name],
                  notes=report.notes)  # fmt: skip
        speeds: dict[tuple[str, int], float] = {}
        for fmt, workers in (("ply", 1), ("las", 1), ("las", 2)):
            out = work / f"speed.{fmt}"
            report = run(truth.files, calib, out, workers=workers, preview=None)
            total = report.seconds["total"]
            speeds[fmt, workers] = report.duration_s / total
            breakdown = {k.strip(): round(v, 2) for k, v in report.seconds.items()}
            _line("speed", output=fmt, workers=workers, seconds=round(total, 2),
                  real_time_multiple=round(speeds[fmt, workers], 1), points=report.points,
                  breakdown_s=breakdown)  # fmt: skip
        n = summary["nearest_time_offset_known"]
        _line("targets", variant="nearest_time_offset_known",
              rms_px=n["rms_px"], rms_ok=n["rms_px"] <= 0.3,
              within_1px=n["within_1px"], within_1px_ok=n["within_1px"] >= 0.99,
              pattern_right=n["pattern_right"], pattern_ok=n["pattern_right"] >= 0.99,
              real_time_multiple={f"{k[0]}_{k[1]}": round(v, 1) for k, v in speeds.items()},
              speed_ok=max(speeds.values()) >= 20.0)  # fmt: skip


if __name__ == "__main__":
    main()
