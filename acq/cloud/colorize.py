"""`acq colorize`: a drive's laser points placed in 3D and coloured from its frames.

1. The log's light part (:func:`acq.log.drive_log.read_log` without image bytes): scan and
   frame stamps with the receipt times and device ticks of the timing records, clock
   pairs, metadata.
2. Offline re-timing (default; :mod:`acq.time.retime`): scans from their ticks over the
   whole log, frames put back on the camera's frame grid.
3. The trajectory (:mod:`acq.motion`): ``--trajectory CSV`` (a post-processed
   GNSS/INS file), else the log's CAN odometry (fused with its GNSS fixes when there are
   any), else none: then the points stay in the laser frame at their own time and are
   coloured without motion compensation (right only for a rig standing still; said in
   the report).
4. Chunks of ``chunk_s`` seconds of scans, each read from the files on its own with the
   frames around it (and, for ``--view best``, the laser points just outside it, for
   the depth buffers), coloured by :func:`acq.cloud.views.start_colouring`; in this process,
   on ``workers`` processes, or on a Dask cluster. The chunking does not depend on how
   the chunks run, so the output bytes do not either. In this process a chunk's frames
   decode on a pool of threads (one per core) while the next chunk is placed and the
   last one written.
5. The cloud, written chunk by chunk in chunk order (:class:`acq.cloud.PlyStream`,
   :class:`acq.cloud.las.LasStream`) under a temporary name renamed at the end (a failure
   leaves no partial file and an earlier output untouched): every point with its own
   time (UTC in PLY, Adjusted Standard GPS time in LAS), scan index, intensity, colour
   and whether it was coloured; ``--frame world`` (with a trajectory) or ``laser``; PLY
   or LAS by the output's extension; a preview PNG.

Times host monotonic ns unless ``_s``; metres; colours RGB.
"""

from __future__ import annotations

import itertools
import math
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from acq import motion
from acq.calib.time_offset import OffsetEstimate, estimate_time_offset
from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import CameraModel
from acq.cloud import views
from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from acq.cloud.points import Cloud
from acq.cloud.preview import preview_png
from acq.errors import InputValueError
from acq.geometry.transforms import Rigid
from acq.log.drive_log import DriveLog, camera_calib, read_log
from acq.log.vehicle_log import read_vehicle
from acq.motion import Trajectory
from acq.time import retime, sync
from acq.time.utc import host_ns_from_utc, utc_seconds

__all__ = [
    "Chunk",
    "ChunkResult",
    "Job",
    "cloud_of",
    "colour_chunk",
    "plan",
    "run",
]

FORMATS = (".ply", ".las", ".laz")
READ_ONCE_BYTES = 2 * 2**30  # logs up to this size are read once, images included
PREVIEW_POINTS = 4_000_000  # at most about this many points kept for the preview
_PER_POINT = ("xyz", "rgb", "coloured", "hidden", "time_ns", "scan", "step", "intensity",
              "dt_s", "theta")  # fmt: skip


@dataclass(frozen=True)
class Job:
    """What every chunk needs (small, picklable): the files, the devices, the camera's
    calibration, the re-timing maps (recorded stamp -> new, sorted by recorded stamp),
    the trajectory (an :class:`acq.motion.trajectory.Trajectory`; None: laser frame) and the
    options."""

    files: tuple[str, ...]
    laser: str
    camera: str
    cam: CameraCalib
    laser_to_vehicle: Rigid
    scan_old: np.ndarray
    scan_new: np.ndarray
    frame_old: np.ndarray
    frame_new: np.ndarray
    time_offset_ns: int
    trajectory: Any
    options: views.Options
    frame_world: bool
    travel_m: float  # the rig's travel between two scans (m), for the points' size
    want_uv: bool = False  # keep each point's pixel and frame (for accuracy checks)
    threads: int = 1  # JPEG decoding threads per chunk


@dataclass(frozen=True)
class Chunk:
    """Scans with (new) stamps in [start_ns, end_ns) of ``job``; ``index`` in the plan."""

    index: int
    start_ns: int
    end_ns: int


