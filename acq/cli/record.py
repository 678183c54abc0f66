"""`acq record`: the daemon systemd runs."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from acq.cli.option_types import LONGEST_S, real

if TYPE_CHECKING:
    from acq.record.status_line import StatusLine

HELP = "record the rig's devices to MCAP (the daemon systemd runs)"


DEFAULT_ADDRESS = "127.0.0.1:8765"  # of --live


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.log.silent_devices import STOPPED_EARLY_S  # imported for this command only

    rec = sub.add_parser(
        "record",
        help=HELP,
        description="Record every scanner and camera of a configuration into MCAP files: "
        "one thread per device, reconnection with backoff, device clocks mapped to the host "
        "clock, chunks fsynced every second (zstd; those of 90 % JPEG images or more stored "
        "as they are, as zstd cannot shrink them), files split by size and duration. Ctrl-C, "
        "SIGTERM, SIGHUP (a dropped ssh link) and every other signal that would end the "
        "process finish the file, but SIGKILL, the faults and the watchdog's SIGABRT. "
        "When it stops, it names each device that recorded "
        f"nothing or stopped recording more than {STOPPED_EARLY_S:g} s before the end. "
        "Exit status: 0 "
        "stopped, 1 runtime failure (a required device without a record, or a device that "
        "recorded nothing, unless `required: false` in the configuration makes it "
        "optional), 2 bad configuration, 3 disk below its reserve (the file is closed first).",
    )
    rec.add_argument(
        "-c",
        "--config",
        help="configuration YAML (default: the simulated rig, config/sim.yaml, shipped with acq; "
        "its recording then goes to ./logs)",
    )
    rec.add_argument("--out", type=Path, help="output folder (default: the config's output.dir)")
    rec.add_argument(
        "--duration",
        type=real(0, LONGEST_S, lo_open=True, what="seconds"),
        metavar="S",
        help="stop after S seconds (default: run until stopped)",
    )
    rec.add_argument(
        "--require",
        nargs="+",
        action="extend",
        default=[],
        metavar="NAME",
        help="devices that must record: without a record from each within 10 s of the start "
        "(at most the duration) the file is closed and the exit status is 1; one that goes "
        "away later is reconnected (as `required: true` on a device of the configuration)",
    )
    rec.add_argument(
        "--live",
        nargs="?",
        const=DEFAULT_ADDRESS,
        metavar="HOST:PORT",
        help="serve every channel of the log live over the Foxglove WebSocket protocol "
        f"(default {DEFAULT_ADDRESS}): in the Foxglove app or Lichtblick, Open connection, "
        "Foxglove WebSocket, ws://HOST:PORT. Another host than loopback is reachable from "
        "the network without authentication (a warning says so). A client that does not "
        "keep up loses its oldest messages; the log loses nothing",
    )
    rec.add_argument(
        "--live-image-hz",
        type=real(0, 1000, what="Hz"),
        metavar="HZ",
        help="camera frames sent to live clients per second and camera, at most (default 5; "
        "0: none); the log keeps every frame",
    )
    rec.add_argument(
        "--live-swath-s",
        type=real(0, 3600, lo_open=True, what="seconds"),
        metavar="S",
        help="with --live: the seconds of coloured scans in /live/swath, the street as it "
        "builds up, placed with the rig's odometry or GNSS (in the laser frame without "
        "them), 2 Hz, at most 300,000 points (default 30)",
    )
    rec.add_argument(
        "--log-colored",
        action="store_true",
        help="also write each scan coloured live (/<scanner>/colored, foxglove.PointCloud) "
        "into the log; off by default: `acq colorize` colours better after the drive "
        "(re-timing, the best view, colour balance)",
    )
    rec.add_argument(
        "--calib",
        type=Path,
        metavar="CALIB",
        help="the rig's calibration (calib.yaml) instead of the configuration's "
        "`calibration:`: its /tf_static and camera calibrations go into the log, and with "
        "--live or --log-colored each scan is coloured as it comes from every camera in "
        "it (the nearest frame in time, motion compensated with the rig's odometry or GNSS)",
    )
    rec.add_argument("-v", "--verbose", action="store_true", help="debug log lines")
    rec.add_argument(
        "--status",
        action="store_true",
        help="print the recorder's status each second (each device's rate, drops, disk "
        "left: what systemd's STATUS= gets) when stderr is not a terminal too, a line "
        "each; in a terminal it is always shown, on the last line under the log lines",
    )
    rec.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from acq.errors import InputValueError
    from acq.record import config as configfile
    from acq.record import recorder

    recorder.setup_logging(args.verbose)
    line = _status_line(args.status)
    if args.config is None:  # the shipped simulated rig, recording below the working folder
        cfg = configfile.load(configfile.shipped())
        out = args.out if args.out is not None else Path("logs")
    else:
        cfg, out = configfile.load(args.config), args.out
    listeners = []
    if args.live is None and args.live_image_hz is not None:
        raise InputValueError("--live-image-hz: only with --live")
    if args.live is None and args.live_swath_s is not None:
        raise InputValueError("--live-swath-s: only with --live")
    calib = None
    if args.calib is not None:
        from acq.camera import calibfile

        calib = calibfile.load(args.calib)
    server = None
    if args.live is not None:
        from acq.addresses import is_loopback
        from acq.cli.exposure import every_interface, warn_if_exposed
        from acq.record import live

        try:
            host, port = live.parse_address(args.live)
        except InputValueError as e:
            raise InputValueError(f"--live: {e}") from None
        warn_if_exposed("acq record", "--live", args.live)
        if not is_loopback(host) and not every_interface(args.live):
            print(
                f"acq record: warning: --live {args.live}: not loopback; the live server "
                "is reachable from the network, without authentication",
                file=sys.stderr,
            )
        hz = 5.0 if args.live_image_hz is None else args.live_image_hz
        server = live.LiveServer(host, port, image_hz=hz)
        recorder.log.info("live server on ws://%s:%d (Foxglove WebSocket)", host, server.port)
        listeners.append(server)
    from acq.record.status_line import TerminalNotifier

    colouring = None
    if server is not None or args.log_colored:
        from acq.record.live_colour import ColourSettings
        from acq.record.swath import SPAN_S

        swath_s = SPAN_S if args.live_swath_s is None else args.live_swath_s
        colouring = ColourSettings(log=args.log_colored, server=server, swath_s=swath_s)

    try:
        return recorder.record(
            cfg, out_dir=out, duration_s=args.duration, required=args.require,
            listeners=listeners, notifier=None if line is None else TerminalNotifier(line),
            calibration=calib, colouring=colouring,
        )  # fmt: skip
    except recorder.UnknownDevice as e:
        raise InputValueError(f"--require: {e}") from None
    finally:
        for listener in listeners:
            listener.stop()
        if line is not None:
            line.erase()


def _status_line(asked: bool) -> StatusLine | None:
    """The status line on stderr when it is a terminal (or when ``asked``), the log lines
    printed above it; None otherwise (systemd's journal: it has STATUS=)."""
    from acq.record.status_line import StatusLine, StatusLineHandler

    terminal = sys.stderr.isatty()
    if not (terminal or asked):
        return None
    line = StatusLine(sys.stderr, in_place=terminal)
    root = logging.getLogger()
    root.handlers[:] = [StatusLineHandler(h, line) for h in root.handlers]
    return line
