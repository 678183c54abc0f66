"""Accuracy and speed of `acq colorize` on a simulated drive (issue 8).

Data: ``acq.sim.drive_log.write_drive_log`` — ``--seconds`` (60) of the synthetic street at
20 km/h in the lane nearest the camera's side, past the validation pattern, with body
vibration; scans re-timed from their logged ticks (not the true clocks); frames stamped
with a camera latency the configuration gets wrong by 10 ms; odometry on the CAN topic.

Calibration from `acq calibrate`, not the truth: the Kannala–Brandt fit of 14 simulated
board images (``acq calibrate fisheye --board``), then ``acq calibrate extrinsic`` on a
simulated board recording (15 still poses), then ``acq calibrate time-offset`` on another
drive (30 s of another street, seed 1, the same camera and its same wrong configured
latency); ``laser_to_vehicle`` as mounted.

One JSON line per result:

- ``calibration``: how far the calibration is from the truth;
- ``accuracy``: per variant, (a) each coloured point's pixel against its true pixel in
  the frame used (RMS, shares within 0.5 and 1 px) and (b) on the validation pattern the
  share of points given their set's colour (the paper's Table 4 criterion: the set whose
  two colours, or a blend of them, the point's colour is nearest), and the same share
  for colours sampled at each point's TRUE pixel in its frame (``pattern_right_ceiling``:
  what the frame, its JPEG and its resolution allow any method colouring from it), over
  all pattern points, over those the camera sees in that frame (``_visible``: from the
  camera, nearer parts of the pattern hide some of the back set that the laser, half a metre
  away, sees) and over those away from colour edges (``_interior``). Variants: ``nearest`` (the
  calibration above, time offset included), ``nearest_time_offset_auto`` (the offset
  estimated from the log itself, ``--time-offset auto``), ``nearest_configured_latency``
  (no time-offset calibration: the camera's configured, wrong latency),
  ``nearest_time_offset_known`` (the true latency error as the time offset), ``best``,
  without motion compensation, with a 10 ms clock error on top, and with the true
  calibration;
- ``speed``: `acq colorize` on the log in a new process (median of 5 runs), its own time
  (reading to writing, decoding included) and the process's wall time as multiples of
  real time, with 1 and 2 workers, and where the time goes;
- ``decoding``: every frame of the log decoded once on one core (CPU-seconds): the
  largest part of the work;
- ``targets`` (``nearest``, everything from `acq calibrate`): RMS <= 0.3 px, >= 99 %
  within 1 px, >= 99 % right colour on the pattern, >= 20x real time (the whole process,
  its best configuration).

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

from acq.calib.validate import DEFAULT_COLOURS
from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.cli import main as acq_main
from acq.cloud.colorize import ChunkResult, run
from acq.cloud.views import Options
from acq.geometry.rotations import rotation_angle
from acq.sim.board_log import BOARD, render_frame, write_board_log
from acq.sim.board_poses import simulate
from acq.sim.drive_log import DriveTruth, write_drive_log
from acq.sim.world import Material, Rig, default_rig

FRONT = ("red", "green")
BACK = ("blue", "yellow")


def _line(bench: str, **fields: Any) -> None:
    print(json.dumps({"bench": bench, **fields}), flush=True)


def board_images(rig: Rig, images: Path, seed: int) -> list[Path]:
    """14 PNG images of the board held 0.7-1.4 m before the rig's (first) camera, a
    little blurred and noisy, in ``images``: what `acq calibrate fisheye --board` takes."""
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
    return paths


def calibrate(work: Path, seed: int = 0) -> Path:
    """calib.yaml from `acq calibrate fisheye --board` and `acq calibrate extrinsic`."""
    rig = default_rig()
    out = work / "calib.yaml"
    paths = board_images(rig, work / "intrinsics", seed)
    intr = work / "intrinsics.yaml"
    quiet = io.StringIO()
    with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
        assert acq_main(["calibrate", "fisheye", *map(str, paths), "--fov", "185", "-o", str(intr),
                         "--camera", "camera", "--board", "9x7x0.1"]) == 0  # fmt: skip
        log = write_board_log(work / "board", n_poses=15, seed=seed + 1, hold_s=1.0)
        assert acq_main(["calibrate", "extrinsic", *map(str, log.files), "--camera", "camera",
                         "--intrinsics", str(intr), "--board", log.spec,
                         "-o", str(out)]) == 0  # fmt: skip
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


def calibrate_time_offset(work: Path, calib: Path, seconds: float = 30.0) -> Path:
    """``calib`` with the camera's time offset from `acq calibrate time-offset` on a drive
    of another street (seed 1) by the same rig, whose camera latency is configured as
    wrong as the measured drive's."""

    truth = write_drive_log(work / "time_drive", seconds, seed=1, pattern_at=None)
    out = work / "calib_time_offset.yaml"
    quiet = io.StringIO()
    with contextlib.redirect_stdout(quiet):
        rc = acq_main(["calibrate", "time-offset", *map(str, truth.files), "--calib", str(calib),
                       "-o", str(out)])  # fmt: skip
    assert rc == 0, quiet.getvalue()
    cam = calibfile.load(out).camera("camera")
    err = truth.config["camera_latency_true_s"] - truth.config["camera_latency_configured_s"]
    _line("time_offset_calibration", drive_s=seconds, estimate_ms=round(cam.time_offset_s * 1e3, 3),
          std_ms=round((cam.std.time_offset_s or math.nan) * 1e3, 3),
          true_ms=round(err * 1e3, 3),
          error_ms=round((cam.time_offset_s - err) * 1e3, 3))  # fmt: skip
    return out


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (RGB units) of colours ``p`` (N,3) from the segment a-b."""
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def evaluate(
    truth: DriveTruth, results: list[ChunkResult], jpegs: dict[int, bytes]
) -> dict[str, float]:
    """(a) pixel errors against the truth and (b) right colour on the pattern, also for
    colours sampled at the true pixels (``jpegs``: the frames by recorded stamp)."""
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
    front = mat[on_pattern] == Material.SOLID
    right = _right_set(rgb[on_pattern], front)
    ps, pk, pstamp = scan[on_pattern], step[on_pattern], stamp[on_pattern]
    ceiling = _right_at_true_pixels(truth, ps, pk, pstamp, front, jpegs)
    visible = _visible(truth, ps, pk, pstamp)
    _, valid_p = truth.true_pixels(ps, pk, pstamp)
    vis_valid = visible[valid_p]  # ceiling has the valid points only

    def share(x: np.ndarray) -> float:
        return round(float(x.mean()), 4) if x.size else math.nan

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
        "pattern_right_ceiling": round(float(ceiling.mean()) if ceiling.size else math.nan, 4),
        "pattern_visible_points": int(visible.sum()),
        "pattern_right_visible": share(right[visible]),
        "pattern_right_visible_ceiling": share(ceiling[vis_valid]),
        "pattern_interior_points": int(interior.sum()),
        "pattern_right_interior": round(
            float(right[interior].mean()) if interior.any() else math.nan, 4
        ),
    }


def _right_set(rgb: np.ndarray, front: np.ndarray) -> np.ndarray:
    """Whether colours ``rgb`` (N,3) are nearest their set's (``front`` (N,) bool)."""
    got = rgb.astype(np.float64)
    d = {name: _segment_distance(got, *(np.array(DEFAULT_COLOURS[c], float) for c in cols))
         for name, cols in (("front", FRONT), ("back", BACK))}  # fmt: skip
    return np.where(front, d["front"] < d["back"], d["back"] < d["front"])


