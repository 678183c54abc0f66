"""`acq calibrate extrinsic`: each camera's camera_to_laser from the checkerboard poses of
a recording (paper §3.2)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from acq import json_text
from acq.cli import output_files
from acq.cli.calibrate_output import FORCE_HELP, same_file
from acq.cli.camera_option import add_camera_option
from acq.cli.option_types import real
from acq.cli.output_files import IMAGE_SUFFIXES, Output
from acq.errors import AcqError, InputError

if TYPE_CHECKING:
    from acq.calib.board_pose import BoardPose
    from acq.calib.checkerboard import BoardSpec
    from acq.calib.extrinsic import ExtrinsicResult
    from acq.calib.extrinsic_log import PoseData
    from acq.camera.calibfile import Calibration, CameraCalib
    from acq.log.drive_log import DriveLog

__all__ = ["add_parser", "run_extrinsic"]


def add_parser(cal_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`acq calibrate extrinsic` under `acq calibrate`."""
    ext = cal_sub.add_parser(
        "extrinsic",
        help="camera-laser transform from checkerboard poses in a log (paper §3.2)",
        description="Find the still board poses in LOG (or --poses), the board's corners in a "
        "frame of each (in the fisheye image itself: a lens swap, as the paper does, moves the "
        "projection centre along the optical axis) and its laser line, and fit camera_to_laser "
        "(Zhang & Pless: linear solution, then robust Levenberg-Marquardt on point-to-plane "
        "distances). Several cameras of one rig, each seeing the board in its own poses of one "
        "recording, are calibrated in one call (each one's frames, the same laser), and "
        "their relative poses (camera A -> camera B) are printed as the rig's consistency "
        "check. Writes CALIB: a copy of --intrinsics with each camera's camera_to_laser "
        "set, and a residual plot PNG per camera (NAME_extrinsic_CAMERA.png with several). "
        "An existing CALIB is updated: the cameras calibrated now replaced, every other "
        "camera's entry kept, the old file kept as CALIB.bak. An output that is one of the "
        "inputs, or an existing file of another kind, is refused; `--intrinsics C -o C "
        "--force` updates C in place; an existing image replaced only when acq wrote it, or "
        "with --force. Nothing is written when any camera fails.",
    )
    ext.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="the recording's MCAP file(s) or folder"
    )
    add_camera_option(ext, "a camera to calibrate", several=True)
    ext.add_argument(
        "--intrinsics", type=Path, required=True, metavar="CALIB",
        help="calib.yaml with the camera's intrinsics (a non-identity camera_to_laser is used "
        "as a coarse guess to pick the board's laser segment)",
    )  # fmt: skip
    ext.add_argument(
        "--board", required=True, metavar="COLSxROWSxSQUARE",
        help="inner corners and square side in metres, e.g. 9x7x0.1",
    )  # fmt: skip
    ext.add_argument(
        "-o", "--output", type=Path, required=True, metavar="CALIB",
        help="calib.yaml to write, or to update (its other cameras kept, the old one as "
        "CALIB.bak)",
    )  # fmt: skip
    ext.add_argument(
        "--poses", metavar="START:END,...",
        help="still intervals in seconds from the log's first scan (default: detected)",
    )  # fmt: skip
    ext.add_argument("--json", action="store_true", help="JSON instead of text")
    ext.add_argument(
        "--plot", type=Path, metavar="PNG", help="residual plot (default: beside CALIB)"
    )
    ext.add_argument(
        "--lens-swap", type=Path, metavar="FISHEYE_CALIB",
        help="the paper's way: LOG was recorded with a regular lens on the camera, which "
        "--intrinsics describes (model: pinhole), and the fisheye is mounted afterwards; "
        "write the result into a copy of FISHEYE_CALIB (the fisheye's intrinsics). CAVEAT: "
        "swapping lenses moves the projection centre along the optical axis (the lenses' "
        "entrance pupils differ, typically by millimetres to centimetres); u0, v0 cannot "
        "absorb that, so it goes into the translation unless --pupil-shift gives it. The "
        "default (no lens swap, the fisheye seeing the board) has no such error",
    )  # fmt: skip
    ext.add_argument(
        "--pupil-shift", type=real(-1, 1, what="metres"), default=0.0, metavar="M",
        help="with --lens-swap: the fisheye's projection centre minus the regular lens's, "
        "along the optical axis, metres, + towards the scene (default 0, the paper's "
        "assumption)",
    )  # fmt: skip
    ext.add_argument("--force", action="store_true", help=FORCE_HELP)
    ext.set_defaults(handler=run_extrinsic)


