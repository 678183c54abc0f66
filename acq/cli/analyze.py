"""`acq analyze sensitivity`: how the projection depends on its 12 parameters (paper §4.1)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from acq import json_text
from acq.cli import output_files
from acq.cli.camera_option import add_camera_option
from acq.cli.option_types import real
from acq.cli.output_files import Output
from acq.errors import InputError

HELP = "analyse a calibration against logs"
SIGMA = real(0, 1e6, what="a standard deviation")  # rad, m, px or px/m
# what it writes into its folder (acq.calib.sensitivity_log)
WRITES = (("fig7_rigid.png", "image"), ("fig8_camera.png", "image"),
          ("fig9_third_order.png", "image"), ("sensitivity.json", "json"))  # fmt: skip


def _sigma_arg(text: str) -> tuple[str, float]:
    """``NAME=VALUE``: a parameter's name and its standard deviation, in range."""
    from acq.calib.sensitivity import parse_sigma

    try:
        name, sigma = parse_sigma(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("--sigma ")) from None
    if not SIGMA.contains(sigma):
        raise argparse.ArgumentTypeError(
            f"expected {SIGMA.what} in {SIGMA.range_text()}, got {text!r}"
        )
    return name, sigma


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    ana = sub.add_parser("analyze", help=HELP)
    ana_sub = ana.add_subparsers(dest="analyze_command", metavar="WHAT", required=True)
    sens = ana_sub.add_parser(
        "sensitivity",
        help="sensitivity of the projection to its 12 parameters (paper §4.1)",
        description="Project the laser points of LOG into CALIB's camera with the paper's "
        "generic model (r = k1 theta + k2 theta^3) and compute, along theta, the eq. (7) "
        "sensitivity of the distance to the principal point (eq. 8, measured from the "
        "principal point, not pixel (0, 0) as printed) to the 3 rotation angles, 3 "
        "translations, k1, k2, u0, v0, mu_x, mu_y, with the pixels one standard deviation of "
        "each moves a point; Figures 7-9 as PNGs; Table 3 (height on a facade at which "
        "dropping k2 theta^3 reaches 0.5..4 px); DIR/sensitivity.json. Files of their kind "
        "in DIR are replaced, any other is refused.",
    )
    sens.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="MCAP logs of one session, or its folder"
    )
    sens.add_argument("--calib", type=Path, required=True, metavar="CALIB", help="calib.yaml")
    sens.add_argument(
        "-o", "--output", type=Path, default=Path("sensitivity"), metavar="DIR",
        help="where to write the PNGs and sensitivity.json (default: ./sensitivity)",
    )  # fmt: skip
    add_camera_option(sens, "the camera to analyse")
    sens.add_argument(
        "--camera-height", type=real(0, 100, lo_open=True, what="metres"), default=2.0,
        metavar="M",
        help="Table 3: camera height above the ground, m (default 2)",
    )  # fmt: skip
    sens.add_argument(
        "--building-distance", type=real(0, 1000, lo_open=True, what="metres"),
        default=10.0, metavar="M",
        help="Table 3: distance from the camera to the facade, m (default 10)",
    )  # fmt: skip
    sens.add_argument(
        "--sigma", type=_sigma_arg, action="append", metavar="NAME=VALUE",
        help="one standard deviation of a parameter in its unit (rad, m, px, px/m), e.g. "
        "yaw=0.002; repeatable; overrides calib.yaml's std and the defaults",
    )  # fmt: skip
    sens.add_argument("--json", action="store_true", help="JSON instead of text")
    sens.add_argument("--force", action="store_true", help=output_files.FORCE_HELP)
    sens.set_defaults(handler=run_sensitivity)


def _row(s: dict[str, Any]) -> str:
    from acq.calib import sensitivity

    i = sensitivity.PARAMS.index(s["param"])
    med = s["median_abs_s"]
    sig = sensitivity.format_sigma(s["sigma"], i, s["value"])
    src = s["sigma_source"] or ""
    return (
        f"  {s['param']:<6} {s['value']:>12.5g} {sensitivity.UNITS[i]:<5} {sig:>9} {src:<8}"
        f" {med if med is not None else float('nan'):>10.3g}"
        f" {s['px_per_sigma_median_theta']:>10.3f} {s['px_per_sigma_max_theta']:>10.3f}"
        f" {s['px_per_sigma_max']:>10.3f}"
    )


def run_sensitivity(args: argparse.Namespace) -> int:
    """Write the figures and sensitivity.json; print a summary (or the JSON)."""
    from acq.calib import sensitivity, sensitivity_log

    out: Path = args.output
    if out.exists() and not out.is_dir():
        raise InputError(f"-o {out}: is a file; give a folder")
    inputs = [("--calib", args.calib), *(("LOG", p) for p in args.logs)]
    outputs = [Output("-o", out / name, kind, makes_folder=True) for name, kind in WRITES]
    output_files.check(inputs, outputs, force=args.force)
    report = sensitivity_log.analyze_logs(
        args.calib, args.logs, out, args.camera_height, args.building_distance,
        camera=args.camera, sigma=dict(args.sigma or ()),
    )  # fmt: skip
    if args.json:
        print(json_text.dumps(report, what="--json"))
        return 0
    th = report["theta_deg"]
    print(
        f"{report['n_points']} of {report['n_laser_points']} laser points in the image, theta "
        f"{th['min']:.1f} .. {th['max']:.1f} deg (median {th['median']:.1f})"
    )
    print(
        f"  {'param':<6} {'value':>12} {'unit':<5} {'sigma':>9} {'from':<8} {'med |s|':>10}"
        f" {'px@θmed':>10} {'px@θmax':>10} {'px max':>10}"
    )
    for s in report["summary"]:
        print(_row(s))
    for line in sensitivity.format_table3(report["table3"]):
        print(line)
    for n in report["notes"]:
        print(f"note: {n}")
    print(f"wrote {', '.join(report['figures'].values())}, {out / 'sensitivity.json'}")
    return 0