def _visible(
    truth: DriveTruth, scan: np.ndarray, step: np.ndarray, stamp: np.ndarray
) -> np.ndarray:
    """Whether each point is seen by the camera in its frame: the ray from the camera's
    true position at the frame's true time to the point hits nothing 2 cm nearer."""
    from acq.sim.raycast import cast
    from acq.sim.sensors import camera_to_world

    k = np.clip(np.searchsorted(truth.frame_stamp_ns, stamp), 0, truth.frame_t_s.size - 1)
    P = truth.points[scan, step].astype(np.float64)
    out = np.zeros(scan.size, dtype=bool)
    for j in np.unique(k).tolist():
        sel = np.flatnonzero(k == j)
        origin = camera_to_world(truth.trajectory, truth.rig, float(truth.frame_t_s[j])).translation
        d = P[sel] - origin
        dist = np.linalg.norm(d, axis=1)
        hit = cast(truth.street, origin, d / dist[:, None])
        out[sel] = hit.distance > dist - 0.02
    return out


def _right_at_true_pixels(
    truth: DriveTruth, scan: np.ndarray, step: np.ndarray, stamp: np.ndarray,
    front: np.ndarray, jpegs: dict[int, bytes],
) -> np.ndarray:  # fmt: skip
    """The right-set test for each point's colour sampled (bilinear) at its TRUE pixel in
    its frame: the ceiling of the pattern criterion for this image and resolution."""
    from acq.camera.jpeg import decode_jpeg

    uv, valid = truth.true_pixels(scan, step, stamp)
    rgb = np.zeros((scan.size, 3), np.uint8)
    for s_ns in np.unique(stamp[valid]).tolist():
        sel = np.flatnonzero(valid & (stamp == s_ns))
        image = decode_jpeg(jpegs[s_ns])
        assert image is not None
        m = uv[sel].astype(np.float32).reshape(-1, 1, 2)
        bgr = cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR).reshape(-1, 3)
        rgb[sel] = bgr[:, ::-1]
    return _right_set(rgb, front)[valid]


