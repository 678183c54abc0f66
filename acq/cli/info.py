"""`acq info`: channels, rates, gaps, drops and clock-sync quality of logs; --repair."""

from __future__ import annotations

import argparse
from pathlib import Path

from acq.errors import InputError

HELP = "channels, rates, gaps, drops and clock-sync quality of logs"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    info = sub.add_parser(
        "info",
        help=HELP,
        description="Summarise MCAP logs: channels with counts, rates and gaps; time span; "
        "drops and disconnects per device; clock-sync quality (drift, uncertainty, receive "
        "minus stamp). Several files of one session are summarised together too. A file "
        "whose writer was killed is read up to the cut and reported as not closed; "
        "--repair writes an indexed copy of it.",
    )
    info.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files")
    info.add_argument("--json", action="store_true", help="JSON instead of text")
    info.add_argument(
        "--repair",
        action="store_true",
        help="write an indexed copy of each LOG (LOG.repaired.mcap, or --output)",
    )
    info.add_argument("-o", "--output", type=Path, help="with --repair and one LOG: the copy")
    info.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from acq.log import summary
    from acq.log.repair import repair

    if args.repair:
        for src in args.logs:
            dst = args.output if args.output else src.with_suffix(".repaired.mcap")
            try:
                n = repair(src, dst)
            except FileExistsError as e:
                raise InputError(f"{e.filename}: exists; not overwritten") from None
            print(f"{src} -> {dst}: {n} messages, indexed")
        return 0
    print(summary.format_info(summary.info_many(args.logs), json=args.json))
    return 0
