"""The `acq` command line: one sub-command per job, each with its own --help.

Exit codes: 0 success, 2 bad usage or bad input (one line naming the file and the key),
1 a runtime failure.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from acq import __version__

Handler = Callable[[argparse.Namespace], int]


class UsageError(Exception):
    """Bad input from the user: printed as one line, exit status 2."""


def _demo(args: argparse.Namespace) -> int:
    from acq import sim_render

    print(
        "acq demo: the recorded demo (simulated rig -> recorder -> MCAP -> coloured cloud)\n"
        "arrives with the recorder (issue 6). Until then it renders the simulated rig:\n"
    )
    return sim_render.run(out=args.out, time_s=2.0, seed=0, exact_equidistant=False)


def _sim_render(args: argparse.Namespace) -> int:
    from acq import sim_render

    return sim_render.run(
        out=args.out, time_s=args.time, seed=args.seed, exact_equidistant=args.equidistant
    )


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="acq",
        description="Mobile-mapping acquisition: laser scanner + fisheye cameras, "
        "synchronised, logged, calibrated and coloured.",
    )
    p.add_argument("--version", action="version", version=f"acq {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = sub.add_parser(
        "demo",
        help="run the simulated rig end to end",
        description="Run the simulated rig. Until the recorder lands this renders one "
        "fisheye frame of the synthetic street with the laser profile of the same instant.",
    )
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.set_defaults(handler=_demo)

    sim = sub.add_parser("sim", help="simulated street and devices")
    sim_sub = sim.add_subparsers(dest="sim_command", metavar="SIM_COMMAND", required=True)
    render = sim_sub.add_parser(
        "render",
        help="render a fisheye frame and the laser profile of the same instant",
        description="Render the synthetic street at one instant: the fisheye frame "
        "(frame.png), the same frame with the laser points of that instant drawn in the "
        "colours the projection core gives them (overlay.png), the true calibration "
        "(calib.yaml) and a summary (summary.json).",
    )
    render.add_argument("--out", required=True, help="output folder (created if missing)")
    render.add_argument("--time", type=float, default=2.0, help="time on the drive, s")
    render.add_argument("--seed", type=int, default=0, help="street seed")
    render.add_argument(
        "--equidistant",
        action="store_true",
        help="an exactly equidistant lens instead of the default with small k1..k4",
    )
    render.set_defaults(handler=_sim_render)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        return handler(args)
    except UsageError as e:
        print(f"acq: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