@dataclass
class ChunkResult:
    """One chunk's points (see :class:`acq.cloud.Cloud`) and its counters."""

    index: int
    xyz: np.ndarray
    rgb: np.ndarray
    coloured: np.ndarray
    hidden: np.ndarray
    time_ns: np.ndarray
    scan: np.ndarray
    step: np.ndarray
    intensity: np.ndarray
    dt_s: np.ndarray
    theta: np.ndarray
    scan_origin: np.ndarray
    frame_stamp_ns: np.ndarray | None = None  # the recorded stamp of the frame used, -1
    uv: np.ndarray | None = None  # (N,2) float32 px in that frame, NaN
    frames_used: int = 0  # decoded and used for this chunk (its margins included)
    frames_failed: int = 0
    outside: int = 0  # points left out: outside the trajectory's span
    used_stamps: np.ndarray | None = None  # recorded stamps of the frames its points used
    seconds: dict[str, float] = field(default_factory=dict)


def _remap(old: np.ndarray, new: np.ndarray, stamps: np.ndarray) -> np.ndarray:
    """``stamps`` through the (sorted ``old`` -> ``new``) map; unknown ones unchanged."""
    if old.size == 0:
        return stamps.copy()
    i = np.clip(np.searchsorted(old, stamps), 0, old.size - 1)
    return np.where(old[i] == stamps, new[i], stamps)


def _margin_ns(job: Job) -> int:
    period = 0.04  # a camera's frame period, s (the window is counted in frames)
    o = job.options
    return round((o.max_dt_s + o.window * period + o.context_s + 0.2) * 1e9)


@dataclass(frozen=True)
class Placed:
    """A log part's points in time order: ``scan`` and ``step`` (N,) indices into the
    log's scans and beams, ``r`` (N,) m, ``time_ns`` (N,), ``P_laser`` (N,3) in the laser
    frame at their own time, ``P_world`` (N,3) placed with the trajectory (NaN without a
    pose there; ``P_laser`` without a trajectory), ``inside`` (N,) whether it had one."""

    scan: np.ndarray
    step: np.ndarray
    r: np.ndarray
    time_ns: np.ndarray
    P_laser: np.ndarray
    P_world: np.ndarray
    inside: np.ndarray


def place(
    log: DriveLog, scan_ns: np.ndarray, keep: np.ndarray, trajectory: Any,
    laser_to_vehicle: Rigid,
) -> Placed:  # fmt: skip
    """The valid points of the scans ``keep`` (S,) bool of ``log``, whose point 0 was
    measured at ``scan_ns`` (S,), each at its own time (:class:`Placed`)."""
    ranges = np.where(keep[:, None], log.ranges, np.nan)
    scan_idx, step = np.nonzero(np.isfinite(ranges))
    r = ranges[scan_idx, step].astype(np.float64)
    beams = log.angle_min + log.angle_increment * np.arange(log.ranges.shape[1])
    P_laser = np.zeros((r.size, 3))  # filled in place: no (N,) temporaries
    np.multiply(r, np.cos(beams)[step], out=P_laser[:, 0])
    np.multiply(r, np.sin(beams)[step], out=P_laser[:, 1])
    time_ns = sync.point_times_ns(scan_ns[scan_idx], log.time_increment, step)
    if time_ns.size and np.any(np.diff(time_ns) < 0):  # scans out of order, or overlapping
        order = np.argsort(time_ns, kind="stable")
        scan_idx, step, P_laser, time_ns, r = (
            scan_idx[order], step[order], P_laser[order], time_ns[order], r[order]
        )  # fmt: skip
    inside = np.ones(time_ns.size, dtype=bool)
    P_world = P_laser
    if trajectory is not None:
        inside = trajectory.covers(time_ns)
        if inside.all():
            P_world = trajectory.transform(time_ns, laser_to_vehicle.apply(P_laser))
        else:
            P_world = np.full_like(P_laser, np.nan)  # no pose: not placed, not coloured
            P_world[inside] = trajectory.transform(
                time_ns[inside], laser_to_vehicle.apply(P_laser[inside])
            )
    return Placed(scan_idx, step, r, time_ns, P_laser, P_world, inside)


def colour_chunk(job: Job, chunk: Chunk, whole: DriveLog | None = None) -> ChunkResult:
    """Read, place and colour one chunk (runs in a worker process or on a Dask worker);
    ``whole``: the log already read (then only its part is used)."""
    with ThreadPoolExecutor(max_workers=max(1, job.threads)) as pool:
        return start_chunk(job, chunk, whole, pool).result()


