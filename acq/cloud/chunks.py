"""A drive cut into chunks of scans (:func:`plan`), each read, placed and coloured on its
own (:func:`colour_chunk`, step 4 of :mod:`acq.cloud.colorize`): the points of its scans
placed at their own time (:func:`place`), coloured by :func:`acq.cloud.views.start_colouring`,
gathered into a :class:`ChunkResult`; chunks' results as one :class:`acq.cloud.Cloud`.

Times host monotonic ns unless ``_s``; metres; colours RGB.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from concurrent.futures import (
    ALL_COMPLETED,
    FIRST_COMPLETED,
    Executor,
    Future,
    ThreadPoolExecutor,
    wait,
)
from dataclasses import dataclass, field, replace
from typing import Any, ParamSpec, Protocol, TypeVar

import numpy as np

from acq.camera.jpeg import SharedDecodes
from acq.cloud import balance, scan_colouring, views
from acq.cloud.job import Job, remap
from acq.cloud.points import Cloud
from acq.cloud.scan_colouring import Placed
from acq.geometry.transforms import Rigid
from acq.log.drive_log import DriveLog, read_log
from acq.log.reader import quiet

__all__ = [
    "NO_CAMERA",
    "PER_POINT",
    "Chunk",
    "ChunkColouring",
    "ChunkResult",
    "CountedPool",
    "Placed",
    "ProgressSink",
    "cloud_of",
    "colour_chunk",
    "frames_used",
    "holds",
    "laser_positions",
    "place",
    "plan",
    "start_chunk",
]

PER_POINT = ("xyz", "rgb", "coloured", "hidden", "time_ns", "scan", "step", "intensity",
              "dt_s", "theta", "camera", "frame")  # fmt: skip
NO_CAMERA = 255  # ChunkResult.camera of a point no camera coloured


@dataclass(frozen=True)
class Chunk:
    """Scans with (new) stamps in [start_ns, end_ns) of ``job``; ``index`` in the plan."""

    index: int
    start_ns: int
    end_ns: int


@dataclass
class ChunkResult:
    """One chunk's points (see :class:`acq.cloud.Cloud`) and its counters. ``camera``
    (N,) uint8: the index in the job's cameras of the camera a point was coloured from
    (``NO_CAMERA`` none); ``frame`` (N,) int32: the index of its frame among that
    camera's frames in the session, in time order (-1 none)."""

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
    camera: np.ndarray
    frame: np.ndarray
    scan_origin: np.ndarray
    frame_stamp_ns: np.ndarray | None = None  # the recorded stamp of the frame used, -1
    uv: np.ndarray | None = None  # (N,2) float32 px in that frame, NaN
    frames_used: int = 0  # decoded and used for this chunk (its margins included)
    frames_failed: int = 0
    outside: int = 0  # points left out: outside the trajectory's span
    # (camera index, recorded stamp) of the frames its points used, (U,2) int64
    used_stamps: np.ndarray | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    # frames of another size than the camera model's, not used, by camera: stamp -> (w, h)
    odd_size: dict[str, dict[int, tuple[int, int]]] = field(default_factory=dict)
    # frames that do not decode, not used, by camera: their recorded stamps
    undecodable: dict[str, set[int]] = field(default_factory=dict)
    gains: balance.Gains | None = None  # the colour balance applied (None: off)
    # with want_uv, per camera: its own (rgb, balanced rgb, coloured) of every point
    samples: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
    # per camera, the session index of each of the chunk's frames (``gains``' rows)
    session_frames: list[np.ndarray] = field(default_factory=list)
    # with want_crops, per camera: the decoded frames' parts around their points, by session frame
    crops: list[dict[int, views.Crop]] = field(default_factory=list)


def _margin_ns(job: Job) -> int:
    period = 0.04  # a camera's frame period, s (the window is counted in frames)
    o = job.options
    return round((o.max_dt_s + o.window * period + o.context_s + 0.2) * 1e9)


def place(
    log: DriveLog, scan_ns: np.ndarray, keep: np.ndarray, trajectory: Any,
    laser_to_vehicle: Rigid,
) -> Placed:  # fmt: skip
    """The valid points of the scans ``keep`` (S,) bool of ``log``, whose point 0 was
    measured at ``scan_ns`` (S,), each at its own time (:func:`scan_colouring.place`)."""
    beams = scan_colouring.Beams(log.angle_min, log.angle_increment, log.time_increment)
    return scan_colouring.place(log.ranges, scan_ns, beams, keep, trajectory, laser_to_vehicle)


