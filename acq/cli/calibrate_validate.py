"""`acq calibrate validate`: the share of laser points on the right colour of the two-depth
validation pattern (paper §4.2)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from acq import json_text
from acq.cli import output_files
from acq.cli.camera_option import add_camera_option
from acq.cli.output_files import Output
from acq.errors import InputError

if TYPE_CHECKING:
    from acq.calib.validate import ValidationResult

__all__ = ["add_parser", "run_validate"]


def add_parser(cal_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`acq calibrate validate` under `acq calibrate`."""
    val = cal_sub.add_parser(
        "validate",
        help="laser points on the right colour of the two-depth pattern (paper §4.2)",
        description="Project the laser points of a still recording of the validation pattern "
        "(two coloured planar sets at different depths: red/green bars in front of a "
        "blue/yellow wall) into the fisheye frames with CALIB, and report the share of points "
        "on their set's colours, the pixel-error histogram (0, 1, 2, 3, >3 px, as the "
        "paper's Table 4) and sigma of a normal fit to the errors at the front set's edges.",
    )
    val.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP file(s) or a folder")
    val.add_argument(
        "--calib", required=True, type=Path, help="calibration (intrinsics + camera_to_laser)"
    )
    add_camera_option(val, "the camera to validate")
    val.add_argument("--json", action="store_true", help="JSON instead of text")
    val.add_argument(
        "-o",
        dest="out",
        type=Path,
        metavar="DIR",
        help="write DIR/validate_overlay.png (replacing an image there, no other file)",
    )
    val.add_argument("--force", action="store_true", help=output_files.FORCE_HELP)
    val.set_defaults(handler=run_validate)


def _validate_lines(res: ValidationResult, name: str) -> list[str]:
    from acq.calib.validate import BINS

    pct = [100.0 * c / res.points if res.points else 0.0 for c in res.histogram]
    lines = [
        f"camera {name!r}: {res.points} laser points on the pattern in {len(res.frames)} frames"
        f" ({res.occluded_beams} back beams hidden from the camera left out)",
        f"  right colour: {100.0 * res.share_right:.2f} %"
        f" (front {res.front[1]}/{res.front[0]}, back {res.back[1]}/{res.back[0]})",
        "  pixel error: " + ", ".join(f"{b} px {p:.2f} %" for b, p in zip(BINS, pct, strict=True)),
        f"  edge error: mean {res.edge_mean_px:+.2f} px, sigma {res.sigma_px:.2f} px"
        f" (normal fit, {res.n_edges} edge crossings)",
    ]
    return lines


def run_validate(args: argparse.Namespace) -> int:
    """The share of laser points on the right colour of the validation pattern, the
    pixel-error histogram and sigma (paper §4.2) for the camera's calibration in CALIB.
    Prints a report (or JSON); with -o writes DIR/validate_overlay.png. 0; 2 bad log or
    calibration file; 1 no pattern found."""
    from acq.calib.validate import validate
    from acq.camera import calibfile
    from acq.log import drive_log

    overlay = args.out / "validate_overlay.png" if args.out is not None else None
    if overlay is not None:
        if args.out.exists() and not args.out.is_dir():
            raise InputError(f"-o {args.out}: is a file; give a folder")
        inputs = [("--calib", args.calib), *(("LOG", p) for p in args.logs)]
        output_files.check(
            inputs, [Output("-o", overlay, "image", makes_folder=True)], force=args.force
        )
    cal = calibfile.load(args.calib)
    log = drive_log.read_log(list(args.logs), camera=args.camera, calib=cal)
    name, cam = drive_log.camera_calib(log, cal, args.camera)
    res = validate(log, cam, overlay=overlay)
    if args.json:
        report = {"camera": name, "logs": [str(p) for p in args.logs], "calib": str(args.calib)}
        report.update(res.to_dict())
        if overlay is not None:
            report["overlay"] = str(overlay)
        print(json_text.dumps(report, what="--json"))
    else:
        print("\n".join(_validate_lines(res, name)))
        if overlay is not None:
            print(f"wrote {overlay}")
    return 0
