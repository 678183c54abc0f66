"""`acq colorize`: a drive's laser points placed in 3D and coloured from its frames.

1. The log's light part (:func:`acq.log.drive_log.read_log` without image bytes): scan and
   frame stamps with the receipt times and device ticks of the timing records, clock
   pairs, metadata.
2. Offline re-timing (default; :mod:`acq.time.retime`): scans from their ticks over the
   whole log, frames put back on the camera's frame grid.
3. The trajectory (:mod:`acq.motion`): ``--trajectory CSV`` (a post-processed
   GNSS/INS file), else the log's CAN odometry (fused with its GNSS fixes when there are
   any), else its GNSS fixes alone (heading from the track), else none: then the points
   stay in the laser frame at their own time and are
   coloured without motion compensation (right only for a rig standing still; said in
   the report).
4. Chunks of ``chunk_s`` seconds of scans, each read from the files on its own with the
   frames around it (and, for ``--view best``, the laser points just outside it, for
   the depth buffers), coloured by :func:`acq.cloud.views.start_colouring` from each
   camera of the job (every camera of calib.yaml the log has, or ``--camera``), the
   cameras' exposure and white balance evened out (:mod:`acq.cloud.balance`), each point
   taking the camera whose view of it is best (:mod:`acq.cloud.multiview`); in this process,
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

Frames of another size than the camera model's are not used, and the report says how
many and where the first is (log time and file).

Steps 1-3 make the :class:`Job` (:mod:`acq.cloud.job`), step 4 is :mod:`acq.cloud.chunks`,
step 5 :mod:`acq.cloud.writer`; this module runs them (:func:`run`: the chunks here, on
workers or on Dask; ``--time-offset auto``; the :class:`Report`).

Times host monotonic ns unless ``_s``; metres; colours RGB.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from acq import progress as progress_bars
from acq.calib.pose_check import CheckOptions, PoseCheck, check_frames, check_pose
from acq.calib.time_offset import OffsetEstimate, estimate_time_offset
from acq.camera.calibfile import Calibration
from acq.camera.jpeg import SharedDecodes
from acq.cloud import heap, views
from acq.cloud.chunks import (
    Chunk,
    ChunkColouring,
    ChunkResult,
    cloud_of,
    colour_chunk,
    frames_used,
    holds,
    plan,
    start_chunk,
)
from acq.cloud.drive_window import DriveWindow, first_at, odd_size_note, read_window, read_windows
from acq.cloud.job import CameraJob, Job, prepare
from acq.cloud.preview import preview_png
from acq.cloud.report import Report
from acq.cloud.tally import Tally
from acq.cloud.writer import FORMATS, CloudWriter
from acq.errors import InputValueError
from acq.extras import needs
from acq.log.drive_log import DriveLog
from acq.log.inputs import session_files
from acq.motion import Trajectory
from acq.stopped import shield_resource_tracker
from acq.time.host_clock_summary import utc_doubt

# the pipeline's parts, as callers of `acq colorize` and its bench know them
__all__ = [
    "CHUNK_S",
    "FORMATS",
    "PREVIEW_POINTS",
    "READ_ONCE_BYTES",
    "Chunk",
    "ChunkResult",
    "Job",
    "Report",
    "check_calibration",
    "check_drive",
    "cloud_of",
    "colour_chunk",
    "estimate_offset",
    "plan",
    "prepare",
    "run",
    "run_chunks",
]

# logs up to this size are read once, images included: about twice that in memory, and
# no faster than the chunks reading their own parts, which hold two chunks' images at
# most (the 60 s two-camera demo drive, 219 MB: 870 MB peak read once, 750 MB by chunks,
# in the same time; a 5-minute, 1 GB log: 15.3 s and 2.07 GB read once, 13.9 s and
# 1.06 GB by chunks)
READ_ONCE_BYTES = 32 * 2**20
# two chunks are in memory at once (one placed while the last is coloured), each with its
# images: 15 s of a two-camera rig hold about 0.45 GB where 30 s held 0.75 GB, at the
# same speed (a 5-minute log to COPC: 906 MB and 28.7 s against 1235 MB and 29.3 s)
CHUNK_S = 15.0
# a log read here in chunks is read first with the images of its first HELD_CHUNKS
# chunks (the two that start at once), HELD_SLACK_S more for their margins and receipt
HELD_CHUNKS = 2
HELD_SLACK_S = 4.0
PREVIEW_POINTS = 4_000_000  # at most about this many points kept for the preview

log = logging.getLogger(__name__)


def run_chunks(
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
    while a chunk's frames decode. The bar counts scans."""
    stamps = np.sort(job.scan_new)
    scans = {c.index: int(np.sum((stamps >= c.start_ns) & (stamps < c.end_ns))) for c in chunks}
    shares = _ChunkShares(scans)
    waiting: dict[int, ChunkResult] = {}  # done out of order
    expected = deque(c.index for c in chunks)

    def done(result: ChunkResult) -> None:
        waiting[result.index] = result
        while expected and expected[0] in waiting:
            index = expected.popleft()
            emit(waiting.pop(index))
            shares.finish(index)

    with progress_bars.bar(sum(scans.values()), "scan", "colouring", progress):
        _run_each(job, chunks, workers, dask, done, whole, shares)