def _extrinsic_lines(
    result: ExtrinsicResult, data: list[PoseData], t0: int, method: str
) -> list[str]:
    import numpy as np

    T = result.camera_to_laser
    d = result.to_dict()
    lines = [
        f"camera_to_laser (P_laser = R P_camera + t), {method}:",
        "  R = " + np.array2string(T.rotation, precision=6, prefix="      "),
        "  t = " + np.array2string(T.translation, precision=4) + " m",
        "  rpy = " + ", ".join(f"{x:.3f}" for x in d["rpy_deg"]) + " deg",
        "  std rotation " + ", ".join(f"{x:.3f}" for x in result.std_rot_deg) + " deg,"
        " translation "
        + ", ".join(f"{x:.1f}" for x in result.std_t_mm)
        + " mm"
        + _spread_note(result),
        f"  RMS {result.rms_m * 1e3:.2f} mm over {result.n_points} points,"
        f" {len(result.residuals_per_pose) - len(result.outliers)} poses kept",
        "poses:",
    ]
    k = 0
    for p in data:
        where = f"  {(p.start_ns - t0) * 1e-9:7.2f}-{(p.end_ns - t0) * 1e-9:7.2f} s"
        if p.pose is None:
            lines.append(f"{where}: skipped ({p.problem})")
            continue
        res = result.residuals_per_pose[k] * 1e3
        flag = "  OUTLIER, dropped" if k in result.outliers else ""
        lines.append(
            f"{where}: {len(p.pose.points)} laser points, corners {p.rms_px:.2f} px"
            f" ({p.frames} frames),"
            f" residual {res:.2f} mm{flag}"
        )
        k += 1
    return lines


def _spread_note(result: ExtrinsicResult) -> str:
    """When the poses' spread widened the std: by how much, and what it means."""
    import numpy as np

    model, spread = result.std_model, result.std_spread
    if model is None or spread is None or not np.isfinite(spread).all():
        return ""
    ratio = float(np.max(spread / np.maximum(model, 1e-300)))
    if ratio <= 1.0:
        return ""
    return (
        f" (the poses' spread, up to {ratio:.1f}x the fit's model: errors a board's points share)"
    )


def _plots(plot: Path | None, output: Path, names: list[str]) -> dict[str, Path]:
    """Each camera's residual plot: --plot (default beside CALIB, NAME_extrinsic.png);
    with several cameras the camera's name added to the file's."""
    base = plot if plot is not None else output.with_name(output.stem + "_extrinsic.png")
    if len(names) <= 1:
        return {n: base for n in names}
    return {n: base.with_name(f"{base.stem}_{n}{base.suffix}") for n in names}


@dataclass
class _Calibrated:
    """One camera's extrinsic calibration: its log (frames of that camera), poses,
    result, entry for the file and plot."""

    name: str
    t0: int
    data: list[PoseData]
    good: list[BoardPose]
    result: ExtrinsicResult
    entry: CameraCalib
    plot: Path


