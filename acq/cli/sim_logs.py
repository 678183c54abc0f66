"""`acq sim log board|validation`: simulated recordings to try the calibration commands on,
each with the calib.yaml it needs and the command to run."""

from __future__ import annotations

import argparse
from pathlib import Path

from acq.cli.option_types import SEED, integer, real
from acq.errors import InputError

__all__ = ["add_parser"]

KINDS = ("board", "validation")


def add_parser(sim_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`acq sim log` under `acq sim`."""
    log = sim_sub.add_parser(
        "log",
        help="write a simulated calibration or validation recording to try acq calibrate on",
        description="Write a simulated recording (MCAP, as the recorder writes it) into a new "
        "or empty folder OUT, with the calib.yaml it needs, and print the command to try on "
        "it. board: a 9x7 checkerboard (0.1 m squares) held still in 12 poses per camera at "
        "1-2.5 m, for `acq calibrate extrinsic` (intrinsics.yaml: the true intrinsics, no "
        "camera_to_laser). validation: the vehicle parked beside the paper's two-depth "
        "pattern for --seconds, for `acq calibrate validate` (calib.yaml: the true calibration).",
    )
    log.add_argument("kind", choices=KINDS, help="which recording")
    log.add_argument("--out", type=Path, required=True, metavar="OUT", help="a new or empty folder")
    log.add_argument(
        "--cameras", type=integer(1, 2, what="cameras"), default=1, metavar="N",
        help="board: the rig's cameras, 1 (camera) or 2 (left, right; default 1)",
    )  # fmt: skip
    log.add_argument(
        "--seconds", type=real(0.2, 60, what="seconds"), default=2.0, metavar="S",
        help="validation: how long the vehicle stands there recording, s (default 2)",
    )  # fmt: skip
    log.add_argument("--seed", type=SEED, default=0, help="seed of the noise and poses")
    log.set_defaults(handler=run_log)


def run_log(args: argparse.Namespace) -> int:
    """Write the recording and its calib.yaml into --out; print the files and the command.
    0; 2 for an --out that is a file or not empty (nothing there is replaced)."""
    from acq.camera import calibfile
    from acq.sim.out_folder import make_folder
    from acq.sim.world import default_rig

    out: Path = args.out
    if args.kind == "validation" and args.cameras != 1:
        raise InputError("--cameras: the validation recording has one camera")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"--out {out}: {'is a file' if not out.is_dir() else 'not empty'}; "
                         "give a new or empty folder")  # fmt: skip
    make_folder(out)
    logs: list[Path]
    if args.kind == "board":
        from acq.sim.board_log import write_board_log

        board = write_board_log(out, seed=args.seed, rig=default_rig(cameras=args.cameras))
        calib, logs = out / "intrinsics.yaml", board.files
        calibfile.save(board.calibration, calib)
        files = " ".join(map(str, logs))
        command = (
            f"acq calibrate extrinsic {files} --intrinsics {calib} --board {board.spec} "
            f"-o {out / 'calib.yaml'}"
        )
    else:
        from acq.sim.validation_log import write_validation_log

        valid = write_validation_log(out, seed=args.seed, duration_s=args.seconds)
        calib, logs = out / "calib.yaml", valid.files
        calibfile.save(valid.calibration, calib)
        command = f"acq calibrate validate {' '.join(map(str, logs))} --calib {calib}"
    print(f"wrote {', '.join(map(str, logs))} and {calib}")
    print(f"try: {command}")
    return 0
