"""`acq replay`: serve a log back through simulated devices on their real transports."""

from __future__ import annotations

import argparse
import contextlib
import logging
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from acq import progress
from acq.atomic_write import write_text
from acq.cli import output_files
from acq.cli.exposure import warn_if_exposed
from acq.cli.option_types import real
from acq.cli.output_files import Output
from acq.errors import InputError
from acq.stop_signals import handling, signal_name

if TYPE_CHECKING:
    from acq.sim.replay import Replay

HELP = "serve a log back through simulated devices on their real transports"


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    replay = sub.add_parser(
        "replay",
        help=HELP,
        description="Serve recorded logs (the split files of one session, in order) back "
        "through simulated devices: each scanner's raw telegrams byte for byte over SCIP "
        "(TCP, or a pseudo-terminal with --pty) or CoLa (TCP), each camera's JPEG bytes as "
        "MJPEG over HTTP, the vehicle's CAN frames on python-can udp_multicast (TTL 0: on "
        "this host) and the GNSS receiver's NMEA sentences on TCP, at their recorded "
        "receive times. Prints the devices' URLs and a "
        "configuration for `acq record -c`. The replay starts when a client first asks a "
        "device for data, and ends with the log (or Ctrl-C / SIGTERM). An address on every "
        "interface (0.0.0.0, ::) is warned of: the devices have no authentication. "
        + output_files.RULE
        + " Exit status: 0 served, 1 runtime failure, 2 bad log or "
        "address.",
    )
    replay.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="MCAP files in order, or a folder"
    )
    replay.add_argument(
        "--speed", type=real(0.01, 1000, what="a speed"), default=1.0, metavar="X",
        help="playback speed (default 1, the recorded pace; 2 plays twice as fast)",
    )  # fmt: skip
    replay.add_argument(
        "--listen", metavar="tcp://HOST:PORT",
        help="the first scanner's address, the next scanners and the GNSS receiver on the "
        "following ports "
        "(default: 127.0.0.1, free ports)",
    )  # fmt: skip
    replay.add_argument(
        "--pty", action="store_true", help="Hokuyo scanners on pseudo-terminals instead of TCP"
    )
    replay.add_argument(
        "--camera-listen", metavar="http://HOST:PORT/PATH",
        help="the first camera's address, the next ones on the following ports "
        "(default: http://127.0.0.1, free ports, /stream.mjpg)",
    )  # fmt: skip
    replay.add_argument(
        "--config-out", type=Path, metavar="YAML",
        help="write the recorder configuration here (and the log's calibration beside it: "
        "NAME.calib.yaml for NAME.yaml) instead of printing it",
    )  # fmt: skip
    replay.add_argument(
        "--force", action="store_true",
        help="replace an existing --config-out (and its calibration), keeping NAME.bak",
    )  # fmt: skip
    replay.set_defaults(handler=run)


def _describe_session(replay: Replay) -> str:
    s = replay.session
    parts = []
    for d in s.devices.values():
        what = {"scanner": "scans", "gnss": "sentences", "can": "CAN frames"}.get(d.kind, "frames")
        parts.append(f"{d.name}: {len(d.times_ns)} {what} at {d.rate_hz:.1f} Hz ({d.driver})")
    files = f"{len(s.files)} file" + ("s" if len(s.files) != 1 else "")
    return f"replaying {files}, {s.duration_s:.1f} s at speed {replay.speed:g}: " + "; ".join(parts)


def _calibration_beside(config: Path) -> Path:
    """Where --config-out's calibration goes: ``NAME.calib.yaml`` beside it."""
    return config.with_name(config.stem + ".calib.yaml")


def _write(path: Path, text: str, backups: list[Output]) -> None:
    """Write ``path`` atomically, keeping the old file first when it is to be replaced."""
    output_files.keep_backups("acq replay", [o for o in backups if o.path == path])
    write_text(path, text)


def _serve_with_a_bar(replay: Replay, stop: threading.Event) -> None:
    """Until the log has been served or ``stop``: a bar of the log served (counted in ms,
    shown in seconds)."""
    done, total = 0, round(replay.session.duration_s * 1000)
    with progress.bar(total, "s", "replaying", scale=0.001):
        while not stop.is_set() and not replay.wait(0.2):
            served = round(replay.served_s() * 1000)
            progress.advance(served - done, "s")
            done = served
        if not stop.is_set():
            progress.advance(total - done, "s")


def run(args: argparse.Namespace) -> int:
    """Serve the logs until they end or Ctrl-C / SIGTERM. Prints the devices' URLs and a
    configuration for ``acq record -c`` (or writes it to --config-out, with the recorded
    calibration beside it when the log holds one)."""
    from acq.record import config as configfile
    from acq.sim.replay import Replay, log

    speed, write_config = args.speed, args.config_out
    logging.getLogger().setLevel(logging.INFO)  # what it serves, where, and when it ends
    warn_if_exposed("acq replay", "--listen", args.listen)
    warn_if_exposed("acq replay", "--camera-listen", args.camera_listen)
    backups: list[Output] = []
    if write_config is not None:
        outputs = [
            Output("--config-out", write_config, "yaml"),
            Output("--config-out", _calibration_beside(write_config), "yaml"),
        ]
        backups = output_files.check([("LOG", p) for p in args.logs], outputs, force=args.force)
    replay = Replay(
        args.logs, speed=speed, scanner_listen=args.listen, pty=args.pty,
        camera_listen=args.camera_listen,
    )  # fmt: skip
    try:
        replay.start()
    except ValueError as e:  # a bad listen address
        raise InputError(str(e)) from None
    except OSError as e:
        raise OSError(e.errno, f"cannot serve: {e.strerror or e}") from e
    stop = threading.Event()
    signals = contextlib.ExitStack()
    if threading.current_thread() is threading.main_thread():
        # every signal that would end the process (a dropped ssh link's SIGHUP too):
        # the devices close their connections and the command ends as at the log's end
        def _stop(signum: int, _frame: object) -> None:
            log.info("%s: the replay stops", signal_name(signum))
            stop.set()

        signals.enter_context(handling(_stop))
    try:
        print(_describe_session(replay))
        for name, url in replay.urls.items():
            print(f"  {name}: {url}")
        calibration = None
        if write_config is not None and replay.session.calibration_yaml:
            rec = replay.session.config
            if rec is None or rec.calibration is None or not rec.calibration.exists():
                calibration = _calibration_beside(write_config)
                _write(calibration, replay.session.calibration_yaml, backups)
                print(f"wrote the recorded calibration to {calibration}")
        text = configfile.dump(
            replay.config(calibration=calibration.resolve() if calibration else None)
        )
        if write_config is not None:
            _write(write_config, text, backups)
            print(f"wrote the configuration to {write_config}: acq record -c {write_config}")
        else:
            print("configuration for `acq record -c FILE` (--config-out writes it):")
            print(text, end="")
        print("the replay starts when a client asks a device for data", flush=True)
        while not stop.is_set() and not replay.wait(0.2):
            if replay.started:
                log.info("started: the log plays for %.1f s", replay.session.duration_s / speed)
                _serve_with_a_bar(replay, stop)
                break
        if replay.wait(0):
            log.info(
                "the log has been served to its end: %s",
                ", ".join(f"{k} {v}" for k, v in replay.sent().items()),
            )
        return 0
    finally:
        replay.close()
        signals.close()
