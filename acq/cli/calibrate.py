"""`acq calibrate fisheye|extrinsic|time-offset|validate|check`: the rig's calibration
(paper §3.2, §3.3.2, §4.2), the camera's time offset and the check on a drive; each
sub-command in its module (acq.cli.calibrate_fisheye, ...)."""

from __future__ import annotations

import argparse

from acq.cli import (
    calibrate_check,
    calibrate_extrinsic,
    calibrate_fisheye,
    calibrate_time_offset,
    calibrate_validate,
)

__all__ = ["HELP", "add_parser"]

HELP = "calibrate the rig's sensors"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    cal = sub.add_parser("calibrate", help=HELP)
    cal_sub = cal.add_subparsers(dest="calibrate_command", metavar="WHAT", required=True)
    calibrate_fisheye.add_parser(cal_sub)
    calibrate_extrinsic.add_parser(cal_sub)
    calibrate_time_offset.add_parser(cal_sub)
    calibrate_validate.add_parser(cal_sub)
    calibrate_check.add_parser(cal_sub)