def _interior(
    truth: DriveTruth, scan: np.ndarray, step: np.ndarray, stamp: np.ndarray, px: float
) -> np.ndarray:
    """Whether the true scene ``px`` pixels left, right, up and down of each point's true
    pixel (in its frame, at the frame's true time) lies on the point's own set."""
    from acq.sim.raycast import cast
    from acq.sim.sensors import camera_to_world

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


def _speed(
    truth: DriveTruth, calib: Path, out: Path, workers: int, repeat: int = 5
) -> tuple[float, float]:
    """`acq colorize` as a user runs it, in a new process each time (``repeat`` runs, the
    median kept): its own time (reading to writing) and the process's wall time
    (interpreter start, imports and compiled-code loading included); one ``speed`` line.
    Returns the real-time multiples of its own time and of the whole process."""
    import statistics
    import subprocess
    import sys

    own, wall, reports = [], [], []
    for _ in range(repeat):
        cmd = [sys.executable, "-m", "acq.cli", "colorize", *map(str, truth.files),
               "--calib", str(calib), "-o", str(out), "--no-preview", "--json",
               "--workers", str(workers)]  # fmt: skip
        t0 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True, check=True)
        wall.append(time.perf_counter() - t0)
        report = json.loads(done.stdout)
        own.append(report["seconds"]["total"])
        reports.append(report)
    k = own.index(statistics.median(own))
    report = reports[k]
    duration = report["duration_s"]
    _line("speed", output=out.suffix[1:], workers=workers, runs=repeat,
          seconds=round(own[k], 2), real_time_multiple=round(duration / own[k], 1),
          process_wall_s=round(statistics.median(wall), 2),
          process_real_time_multiple=round(duration / statistics.median(wall), 1),
          points=report["points"], frames_used=report["frames_used"],
          breakdown_s={key.strip(): round(v, 2)
                       for key, v in report["seconds"].items()})  # fmt: skip
    return float(duration / own[k]), float(duration / statistics.median(wall))