def start_chunk(job: Job, chunk: Chunk, whole: DriveLog | None, pool: Executor) -> ChunkColouring:
    """Read and place one chunk and queue its frames on ``pool`` (:func:`colour_chunk`
    without waiting: :meth:`ChunkColouring.result` does)."""
    t0 = time.perf_counter()
    margin = _margin_ns(job)
    # the same scans and frames whether read here or cut from the whole log: those
    # stamped within the margin (plus half a second), read by receipt time a second wider
    lo, hi = chunk.start_ns - margin - 500_000_000, chunk.end_ns + margin + 500_000_000
    if whole is None:
        whole = read_log(
            list(job.files), laser=job.laser, camera=job.camera or None,
            start_ns=lo - 10**9, end_ns=hi + 10**9,
        )  # fmt: skip
    log = whole.between(lo, hi)
    t_read = time.perf_counter()
    scan_ns = _remap(job.scan_old, job.scan_new, log.scan_ns)
    frame_ns = _remap(job.frame_old, job.frame_new, log.frame_ns) - job.time_offset_ns
    core_scan = (scan_ns >= chunk.start_ns) & (scan_ns < chunk.end_ns)
    # the margins' scans only fill best's depth buffers
    keep_scan = (
        (scan_ns >= chunk.start_ns - margin) & (scan_ns < chunk.end_ns + margin)
        if job.options.view == "best"
        else core_scan
    )
    l2v = job.laser_to_vehicle
    pts = place(log, scan_ns, keep_scan, job.trajectory, l2v)
    pose_at = job.trajectory.pose_at if job.trajectory is not None else None
    # the chunk's own points are coloured; those of its margins only hide others
    core = core_scan[pts.scan] & (pts.inside if job.frame_world else True)
    size = views.point_size(pts.r, log.angle_increment, job.travel_m)
    usable = (
        job.trajectory.covers(frame_ns) if pose_at is not None else np.ones(frame_ns.size, bool)
    )
    compensate = pose_at is not None and job.options.motion_compensation
    colouring = views.start_colouring(
        pts.P_world if compensate else pts.P_laser, pts.time_ns, size, frame_ns, log.jpegs,
        job.cam, l2v, pose_at, job.options,
        pool=pool, want_uv=job.want_uv, frame_ok=usable, need=core,
    )  # fmt: skip
    seconds = {"read": t_read - t0, "place, queue": time.perf_counter() - t_read}
    return ChunkColouring(job, chunk, log, scan_ns, core_scan, core, pts, colouring, seconds)


@dataclass
class ChunkColouring:
    """A chunk read and placed, its frames decoding (:func:`start_chunk`)."""

    job: Job
    chunk: Chunk
    log: DriveLog
    scan_ns: np.ndarray
    core_scan: np.ndarray
    core: np.ndarray
    pts: Placed
    colouring: views.Colouring
    seconds: dict[str, float]

    def result(self) -> ChunkResult:
        """Wait for the chunk's frames; its points (:class:`ChunkResult`)."""
        t0 = time.perf_counter()
        job, chunk, log, pts = self.job, self.chunk, self.log, self.pts
        core: slice | np.ndarray = slice(None) if self.core.all() else self.core  # no copies
        col = self.colouring.result()
        t_colour = time.perf_counter()
        l2v = job.laser_to_vehicle
        xyz = pts.P_world if job.frame_world else pts.P_laser
        # the laser's position at each core scan's point 0 (the track; scans with a pose)
        core_scans = np.flatnonzero(self.core_scan)
        origin = np.zeros((core_scans.size, 3))
        if job.frame_world and core_scans.size:
            ok = job.trajectory.covers(self.scan_ns[core_scans])
            Rs, ts = job.trajectory.pose_at(self.scan_ns[core_scans][ok])
            origin = np.einsum("nij,j->ni", Rs, l2v.translation) + ts
        # scan indices global to the session: the chunk's scans come after the earlier ones
        first_scan = int(np.searchsorted(job.scan_new, chunk.start_ns)) if job.scan_new.size else 0
        local = np.cumsum(self.core_scan) - 1
        scan_idx, step = pts.scan[core], pts.step[core]
        frame = col.frame[core]
        return ChunkResult(
            index=chunk.index,
            xyz=xyz[core],
            rgb=col.rgb[core],
            coloured=col.coloured[core],
            hidden=col.hidden[core],
            time_ns=pts.time_ns[core],
            scan=(first_scan + local[scan_idx]).astype(np.uint32),
            step=step.astype(np.uint32),
            intensity=log.intensities[scan_idx, step].astype(np.float32),
            dt_s=col.dt_s[core],
            theta=col.theta[core],
            scan_origin=origin,
            frame_stamp_ns=(
                np.where(frame >= 0, log.frame_ns[np.maximum(frame, 0)], -1)
                if job.want_uv
                else None
            ),
            uv=col.uv[core] if col.uv is not None else None,
            frames_used=col.frames_used,
            frames_failed=col.frames_failed,
            outside=int(np.count_nonzero(~pts.inside & self.core_scan[pts.scan])),
            used_stamps=np.unique(log.frame_ns[frame[frame >= 0]]),
            seconds={
                **self.seconds,
                "waiting for frames": t_colour - t0,
                "finish": time.perf_counter() - t_colour,
            },
        )