_P = ParamSpec("_P")
_T = TypeVar("_T")


class CountedPool(Executor):
    """``pool``, keeping the tasks submitted through it (a chunk's frames)."""

    def __init__(self, pool: Executor) -> None:
        self.pool = pool
        self.tasks: list[Future[Any]] = []

    def submit(self, fn: Callable[_P, _T], /, *args: _P.args, **kwargs: _P.kwargs) -> Future[_T]:
        task = self.pool.submit(fn, *args, **kwargs)
        self.tasks.append(task)
        return task


class ProgressSink(Protocol):
    """Where a chunk run elsewhere reports its frames: a queue shared with the process
    that shows the bar (a multiprocessing manager's, or Dask's ``distributed.Queue``)."""

    def put(self, item: tuple[int, int, int]) -> Any: ...


def _report_frames(index: int, tasks: Sequence[Future[Any]], sink: ProgressSink) -> None:
    """Wait for ``tasks``, putting (chunk ``index``, frames done, frames in all) into
    ``sink``: when the first ends, then at most every REPORT_S, and when the last ends.
    On this thread: a Dask worker takes a queue's puts from its task's thread only."""
    total, pending, reported = len(tasks), set(tasks), 0
    while pending:
        how = FIRST_COMPLETED if reported == 0 else ALL_COMPLETED
        pending = wait(pending, timeout=REPORT_S, return_when=how).not_done
        done = total - len(pending)
        if done > reported:
            sink.put((index, done, total))
            reported = done


REPORT_S = 0.25  # how often a chunk run elsewhere reports its frames


def colour_chunk(
    job: Job, chunk: Chunk, whole: DriveLog | None = None, sink: ProgressSink | None = None
) -> ChunkResult:
    """Read, place and colour one chunk (runs in a worker process or on a Dask worker);
    ``whole``: the log already read (then only its part is used); ``sink``: where to
    report its frames as they are done. The damage its part of the log may have is not
    logged again: reading the whole log first did."""
    with quiet(), ThreadPoolExecutor(max_workers=max(1, job.threads)) as threads:
        pool = CountedPool(threads)
        started = start_chunk(job, chunk, whole, pool)
        if sink is not None:
            _report_frames(chunk.index, pool.tasks, sink)
        return started.result()


def holds(whole: DriveLog, job: Job, chunk: Chunk) -> bool:
    """Whether ``whole`` (a log read with images, maybe for a first span only) has
    every frame's bytes :func:`start_chunk` cuts for ``chunk``."""
    if whole.jpegs_until_ns is None:
        return True
    # its frames are stamped before the end + margin; received up to a second later
    return chunk.end_ns + _margin_ns(job) + 2 * 10**9 <= whole.jpegs_until_ns


