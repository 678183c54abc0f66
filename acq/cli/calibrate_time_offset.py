"""`acq calibrate time-offset`: the camera's time offset from a drive (mutual information of
the frames' grey levels and the laser's return strengths)."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import asdict, replace
from pathlib import Path

from acq import json_text
from acq.cli import output_files
from acq.cli.calibrate_output import FORCE_HELP, same_file
from acq.cli.camera_option import add_camera_option
from acq.cli.colorize import TRAJECTORY_HELP
from acq.cli.option_types import LONGEST_S, integer, real
from acq.cli.output_files import Output
from acq.errors import AcqError

__all__ = ["add_parser", "run_time_offset"]


def add_parser(cal_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`acq calibrate time-offset` under `acq calibrate`."""
    tof = cal_sub.add_parser(
        "time-offset",
        help="the camera's time offset from a drive (the latency its stamps got wrong)",
        description="Estimate the camera's time offset (camera time minus laser time: what "
        "the camera's configured latency got wrong) from a drive: every laser point goes "
        "into the frame nearest its time, motion-compensated, as the rig stood at the "
        "frame's candidate instant, and the offset that makes the image's grey levels there "
        "most informative of the laser's return strengths (mutual information) wins. Needs "
        "the rig moving (CAN odometry in the log or --trajectory), textured surfaces "
        "(facades, road markings) and return strengths in the log (SCIP ME / CoLa RSSI1). "
        "Writes OUT: a copy of CALIB with the camera's time_offset_s, its standard "
        "error (a jackknife over blocks of consecutive frames) and in its method how it "
        "was estimated; an existing OUT is updated (that camera's entry replaced, the others "
        "kept, the old file kept as OUT.bak). An output that is one of the inputs, or an "
        "existing file of another kind, is refused; `--calib C -o C --force` updates C in "
        "place. Every camera of CALIB the log has frames of, or those --camera names; "
        "nothing is written unless every one has its estimate. "
        "Exit status: 0 written, 1 no clear estimate (why is printed), 2 bad input.",
    )
    tof.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files or a folder")
    tof.add_argument(
        "--calib", type=Path, required=True, help="calib.yaml (intrinsics, extrinsics)"
    )
    tof.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT",
        help="calib.yaml to write, or to update (its other cameras kept, the old one as OUT.bak)",
    )  # fmt: skip
    add_camera_option(tof, "a camera to estimate", several=True)
    tof.add_argument(
        "--trajectory", type=Path, metavar="CSV",
        help=f"{TRAJECTORY_HELP} (default: the log's CAN odometry)",
    )  # fmt: skip
    tof.add_argument(
        "--start", type=real(0, LONGEST_S, what="seconds"), metavar="S",
        help="use the log from S seconds after its first scan (default: its middle part)",
    )  # fmt: skip
    tof.add_argument(
        "--seconds", type=real(0, 600, lo_open=True, what="seconds"), default=60.0,
        metavar="S",
        help="how much of the log to use, seconds (default 60)",
    )  # fmt: skip
    tof.add_argument(
        "--search", type=real(0, 1, lo_open=True, what="seconds"), default=0.06, metavar="S",
        help="search CALIB's offset +- S seconds (default 0.06)",
    )  # fmt: skip
    tof.add_argument(
        "--frames", type=integer(1, 10_000), default=1500, metavar="N",
        help="at most N frames, spread over the part used (default 1500)",
    )  # fmt: skip
    tof.add_argument("--json", action="store_true", help="JSON (with the curve) instead of text")
    tof.add_argument("--force", action="store_true", help=FORCE_HELP)
    tof.set_defaults(handler=run_time_offset)


