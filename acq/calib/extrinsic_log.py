"""Camera–laser extrinsics from a recorded log (``acq calibrate extrinsic``, paper §3.2).

The operator holds a checkerboard still in 15 or more poses in view of both sensors.
From the log (:func:`acq.log.drive_log.read_log`):

1. still poses (:func:`still_intervals`): runs of at least ``min_still_s`` where
   consecutive frames barely change (mean absolute difference of 1/4-scale grey images,
   grey levels) and consecutive scans barely change (median absolute range change, m);
   or the intervals given (``--poses START:END,...``, seconds from the log's first scan);
2. per pose: the per-beam median of its scans (robust to noise and passers-by) and the
   board's corners averaged over up to 10 of its frames (:class:`CornerFinder`: on the
   fisheye image, else on virtual pinhole views rendered through the camera model,
   mapped back; :func:`average_corners`), hence the board plane in the camera frame
   (:func:`acq.calib.board_pose.board_pose_from_corners`). Averaging matters: with one frame
   per pose the camera's planes limit the rotation to ~0.18° (median, 20 poses at 1–4 m,
   0.2 px corner noise; the Cramér–Rao bound of that data, ``bench/extrinsic.py``), with
   4 frames and 6 scans per pose to ~0.06°;
3. the laser points on the board (:func:`board_segment`): the scan cut at range jumps,
   the straight segments of a board's length; with a coarse ``camera_to_laser`` (not the
   identity) the one nearest the camera's plane, else the one in front of its
   neighbours (the board stands before the background) whose range is nearest the
   board's distance from the camera; at each end, the outermost points off the line
   (mixed returns at the board's edges, within ``trim_m``) dropped, those on it kept;
4. :func:`acq.calib.extrinsic.calibrate` on all poses.

Frames of another size than the camera model's are skipped, and a WARNING says how many
and where the first is (log time and file).

Units: metres, radians unless ``_deg``; times host ns unless ``_s``.
"""

from __future__ import annotations

import itertools
import logging
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from acq import progress
from acq.calib.board_pose import BoardPose, board_pose_from_corners
from acq.calib.checkerboard import BoardSpec, board_hint, detect_corners
from acq.camera.camera_models import CameraModel
from acq.errors import InputValueError
from acq.geometry.transforms import Rigid
from acq.log import drive_log
from acq.log.locate import locate

__all__ = [
    "METHOD",
    "NOT_IN_IMAGE",
    "CornerFinder",
    "PoseData",
    "average_corners",
    "board_segment",
    "board_size_hint",
    "parse_poses",
    "poses_from_log",
    "scan_points",
    "still_intervals",
]

METHOD = "zhang_pless"
NOT_IN_IMAGE = "board not found in the image"  # PoseData.problem
# still frames of one pose in a row without the board before the pose is given up: a
# board in another camera's view (a rig of several) costs that many searches, not ten
MISSES_BEFORE_GIVING_UP = 3

logger = logging.getLogger(__name__)


# --- still poses ----------------------------------------------------------------------


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index runs where ``flags`` is True."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    d = np.diff(padded)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def still_intervals(
    log: drive_log.DriveLog,
    *,
    min_still_s: float = 0.5,
    grey_change: float = 20.0,
    range_change_m: float = 0.05,
    max_changed: float = 0.002,
    margin_s: float = 0.1,
) -> list[tuple[int, int]]:
    """(start_ns, end_ns) runs of at least ``min_still_s`` where both the frames and the
    scans are still; ``margin_s`` is cut at each end.

    A frame is still when at most ``max_changed`` of its 1/4-scale grey pixels changed by
    more than ``grey_change`` levels since the previous frame, a scan when at most that
    share (and 3) of its beams changed by more than ``range_change_m`` m. (A mean or a
    median over the whole image or scan misses a board covering a tenth of it.)"""
    if log.n_frames < 2 or log.n_scans < 2:
        return []
    flag = cv2.IMREAD_REDUCED_GRAYSCALE_4
    small: list[np.ndarray | None] = []
    with progress.bar(log.n_frames, "frame", "still intervals"):
        for jpeg in log.jpegs:
            small.append(cv2.imdecode(np.frombuffer(jpeg, np.uint8), flag))
            progress.advance(1, "frame")
    fchange = np.ones(log.n_frames)
    for k in range(1, log.n_frames):
        a, b = small[k - 1], small[k]
        if a is not None and b is not None and a.shape == b.shape:
            fchange[k] = float(np.mean(cv2.absdiff(a, b) > grey_change))
    fchange[0] = fchange[1]
    r = np.where(np.isfinite(log.ranges), log.ranges, 0.0)
    schange = np.ones(log.n_scans, dtype=np.int64) * r.shape[1]
    schange[1:] = np.count_nonzero(np.abs(np.diff(r, axis=0)) > range_change_m, axis=1)
    schange[0] = schange[1]
    scan_still = schange <= max(3, max_changed * r.shape[1])
    # the scans' stillness around each frame's time: the frame is still when both are
    at = np.clip(np.searchsorted(log.scan_ns, log.frame_ns), 1, log.n_scans - 1)
    still = (fchange <= max_changed) & scan_still[at] & scan_still[at - 1]
    out = []
    margin = round(margin_s * 1e9)
    for i, j in _runs(still):
        start, end = int(log.frame_ns[i]) + margin, int(log.frame_ns[j - 1]) - margin
        if end - start >= min_still_s * 1e9:
            out.append((start, end))
    return out


