"""What every chunk of `acq colorize` needs (:class:`Job`), made from a session's logs
(steps 1-3 of :mod:`acq.cloud.colorize`): the log's light part, the offline re-timing of
its scans and frames, the trajectory to place points with.

Times host monotonic ns unless ``_s``; metres.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from acq import motion
from acq.camera import projection
from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import CameraModel
from acq.camera.selection import choose_cameras
from acq.cloud import views
from acq.cloud.report import Report
from acq.drivers.scanner import SCANNERS
from acq.errors import InputValueError
from acq.geometry.transforms import Rigid
from acq.log.drive_log import DriveLog, check_frame_size, read_log
from acq.log.inputs import session_files
from acq.log.vehicle_log import read_vehicle
from acq.motion import Trajectory
from acq.motion.pose_source import trajectory_from_vehicle
from acq.time import retime
from acq.time.utc import host_ns_from_utc

__all__ = ["CameraJob", "Job", "check_crs", "prepare", "remap"]


@dataclass(frozen=True)
class CameraJob:
    """One camera's part of a :class:`Job`: its name in the log and calibration, its
    calibration, its frames' re-timing map (recorded stamp -> new, sorted by recorded
    stamp) and its time offset (camera time minus laser time, ns)."""

    name: str
    cam: CameraCalib
    frame_old: np.ndarray
    frame_new: np.ndarray
    time_offset_ns: int


@dataclass(frozen=True)
class Job:
    """What every chunk needs (small, picklable): the files, the laser, the cameras to
    colour from (:class:`CameraJob`, none for a log without frames), the scans'
    re-timing map (recorded stamp -> new, sorted by recorded stamp), the trajectory (an
    :class:`acq.motion.trajectory.Trajectory`; None: laser frame) and the options."""

    files: tuple[str, ...]
    laser: str
    cameras: tuple[CameraJob, ...]
    laser_to_vehicle: Rigid
    scan_old: np.ndarray
    scan_new: np.ndarray
    trajectory: Any
    options: views.Options
    frame_world: bool
    travel_m: float  # the rig's travel between two scans (m), for the points' size
    want_uv: bool = False  # keep each point's pixel and frame (for accuracy checks)
    # with want_uv: keep each decoded frame's part around its points (views.Crop), for
    # acq mesh --texture to sample without decoding the frame again
    want_crops: bool = False
    threads: int = 1  # JPEG decoding threads per chunk

    def with_offsets(self, offsets_ns: dict[str, int]) -> Job:
        """This job with the time offsets of the cameras named in ``offsets_ns``."""
        cams = tuple(
            replace(c, time_offset_ns=offsets_ns[c.name]) if c.name in offsets_ns else c
            for c in self.cameras
        )
        return replace(self, cameras=cams)


def remap(old: np.ndarray, new: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """``stamps`` through the (sorted ``old`` -> ``new``) map; unknown ones unchanged."""
    if old.size == 0:
        return stamps.copy()
    i = np.clip(np.searchsorted(old, stamps), 0, old.size - 1)
    return np.where(old[i] == stamps, new[i], stamps)


def _retime_scans(log: DriveLog, report: Report) -> np.ndarray:
    """New stamps for ``log``'s scans (its recorded ones, sorted); notes in ``report``."""
    scan_new = log.scan_ns.copy()
    if not np.any(log.scan_ticks >= 0):  # a ROS 2 bag, or no timing records
        report.notes.append("scans not re-timed: the log has no device ticks (stamps kept)")
        return scan_new
    driver = log.metadata.get(f"device.{log.laser}", {}).get("driver", "")
    try:
        cls = SCANNERS.get(driver)
        rs = retime.retime_scans(
            log.scan_ns, log.scan_ticks, log.scan_recv_ns, cls.tick_hz, cls.tick_bits
        )
        scan_new = rs.scan_ns
        report.retiming.update(scan_shift_rms_ms=rs.shift_rms_ms, scan_shift_max_ms=rs.shift_max_ms)
        if rs.note:
            report.notes.append(f"scans not re-timed: {rs.note}")
    except (KeyError, ValueError) as e:
        report.notes.append(f"scans not re-timed: unknown scanner driver {driver!r} ({e})")
    return scan_new


def _retime_frames(log: DriveLog, report: Report, first: bool) -> np.ndarray:
    """New stamps for the frames of ``log``'s camera; notes in ``report`` (the first
    camera's figures also at the top of ``report.retiming``, as for one camera)."""
    if not log.n_frames:
        return log.frame_ns.copy()
    rf = retime.retime_frames(log.frame_ns)
    figures = {
        "frame_period_s": rf.period_s,
        "frame_residual_rms_ms": rf.residual_rms_ms,
        "frame_shift_max_ms": rf.shift_max_ms,
    }
    report.retiming.setdefault("cameras", {})[log.camera] = figures
    if first:
        report.retiming.update(figures)
    if rf.note:
        report.notes.append(f"{log.camera}: frames not re-timed: {rf.note}")
    return rf.frame_ns


