"""`acq demo`: record the simulated rig and colour its cloud, end to end."""

from __future__ import annotations

import argparse
from pathlib import Path

from acq.cli.option_types import real
from acq.errors import AcqError

HELP = "record the simulated rig and colour its cloud, end to end"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.sim.demo import MAX_SECONDS, OUT_MARK

    demo = sub.add_parser(
        "demo",
        help=HELP,
        description="Start the simulated rig (a UTM-30LX speaking SCIP on a pseudo-terminal, "
        "a 185-degree fisheye serving MJPEG over HTTP and the car's CAN odometry, all on the "
        "synthetic street), record it through the real drivers and recorder for --seconds, "
        "then colour every laser point with the fisheye frame nearest in time, using the "
        "rig's calibration and the simulator's path. Writes DIR/demo.mcap, DIR/cloud.ply "
        "(x y z, colour, UTC time, scan, intensity), DIR/preview.png (the coloured facade "
        "and a top view), calib.yaml and config.yaml, and prints a summary checked against "
        "the simulator's truth. `acq colorize DIR/demo.mcap --calib DIR/calib.yaml -o "
        "OUT.ply` colours the same log from its recorded odometry. DIR must be new, empty, "
        f"or an earlier demo's (it holds {OUT_MARK}): the demo replaces its own files "
        "there and nothing else.",
    )
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument(
        "--seconds", type=real(0, MAX_SECONDS, lo_open=True, what="seconds"), default=10.0,
        help=f"how long to record, at most {MAX_SECONDS:g} (default 10)",
    )  # fmt: skip
    demo.set_defaults(handler=run)


def _progress(line: str) -> None:
    print(line, flush=True)


def run(args: argparse.Namespace) -> int:
    from acq.sim import demo

    result = demo.run(Path(args.out), args.seconds, progress=_progress)
    print("\n".join(result.lines), flush=True)
    if result.frames_used == 0:
        raise AcqError("no camera frame was recorded, the cloud has no colour (a busy machine?)")
    return 0
