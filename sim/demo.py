"""`acq demo`: the simulated rig, recorded through the real recorder, coloured into a cloud.

The rig: a simulated Hokuyo UTM-30LX (SCIP 2.0 on a pseudo-terminal, its own drifting
millisecond clock), the simulated 185-degree fisheye (MJPEG over HTTP, in its own
process so its JPEG encoding does not take the recorder's GIL) and the simulated car
(:mod:`acq.sim.can_vehicle`: wheel speeds and yaw rate as CAN frames of ``sim/vehicle.dbc``
on a python-can ``virtual`` bus, which reaches the recorder because both run in this
process), all driving down the synthetic street from one shared instant ``t_origin``.
The real recorder (drivers, clock sync, CAN odometry, MCAP writer) records them for
``seconds`` into ``DIR/demo.mcap``, with ``/vehicle/odometry`` and ``/vehicle/can``;
the log is then coloured with the rig's true calibration (``DIR/calib.yaml``) into
``DIR/cloud.ply`` and pictured in ``DIR/preview.png``.

The demo colours through the pipeline of ``acq colorize`` (:func:`acq.cloud.colorize.run`:
offline re-timing, chunks, views, the PLY writer) with the simulator's trajectory in
place of the log's odometry, so the cloud lies in the street's world frame: because the
demo owns the simulator, the summary checks the chain against the truth (the scan and
frame stamps, the recorded odometry, and each coloured point's colour against the true
colour of the surface the laser hit). ``acq colorize DIR/demo.mcap --calib
DIR/calib.yaml`` colours the same log from the recorded CAN odometry instead (dead
reckoning), as on a real drive.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from acq import cloud, motion
from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CameraCalib
from acq.cloud import colorize
from acq.errors import AcqError, InputError
from acq.log import LogInfo, drive_log
from acq.log import info as log_info
from acq.motion.trajectory import Trajectory
from acq.record import config as configfile
from acq.record.recorder import Recorder, RecorderError
from acq.record.sdnotify import Notifier

__all__ = ["CAMERA_SIM", "COLOUR_TOLERANCE", "colour_check", "run"]

EXIT_OK, EXIT_FAILURE = 0, 1

# The simulated camera's options (JSON for its process): s, frames/s.
CAMERA_SIM: dict[str, Any] = {
    "fps": 25.0,
    "exposure_s": 0.004,
    "latency_s": 0.020,  # end of exposure -> frame available
    "jitter_s": 0.003,  # mean of the random part (exponential, clipped at 4x)
    "jpeg_quality": 90,
    "seed": 0,
}
SCANNER_MODEL = "utm-30lx"
SCANNER_DRIFT_PPM = 30.0  # the simulated scanner's clock runs fast by this much
COLOUR_TOLERANCE = 24  # max |channel difference| for "the same colour as the truth"
STOP_AHEAD_S = 0.005  # the recorder is stopped this long before a scan is due (see _record)
CAN_INTERFACE = "virtual"  # python-can's in-process bus: the car and the recorder share it
MAX_SECONDS = 170.0  # the simulated drive loops over its 1 km street every 180 s


def camera_latency_s(sim: dict[str, Any] = CAMERA_SIM) -> float:
    """What the camera driver subtracts from receipt to get the middle of the exposure:
    the sim's latency, half its exposure and the mean of its clipped exponential jitter."""
    jitter = float(sim["jitter_s"]) * (1.0 - math.exp(-4.0))
    return float(sim["latency_s"]) + float(sim["exposure_s"]) / 2 + jitter


@dataclass
class DemoResult:
    """What the demo did: files written, counts, checks against the truth, step times."""

    out: Path
    files: dict[str, Path] = field(default_factory=dict)
    steps_s: dict[str, float] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)  # the printed summary
    frames_used: int = 0  # frames the cloud was coloured from
    colour_agreement: tuple[float, float] = (math.nan, math.nan)  # strict, within a pixel


