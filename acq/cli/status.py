"""`acq status`: a running recorder's state, read from the log it writes or from its
live server."""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from acq.cli.option_types import real

if TYPE_CHECKING:
    from acq.monitor.snapshot import Source

HELP = "a running recorder's devices, time base, disk and file, refreshed each second"
DEFAULT_FOLDER = Path("logs")  # where `acq record` without -c records, below the working folder
# HOST:PORT, [IPv6]:PORT: a live server (a path of that form that exists is a log)
ADDRESS = re.compile(r"(\[[0-9A-Fa-f:.%\w]+\]|[\w.-]+):\d+")
FIRST_STATUS_S = 4.0  # a live server's first /acq/status comes within a second or so, s


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "status",
        help=HELP,
        description="Show a running recorder, from its live server (HOST:PORT: `acq "
        "record --live HOST:PORT`, the recorder possibly on another host) or from the log "
        "it is writing: each device's "
        "rate, drops, time since its last record (gap), clock-sync uncertainty and drift, "
        "and last event (the recorder's /acq/status, 1 Hz); the host clock's time base "
        "(/acq/timebase); the file being written, its size and write rate; the disk's "
        "minutes left above the recorder's reserve at that rate; when the recorder colours "
        "live, the share of the last scans' points coloured, per camera, and the scans it "
        "skipped. From a log, only what the recorder adds each second is read, and its "
        "new files are followed as it rolls them; from a live server, the recorder's "
        "file name and disk figures (no file size or write rate). A "
        "terminal gets a full-screen view refreshed each second until Ctrl-C; any other "
        "output one plain snapshot. A log no longer being written is shown in its last "
        "state. Exit status with --json (and for the plain snapshot): 0 all well, 1 a "
        "device silent for more than --stale-s s, a required device disconnected, or a "
        "running recorder silent for --stale-s, or a live server that cannot be reached "
        "or does not speak the Foxglove protocol; 2 no log found, or a bad HOST:PORT.",
    )
    p.add_argument(
        "log",
        nargs="?",
        metavar="LOG_OR_FOLDER_OR_HOST:PORT",
        help="a log, or a folder: its newest session's newest file (default: -c's "
        "output.dir; without -c, the live server of `acq record --live` on this host, "
        "127.0.0.1:8765, when one runs, else ./logs, where `acq record` without -c "
        "records, when it exists, else the current folder); or HOST:PORT ([IPv6]:PORT), "
        "the live server of `acq record --live` (e.g. 127.0.0.1:8765), when no file of "
        "that name exists",
    )
    p.add_argument(
        "-c",
        "--config",
        type=Path,
        help="a recorder configuration: follow the newest log in its output.dir",
    )
    p.add_argument(
        "--json", action="store_true", help="print one snapshot as JSON (for scripts) and exit"
    )
    p.add_argument(
        "--stale-s",
        type=real(0.5, 3600, what="seconds"),
        default=5.0,
        metavar="S",
        help="a device without a record for longer than S seconds is down (default 5)",
    )
    p.set_defaults(handler=run)


def _source(args: argparse.Namespace) -> Source:
    """The live server when the argument is HOST:PORT (and no such file), else the log."""
    from acq.monitor.log_source import LogSource

    given = args.log
    if given is not None and ADDRESS.fullmatch(given) and not Path(given).exists():
        from acq.errors import InputValueError
        from acq.monitor.live_source import LiveSource
        from acq.record.live import parse_address

        if args.config is not None:
            raise InputValueError("-c: only with a log folder, not with a live server's HOST:PORT")
        source = LiveSource(*parse_address(given))
        source.wait_status(FIRST_STATUS_S)
        return source
    if given is not None:
        return LogSource(Path(given))
    if args.config is not None:
        from acq.record import config as configfile

        return LogSource(configfile.load(args.config).output.dir)
    from acq.cli.record import DEFAULT_ADDRESS

    if _listening(DEFAULT_ADDRESS):  # `acq record --live` on this host
        args.log = DEFAULT_ADDRESS
        return _source(args)
    return LogSource(DEFAULT_FOLDER if DEFAULT_FOLDER.is_dir() else Path("."))


def _listening(address: str) -> bool:
    """Whether something accepts TCP connections at ``address`` (HOST:PORT) at once."""
    import socket

    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host, int(port)), timeout=0.5):
            return True
    except OSError:
        return False


def run(args: argparse.Namespace) -> int:
    source = _source(args)
    try:
        return _show(source, args)
    finally:
        source.close()


def _show(source: Source, args: argparse.Namespace) -> int:
    """One snapshot (JSON, or plain text off a terminal), or the full-screen view."""
    from acq.json_text import dumps
    from acq.monitor.snapshot import problems
    from acq.monitor.view import as_json, render

    if args.json or not sys.stdout.isatty():
        snap = source.snapshot()
        if args.json:
            print(dumps(as_json(snap, args.stale_s), what="acq status --json"))
        else:
            from rich.console import Console

            # a pipe or a file: lines as long as the table needs, no escape codes
            Console(highlight=False, width=160, no_color=True).print(render(snap, args.stale_s))
        return 1 if problems(snap, args.stale_s) else 0
    from rich.live import Live

    from acq.stopped import stopping

    # Ctrl-C, and every signal that would end the process (SIGTERM, SIGHUP of a closed
    # window), leave the view through Live's exit: the terminal given back as it was
    try:
        with (
            stopping(),
            Live(render(source.snapshot(), args.stale_s), screen=True, auto_refresh=False) as live,
        ):
            while True:
                time.sleep(1.0)
                live.update(render(source.snapshot(), args.stale_s), refresh=True)
    except KeyboardInterrupt:
        return 0
