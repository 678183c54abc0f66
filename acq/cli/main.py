"""The `acq` command line: the parser root, and the one place where an error becomes a
line on stderr and an exit status.

Exit status: 0 success; 2 bad usage or bad input (a bad option or value, refused while
the command line is parsed, or :class:`acq.errors.InputError`: one line naming the
option, or the file and the key); 1 a runtime failure (any other error: one line, the
traceback with ``--debug``); 3 an output that did not fit on its disk (``acq record``:
the disk below its reserve); 130 Ctrl-C; a command that writes files (``stops_cleanly``)
stopped by a signal: 128 + its number, its temporaries removed and one line said. A
closed stdout (``acq info LOG | head``) ends the command quietly.

Each command's module imports the library it calls inside its handler, and only the
command named is given its arguments (their choices come from the driver registry, the
simulator and the cloud package): `python -X importtime -m acq.cli record --help` spends
about 0.06 s importing, against 0.24 s with every command's parser built and 0.44 s with
every library the commands call imported at the top (best of 5 and of 3, a loaded
2-core machine).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import os
import sys
import traceback
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, NoReturn

from acq import __version__, progress
from acq.cli import (
    analyze,
    calibrate,
    colorize,
    demo,
    devices,
    export,
    info,
    mesh,
    probe,
    record,
    replay,
    sim,
    status,
    view,
)
from acq.cli.standard_streams import reopen_closed
from acq.credentials import RedactingFilter, redact
from acq.errors import AcqError, DiskFullError, InputError
from acq.stopped import Stopped, stopping

if TYPE_CHECKING:
    from _typeshed import SupportsWrite

__all__ = ["build_parser", "main"]

# in the order `acq --help` lists them
COMMANDS: dict[str, ModuleType] = {
    "demo": demo,
    "sim": sim,
    "probe": probe,
    "record": record,
    "info": info,
    "status": status,
    "replay": replay,
    "colorize": colorize,
    "mesh": mesh,
    "view": view,
    "export": export,
    "calibrate": calibrate,
    "analyze": analyze,
    "devices": devices,
}
VERSION = f"acq {__version__}"
EXIT_FAILURE, EXIT_USAGE, EXIT_DISK_FULL, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 1, 2, 3, 130, 141


class _Parser(argparse.ArgumentParser):
    """argparse's parser, its usage errors one line (``acq colorize: argument --chunk:
    expected seconds in [1, 600], got 'nan'``) and exit status 2; its sub-parsers too.
    Options are taken by their whole names only: a prefix (``--camera`` for
    ``--camera-height``) is no option."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        _say(self.prog, message)
        raise SystemExit(EXIT_USAGE)

    def _print_message(self, message: str, file: SupportsWrite[str] | None = None) -> None:
        # argparse's own ignores a failed write: --help on a full disk would exit 0
        if message:
            (file or sys.stderr).write(message)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole parser; with ``only``, every command but that one without its arguments
    (what its --help and its run need, without importing what the others list)."""
    p = _Parser(
        prog="acq",
        description="Mobile-mapping acquisition: laser scanner + fisheye cameras, "
        "synchronised, logged, calibrated and coloured.",
    )
    p.add_argument("--version", action="version", version=VERSION)
    p.add_argument(
        "--debug", action="store_true", help="a runtime failure's traceback, not one line"
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in COMMANDS.items():
        if only is None or name == only:
            module.add_parser(sub)
        else:
            sub.add_parser(name, help=module.HELP)
    _add_common(p, top=True)
    return p


def _add_common(parser: argparse.ArgumentParser, top: bool = False) -> None:
    """--version and --debug on every sub-command too; ``_prog`` names the command in
    error lines (``acq calibrate fisheye: ...``)."""
    if not top:
        parser.add_argument("--version", action="version", version=VERSION)
        if "logs" in {a.dest for a in parser._actions}:
            parser.add_argument(
                "--progress", action="store_true",
                help="progress bars even when stderr is not a terminal (reading the logs, "
                "and the command's own work)",
            )  # fmt: skip
        parser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                            help=argparse.SUPPRESS)  # fmt: skip
    parser.set_defaults(_prog=parser.prog)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _add_common(child)


def _command(argv: Sequence[str]) -> str | None:
    """The command named in ``argv`` (its first word that is one), None for none."""
    return next((a for a in argv if a in COMMANDS), None)


def main(argv: Sequence[str] | None = None) -> int:
    """Run `acq` with ``argv`` (default: the process's); the exit status."""
    reopen_closed()  # a closed stdout (`acq record >&-`) is /dev/null, not the next file
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser(_command(argv) or "").parse_args(argv)
    except SystemExit as e:  # --help, --version, or a usage error (its line printed)
        return _flushed("acq", e.code if isinstance(e.code, int) else EXIT_USAGE)
    except OSError as e:  # --help or --version into a closed or full stdout
        return _flushed("acq", EXIT_FAILURE, e)
    handler: Callable[[argparse.Namespace], int] = args.handler
    prog: str = args._prog
    _log_lines(prog)
    # what the imports made lives as long as the process: out of the collector's scans
    # (its full collections otherwise walk it again while a log's messages are read)
    gc.freeze()
    logs: Sequence[os.PathLike[str]] = getattr(args, "logs", None) or []
    try:
        if logs:
            logs = _log_inputs(args, logs)
        progress.enable(progress.wanted(getattr(args, "progress", False)))
        stops = stopping() if getattr(args, "stops_cleanly", False) else contextlib.nullcontext()
        with stops, progress.reading(logs):
            code = handler(args)
        sys.stdout.flush()  # a closed or full stdout fails here, not at exit
        return code
    except InputError as e:
        _say(prog, str(e))
        return EXIT_USAGE
    except Stopped as e:
        _drop_stdout()
        with contextlib.suppress(OSError):  # SIGHUP: the terminal may be gone
            _say(prog, f"stopped by {e.name}: the file being written removed, its old output kept")
        return e.exit_status
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader went away (`acq info LOG | head`): nothing to say
        _drop_stdout()
        return EXIT_BROKEN_PIPE
    except Exception as e:
        _drop_stdout()
        full = e if isinstance(e, DiskFullError) else _full_disk(e)
        if full is not None:
            _say(prog, str(full))
            return EXIT_DISK_FULL
        if args.debug:
            traceback.print_exc()
        _say(prog, _describe(e, args.debug))
        return EXIT_FAILURE


def _full_disk(e: Exception) -> DiskFullError | None:
    """A file error of a full disk (a quota, a size limit) as the line naming the file
    and its disk; None for any other."""
    from acq.disk_space import FULL_DISK_ERRNOS, full_disk_error

    if isinstance(e, OSError) and e.errno in FULL_DISK_ERRNOS and e.filename:
        return full_disk_error(Path(os.fsdecode(e.filename)), e)
    return None


def _log_inputs(args: argparse.Namespace, logs: Sequence[os.PathLike[str]]) -> list[Path]:
    """The files a command's LOG arguments (files or folders) name, for its progress bar;
    ``args.logs`` becomes them, one session's (:func:`acq.log.inputs.session_files`:
    InputError naming each session otherwise), unless the command takes several
    sessions (``sessions_apart``: it resolves them itself)."""
    from acq.log.inputs import log_files, session_files

    if getattr(args, "sessions_apart", False):
        return log_files(logs)
    args.logs = session_files(logs)
    return list(args.logs)


def _log_lines(prog: str) -> None:
    """Library warnings as the command's own lines on stderr (``acq colorize: X.mcap: 1
    corrupt chunk skipped ...``), unless something already takes them (``acq record``
    sets its own; a test's log capture)."""
    root = logging.getLogger()
    if root.handlers:
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{prog}: %(message)s"))
    handler.addFilter(RedactingFilter())
    root.addHandler(handler)
    root.setLevel(logging.WARNING)
    warnings.showwarning = _warning_line


def _warning_line(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: object = None,
    line: str | None = None,
) -> None:
    """A library's warning (numpy's RuntimeWarning...) as one of the command's lines,
    not Python's two lines of source."""
    logging.getLogger("py.warnings").warning(
        "warning: %s: %s (%s, line %d)", category.__name__, message, Path(filename).name, lineno
    )


def _flushed(prog: str, code: int, failed: OSError | None = None) -> int:
    """``code`` once stdout is written out, unless writing it ``failed`` or fails now: a
    closed stdout ends quietly (141), a full one is a failure (one line, 1)."""
    try:
        if failed is not None:
            raise failed
        sys.stdout.flush()
    except BrokenPipeError:
        _drop_stdout()
        return EXIT_BROKEN_PIPE
    except OSError as e:
        _drop_stdout()
        _say(prog, _describe(e, False))
        return EXIT_FAILURE
    return code


def _describe(e: Exception, debug: bool) -> str:
    """One line for a runtime failure: its message; a file error's file and reason; an
    unexpected error (a bug) with its type and where to see more."""
    if isinstance(e, OSError) and e.strerror:
        where = e.filename if e.filename is not None else ""
        return f"{where}: {e.strerror}" if where else e.strerror
    if isinstance(e, AcqError):
        return str(e)
    text = str(e.args[0]) if isinstance(e, KeyError) and e.args else str(e)
    first = text.splitlines()[0] if text else ""
    hint = "" if debug else " (a bug? --debug shows the traceback)"
    return f"{type(e).__name__}: {first}{hint}"


def _say(prog: str, message: str) -> None:
    print(f"{prog}: {redact(message)}", file=sys.stderr, flush=True)


def _drop_stdout() -> None:
    """Send what stdout still holds to /dev/null, so the interpreter's last flush of a
    closed pipe or a full disk does not fail again at exit."""
    try:
        sys.stdout.flush()
    except OSError:
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)
        except (OSError, ValueError):  # a stdout with no descriptor (a test's capture)
            pass