class _Clock:
    """Progress lines with the time since the demo started, to ``out``."""

    def __init__(self, out: Callable[[str], None]) -> None:
        self.t0 = time.monotonic()
        self.mark = self.t0
        self.out = out

    def say(self, text: str) -> None:
        self.out(f"[{time.monotonic() - self.t0:5.1f} s] {text}")

    def lap(self) -> float:
        now = time.monotonic()
        took, self.mark = now - self.mark, now
        return took


class _SimRig:
    """The simulated scanner (in process, on a pty), camera (own process) and car (in
    process, on a python-can ``virtual`` bus named ``can_channel``) sharing ``t_origin``
    (host monotonic s): the same place on the street at the same time."""

    def __init__(self, t_origin: float) -> None:
        from acq.sim.can_vehicle import SimVehicle
        from acq.sim.device_clock import SimClock
        from acq.sim.mjpeg_server import MjpegServerProcess
        from acq.sim.scan_source import StreetSource
        from acq.sim.scanner_models import MODELS
        from acq.sim.scip_device import ScipDevice
        from acq.sim.transport import PtyDeviceServer

        self.t_origin = t_origin
        self.camera: Any = None
        self.server: Any = None
        self.car: Any = None
        # a virtual bus is one process's: a name of its own (two demos, the test suite)
        self.can_channel = f"acq-demo-{os.getpid()}-{time.monotonic_ns()}"
        self._tmp: str | None = None  # holds the pty's link
        model = MODELS[SCANNER_MODEL]
        # the camera process starts (and loads its renderer) while the scanner is built
        started: dict[str, Any] = {}

        def start_camera() -> None:
            try:
                started["camera"] = MjpegServerProcess(**CAMERA_SIM, t_origin=t_origin)
            except Exception as e:  # raised in the caller below
                started["error"] = e

        thread = threading.Thread(target=start_camera, name="sim-camera-start", daemon=True)
        thread.start()
        try:
            try:
                self.source = StreetSource(model, seed=0, t_origin=t_origin)
                clock = SimClock(
                    tick_hz=model.clock_hz,
                    wrap_bits=model.clock_bits,
                    drift_ppm=SCANNER_DRIFT_PPM,
                    offset_ticks=1234567.0,
                )
                self.scanner = ScipDevice(model, source=self.source, clock=clock)
                self._tmp = tempfile.mkdtemp(prefix="acq-demo-")
                link = Path(self._tmp) / "ttyACM-sim"
                self.server = PtyDeviceServer(self.scanner, link=link).start()
                # the car: the scanner's trajectory, looping with the street
                self.car = SimVehicle(
                    CAN_INTERFACE,
                    self.can_channel,
                    trajectory=self.source.trajectory,
                    t_origin=t_origin,
                    loop_s=self.loop_s,
                ).start()
            finally:
                thread.join()
                self.camera = started.get("camera")
            if "error" in started:
                raise RuntimeError(f"the simulated camera did not start: {started['error']}")
        except BaseException:
            self.close()
            raise

    @property
    def loop_s(self) -> float:
        """The drive's period, s: it loops over the street."""
        return max(self.source.street.length_m, 1.0) / self.source.trajectory.speed

    def trajectory(self, start_ns: int, end_ns: int, rate_hz: float = 1000.0) -> Trajectory:
        """The car's true poses from ``start_ns`` to ``end_ns`` (host ns; none before
        ``t_origin``) every 1/``rate_hz`` s: what the demo places its points with."""
        origin_ns = round(self.t_origin * 1e9)
        step = round(1e9 / rate_hz)
        t_ns = np.arange(max(start_ns, origin_ns), end_ns + step, step, dtype=np.int64)
        R, p = self.source.trajectory.poses(((t_ns - origin_ns) * 1e-9) % self.loop_s)
        return Trajectory(t_ns, R, p)

    def close(self) -> None:
        if self.car is not None:
            self.car.close()
            self.car = None
        if self.server is not None:
            self.server.close()
            self.server = None
        if self.camera is not None:
            self.camera.close()
            self.camera = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