def _trajectory(
    files: Sequence[Path],
    given: Path | Trajectory | None,
    log: DriveLog,
    report: Report,
    crs: str | None = None,
) -> Any:
    """The trajectory to place points with, or None (see the module docstring, step 3):
    ``given`` as it is, read from its file, or made from the log; in ``crs`` when one
    is asked for (GNSS fixes and a file's latitudes/longitudes projected into it)."""
    if isinstance(given, Trajectory):
        report.trajectory = f"given ({len(given)} poses)"
        return given
    path = given
    if path is not None:
        clock = log.clock
        traj = motion.from_csv(path, utc_to_host_ns=lambda u: host_ns_from_utc(u, clock), frame=crs)
        report.trajectory = f"{path} ({len(traj.t_ns)} poses)"
        return traj
    vehicle = log.vehicle
    if vehicle is None:
        vehicle = read_vehicle(list(files))
    chosen = trajectory_from_vehicle(vehicle, crs)
    report.notes += chosen.notes
    if chosen.trajectory is not None:
        report.trajectory = chosen.description
    return chosen.trajectory


def check_crs(crs: str, traj: Any, world: bool, what: str) -> None:
    """InputValueError unless the points will really be in ``crs``: placed in the world
    frame (``world``) by a trajectory ``traj`` whose frame is that CRS. ``what``: the
    trajectory as the report names it."""
    import pyproj

    need = (
        "--crs needs a georeferenced trajectory: GNSS fixes in the log, or --trajectory CSV "
        "(GNSS/INS)"
    )
    if not world:
        place = "the laser frame" if traj is None else "the laser frame (--frame laser)"
        raise InputValueError(f"--crs {crs}: the points would be in {place}; {need}")
    frame = str(getattr(traj, "frame", "odometry"))
    if frame == "odometry":
        raise InputValueError(
            f"--crs {crs}: the trajectory is {what}, local coordinates with no tie to the "
            f"Earth; {need}"
        )
    if frame == "enu" or not pyproj.CRS.from_user_input(frame).equals(
        pyproj.CRS.from_user_input(crs)
    ):
        raise InputValueError(
            f"--crs {crs}: the trajectory ({what}) is in {frame}, not reprojected; give "
            f"the trajectory in {crs}"
        )
    if any(getattr(traj, "origin", (0.0, 0.0, 0.0))):
        raise InputValueError(
            f"--crs {crs}: the trajectory's coordinates are {crs} minus an origin offset "
            f"{traj.origin}; give them whole"
        )


def _warm_kernels(model: CameraModel) -> None:
    """Load the compiled kernels colorize calls, each on a tiny input of the real types
    (numba's first call of a cached kernel costs a tenth of a second or more, part of it
    without the GIL): run on a thread while the log is read."""

    try:
        traj = Trajectory(np.array([0, 10**8]), np.stack([np.eye(3)] * 2), np.zeros((2, 3)))
        t = np.array([5 * 10**7], dtype=np.int64)
        traj.pose_at(t)
        traj.transform(t, np.zeros((1, 3)))
        image = np.zeros((model.height, model.width, 3), dtype=np.uint8)
        projection.colour_into(
            np.zeros((1, 3)), np.zeros(1, dtype=np.int64), model, (np.eye(3), np.zeros(3)),
            image, np.zeros((1, 3), dtype=np.uint8), np.zeros(1, dtype=bool),
        )  # fmt: skip
    except Exception:  # only a head start: the real calls report any problem
        pass


