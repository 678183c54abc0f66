"""`acq calibrate check` against the truth on simulated drives, one JSON line per drive,
camera and case, then one summary line per case, then (``--speed``) its time against
`acq colorize` on a 60 s drive: each command a new process measured from outside (as a
user runs it: its start and imports counted), alternating, ``--repeat`` times each, the
medians compared.

Each drive: :func:`acq.sim.drive_log.write_drive_log` with the two-camera rig (another
street per seed, ``--seconds`` long, each camera's latency configured right), read once.
Cases: the true calibration (a "moved" there is a false alarm), and camera_to_laser
turned by 0.3, 0.5 and 1 deg about each of the laser's axes and shifted by 1, 2 and 5
cm along each; both cameras changed alike, each checked on its own
(:func:`acq.cloud.colorize.check_calibration`, what `acq calibrate check` runs). Per
row: the verdict, the estimate's error against the true pose (deg, mm) and time offset
(ms; the true one: the re-timed frames' mean error minus the re-timed scans'), the
standard errors; per axis the signed errors and standard errors (``*_xyz``: the laser's
x, y, z; ``err_dir_mm``: the translation's error along the vehicle's forward axis
(along the travel), up, and the camera's optical axis, each in the laser frame). Per
case: how often it said "moved", the errors' median and largest, and per axis the signed
errors' mean and spread (bias against noise).

Run as a script: ``python bench/calib_check.py [--drives N] [--seconds S] [--case NAME]...
[--frames N]... [--fixed-offset] [--true-trajectory] [--work DIR] [--speed [--repeat N]]``
(``--case true --drives 10 --seconds 60``: the false-alarm run) (defaults 2 drives of 20
s: about 5 minutes on 2 cores).
``--frames N`` (repeatable): the check's frames per camera (``acq calibrate check
--frames``; default its 80), each drive checked at each; ``--fixed-offset``: the time
offset held at the true one (not searched), to see what it costs the pose;
``--true-trajectory``: the points placed with the simulator's trajectory instead of the
one the log's CAN odometry gives (what the odometry's errors cost); ``--work DIR``: the
drives kept there (with their truth, pickled) and used again by the next run.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from acq.calib.pose_check import CheckOptions
from acq.calib.pose_search import shifted
from acq.cloud.colorize import Report, check_calibration, prepare
from acq.geometry.rotations import rotation_angle, rotvec_from_matrix
from acq.sim.drive_log import write_drive_log
from acq.sim.world import default_rig

AXES = ("x", "y", "z")


def cases() -> dict[str, np.ndarray]:
    """Case name -> the change (7,) (rad, m) applied to CALIB's camera_to_laser."""
    out = {"true": np.zeros(7)}
    for deg in (0.3, 0.5, 1.0):
        for i, a in enumerate(AXES):
            x = np.zeros(7)
            x[i] = np.radians(deg)
            out[f"rot {deg} deg {a}"] = x
    for cm in (1, 2, 5):
        for i, a in enumerate(AXES):
            x = np.zeros(7)
            x[3 + i] = cm / 100
            out[f"shift {cm} cm {a}"] = x
    return out


def _r(v: np.ndarray, scale: float, nd: int) -> list[float]:
    return [round(scale * float(a), nd) for a in v]


