"""The `acq` command line: one sub-command per job, each with its own --help.

Exit codes: 0 success, 2 bad usage or bad input (one line naming the file and the key),
1 a runtime failure.
"""

from __future__ import annotations

import argparse
import gc
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from acq import __version__

Handler = Callable[[argparse.Namespace], int]


class UsageError(Exception):
    """Bad input from the user: printed as one line, exit status 2."""


def _demo(args: argparse.Namespace) -> int:
    from acq.sim import demo

    return demo.run(Path(args.out), args.seconds)


def _sim_render(args: argparse.Namespace) -> int:
    from acq.sim import render

    return render.run(
        out=args.out, time_s=args.time, seed=args.seed, exact_equidistant=args.equidistant
    )


def _probe_scanner(args: argparse.Namespace) -> int:
    from acq.record.probe import probe_scanner

    if args.count < 0:
        raise UsageError(f"--count {args.count}: expected 0 or more")
    return probe_scanner(args.driver, args.url, args.count, args.json, args.timeout)


def _sim_scanner(args: argparse.Namespace) -> int:
    from acq.sim.devices import make_scanner, parse_listen, serve_scanner

    try:
        if args.listen is not None:
            parse_listen(args.listen)  # a bad address fails before the street is built
        m, device = make_scanner(
            args.model, seed=args.seed, drift_ppm=args.drift_ppm, protocol=args.protocol
        )
        server = serve_scanner(device, args.listen, pty=args.pty)
    except ValueError as e:
        raise UsageError(str(e)) from None
    except OSError as e:
        print(f"acq sim scanner: {args.listen}: {e.strerror or e}", file=sys.stderr)
        return 1
    driver = "hokuyo" if m.vendor == "hokuyo" else "sick"
    print(f"simulated {m.name} ({m.protocol}) on {server.url}", flush=True)
    print(f"try: acq probe scanner --driver {driver} --url {server.url}", flush=True)
    try:
        _wait_for_signal()
    finally:
        server.close()
    return 0


def _probe_camera(args: argparse.Namespace) -> int:
    from acq.record.probe import probe_camera

    if args.count < 1:
        raise UsageError(f"--count {args.count}: expected 1 or more")
    return probe_camera(
        args.driver, args.source, args.count, args.json, args.snapshot, args.fps, args.timeout
    )


def _wait_for_signal() -> None:
    """Block until Ctrl-C or SIGTERM."""
    import signal
    import threading

    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        while not done.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass


def _sim_camera(args: argparse.Namespace) -> int:
    from acq.sim.camera_device import serve_camera

    try:
        server = serve_camera(args.listen, seed=args.seed)
    except ValueError as e:
        raise UsageError(str(e)) from None
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


def _record(args: argparse.Namespace) -> int:
    from acq.record import config as configfile
    from acq.record import recorder

    recorder.setup_logging(args.verbose)
    try:
        if args.config is None:  # the shipped simulated rig, recording below the working folder
            cfg = configfile.load(configfile.shipped())
            out = args.out if args.out is not None else Path("logs")
        else:
            cfg, out = configfile.load(args.config), args.out
        return recorder.record(cfg, out_dir=out, duration_s=args.duration)
    except configfile.ConfigError as e:
        raise UsageError(str(e)) from None
    except recorder.RecorderError as e:
        raise UsageError(str(e)) from None


def _info(args: argparse.Namespace) -> int:
    from acq.log import loginfo

    try:
        if args.repair:
            for src in args.logs:
                dst = args.output if args.output else src.with_suffix(".repaired.mcap")
                n = loginfo.repair(src, dst)
                print(f"{src} -> {dst}: {n} messages, indexed")
            return 0
        print(loginfo.format_info(loginfo.info_many(args.logs), json=args.json))
    except loginfo.LogError as e:
        raise UsageError(str(e)) from None
    except FileExistsError as e:
        raise UsageError(f"{e.filename}: exists; not overwritten") from None
    return 0