def _calibrate_one(
    args: argparse.Namespace,
    log: DriveLog,
    name: str,
    calib: Calibration,
    target: Calibration,
    spec: BoardSpec,
    plots: dict[str, Path],
    several: bool,
) -> _Calibrated:
    """The calibration of ``log``'s camera, ``name`` in ``calib``, from the logs."""
    import numpy as np

    from acq.calib.extrinsic import calibrate
    from acq.calib.extrinsic_log import (
        METHOD,
        NOT_IN_IMAGE,
        board_size_hint,
        parse_poses,
        poses_from_log,
        still_intervals,
    )
    from acq.camera import calibfile
    from acq.camera.calibfile import CalibStd, CameraCalib
    from acq.geometry.transforms import Rigid

    cam = calib.cameras[name]
    target_cam = cam
    if args.lens_swap is not None:
        try:
            target_cam = target.camera(name)
        except calibfile.UnknownCameraError as e:
            raise InputError(f"--lens-swap {args.lens_swap}: {e}") from None
    t0 = int(log.scan_ns[0])
    intervals = parse_poses(args.poses, t0) if args.poses else still_intervals(log)
    coarse = cam.extrinsics
    if coarse is not None and np.allclose(coarse.rotation, np.eye(3)):
        coarse = None
    data = poses_from_log(log, cam.model, spec, intervals, coarse=coarse)
    good = [p.pose for p in data if p.pose is not None]
    try:
        result = calibrate(good)
    except ValueError as e:  # too few or degenerate poses
        who = f"camera {name!r}: " if several else ""
        unseen = [(p.start_ns, p.end_ns) for p in data if p.problem == NOT_IN_IMAGE]
        hint = board_size_hint(log, cam.model, unseen, spec) if unseen else ""
        found = f"{e} ({len(good)} usable of {len(intervals)} still poses found)"
        if hint:  # a board of another size found: --board is wrong
            raise InputError(f"{who}--board {args.board}: {found}{hint}") from e
        raise AcqError(f"{who}{found}") from e
    std = CalibStd(  # about the laser axes (rad -> deg), m; the intrinsics' std kept
        rotation_deg=tuple(np.degrees(result.std[:3])), translation_m=tuple(result.std[3:])
    ).rounded()
    std = target_cam.std.merged(std, CalibStd.EXTRINSICS)
    T, method = result.camera_to_laser, METHOD
    if args.lens_swap is not None:
        T = Rigid(T.rotation, T.translation + T.rotation @ np.array([0.0, 0.0, args.pupil_shift]))
        method = f"{METHOD}+lens_swap"
    entry = CameraCalib(target_cam.model, T, target_cam.time_offset_s, method, std, target_cam.note)
    plot = plots.get(name) or next(iter(plots.values()))
    return _Calibrated(name, t0, data, good, result, entry, plot)


