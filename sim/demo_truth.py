"""`acq demo`'s checks against the simulator's truth: the recorded scan stamps and every
camera's frame stamps, the CAN odometry and its dead reckoning, and each coloured
point's colour against the true colour of the surface the laser hit (the demo owns the
simulator, so it can).

A camera's frame stamps are measured against true time, but its ``time_offset_s`` is
camera time minus LASER time, and the laser's stamps are off too (by tenths of a
millisecond, another amount each run): the true ``time_offset_s``, what ``acq calibrate
time-offset`` estimates, is the frames' mean error minus the scans', both re-timed as
``acq colorize`` does (:mod:`acq.time.retime`).

Times host monotonic (s unless ``_ns``); metres; colours RGB.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from acq import cloud, motion
from acq.log import drive_log
from acq.log.vehicle_log import read_vehicle
from acq.sim import sensors
from acq.sim.camera_device import FrameTruth, jpeg_digest
from acq.sim.can_vehicle import true_motion
from acq.sim.demo_rig import CAMERA_SIM, SimRig, demo_rig
from acq.sim.raycast import cast
from acq.time import retime

__all__ = ["COLOUR_TOLERANCE", "check_log", "check_odometry", "colour_check"]

COLOUR_TOLERANCE = 24  # max |channel difference| for "the same colour as the truth"


def check_odometry(rig: SimRig, mcap_path: Path) -> list[str]:
    """Summary lines comparing the recorded CAN odometry with the car's true motion at
    the odometry's stamps, and its dead reckoning with the true path over the log."""

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


