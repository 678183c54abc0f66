"""`acq calibrate check`: whether each camera's calibration still holds on a drive, from
the drive itself (no target): :mod:`acq.calib.pose_check`."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from acq import json_text
from acq.cli import output_files
from acq.cli.calibrate_output import FORCE_HELP
from acq.cli.camera_option import add_camera_option
from acq.cli.colorize import TRAJECTORY_HELP
from acq.cli.option_types import LONGEST_S, integer, real
from acq.cli.output_files import Output
from acq.errors import AcqError

if TYPE_CHECKING:
    from acq.calib.pose_check import PoseCheck
    from acq.camera.calibfile import CameraCalib

__all__ = ["add_parser", "run_check"]


def add_parser(cal_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`acq calibrate check` under `acq calibrate`."""
    chk = cal_sub.add_parser(
        "check",
        help="whether the cameras' calibration still holds, from an ordinary drive",
        description="Check each camera's calibration on an ordinary drive (no target): "
        "the pose (camera_to_laser) and time offset that best align the laser's swath, "
        "placed with the drive's trajectory, with the frames (mutual information of "
        "return strengths and grey levels, and of the laser's depth edges and the "
        "images' gradients), standard errors from disjoint blocks of frames, and a "
        "verdict: the calibration holds (the estimate within its uncertainty of CALIB's), "
        "it moved (by how much in degrees, mm and ms, and in pixels at 10 m), or the "
        "drive cannot tell (too little motion, texture or return strength; why is "
        "printed). Needs the rig moving (CAN odometry in the log or --trajectory) and "
        "return strengths in the log (SCIP ME / CoLa RSSI1). --write OUT writes CALIB "
        "with each camera's estimate and its standard errors (never over CALIB or another "
        "existing YAML without --force). Exit status: 0 a verdict for every camera (holds "
        "or moved), 1 a camera the drive cannot tell (nothing written), 2 bad input.",
    )
    chk.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files or a folder")
    chk.add_argument(
        "--calib", type=Path, required=True, help="calib.yaml (intrinsics, extrinsics)"
    )
    add_camera_option(chk, "a camera to check", several=True)
    chk.add_argument(
        "--write", type=Path, metavar="OUT",
        help="write CALIB with the estimated poses and time offsets to OUT",
    )  # fmt: skip
    chk.add_argument("--force", action="store_true", help=FORCE_HELP)
    chk.add_argument(
        "--trajectory", type=Path, metavar="CSV",
        help=f"{TRAJECTORY_HELP} (default: the log's CAN odometry)",
    )  # fmt: skip
    chk.add_argument(
        "--start", type=real(0, LONGEST_S, what="seconds"), metavar="S",
        help="use the log from S seconds after its first scan (default: its middle part)",
    )  # fmt: skip
    chk.add_argument(
        "--seconds", type=real(0, 600, lo_open=True, what="seconds"), default=60.0,
        metavar="S", help="how much of the log to use, seconds (default 60)",
    )  # fmt: skip
    chk.add_argument(
        "--frames", type=integer(8, 2000), default=80, metavar="N",
        help="at most N frames per camera, spread over the part used (default 80)",
    )  # fmt: skip
    chk.add_argument("--json", action="store_true", help="JSON instead of text")
    chk.set_defaults(handler=run_check)


def _refined(cam: CameraCalib, c: PoseCheck, logs: list[Path]) -> CameraCalib:
    """``cam`` with the check's estimate, its standard errors and how it was made."""
    import numpy as np

    from acq.camera import calibfile
    from acq.camera.calibfile import CalibStd

    std = CalibStd(
        rotation_deg=tuple(np.degrees(c.std[:3]).tolist()),
        translation_m=tuple(c.std[3:6].tolist()),
        time_offset_s=float(c.std[6]),
    ).rounded()
    how = (
        f"acq calibrate check on {', '.join(p.name for p in logs)} ({c.frames} frames, "
        f"{c.points} laser points; mutual information of the swath and the frames)"
    )
    method = calibfile.method_with(cam.method, "camera_to_laser", how)
    return replace(
        cam, extrinsics=c.camera_to_laser, time_offset_s=round(c.time_offset_s, 6),
        std=cam.std.merged(std, ("rotation_deg", "translation_m", "time_offset_s")),
        method=method,
    )  # fmt: skip


def run_check(args: argparse.Namespace) -> int:
    """0 a verdict for every camera; 1 a camera the drive cannot tell; 2 bad input."""
    from acq.calib.pose_check import CheckOptions
    from acq.camera import calibfile
    from acq.cloud import colorize

    inputs = [("--calib", args.calib), *(("LOG", p) for p in args.logs)]
    if args.trajectory is not None:
        inputs.append(("--trajectory", args.trajectory))
    targets = []
    if args.write is not None:
        targets.append(Output("--write", args.write, "yaml", in_place_of=("--calib",)))
    backups = output_files.check(inputs, targets, force=args.force)
    calib = calibfile.load(args.calib)
    job, report, checks = colorize.check_drive(
        args.logs, calib, camera=args.camera, trajectory=args.trajectory, start_s=args.start,
        seconds=args.seconds,
        options=CheckOptions(max_frames=args.frames, threads=os.cpu_count() or 1),
    )  # fmt: skip
    for note in report.notes:
        if "laser_to_vehicle" in note:  # the check depends on it: said, not buried
            print(f"warning: {note}", file=sys.stderr)
    if not job.cameras:
        raise AcqError("the log has no frames of the calibration's cameras")
    keys = [next(iter(calib.cameras))] if len(calib.cameras) == 1 else [c.name for c in job.cameras]
    if args.json:
        out = [{"camera": k, **c.to_dict()} for k, c in zip(keys, checks, strict=True)]
        print(json_text.dumps(out[0] if len(out) == 1 else {"cameras": out}, what="--json"))
    else:
        for k, c in zip(keys, checks, strict=True):
            print(c.line(k))
    if any(not c.found or c.verdict == "cannot tell" for c in checks):
        if args.write is not None:
            print(f"acq calibrate check: nothing written to {args.write}", file=sys.stderr)
        return 1
    if args.write is not None:
        cams = dict(calib.cameras)
        for k, cj, c in zip(keys, job.cameras, checks, strict=True):
            cams[k] = _refined(cj.cam, c, args.logs)
        output_files.keep_backups("acq calibrate check", backups)
        calibfile.save(replace(calib, cameras=cams), args.write)
        if not args.json:
            print(f"wrote {args.write}")
    return 0
