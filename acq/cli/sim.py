"""`acq sim render|scanner|camera|rig`: the synthetic street and its simulated devices."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from acq.atomic_write import write_text
from acq.cli import output_files, sim_logs
from acq.cli.camera_option import add_camera_option
from acq.cli.exposure import warn_if_exposed
from acq.cli.option_types import SEED, real
from acq.cli.output_files import Output
from acq.errors import InputError

HELP = "simulated street and devices"
RENDERED = (("frame.png", "image"), ("overlay.png", "image"), ("calib.yaml", "yaml"),
            ("summary.json", "json"))  # fmt: skip


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from acq.sim.scanner_models import MODELS

    sim = sub.add_parser("sim", help=HELP)
    sim_sub = sim.add_subparsers(dest="sim_command", metavar="SIM_COMMAND", required=True)
    render = sim_sub.add_parser(
        "render",
        help="render a fisheye frame and the laser profile of the same instant",
        description="Render the synthetic street at one instant: the fisheye frame "
        "(frame.png), the same frame with the laser points of that instant drawn in the "
        "colours the projection core gives them (overlay.png), the true calibration "
        "(calib.yaml) and a summary (summary.json). " + output_files.RULE,
    )
    render.add_argument("--out", required=True, help="output folder (created if missing)")
    render.add_argument(
        "--time", type=real(0, 36, what="seconds"), default=2.0,
        help="time on the drive, s, on the street's 200 m at 20 km/h (default 2)",
    )  # fmt: skip
    render.add_argument("--seed", type=SEED, default=0, help="street seed")
    render.add_argument(
        "--force",
        action="store_true",
        help="replace an existing calib.yaml (keeping a .bak) and outputs that acq did not write",
    )
    render.add_argument(
        "--equidistant",
        action="store_true",
        help="an exactly equidistant lens instead of the default with small k1..k4",
    )
    add_camera_option(
        render, "the simulated camera to render", named="camera (the one-camera rig's) or "
        "left, right, rear (the three-camera rig's)", default="camera",
    )  # fmt: skip
    render.set_defaults(handler=run_render)

    sim_logs.add_parser(sim_sub)
    simscan = sim_sub.add_parser(
        "scanner",
        help="serve one simulated scanner for any client",
        description="Serve one simulated laser scanner that speaks the real device's "
        "protocol (SCIP 2.0/2.2 or CoLa-A/B) over TCP or a pseudo-terminal, scanning the "
        "synthetic street. Runs until Ctrl-C or SIGTERM.",
    )
    simscan.add_argument("--model", required=True, choices=sorted(MODELS), help="device model")
    where = simscan.add_mutually_exclusive_group()
    where.add_argument(
        "--listen", help="tcp://HOST:PORT to listen on (default: 127.0.0.1, a free port)"
    )
    where.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal (SCIP)")
    simscan.add_argument(
        "--protocol", choices=["cola-b", "cola-a"], default="cola-b",
        help="SICK models: the CoLa dialect the device starts in (default cola-b)",
    )  # fmt: skip
    simscan.add_argument(
        "--drift-ppm", type=real(-1000, 1000, what="ppm"), default=0.0,
        help="device clock drift, ppm (default 0)",
    )  # fmt: skip
    simscan.add_argument("--seed", type=SEED, default=0, help="street seed")
    simscan.set_defaults(handler=run_scanner)

    simcam = sim_sub.add_parser(
        "camera",
        help="serve one simulated camera as MJPEG over HTTP",
        description="Serve the simulated 185-degree fisheye, rendering the synthetic street at "
        "25 Hz on its own clock, as an MJPEG stream (multipart/x-mixed-replace) over HTTP. "
        "Runs until Ctrl-C or SIGTERM.",
    )
    simcam.add_argument(
        "--listen",
        help="http://HOST:PORT/PATH to serve on (default: 127.0.0.1, a free port, /stream.mjpg)",
    )
    simcam.add_argument("--seed", type=SEED, default=0, help="street seed")
    simcam.add_argument(
        "--still",
        action="store_true",
        help="serve the street's first view, each frame's time written on it, instead of "
        "rendering every frame (20-40 ms of a core each): a camera that keeps 25 Hz on a "
        "busy machine, for testing a link or a recorder rather than a picture",
    )
    simcam.set_defaults(handler=run_camera)
    _add_rig_parser(sim_sub)


RIG_MARK = ".acq-sim-rig"  # in a folder `acq sim rig` wrote: it may write there again
RIG_FILES = ("rig.yaml", "calib.yaml")


def _add_rig_parser(sim_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    rig = sim_sub.add_parser(
        "rig",
        help="serve the whole simulated rig (scanner, two cameras, car, GNSS) for acq record",
        description="Serve the simulated rig of `acq demo` as live devices on this host's "
        "loopback, all driving down the synthetic street from one instant: a UTM-30LX "
        "speaking SCIP over TCP, two 185-degree fisheyes (left, right) serving MJPEG over "
        "HTTP, each from its own process, the car's wheel speeds and yaw rate as CAN frames "
        "(python-can udp_multicast, TTL 0: they stay on this host) and a GNSS receiver "
        "sending NMEA over TCP. The cameras first render the frames of the drive's first "
        "--prerender seconds (later frames are rendered when due, late on a busy machine). "
        "When the devices are up it writes DIR/rig.yaml (the configuration for `acq record "
        "-c`) and DIR/calib.yaml (the rig's true calibration, for `acq colorize --calib`) "
        "and prints the commands to record and colour; DIR/rig.yaml is removed when the rig "
        "stops (its devices are gone). Runs until Ctrl-C, SIGTERM or --duration. The drive "
        "loops over the street's 1 km every 180 s: record less than that. DIR must be new, "
        f"empty or an earlier rig's (it holds {RIG_MARK}): only its own files there are "
        "replaced.",
    )
    rig.add_argument(
        "--out", default="rig", help="folder for rig.yaml and calib.yaml (default: rig)"
    )
    rig.add_argument(
        "--duration", type=real(0, 1e6, lo_open=True, what="seconds"), metavar="S",
        help="stop S seconds after it is ready (default: run until Ctrl-C)",
    )  # fmt: skip
    rig.add_argument(
        "--prerender", type=real(0, 170, what="seconds"), default=30.0, metavar="S",
        help="seconds of the drive the cameras render before it starts, at most 170 "
        "(default 30, enough to record 20 s; 93 s to start with a load of 10 on 2 cores; "
        "1.8 MB of memory a second per camera)",
    )  # fmt: skip
    rig.set_defaults(handler=run_rig)


def run_render(args: argparse.Namespace) -> int:
    from acq.sim import render

    render.check_camera(args.camera or "camera")  # before any output is touched
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; give a folder")
    outputs = [Output("--out", out / name, kind, makes_folder=True) for name, kind in RENDERED]
    output_files.keep_backups("acq sim render", output_files.check([], outputs, force=args.force))
    s = render.write(args.out, args.time, args.seed, args.equidistant, args.camera or "camera")
    print(
        f"t = {s.time_s:.3f} s: {s.laser_points} laser points with an echo, {s.in_image} on "
        f"the fisheye image ({s.occluded} hidden behind nearer objects)\n"
        f"pixel error against the truth: RMS {s.pixel_error_rms_px:.3f} px, "
        f"max {s.pixel_error_max_px:.3f} px (laser range noise included)\n"
        f"colour equal to the true surface colour: {100 * s.colour_agreement:.1f}% of the "
        f"visible points\n"
        f"wrote {out / 'frame.png'}, {out / 'overlay.png'}, {out / 'calib.yaml'}, "
        f"{out / 'summary.json'}"
    )
    return 0


def _wait_for_signal(deadline: float | None = None) -> None:
    """Block until Ctrl-C or SIGTERM, or until ``deadline`` (monotonic s)."""
    import time

    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        while not done.wait(0.5 if deadline is None else min(0.5, deadline - time.monotonic())):
            if deadline is not None and time.monotonic() >= deadline:
                break
    except KeyboardInterrupt:
        pass


def run_scanner(args: argparse.Namespace) -> int:
    from acq.sim.devices import make_scanner, parse_listen, serve_scanner

    warn_if_exposed("acq sim scanner", "--listen", args.listen)
    try:
        if args.listen is not None:
            parse_listen(args.listen)  # a bad address fails before the street is built
        m, device = make_scanner(
            args.model, seed=args.seed, drift_ppm=args.drift_ppm, protocol=args.protocol
        )
        server = serve_scanner(device, args.listen, pty=args.pty)
    except ValueError as e:  # the address or the model's options
        raise InputError(str(e)) from None
    except OSError as e:
        print(f"acq sim scanner: {args.listen}: {e.strerror or e}", file=sys.stderr)
        return 1
    driver = "hokuyo" if m.vendor == "hokuyo" else "sick"
    # pyserial's socket:// for the SCIP driver, tcp:// for a SICK device (as in a config)
    url = server.url if driver == "hokuyo" else server.url.replace("socket://", "tcp://", 1)
    print(f"simulated {m.name} ({m.protocol}) on {url}", flush=True)
    print(f"try: acq probe scanner --driver {driver} --url {url}", flush=True)
    try:
        _wait_for_signal()
    finally:
        server.close()
    return 0


def run_camera(args: argparse.Namespace) -> int:
    from acq.sim.mjpeg_server import serve_camera

    warn_if_exposed("acq sim camera", "--listen", args.listen)
    try:
        server = serve_camera(args.listen, seed=args.seed, still=args.still)
    except ValueError as e:  # the address
        raise InputError(str(e)) from None
    except OSError as e:
        print(f"acq sim camera: {args.listen}: {e.strerror or e}", file=sys.stderr)
        return 1
    print(f"simulated fisheye camera (MJPEG over HTTP) on {server.url}", flush=True)
    print(f"try: acq probe camera --driver opencv --source {server.url}", flush=True)
    try:
        _wait_for_signal()
    finally:
        server.close()
    return 0


def _interrupt(*_: object) -> None:
    raise KeyboardInterrupt


def run_rig(args: argparse.Namespace) -> int:
    import time

    import yaml

    from acq.camera import calibfile
    from acq.sim.demo_rig import CAMERAS, SimRig, rig_config, true_calibration
    from acq.sim.out_folder import claim_folder, record_files

    out = Path(args.out)
    claim_folder(out, RIG_MARK, "an acq sim rig", RIG_FILES)
    config_path, calib_path = out / "rig.yaml", out / "calib.yaml"
    config_path.unlink(missing_ok=True)  # an earlier rig's: its devices are gone
    print(
        f"acq sim rig: a simulated UTM-30LX, two 185-degree fisheyes ({', '.join(CAMERAS)}), "
        "the car's CAN bus and a GNSS receiver on the synthetic street, on this host's "
        f"loopback; the cameras first render {args.prerender:g} s of frames",
        flush=True,
    )
    signal.signal(signal.SIGTERM, _interrupt)  # while the cameras render: stop them too
    rig = SimRig(prerender_s=args.prerender, loopback=True, gnss=True)
    try:
        for name, url in rig.urls.items():
            print(f"  {name}: {url}", flush=True)
        calibfile.save(true_calibration(), calib_path)
        data = rig_config(rig, Path(calib_path.name), {"dir": "logs", "prefix": "rig"})
        write_text(
            config_path,
            "# `acq sim rig`'s devices, while it runs (it removes this file when it stops)\n"
            + yaml.safe_dump(data, sort_keys=False),
        )
        record_files(out, RIG_MARK, "an acq sim rig", RIG_FILES)
        print(
            f"wrote {config_path} and {calib_path} (the rig's true calibration)\n"
            f"record it: acq record -c {config_path} --out logs --duration 20\n"
            f"colour it: acq colorize logs/rig_*.mcap --calib {calib_path} -o cloud.ply\n"
            + (
                f"the rig stops in {args.duration:g} s"
                if args.duration
                else "the rig runs until Ctrl-C"
            ),
            flush=True,
        )
        _wait_for_signal(None if args.duration is None else time.monotonic() + args.duration)
    finally:
        rig.close()
        config_path.unlink(missing_ok=True)
        record_files(out, RIG_MARK, "an acq sim rig", RIG_FILES)
    print(f"acq sim rig: stopped; removed {config_path}", flush=True)
    return 0
