"""`acq view`: clouds, meshes and drives in the browser, from a local server (no network)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from acq.addresses import is_loopback
from acq.cli.option_types import integer
from acq.errors import InputError
from acq.view.lod import RUN_POINTS
from acq.view.server import DEFAULT_MAX_POINTS

HELP = "see clouds, meshes and drives in a web browser, served from this machine (offline)"
DEFAULT_HOST = "127.0.0.1"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    v = sub.add_parser(
        "view",
        help=HELP,
        description="Serve a web page that draws each PATH as a layer: a .ply, .las, .laz "
        "or .copc.laz cloud as points in their colours (as `acq colorize` writes them), a "
        ".ply or .glb mesh (as `acq mesh` writes it) as coloured or textured facets, a "
        "drive's .mcap log (or a session's split files) as its trajectory, a frustum per "
        "camera pose every 2 m and its coloured cloud: the cloud `acq colorize` wrote beside "
        "the log (a .ply in its folder whose first and last points' times lie within the "
        "log's), else one coloured here in the background (kept in ~/.cache/acq/view). A "
        "folder stands for the .ply, .glb, .las, .laz and .mcap files in it. Every file is "
        "checked before the server starts; clouds are decoded once it serves (the page says "
        "'decoding NAME…'), a cloud whose points then prove unreadable said in one line on "
        "stderr and on the page. The page and its libraries (three.js) come "
        "with acq: no network is needed. In the page: drag to orbit, right-drag to pan, the "
        "wheel to zoom; a box per layer hides it; a slider sets the points' size; a select "
        "colours the clouds by RGB, intensity, time, scan, source camera or coloured-or-not, "
        "with a legend; 'show "
        "frame' and a click on a point show the camera frame it was coloured from, the "
        "point ringed; 'walk' puts the eye on the trajectory (arrow keys or W/S move along "
        "it); the measure box gives a distance and its points in the file's CRS (a "
        "LAS/LAZ/COPC file's, or a PLY's 'crs' comment), and a view in a projected CRS has "
        "a scale bar and a north arrow (a CRS not in metres is refused). Prints "
        "the page's URL and serves until Ctrl-C (or SIGTERM, SIGHUP). Exit status: "
        "0 stopped so, 2 a bad file or option (the port in use among them).",
    )
    v.add_argument(
        "paths", nargs="+", type=Path, metavar="PATH",
        help=".ply, .glb, .las, .laz, .copc.laz or .mcap files, or folders",
    )  # fmt: skip
    v.add_argument(
        "--max-points", type=integer(1, 2**62, what="a count of points"),
        default=DEFAULT_MAX_POINTS, metavar="N",
        help="most points of a cloud sent to the page at first (default "
        f"{DEFAULT_MAX_POINTS:,}: a laptop's browser draws about a million points "
        "smoothly and slows around 5-10 million); a larger cloud is shown by N of its "
        "points evenly spread through the file, and its layer says so (e.g. '2,000,000 of "
        "10,000,000 points'); then, as the view closes in, the page loads the points there "
        f"in full (a COPC file's octree nodes, another file's runs of {RUN_POINTS:,} points), "
        "6,000,000 points drawn at most (the page's URL's ?budget=N sets another)",
    )  # fmt: skip
    v.add_argument(
        "--calib", type=Path, metavar="CALIB",
        help="the calibration of the .mcap drives (default: calib.yaml beside the log); "
        "without one a drive shows its trajectory only",
    )  # fmt: skip
    v.add_argument(
        "--host", default=DEFAULT_HOST,
        help=f"address to serve on (default {DEFAULT_HOST}: this machine only); another "
        "makes the files readable from the network without authentication (a warning says so)",
    )  # fmt: skip
    v.add_argument(
        "--port",
        type=integer(0, 65535, what="a port"),
        default=0,
        help="TCP port to serve on, [0, 65535] (default 0: a free one, printed)",
    )
    v.add_argument(
        "--open", action="store_true",
        help="open the page in the system's web browser (where there is one)",
    )  # fmt: skip
    v.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import webbrowser

    from acq.stopped import stopping
    from acq.view import AddressError, ViewServer

    if not is_loopback(args.host):
        print(
            f"acq view: warning: --host {args.host}: the files are served to the network, "
            "without authentication",
            file=sys.stderr, flush=True,
        )  # fmt: skip
    server = ViewServer(
        args.paths, host=args.host, port=args.port, max_points=args.max_points,
        calib=args.calib,
        on_error=lambda line: print(f"acq view: {line}", file=sys.stderr, flush=True),
    )  # fmt: skip
    try:
        server.start()
    except AddressError as e:  # named as the command line names it
        raise InputError(f"--{e.about} {e.value}: {e.reason}") from None
    try:
        # Ctrl-C, SIGTERM or SIGHUP end it, even where SIGINT came ignored (a command
        # started in the background by a script, where Python leaves it ignored); from
        # before the URL is printed, which is when a caller may send one
        with stopping():
            n = len(server.layers)
            print(f"serving {n} layer{'s' * (n != 1)} at {server.url} (Ctrl-C to stop)", flush=True)
            if args.open and not webbrowser.open(server.url):
                print(f"acq view: no web browser found: open {server.url}", file=sys.stderr)
            # timed: a process's signal may be taken by one of the server's threads, and
            # then only the main thread's next step runs its handler (an untimed wait on
            # a lock never takes one)
            while True:
                time.sleep(0.2)
    except KeyboardInterrupt:  # the way to stop it (Stopped is one): not a failure
        pass
    finally:
        server.stop()
    return 0