def start_chunk(
    job: Job, chunk: Chunk, whole: DriveLog | None, pool: Executor,
    decodes: SharedDecodes | None = None,
) -> ChunkColouring:  # fmt: skip
    """Read and place one chunk and queue its frames, every camera's, on ``pool``
    (:func:`colour_chunk` without waiting: :meth:`ChunkColouring.result` does);
    ``decodes``: the JPEGs go there instead, shared with the other chunks queued (a
    frame of two chunks' margins decoded once)."""
    t0 = time.perf_counter()
    margin = _margin_ns(job)
    # the same scans and frames whether read here or cut from the whole log: those
    # stamped within the margin (plus half a second), read by receipt time a second wider
    lo, hi = chunk.start_ns - margin - 500_000_000, chunk.end_ns + margin + 500_000_000
    if whole is None:
        whole = read_log(
            list(job.files), laser=job.laser, cameras=[c.name for c in job.cameras] or None,
            start_ns=lo - 10**9, end_ns=hi + 10**9,
        )  # fmt: skip
    log = whole.between(lo, hi)
    t_read = time.perf_counter()
    scan_ns = remap(job.scan_old, job.scan_new, log.scan_ns)
    core_scan = (scan_ns >= chunk.start_ns) & (scan_ns < chunk.end_ns)
    # the margins' scans only fill best's depth buffers
    keep_scan = (
        (scan_ns >= chunk.start_ns - margin) & (scan_ns < chunk.end_ns + margin)
        if job.options.view == "best"
        else core_scan
    )
    l2v = job.laser_to_vehicle
    pts = place(log, scan_ns, keep_scan, job.trajectory, l2v)
    if job.frame_world and job.options.motion_compensation:  # only P_world is used from here
        pts = replace(pts, P_laser=pts.P_laser[:0])
    # the chunk's own points are coloured; those of its margins only hide others
    core = core_scan[pts.scan] & (pts.inside if job.frame_world else True)
    size = views.point_size(pts.r, log.angle_increment, job.travel_m)
    cameras = [
        scan_colouring.camera_frames(
            cj.name,
            cj.cam,
            remap(cj.frame_old, cj.frame_new, log.cameras[cj.name].frame_ns),
            log.cameras[cj.name].jpegs,
            cj.time_offset_ns,
            job.trajectory,
        )
        for cj in job.cameras
    ]
    colourings = scan_colouring.start(
        pts, size, cameras, job.trajectory, l2v, job.options, pool=pool, need=core,
        want_uv=job.want_uv, want_crops=job.want_crops, decodes=decodes,
    )  # fmt: skip
    odd_size = {
        c.name: {int(log.cameras[c.name].frame_ns[k]): wh for k, wh in c.odd_size.items()}
        for c in cameras
        if c.odd_size
    }
    seconds = {"read": t_read - t0, "place, queue": time.perf_counter() - t_read}
    # the JPEGs are held by their queued tasks alone from here, each let go once decoded
    log = replace(log, cameras={n: replace(f, jpegs=[]) for n, f in log.cameras.items()})
    cameras = [replace(c, jpegs=()) for c in cameras]
    return ChunkColouring(
        job, chunk, log, scan_ns, core_scan, core, pts, cameras, colourings, seconds, odd_size
    )


@dataclass
class ChunkColouring:
    """A chunk read and placed, its frames decoding (:func:`start_chunk`): one
    colouring per camera of the job."""

    job: Job
    chunk: Chunk
    log: DriveLog
    scan_ns: np.ndarray
    core_scan: np.ndarray
    core: np.ndarray
    pts: Placed
    cameras: list[scan_colouring.CameraFrames]
    colourings: list[views.Colouring]
    seconds: dict[str, float]
    # frames of another size than the camera model's, by camera: recorded stamp -> (w, h)
    odd_size: dict[str, dict[int, tuple[int, int]]] = field(default_factory=dict)

    def result(self) -> ChunkResult:
        """Wait for the chunk's frames; its points (:class:`ChunkResult`): each
        camera's colours balanced (:mod:`acq.cloud.balance`), each point's camera
        chosen (:mod:`acq.cloud.multiview`)."""
        t0 = time.perf_counter()
        job, chunk, log, pts = self.job, self.chunk, self.log, self.pts
        core: slice | np.ndarray = slice(None) if self.core.all() else self.core  # no copies
        cols = [c.result() for c in self.colourings]
        t_colour = time.perf_counter()
        n = pts.time_ns.size
        frames = [log.cameras[cj.name] for cj in job.cameras]
        merged = scan_colouring.merge(cols, self.cameras, job.options, n, want_uv=job.want_uv)
        cam_idx, frame, coloured = merged.camera, merged.frame, merged.coloured
        # per camera, the session index of each of the chunk's frames (``gains``' rows)
        session_frames = [
            np.searchsorted(cj.frame_old, f.frame_ns)
            for cj, f in zip(job.cameras, frames, strict=True)
        ]
        # each point's frame: its recorded stamp (with want_uv) and its index among its
        # camera's frames in the session, looked up per frame
        stamp = np.full(n if job.want_uv else 0, -1, dtype=np.int64)
        session_frame = np.full(n, -1, dtype=np.int32)
        for c, f in enumerate(frames):
            sel = np.flatnonzero(cam_idx == c)
            if job.want_uv:
                stamp[sel] = f.frame_ns[frame[sel]]
            session_frame[sel] = session_frames[c][frame[sel]]
        t_choose = time.perf_counter()
        xyz = pts.P_world if job.frame_world else pts.P_laser
        # the laser's position at each core scan's point 0 (the track; scans with a pose)
        core_scans = np.flatnonzero(self.core_scan)
        origin = np.zeros((core_scans.size, 3))
        if job.frame_world and core_scans.size:
            ok = job.trajectory.covers(self.scan_ns[core_scans])
            origin = laser_positions(job, self.scan_ns[core_scans][ok])
        # scan indices global to the session: the chunk's scans come after the earlier ones
        first_scan = int(np.searchsorted(job.scan_new, chunk.start_ns)) if job.scan_new.size else 0
        local = np.cumsum(self.core_scan) - 1
        scan_idx, step = pts.scan[core], pts.step[core]
        used_pairs = np.concatenate(
            [
                np.stack([np.full(u.size, c), f.frame_ns[u]], axis=1)
                for c, f in enumerate(frames)
                for u in [np.flatnonzero(np.bincount(frame[cam_idx == c], minlength=1))]
            ]
            or [np.zeros((0, 2), np.int64)]
        )
        return ChunkResult(
            index=chunk.index,
            xyz=xyz[core],
            rgb=merged.rgb[core],
            coloured=coloured[core],
            hidden=merged.hidden[core],
            time_ns=pts.time_ns[core],
            scan=(first_scan + local[scan_idx]).astype(np.uint32),
            step=step.astype(np.uint32),
            intensity=log.intensities[scan_idx, step].astype(np.float32),
            dt_s=merged.dt_s[core],
            theta=merged.theta[core],
            camera=np.where(coloured, cam_idx, NO_CAMERA).astype(np.uint8)[core],
            frame=session_frame[core],
            scan_origin=origin,
            frame_stamp_ns=stamp[core] if job.want_uv else None,
            uv=merged.uv[core] if merged.uv is not None else None,
            frames_used=sum(col.frames_used for col in cols),
            frames_failed=sum(col.frames_failed for col in cols),
            outside=int(np.count_nonzero(~pts.inside & self.core_scan[pts.scan])),
            used_stamps=used_pairs,
            seconds={
                **self.seconds,
                "waiting for frames": t_colour - t0,
                "balance, choice": t_choose - t_colour,
                "finish": time.perf_counter() - t_choose,
            },
            odd_size=self.odd_size,
            undecodable={
                cj.name: set(frames[c].frame_ns[col.failed].tolist())
                for c, (cj, col) in enumerate(zip(job.cameras, cols, strict=True))
                if col.failed.size
            },
            gains=merged.gains,
            session_frames=session_frames,
            crops=[
                {int(rows[j]): crop for j, crop in col.crops.items()}
                for rows, col in zip(session_frames, cols, strict=True)
            ],
            samples=(
                {
                    cj.name: (cols[c].rgb[core], merged.rgbs[c][core], cols[c].coloured[core])
                    for c, cj in enumerate(job.cameras)
                }
                if job.want_uv
                else None
            ),
        )


