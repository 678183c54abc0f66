"""`acq calibrate time-offset`'s estimate against the truth, one JSON line per recording
and camera, then one summary line per kind of recording.

- ``demo``: `acq demo --out DIR` (the simulated rig recorded live by the real recorder;
  the same street every run), the true ``time_offset_s`` of each camera from its summary
  (camera minus laser time: re-timed frames minus re-timed scans,
  :mod:`acq.sim.demo_truth`), then `acq calibrate time-offset DIR/demo.mcap --calib
  DIR/calib.yaml --json`. Each run records in real time: a quiet machine.
- ``drive``: :func:`acq.sim.drive_log.write_drive_log` (a left and a right camera, 4 s,
  another street per seed), the truth from its :class:`DriveTruth` (the same
  difference), the estimate as `acq calibrate time-offset` makes it.
- ``scene``: the demo's street, path and cameras rendered offline, every stamp exact
  (truth 0), the scanner's turns starting at another phase (of its 25 ms) per run, the
  estimate from the true path: the estimator's own error on the demo's scene, without
  the recorder's stamps, the re-timing, the odometry or the truth line. Every demo run
  films the same street along the same path with the same frames; only the scanner's
  phase (where its lines fall on the walls), the stamps' errors and the range noise
  differ. The estimate's error on one scene follows that phase smoothly (by up to 2 ms
  on the demo's left camera), so the demo runs sample one scene's errors, not a bias:
  ``scene`` measures them over a whole period of phases, a few seconds each, where a
  demo run takes half a minute of a quiet machine.

Per recording and camera: the estimate, its standard error, the error (ms) and the error
over the standard error. The summary, per camera: the mean error and its standard error
(a bias would show), the errors' RMS (ms); and the RMS and largest |error| / standard
error (about 1 and 2 when the standard error is right).

Run as a script: ``python bench/time_offset.py [--demo-runs N] [--drives N] [--scene-runs N]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from acq.calib.time_offset import estimate_time_offset
from acq.cli import main as acq_main
from acq.motion.trajectory import Trajectory
from acq.sim import demo, sensors
from acq.sim.demo_rig import CAMERAS, SCANNER_MODEL, camera_sim, demo_rig, true_calibration
from acq.sim.mjpeg_server import sim_camera
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import MODELS


def _truth(lines: list[str]) -> dict[str, float]:
    """Each camera's true time_offset_s (ms) from the demo's summary."""
    text = "\n".join(lines)
    out = {}
    for name in CAMERAS:
        m = re.search(rf"{name} frame stamps .*\n +time_offset_s ([-+][\d.]+) ms", text)
        if m is None:
            raise SystemExit(f"the demo's summary has no true time_offset_s for {name}")
        out[name] = float(m.group(1))
    return out


def _estimates(out: Path) -> dict[str, dict[str, Any]]:
    """`acq calibrate time-offset --json` on the demo's log, by camera."""
    argv = ["calibrate", "time-offset", str(out / "demo.mcap"), "--calib",
            str(out / "calib.yaml"), "-o", str(out / "estimated.yaml"), "--json"]  # fmt: skip
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = acq_main(argv)
    if code != 0:
        raise SystemExit(f"acq calibrate time-offset exited {code}")
    report = json.loads(printed.getvalue())
    return {c["camera"]: c for c in report["cameras"]}


def _drive_truth(seed: int, directory: Path) -> tuple[dict[str, float], dict[str, Any]]:
    """A simulated drive's true time_offset_s per camera (ms) and the estimates."""
    from acq.cloud.colorize import Report, estimate_offset, prepare
    from acq.cloud.job import remap
    from acq.sim.drive_log import write_drive_log
    from acq.sim.world import default_rig

    truth = write_drive_log(directory, 4.0, pattern_at=None, seed=seed, rig=default_rig(cameras=2))
    job, whole = prepare(truth.files, truth.calibration, Report(output="x"), jpegs=True)
    scans = remap(job.scan_old, job.scan_new, truth.scan_stamp_ns)
    scan_err = np.mean(scans - (truth.start_ns + truth.scan_t0_s * 1e9))
    true_ms, found = {}, {}
    for cj in job.cameras:
        c = truth.cameras[cj.name]
        frames = remap(cj.frame_old, cj.frame_new, c.frame_stamp_ns)
        frame_err = np.mean(frames - (truth.start_ns + c.frame_t_s * 1e9))
        true_ms[cj.name] = float(frame_err - scan_err) * 1e-6
        est = estimate_offset(job, camera=cj, whole=whole, threads=2)
        found[cj.name] = {"offset_s": est.offset_s, "std_s": est.std_s}
    return true_ms, found


