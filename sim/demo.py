"""`acq demo`: the simulated rig, recorded through the real recorder, coloured into a cloud.

The rig (:mod:`acq.sim.demo_rig`): a simulated Hokuyo UTM-30LX (SCIP 2.0 on a
pseudo-terminal, its own drifting millisecond clock), two simulated 185-degree fisheyes,
``left`` and ``right`` (MJPEG over HTTP, each in its own process so its rendering and
JPEG encoding take no other's GIL; each its own lens, mounting, latency, frame clock,
exposure and white balance) and the simulated car (:mod:`acq.sim.can_vehicle`: wheel
speeds and yaw rate as CAN frames of ``sim/vehicle.dbc`` on a python-can ``virtual``
bus, which reaches the recorder because both run in this process), all driving down the
synthetic street from one shared instant ``t_origin``. The real recorder (drivers, clock
sync, CAN odometry, MCAP writer) records them for ``seconds`` into ``DIR/demo.mcap``
(``/laser/scan``, ``/left/image/compressed``, ``/right/image/compressed``,
``/vehicle/odometry``, ``/vehicle/can``...); the log is then coloured with the rig's
true calibration (``DIR/calib.yaml``) into ``DIR/cloud.ply`` and pictured in
``DIR/preview.png``; its facets are joined as `acq mesh` joins them into ``DIR/mesh.glb``
(per-vertex colour, one file) and, textured from the fisheye frames as `acq mesh
--texture` does, into ``DIR/mesh_textured.glb``; both are read back and rendered, with
the cloud, from three viewpoints along the drive beside the true street
(:mod:`acq.sim.mesh_views`) into ``DIR/mesh_views.png``, the summary giving how close
each comes to the truth.

The demo colours through the pipeline of ``acq colorize``
(:func:`acq.cloud.colorize.run`: offline re-timing, chunks, views, the PLY writer) with
the simulator's trajectory in place of the log's odometry, so the cloud lies in the
street's world frame: because the demo owns the simulator, the summary checks the chain
against the truth (:mod:`acq.sim.demo_truth`: the scan stamps and every camera's frame
stamps, the recorded odometry, and each coloured point's colour against the true colour
of the surface the laser hit). ``acq colorize DIR/demo.mcap --calib DIR/calib.yaml``
colours the same log from the recorded CAN odometry instead (dead reckoning), as on a
real drive.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from acq import cloud
from acq.camera import calibfile
from acq.cli.mesh import TEXELS
from acq.cloud import colorize
from acq.errors import AcqError, InputError
from acq.log import LogInfo, drive_log
from acq.log import info as log_info
from acq.mesh.drive import MeshReport, prepare_mesh
from acq.provenance import write_image
from acq.record import config as configfile
from acq.record.recorder import Recorder, RecorderError
from acq.record.sdnotify import Notifier
from acq.sim.camera_device import FrameTruth
from acq.sim.demo_rig import (
    CAMERAS,
    SCANNER_DRIFT_PPM,
    SCANNER_MODEL,
    SimRig,
    camera_latency_s,
    camera_sim,
    rig_config,
    true_calibration,
)
from acq.sim.demo_truth import check_log, check_odometry
from acq.sim.mesh_views import (
    ViewsResult,
    compare,
    picture,
    read_mesh,
    read_textured_mesh,
    street_views,
)
from acq.sim.out_folder import claim_folder, record_files

__all__ = ["MAX_SECONDS", "OUT_MARK", "DemoResult", "run"]

EXIT_OK, EXIT_FAILURE = 0, 1

# The camera the demo colours from: None, every camera of calib.yaml (as `acq colorize`
# does by default); a name colours from that camera alone.
COLOUR_CAMERA: str | None = None

# The cameras render the frames of the recording before it starts (see SimRig): the
# drive from its start to the recorder's start, the recording and its stop take about
# --seconds + PRERENDER_MARGIN_S; at most PRERENDER_MAX_S (memory: 1.8 MB per second).
PRERENDER_MARGIN_S = 2.0
PRERENDER_MAX_S = 60.0
STOP_AHEAD_S = 0.005  # the recorder is stopped this long before a scan is due (see _record)
DRIFT_RESOLVED_PPM = 20.0  # a drift interval this wide or narrower is shown as a figure
MAX_SECONDS = 170.0  # the simulated drive loops over its 1 km street every 180 s
OUT_MARK = ".acq-demo"  # in a folder the demo wrote: it may write there again
FILES = (
    "demo.mcap", "cloud.ply", "preview.png", "mesh.glb", "mesh_textured.glb",
    "mesh_views.png", "calib.yaml", "config.yaml",
)  # fmt: skip
VIEWS_AT = (0.35, 0.5, 0.65)  # the mesh's three viewpoints, as shares of the drive's time


@dataclass
class DemoResult:
    """What the demo did: files written, counts, checks against the truth, step times."""

    out: Path
    files: dict[str, Path] = field(default_factory=dict)
    steps_s: dict[str, float] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)  # the printed summary
    frames_used: int = 0  # frames the cloud was coloured from
    frames: dict[str, int] = field(default_factory=dict)  # frames recorded, per camera
    # CPU s: this process while recording (recorder, scanner, car), each camera's process
    cpu_s: dict[str, float] = field(default_factory=dict)
    colour_agreement: tuple[float, float] = (math.nan, math.nan)  # strict, within a pixel
    mesh: MeshReport | None = None  # what the mesh step wrote
    textured: MeshReport | None = None  # what the textured mesh step wrote
    views: ViewsResult | None = None  # the mesh and the cloud from three viewpoints


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


def _output(seconds: float) -> dict[str, Any]:
    """The recorder's output section: one file for the whole recording."""
    return {
        "dir": ".recording",
        "prefix": "demo",
        "split_minutes": max(10.0, math.ceil(seconds / 60.0) + 1.0),
        "split_megabytes": 1e6,
        "reserve_megabytes": 50,
    }


