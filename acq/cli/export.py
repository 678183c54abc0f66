"""`acq export ros2`: a session's logs as a ROS 2 bag."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from acq.atomic_write import discard, temporary_beside
from acq.cli import output_files
from acq.cli.output_files import Output
from acq.disk_space import naming_full_disk
from acq.errors import InputError
from acq.extras import require

HELP = "logs for other tools: a ROS 2 bag (rosbag2, MCAP storage)"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    export = sub.add_parser("export", help=HELP, description=HELP)
    kinds = export.add_subparsers(dest="kind", required=True, metavar="KIND")
    ros2 = kinds.add_parser(
        "ros2",
        help="a rosbag2 folder (MCAP storage, CDR) that `ros2 bag play BAG` replays",
        description="Write the logs of one session (LOG: its split files, in order) as a "
        "rosbag2 folder BAG with MCAP storage, CDR messages of ROS 2 Jazzy: /<laser>/scan "
        "(sensor_msgs/LaserScan, stamped at the first point), /<camera>/image/compressed "
        "(sensor_msgs/CompressedImage, at mid-exposure), /<camera>/camera_info "
        "(sensor_msgs/CameraInfo; a fisheye's model is 'equidistant'), /tf_static "
        "(transient local: base_link -> laser -> <camera>_optical), /odom (nav_msgs/Odometry) "
        "and /tf (odom -> base_link) dead-reckoned from the CAN odometry, /gnss/fix "
        "(sensor_msgs/NavSatFix). Stamps are UTC (a log on the host's monotonic clock is "
        "mapped through its /acq/clock pairs). acq's timing and raw records are left out. "
        "Replay: ros2 bag play BAG. An existing BAG is replaced when it holds only the files "
        "acq wrote there; a folder with any other file is refused, and with --force kept "
        "whole as BAG.bak (a file acq did not write is never deleted); an input, a file "
        "or the current folder is refused. "
        "Exit status: 0 written, 2 bad input, 3 the disk full, 1 another failure; stopped by "
        "a signal (SIGTERM, SIGHUP, Ctrl-C), 128 + its number, the old BAG kept.",
    )
    ros2.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="MCAP files of a session, or its folder"
    )
    ros2.add_argument(
        "-o", "--output", type=Path, required=True, metavar="BAG", help="the bag's folder"
    )
    ros2.add_argument(
        "--force",
        action="store_true",
        help="a BAG folder holding files acq did not write: keep it whole as BAG.bak and "
        "write the bag in its place (without: refused, naming the files)",
    )
    ros2.set_defaults(handler=run, stops_cleanly=True)


def _check_bag(logs: list[Path], bag: Path, force: bool) -> Path | None:
    """Refuse a BAG that is an input, holds one, is an existing file, or holds files acq
    did not write (without --force); the path the old folder is kept as (--force), or
    None."""
    from acq.export.ros2 import bag_files

    if not bag.is_dir():  # absent, or a file: the files' rule says why not
        output_files.check([("LOG", p) for p in logs], [Output("-o", bag, "mcap")])
        return None
    if any(p.resolve().is_relative_to(bag.resolve()) for p in logs):
        raise InputError(f"-o {bag}: holds an input LOG; give another folder")
    return output_files.check_folder_replace("-o", bag, bag_files(bag), force=force)


def run(args: argparse.Namespace) -> int:
    from acq.export import export_ros2
    from acq.export.ros2 import bag_files

    require("ros2", "writing a rosbag2 bag")
    bag = output_files.folder_output("-o", args.output)
    kept = _check_bag(args.logs, bag, args.force)
    # written in a folder beside (rosbags names its storage file after the bag's folder),
    # then put in place: a failure leaves the old bag as it was
    work = temporary_beside(bag, suffix="", folder=True)
    try:
        with naming_full_disk(bag):
            report = export_ros2(args.logs, work / bag.name)
        if kept is not None:
            os.rename(bag, kept)  # whole, as it was: nothing of the user's deleted
            print(f"acq export ros2: kept the old {bag} as {kept}", file=sys.stderr)
        elif bag.is_dir() and not output_files.foreign_files(bag, bag_files(bag)):
            os.replace(bag, work / "old")  # acq's files only: removed with the work folder
        os.replace(work / bag.name, bag)  # refused (the old one stays) if files came since
    finally:
        discard(work)
    counts = ", ".join(f"{topic} {n}" for topic, n in sorted(report.counts.items()))
    print(f"{bag}: {counts}")
    if report.left_out:
        left = ", ".join(f"{topic} {n}" for topic, n in sorted(report.left_out.items()))
        print(f"left out (no ROS 2 counterpart): {left}", file=sys.stderr)
    for note in report.notes:
        print(f"note: {note}", file=sys.stderr)
    return 0