class _ChunkShares:
    """A chunk's scans on the progress bar (:mod:`acq.progress`): when it runs in this
    process, a share for each of its frames decoded (so the bar moves within a chunk);
    the rest when it is written."""

    def __init__(self, scans: dict[int, int]) -> None:
        self.scans = scans
        self._shown: dict[int, float] = dict.fromkeys(scans, 0.0)
        self._lock = threading.Lock()

    def watch(self, index: int, tasks: Sequence[Future[Any]]) -> None:
        """Chunk ``index``'s frame tasks: each one done moves the bar."""
        share = 0.9 * self.scans[index] / max(len(tasks), 1)  # the rest when written
        for task in tasks:
            task.add_done_callback(lambda _t: self._add(index, share))

    def _add(self, index: int, n: float) -> None:
        with self._lock:
            before = self._shown[index]
            self._shown[index] = before + n
        progress_bars.advance(math.floor(before + n) - math.floor(before), "scan")

    def frames_done(self, index: int, done: int, total: int) -> None:
        """Chunk ``index``, run elsewhere, has ``done`` of its ``total`` frames done."""
        target = 0.9 * self.scans[index] * done / max(total, 1)
        with self._lock:
            before = self._shown[index]
            if target <= before:  # an old report, or the chunk was written already
                return
            self._shown[index] = target
        progress_bars.advance(math.floor(target) - math.floor(before), "scan")

    def drain(self, take: Callable[[], list[Any]], stop: threading.Event) -> None:
        """Until ``stop`` and then what is left: the (chunk, done, total) reports
        ``take`` gets (it waits a moment for them)."""
        while True:
            stopping = stop.is_set()
            reports = take()
            for index, done, total in reports:
                self.frames_done(index, done, total)
            if stopping and not reports:
                return

    def finish(self, index: int) -> None:
        with self._lock:
            before, self._shown[index] = self._shown[index], self.scans[index]
        progress_bars.advance(self.scans[index] - math.floor(before), "scan")