def true_calibration() -> Calibration:
    """The simulated rig's true calibration (the lens as kannala_brandt)."""
    from acq.sim.world import default_rig

    rig = default_rig()
    return Calibration(
        laser="laser",
        cameras={"camera": CameraCalib(rig.lens, rig.camera_to_laser, method="simulator truth")},
        laser_to_vehicle=rig.laser_to_vehicle,
    )


def _config(
    scanner_url: str, camera_url: str, can_channel: str, calib: Path, seconds: float
) -> dict[str, Any]:
    from acq.sim.can_vehicle import DBC_PATH

    return {
        "version": 1,
        "scanners": [
            {
                "name": "laser",
                "driver": "hokuyo",
                "url": scanner_url,
                "latency_s": "auto",
                "options": {"intensity": True},
            }
        ],
        "cameras": [
            {
                "name": "camera",
                "driver": "opencv",
                "source": camera_url,
                "fps": CAMERA_SIM["fps"],
                "latency_s": round(camera_latency_s(), 6),
            }
        ],
        "can": {  # the signals are the config's defaults, those of sim/vehicle.dbc
            "interface": CAN_INTERFACE,
            "channel": can_channel,
            "dbc": str(DBC_PATH.resolve()),
        },
        "calibration": str(calib),
        "output": {
            "dir": ".recording",
            "prefix": "demo",
            "split_minutes": max(10.0, math.ceil(seconds / 60.0) + 1.0),
            "split_megabytes": 1e6,
            "reserve_megabytes": 50,
        },
    }


def _record(recorder: Recorder, rig: _SimRig, seconds: float, clock: _Clock) -> int:
    """Run the recorder in a thread for ``seconds``, printing progress; its exit code.

    The demo stops the recorder itself (it runs without a duration), between two scans:
    a reader finishes the record it is receiving when told to stop, the scanner's up to
    a scan period later, the car's within one CAN frame. Stopped just before a scan is
    due, the last scan recorded began ~14 ms before the stop, when the odometry still
    runs: the car's odometry spans every recorded scan (`acq colorize` has no pose for
    points outside it and leaves them out).
    """
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(recorder.run()), name="recorder")
    thread.start()
    try:
        next_say = time.monotonic() + 2.0
        while thread.is_alive():
            started = recorder.started_ns
            left = (started + seconds * 1e9 - time.monotonic_ns()) * 1e-9 if started else 0.2
            if left <= 0:
                _stop_before_a_scan(rig)
                break
            thread.join(timeout=min(0.2, left))
            if time.monotonic() >= next_say and thread.is_alive():
                next_say += 2.0
                d = recorder.devices
                elapsed = (time.monotonic_ns() - recorder.started_ns) * 1e-9
                clock.say(
                    f"recording {min(elapsed, seconds):4.1f} s of {seconds:g}: "
                    f"{d['laser'].received} scans, {d['camera'].received} frames"
                    + (f", {d['vehicle'].received} odometry" if "vehicle" in d else "")
                )
    finally:
        recorder.stop()
        thread.join()
    return codes[0] if codes else EXIT_FAILURE


def _stop_before_a_scan(rig: _SimRig, ahead_s: float = STOP_AHEAD_S) -> None:
    """Return when the simulated scanner's next scan is due within ``ahead_s`` (or is
    late, or none is): the scan then read after the stop began >= 18.75 - ``ahead_s``
    ms before it (its points take the first 3/4 of the 25 ms period, then it is sent)."""
    while True:
        now = time.monotonic()
        due = rig.scanner.next_due(now)
        if due is None or due - now <= ahead_s:
            return
        time.sleep(due - now - 0.6 * ahead_s)