def prepare(
    logs: Sequence[Path],
    calib: Calibration,
    report: Report,
    *,
    camera: str | Sequence[str] | None = None,
    frame: str | None = None,
    options: views.Options | None = None,
    trajectory: Path | Trajectory | None = None,
    retime_offline: bool = True,
    time_offset_s: float | None = None,
    jpegs: bool = False,
    threads: int = 1,
    crs: str | None = None,
    jpegs_for_s: float | None = None,
) -> tuple[Job, DriveLog]:
    """The :class:`Job` for ``logs`` (steps 1-3 of the module docstring) and the log's
    light part (with the images and the scans' returns when ``jpegs``: else the chunks
    read their own; ``jpegs_for_s``: only the images of the log's first that many
    seconds, as :func:`acq.log.drive_log.read_log` takes it); notes go into ``report``. ``camera``:
    the cameras to colour from (default: every camera of ``calib`` in the log; a
    calibration of one camera pairs with the log's only camera). ``time_offset_s``:
    for every camera, instead of ``calib``'s. ``trajectory``:
    a file (``--trajectory``) or the poses themselves; None: from the log. ``crs``: the
    output's CRS, InputValueError (:func:`check_crs`) unless the trajectory is in it."""
    options = options or views.Options()
    files = session_files(logs)
    names = [camera] if isinstance(camera, str) else list(camera or ())
    first = calib.cameras.get(names[0]) if names else next(iter(calib.cameras.values()), None)
    if first is not None:
        threading.Thread(target=_warm_kernels, args=(first.model,), daemon=True).start()
    index = read_log(files, cameras=names, jpegs=jpegs, returns=jpegs,
                     vehicle=trajectory is None, calib=calib, jpegs_for_s=jpegs_for_s)  # fmt: skip
    report.notes += index.notes
    pairs = _camera_calibs(index, calib, names, report)
    scan_new = _retime_scans(index, report) if retime_offline else index.scan_ns
    traj = _trajectory(files, trajectory, index, report, crs)
    world = frame == "world" if frame is not None else traj is not None
    if world and traj is None:
        raise InputValueError("--frame world needs a trajectory (CAN odometry or GNSS fixes "
                         "in the log, or --trajectory CSV); use --frame laser")  # fmt: skip
    if crs:
        check_crs(crs, traj, world, report.trajectory or "none")
    if options.view == "best" and (traj is None or not options.motion_compensation):
        raise InputValueError(
            "--view best needs a trajectory (CAN odometry or GNSS fixes in the log, or "
            "--trajectory CSV) and motion compensation; use --view nearest"
            if traj is None
            else "--view best needs motion compensation: drop --no-motion-compensation, "
            "or use --view nearest"
        )
    if traj is None:
        report.notes.append(
            "no trajectory: points in the laser frame at their own time, coloured without "
            "motion compensation (right only while the rig stands still)"
        )
        options = replace(options, motion_compensation=False)
    report.frame = "world" if world else "laser"
    if traj is not None and calib.laser_to_vehicle is None:
        report.notes.append(
            "calib.yaml has no laser_to_vehicle: the laser taken at the vehicle's origin, "
            "its axes the vehicle's; the points' places and the rig's motion at the laser "
            "are wrong unless it is so mounted (add laser_to_vehicle to calib.yaml)"
        )
    s_order = np.argsort(index.scan_ns)
    period = float(np.median(np.diff(np.sort(scan_new)))) * 1e-9 if scan_new.size > 1 else 0.025
    speed = _median_speed(traj, scan_new)
    cameras = []
    for k, (name, cam) in enumerate(pairs):
        frames = index.with_camera(name)
        frame_new = (
            _retime_frames(frames, report, first=k == 0) if retime_offline else frames.frame_ns
        )
        f_order = np.argsort(frames.frame_ns)
        offset = cam.time_offset_s if time_offset_s is None else float(time_offset_s)
        cameras.append(
            CameraJob(name, cam, frames.frame_ns[f_order], frame_new[f_order], round(offset * 1e9))
        )
    job = Job(
        files=tuple(str(f) for f in files),
        laser=index.laser,
        cameras=tuple(cameras),
        laser_to_vehicle=(
            calib.laser_to_vehicle if calib.laser_to_vehicle is not None else Rigid.identity()
        ),
        scan_old=index.scan_ns[s_order],
        scan_new=scan_new[s_order],
        trajectory=traj,
        options=options,
        frame_world=world,
        travel_m=speed * period,
        threads=threads,
    )
    return job, index


def _camera_calibs(
    index: DriveLog, calib: Calibration, names: list[str], report: Report
) -> list[tuple[str, CameraCalib]]:
    """(name in the log, calibration) of each camera to colour from: those ``names``,
    else every camera of both the log and ``calib``
    (:func:`acq.camera.selection.choose_cameras`); without ``names``, a camera of
    ``calib`` left out for want of frames is noted in ``report``."""
    picked = choose_cameras(names, index.camera_names, list(calib.cameras), one=False,
                            calib=calib.label)  # fmt: skip
    used = {key for _, key in picked}
    if not names:  # else the others were not asked for
        report.notes += [f"camera {n}: no frames in the log; not used" for n in calib.cameras
                         if n not in used]  # fmt: skip
    for name, key in picked:
        check_frame_size(index, name, calib.cameras[key])
    return [(name, calib.cameras[key]) for name, key in picked]


def _median_speed(traj: Any, scan_ns: np.ndarray) -> float:
    """The rig's median speed over the log (m/s), 0 without a trajectory."""
    t = np.unique(scan_ns)  # sorted; a stamp twice has no speed
    if traj is None or t.size < 2:
        return 0.0
    t = t[:: max(1, t.size // 200)]
    t = t[traj.covers(t)]
    if t.size < 2:
        return 0.0
    _, pos = traj.pose_at(t)
    v = np.linalg.norm(np.diff(pos, axis=0), axis=1) / (np.diff(t) * 1e-9)
    return float(np.median(v)) if v.size else 0.0