def run_extrinsic(args: argparse.Namespace) -> int:
    """Write each camera's camera_to_laser, calibrated from the board poses in the logs,
    into CALIB (a copy of --intrinsics with them set, merged into an existing CALIB).

    Cameras: each --camera given (repeatable); none given: every camera of both the
    logs and --intrinsics (:func:`acq.camera.selection.choose_cameras`).

    --lens-swap (the paper's way): the logs were recorded with a regular lens that
    --intrinsics describes, and the fisheye was mounted afterwards; CALIB is then a copy
    of FISHEYE_CALIB with the camera's camera_to_laser set, its origin moved
    --pupil-shift along the optical axis (the fisheye's projection centre minus the
    regular lens's, m, + towards the scene; 0 is the paper's tacit assumption, and its
    error goes into the translation).

    Prints the result (or JSON) and, with two cameras or more in CALIB, their relative
    poses; writes the residual plot PNG of each camera (default: beside CALIB). 0; 2 bad
    input (board, log, camera, calibration file, --poses); 1 when a camera's calibration
    cannot be made (too few usable or degenerate poses): then nothing is written."""
    from acq.calib.checkerboard import parse_board
    from acq.calib.extrinsic_log import METHOD
    from acq.calib.plots import residual_plot
    from acq.calib.relative_pose import relative_poses
    from acq.camera import calibfile
    from acq.camera.calibfile import Calibration
    from acq.camera.selection import choose_cameras, named_once
    from acq.log import drive_log

    logs, intrinsics, board, output = args.logs, args.intrinsics, args.board, args.output
    lens_swap = args.lens_swap
    inputs = [("--intrinsics", intrinsics), *(("LOG", p) for p in logs)]
    if lens_swap is not None:
        inputs.append(("--lens-swap", lens_swap))
    # an existing CALIB other than the input is updated (merged by camera, NAME.bak kept)
    in_place = same_file(output, intrinsics) or same_file(output, lens_swap)
    yaml_out = Output(
        "-o", output, "yaml", update=not in_place, in_place_of=("--intrinsics", "--lens-swap")
    )
    asked = named_once(args.camera) if args.camera else None
    first_plots = _plots(args.plot, output, asked or ["camera"])
    for p in first_plots.values():
        if p.suffix.lower() not in IMAGE_SUFFIXES:
            raise InputError(f"--plot {p}: expected a .png or .jpg file")
    outputs = [yaml_out, *(Output("--plot", p, "image") for p in first_plots.values())]
    backups = output_files.check(inputs, outputs, force=args.force)
    spec = parse_board(board)
    calib = calibfile.load(intrinsics, intrinsics_only=True)
    target = calib if lens_swap is None else calibfile.load(lens_swap, intrinsics_only=True)
    old = None if in_place or not output.exists() else calibfile.load(output, intrinsics_only=True)
    if old is not None:
        calibfile.merged(old, target, (), str(output))  # another laser's: refused before the work
    log = drive_log.read_log(list(logs), cameras=asked or [], calib=calib)
    picked = choose_cameras(asked, log.camera_names, list(calib.cameras), one=False,
                            calib=calib.label)  # fmt: skip
    if len(picked) > 1 and asked is None:
        plots = _plots(args.plot, output, [key for _, key in picked])
        outputs = [yaml_out, *(Output("--plot", p, "image") for p in plots.values())]
        backups = output_files.check(inputs, outputs, force=args.force)
    else:
        plots = first_plots
    done = [
        _calibrate_one(
            args, log.with_camera(name), key, calib, target, spec, plots, len(picked) > 1
        )
        for name, key in picked
    ]
    entries = {c.name: c.entry for c in done}
    out = Calibration(target.laser, {**target.cameras, **entries}, target.laser_to_vehicle)
    if old is not None:
        out = calibfile.merged(old, out, list(entries), str(output))
    placed = {n: c.extrinsics for n, c in out.cameras.items() if c.extrinsics is not None}
    relative = relative_poses(placed, {n: out.cameras[n].std for n in placed})
    output_files.keep_backups("acq calibrate extrinsic", backups)
    calibfile.save(out, output)
    for c in done:  # whole or not at all (acq.provenance.write_image)
        residual_plot(c.result, c.good, c.plot)
    if args.json:
        reports = [_extrinsic_report(args, c) for c in done]
        report: dict[str, Any] = reports[0] if len(reports) == 1 else {
            "cameras": reports, "logs": [str(p) for p in logs], "board": board,
            "output": str(output),
        }  # fmt: skip
        if relative:
            report["relative"] = [r.to_dict() for r in relative]
        print(json_text.dumps(report, what="--json"))
    else:
        for c in done:
            if len(done) > 1:
                print(f"camera {c.name!r}:")
            print("\n".join(_extrinsic_lines(c.result, c.data, c.t0, METHOD)))
            if lens_swap is not None:
                print(
                    f"lens swap: found with the regular lens of {intrinsics}, written with the "
                    f"fisheye model of {lens_swap}, origin moved {args.pupil_shift * 1e3:.1f} "
                    "mm along the optical axis (--pupil-shift; the swap's unknown shift is in t)"
                )
        if relative:
            print(f"relative poses of the cameras in {output} (camera A -> camera B):")
            print("\n".join(r.line() for r in relative))
        cams = ", ".join(repr(c.name) for c in done)
        plots_written = ", ".join(str(c.plot) for c in done)
        print(f"wrote {output} (camera{'s' if len(done) > 1 else ''} {cams}) and {plots_written}")
    return 0


def _extrinsic_report(args: argparse.Namespace, c: _Calibrated) -> dict[str, Any]:
    """One camera's JSON report."""
    report = {
        "camera": c.name,
        "logs": [str(p) for p in args.logs],
        "board": args.board,
        "output": str(args.output),
        "plot": str(c.plot),
        "poses": [p.to_dict(c.t0) for p in c.data],
        **c.result.to_dict(),
    }
    if args.lens_swap is not None:
        report["lens_swap"] = {
            "fisheye": str(args.lens_swap),
            "pupil_shift_m": args.pupil_shift,
            "camera_to_laser": c.entry.camera_to_laser.to_dict(),
        }
    return report