def _scene(runs: int, seconds: float = 10.0) -> list[dict[str, Any]]:
    """The ``scene`` rows (module docstring): each camera's frames rendered once (host
    time 0 the drive's start), then per run the scans from phase ``run / runs`` of the
    scanner's period, their points placed on the true path, and the estimate."""
    model = MODELS[SCANNER_MODEL]
    source = StreetSource(model, rig=demo_rig(), seed=0, t_origin=0.0)
    loop = source.street.length_m / source.trajectory.speed
    t = np.arange(-0.5, seconds + 0.5, 0.001)
    R, p = source.trajectory.poses(t % loop)
    path = Trajectory(np.rint(t * 1e9).astype(np.int64), R, p)
    calib = true_calibration()
    films = {}
    for name in CAMERAS:
        camera = sim_camera(**camera_sim(name), t_origin=0.0)
        frames = [camera.next_frame() for _ in range(int(seconds * camera.fps))]
        films[name] = (np.array([round(f.t_mid * 1e9) for f in frames]), [f.jpeg for f in frames])
    rows = []
    for run in range(runs):
        rng = np.random.default_rng(run)
        points, times, strengths = [], [], []
        for k in range(int(seconds / model.scan_period)):
            t0 = (k + run / runs) * model.scan_period
            scan = sensors.render_scan(source.street, source.trajectory, source.rig, t0 % loop, rng)
            echo = np.isfinite(scan.ranges)
            ray = scan.points[echo] - scan.origins[echo]
            ray /= np.linalg.norm(ray, axis=1, keepdims=True)  # the measured range along it
            points.append(scan.origins[echo] + ray * scan.ranges[echo, None])
            times.append(np.rint((t0 + scan.times[echo] - scan.t0) * 1e9).astype(np.int64))
            ranges = scan.ranges.astype(np.float64)
            strengths.append(sensors.return_strength(ranges, scan.colours)[echo])
        for name, (frame_ns, jpegs) in films.items():
            est = estimate_time_offset(
                np.concatenate(points), np.concatenate(times), np.concatenate(strengths),
                frame_ns, jpegs, calib.cameras[name], calib.laser_to_vehicle, path.pose_at,
                path.covers, max_frames=1500, threads=2,
            )  # fmt: skip
            found = {"offset_s": est.offset_s, "std_s": est.std_s}
            rows.append(_row("scene", run, name, 0.0, found))
            print(json.dumps(rows[-1]), flush=True)
    return rows


def _row(kind: str, run: int, name: str, truth_ms: float, est: dict[str, Any]) -> dict[str, Any]:
    value, se = 1e3 * est["offset_s"], 1e3 * est["std_s"]
    return {
        "kind": kind, "run": run, "camera": name, "truth_ms": round(truth_ms, 3),
        "estimate_ms": round(value, 3), "se_ms": round(se, 3),
        "error_ms": round(value - truth_ms, 3),
        "error_over_se": round((value - truth_ms) / se, 2),
    }  # fmt: skip


def _summary(kind: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    summary: dict[str, Any] = {"kind": kind, "recordings": len({r["run"] for r in rows})}
    for name in CAMERAS:
        e = np.array([r["error_ms"] for r in rows if r["camera"] == name])
        se_mean = float(e.std(ddof=1) / np.sqrt(e.size)) if e.size > 1 else float("nan")
        summary[name] = {
            "mean_error_ms": round(float(e.mean()), 3),
            "se_of_mean_ms": round(se_mean, 3),
            "rms_error_ms": round(float(np.sqrt(np.mean(e**2))), 3),
        }
    z = np.array([r["error_over_se"] for r in rows])
    summary["error_over_se"] = {
        "rms": round(float(np.sqrt(np.mean(z**2))), 2),
        "max_abs": round(float(np.abs(z).max()), 2),
    }
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo-runs", type=int, default=2, help="demo recordings (default 2)")
    parser.add_argument("--drives", type=int, default=10, help="simulated drives (default 10)")
    parser.add_argument(
        "--scene-runs", type=int, default=0,
        help="the demo's scene offline, exact stamps, at N phases of the scanner (default 0)",
    )  # fmt: skip
    args = parser.parse_args()
    kinds: dict[str, list[dict[str, Any]]] = {"demo": [], "drive": [], "scene": []}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.demo_runs):
            out = Path(tmp) / f"demo{run}"
            truth = _truth(demo.run(out, 10.0).lines)
            for name, est in _estimates(out).items():
                kinds["demo"].append(_row("demo", run, name, truth[name], est))
                print(json.dumps(kinds["demo"][-1]), flush=True)
        for seed in range(args.drives):
            true_ms, found = _drive_truth(seed, Path(tmp) / f"drive{seed}")
            for name, est in found.items():
                kinds["drive"].append(_row("drive", seed, name, true_ms[name], est))
                print(json.dumps(kinds["drive"][-1]), flush=True)
    if args.scene_runs:
        kinds["scene"] = _scene(args.scene_runs)
    for kind, rows in kinds.items():
        if rows:
            print(json.dumps({"summary": _summary(kind, rows)}), flush=True)


if __name__ == "__main__":
    main()