def parse_poses(text: str, t0_ns: int) -> list[tuple[int, int]]:
    """``START:END,...`` (seconds from ``t0_ns``) -> (start_ns, end_ns) intervals."""
    out = []
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        try:
            a, b = (float(x) for x in part.split(":"))
        except ValueError:
            raise InputValueError(f"--poses {text!r}: expected START:END,... in seconds") from None
        if not (math.isfinite(a) and math.isfinite(b) and b > a):
            raise InputValueError(f"--poses {part!r}: need END > START")
        out.append((t0_ns + round(a * 1e9), t0_ns + round(b * 1e9)))
    if not out:
        raise InputValueError(f"--poses {text!r}: no interval")
    return out


# --- the camera: corners and board plane ----------------------------------------------


def _look_at(direction: np.ndarray) -> np.ndarray:
    """Rotation (virtual camera -> camera) whose z is ``direction``, x roughly the camera's x."""
    z = direction / np.linalg.norm(direction)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _views(step_deg: float = 30.0) -> list[np.ndarray]:
    """Virtual view directions (camera frame): the axis, then rings around it."""
    dirs = [np.array([0.0, 0.0, 1.0])]
    for tilt in (step_deg, 2 * step_deg):
        for az in range(0, 360, 45):
            t, a = math.radians(tilt), math.radians(az)
            dirs.append(
                np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
            )
    return dirs


def _view_maps(
    model: CameraModel, R: np.ndarray, view_px: int, view_fov_deg: float
) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """cv2.remap maps of a virtual pinhole view (``view_px`` square, ``view_fov_deg``
    wide, turned by ``R`` from the camera), its focal length and centre (px); None when
    less than half of it falls inside the image."""
    f = 0.5 * view_px / math.tan(math.radians(view_fov_deg) / 2)
    c = 0.5 * (view_px - 1)
    g = np.arange(view_px, dtype=np.float64)
    uu, vv = np.meshgrid(g, g)
    local = np.column_stack([(uu.ravel() - c) / f, (vv.ravel() - c) / f, np.ones(uu.size)])
    src, valid = model.project(local @ R.T)
    if valid.mean() < 0.5:
        return None
    mx = src[:, 0].reshape(view_px, view_px).astype(np.float32)
    my = src[:, 1].reshape(view_px, view_px).astype(np.float32)
    return mx, my, f, c


class CornerFinder:
    """Finds a board's corners in fisheye frames (px), first on the image itself, else on
    virtual pinhole views (``view_px`` square, ``view_fov_deg`` wide) resampled through
    ``model`` in several directions, corners found there mapped back through the model.

    Remembers where it last succeeded (the image or which view), so the frames of one
    still pose cost one detection each; elsewhere OpenCV's quick check goes first, so a
    frame without the board (another camera's pose) costs milliseconds, not seconds."""

    def __init__(
        self,
        spec: BoardSpec,
        model: CameraModel,
        *,
        view_px: int = 900,
        view_fov_deg: float = 90.0,
    ) -> None:
        self.spec, self.model = spec, model
        self.view_px, self.view_fov_deg = view_px, view_fov_deg
        self._maps: dict[int, tuple[np.ndarray, np.ndarray, float, float] | None] = {}
        self._views = _views()
        self.last: int | None = None  # -1: the image itself, else a view index

    def _in(self, gray: np.ndarray, where: int) -> np.ndarray | None:
        fast = where != self.last
        if where < 0:
            return detect_corners(gray, self.spec, fast=fast)
        if where not in self._maps:
            R = _look_at(self._views[where])
            self._maps[where] = _view_maps(self.model, R, self.view_px, self.view_fov_deg)
        maps = self._maps[where]
        if maps is None:
            return None
        mx, my, f, c = maps
        view = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderValue=0)
        found = detect_corners(view, self.spec, fast=fast)
        if found is None:
            return None
        rays = (
            np.column_stack([(found - c) / f, np.ones(len(found))]) @ _look_at(self._views[where]).T
        )
        back, ok = self.model.project(rays)
        return back if ok.all() else None

    def __call__(self, gray: np.ndarray) -> np.ndarray | None:
        """(cols*rows, 2) corners in ``gray`` (px), or None."""
        order = [-1, *range(len(self._views))]
        if self.last is not None:
            order.remove(self.last)
            order.insert(0, self.last)
        for where in order:
            uv = self._in(gray, where)
            if uv is not None:
                self.last = where
                return uv
        return None