def _record(recorder: Recorder, rig: SimRig, seconds: float, clock: _Clock) -> int:
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
                frames = ", ".join(f"{d[name].received} {name}" for name in CAMERAS if name in d)
                clock.say(
                    f"recording {min(elapsed, seconds):4.1f} s of {seconds:g}: "
                    f"{d['laser'].received} scans, frames {frames}"
                    + (f", {d['vehicle'].received} odometry" if "vehicle" in d else "")
                )
    finally:
        recorder.stop()
        thread.join()
    return codes[0] if codes else EXIT_FAILURE


def _stop_before_a_scan(rig: SimRig, ahead_s: float = STOP_AHEAD_S) -> None:
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


def _camera_lines(info: LogInfo, truth_frames: dict[str, list[FrameTruth]]) -> list[str]:
    """Per camera: frames recorded (rate), the recorder's drops, frames the camera sent
    late or not at all while recorded, and the latency the driver subtracts."""
    chan = {c.topic: c for c in info.channels}
    lines = []
    for name in CAMERAS:
        frames = chan.get(f"/{name}/image/compressed")
        sim = camera_sim(name)
        truth = truth_frames.get(name, [])
        late = sum(t.status == "late" for t in truth)
        delay = max(
            (t.t_sent - t.t_available for t in truth if t.status == "sent" and t.t_sent),
            default=math.nan,
        )
        recorded = f"{frames.count} frames ({frames.rate_hz:.1f} Hz)" if frames else "no frames"
        lines.append(
            f"{name}: {recorded}, drops {info.drops.get(name, 0)}, late {late} (not sent: over "
            f"0.5 s late), the others sent at most {delay * 1e3:.1f} ms after due; latency "
            f"{camera_latency_s(name) * 1e3:.1f} ms configured (sim {sim['latency_s'] * 1e3:.0f} "
            f"ms + half the {sim['exposure_s'] * 1e3:.0f} ms exposure + mean jitter)"
        )
    return lines