def _size(path: Path) -> str:
    n = path.stat().st_size
    return f"{n / 1e6:.1f} MB" if n >= 1e6 else f"{n / 1e3:.0f} kB" if n >= 1e3 else f"{n} B"


def _odometry_truth(rig: _SimRig, mcap_path: Path) -> list[str]:
    """Summary lines comparing the recorded CAN odometry with the car's true motion at
    the odometry's stamps, and its dead reckoning with the true path over the log."""
    from acq.log.vehicle_log import read_vehicle
    from acq.sim.can_vehicle import true_motion

    odo = read_vehicle([mcap_path]).odometry
    if len(odo) < 2:
        return ["WARNING: no CAN odometry in the log: `acq colorize` cannot place its points"]
    t = odo.t_ns * 1e-9
    drive = rig.source.trajectory
    t_drive = (t - rig.t_origin) % rig.loop_s
    speed, yaw_rate = true_motion(drive, t_drive)
    m, ym = odo.speed_measured, odo.yaw_rate_measured
    span = float(t[-1] - t[0])
    speed_err = np.abs(odo.speed[m] - speed[m]).max(initial=0.0)
    yaw_err = math.degrees(np.abs(odo.yaw_rate[ym] - yaw_rate[ym]).max(initial=0.0))
    lines = [
        f"odometry {len(odo)} samples ({(len(odo) - 1) / span:.0f} Hz): speed "
        f"{speed_err * 1e3:.1f} mm/s, yaw rate {yaw_err:.3f} deg/s max off the truth at "
        "its stamps"
    ]
    # dead reckoning (as `acq colorize` does) against the truth, from the first sample
    path = motion.from_odometry(odo.t_ns, odo.speed, odo.yaw_rate, on_gap="flag")
    _, end = path.pose_at(odo.t_ns[-1:])
    R, p = drive.poses(t_drive[[0, -1]])
    true_end = R[0].T @ (p[1] - p[0])  # in the frame of the first pose, as the odometry
    err = float(np.linalg.norm(end[0] - true_end))
    lines.append(
        f"  dead reckoned over {span:.1f} s: {np.linalg.norm(end[0]):.2f} m, "
        f"the end {100 * err:.1f} cm off the true path's"
    )
    return lines