def views_choices() -> tuple[str, ...]:
    from acq.cloud.views import VIEWS

    return VIEWS


def _colorize(args: argparse.Namespace) -> int:
    from acq.cloud.colorize import main_colorize

    return main_colorize(args)


def _replay(args: argparse.Namespace) -> int:
    from acq.sim.replay import replay_main

    return replay_main(
        args.logs, args.speed, args.listen, args.pty, args.camera_listen, args.config_out
    )


def _calibrate_fisheye(args: argparse.Namespace) -> int:
    from acq.calib.fisheye_calib import main_fisheye

    return main_fisheye(
        args.images, args.fov, args.output, camera=args.camera, ellipse=args.ellipse,
        json_out=args.json, overlay=args.overlay, board=args.board,
    )  # fmt: skip


def _calibrate_extrinsic(args: argparse.Namespace) -> int:
    from acq.calib.extrinsic_log import main_extrinsic

    return main_extrinsic(
        args.logs, args.camera, args.intrinsics, args.board, args.output, args.poses,
        args.json, args.plot, lens_swap=args.lens_swap, pupil_shift_m=args.pupil_shift,
    )  # fmt: skip


def _calibrate_time_offset(args: argparse.Namespace) -> int:
    from acq.calib.time_offset import main_time_offset

    return main_time_offset(args)


def _time_offset_arg(text: str) -> float | str:
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds or 'auto', got {text!r}") from None


def _calibrate_validate(args: argparse.Namespace) -> int:
    from acq.calib.validate import main_validate

    return main_validate(args.logs, args.calib, args.camera, args.json, args.out)


def _sigma_arg(text: str) -> tuple[str, float]:
    from acq.calib.sensitivity import parse_sigma

    try:
        return parse_sigma(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e).removeprefix("--sigma ")) from None


def _analyze_sensitivity(args: argparse.Namespace) -> int:
    from acq.calib.sensitivity import main_sensitivity

    return main_sensitivity(
        args.calib, args.logs, args.output, args.camera_height, args.building_distance,
        args.json, sigma=dict(args.sigma or ()),
    )  # fmt: skip