def _summary(
    result: DemoResult,
    recorder: Recorder,
    info: LogInfo,
    pc: cloud.Cloud,
    truth_frames: dict[str, list[FrameTruth]],
    truth_lines: list[str],
    notes: list[str],
) -> list[str]:
    chan = {c.topic: c for c in info.channels}
    scans = chan.get("/laser/scan")
    laser = recorder.devices["laser"]
    sync = {d.name: d for d in info.devices}
    lines = ["summary"]
    rec = f"  recorded  {info.duration_s:.1f} s"
    if scans is not None:
        rec += f": {scans.count} scans ({scans.rate_hz:.1f} Hz)"
    drops = ", ".join(
        f"{name} {n}" for name, n in sorted(info.drops.items()) if name not in CAMERAS
    )
    lines.append(rec + f"; drops: {drops or 'none'}")
    lines.extend(f"  cameras   {t}" if i == 0 else f"            {t}"
                 for i, t in enumerate(_camera_lines(info, truth_frames)))  # fmt: skip
    clock = "  clock     laser: "
    if laser.latency_bounds_s is not None:
        lo, hi = laser.latency_bounds_s
        clock += f"latency {laser.latency_s * 1e3:.2f} ms (TM bounds {lo * 1e3:.2f}-{hi * 1e3:.2f})"
    else:
        clock += f"latency {laser.latency_s * 1e3:.2f} ms (no TM bounds)"
    ls = sync.get("laser")
    if ls is not None and ls.drift_fit_ppm is not None and ls.drift_ci_ppm is not None:
        true_ppm = (1.0 / (1.0 + SCANNER_DRIFT_PPM * 1e-6) - 1.0) * 1e6  # host s per device s
        lo, hi = ls.drift_ci_ppm
        if hi - lo <= DRIFT_RESOLVED_PPM:
            clock += f", drift {ls.drift_fit_ppm:+.1f} ppm (95 % {lo:+.1f}..{hi:+.1f}; "
        else:  # the device's ticks cannot pin it: no figure that reads as the drift
            clock += (f", drift unresolved in {info.duration_s:.0f} s of device ticks: "
                      f"within {lo:+.0f}..{hi:+.0f} ppm at 95 % (")  # fmt: skip
        clock += f"true {true_ppm:+.1f})"
    if ls is not None and ls.residual_ms_p50 is not None:
        clock += f", receipt - stamp {ls.residual_ms_p50:.2f}/{ls.residual_ms_p95:.2f} ms p50/p95"
    lines.append(clock)
    lines.extend(f"  truth     {t}" if i == 0 else f"            {t}"
                 for i, t in enumerate(truth_lines))  # fmt: skip
    source = f"the {COLOUR_CAMERA} camera's" if COLOUR_CAMERA else "the cameras'"
    lines.append(
        f"  cloud     {pc.size:,} points, {int(pc.coloured.sum()):,} coloured "
        f"({100 * pc.coloured_share:.1f} %) from {pc.frames_used} of {source} {pc.frames} frames"
    )
    if result.mesh is not None and result.views is not None:
        v = result.views
        lines.append(
            f"  mesh      {result.mesh.facets:,} facets on {result.mesh.vertices:,} vertices; "
            f"from {len(v.names)} viewpoints beside the true street, where it is visible "
            f"and covered: mesh {v.mesh.text()}; cloud {v.cloud.text()}"
        )
    if result.textured is not None and result.views is not None and result.views.textured:
        lines.append(
            f"  textured  {result.textured.textured or 0:,} of {result.textured.facets:,} "
            f"facets textured from a frame; from the same viewpoints: "
            f"{result.views.textured.text()}"
        )
    lines.append("  files     " + ", ".join(
        f"{p} ({_size(p)})" if i == 0 else f"{p.name} ({_size(p)})"
        for i, p in enumerate(result.files.values())
    ))  # fmt: skip
    lines.append("  time      " + ", ".join(
        f"{k} {v:.1f} s" for k, v in result.steps_s.items()
    ))  # fmt: skip
    lines.append("  CPU       " + ", ".join(
        f"{k} {v:.1f} s" for k, v in result.cpu_s.items()
    ) + " (the recorder, scanner and car while recording; each camera's process, its "
        "frames rendered first)")  # fmt: skip
    if notes:
        lines.append("  notes     " + "; ".join(notes))
    folder = next(iter(result.files.values())).parent
    lines.append(f"  look      acq view {folder}   (its cloud, meshes and drive in a web browser)")
    return lines