def plan(scan_ns: np.ndarray, chunk_s: float) -> list[Chunk]:
    """Chunks of ``chunk_s`` seconds covering every scan time (sorted ``scan_ns``)."""
    if scan_ns.size == 0:
        return []
    start, end = int(scan_ns[0]), int(scan_ns[-1]) + 1
    step = max(1, round(chunk_s * 1e9))
    edges = [*range(start, end, step), end]
    return [Chunk(i, a, b) for i, (a, b) in enumerate(itertools.pairwise(edges))]


def _run_chunks(
    job: Job,
    chunks: list[Chunk],
    workers: int,
    dask: str | None,
    progress: bool,
    emit: Callable[[ChunkResult], None],
    whole: DriveLog | None = None,
) -> None:
    """Every chunk's result to ``emit``, in chunk order, however they run (``whole``:
    the log read already with its images, for running here; else each chunk reads its
    part). Here, the next chunk is read and placed and the last one emitted (written)
    while a chunk's frames decode."""
    from tqdm import tqdm

    bar = tqdm(total=len(chunks), unit="chunk", disable=not progress, file=sys.stderr)
    waiting: dict[int, ChunkResult] = {}  # done out of order
    expected = deque(c.index for c in chunks)

    def done(result: ChunkResult) -> None:
        waiting[result.index] = result
        while expected and expected[0] in waiting:
            emit(waiting.pop(expected.popleft()))
            bar.update()

    try:
        if dask:
            from dask.distributed import Client, as_completed

            with Client(dask) as client:
                job_f = client.scatter(job, broadcast=True)
                futures = [client.submit(colour_chunk, job_f, c, pure=False) for c in chunks]
                for fut in as_completed(futures):
                    done(fut.result())
        elif workers > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            from concurrent.futures import as_completed as completed

            ctx = multiprocessing.get_context("spawn")  # numba and threads: no fork
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                pending = [pool.submit(colour_chunk, job, c) for c in chunks]
                for fut in completed(pending):
                    done(fut.result())
        else:  # one process: the log read once (whole), or each chunk its part
            threads = ThreadPoolExecutor(max_workers=max(1, job.threads))
            try:
                started: ChunkColouring | None = None
                for c in chunks:
                    following = start_chunk(job, c, whole, threads)
                    if started is not None:
                        done(started.result())
                    started = following
                if started is not None:
                    done(started.result())
            finally:  # on an error (a full disk, Ctrl-C) the queued frames are dropped
                threads.shutdown(cancel_futures=True)
    finally:
        bar.close()


@dataclass
class Report:
    """What `acq colorize` did, for the text or JSON report."""

    output: str
    points: int = 0
    coloured: int = 0
    hidden: int = 0
    frames: int = 0
    frames_used: int = 0
    frames_failed: int = 0
    scans: int = 0
    duration_s: float = 0.0
    frame: str = "world"
    view: str = "nearest"
    trajectory: str = ""
    retiming: dict[str, Any] = field(default_factory=dict)
    time_offset: dict[str, Any] = field(default_factory=dict)
    chunks: int = 0
    bytes: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        share = self.coloured / self.points if self.points else 0.0
        rt = self.retiming
        out = [
            f"{self.points:,} points from {self.scans:,} scans ({self.duration_s:.1f} s), "
            f"{100 * share:.1f} % coloured from {self.frames_used:,} of {self.frames:,} frames "
            f"(--view {self.view}); {self.hidden:,} hidden from every candidate frame",
            f"frame: {self.frame}; trajectory: {self.trajectory or 'none'}",
        ]
        if rt:
            out.append(
                f"re-timed offline: scans moved {rt.get('scan_shift_rms_ms', 0):.3f} ms RMS, "
                f"frames {rt.get('frame_residual_rms_ms', 0):.2f} ms RMS receipt jitter removed"
            )
        total = sum(self.seconds.values())
        if total:
            parts = ", ".join(f"{k} {v:.1f} s" for k, v in self.seconds.items())
            speed = self.duration_s / self.seconds.get("total", total) if total else 0.0
            out.append(f"time: {parts} ({speed:.1f}x real time)")
        out += [f"note: {n}" for n in self.notes]
        out.append(f"wrote {self.output}")
        return out