def run_time_offset(args: argparse.Namespace) -> int:
    """0 written; 1 no clear estimate (why is printed); 2 bad input."""
    import numpy as np

    from acq.camera import calibfile
    from acq.camera.calibfile import CalibStd
    from acq.cloud import colorize

    inputs = [("--calib", args.calib), *(("LOG", p) for p in args.logs)]
    if args.trajectory is not None:
        inputs.append(("--trajectory", args.trajectory))
    # an existing OUT other than --calib is updated (merged by camera, NAME.bak kept)
    in_place = same_file(args.output, args.calib)
    target = Output("-o", args.output, "yaml", update=not in_place, in_place_of=("--calib",))
    backups = output_files.check(inputs, [target], force=args.force)
    calib = calibfile.load(args.calib)
    old = None
    if not in_place and args.output.exists():
        old = calibfile.load(args.output, intrinsics_only=True)
        calibfile.merged(old, calib, (), str(args.output))  # another laser's: refused now
    report = colorize.Report(output=str(args.output))
    job, _ = colorize.prepare(
        args.logs, calib, report, camera=args.camera, trajectory=args.trajectory
    )
    for note in report.notes:
        if "laser_to_vehicle" in note:  # the estimate depends on it: said, not buried
            print(f"warning: {note}", file=sys.stderr)
    # a calibration of one camera names it as it likes; several are named as in the log
    keys = [next(iter(calib.cameras))] if len(calib.cameras) == 1 else [c.name for c in job.cameras]
    found = []
    for cj in job.cameras:
        est = colorize.estimate_offset(
            job, camera=cj, start_s=args.start, seconds=args.seconds, search_s=args.search,
            max_frames=args.frames, threads=os.cpu_count() or 1,
        )  # fmt: skip
        found.append(est)
    if args.json:
        reports = []
        for key, cj, est in zip(keys, job.cameras, found, strict=True):
            out = {k: v for k, v in asdict(est).items() if k not in ("candidates_s", "scores")}
            out["curve"] = {"offset_s": est.candidates_s.tolist(), "mi_nats": est.scores.tolist()}
            out["prior_s"] = cj.cam.time_offset_s
            reports.append(out if len(found) == 1 else {"camera": key, **out})
        whole = reports[0] if len(reports) == 1 else {"cameras": reports}
        print(json_text.dumps(whole, what="--json"))
    failed = [f"{k}: {e.note}" for k, e in zip(keys, found, strict=True) if not e.found]
    if failed:  # nothing written unless every camera has its estimate
        notes = [e.note for e in found if not e.found]
        raise AcqError(f"no estimate: {notes[0] if len(found) == 1 else '; '.join(failed)}")
    cams = dict(calib.cameras)
    for key, cj, est in zip(keys, job.cameras, found, strict=True):
        std = cj.cam.std
        if np.isfinite(est.std_s):
            std = std.merged(CalibStd(time_offset_s=est.std_s).rounded(), ("time_offset_s",))
        how = (
            f"estimated from {', '.join(Path(p).name for p in args.logs)} ({est.frames} frames, "
            f"{est.points} laser points; mutual information of grey levels and return strengths)"
        )
        method = calibfile.method_with(cj.cam.method, "time_offset_s", how)
        cams[key] = replace(cj.cam, time_offset_s=round(est.offset_s, 6), std=std, method=method)
    result = replace(calib, cameras=cams)
    if old is not None:
        result = calibfile.merged(old, result, keys, str(args.output))
    output_files.keep_backups("acq calibrate time-offset", backups)
    calibfile.save(result, args.output)
    if not args.json:
        for key, cj, est in zip(keys, job.cameras, found, strict=True):
            print(
                f"camera {key}: time offset {1e3 * est.offset_s:+.2f} ms +- "
                f"{1e3 * est.std_s:.2f} ms (CALIB had {1e3 * cj.cam.time_offset_s:+.2f} ms), "
                f"from {est.points:,} laser points in {est.frames:,} frames; the peak stands "
                f"{100 * est.contrast:.0f} % over the curve's median"
            )
        print(f"wrote {args.output}")
    return 0