def average_corners(
    detections: Sequence[np.ndarray], tol_px: float = 1.0
) -> tuple[np.ndarray, int]:
    """The mean of one still board's corner detections (each (N,2) px) and how many were
    averaged: each detection put in the first one's corner order (OpenCV may report a
    board reversed), those more than ``tol_px`` (RMS) from the per-corner median left out
    (the board moved). Image noise is independent from frame to frame, so n frames bring
    a corner's noise down by about sqrt(n)."""
    ref = detections[0]
    aligned = []
    for uv in detections:
        if uv.shape != ref.shape:
            continue
        rev = uv[::-1]
        aligned.append(uv if np.sum((uv - ref) ** 2) <= np.sum((rev - ref) ** 2) else rev)
    stack = np.stack(aligned)
    med = np.median(stack, axis=0)
    rms = np.sqrt(np.mean(np.sum((stack - med) ** 2, axis=2), axis=1))
    keep = stack[rms <= tol_px]
    if not len(keep):
        keep = stack[[int(np.argmin(rms))]]
    return keep.mean(axis=0), len(keep)


# --- the laser: points on the board ---------------------------------------------------


def scan_points(ranges: np.ndarray, angle_min: float, angle_increment: float) -> np.ndarray:
    """(N,3) laser-frame points (m, z = 0) of ``ranges`` (NaN where no finite range)."""
    a = angle_min + angle_increment * np.arange(len(ranges))
    r = np.where(np.isfinite(ranges), ranges, np.nan).astype(np.float64)
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)])


def _segments(points: np.ndarray, jump_m: float, min_points: int) -> list[np.ndarray]:
    """Index runs of consecutive finite points no more than ``jump_m`` apart."""
    ok = np.isfinite(points[:, 0])
    gaps = np.linalg.norm(np.diff(points[:, :2], axis=0), axis=1)
    cut = np.concatenate([[True], ~(gaps <= jump_m)]) | ~ok
    out = []
    for a, b in _runs(ok):
        starts = [a] + [i for i in range(a + 1, b) if cut[i]] + [b]
        for s, e in itertools.pairwise(starts):
            if e - s >= min_points:
                out.append(np.arange(s, e))
    return out