def _drive(
    seed: int, seconds: float, directory: Path, chosen: dict[str, np.ndarray],
    options: list[CheckOptions], true_trajectory: bool = False,
) -> list[dict[str, Any]]:  # fmt: skip
    kept = directory / "truth.pickle"  # the drive written before (--work)
    if kept.exists():
        truth = pickle.loads(kept.read_bytes())
    else:
        truth = write_drive_log(directory, seconds, pattern_at=None, seed=seed,
                                rig=default_rig(cameras=2),
                                configured_camera_latency_s=None)  # fmt: skip
        kept.write_bytes(pickle.dumps(truth))
    given = truth.host_trajectory() if true_trajectory else None
    job, whole = prepare(truth.files, truth.calibration, Report(output="x"), jpegs=True,
                         trajectory=given)  # fmt: skip
    offsets = truth.time_offsets_s(job)
    rows = []
    # the vehicle's forward and up axes in the laser frame
    forward = job.laser_to_vehicle.rotation.T @ np.array([1.0, 0.0, 0.0])
    up = job.laser_to_vehicle.rotation.T @ np.array([0.0, 0.0, 1.0])
    for case, x in chosen.items():
        for cj in job.cameras:
            true = truth.calibration.camera(cj.name)
            cam = replace(true, extrinsics=shifted(true.camera_to_laser, x),
                          time_offset_s=offsets[cj.name])  # fmt: skip
            cj_case = replace(cj, cam=cam)
            job_case = replace(job, cameras=(cj_case,))
            optical = true.camera_to_laser.rotation[:, 2]
            for opt in options:
                t0 = time.perf_counter()
                (c,) = check_calibration(job_case, whole=whole, options=opt)
                row: dict[str, Any] = {"bench": "calib_check", "seed": seed, "camera": cj.name,
                                       "case": case, "max_frames": opt.max_frames,
                                       "blur_px": opt.blur_px,
                                       "fixed_offset": not opt.time_offset,
                                       "verdict": c.verdict, "reason": c.reason,
                                       "seconds": round(time.perf_counter() - t0, 2)}  # fmt: skip
                if c.found:
                    assert c.camera_to_laser is not None
                    R_err = c.camera_to_laser.rotation @ true.camera_to_laser.rotation.T
                    t_err = c.camera_to_laser.translation - true.camera_to_laser.translation
                    row |= {
                        "frames": c.frames,
                        "err_deg": round(float(np.degrees(rotation_angle(R_err))), 3),
                        "err_mm": round(1e3 * float(np.linalg.norm(t_err)), 1),
                        "err_ms": round(1e3 * (c.time_offset_s - offsets[cj.name]), 2),
                        "std_deg": round(float(np.degrees(np.linalg.norm(c.std[:3]))), 3),
                        "std_mm": round(1e3 * float(np.linalg.norm(c.std[3:6])), 1),
                        "std_ms": round(1e3 * float(c.std[6]), 2),
                        "px_at_10m": round(c.px_at_10m, 1),
                        "err_deg_xyz": _r(rotvec_from_matrix(R_err), np.degrees(1.0), 3),
                        "err_mm_xyz": _r(t_err, 1e3, 1),
                        "std_deg_xyz": _r(c.std[:3], np.degrees(1.0), 3),
                        "std_mm_xyz": _r(c.std[3:6], 1e3, 1),
                        "err_dir_mm": {k: round(1e3 * float(t_err @ d), 1) for k, d in
                                       (("along", forward), ("up", up), ("optical", optical))},
                    }  # fmt: skip
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def summary(rows: list[dict[str, Any]], chosen: dict[str, np.ndarray]) -> list[dict[str, Any]]:
    """Per case (and frames, offset held or not): the share said "moved" (a false alarm
    for "true"), the errors; per axis the signed errors' mean and spread."""
    out = []
    settings = sorted({(r["max_frames"], r["fixed_offset"]) for r in rows})
    for case in chosen:
        for frames, fixed in settings:
            mine = [r for r in rows if r["case"] == case and r["max_frames"] == frames
                    and r["fixed_offset"] == fixed]  # fmt: skip
            found = [r for r in mine if "err_deg" in r]
            s: dict[str, Any] = {"bench": "calib_check", "case": case, "max_frames": frames,
                                 "fixed_offset": fixed, "runs": len(mine),
                                 "moved": sum(r["verdict"] == "moved" for r in mine),
                                 "cannot_tell": sum(r["verdict"] == "cannot tell"
                                                    for r in mine)}  # fmt: skip
            for key in ("err_deg", "err_mm", "err_ms", "std_deg", "std_mm", "seconds"):
                v = np.abs([r[key] for r in found])
                if v.size:
                    s[f"{key}_median"] = round(float(np.median(v)), 3)
                    s[f"{key}_max"] = round(float(v.max()), 3)
            for key in ("err_deg_xyz", "err_mm_xyz"):
                v = np.array([r[key] for r in found])
                if len(v) > 1:
                    s[f"{key}_mean"] = _r(v.mean(axis=0), 1.0, 3)
                    s[f"{key}_sd"] = _r(v.std(axis=0, ddof=1), 1.0, 3)
            # along the travel, up and the optical axis (a bias there is each camera's own)
            if len(found) > 1:
                names = list(found[0]["err_dir_mm"])
                d = np.array([[r["err_dir_mm"][k] for k in names] for r in found])
                for stat, v in (("mean", d.mean(axis=0)), ("sd", d.std(axis=0, ddof=1))):
                    s[f"err_dir_mm_{stat}"] = dict(zip(names, _r(v, 1.0, 2), strict=True))
            out.append(s)
            print(json.dumps(s), flush=True)
    return out


