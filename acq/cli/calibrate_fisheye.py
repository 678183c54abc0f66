"""`acq calibrate fisheye`: a fisheye camera's intrinsics from its image circle, or a
Kannala-Brandt fit to a checkerboard (paper §3.3.2)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from acq import json_text
from acq.cli import output_files
from acq.cli.camera_option import add_camera_option
from acq.cli.option_types import real
from acq.cli.output_files import IMAGE_SUFFIXES, Output
from acq.errors import AcqError, InputError, InputValueError

if TYPE_CHECKING:
    from acq.calib.image_circle import CircleResult
    from acq.camera.camera_models import KannalaBrandt

__all__ = ["add_parser", "run_fisheye"]


def add_parser(cal_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`acq calibrate fisheye` under `acq calibrate`."""
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
    fish.add_argument(
        "images", nargs="+", type=Path, metavar="IMAGE",
        help="images of one camera (8- or 16-bit, grey or colour); one whose header declares "
        "more than 100 megapixels is refused before it is decoded",
    )  # fmt: skip
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
        print(json_text.dumps(report, what="--json"))
    else:
        lines.append(
            f"wrote {output} (camera {name!r}, {model.name}, method {method}); overlay {overlay}"
        )
        print("\n".join(lines))
    for w in [*result.warnings, *notes]:
        print(f"warning: {w}", file=sys.stderr)
    return 0