def _retime(log: DriveLog, report: Report) -> tuple[np.ndarray, np.ndarray]:
    """(scan_new, frame_new) for ``log``'s recorded stamps; notes in ``report``."""
    from acq.drivers.scanner import SCANNERS

    scan_new, frame_new = log.scan_ns.copy(), log.frame_ns.copy()
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
    if log.n_frames:
        rf = retime.retime_frames(log.frame_ns)
        frame_new = rf.frame_ns
        report.retiming.update(
            frame_period_s=rf.period_s,
            frame_residual_rms_ms=rf.residual_rms_ms,
            frame_shift_max_ms=rf.shift_max_ms,
        )
        if rf.note:
            report.notes.append(f"frames not re-timed: {rf.note}")
    return scan_new, frame_new


def _trajectory(
    files: Sequence[Path], given: Path | Trajectory | None, log: DriveLog, report: Report
) -> Any:
    """The trajectory to place points with, or None (see the module docstring, step 3):
    ``given`` as it is, read from its file, or made from the log."""
    if isinstance(given, Trajectory):
        report.trajectory = f"given ({len(given)} poses)"
        return given
    path = given
    if path is not None:
        clock = log.clock
        traj = motion.from_csv(path, utc_to_host_ns=lambda u: host_ns_from_utc(u, clock))
        report.trajectory = f"{path} ({len(traj.t_ns)} poses)"
        return traj
    vehicle = log.vehicle
    if vehicle is None:
        vehicle = read_vehicle(list(files))
    report.notes += vehicle.notes
    odo = vehicle.odometry
    if len(odo) < 2:
        return None
    fixes = vehicle.fixes
    usable = np.isfinite(fixes.lat) & (fixes.quality > 0) if len(fixes) else np.zeros(0, bool)
    if usable.sum() >= 5:
        track = motion.gnss_track(
            fixes.t_ns, fixes.lat, fixes.lon, fixes.alt, hdop=fixes.hdop, quality=fixes.quality
        )
        fusion = motion.fuse(odo.t_ns, odo.speed, odo.yaw_rate, track, on_gap="flag")
        report.trajectory = (
            f"CAN odometry ({len(odo)} samples) fused with {int(usable.sum())} GNSS fixes "
            f"(residual {fusion.residual_rms_m:.2f} m RMS)"
        )
        return fusion.trajectory
    traj = motion.from_odometry(odo.t_ns, odo.speed, odo.yaw_rate, on_gap="flag")
    report.trajectory = f"CAN odometry ({len(odo)} samples, dead reckoning)"
    return traj


def _warm_kernels(model: CameraModel) -> None:
    """Load the compiled kernels colorize calls, each on a tiny input of the real types
    (numba's first call of a cached kernel costs a tenth of a second or more, part of it
    without the GIL): run on a thread while the log is read."""
    from acq.camera import projection

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
    camera: str | None = None,
    frame: str | None = None,
    options: views.Options | None = None,
    trajectory: Path | Trajectory | None = None,
    retime_offline: bool = True,
    time_offset_s: float | None = None,
    jpegs: bool = False,
    threads: int = 1,
) -> tuple[Job, DriveLog]:
    """The :class:`Job` for ``logs`` (steps 1-3 of the module docstring) and the log's
    light part (with the images when ``jpegs``); notes go into ``report``. ``trajectory``:
    a file (``--trajectory``) or the poses themselves; None: from the log."""
    options = options or views.Options()
    files = _session_files(logs)
    first = calib.cameras.get(camera) if camera else next(iter(calib.cameras.values()), None)
    if first is not None:
        threading.Thread(target=_warm_kernels, args=(first.model,), daemon=True).start()
    index = read_log(files, camera=camera, jpegs=jpegs, vehicle=trajectory is None)
    name, cam = camera_calib(index, calib, camera)
    report.notes += index.notes
    scan_new, frame_new = (
        _retime(index, report) if retime_offline else (index.scan_ns, index.frame_ns)
    )
    traj = _trajectory(files, trajectory, index, report)
    world = frame == "world" if frame is not None else traj is not None
    if world and traj is None:
        raise InputValueError("--frame world needs a trajectory (CAN odometry in the log or "
                         "--trajectory CSV); use --frame laser")  # fmt: skip
    if traj is None:
        report.notes.append(
            "no trajectory: points in the laser frame at their own time, coloured without "
            "motion compensation (right only while the rig stands still)"
        )
        options = replace(options, motion_compensation=False)
    report.frame = "world" if world else "laser"
    s_order = np.argsort(index.scan_ns)
    f_order = np.argsort(index.frame_ns)
    period = float(np.median(np.diff(np.sort(scan_new)))) * 1e-9 if scan_new.size > 1 else 0.025
    speed = _median_speed(traj, scan_new)
    offset = cam.time_offset_s if time_offset_s is None else float(time_offset_s)
    job = Job(
        files=tuple(str(f) for f in files),
        laser=index.laser,
        camera=name if index.camera else "",
        cam=cam,
        laser_to_vehicle=(
            calib.laser_to_vehicle if calib.laser_to_vehicle is not None else Rigid.identity()
        ),
        scan_old=index.scan_ns[s_order],
        scan_new=scan_new[s_order],
        frame_old=index.frame_ns[f_order],
        frame_new=frame_new[f_order],
        time_offset_ns=round(offset * 1e9),
        trajectory=traj,
        options=options,
        frame_world=world,
        travel_m=speed * period,
        threads=threads,
    )
    return job, index