def speed(work: Path, seconds: float = 60.0, repeat: int = 3) -> dict[str, Any]:
    """`acq calibrate check` and `acq colorize` on the same two-camera drive of
    ``seconds`` (``colorize_speed``'s, the rig ``acq demo`` records), each a new process
    measured from outside as a user runs it, alternating, ``repeat`` times each: a
    ``calib_check_run`` line per process, then the medians (wall s, peak MB, CPU s)."""
    from colorize_speed import drive, measured  # this folder: run as a script

    files, calib, _ = drive(work, seconds)
    logs = [str(f) for f in files]
    acq = [sys.executable, "-m", "acq.cli"]
    commands = {
        "check": [*acq, "calibrate", "check", *logs, "--calib", str(calib)],
        "colorize": [*acq, "colorize", *logs, "--calib", str(calib), "-o",
                     str(work / "speed.ply"), "--force"],
    }  # fmt: skip
    runs: dict[str, list[tuple[float, float, float]]] = {k: [] for k in commands}
    for k in range(repeat):
        for name in list(commands)[:: 1 if k % 2 == 0 else -1]:
            wall, peak, cpu, _ = measured(commands[name])
            runs[name].append((wall, peak, cpu))
            print(json.dumps({"bench": "calib_check_run", "command": name,
                              "wall_s": round(wall, 3), "peak_mb": round(peak, 1),
                              "cpu_s": round(cpu, 3),
                              "load": [round(x, 2) for x in os.getloadavg()]}),
                  flush=True)  # fmt: skip
    med = {k: [statistics.median(c) for c in zip(*r, strict=True)] for k, r in runs.items()}
    row = {"bench": "calib_check_speed", "drive_s": seconds, "runs": repeat,
           "check_s": round(med["check"][0], 2), "colorize_s": round(med["colorize"][0], 2),
           "check_peak_mb": round(med["check"][1], 1),
           "colorize_peak_mb": round(med["colorize"][1], 1),
           "check_cpu_s": round(med["check"][2], 2), "colorize_cpu_s": round(med["colorize"][2], 2),
           "target_met": med["check"][0] <= med["colorize"][0]}  # fmt: skip
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drives", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--speed", action="store_true", help="also time it against acq colorize")
    ap.add_argument("--repeat", type=int, default=3,
                    help="--speed: runs of each command, alternating (3)")  # fmt: skip
    ap.add_argument("--work", type=Path,
                    help="keep the drives here, and use those already there (default: a "
                         "temporary folder)")  # fmt: skip
    ap.add_argument("--case", action="append", metavar="NAME", help="only this case (repeatable)")
    ap.add_argument("--frames", type=int, action="append", metavar="N",
                    help="the check's frames per camera (repeatable; default 80)")  # fmt: skip
    ap.add_argument("--blur", type=float, metavar="PX",
                    help="the check's blur of the images (px; default its own)")  # fmt: skip
    ap.add_argument("--fixed-offset", action="store_true",
                    help="hold the time offset at the true one (not searched)")  # fmt: skip
    ap.add_argument("--true-trajectory", action="store_true",
                    help="place the points with the true trajectory (not odometry)")  # fmt: skip
    args = ap.parse_args()
    base = CheckOptions(time_offset=not args.fixed_offset)
    if args.blur is not None:
        base = replace(base, blur_px=args.blur)
    options = [replace(base, max_frames=n) for n in args.frames or [base.max_frames]]
    chosen = {k: v for k, v in cases().items() if not args.case or k in args.case}
    if args.case and len(chosen) != len(set(args.case)):
        ap.error(f"--case: unknown case among {args.case}; the cases: {', '.join(cases())}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        for seed in range(args.drives):
            rows += _drive(seed, args.seconds, work / f"drive_{seed}_{args.seconds:g}s", chosen,
                           options, args.true_trajectory)  # fmt: skip
        summary(rows, chosen)
        if args.speed:
            speed(work, repeat=args.repeat)


if __name__ == "__main__":
    main()
