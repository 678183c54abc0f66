"""A window of a drive for the checks that compare the laser with a camera's frames
(``--time-offset auto``, ``acq calibrate check``): its scans placed with the job's
trajectory by the colouring core (:func:`acq.cloud.chunks.place`), their return
strengths, and the camera's frames in it, re-timed. Times host ns unless ``_s``; metres.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from acq.camera.camera_models import CameraModel
from acq.cloud import views
from acq.cloud.chunks import place
from acq.cloud.job import CameraJob, Job, remap
from acq.cloud.scan_colouring import Placed
from acq.log.drive_log import DriveLog, read_log
from acq.log.locate import locate
from acq.time import sync

__all__ = ["DriveWindow", "Pick", "first_at", "odd_size_note", "read_window", "read_windows"]

READ_MARGIN_NS = 2 * 10**9  # read this much more either side: receipt lags measurement

log = logging.getLogger(__name__)


def first_at(drive: DriveLog, stamps: Iterable[int], files: Sequence[str]) -> str:
    """Where the first of ``stamps`` (recorded stamps of ``drive``'s frames) lies: its
    log time (its receipt) and file."""
    first = min(stamps)
    i = int(np.searchsorted(drive.frame_ns, first))
    recv = int(drive.frame_recv_ns[i]) if i < drive.frame_recv_ns.size else -1
    return locate(files, recv if recv >= 0 else first)


def odd_size_note(
    drive: DriveLog, odd: dict[int, tuple[int, int]], model: CameraModel, files: Sequence[str]
) -> str:
    """What was skipped: ``odd`` (recorded stamp -> (w, h) px) frames of ``drive``, not of
    ``model``'s size; the first named by its log time (its receipt) and file."""
    sizes = ", ".join(sorted({f"{w}x{h}" for w, h in odd.values()}))
    return (
        f"{len(odd)} frames of another size ({sizes}) than the camera model's "
        f"{model.width}x{model.height} skipped; the first at {first_at(drive, odd, files)}"
    )


@dataclass(frozen=True)
class DriveWindow:
    """``points`` placed in the world (time order), ``strength`` (N,) their return
    strengths (None: the log has none), the camera's frames whose time on the laser's
    clock (CALIB's offset) lies in the window: ``frame_ns`` (M,) re-timed stamps, no
    offset applied, and their ``jpegs``; ``span_ns`` the window (start, end)."""

    points: Placed
    strength: np.ndarray | None
    frame_ns: np.ndarray
    jpegs: list[bytes]
    span_ns: tuple[int, int]


Pick = Callable[[CameraJob, np.ndarray], np.ndarray]
"""Which of a camera's frames a check uses: (its job, the re-timed stamps (M,) ns of its
frames in the window, no offset applied) -> their indices."""


def read_window(
    job: Job, cj: CameraJob, *, whole: DriveLog | None = None, start_s: float | None = None,
    seconds: float = 60.0, margin_s: float = 0.0, what: str = "window",
    pick: Pick | None = None,
) -> DriveWindow:  # fmt: skip
    """:func:`read_windows` of one camera ``cj``."""
    (w,) = read_windows(job, [cj], whole=whole, start_s=start_s, seconds=seconds,
                        margin_s=margin_s, what=what, pick=pick)  # fmt: skip
    return w


def read_windows(
    job: Job, cameras: Sequence[CameraJob], *, whole: DriveLog | None = None,
    start_s: float | None = None, seconds: float = 60.0, margin_s: float = 0.0,
    what: str = "window", pick: Pick | None = None,
) -> list[DriveWindow]:  # fmt: skip
    """``seconds`` of the job's drive (which needs a trajectory) from ``start_s`` after
    its first scan (default: the middle ``seconds``), one window per camera of
    ``cameras`` with its frames, all sharing the scans (read and placed once); the
    scans ``margin_s`` either side too (the swath a frame at the window's edge sees);
    ``whole``: the log already read, with its images, else the window is read. Frames of
    another size than the model's are left out, said in a warning starting ``what``.
    ``pick``: only the frames it picks (chosen from the job's stamps before the log is
    read, so that only their images are read)."""
    first, last = int(job.scan_new[0]), int(job.scan_new[-1])
    span = round(seconds * 1e9)
    lo = first + (max(0, (last - first - span) // 2) if start_s is None else round(start_s * 1e9))
    hi = lo + span
    margin = round(margin_s * 1e9)
    wanted = None if pick is None else {cj.name: _picked(cj, pick, lo, hi) for cj in cameras}
    if whole is None:
        whole = read_log(
            list(job.files), laser=job.laser, cameras=[cj.name for cj in cameras],
            start_ns=lo - margin - READ_MARGIN_NS, end_ns=hi + margin + READ_MARGIN_NS,
            jpegs_at=wanted,
        )  # fmt: skip
    scan_ns = remap(job.scan_old, job.scan_new, whole.scan_ns)
    keep = (scan_ns >= lo - margin) & (scan_ns < hi + margin)
    pts = place(whole, scan_ns, keep, job.trajectory, job.laser_to_vehicle)
    strength = None
    if whole.intensities.size:
        strength = whole.intensities[pts.scan, pts.step].astype(np.float64)
    out = []
    for cj in cameras:
        mine = whole.with_camera(cj.name)
        frame_ns = remap(cj.frame_old, cj.frame_new, mine.frame_ns)
        sel = _in_window(cj, frame_ns, lo, hi)
        if wanted is not None:
            sel = sel[np.isin(mine.frame_ns[sel], list(wanted[cj.name]))]
        odd = views.odd_sized([mine.jpegs[int(i)] for i in sel], cj.cam.model)
        if odd:
            stamps = {int(mine.frame_ns[sel[k]]): size for k, size in odd.items()}
            log.warning("%s: %s", what, odd_size_note(mine, stamps, cj.cam.model, job.files))
            sel = np.delete(sel, list(odd))
        jpegs = [mine.jpegs[int(i)] for i in sel]
        out.append(DriveWindow(pts, strength, frame_ns[sel], jpegs, (lo, hi)))
    return out


def _in_window(cj: CameraJob, frame_ns: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Indices of ``cj``'s frames re-timed at ``frame_ns`` whose time on the laser's
    clock lies in [lo, hi) ns."""
    laser_ns = sync.on_laser_clock(frame_ns, cj.time_offset_ns)
    return np.flatnonzero((laser_ns >= lo) & (laser_ns < hi))


def _picked(cj: CameraJob, pick: Pick, lo: int, hi: int) -> set[int]:
    """The recorded stamps of the frames ``pick`` picks of ``cj``'s in [lo, hi) ns
    (:func:`_in_window`), from the job's stamps: before the log is read."""
    sel = _in_window(cj, cj.frame_new, lo, hi)
    return set(cj.frame_old[sel[pick(cj, cj.frame_new[sel])]].tolist())