def laser_positions(job: Job, scan_ns: np.ndarray) -> np.ndarray:
    """The laser's position (n,3) m in the world frame at the (new) stamps ``scan_ns``
    (n,), which the job's trajectory must cover."""
    Rs, ts = job.trajectory.pose_at(scan_ns)
    return np.asarray(np.einsum("nij,j->ni", Rs, job.laser_to_vehicle.translation) + ts)


def plan(scan_ns: np.ndarray, chunk_s: float) -> list[Chunk]:
    """Chunks of ``chunk_s`` seconds covering every scan time (sorted ``scan_ns``)."""
    if scan_ns.size == 0:
        return []
    start, end = int(scan_ns[0]), int(scan_ns[-1]) + 1
    step = max(1, round(chunk_s * 1e9))
    edges = [*range(start, end, step), end]
    return [Chunk(i, a, b) for i, (a, b) in enumerate(itertools.pairwise(edges))]


def frames_used(used: list[np.ndarray]) -> int:
    """Frames the cloud's points were coloured from, given each chunk's (a frame two
    chunks share, once)."""
    return int(np.unique(np.concatenate(used), axis=0).shape[0]) if used else 0


def cloud_of(results: list[ChunkResult], index: DriveLog, cameras: Sequence[str] = ()) -> Cloud:
    """The points of chunks' ``results`` (of the log ``index``, coloured from
    ``cameras``, in the job's order) as one :class:`Cloud` (its ``view_axis`` is the
    default rig's camera side, +y)."""

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
        camera=cat("camera", (0,), np.uint8),
        frame=cat("frame", (0,), np.int32),
        camera_names=tuple(cameras),
        scan_origin=cat("scan_origin", (0, 3), np.float64),
        view_axis=np.array([0.0, 1.0, 0.0]),
        clock=index.clock,
        frames=index.n_frames,
        frames_used=frames_used([r.used_stamps for r in results if r.used_stamps is not None]),
        frames_failed=sum(r.frames_failed for r in results),
    )