def _run_each(
    job: Job,
    chunks: list[Chunk],
    workers: int,
    dask: str | None,
    done: Callable[[ChunkResult], None],
    whole: DriveLog | None,
    shares: _ChunkShares,
) -> None:
    """Each chunk's result to ``done`` as it comes, however the chunks run."""
    if dask:
        with needs("cluster", "--dask"):
            from dask.distributed import Client, Queue, as_completed

        with Client(dask) as client:
            queue = Queue(client=client)

            def take_dask() -> list[Any]:
                items: list[Any] = queue.get(batch=True)  # at once, what is there
                if not items:
                    time.sleep(0.2)
                return items

            with _draining(shares, take_dask):
                job_f = client.scatter(job, broadcast=True)
                sink = DaskQueueSink(queue.name)
                futures = [
                    client.submit(colour_chunk, job_f, c, None, sink, pure=False) for c in chunks
                ]
                for fut in as_completed(futures):
                    done(fut.result())
    elif workers > 1:
        import multiprocessing
        import queue as queues
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures import as_completed as completed

        ctx = multiprocessing.get_context("spawn")  # numba and threads: no fork
        shield_resource_tracker()
        with ctx.Manager() as manager:
            reports = manager.Queue()

            def take() -> list[Any]:
                try:
                    return [reports.get(timeout=0.2)]
                except queues.Empty:
                    return []
                except (EOFError, OSError):  # its server ended (a signal to the group)
                    time.sleep(0.2)
                    return []

            with (
                _draining(shares, take),
                ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool,
            ):
                pending = [pool.submit(colour_chunk, job, c, None, reports) for c in chunks]
                try:
                    for fut in completed(pending):
                        done(fut.result())
                finally:  # on an error (a full disk, a signal) the chunks not begun are dropped
                    pool.shutdown(cancel_futures=True)
    else:  # one process: the log read once (whole), or each chunk its part
        threads = ThreadPoolExecutor(max_workers=max(1, job.threads))
        decodes = SharedDecodes(threads)  # the frames of two chunks' margins decoded once
        try:
            started: ChunkColouring | None = None
            held = [c.index for c in chunks if whole is not None and holds(whole, job, c)]
            for c in chunks:
                following = start_chunk(job, c, whole if c.index in held else None, threads,
                                        decodes)  # fmt: skip
                if whole is not None and held and c.index == held[-1] < chunks[-1].index:
                    # the chunks that cut their images from it have them: each JPEG is
                    # let go once its queued frame is decoded
                    for frames in whole.cameras.values():
                        frames.jpegs.clear()
                shares.watch(c.index, [f for col in following.colourings for f in col.futures])
                if started is not None:
                    done(started.result())
                started = following
            if started is not None:
                done(started.result())
        finally:  # on an error (a full disk, Ctrl-C) the queued frames are dropped
            threads.shutdown(cancel_futures=True)


@contextmanager
def _draining(shares: _ChunkShares, take: Callable[[], list[Any]]) -> Iterator[None]:
    """The chunks' reports (``take``: from the queue they put them in) to ``shares``, on
    a thread while the block runs."""
    stop = threading.Event()
    drainer = threading.Thread(target=shares.drain, args=(take, stop), daemon=True)
    drainer.start()
    try:
        yield
    finally:
        stop.set()
        drainer.join()


