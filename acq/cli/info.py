"""`acq info`: channels, rates, gaps, drops and clock-sync quality of logs; --repair."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from acq import json_text
from acq.cli import output_files
from acq.cli.colorize import CHECK_S, warn_moved
from acq.cli.output_files import Output
from acq.credentials import redact
from acq.errors import InputError

HELP = "channels, rates, gaps, drops and clock-sync quality of logs"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.log.silent_devices import STOPPED_EARLY_S  # imported for this command only

    info = sub.add_parser(
        "info",
        help=HELP,
        description="Summarise MCAP logs: channels with counts, rates and gaps; time span; "
        "drops and disconnects per device; clock-sync quality (drift, uncertainty, receive "
        "minus stamp); a warning for each configured device that recorded nothing or "
        f"stopped recording more than {STOPPED_EARLY_S:g} s before the end. "
        "Several files of one session are summarised together too; files of "
        "several sessions each session on its own. A folder stands for its .mcap files. A "
        "file being written is read as far as its recorder has written it; one whose "
        "writer was killed is read up to the cut and reported as not closed; --repair "
        "writes an indexed copy of it, which later commands read in its place when given "
        "both (a folder holding both).",
    )
    info.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="MCAP files, or folders of them"
    )
    info.add_argument("--json", action="store_true", help="JSON instead of text")
    info.add_argument(
        "--repair",
        action="store_true",
        help="write an indexed copy of each LOG (LOG.repaired.mcap, or --output); an "
        "existing file is never overwritten",
    )
    info.add_argument(
        "-o", "--output", type=Path, help="with --repair and one LOG: the copy (a new file)"
    )
    info.add_argument(
        "--calib", type=Path, metavar="CALIB",
        help="also check each camera's calibration on each session's drive, as `acq "
        f"calibrate check` does on {CHECK_S:g} s of its middle (needs the rig's motion "
        "and the laser's return strengths): a line per camera, a warning when it has "
        "moved beyond its uncertainty",
    )  # fmt: skip
    info.set_defaults(handler=run, sessions_apart=True)


def run(args: argparse.Namespace) -> int:
    from acq.log import inputs, summary
    from acq.log.repair import repair

    if args.repair:
        logs = inputs.log_files(args.logs)
        if args.output is not None and len(logs) > 1:
            raise InputError("-o: with one LOG only (each LOG's copy is LOG.repaired.mcap)")
        for src in logs:
            dst = args.output if args.output else src.with_suffix(".repaired.mcap")
            option = "-o" if args.output else "the copy"
            output_files.check([("LOG", p) for p in logs], [Output(option, dst, "mcap")])
            if dst.exists():
                raise InputError(f"{dst}: exists; not overwritten")
            with output_files.atomic(dst) as tmp:  # a failure leaves no half copy
                n = repair(src, tmp, into_empty=True)
            print(f"{src} -> {dst}: {n} messages, indexed")
        return 0
    sessions = inputs.sessions(args.logs)
    per_session = [summary.info_many(s.files) for s in sessions]
    infos = [i for found in per_session for i in found]
    checks = [_checked(args.calib, s.files) for s in sessions] if args.calib else []
    if args.json and checks:  # each session's objects carry its cameras' checks
        objects = json.loads(summary.format_info(infos, json=True))
        owners = [k for k, found in enumerate(per_session) for _ in found]
        for obj, k in zip(objects, owners, strict=True):
            obj["calibration_check"] = checks[k]
        print(redact(json_text.dumps(objects, what="acq info --json")))
    else:
        if len(sessions) > 1 and not args.json:
            listed = "; ".join(s.describe() for s in sessions)
            print(f"{len(sessions)} recording sessions, each summarised on its own: {listed}\n")
        # logs of older versions may hold a password in a device URL's query
        print(redact(summary.format_info(infos, json=args.json)))
        for session, found in zip(sessions, checks, strict=False):  # none without --calib
            where = f" ({session.describe()})" if len(sessions) > 1 else ""
            print(f"\ncalibration check{where}:")
            print("\n".join(f"  {c['line']}" for c in found.values()))
    for found in checks:
        warn_moved("acq info", found)
    return 0


def _checked(calib_path: Path, files: list[Path]) -> dict[str, dict[str, Any]]:
    """Per camera of CALIB in the session ``files``, its calibration check's figures
    (:meth:`acq.calib.pose_check.PoseCheck.summary`)."""
    from acq.camera import calibfile
    from acq.cloud.colorize import check_drive

    job, _, checks = check_drive(files, calibfile.load(calib_path), seconds=CHECK_S)
    return {cj.name: c.summary(cj.name) for cj, c in zip(job.cameras, checks, strict=True)}