def _line_fit(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Centre, direction, RMS distance to the line and length (m) of 2-D points."""
    c = P.mean(axis=0)
    _, s, Vt = np.linalg.svd(P - c, full_matrices=False)
    d = Vt[0]
    along = (P - c) @ d
    rms = float(s[1] / math.sqrt(len(P))) if len(s) > 1 else 0.0
    return c, d, rms, float(along.max() - along.min())


def board_segment(
    ranges: np.ndarray,
    angle_min: float,
    angle_increment: float,
    plane: tuple[np.ndarray, float],
    spec: BoardSpec,
    *,
    coarse: Rigid | None = None,
    jump_m: float = 0.05,
    max_line_rms_m: float = 0.02,
    trim_m: float = 0.02,
    min_points: int = 10,
) -> np.ndarray | None:
    """(M,3) laser points on the board (see the module docstring, step 3), or None.

    ``plane``: the board's (unit normal, distance) in the camera frame; ``coarse``: a
    rough camera_to_laser, used when given (not None)."""
    P = scan_points(ranges, angle_min, angle_increment)
    n, d = plane
    grid = max(spec.cols + 1, spec.rows + 1) * spec.square
    cands = []
    for idx in _segments(P, jump_m, min_points):
        c, u, rms, length = _line_fit(P[idx, :2])
        if rms > max_line_rms_m or not 0.25 <= length <= 2.0 * grid:
            continue
        cands.append((idx, c, u))
    if not cands:
        return None
    if coarse is not None:
        n_l = coarse.rotation @ n  # the plane in the laser frame: n_l . X = d + n_l . t
        d_l = d + float(n_l @ coarse.translation)
        errs = [float(np.median(np.abs(P[i] @ n_l - d_l))) for i, _, _ in cands]
        best = int(np.argmin(errs))
        if errs[best] > 0.15:
            return None
    else:
        # in front of the background: its neighbours beyond the ends are farther (or none)
        r = np.where(np.isfinite(ranges), ranges, np.inf)

        def foreground(idx: np.ndarray) -> bool:
            a, b = idx[0] - 1, idx[-1] + 1
            before = a < 0 or r[a] > r[idx[0]] + jump_m
            after = b >= len(r) or r[b] > r[idx[-1]] + jump_m
            return bool(before and after)

        fg = [k for k, (i, _, _) in enumerate(cands) if foreground(i)]
        if not fg:
            return None
        # the camera sees the board at distance ~d; camera and laser are close
        best = min(fg, key=lambda k: abs(float(np.median(r[cands[k][0]])) - abs(d)))
    idx, c, u = cands[best]
    Q = P[idx]
    keep = _off_line_ends(Q[:, :2], c, u, trim_m)
    return Q[keep] if keep.sum() >= 2 else None


def _off_line_ends(P: np.ndarray, c: np.ndarray, u: np.ndarray, end_m: float) -> np.ndarray:
    """Which of the segment's 2-D points (m; line centre ``c``, direction ``u``, in scan
    order) to keep: all but, at each end, the run of outermost points off the line by
    more than 3 robust standard deviations (MAD, at least 1 mm) of the distances, within
    ``end_m`` of the end: the mixed returns of beams that graze the board's edge, their
    range between the board's and the background's. Ends on the line are kept: they give
    the fit its longest lever; a point off the line inside the board is noise."""
    along = (P - c) @ u
    off = (P - c) @ np.array([-u[1], u[0]])
    dev = np.abs(off - np.median(off))
    # sigma at least 1 mm: no scanner is better, and exact (simulated) ranges have none
    bad = dev > 3.0 * max(1.4826 * float(np.median(dev)), 1e-3)
    keep = np.ones(len(P), dtype=bool)
    for order, edge in ((range(len(P)), along[0]), (range(len(P) - 1, -1, -1), along[-1])):
        for i in order:
            if not bad[i] or abs(along[i] - edge) > end_m:
                break
            keep[i] = False
    return keep


# --- per pose ---------------------------------------------------------------------------


@dataclass(frozen=True)
class PoseData:
    """One still interval: ``start_ns``/``end_ns``, the first frame used (``frame_ns``, -1
    when no board was found), the camera's board RMS (px) with the corners averaged over
    ``frames`` frames, and the pose (None with ``problem``)."""

    start_ns: int
    end_ns: int
    frame_ns: int
    rms_px: float
    pose: BoardPose | None
    problem: str = ""
    frames: int = 0

    def to_dict(self, t0_ns: int) -> dict[str, Any]:
        return {
            "start_s": (self.start_ns - t0_ns) * 1e-9,
            "end_s": (self.end_ns - t0_ns) * 1e-9,
            "frame_s": None if self.frame_ns < 0 else (self.frame_ns - t0_ns) * 1e-9,
            "corner_rms_px": None if math.isnan(self.rms_px) else self.rms_px,
            "frames": self.frames,
            "laser_points": 0 if self.pose is None else len(self.pose.points),
            "problem": self.problem,
        }


def _pose_in(
    log: drive_log.DriveLog,
    start: int,
    end: int,
    model: CameraModel,
    spec: BoardSpec,
    finder: CornerFinder,
    coarse: Rigid | None,
    frames_per_pose: int,
    odd: dict[int, tuple[int, int]],
) -> PoseData:
    """The board's pose in one still interval (:func:`poses_from_log`); frames of another
    size than the model's go into ``odd`` (index -> (w, h) px)."""
    obj = spec.object_points()
    size = (model.height, model.width)
    s = (log.scan_ns >= start) & (log.scan_ns <= end)
    f = np.flatnonzero((log.frame_ns >= start) & (log.frame_ns <= end))
    if not s.any() or not f.size:
        return PoseData(start, end, -1, math.nan, None, "no scan or no frame")
    # the middle frames first, spread over the interval
    order = f[np.argsort(np.abs(f - f[len(f) // 2]))]
    step = max(1, len(order) // frames_per_pose)
    detections, used, misses = [], -1, 0
    for k in order[::step][:frames_per_pose]:
        gray = cv2.imdecode(np.frombuffer(log.jpegs[k], np.uint8), cv2.IMREAD_GRAYSCALE)
        if gray is not None and gray.shape != size:
            odd[int(k)] = (gray.shape[1], gray.shape[0])
            continue
        found = None if gray is None else finder(gray)
        if found is not None:
            detections.append(found)
            used = int(log.frame_ns[k]) if used < 0 else used
        elif not detections:
            misses += 1
            if misses == MISSES_BEFORE_GIVING_UP:  # the board is not in this camera's view
                break
    if not detections:
        why = (
            "no frame of the camera model's size"
            if all(int(k) in odd for k in order[::step][:frames_per_pose])
            else NOT_IN_IMAGE
        )
        return PoseData(start, end, -1, math.nan, None, why)
    uv, n_frames = average_corners(detections)
    fit = board_pose_from_corners(model, obj, uv)
    with warnings.catch_warnings():  # beams with no return in any scan stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        ranges = np.nanmedian(np.where(np.isfinite(log.ranges[s]), log.ranges[s], np.nan), 0)
    pts = board_segment(
        ranges, log.angle_min, log.angle_increment, fit.plane(), spec, coarse=coarse
    )
    if pts is None:
        why = "board not found in the scan"
        return PoseData(start, end, used, fit.rms_px, None, why, n_frames)
    pid = f"{(start - int(log.scan_ns[0])) * 1e-9:.2f}s"
    pose = BoardPose.from_fit(fit, pts, id=pid)
    return PoseData(start, end, used, fit.rms_px, pose, frames=n_frames)


def board_size_hint(
    log: drive_log.DriveLog,
    model: CameraModel,
    intervals: Sequence[tuple[int, int]],
    spec: BoardSpec,
    max_frames: int = 5,
) -> str:
    """:func:`acq.calib.checkerboard.board_hint` on the middle frame of up to
    ``max_frames`` of ``intervals`` (host ns; those where the board was not found), a
    size found as :class:`CornerFinder` finds it through ``model``."""
    finders: dict[BoardSpec, CornerFinder] = {}

    def find(gray: np.ndarray, size: BoardSpec) -> np.ndarray | None:
        return finders.setdefault(size, CornerFinder(size, model))(gray)

    grays = []
    for start, end in intervals[:: max(1, len(intervals) // max_frames)][:max_frames]:
        f = np.flatnonzero((log.frame_ns >= start) & (log.frame_ns <= end))
        if f.size and log.jpegs:
            jpeg = np.frombuffer(log.jpegs[int(f[f.size // 2])], np.uint8)
            gray = cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE)
            if gray is not None:
                grays.append(gray)
    return board_hint(grays, spec, find)


def poses_from_log(
    log: drive_log.DriveLog,
    model: CameraModel,
    spec: BoardSpec,
    intervals: Sequence[tuple[int, int]],
    *,
    coarse: Rigid | None = None,
    frames_per_pose: int = 10,
) -> list[PoseData]:
    """A :class:`PoseData` per interval (see the module docstring, steps 2–3); the
    corners averaged over up to ``frames_per_pose`` of the interval's frames (the middle
    ones first)."""
    finder = CornerFinder(spec, model)
    out = []
    odd: dict[int, tuple[int, int]] = {}  # frames of another size: index -> (w, h) px
    with progress.bar(len(intervals), "pose", "board poses"):
        for start, end in intervals:
            out.append(_pose_in(log, start, end, model, spec, finder, coarse, frames_per_pose, odd))
            progress.advance(1, "pose")
    if odd:
        first = min(odd, key=lambda k: int(log.frame_ns[k]))
        recv = int(log.frame_recv_ns[first]) if first < log.frame_recv_ns.size else -1
        sizes = ", ".join(sorted({f"{w}x{h}" for w, h in odd.values()}))
        where = locate(log.files, recv if recv >= 0 else int(log.frame_ns[first]))
        logger.warning(
            "%d frames of another size (%s) than the camera model's %dx%d skipped; "
            "the first at %s", len(odd), sizes, model.width, model.height, where,
        )  # fmt: skip
    return out