def _truth(
    rig: _SimRig, log: drive_log.DriveLog, pc: cloud.Cloud, truth_frames: list[Any]
) -> tuple[list[str], tuple[float, float]]:
    """Summary lines comparing the log with the simulator's truth, and the shares of
    checked coloured points whose colour is the true surface colour (see colour_check)."""
    from acq.sim import sensors
    from acq.sim.camera_device import jpeg_digest

    lines = []
    # scans: the device's record of what it sent, matched by its clock tick
    sent = {s.timestamp: s for s in list(rig.scanner.sent)}
    step_dt = rig.scanner.step_dt
    matched = [(k, sent[int(t)]) for k, t in enumerate(log.scan_ticks) if int(t) in sent]
    if matched:
        true0 = np.array([s.t0 + s.start * step_dt for _, s in matched])
        err = np.array([log.scan_ns[k] * 1e-9 for k, _ in matched]) - true0
        lines.append(
            f"scan stamps {1e3 * err.mean():+.3f} ms mean, {1e3 * np.abs(err).max():.3f} ms "
            f"max off the true time of point 0 ({len(matched)} scans)"
        )
    by_digest = {t.digest: t.t_mid for t in truth_frames if t.digest}
    ferr = np.array(
        [
            log.frame_ns[i] * 1e-9 - by_digest[d]
            for i, d in enumerate(jpeg_digest(j) for j in log.jpegs)
            if d in by_digest
        ]
    )
    if ferr.size:
        lines.append(
            f"frame stamps {1e3 * ferr.mean():+.2f} ms mean, {1e3 * ferr.std():.2f} ms sd off "
            f"the true middle of exposure ({ferr.size} frames; the camera sends no time)"
        )
    late = float(np.median(ferr)) if ferr.size else math.inf
    expected = CAMERA_SIM["fps"] * log.n_scans / rig.scanner.model.scan_hz
    if late > 0.01 or len(log.jpegs) < 0.8 * expected:
        lines.append(
            f"WARNING: the simulated camera did not keep real time ({len(log.jpegs)} frames, "
            f"median {1e3 * late:.0f} ms late): a busy machine? its colours are misplaced"
        )
    # colours: every checked point's laser ray cast again, noise-free, at its true time
    src = rig.source
    sent_of = dict(matched)
    checked = np.flatnonzero(pc.coloured & np.isin(pc.scan, list(sent_of)))
    if checked.size == 0:
        return lines, (math.nan, math.nan)
    amin = rig.scanner.model.amin
    start = np.array([sent_of[int(k)].start for k in pc.scan[checked]])
    t0 = np.array([sent_of[int(k)].t0 for k in pc.scan[checked]])
    step = start + pc.step[checked]
    t_drive = (t0 + step * step_dt - src.t_origin) % rig.loop_s
    R, origins = sensors.laser_to_world(src.trajectory, src.rig, t_drive)
    a = src.rig.angles[step - amin]
    dirs = np.einsum("nij,nj->ni", R, np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1))
    strict, near = colour_check(
        src.street, origins, dirs, pc.rgb[checked], src.rig.lens.fx, COLOUR_TOLERANCE
    )
    shares = (float(strict.mean()), float(near.mean()))
    tol = f"{COLOUR_TOLERANCE}/255"
    lines.append(
        f"colour of {100 * shares[0]:.1f} % of the {checked.size:,} coloured points within {tol} "
        "of the surface's where the laser hit,"
    )
    lines.append(
        f"  of {100 * shares[1]:.1f} % within {tol} of the surface's one camera pixel around it "
        "(a pixel on an edge blends both sides)"
    )
    return lines, shares