def _views(
    rig: SimRig, scan_ns: np.ndarray, glb: Path, textured_glb: Path, pc: cloud.Cloud
) -> ViewsResult:
    """The mesh read back from ``glb``, the textured mesh from ``textured_glb`` and the
    cloud ``pc`` from three viewpoints along the recorded drive (its scans' host times
    ``scan_ns``), beside the true street."""
    origin_ns = round(rig.t_origin * 1e9)
    t0, t1 = ((int(scan_ns[k]) - origin_ns) * 1e-9 % rig.loop_s for k in (0, -1))
    source = rig.source
    views = street_views(source.trajectory, [t0 + f * (t1 - t0) for f in VIEWS_AT])
    between_scans_m = source.trajectory.speed * source.rig.scan_period  # the splat's size
    return compare(source.street, views, read_mesh(glb), (pc.xyz, pc.rgb), between_scans_m,
                   textured=read_textured_mesh(textured_glb))  # fmt: skip


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
    claim_folder(out, OUT_MARK, "acq demo's", FILES)
    try:
        _make(result, seconds, progress)
    finally:  # what it wrote, also when it failed: the next run may replace it
        record_files(out, OUT_MARK, "acq demo's", FILES)


def _make(result: DemoResult, seconds: float, progress: Callable[[str], None]) -> None:
    """The demo's files into its claimed folder ``result.out``."""
    out = result.out
    clock = _Clock(progress)
    progress(
        f"acq demo: a simulated UTM-30LX and two 185-degree fisheyes ({', '.join(CAMERAS)}) "
        f"driving down a synthetic street,\nrecorded for {seconds:g} s by the real recorder, "
        f"coloured into a cloud; into {out}/"
    )
    rec_dir = Path(tempfile.mkdtemp(prefix=".recording-", dir=out))
    calib = true_calibration()
    calib_path = out / "calib.yaml"
    calibfile.save(calib, calib_path)
    clock.say(
        f"the cameras render their first {min(seconds + PRERENDER_MARGIN_S, PRERENDER_MAX_S):g} s "
        "of frames"
    )
    rig = SimRig(prerender_s=min(seconds + PRERENDER_MARGIN_S, PRERENDER_MAX_S))
    try:
        result.steps_s["start"] = clock.lap()
        clock.say(f"simulated {SCANNER_MODEL.upper()} on {rig.server.url} (SCIP over a pty)")
        for name, camera in rig.cameras.items():
            clock.say(f"simulated {name} fisheye at {camera.url} (MJPEG over HTTP, own process)")
        clock.say(
            f"simulated car on CAN bus {rig.urls['vehicle']} (wheel speeds and "
            "yaw rate, sim/vehicle.dbc)"
        )
        config_path = out / "config.yaml"
        data = rig_config(rig, calib_path, _output(seconds))
        config_path.write_text(
            "# the demo's configuration (the devices lived only while it ran)\n"
            + yaml.safe_dump(data, sort_keys=False),
            encoding="utf-8",
        )
        config = configfile.load(config_path)
        recorder = Recorder(config, out_dir=rec_dir, notifier=Notifier({}))  # stopped by _record
        clock.say(f"recording {seconds:g} s through the recorder")
        cpu0 = time.process_time()
        code = _record(recorder, rig, seconds, clock)
        result.cpu_s["recording"] = time.process_time() - cpu0
        truth_frames = {name: camera.truth() for name, camera in rig.cameras.items()}
        for name, camera in rig.cameras.items():
            result.cpu_s[name] = camera.cpu_seconds()
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

    whole = drive_log.read_log(mcap_path, cameras=list(CAMERAS))  # once, every camera
    logs = {name: whole.with_camera(name) for name in CAMERAS}
    log = logs[COLOUR_CAMERA or CAMERAS[0]]
    # `acq colorize DIR/demo.mcap --calib DIR/calib.yaml`, placing with the true trajectory
    ply_path, png_path = out / "cloud.ply", out / "preview.png"
    stamps = np.concatenate([log.scan_ns, *(g.frame_ns for g in logs.values())])
    truth = rig.trajectory(int(stamps.min()) - 10**9, int(stamps.max()) + 10**9)
    results: list[colorize.ChunkResult] = []
    colorize.run(
        [mcap_path],
        calibfile.load(calib_path),
        ply_path,
        camera=COLOUR_CAMERA,
        trajectory=truth,
        results=results,
    )
    colour_cameras = [COLOUR_CAMERA] if COLOUR_CAMERA else list(CAMERAS)
    pc = colorize.cloud_of(results, log, colour_cameras)
    pc = replace(pc, frames=sum(logs[name].n_frames for name in colour_cameras))
    result.steps_s["colour"] = clock.lap()
    clock.say(
        f"coloured {pc.size:,} points from {log.n_scans} scans with {pc.frames_used} frames "
        f"into {ply_path}"
    )
    length = float(np.linalg.norm(pc.scan_origin[-1] - pc.scan_origin[0]))
    n_frames = sum(g.n_frames for g in logs.values())
    title = (
        f"acq demo: {pc.size:,} points, {100 * pc.coloured_share:.0f} % coloured, "
        f"{log.n_scans} scans, {n_frames} frames of {len(logs)} cameras, {length:.0f} m of street"
    )
    cloud.preview_png(png_path, pc, title=title)
    result.steps_s["write"] = clock.lap()
    clock.say(f"wrote {png_path}")
    glb_path, views_path = out / "mesh.glb", out / "mesh_views.png"
    textured_path = out / "mesh_textured.glb"
    calib = calibfile.load(calib_path)
    result.mesh = prepare_mesh(
        [mcap_path], calib, glb_path, camera=COLOUR_CAMERA, trajectory=truth, tile_m=math.inf,
    ).run()  # fmt: skip
    result.textured = prepare_mesh(
        [mcap_path], calib, textured_path, camera=COLOUR_CAMERA, trajectory=truth,
        tile_m=math.inf, texels=TEXELS,
    ).run()  # fmt: skip
    result.views = _views(rig, log.scan_ns, glb_path, textured_path, pc)
    title = (f"acq demo: {result.mesh.facets:,} facets (vertex colours, textured) and the "
             "cloud, beside the true street")  # fmt: skip
    write_image(views_path, picture(result.views, title)[:, :, ::-1])
    result.steps_s["mesh"] = clock.lap()
    clock.say(
        f"wrote {glb_path} ({_size(glb_path)}), {textured_path} ({_size(textured_path)}) "
        f"and {views_path}"
    )

    info = log_info(mcap_path)
    truth_lines, result.colour_agreement = check_log(
        rig, logs, pc, truth_frames, colour_camera=COLOUR_CAMERA
    )
    truth_lines += check_odometry(rig, mcap_path)
    result.steps_s["check"] = clock.lap()
    result.steps_s["total"] = time.monotonic() - clock.t0
    result.files = {
        "log": mcap_path,
        "cloud": ply_path,
        "preview": png_path,
        "mesh": glb_path,
        "textured mesh": textured_path,
        "mesh views": views_path,
        "calib": calib_path,
        "config": config_path,
    }
    notes = list(dict.fromkeys(n for g in logs.values() for n in g.notes))
    result.lines = _summary(result, recorder, info, pc, truth_frames, truth_lines, notes)
    result.frames_used = pc.frames_used
    result.frames = {name: g.n_frames for name, g in logs.items()}
