"""`acq calibrate fisheye|extrinsic|time-offset|validate`: the rig's calibration
(paper §3.2, §3.3.2, §4.2) and the camera's time offset."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from acq.cli import output_files
from acq.cli.camera_option import add_camera_option
from acq.cli.colorize import TRAJECTORY_HELP
from acq.cli.option_types import LONGEST_S, integer, real
from acq.cli.output_files import IMAGE_SUFFIXES, Output
from acq.errors import AcqError, InputError, InputValueError

if TYPE_CHECKING:
    from acq.calib.board_pose import BoardPose
    from acq.calib.extrinsic import ExtrinsicResult
    from acq.calib.extrinsic_log import PoseData
    from acq.calib.fisheye_calib import BoardSpec
    from acq.calib.image_circle import CircleResult
    from acq.calib.validate import ValidationResult
    from acq.camera.calibfile import Calibration, CameraCalib
    from acq.camera.camera_models import KannalaBrandt
    from acq.log.drive_log import DriveLog

HELP = "calibrate the rig's sensors"
FORCE_HELP = (
    "replace an existing output YAML (or update the input one in place), keeping NAME.bak, "
    "and outputs that acq did not write"
)


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    cal = sub.add_parser("calibrate", help=HELP)
    cal_sub = cal.add_subparsers(dest="calibrate_command", metavar="WHAT", required=True)
    fish = cal_sub.add_parser(
        "fisheye",
        help="fisheye intrinsics from the image circle (paper §3.3.2)",
        description="Find the image circle of a fisheye camera in one or more of its images "
        "(any scene): barycentre of the non-black pixels, least-squares circle on Canny edges, "
        "Hough circle, and a sub-pixel fit of the rim along rays (the one used). Works on "
        "circles cut by the sensor edges. Writes u0, v0 = the centre and f = r / theta_max "
        "(theta_max = fov / 2) into the camera's entry of CALIB (equidistant model; the rest "
        "of an existing file is kept), and an overlay PNG. That f rests on --fov and on an "
        "equidistant lens, which the circle cannot check: the result and the camera's note in "
        "CALIB say so, with f for an aperture 5 degrees off. With --board, also fits the "
        "Kannala-Brandt model (k1..k4) to a checkerboard in the images and writes that instead, "
        "saying how far the circle's f is from it and how much of that the aperture explains. "
        "An existing CALIB is updated, its old content kept as CALIB.bak; an IMAGE or any file "
        "that is not YAML is refused as CALIB.",
    )
    fish.add_argument("images", nargs="+", type=Path, metavar="IMAGE", help="images of one camera")
    fish.add_argument(
        "--fov", type=real(0, 360, lo_open=True, hi_open=True, what="degrees"),
        required=True, metavar="DEG",
        help="the lens's full aperture in degrees, from its data sheet (e.g. 185)",
    )  # fmt: skip
    add_camera_option(
        fish,
        "the entry of CALIB to write",
        default="CALIB's only camera, or 'camera' in a new file",
    )
    fish.add_argument(
        "-o", "--output", type=Path, required=True, metavar="CALIB",
        help="calib.yaml to create or update (the old one kept as CALIB.bak)",
    )  # fmt: skip
    fish.add_argument(
        "--ellipse", action="store_true",
        help="non-square pixels: fit an axis-aligned ellipse "
        "(fx = rx / theta_max, fy = ry / theta_max)",
    )  # fmt: skip
    fish.add_argument("--json", action="store_true", help="JSON instead of text")
    fish.add_argument(
        "--overlay", type=Path, metavar="PNG",
        help="where to draw the circles on the first image (default: CALIB's name + _circle.png)",
    )  # fmt: skip
    fish.add_argument(
        "--board", metavar="COLSxROWSxSQUARE",
        help="also fit Kannala-Brandt to this checkerboard (inner corners, square in metres, "
        "e.g. 8x6x0.117), starting from the circle",
    )  # fmt: skip
    fish.add_argument("--force", action="store_true", help=output_files.FORCE_HELP)
    fish.set_defaults(handler=run_fisheye)

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


# --- fisheye ------------------------------------------------------------------------------


def _circle_lines(
    result: CircleResult, model: KannalaBrandt, fov_deg: float, n_images: int
) -> list[str]:
    c = result.circle
    th = math.radians(fov_deg) / 2
    lines = [
        f"image circle from {n_images} image(s), {result.rays.get('inliers', 0)} rim points: "
        f"centre ({c.cx:.2f}, {c.cy:.2f}) px, radius {c.radius:.2f} px"
        + (f" (rx {c.rx:.2f}, ry {c.ry:.2f})" if c.rx != c.ry else ""),
    ]
    for name, e in result.estimates.items():
        note = f"  [{'; '.join(e.notes)}]" if e.notes else ""
        lines.append(
            f"  {name:<11} centre ({e.circle.cx:8.2f}, {e.circle.cy:8.2f})  "
            f"radius {e.circle.radius:7.2f}{note}"
        )
    off = max(result.spread_centre_px, result.spread_radius_px) > 1.5
    lines.append(
        f"  spread      centre {result.spread_centre_px:.2f} px, "
        f"radius {result.spread_radius_px:.2f} px over {', '.join(e.name for e in result.unbiased)}"
        + ("; the notes and warnings say why a fit is off" if off else "")
    )
    if model.fx == model.fy:
        lines.append(
            f"f = r / theta_max = {c.radius:.2f} / {th:.4f} rad = {model.fx:.2f} px/rad "
            f"(fov {fov_deg:g} deg); u0 {model.cx:.2f}, v0 {model.cy:.2f}"
        )
    else:
        lines.append(
            f"fx = {model.fx:.2f}, fy = {model.fy:.2f} px/rad (fov {fov_deg:g} deg); "
            f"u0 {model.cx:.2f}, v0 {model.cy:.2f}"
        )
    return lines


def run_fisheye(args: argparse.Namespace) -> int:
    """Write the camera's intrinsics from its image circle (and, with --board, a
    Kannala-Brandt checkerboard fit) into CALIB; print a summary (or JSON), write the
    overlay PNG (default: beside CALIB). 0; 2 bad input; 1 nothing found."""

    from acq.calib import image_circle
    from acq.calib.fisheye_calib import (
        METHOD_BOARD,
        METHOD_CIRCLE,
        calibrate_board,
        circle_assumptions,
        circle_check,
        circle_model,
        parse_board,
        read_images,
        update_calibration,
    )
    from acq.calib.plots import draw_overlay
    from acq.camera import calibfile
    from acq.provenance import write_image

    images, fov_deg, output = args.images, args.fov, args.output
    overlay = args.overlay or output.with_name(output.stem + "_circle.png")
    if overlay.suffix.lower() not in IMAGE_SUFFIXES:
        raise InputError(f"--overlay {overlay}: expected a .png or .jpg file")
    outputs = [Output("-o", output, "yaml", update=True), Output("--overlay", overlay, "image")]
    backups = output_files.check([("IMAGE", p) for p in images], outputs, force=args.force)
    spec = parse_board(args.board) if args.board else None
    imgs = read_images(images)
    try:
        result = image_circle.detect(imgs, ellipse=args.ellipse, names=list(map(str, images)))
        model: KannalaBrandt = circle_model(result, fov_deg)
    except ValueError as e:  # no circle in these images
        raise AcqError(str(e)) from e
    report: dict[str, Any] = {
        "images": [str(p) for p in images],
        "fov_deg": fov_deg,
        "circle": result.to_dict(),
        "circle_model": model.to_dict(),
    }
    lines = _circle_lines(result, model, fov_deg, len(imgs))
    method = METHOD_CIRCLE
    std = None  # the circle's fit sigma is not the principal point's: no std from it
    assumed = circle_assumptions(model)
    note = assumed.note()  # unless a board checks the circle
    if spec is None:
        report["circle_model_assumes"] = assumed.to_dict()
        lines.append(note)
    else:
        grays = [image_circle.to_gray(i) for i in imgs]
        try:
            fit, _ = calibrate_board(grays, spec, model)
        except InputValueError:  # a board of another size found: --board is wrong
            raise
        except ValueError as e:  # too few boards found
            raise AcqError(str(e)) from e
        m = fit.model
        check = circle_check(model, result.circle.radius, fit)
        report["board"] = fit.to_dict() | {"circle_model_gap_px": round(check.gap_px, 3)}
        report["circle_check"] = check.to_dict()
        lines.append(
            f"checkerboard ({len(fit.views)} of {len(imgs)} images, corners up to "
            f"{fit.max_theta_deg:.1f} deg off axis): Kannala-Brandt fx {m.fx:.2f} fy "
            f"{m.fy:.2f} cx {m.cx:.2f} cy {m.cy:.2f} k {', '.join(f'{k:.5f}' for k in m.k)}; "
            f"RMS {fit.rms_px:.3f} px"
        )
        lines.append(check.line())
        model, method, std, note = m, METHOD_BOARD, fit.std(), ""
    calib, name, notes = update_calibration(output, args.camera, model, method, std, note)
    output_files.keep_backups("acq calibrate fisheye", backups)
    calibfile.save(calib, output)
    title = f"{Path(images[0]).name}: {len(imgs)} image(s)"
    write_image(overlay, draw_overlay(imgs[0], result, title))
    report |= {"camera": name, "calib": str(output), "model": model.to_dict()}
    report |= {"method": method, "overlay": str(overlay)}
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        lines.append(
            f"wrote {output} (camera {name!r}, {model.name}, method {method}); overlay {overlay}"
        )
        print("\n".join(lines))
    for w in [*result.warnings, *notes]:
        print(f"warning: {w}", file=sys.stderr)
    return 0


# --- extrinsic ----------------------------------------------------------------------------


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
        " translation " + ", ".join(f"{x:.1f}" for x in result.std_t_mm) + " mm",
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


def _plots(plot: Path | None, output: Path, names: list[str]) -> dict[str, Path]:
    """Each camera's residual plot: --plot (default beside CALIB, NAME_extrinsic.png);
    with several cameras the camera's name added to the file's."""
    base = plot if plot is not None else output.with_name(output.stem + "_extrinsic.png")
    if len(names) <= 1:
        return {n: base for n in names}
    return {n: base.with_name(f"{base.stem}_{n}{base.suffix}") for n in names}


def _same_file(a: Path, b: Path | None) -> bool:
    return b is not None and a.exists() and b.exists() and os.path.samefile(a, b)


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
    from acq.calib.extrinsic_log import METHOD
    from acq.calib.fisheye_calib import parse_board
    from acq.calib.plots import residual_plot
    from acq.calib.relative_pose import relative_poses
    from acq.camera import calibfile
    from acq.camera.calibfile import Calibration
    from acq.camera.selection import choose_cameras
    from acq.log import drive_log

    logs, intrinsics, board, output = args.logs, args.intrinsics, args.board, args.output
    lens_swap = args.lens_swap
    inputs = [("--intrinsics", intrinsics), *(("LOG", p) for p in logs)]
    if lens_swap is not None:
        inputs.append(("--lens-swap", lens_swap))
    # an existing CALIB other than the input is updated (merged by camera, NAME.bak kept)
    in_place = _same_file(output, intrinsics) or _same_file(output, lens_swap)
    yaml_out = Output(
        "-o", output, "yaml", update=not in_place, in_place_of=("--intrinsics", "--lens-swap")
    )
    asked: list[str] | None = list(dict.fromkeys(args.camera)) if args.camera else None
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
        print(json.dumps(report, indent=2))
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


# --- time offset --------------------------------------------------------------------------


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
    in_place = _same_file(args.output, args.calib)
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
        print(json.dumps(whole, indent=2, default=float))
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


# --- validate -----------------------------------------------------------------------------


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
        print(json.dumps(report, indent=2))
    else:
        print("\n".join(_validate_lines(res, name)))
        if overlay is not None:
            print(f"wrote {overlay}")
    return 0