def _decoding(jpegs: list[bytes], duration_s: float) -> None:
    """Where most of the time goes: decoding every frame of the log once on one core
    (acq.camera.jpeg.decode_jpeg, OpenCV's libjpeg-turbo), the best of 3; one ``decoding``
    line, with the CPU-seconds it costs a second of log."""
    from acq.camera.jpeg import decode_jpeg

    best = math.inf
    for _ in range(3):
        t0 = time.process_time()
        for jpeg in jpegs:
            decode_jpeg(jpeg)
        best = min(best, time.process_time() - t0)
    _line("decoding", frames=len(jpegs), cpu_s=round(best, 2),
          ms_per_frame=round(best / len(jpegs) * 1e3, 3),
          cpu_s_per_log_second=round(best / duration_s, 4))  # fmt: skip


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
        offset_path = work / "calibration" / "calib_time_offset.yaml"
        if not offset_path.exists():
            offset_path = calibrate_time_offset(work / "calibration", calib_path)
        calib = calibfile.load(offset_path)
        configured = calibfile.load(calib_path)  # the same without the time offset
        true_calib = truth.calibration
        from acq.log.drive_log import read_log

        log = read_log(truth.files)
        jpegs = dict(zip(log.frame_ns.tolist(), log.jpegs, strict=True))
        latency_error = (
            truth.config["camera_latency_true_s"] - truth.config["camera_latency_configured_s"]
        )
        known = latency_error
        variants: list[tuple[str, Calibration, Options, float | str | None]] = [
            ("nearest", calib, Options(), None),
            ("nearest_time_offset_auto", configured, Options(), "auto"),
            ("nearest_configured_latency", configured, Options(), None),
            ("nearest_time_offset_known", calib, Options(), known),
            ("best", calib, Options(view="best"), None),
            ("nearest_no_motion_compensation", calib, Options(motion_compensation=False), None),
            ("nearest_plus_10ms_clock_error", calib, Options(),
             calib.camera("camera").time_offset_s + 0.010),
            ("nearest_true_calib_known", true_calib, Options(), known),
        ]  # fmt: skip
        summary: dict[str, dict[str, float]] = {}
        for name, cal, options, offset in variants:
            results: list[ChunkResult] = []
            report = run(truth.files, cal, work / f"{name}.ply", options=options,
                         results=results, want_uv=True, preview=None,
                         time_offset_s=offset)  # fmt: skip
            summary[name] = evaluate(truth, results, jpegs)
            used = report.time_offset.get("used_s", math.nan)
            _line("accuracy", variant=name, time_offset=offset,
                  time_offset_used_ms=round(used * 1e3, 3),
                  time_offset_error_ms=round((used - known) * 1e3, 3), **summary[name],
                  notes=report.notes)  # fmt: skip
        _decoding(log.jpegs, report.duration_s)
        speeds: dict[tuple[str, int], tuple[float, float]] = {}
        calib_file = work / "calibration" / "calib_time_offset.yaml"
        for fmt, workers in (("ply", 1), ("las", 1), ("las", 2)):
            speeds[fmt, workers] = _speed(truth, calib_file, work / f"speed.{fmt}", workers)
        n = summary["nearest"]
        _line("targets", variant="nearest",
              rms_px=n["rms_px"], rms_ok=n["rms_px"] <= 0.3,
              within_1px=n["within_1px"], within_1px_ok=n["within_1px"] >= 0.99,
              pattern_right=n["pattern_right"], pattern_ok=n["pattern_right"] >= 0.99,
              real_time_multiple={f"{k[0]}_{k[1]}": round(v[0], 1) for k, v in speeds.items()},
              process_real_time_multiple={f"{k[0]}_{k[1]}": round(v[1], 1)
                                          for k, v in speeds.items()},
              speed_ok=max(v[1] for v in speeds.values()) >= 20.0)  # fmt: skip


if __name__ == "__main__":
    main()