def _frame_lines(
    rig: SimRig,
    name: str,
    log: drive_log.DriveLog,
    truth: list[FrameTruth],
    expected: float,
    scan_err_s: float | None,
) -> list[str]:
    """Camera ``name``'s recorded frame stamps against the true middles of exposure of
    the frames it sent (matched by the bytes' hash), the true ``time_offset_s`` (module
    docstring; ``scan_err_s`` the re-timed scans' mean error, s), its middle recorded
    frame against the simulator's view through that camera at that time, and a warning
    when it fell behind."""
    by_digest = {t.digest: t.t_mid for t in truth if t.digest}
    matched = [
        (i, by_digest[d]) for i, d in enumerate(jpeg_digest(j) for j in log.jpegs) if d in by_digest
    ]
    ferr = np.array([log.frame_ns[i] * 1e-9 - t_mid for i, t_mid in matched])
    lines = []
    if ferr.size:
        lines.append(
            f"{name} frame stamps {1e3 * ferr.mean():+.2f} ms mean, {1e3 * ferr.std():.2f} ms sd "
            f"off the true middle of exposure ({ferr.size} frames; the camera sends no time)"
        )
        if scan_err_s is not None:
            new_ns = retime.retime_frames(log.frame_ns).frame_ns
            fnew = float(np.mean([new_ns[i] * 1e-9 - t_mid for i, t_mid in matched]))
            lines.append(
                f"  time_offset_s {1e3 * (fnew - scan_err_s):+.2f} ms (camera minus laser "
                f"time, what acq calibrate time-offset estimates): the frames "
                f"{1e3 * fnew:+.2f} ms minus the scans {1e3 * scan_err_s:+.2f} ms, both "
                "re-timed as acq colorize does"
            )
        i, t_mid = matched[len(matched) // 2]
        seen = cv2.imdecode(np.frombuffer(log.jpegs[i], np.uint8), cv2.IMREAD_COLOR)
        src = rig.source
        view = sensors.render_frame(
            src.street, src.trajectory, demo_rig(), (t_mid - rig.t_origin) % rig.loop_s, name
        )
        if seen is not None:
            off = float(np.abs(seen.astype(np.int16) - view).mean())
            lines.append(
                f"  its frame {i}: {off:.1f} levels mean off the simulator's view through the "
                f"{name} camera at its true time (JPEG)"
            )
    late = float(np.median(ferr)) if ferr.size else math.inf
    if late > 0.01 or len(log.jpegs) < 0.8 * expected:
        lines.append(
            f"WARNING: the simulated {name} camera did not keep real time ({len(log.jpegs)} "
            f"frames, median {1e3 * late:.0f} ms late): a busy machine? its colours are misplaced"
        )
    return lines


def check_log(
    rig: SimRig,
    logs: dict[str, drive_log.DriveLog],
    pc: cloud.Cloud,
    truth_frames: dict[str, list[FrameTruth]],
    colour_camera: str | None = None,
) -> tuple[list[str], tuple[float, float]]:
    """Summary lines comparing the log (read once per camera: ``logs`` by camera name)
    with the simulator's truth (``truth_frames``: each camera's), and the shares of checked
    coloured points whose colour is the true surface colour (see colour_check). With
    ``colour_camera``, the camera every point was coloured from: also the shares within
    the tolerance of the surface colour as that camera saw it (times its exposure and
    white balance at the point's time), which balancing the cameras would bring back
    to the surface colour."""

    lines = []
    log = next(iter(logs.values()))
    # scans: the device's record of what it sent, matched by its clock tick
    sent = {s.timestamp: s for s in list(rig.scanner.sent)}
    step_dt = rig.scanner.step_dt
    matched = [(k, sent[int(t)]) for k, t in enumerate(log.scan_ticks) if int(t) in sent]
    scan_err_s = None
    if matched:
        true0 = np.array([s.t0 + s.start * step_dt for _, s in matched])
        err = np.array([log.scan_ns[k] * 1e-9 for k, _ in matched]) - true0
        lines.append(
            f"scan stamps {1e3 * err.mean():+.3f} ms mean, {1e3 * np.abs(err).max():.3f} ms "
            f"max off the true time of point 0 ({len(matched)} scans)"
        )
        model = rig.scanner.model
        new_ns = retime.retime_scans(
            log.scan_ns, log.scan_ticks, log.scan_recv_ns, model.clock_hz, model.clock_bits
        ).scan_ns
        scan_err_s = float(np.mean(np.array([new_ns[k] * 1e-9 for k, _ in matched]) - true0))
    expected = CAMERA_SIM["fps"] * log.n_scans / rig.scanner.model.scan_hz
    for name, camera_log in logs.items():
        truth = truth_frames.get(name, [])
        lines += _frame_lines(rig, name, camera_log, truth, expected, scan_err_s)
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
    rgb = pc.rgb[checked]
    f_px = src.rig.lens.fx
    strict, near = colour_check(src.street, origins, dirs, rgb, f_px, COLOUR_TOLERANCE)
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
    if colour_camera is not None:
        gains = demo_rig().camera(colour_camera).photometry.gains(t_drive)
        seen_strict, seen_near = colour_check(
            src.street, origins, dirs, rgb, f_px, COLOUR_TOLERANCE, gains=gains
        )
        lines.append(
            f"  as the {colour_camera} camera saw it (its exposure and white balance, not "
            f"balanced): {100 * seen_strict.mean():.1f} %, {100 * seen_near.mean():.1f} % within "
            "a pixel"
        )
    return lines, shares


def colour_check(
    street: Any,
    origins: np.ndarray,
    dirs: np.ndarray,
    rgb: np.ndarray,
    f_px: float,
    tolerance: int = COLOUR_TOLERANCE,
    gains: np.ndarray | None = None,
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
    ``gains`` (N,3) BGR: the true colours as a camera of those gains sees them
    (:func:`acq.sim.sensors.apply_gains`), for colours not balanced.
    """

    rgb = np.asarray(rgb, dtype=np.int16)
    up = np.where(np.abs(dirs[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(dirs, up)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(dirs, e1)
    colours = [cast(street, origins, dirs).colour]
    for e in (e1, -e1, e2, -e2):
        d = dirs + e / f_px
        colours.append(cast(street, origins, d / np.linalg.norm(d, axis=1, keepdims=True)).colour)
    if gains is not None:
        colours = [sensors.apply_gains(c, gains) for c in colours]
    true_rgb = np.stack(colours)[:, :, ::-1].astype(np.int16)  # (5, N, 3)
    strict = np.abs(rgb - true_rgb[0]).max(axis=1) <= tolerance
    lo, hi = true_rgb.min(axis=0) - tolerance, true_rgb.max(axis=0) + tolerance
    near = strict | np.all((rgb >= lo) & (rgb <= hi), axis=1)
    return strict, near