def estimate_offset(
    job: Job,
    *,
    whole: DriveLog | None = None,
    start_s: float | None = None,
    seconds: float = 60.0,
    search_s: float = 0.06,
    max_frames: int = 1500,
    threads: int = 1,
) -> OffsetEstimate:
    """The camera's time offset (:mod:`acq.calib.time_offset`) from ``seconds`` of the job's
    log from ``start_s`` after its first scan (default: the middle ``seconds``), with
    CALIB's offset as the prior; ``whole``: the log already read, with its images."""
    if job.trajectory is None:
        return OffsetEstimate.not_found(
            "needs the rig's motion: CAN odometry in the log or --trajectory"
        )
    if not job.camera:
        return OffsetEstimate.not_found("the log has no camera frames")
    first, last = int(job.scan_new[0]), int(job.scan_new[-1])
    span = round(seconds * 1e9)
    lo = first + (max(0, (last - first - span) // 2) if start_s is None else round(start_s * 1e9))
    hi = lo + span
    if whole is None:
        whole = read_log(
            list(job.files), laser=job.laser, camera=job.camera,
            start_ns=lo - 2 * 10**9, end_ns=hi + 2 * 10**9,
        )  # fmt: skip
    scan_ns = _remap(job.scan_old, job.scan_new, whole.scan_ns)
    frame_ns = _remap(job.frame_old, job.frame_new, whole.frame_ns)
    keep = (scan_ns >= lo) & (scan_ns < hi)
    pts = place(whole, scan_ns, keep, job.trajectory, job.laser_to_vehicle)
    strength = whole.intensities[pts.scan, pts.step] if whole.intensities.size else None
    if strength is None or not np.any(strength > 0):
        return OffsetEstimate.not_found(
            "no laser return strengths in the log (record them: SCIP ME, CoLa RSSI1)"
        )
    in_span = (frame_ns - job.time_offset_ns >= lo) & (frame_ns - job.time_offset_ns < hi)
    sel = np.flatnonzero(in_span)
    return estimate_time_offset(
        pts.P_world, pts.time_ns, strength.astype(np.float64), frame_ns[sel],
        [whole.jpegs[int(i)] for i in sel], job.cam, job.laser_to_vehicle,
        job.trajectory.pose_at, job.trajectory.covers, prior_s=job.cam.time_offset_s,
        search_s=search_s, max_frames=max_frames, threads=threads,
    )  # fmt: skip


def run(
    logs: Sequence[Path],
    calib: Calibration,
    output: Path,
    *,
    camera: str | None = None,
    frame: str | None = None,
    options: views.Options | None = None,
    trajectory: Path | Trajectory | None = None,
    crs: str | None = None,
    retime_offline: bool = True,
    time_offset_s: float | str | None = None,
    workers: int = 1,
    dask: str | None = None,
    chunk_s: float = 30.0,
    preview: Path | None = None,
    progress: bool = False,
    results: list[ChunkResult] | None = None,
    want_uv: bool = False,
) -> Report:
    """The whole command (module docstring); raises InputError (LogError, CalibFileError,
    InputValueError...) with a one-line message for bad input, OSError naming ``output``
    when it cannot be written. ``results``: a list to receive the chunks' results
    (with each point's frame and pixel when ``want_uv``), for accuracy checks.
    ``time_offset_s``: seconds, None for CALIB's, or "auto" (:func:`estimate_offset`).
    ``trajectory``: as :func:`prepare` takes it."""
    t_start = time.perf_counter()
    options = options or views.Options()
    report = Report(output=str(output), view=options.view)
    # here, a log up to READ_ONCE_BYTES is read once with its images; a longer one's
    # chunks read their own part (its images never all in memory), as workers do
    size = sum(f.stat().st_size for f in _session_files(logs) if f.is_file())
    local = workers <= 1 and not dask
    once = local and size <= READ_ONCE_BYTES
    auto = isinstance(time_offset_s, str)
    if auto and time_offset_s != "auto":
        raise InputValueError(f"--time-offset {time_offset_s}: expected seconds or 'auto'")
    job, index = prepare(
        logs, calib, report, camera=camera, frame=frame, options=options,
        trajectory=trajectory, retime_offline=retime_offline,
        time_offset_s=None if isinstance(time_offset_s, str) else time_offset_s, jpegs=once,
        threads=(os.cpu_count() or 1) if local else 1,
    )  # fmt: skip
    job = replace(job, want_uv=want_uv)
    t_offset = time.perf_counter()
    if auto:
        est = estimate_offset(job, whole=index if once else None, threads=job.threads)
        report.time_offset.update(
            estimated_s=est.offset_s, std_s=est.std_s, points=est.points, frames=est.frames,
            contrast=round(est.contrast, 3), found=est.found,
        )  # fmt: skip
        if est.found:
            job = replace(job, time_offset_ns=round(est.offset_s * 1e9))
        else:
            report.notes.append(f"--time-offset auto: {est.note}; CALIB's time_offset_s used")
    world = job.frame_world
    report.time_offset["used_s"] = job.time_offset_ns * 1e-9
    scan_new = np.sort(job.scan_new)
    chunks = plan(scan_new, chunk_s)
    t_plan = time.perf_counter()
    out = _Writer(output, crs, index.clock, report)
    # a long log's cloud is not held: counts, and every k-th scan for the preview
    every = max(1, math.ceil(index.ranges.size / PREVIEW_POINTS))
    tally = _Tally(every if preview is not None else 0)

    def emit(r: ChunkResult) -> None:
        out.write(r)
        tally.add(r)
        if results is not None:
            results.append(r)

    try:
        _run_chunks(job, chunks, workers, dask, progress, emit, index if once else None)
        t_colour = time.perf_counter()
        size = out.close()
    except BaseException:
        out.stream.abort()
        raise
    report.points, report.coloured, report.hidden = tally.points, tally.coloured, tally.hidden
    report.frames, report.scans = index.n_frames, index.n_scans
    report.frames_used = _frames_used(tally.used)
    report.frames_failed = tally.failed
    report.duration_s = float(np.ptp(scan_new)) * 1e-9 if scan_new.size else 0.0
    report.chunks = len(chunks)
    report.bytes = size
    if tally.outside:
        report.notes.append(
            f"{tally.outside:,} points measured outside the trajectory's span: "
            + ("left out (no pose)" if world else "kept, not coloured")
        )
    if preview is not None:
        pc = cloud_of(tally.preview, index)
        preview_png(preview, pc, title=f"acq colorize {output.name}")
        if every > 1:
            report.notes.append(f"the preview shows one scan in {every}")
    t_end = time.perf_counter()
    parts: dict[str, float] = {"index": t_offset - t_start}
    if auto:
        parts["time offset"] = t_plan - t_offset
    parts["chunks and writing"] = t_colour - t_plan
    # the chunks' frames decode on threads meanwhile: "waiting" is what they add
    for key in ("read", "place, queue", "waiting for frames", "finish"):
        parts[f"  {key} (summed over chunks)"] = tally.seconds.get(key, 0.0)
    parts["  writing"] = out.seconds
    parts["closing, preview"] = t_end - t_colour
    parts["total"] = t_end - t_start
    report.seconds = parts
    return report


@dataclass
class _Tally:
    """What the report and the preview keep of the chunks written: counts, the frames
    used, and every ``every``-th scan's points for the preview (0: none)."""

    every: int
    points: int = 0
    coloured: int = 0
    hidden: int = 0
    failed: int = 0
    outside: int = 0
    used: list[np.ndarray] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    preview: list[ChunkResult] = field(default_factory=list)

    def add(self, r: ChunkResult) -> None:
        self.points += r.time_ns.size
        self.coloured += int(np.count_nonzero(r.coloured))
        self.hidden += int(np.count_nonzero(r.hidden))
        self.failed += r.frames_failed
        self.outside += r.outside
        if r.used_stamps is not None:
            self.used.append(r.used_stamps)
        for key, v in r.seconds.items():
            self.seconds[key] = self.seconds.get(key, 0.0) + v
        if self.every == 1:
            self.preview.append(r)
        elif self.every > 1:
            k = r.scan % self.every == 0
            thin = {name: getattr(r, name)[k] for name in _PER_POINT}
            self.preview.append(replace(r, **thin, uv=None, frame_stamp_ns=None))


def _median_speed(traj: Any, scan_ns: np.ndarray) -> float:
    """The rig's median speed over the log (m/s), 0 without a trajectory."""
    if traj is None or scan_ns.size < 2:
        return 0.0
    t = np.sort(scan_ns)[:: max(1, scan_ns.size // 200)]
    t = t[traj.covers(t)]
    if t.size < 2:
        return 0.0
    _, pos = traj.pose_at(t)
    v = np.linalg.norm(np.diff(pos, axis=0), axis=1) / (np.diff(t) * 1e-9)
    return float(np.median(v)) if v.size else 0.0


def _frames_used(used: list[np.ndarray]) -> int:
    """Frames the cloud's points were coloured from, given each chunk's (a frame two
    chunks share, once)."""
    return int(np.unique(np.concatenate(used)).size) if used else 0


def cloud_of(results: list[ChunkResult], index: DriveLog) -> Cloud:
    """The points of chunks' ``results`` (of the log ``index``) as one :class:`Cloud`
    (its ``view_axis`` is the default rig's camera side, +y)."""

    def cat(name: str, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        parts = [getattr(r, name) for r in results]
        return np.concatenate(parts) if parts else np.zeros(shape, dtype)

    return Cloud(
        xyz=cat("xyz", (0, 3), np.float64),
        rgb=cat("rgb", (0, 3), np.uint8),
        coloured=cat("coloured", (0,), bool),
        time_ns=cat("time_ns", (0,), np.int64),
        scan=cat("scan", (0,), np.uint32),
        step=cat("step", (0,), np.uint32),
        intensity=cat("intensity", (0,), np.float32),
        dt_s=cat("dt_s", (0,), np.float32),
        scan_origin=cat("scan_origin", (0, 3), np.float64),
        view_axis=np.array([0.0, 1.0, 0.0]),
        clock=index.clock,
        frames=index.n_frames,
        frames_used=_frames_used([r.used_stamps for r in results if r.used_stamps is not None]),
        frames_failed=sum(r.frames_failed for r in results),
    )


@contextmanager
def _naming(output: Path) -> Iterator[None]:
    """An OSError writing ``output`` (really its temporary file) names ``output``."""
    try:
        yield
    except OSError as e:
        raise OSError(e.errno, e.strerror or str(e), str(output)) from e


class _Writer:
    """The output file, written chunk by chunk in chunk order: PLY or LAS by
    ``output``'s extension; ``seconds`` spent writing. Its OSErrors name ``output``."""

    def __init__(self, output: Path, crs: str | None, clock: np.ndarray, report: Report) -> None:
        self.output = output
        suffix = output.suffix.lower()
        comments = [f"frame {report.frame}", f"view {report.view}", *(
            [f"crs {crs}"] if crs else [])]  # fmt: skip
        self.stream: PlyStream | LasStream
        if suffix == ".ply":
            with _naming(output):
                self.stream = PlyStream(output, comments)
            if crs:
                report.notes.append("PLY has no CRS field: --crs written as a comment")
        elif suffix in (".las", ".laz"):
            with _naming(output):
                self.stream = LasStream(output, crs=crs, comments=comments)
        else:
            raise InputValueError(f"{output}: unknown format; expected {', '.join(FORMATS)}")
        self.clock = clock
        self.seconds = 0.0

    def write(self, r: ChunkResult) -> None:
        t0 = time.perf_counter()
        utc = utc_seconds(r.time_ns, self.clock)
        with _naming(self.output):
            self.stream.write(r.xyz, r.rgb, utc, r.intensity, r.scan, r.coloured)
        self.seconds += time.perf_counter() - t0

    def close(self) -> int:
        """Close and rename into place; the file's size in bytes."""
        with _naming(self.output):
            return self.stream.close()


def _session_files(logs: Sequence[Path]) -> list[Path]:
    """The MCAP files of ``logs`` (a folder stands for its *.mcap files, sorted)."""
    out: list[Path] = []
    for p in logs:
        if p.is_dir():
            found = sorted(p.glob("*.mcap"))
            if not found:
                raise InputValueError(f"{p}: no .mcap files in this folder")
            out += found
        else:
            out.append(p)
    return out