class DaskQueueSink:
    """A chunk's reports into the Dask queue named ``name``, opened on the worker (a
    ``distributed.Queue`` given as a task's argument is opened on the scheduler too,
    where it blocks)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._queue: Any = None

    def __getstate__(self) -> dict[str, Any]:
        return {"name": self.name, "_queue": None}

    def put(self, item: tuple[int, int, int]) -> None:
        if self._queue is None:
            from dask.distributed import Queue

            self._queue = Queue(self.name)
        self._queue.put(item)


def estimate_offset(
    job: Job,
    *,
    camera: CameraJob | None = None,
    whole: DriveLog | None = None,
    start_s: float | None = None,
    seconds: float = 60.0,
    search_s: float = 0.06,
    max_frames: int = 1500,
    threads: int = 1,
) -> OffsetEstimate:
    """The time offset of ``camera`` (default: the job's first) (:mod:`acq.calib.time_offset`)
    from ``seconds`` of the job's log from ``start_s`` after its first scan (default: the
    middle ``seconds``), with CALIB's offset as the prior; ``whole``: the log already
    read, with its images."""
    if job.trajectory is None:
        return OffsetEstimate.not_found(
            "needs the rig's motion: CAN odometry in the log or --trajectory"
        )
    if not job.cameras:
        return OffsetEstimate.not_found("the log has no camera frames")
    cj = camera or job.cameras[0]
    w = read_window(job, cj, whole=whole, start_s=start_s, seconds=seconds, what="time offset")
    if w.strength is None or not np.any(w.strength > 0):
        return OffsetEstimate.not_found(
            "no laser return strengths in the log (record them: SCIP ME, CoLa RSSI1)"
        )
    return estimate_time_offset(
        w.points.P_world, w.points.time_ns, w.strength, w.frame_ns, w.jpegs, cj.cam,
        job.laser_to_vehicle,
        job.trajectory.pose_at, job.trajectory.covers, prior_s=cj.cam.time_offset_s,
        search_s=search_s, max_frames=max_frames, threads=threads,
    )  # fmt: skip


def check_calibration(
    job: Job,
    *,
    cameras: Sequence[CameraJob] | None = None,
    whole: DriveLog | None = None,
    start_s: float | None = None,
    seconds: float = 60.0,
    options: CheckOptions | None = None,
) -> list[PoseCheck]:
    """Whether each of ``cameras``' (default: the job's) calibration holds on ``seconds``
    of the job's log from ``start_s`` after its first scan (default: the middle
    ``seconds``) (:mod:`acq.calib.pose_check`), in their order; ``whole``: the log
    already read, with its images. The scans are read and placed once for all; the
    cameras are checked side by side on ``options.threads``."""
    cams = list(job.cameras if cameras is None else cameras)
    if job.trajectory is None:
        why = "needs the rig's motion: CAN odometry in the log or --trajectory"
        return [PoseCheck("cannot tell", why) for _ in cams]
    if not cams:
        return []
    opt = options or CheckOptions()
    trajectory = job.trajectory
    windows = read_windows(job, cams, whole=whole, start_s=start_s, seconds=seconds,
                           margin_s=opt.window_s + 0.2, what="check",
                           pick=lambda cj, ns: check_frames(ns, cj.cam, trajectory.pose_at,
                                                            trajectory.covers, opt))  # fmt: skip
    strength = windows[0].strength
    if strength is None or not np.any(strength > 0):
        why = "no laser return strengths in the log (record them: SCIP ME, CoLa RSSI1)"
        return [PoseCheck("cannot tell", why) for _ in cams]

    def one(cw: tuple[CameraJob, DriveWindow]) -> PoseCheck:
        cj, w = cw
        p = w.points
        return check_pose(
            p.P_world, p.time_ns, strength, p.scan, p.step, p.r, w.frame_ns, w.jpegs, cj.cam,
            job.laser_to_vehicle, trajectory.pose_at, trajectory.covers, opt,
        )  # fmt: skip

    pairs = list(zip(cams, windows, strict=True))
    if len(pairs) == 1 or opt.threads < 2:
        return [one(cw) for cw in pairs]
    with ThreadPoolExecutor(min(len(pairs), opt.threads)) as pool:
        return list(pool.map(one, pairs))


def check_drive(
    logs: Sequence[Path],
    calib: Calibration,
    *,
    camera: str | Sequence[str] | None = None,
    trajectory: Path | Trajectory | None = None,
    start_s: float | None = None,
    seconds: float = 60.0,
    options: CheckOptions | None = None,
) -> tuple[Job, Report, list[PoseCheck]]:
    """Each camera's calibration checked on ``logs`` (one session):
    :func:`check_calibration` on ``seconds`` from ``start_s`` (default: the middle); the
    job (its cameras in the order of the checks) and the report holding prepare's notes."""
    report = Report(output="")
    job, _ = prepare(logs, calib, report, camera=camera, trajectory=trajectory)
    opt = options or CheckOptions(threads=os.cpu_count() or 1)
    checks = check_calibration(job, start_s=start_s, seconds=seconds, options=opt)
    return job, report, checks