def colour_check(
    street: Any,
    origins: np.ndarray,
    dirs: np.ndarray,
    rgb: np.ndarray,
    f_px: float,
    tolerance: int = COLOUR_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """Coloured points against the simulator's surface colours: (strict, within a pixel),
    (N,) bool each.

    ``origins`` (N,3) m and unit ``dirs`` (N,3) are the laser rays that measured the
    points (world frame of ``street``, a ``acq.sim.world.Street``), ``rgb`` (N,3) uint8 their
    colours, ``f_px`` the camera's focal length, px/rad. Strict: every channel within
    ``tolerance`` of the true colour where the ray hits. Within a pixel: or within
    ``tolerance`` of the range (per channel) of the true colours at that spot and at four
    rays around it, one camera pixel away as seen from the ray's origin: the camera sees
    a surface through pixels of that size, and a pixel on an edge mixes both sides.
    """
    from acq.sim.raycast import cast

    rgb = np.asarray(rgb, dtype=np.int16)
    up = np.where(np.abs(dirs[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(dirs, up)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(dirs, e1)
    colours = [cast(street, origins, dirs).colour]
    for e in (e1, -e1, e2, -e2):
        d = dirs + e / f_px
        colours.append(cast(street, origins, d / np.linalg.norm(d, axis=1, keepdims=True)).colour)
    true_rgb = np.stack(colours)[:, :, ::-1].astype(np.int16)  # (5, N, 3)
    strict = np.abs(rgb - true_rgb[0]).max(axis=1) <= tolerance
    lo, hi = true_rgb.min(axis=0) - tolerance, true_rgb.max(axis=0) + tolerance
    near = strict | np.all((rgb >= lo) & (rgb <= hi), axis=1)
    return strict, near


def _summary(
    result: DemoResult,
    recorder: Recorder,
    info: LogInfo,
    log: drive_log.DriveLog,
    pc: cloud.Cloud,
    truth_lines: list[str],
) -> list[str]:
    chan = {c.topic: c for c in info.channels}
    scans, frames = chan.get("/laser/scan"), chan.get("/camera/image/compressed")
    laser = recorder.devices["laser"]
    sync = {d.name: d for d in info.devices}
    lines = ["summary"]
    rec = f"  recorded  {info.duration_s:.1f} s"
    if scans is not None:
        rec += f": {scans.count} scans ({scans.rate_hz:.1f} Hz)"
    if frames is not None:
        rec += f", {frames.count} frames ({frames.rate_hz:.1f} Hz)"
    drops = ", ".join(f"{name} {n}" for name, n in sorted(info.drops.items())) or "none"
    lines.append(rec + f"; drops: {drops}")
    clock = "  clock     laser: "
    if laser.latency_bounds_s is not None:
        lo, hi = laser.latency_bounds_s
        clock += f"latency {laser.latency_s * 1e3:.2f} ms (TM bounds {lo * 1e3:.2f}-{hi * 1e3:.2f})"
    else:
        clock += f"latency {laser.latency_s * 1e3:.2f} ms (no TM bounds)"
    ls = sync.get("laser")
    if ls is not None and ls.drift_ppm is not None:
        true_ppm = (1.0 / (1.0 + SCANNER_DRIFT_PPM * 1e-6) - 1.0) * 1e6  # host s per device s
        clock += f", drift {ls.drift_ppm:+.1f} ppm (true {true_ppm:+.1f})"
    if ls is not None and ls.residual_ms_p50 is not None:
        clock += f", receipt - stamp {ls.residual_ms_p50:.2f}/{ls.residual_ms_p95:.2f} ms p50/p95"
    lines.append(clock)
    lines.append(
        f"            camera: latency {camera_latency_s() * 1e3:.1f} ms configured (sim: "
        f"{CAMERA_SIM['latency_s'] * 1e3:.0f} ms + half the {CAMERA_SIM['exposure_s'] * 1e3:.0f}"
        f" ms exposure + mean jitter)"
    )
    lines.extend(f"  truth     {t}" if i == 0 else f"            {t}"
                 for i, t in enumerate(truth_lines))  # fmt: skip
    lines.append(
        f"  cloud     {pc.size:,} points, {int(pc.coloured.sum()):,} coloured "
        f"({100 * pc.coloured_share:.1f} %; the camera looks left, the scanner sees both "
        f"sides) from {pc.frames_used} of {pc.frames} frames"
    )
    lines.append("  files     " + ", ".join(
        f"{p} ({_size(p)})" if i == 0 else f"{p.name} ({_size(p)})"
        for i, p in enumerate(result.files.values())
    ))  # fmt: skip
    lines.append("  time      " + ", ".join(
        f"{k} {v:.1f} s" for k, v in result.steps_s.items()
    ))  # fmt: skip
    if log.notes:
        lines.append("  notes     " + "; ".join(log.notes))
    return lines


def run(
    out: Path, seconds: float = 10.0, progress: Callable[[str], None] = lambda _: None
) -> DemoResult:
    """The demo into folder ``out``, its progress lines to ``progress``. InputError for
    bad arguments, AcqError when the recording fails (the recorder's errors too: the
    demo wrote its configuration)."""
    result = DemoResult(Path(out).absolute())  # the config it writes names files by path
    try:
        _run(result, seconds, progress)
    except RecorderError as e:
        raise AcqError(str(e)) from e
    return result


def _run(result: DemoResult, seconds: float, progress: Callable[[str], None]) -> None:
    out = result.out
    if not (math.isfinite(seconds) and 0 < seconds <= MAX_SECONDS):
        raise InputError(
            f"--seconds {seconds:g}: expected 0 < seconds <= {MAX_SECONDS:g} "
            "(one drive down the simulated 1 km street)"
        )
    clock = _Clock(progress)
    progress(
        f"acq demo: a simulated UTM-30LX and 185-degree fisheye driving down a synthetic street,"
        f"\nrecorded for {seconds:g} s by the real recorder, coloured into a cloud; into {out}/"
    )
    out.mkdir(parents=True, exist_ok=True)
    rec_dir = out / ".recording"
    shutil.rmtree(rec_dir, ignore_errors=True)
    calib = true_calibration()
    calib_path = out / "calib.yaml"
    calibfile.save(calib, calib_path)
    t_origin = time.monotonic()  # the drive starts here, for the scanner and the camera
    rig = _SimRig(t_origin)
    try:
        result.steps_s["start"] = clock.lap()
        clock.say(f"simulated {SCANNER_MODEL.upper()} on {rig.server.url} (SCIP over a pty)")
        clock.say(f"simulated fisheye at {rig.camera.url} (MJPEG over HTTP, own process)")
        clock.say(
            f"simulated car on CAN bus {CAN_INTERFACE}:{rig.can_channel} (wheel speeds and "
            "yaw rate, sim/vehicle.dbc)"
        )
        config_path = out / "config.yaml"
        data = _config(rig.server.url, rig.camera.url, rig.can_channel, calib_path, seconds)
        config_path.write_text(
            "# the demo's configuration (the devices lived only while it ran)\n"
            + yaml.safe_dump(data, sort_keys=False),
            encoding="utf-8",
        )
        config = configfile.load(config_path)
        recorder = Recorder(config, out_dir=rec_dir, notifier=Notifier({}))  # stopped by _record
        clock.say(f"recording {seconds:g} s through the recorder")
        code = _record(recorder, rig, seconds, clock)
        truth_frames = rig.camera.truth()
    finally:
        rig.close()
    result.steps_s["record"] = clock.lap()
    parts = sorted(rec_dir.glob("*.mcap"))
    if code != EXIT_OK or len(parts) != 1:
        raise AcqError(f"the recorder stopped with code {code}, files {parts}")
    mcap_path = out / "demo.mcap"
    parts[0].replace(mcap_path)
    shutil.rmtree(rec_dir, ignore_errors=True)
    clock.say(f"wrote {mcap_path} ({_size(mcap_path)})")

    log = drive_log.read_log(mcap_path)
    # `acq colorize DIR/demo.mcap --calib DIR/calib.yaml`, placing with the true trajectory
    ply_path, png_path = out / "cloud.ply", out / "preview.png"
    stamps = np.concatenate([log.scan_ns, log.frame_ns])
    truth = rig.trajectory(int(stamps.min()) - 10**9, int(stamps.max()) + 10**9)
    results: list[colorize.ChunkResult] = []
    colorize.run(
        [mcap_path], calibfile.load(calib_path), ply_path, trajectory=truth, results=results
    )
    pc = colorize.cloud_of(results, log)
    result.steps_s["colour"] = clock.lap()
    clock.say(
        f"coloured {pc.size:,} points from {log.n_scans} scans with {pc.frames_used} frames "
        f"into {ply_path}"
    )
    length = float(np.linalg.norm(pc.scan_origin[-1] - pc.scan_origin[0]))
    title = (
        f"acq demo: {pc.size:,} points, {100 * pc.coloured_share:.0f} % coloured, "
        f"{log.n_scans} scans, {log.n_frames} frames, {length:.0f} m of street"
    )
    cloud.preview_png(png_path, pc, title=title)
    result.steps_s["write"] = clock.lap()
    clock.say(f"wrote {png_path}")

    info = log_info(mcap_path)
    truth_lines, result.colour_agreement = _truth(rig, log, pc, truth_frames)
    truth_lines += _odometry_truth(rig, mcap_path)
    result.steps_s["check"] = clock.lap()
    result.steps_s["total"] = time.monotonic() - clock.t0
    result.files = {
        "log": mcap_path,
        "cloud": ply_path,
        "preview": png_path,
        "calib": calib_path,
        "config": config_path,
    }
    result.lines = _summary(result, recorder, info, log, pc, truth_lines)
    result.frames_used = pc.frames_used
