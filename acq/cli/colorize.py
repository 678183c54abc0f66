"""`acq colorize`: a drive's coloured 3D cloud (PLY or LAS)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from acq import json_text
from acq.cli import output_files
from acq.cli.camera_option import add_camera_option
from acq.cli.option_types import integer, real
from acq.cli.output_files import Output
from acq.errors import InputError
from acq.extras import require

# the columns acq.motion.ins.from_csv reads
TRAJECTORY_HELP = (
    "post-processed GNSS/INS trajectory, a CSV file with a header line: time (UTC seconds "
    "or ISO-8601) or gps_week,gps_sow; x,y,z (m) or lat,lon,h (WGS-84 deg, m); "
    "roll,pitch,yaw or roll,pitch,heading (deg); other columns ignored"
)
HELP = "coloured 3D cloud of a drive (PLY, LAS, LAZ, COPC or E57)"
# a chunk's scans and their points are in memory at once: a few seconds at the least
CHUNK_S = real(1, 600, what="seconds")
# --check: how much of the drive the calibration check reads, s (its middle): as much as
# `acq calibrate check` reads by default, for the same verdict (30 s gave a false alarm)
CHECK_S = 60.0


def warn_moved(command: str, checks: dict[str, dict[str, Any]]) -> None:
    """A warning on stderr for each camera whose calibration check (``checks``: per camera,
    :meth:`acq.calib.pose_check.PoseCheck.to_dict` and its ``line``) says it moved."""
    for name, c in checks.items():
        if c.get("verdict") == "moved":
            print(
                f"{command}: warning: the calibration of camera {name} has moved: {c['line']}"
                " (`acq calibrate check LOG --calib CALIB --write OUT` refines it)",
                file=sys.stderr, flush=True,
            )  # fmt: skip


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.cloud.views import VIEWS

    col = sub.add_parser(
        "colorize",
        help=HELP,
        description="Place every laser point of LOG (the split files of one session, or "
        "their folder) at its own time and colour it from the frames of every camera of "
        "CALIB, each point from the camera that sees it best, the cameras' exposure and "
        "white balance evened out: in each camera, the frame "
        "nearest in time with the rig's motion between the two instants compensated "
        "(--view nearest), or the one among its neighbours that sees it nearest its optical "
        "axis without nearer laser points in the way (--view best). Stamps are re-timed "
        "offline first (scans from their device ticks, frames onto the camera's frame grid). "
        "The trajectory: --trajectory CSV, else the log's CAN odometry (fused with its GNSS "
        "fixes when there are any), else its GNSS fixes alone, else none (points stay in "
        "the laser frame). Points no frame sees are kept, flagged 'coloured' 0. Every "
        "point keeps its time (PLY 'scalar_time': UTC s; LAS: Adjusted Standard GPS time), scan "
        "index and intensity. OUT and the preview replace what acq wrote before; an input, a "
        "file of another kind or anyone else's is refused (--force replaces the last). Exit "
        "status: 0 written, 2 bad input, 3 the disk full, 1 another failure; stopped by a "
        "signal (SIGTERM, SIGHUP, Ctrl-C), 128 + its number, the old OUT kept.",
    )
    col.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files or a folder")
    col.add_argument("--calib", type=Path, required=True, help="calib.yaml (camera and laser)")
    col.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT",
        help="the format from the suffix: OUT.ply, OUT.las (LAS 1.4, point format 7), "
        "OUT.laz (the same, LASzip-compressed), OUT.copc.laz (Cloud-Optimized Point Cloud, "
        "for streaming; its points wait in scratch files beside OUT, 46 bytes each, twice "
        "that at most) or OUT.e57 (ASTM E57)",
    )  # fmt: skip
    add_camera_option(
        col, "colour from this camera (each point takes the camera whose view of it is best: "
        "the smallest footprint on the surface, away from the image circle's rim, nearest in "
        "time; the PLY's scalar_camera and scalar_frame, LAS: camera, frame, say which)",
        several=True,
    )  # fmt: skip
    col.add_argument(
        "--blend", action="store_true",
        help="blend the colours of every camera that sees a point, weighted by how good "
        "each view is, instead of taking the best one's",
    )  # fmt: skip
    col.add_argument(
        "--no-balance", action="store_true",
        help="keep each frame's colours as the camera took them; by default the cameras' "
        "exposure and white balance are evened out, per camera and frame, from points seen "
        "in several frames and by several cameras",
    )  # fmt: skip
    add_placing_options(
        col, "into the LAS/LAZ/COPC header as WKT 1 (E57: coordinateMetadata)", "clouds"
    )
    col.add_argument(
        "--view", choices=VIEWS, default="nearest",
        help="nearest (default): the frame nearest in time; best: the neighbour frame that "
        "sees the point nearest its axis, not hidden by nearer laser points",
    )  # fmt: skip
    col.add_argument(
        "--window", type=integer(0, 50), default=3, metavar="N",
        help="--view best: frames either side of the nearest to consider (default 3)",
    )  # fmt: skip
    col.add_argument(
        "--max-dt", type=real(0, 10, lo_open=True, what="seconds"), default=0.1, metavar="S",
        help="farthest frame from a point's time, seconds (default 0.1)",
    )  # fmt: skip
    col.add_argument(
        "--time-offset", type=real(-60, 60, what="seconds", words=("auto",)), metavar="S|auto",
        help="camera time minus laser time, seconds (default: CALIB's time_offset_s): what "
        "the camera's configured latency got wrong; at 20 km/h 10 ms move colours 5.6 cm. "
        "'auto': estimate it from this log first, as 'acq calibrate time-offset' does "
        "(needs motion and the laser's return strengths; CALIB's value is kept when it "
        "finds no clear peak)",
    )  # fmt: skip
    col.add_argument("--no-retime", action="store_true", help="use the stamps as recorded (online)")
    col.add_argument(
        "--no-motion-compensation", action="store_true",
        help="colour each point as if the rig stood still between it and its frame "
        "(for comparison)",
    )  # fmt: skip
    col.add_argument(
        "--workers", type=integer(1, 256), default=1, metavar="N",
        help="processes on this machine (default 1); the output is the same for any N",
    )  # fmt: skip
    col.add_argument(
        "--dask", metavar="ADDRESS",
        help="run the chunks on this Dask scheduler (tcp://host:8786); the workers must "
        "see the log files at the same paths (the cluster extra: pip install 'acq[cluster]')",
    )  # fmt: skip
    col.add_argument(
        "--chunk", type=CHUNK_S, default=None, metavar="S",
        help=f"seconds of scans per chunk, {CHUNK_S.range_text()} (default 15; two chunks "
        "and their images are in memory at once)",
    )  # fmt: skip
    col.add_argument(
        "--preview", type=Path, metavar="PNG",
        help="the preview image (default: OUT's name + _preview.png)",
    )  # fmt: skip
    col.add_argument("--no-preview", action="store_true", help="no preview image")
    col.add_argument(
        "--check", action="store_true",
        help="first check each camera's calibration on the drive itself, as `acq calibrate "
        f"check` does on {CHECK_S:g} s of its middle (needs the rig's motion and the "
        "laser's return strengths): a warning when it has moved beyond its uncertainty, "
        "the figures in the report and in the cloud's metadata (PLY and E57 comments, a "
        "LAS VLR)",
    )  # fmt: skip
    col.add_argument("--json", action="store_true", help="JSON report instead of text")
    col.add_argument("--force", action="store_true", help=output_files.FORCE_HELP)
    col.set_defaults(handler=run, stops_cleanly=True)


def add_placing_options(
    parser: argparse.ArgumentParser, crs_written: str, products: str, laser_note: str = ""
) -> None:
    """``--frame``, ``--trajectory`` and ``--crs``: how points are placed, the same for
    every command that places them; ``crs_written``: where the CRS goes in the output
    ("into the LAS header"), ``products``: what is written in a local frame without it
    ("clouds"), ``laser_note``: added to --frame laser's help."""
    parser.add_argument(
        "--frame", choices=("world", "laser"),
        help="world: placed with the trajectory (default when there is one); laser: each "
        f"point in the scanner frame at its own time{laser_note}",
    )  # fmt: skip
    parser.add_argument(
        "--trajectory", type=Path, metavar="CSV",
        help=f"{TRAJECTORY_HELP}; laser_to_vehicle from CALIB is the lever arm and boresight "
        "(default: the log's CAN odometry, fused with its GNSS fixes)",
    )  # fmt: skip
    parser.add_argument(
        "--crs", metavar="EPSG:CODE",
        help="projected coordinate reference system of the output (e.g. EPSG:25831), written "
        f"{crs_written}: the GNSS fixes (or --trajectory's latitudes and longitudes) are "
        "projected into it. Only where it is true: refused (exit 2) for points in the laser "
        "frame and for a local trajectory (CAN odometry alone, dead reckoning); without "
        f"--crs such {products} are written in their local frame",
    )  # fmt: skip