def run(
    logs: Sequence[Path],
    calib: Calibration,
    output: Path,
    *,
    camera: str | Sequence[str] | None = None,
    frame: str | None = None,
    options: views.Options | None = None,
    trajectory: Path | Trajectory | None = None,
    crs: str | None = None,
    retime_offline: bool = True,
    time_offset_s: float | str | None = None,
    workers: int = 1,
    dask: str | None = None,
    chunk_s: float = CHUNK_S,
    preview: Path | None = None,
    progress: bool = False,
    results: list[ChunkResult] | None = None,
    want_uv: bool = False,
    check_s: float | None = None,
) -> Report:
    """The whole command (module docstring); raises InputError (LogError, CalibFileError,
    InputValueError...) with a one-line message for bad input, OSError naming ``output``
    when it cannot be written. ``results``: a list to receive the chunks' results
    (with each point's frame and pixel when ``want_uv``), for accuracy checks.
    ``time_offset_s``: seconds, None for CALIB's, or "auto" (:func:`estimate_offset`).
    ``trajectory``: as :func:`prepare` takes it. ``check_s``: first check each camera's
    calibration on that many seconds of the drive's middle (:func:`check_calibration`),
    its figures into the report (``calibration_check``) and the cloud's metadata."""
    t_start = time.perf_counter()
    options = options or views.Options()
    report = Report(output=str(output), view=options.view)
    # here, a log up to READ_ONCE_BYTES is read once with its images; a longer one's
    # chunks after the first two read their own part (its images never all in memory),
    # and on workers or Dask every chunk does
    logs = session_files(logs)
    size = sum(f.stat().st_size for f in logs if f.is_file())
    local = workers <= 1 and not dask
    once = local and size <= READ_ONCE_BYTES
    # a longer log read here: with the images of its first chunks, which start at once,
    # and their margins (the others read their own part while those decode)
    first_s = None if once or not local else HELD_CHUNKS * chunk_s + HELD_SLACK_S
    auto = isinstance(time_offset_s, str)
    if auto and time_offset_s != "auto":
        raise InputValueError(f"--time-offset {time_offset_s}: expected seconds or 'auto'")
    job, index = prepare(
        logs, calib, report, camera=camera, frame=frame, options=options,
        trajectory=trajectory, retime_offline=retime_offline,
        time_offset_s=None if isinstance(time_offset_s, str) else time_offset_s,
        jpegs=once or first_s is not None, threads=(os.cpu_count() or 1) if local else 1,
        crs=crs, jpegs_for_s=first_s,
    )  # fmt: skip
    job = replace(job, want_uv=want_uv)
    heap.give_back()  # what reading left before the chunks' arrays come
    doubt = utc_doubt(index.metadata)
    if doubt is not None:
        report.notes.append(f"UTC not trusted (the points' times): {doubt}")
    t_offset = time.perf_counter()
    if auto:
        found: dict[str, int] = {}
        for k, cj in enumerate(job.cameras):
            est = estimate_offset(job, camera=cj, whole=index if once else None,
                                  threads=job.threads)  # fmt: skip
            figures = {
                "estimated_s": est.offset_s, "std_s": est.std_s, "points": est.points,
                "frames": est.frames, "contrast": round(est.contrast, 3), "found": est.found,
            }  # fmt: skip
            report.time_offset.setdefault("cameras", {})[cj.name] = figures
            if k == 0:
                report.time_offset.update(figures)
            if est.found:
                found[cj.name] = round(est.offset_s * 1e9)
            else:
                report.notes.append(
                    f"--time-offset auto ({cj.name}): {est.note}; CALIB's time_offset_s used"
                )
        job = job.with_offsets(found)
    t_check = time.perf_counter()
    if check_s is not None:
        opt = CheckOptions(threads=job.threads)
        checks = check_calibration(job, whole=index if once else None, seconds=check_s,
                                   options=opt)  # fmt: skip
        for cj, checked in zip(job.cameras, checks, strict=True):
            report.calibration_check[cj.name] = checked.summary(cj.name)
    world = job.frame_world
    if job.cameras:  # the first camera's figures at the top, as for one camera
        report.time_offset["used_s"] = job.cameras[0].time_offset_ns * 1e-9
    for cj in job.cameras:
        report.time_offset.setdefault("cameras", {}).setdefault(cj.name, {})["used_s"] = (
            cj.time_offset_ns * 1e-9
        )
    scan_new = np.sort(job.scan_new)
    chunks = plan(scan_new, chunk_s)
    t_plan = time.perf_counter()
    out = CloudWriter(output, crs, index.clock, report, [c.name for c in job.cameras],
                      utc_doubt=doubt, checks=report.check_lines())  # fmt: skip
    # a long log's cloud is not held: counts, and every k-th scan for the preview
    every = max(1, math.ceil(index.n_scans * index.steps / PREVIEW_POINTS))
    tally = Tally(every if preview is not None else 0)

    def emit(r: ChunkResult) -> None:
        out.write(r)
        tally.add(r)
        if results is not None:
            results.append(r)
        heap.give_back()  # the chunk's memory, before the next one's

    try:
        imaged = once or first_s is not None  # the index holds images (some or all)
        run_chunks(job, chunks, workers, dask, progress, emit, index if imaged else None)
        t_colour = time.perf_counter()
        size = out.close()
    except BaseException:
        out.stream.abort()
        raise
    report.points, report.coloured, report.hidden = tally.points, tally.coloured, tally.hidden
    report.frames = sum(index.cameras[c.name].frame_ns.size for c in job.cameras)
    report.scans = index.n_scans
    report.frames_used = frames_used(tally.used)
    used = np.concatenate(tally.used) if tally.used else np.zeros((0, 2), np.int64)
    for c, cj in enumerate(job.cameras):
        report.cameras[cj.name] = {
            "points": int(tally.by_camera[c]) if c < tally.by_camera.size else 0,
            "frames_used": int(np.unique(used[used[:, 0] == c, 1]).size),
            "frames": int(cj.frame_old.size),
        }
    report.balance = tally.balance_summary([c.name for c in job.cameras], job.options.balance)
    for cj in job.cameras:
        odd = tally.odd_size.get(cj.name)
        if odd:
            report.frames_odd_size += len(odd)
            note = odd_size_note(index.with_camera(cj.name), odd, cj.cam.model, job.files)
            report.notes.append(f"{cj.name}: {note}" if len(job.cameras) > 1 else note)
        bad = tally.undecodable.get(cj.name)
        if bad:
            report.cameras[cj.name]["frames_undecodable"] = len(bad)
            first = first_at(index.with_camera(cj.name), bad, job.files)
            note = f"{len(bad)} frames that do not decode as JPEG skipped; the first at {first}"
            report.notes.append(f"{cj.name}: {note}" if len(job.cameras) > 1 else note)
    report.frames_failed = sum(len(b) for b in tally.undecodable.values())
    report.duration_s = float(np.ptp(scan_new)) * 1e-9 if scan_new.size else 0.0
    report.chunks = len(chunks)
    report.bytes = size
    if tally.outside:
        report.notes.append(
            f"{tally.outside:,} points measured outside the trajectory's span: "
            + ("left out (no pose)" if world else "kept, not coloured")
        )
    if preview is not None:
        heap.give_back()  # the chunks' memory, before the preview's
        pc = tally.preview_cloud(index.clock, [c.name for c in job.cameras])
        preview_png(preview, pc, title=f"acq colorize {output.name}")
        if every > 1:
            report.notes.append(f"the preview shows one scan in {every}")
    t_end = time.perf_counter()
    parts: dict[str, float] = {"index": t_offset - t_start}
    if auto:
        parts["time offset"] = t_check - t_offset
    if check_s is not None:
        parts["calibration check"] = t_plan - t_check
    parts["chunks and writing"] = t_colour - t_plan
    # the chunks' frames decode on threads meanwhile: "waiting" is what they add
    for key in ("read", "place, queue", "waiting for frames", "finish"):
        parts[f"  {key} (summed over chunks)"] = tally.seconds.get(key, 0.0)
    parts["  writing"] = out.seconds
    parts["closing, preview"] = t_end - t_colour
    parts["total"] = t_end - t_start
    report.seconds = parts
    return report