def _devices(args: argparse.Namespace) -> int:
    from acq.record.devices import main_devices

    return main_devices(args.json, args.reset)


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
        help="record the simulated rig and colour its cloud, end to end",
        description="Start the simulated rig (a UTM-30LX speaking SCIP on a pseudo-terminal, "
        "a 185-degree fisheye serving MJPEG over HTTP and the car's CAN odometry, all on the "
        "synthetic street), record it through the real drivers and recorder for --seconds, "
        "then colour every laser point with the fisheye frame nearest in time, using the "
        "rig's calibration and the simulator's path. Writes DIR/demo.mcap, DIR/cloud.ply "
        "(x y z, colour, UTC time, scan, intensity), DIR/preview.png (the coloured facade "
        "and a top view), calib.yaml and config.yaml, and prints a summary checked against "
        "the simulator's truth. `acq colorize DIR/demo.mcap --calib DIR/calib.yaml -o "
        "OUT.ply` colours the same log from its recorded odometry.",
    )
    demo.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    demo.add_argument("--seconds", type=float, default=10.0, help="how long to record (default 10)")
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

    from acq.drivers.scanner import driver_names
    from acq.sim.scanner_models import MODELS

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
    simscan.add_argument("--drift-ppm", type=float, default=0.0, help="device clock drift")
    simscan.add_argument("--seed", type=int, default=0, help="street seed")
    simscan.set_defaults(handler=_sim_scanner)

    probe = sub.add_parser("probe", help="talk to one device and print what it says")
    probe_sub = probe.add_subparsers(dest="probe_command", metavar="DEVICE", required=True)
    pscan = probe_sub.add_parser(
        "scanner",
        help="device info, then N scans",
        description="Connect to one laser scanner, print its identity and geometry, then N "
        "scans (with --json: one JSON object for the device, then one per scan with time, "
        "ranges in metres (null where there is no finite range) and intensities).",
    )
    pscan.add_argument("--driver", required=True, choices=driver_names())
    pscan.add_argument(
        "--url",
        required=True,
        help="hokuyo: a pyserial URL (/dev/ttyACM0, /dev/serial/by-id/..., "
        "socket://192.168.0.10:10940); sick: tcp://192.168.0.1:2112",
    )
    pscan.add_argument("--count", type=int, default=10, help="scans to read (default 10)")
    pscan.add_argument("--json", action="store_true", help="JSON lines instead of text")
    pscan.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for data")
    pscan.set_defaults(handler=_probe_scanner)

    from acq.drivers.camera import camera_driver_names

    pcam = probe_sub.add_parser(
        "camera",
        help="grab N frames: size, rate, timestamps, drops",
        description="Open one camera, print the format it applied, then N frames with their "
        "sequence numbers and times (the middle of exposure, and where that time came from), "
        "the measured rate and the frames known to be dropped.",
    )
    pcam.add_argument("--driver", required=True, choices=camera_driver_names())
    pcam.add_argument(
        "--source",
        required=True,
        help="opencv: an index, /dev/videoN, an http(s)/rtsp URL or a GStreamer pipeline; "
        "v4l2: /dev/videoN or /dev/v4l/by-id/...",
    )
    pcam.add_argument("--count", type=int, default=25, help="frames to grab (default 25)")
    pcam.add_argument("--fps", type=float, default=25.0, help="frame rate to request")
    pcam.add_argument("--json", action="store_true", help="JSON lines instead of text")
    pcam.add_argument("--snapshot", metavar="PNG", help="write the last frame to this PNG")
    pcam.add_argument("--timeout", type=float, default=2.0, help="seconds to wait for a frame")
    pcam.set_defaults(handler=_probe_camera)

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
    simcam.add_argument("--seed", type=int, default=0, help="street seed")
    simcam.set_defaults(handler=_sim_camera)

    rec = sub.add_parser(
        "record",
        help="record the rig's devices to MCAP (the daemon systemd runs)",
        description="Record every scanner and camera of a configuration into MCAP files: "
        "one thread per device, reconnection with backoff, device clocks mapped to the host "
        "clock, zstd chunks fsynced every second, files split by size and duration. Ctrl-C "
        "or SIGTERM finish the file. Exit status: 0 stopped, 1 runtime failure, 2 bad "
        "configuration, 3 disk below its reserve (the file is closed first).",
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
        type=float,
        metavar="S",
        help="stop after S seconds (default: run until stopped)",
    )
    rec.add_argument("-v", "--verbose", action="store_true", help="debug log lines")
    rec.set_defaults(handler=_record)

    info = sub.add_parser(
        "info",
        help="channels, rates, gaps, drops and clock-sync quality of logs",
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
    info.set_defaults(handler=_info)

    replay = sub.add_parser(
        "replay",
        help="serve a log back through simulated devices on their real transports",
        description="Serve recorded logs (the split files of one session, in order) back "
        "through simulated devices: each scanner's raw telegrams byte for byte over SCIP "
        "(TCP, or a pseudo-terminal with --pty) or CoLa (TCP), each camera's JPEG bytes as "
        "MJPEG over HTTP, at their recorded receive times. Prints the devices' URLs and a "
        "configuration for `acq record -c`. The replay starts when a client first asks a "
        "device for data, and ends with the log (or Ctrl-C / SIGTERM). Exit status: 0 "
        "served, 1 runtime failure, 2 bad log or address.",
    )
    replay.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files, in order")
    replay.add_argument(
        "--speed", type=float, default=1.0, metavar="X",
        help="playback speed (default 1, the recorded pace; 2 plays twice as fast)",
    )  # fmt: skip
    replay.add_argument(
        "--listen", metavar="tcp://HOST:PORT",
        help="the first scanner's address, the next ones on the following ports "
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
        help="write the recorder configuration here (and the log's calibration beside it) "
        "instead of printing it",
    )  # fmt: skip
    replay.set_defaults(handler=_replay)

    col = sub.add_parser(
        "colorize",
        help="coloured 3D cloud of a drive (PLY or LAS)",
        description="Place every laser point of LOG (the split files of one session, or "
        "their folder) at its own time and colour it from the camera frames: the frame "
        "nearest in time with the rig's motion between the two instants compensated "
        "(--view nearest), or the one among its neighbours that sees it nearest its optical "
        "axis without nearer laser points in the way (--view best). Stamps are re-timed "
        "offline first (scans from their device ticks, frames onto the camera's frame grid). "
        "The trajectory: --trajectory CSV, else the log's CAN odometry, else none (points "
        "stay in the laser frame). Points no frame sees are kept, flagged 'coloured' 0. Every "
        "point keeps its time (PLY 'time': UTC s; LAS: Adjusted Standard GPS time), scan "
        "index and intensity. Exit status: 0 written, 2 bad input.",
    )
    col.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files or a folder")
    col.add_argument("--calib", type=Path, required=True, help="calib.yaml (camera and laser)")
    col.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT",
        help="OUT.ply or OUT.las (LAS 1.4, point format 7)",
    )  # fmt: skip
    col.add_argument("--camera", metavar="NAME", help="camera (default: the only one)")
    col.add_argument(
        "--frame", choices=("world", "laser"),
        help="world: placed with the trajectory (default when there is one); laser: each "
        "point in the scanner frame at its own time",
    )  # fmt: skip
    col.add_argument(
        "--view", choices=views_choices(), default="nearest",
        help="nearest (default): the frame nearest in time; best: the neighbour frame that "
        "sees the point nearest its axis, not hidden by nearer laser points",
    )  # fmt: skip
    col.add_argument(
        "--trajectory", type=Path, metavar="CSV",
        help="post-processed GNSS/INS trajectory (see acq/trajectory.py for the columns); "
        "laser_to_vehicle from CALIB is the lever arm and boresight",
    )  # fmt: skip
    col.add_argument(
        "--crs", metavar="EPSG:CODE",
        help="coordinate reference system of the output, written into the LAS header",
    )  # fmt: skip
    col.add_argument(
        "--window", type=int, default=3, metavar="N",
        help="--view best: frames either side of the nearest to consider (default 3)",
    )  # fmt: skip
    col.add_argument(
        "--max-dt", type=float, default=0.1, metavar="S",
        help="farthest frame from a point's time, seconds (default 0.1)",
    )  # fmt: skip
    col.add_argument(
        "--time-offset", type=_time_offset_arg, metavar="S|auto",
        help="camera time minus laser time, seconds (default: CALIB's time_offset_s): what "
        "the camera's configured latency got wrong; at 20 km/h 10 ms move colours 5.6 cm. "
        "'auto': estimate it from this log first, as 'acq calibrate time-offset' does "
        "(needs motion and the laser's return strengths; CALIB's value is kept when it "
        "finds no clear peak)",
    )  # fmt: skip
    col.add_argument("--no-retime", action="store_true", help="use the stamps as recorded (online)")
    col.add_argument(
        "--no-motion-compensation", action="store_true",
        help="colour each point as if the rig stood still between it and its frame "
        "(for comparison)",
    )  # fmt: skip
    col.add_argument(
        "--workers", type=int, default=1, metavar="N",
        help="processes on this machine (default 1); the output is the same for any N",
    )  # fmt: skip
    col.add_argument(
        "--dask", metavar="ADDRESS",
        help="run the chunks on this Dask scheduler (tcp://host:8786); the workers must "
        "see the log files at the same paths",
    )  # fmt: skip
    col.add_argument(
        "--chunk", type=float, default=30.0, metavar="S",
        help="seconds of scans per chunk (default 30)",
    )  # fmt: skip
    col.add_argument(
        "--preview", type=Path, metavar="PNG",
        help="the preview image (default: OUT's name + _preview.png)",
    )  # fmt: skip
    col.add_argument("--no-preview", action="store_true", help="no preview image")
    col.add_argument("--progress", action="store_true", help="a progress bar even when piped")
    col.add_argument("--json", action="store_true", help="JSON report instead of text")
    col.set_defaults(handler=_colorize)

    cal = sub.add_parser("calibrate", help="calibrate the rig's sensors")
    cal_sub = cal.add_subparsers(dest="calibrate_command", metavar="WHAT", required=True)
    fish = cal_sub.add_parser(
        "fisheye",
        help="fisheye intrinsics from the image circle (paper §3.3.2)",
        description="Find the image circle of a fisheye camera in one or more of its images "
        "(any scene): barycentre of the non-black pixels, least-squares circle on Canny edges, "
        "Hough circle, and a sub-pixel fit of the rim along rays (the one used). Works on "
        "circles cut by the sensor edges. Writes u0, v0 = the centre and f = r / theta_max "
        "(theta_max = fov / 2) into the camera's entry of CALIB (equidistant model; the rest "
        "of an existing file is kept), and an overlay PNG. With --board, also fits the "
        "Kannala-Brandt model (k1..k4) to a checkerboard in the images and writes that instead.",
    )
    fish.add_argument("images", nargs="+", type=Path, metavar="IMAGE", help="images of one camera")
    fish.add_argument(
        "--fov", type=float, required=True, metavar="DEG",
        help="the lens's full aperture in degrees, from its data sheet (e.g. 185)",
    )  # fmt: skip
    fish.add_argument(
        "--camera", metavar="NAME",
        help="the entry under cameras: (default: CALIB's only camera, or 'camera' in a new file)",
    )  # fmt: skip
    fish.add_argument(
        "-o", "--output", type=Path, required=True, metavar="CALIB",
        help="calib.yaml to create or update",
    )  # fmt: skip
    fish.add_argument(
        "--ellipse", action="store_true",
        help="non-square pixels: fit an axis-aligned ellipse "
        "(fx = rx / theta_max, fy = ry / theta_max)",
    )  # fmt: skip
    fish.add_argument("--json", action="store_true", help="JSON instead of text")
    fish.add_argument(
        "--overlay", type=Path, metavar="PNG",
        help="where to draw the circles on the first image (default: CALIB's name + _circle.png)",
    )  # fmt: skip
    fish.add_argument(
        "--board", metavar="COLSxROWSxSQUARE",
        help="also fit Kannala-Brandt to this checkerboard (inner corners, square in metres, "
        "e.g. 8x6x0.117), starting from the circle",
    )  # fmt: skip
    fish.set_defaults(handler=_calibrate_fisheye)

    ext = cal_sub.add_parser(
        "extrinsic",
        help="camera-laser transform from checkerboard poses in a log (paper §3.2)",
        description="Find the still board poses in LOG (or --poses), the board's corners in a "
        "frame of each (in the fisheye image itself: a lens swap, as the paper does, moves the "
        "projection centre along the optical axis) and its laser line, and fit camera_to_laser "
        "(Zhang & Pless: linear solution, then robust Levenberg-Marquardt on point-to-plane "
        "distances). Writes CALIB: a copy of --intrinsics with the camera's camera_to_laser "
        "set, and a residual plot PNG.",
    )
    ext.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="the recording's MCAP file(s)"
    )
    ext.add_argument("--camera", metavar="NAME", help="camera (default: the only one)")
    ext.add_argument(
        "--intrinsics", type=Path, required=True, metavar="CALIB",
        help="calib.yaml with the camera's intrinsics (a non-identity camera_to_laser is used "
        "as a coarse guess to pick the board's laser segment)",
    )  # fmt: skip
    ext.add_argument(
        "--board", required=True, metavar="COLSxROWSxSQUARE",
        help="inner corners and square side in metres, e.g. 9x7x0.1",
    )  # fmt: skip
    ext.add_argument(
        "-o", "--output", type=Path, required=True, metavar="CALIB", help="calib.yaml to write"
    )
    ext.add_argument(
        "--poses", metavar="START:END,...",
        help="still intervals in seconds from the log's first scan (default: detected)",
    )  # fmt: skip
    ext.add_argument("--json", action="store_true", help="JSON instead of text")
    ext.add_argument(
        "--plot", type=Path, metavar="PNG", help="residual plot (default: beside CALIB)"
    )
    ext.add_argument(
        "--lens-swap", type=Path, metavar="FISHEYE_CALIB",
        help="the paper's way: LOG was recorded with a regular lens on the camera, which "
        "--intrinsics describes (model: pinhole), and the fisheye is mounted afterwards; "
        "write the result into a copy of FISHEYE_CALIB (the fisheye's intrinsics). CAVEAT: "
        "swapping lenses moves the projection centre along the optical axis (the lenses' "
        "entrance pupils differ, typically by millimetres to centimetres); u0, v0 cannot "
        "absorb that, so it goes into the translation unless --pupil-shift gives it. The "
        "default (no lens swap, the fisheye seeing the board) has no such error",
    )  # fmt: skip
    ext.add_argument(
        "--pupil-shift", type=float, default=0.0, metavar="M",
        help="with --lens-swap: the fisheye's projection centre minus the regular lens's, "
        "along the optical axis, metres, + towards the scene (default 0, the paper's "
        "assumption)",
    )  # fmt: skip
    ext.set_defaults(handler=_calibrate_extrinsic)

    tof = cal_sub.add_parser(
        "time-offset",
        help="the camera's time offset from a drive (the latency its stamps got wrong)",
        description="Estimate the camera's time offset (camera time minus laser time: what "
        "the camera's configured latency got wrong) from a drive: every laser point goes "
        "into the frame nearest its time, motion-compensated, as the rig stood at the "
        "frame's candidate instant, and the offset that makes the image's grey levels there "
        "most informative of the laser's return strengths (mutual information) wins. Needs "
        "the rig moving (CAN odometry in the log or --trajectory), textured surfaces "
        "(facades, road markings) and return strengths in the log (SCIP ME / CoLa RSSI1). "
        "Writes OUT: a copy of CALIB with the camera's time_offset_s and its standard "
        "deviation set. Exit status: 0 written, 1 no clear estimate (why is printed), 2 bad "
        "input.",
    )
    tof.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP files or a folder")
    tof.add_argument(
        "--calib", type=Path, required=True, help="calib.yaml (intrinsics, extrinsics)"
    )
    tof.add_argument(
        "-o", "--output", type=Path, required=True, metavar="OUT", help="calib.yaml to write"
    )
    tof.add_argument("--camera", metavar="NAME", help="camera (default: the only one)")
    tof.add_argument(
        "--trajectory", type=Path, metavar="CSV",
        help="post-processed GNSS/INS trajectory (default: the log's CAN odometry)",
    )  # fmt: skip
    tof.add_argument(
        "--start", type=float, metavar="S",
        help="use the log from S seconds after its first scan (default: its middle part)",
    )  # fmt: skip
    tof.add_argument(
        "--seconds", type=float, default=60.0, metavar="S",
        help="how much of the log to use, seconds (default 60)",
    )  # fmt: skip
    tof.add_argument(
        "--search", type=float, default=0.06, metavar="S",
        help="search CALIB's offset +- S seconds (default 0.06)",
    )  # fmt: skip
    tof.add_argument(
        "--frames", type=int, default=1500, metavar="N",
        help="at most N frames, spread over the part used (default 1500)",
    )  # fmt: skip
    tof.add_argument("--json", action="store_true", help="JSON (with the curve) instead of text")
    tof.set_defaults(handler=_calibrate_time_offset)

    val = cal_sub.add_parser(
        "validate",
        help="laser points on the right colour of the two-depth pattern (paper §4.2)",
        description="Project the laser points of a still recording of the validation pattern "
        "(two coloured planar sets at different depths: red/green bars in front of a "
        "blue/yellow wall) into the fisheye frames with CALIB, and report the share of points "
        "on their set's colours, the pixel-error histogram (0, 1, 2, 3, >3 px, as the "
        "paper's Table 4) and sigma of a normal fit to the errors at the front set's edges.",
    )
    val.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP file(s)")
    val.add_argument(
        "--calib", required=True, type=Path, help="calibration (intrinsics + camera_to_laser)"
    )
    val.add_argument("--camera", metavar="NAME", help="camera (default: the only one)")
    val.add_argument("--json", action="store_true", help="JSON instead of text")
    val.add_argument(
        "-o", dest="out", type=Path, metavar="DIR", help="write DIR/validate_overlay.png"
    )
    val.set_defaults(handler=_calibrate_validate)

    ana = sub.add_parser("analyze", help="analyse a calibration against logs")
    ana_sub = ana.add_subparsers(dest="analyze_command", metavar="WHAT", required=True)
    sens = ana_sub.add_parser(
        "sensitivity",
        help="sensitivity of the projection to its 12 parameters (paper §4.1)",
        description="Project the laser points of LOG into CALIB's camera with the paper's "
        "generic model (r = k1 theta + k2 theta^3) and compute, along theta, the eq. (7) "
        "sensitivity of the distance to the principal point (eq. 8, measured from the "
        "principal point, not pixel (0, 0) as printed) to the 3 rotation angles, 3 "
        "translations, k1, k2, u0, v0, mu_x, mu_y, with the pixels one standard deviation of "
        "each moves a point; Figures 7-9 as PNGs; Table 3 (height on a facade at which "
        "dropping k2 theta^3 reaches 0.5..4 px); DIR/sensitivity.json.",
    )
    sens.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="MCAP logs of one session")
    sens.add_argument("--calib", type=Path, required=True, metavar="CALIB", help="calib.yaml")
    sens.add_argument(
        "-o", "--output", type=Path, default=Path("sensitivity"), metavar="DIR",
        help="where to write the PNGs and sensitivity.json (default: ./sensitivity)",
    )  # fmt: skip
    sens.add_argument(
        "--camera-height", type=float, default=2.0, metavar="M",
        help="Table 3: camera height above the ground, m (default 2)",
    )  # fmt: skip
    sens.add_argument(
        "--building-distance", type=float, default=10.0, metavar="M",
        help="Table 3: distance from the camera to the facade, m (default 10)",
    )  # fmt: skip
    sens.add_argument(
        "--sigma", type=_sigma_arg, action="append", metavar="NAME=VALUE",
        help="one standard deviation of a parameter in its unit (rad, m, px, px/m), e.g. "
        "yaw=0.002; repeatable; overrides calib.yaml's std and the defaults",
    )  # fmt: skip
    sens.add_argument("--json", action="store_true", help="JSON instead of text")
    sens.set_defaults(handler=_analyze_sensitivity)

    devices = sub.add_parser(
        "devices",
        help="list attached scanners, cameras, serial ports, CAN interfaces",
        description="List what this machine has attached that a rig uses: USB devices by "
        "vendor and product, serial ports with their stable /dev/serial/by-id names, V4L2 "
        "cameras, CAN interfaces; each with the configuration line to paste.",
    )
    devices.add_argument("--json", action="store_true", help="JSON instead of text")
    devices.add_argument(
        "--reset", metavar="BUS:ADDR", help="reset a wedged USB device (e.g. 001:004)"
    )
    devices.set_defaults(handler=_devices)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    # what the imports made lives as long as the process: out of the collector's scans
    # (its full collections otherwise walk it again while a log's messages are read)
    gc.freeze()
    try:
        return handler(args)
    except UsageError as e:
        print(f"acq: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
