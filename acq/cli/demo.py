"""`acq demo`: record the simulated rig and colour its cloud, end to end."""

from __future__ import annotations

import argparse
from pathlib import Path

from acq.cli.option_types import real
from acq.errors import AcqError
from acq.extras import require

HELP = "record the simulated rig and colour its cloud, end to end"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.sim.demo import COLOUR_CAMERA, MAX_SECONDS, OUT_MARK

    source = f"the {COLOUR_CAMERA} camera" if COLOUR_CAMERA else "every camera"
    pick = f" --camera {COLOUR_CAMERA}" if COLOUR_CAMERA else ""

    demo = sub.add_parser(
        "demo",
        help=HELP,
        description="Start the simulated rig (a UTM-30LX speaking SCIP on a pseudo-terminal, "
        "two 185-degree fisheyes, left and right, each serving MJPEG over HTTP from its own "
        "process with its own lens, mounting, latency, exposure and white balance, and the car's "
        "CAN odometry, all on the synthetic street), record it through the real drivers and "
        "recorder for --seconds (the cameras first render their frames of the drive, so that "
        "both keep 25 Hz on a busy machine), then colour every laser point with the frame "
        "nearest in time, using the rig's calibration and the simulator's path. Writes "
        "DIR/demo.mcap (topics /laser/..., /left/..., /right/..., /vehicle/...), DIR/cloud.ply "
        "(x y z, colour, UTC time, scan, intensity), DIR/preview.png (the coloured facade "
        "and a top view), DIR/mesh.glb and DIR/mesh_textured.glb (its facets as `acq mesh` "
        "joins them, vertex-coloured and textured from the frames), DIR/mesh_views.png (both "
        "and the cloud rendered beside the true street), calib.yaml (both cameras) and "
        "config.yaml, and prints a summary "
        "(each camera's frames, drops and late frames) checked against the simulator's truth. "
        f"The cloud is coloured from {source}. `acq colorize DIR/demo.mcap --calib "
        f"DIR/calib.yaml{pick} -o OUT.ply` colours the same log from its recorded odometry. "
        "DIR must be new, empty, "
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

    require("mesh", "the demo's textured mesh")
    result = demo.run(Path(args.out), args.seconds, progress=_progress)
    print("\n".join(result.lines), flush=True)
    if result.frames_used == 0:
        raise AcqError("no camera frame was recorded, the cloud has no colour (a busy machine?)")
    return 0