def check_crs_option(crs: str | None, frame: str | None) -> None:
    """InputError unless ``--crs`` (if given) is a projected CRS and ``--frame`` is not
    laser (the trajectory's own CRS is checked once it is read)."""
    if not crs:
        return
    import pyproj

    try:
        found = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as e:
        raise InputError(f"--crs {crs}: {e}") from None
    if not found.is_projected:
        raise InputError(f"--crs {crs}: not a projected CRS (metres), as the cloud's is")
    if frame == "laser":
        raise InputError(
            f"--crs {crs}: the points would be in the laser frame (--frame laser); "
            "--crs needs --frame world and a georeferenced trajectory"
        )


def run(args: argparse.Namespace) -> int:
    from acq.camera import calibfile
    from acq.cloud import colorize, views
    from acq.cloud.writer import format_of

    format_of(args.output, "-o")
    if args.dask:
        require("cluster", "--dask")
    check_crs_option(args.crs, args.frame)
    options = views.Options(
        view=args.view,
        motion_compensation=not args.no_motion_compensation,
        max_dt_s=args.max_dt,
        window=args.window,
        balance=not args.no_balance,
        blend=args.blend,
    )
    preview = args.preview or args.output.with_name(args.output.stem + "_preview.png")
    if not args.no_preview and preview.suffix.lower() != ".png":
        raise InputError(f"--preview {preview}: expected a .png file")
    outputs = [Output("-o", args.output, "cloud")]
    outputs += [] if args.no_preview else [Output("--preview", preview, "image")]
    inputs = [("--calib", args.calib), *(("LOG", p) for p in args.logs)]
    if args.trajectory is not None:
        inputs.append(("--trajectory", args.trajectory))
    output_files.check(inputs, outputs, force=args.force)
    calib = calibfile.load(args.calib)
    report = colorize.run(
        args.logs, calib, args.output, camera=args.camera, frame=args.frame,
        options=options, trajectory=args.trajectory, crs=args.crs,
        retime_offline=not args.no_retime, time_offset_s=args.time_offset,
        workers=args.workers, dask=args.dask, chunk_s=args.chunk or colorize.CHUNK_S,
        preview=None if args.no_preview else preview,
        progress=args.progress or (not args.json and sys.stderr.isatty()),
        check_s=CHECK_S if args.check else None,
    )  # fmt: skip
    warn_moved("acq colorize", report.calibration_check)
    if args.json:
        print(json_text.dumps(report, what="--json"))
    else:
        print("\n".join(report.lines()))
    return 0
