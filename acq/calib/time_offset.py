"""The camera's time offset from a drive's own data (``acq colorize --time-offset auto``,
``acq calibrate time-offset``).

A camera that sends no clock (MJPEG over HTTP, most USB cameras) is stamped at receipt
minus a configured latency; an error in that latency moves every frame in time, and at
20 km/h 10 ms put the colours 5.6 cm along the road (1-3 px at 2-6 m). Agreement
between frames cannot see it (every frame is off by the same time, so all of them
sample the same wrong spot); the laser's own view of the surfaces can: its return
strength follows the surfaces' brightness (a window, a painted line, a poster) as the
image does. For a candidate offset every laser point is projected, motion-compensated,
into the frame nearest its time as the rig stood at the frame's candidate instant, and
the image's grey level sampled there (bilinear); the estimate is the offset that
maximises the mutual information between the points' return strengths and those grey
levels (the criterion of Pandey et al., "Automatic targetless extrinsic calibration of
a 3D lidar and camera by maximizing mutual information", AAAI 2012, here along the time
axis). Mutual information, not correlation: it needs no model of how reflectance in the
laser's infrared maps to grey, which differs per material.

A coarse grid over ``search_s`` either side of the prior, then a fine one around the
best, then a parabola through the fine curve's top. The standard error is a delete-one
jackknife over ``blocks`` runs of consecutive frames: the estimate's error comes mostly
from the scene (which surfaces the laser's lines happen to sample, shared by
neighbouring frames), so sets of frames taken in turn (every 4th) agree with each other
while all being off together; blocks of the drive do not. On 14 recordings of the
demo, 28 estimates, the error over this standard error had an RMS of 1.1 (at most 2.9);
on 11 of them, four sets of every 4th frame gave 2.7 (at most 8.6)
(``bench/time_offset.py``). No bias: on 50 simulated drives (another street each) the
mean error was -0.03 +- 0.09 ms for the left camera, +0.30 +- 0.27 ms for the right;
on one street the error follows where the scanner's lines fall on the surfaces (up to
+-2 ms on the demo's, with the scanner's phase), which the blocks see.

It needs motion (a rig standing still sees the same whatever the offset) and return
strengths in the log (SCIP ``ME``, CoLa ``RSSI1``); it says so instead of guessing. Times
host ns unless ``_s``; metres.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from acq import progress
from acq.calib.drive_frames import moving_frames, points_near
from acq.calib.information import information, joint_counts, quantile_bins, quantile_edges
from acq.camera import projection
from acq.camera.calibfile import CameraCalib
from acq.camera.jpeg import decoded_frames
from acq.geometry.transforms import PoseFn, Rigid, world_to_laser_each
from acq.time import sync

__all__ = ["OffsetEstimate", "estimate_time_offset"]


@dataclass(frozen=True)
class OffsetEstimate:
    """``offset_s``: camera time minus laser time (s; what calib.yaml's ``time_offset_s``
    holds, NaN when not found); ``std_s`` its standard error from the folds;
    ``candidates_s`` -> ``scores`` the coarse curve (mutual information, nats);
    ``points`` and ``frames`` used; ``contrast`` the peak's rise over the curve's median
    relative to the median; ``found`` and ``note`` why not; ``folds_s`` the estimates
    with each block of frames left out (the jackknife's, s)."""

    offset_s: float
    std_s: float
    candidates_s: np.ndarray
    scores: np.ndarray
    points: int
    frames: int
    contrast: float
    found: bool
    note: str = ""
    folds_s: list[float] = field(default_factory=list)

    @classmethod
    def not_found(cls, note: str) -> OffsetEstimate:
        """No estimate, with the reason."""
        empty = np.zeros(0)
        return cls(np.nan, np.nan, empty, empty, 0, 0, 0.0, False, note)


def _jackknife_se(left_out: np.ndarray) -> float:
    """The delete-one jackknife's standard error from the estimates with each block
    left out in turn (NaN for fewer than two)."""
    k = left_out.size
    if k < 2:
        return float("nan")
    return float(np.sqrt((k - 1) / k * np.sum((left_out - left_out.mean()) ** 2)))


@dataclass
class _Frame:
    index: int  # into the log's frames
    t_ns: int  # its stamp (re-timed) before any offset
    points: np.ndarray  # indices into the points


def _remap(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``image`` (float32) at the pixels ``uv`` (N,2) (bilinear, the border repeated):
    (N,), in rows of 1024 (OpenCV's maps have fewer than 32767 rows and columns)."""
    n = uv.shape[0]
    m = np.zeros((-(-n // 1024) * 1024, 2), dtype=np.float32)
    m[:n] = uv
    m = m.reshape(-1, 1024, 2)
    out = cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n]


def estimate_time_offset(
    P_world: np.ndarray,
    time_ns: np.ndarray,
    strength: np.ndarray,
    frame_ns: np.ndarray,
    jpegs: list[bytes],
    cam: CameraCalib,
    laser_to_vehicle: Rigid,
    pose_at: PoseFn,
    covers: Callable[[np.ndarray], np.ndarray],
    *,
    prior_s: float = 0.0,
    search_s: float = 0.06,
    coarse_s: float = 0.002,
    fine_s: float = 0.00025,
    max_frames: int = 300,
    min_speed_mps: float = 1.0,
    bins: int = 24,
    blur_px: float = 0.7,
    blocks: int = 12,
    threads: int = 2,
) -> OffsetEstimate:
    """The camera's time offset (module docstring) from points ``P_world`` (N,3) m
    measured at ``time_ns`` (N,) with return strengths ``strength`` (N,), and frames
    stamped ``frame_ns`` (M,) (re-timed, no offset applied) with their ``jpegs``; the
    rig's pose from ``pose_at``/``covers``. Candidates ``prior_s`` +- ``search_s``."""
    v2l = laser_to_vehicle.inverse()
    fail = OffsetEstimate.not_found

    usable = np.isfinite(P_world).all(axis=1) & (strength > 0)
    if not usable.any():
        return fail("no laser return strengths in the log (SCIP ME / CoLa RSSI1 needed)")
    # frames while the rig moves, spread over the drive; each with the points nearest it
    period = float(np.median(np.diff(np.sort(frame_ns)))) if frame_ns.size > 1 else 4e7
    prior_ns = round(prior_s * 1e9)
    t_prior = frame_ns - prior_ns
    pick = moving_frames(
        t_prior, pose_at, covers, min_speed_mps=min_speed_mps, max_frames=max_frames
    )
    if pick.size == 0:
        return fail("the rig does not move (or no pose) while the camera records")
    near = points_near(time_ns, usable, t_prior[pick], period / 2)
    frames = [
        _Frame(j, int(frame_ns[j]), idx) for j, idx in zip(pick.tolist(), near, strict=True)
        if idx.size
    ]  # fmt: skip
    if not frames:
        return fail("no laser points near the frames' times")

    model, c2l = cam.model, cam.camera_to_laser

    def sample(offsets_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grey levels (K, n) of every frame's points under each offset, valid (n,) in
        all of them, and each point's block (of ``blocks`` runs of consecutive frames)."""
        k = offsets_s.size
        cuts = np.concatenate([[0], np.cumsum([f.points.size for f in frames])])
        g = np.zeros((k, int(cuts[-1])), dtype=np.float32)  # written in place, not joined
        good = np.zeros(g.shape[1], dtype=bool)
        jpeg_order = np.array([f.index for f in frames])
        decoded = decoded_frames(jpegs, jpeg_order, threads)
        with progress.bar(len(frames), "frame", f"time offset ({k} offsets)"):
            for r, (f, image) in enumerate(zip(frames, decoded, strict=True)):
                progress.advance(1, "frame")
                if image is None or image.shape[:2] != (model.height, model.width):
                    continue  # not sampled: its pixels are not the model's (callers say so)
                t = sync.on_laser_clock(f.t_ns, np.rint(offsets_s * 1e9))
                if not covers(t).all():
                    continue
                grey: np.ndarray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32)
                if blur_px > 0:
                    grey = cv2.GaussianBlur(grey, (0, 0), blur_px)
                # every offset at once: one projection and one remap a frame
                R, tr = pose_at(t)
                P_l = world_to_laser_each(P_world[f.points], R, tr, v2l)
                uv, ok = projection.project(P_l.reshape(-1, 3), model, c2l)
                a, b = int(cuts[r]), int(cuts[r + 1])
                good[a:b] = ok.reshape(k, b - a).all(axis=0)
                g[:, a:b] = _remap(grey, uv).reshape(k, b - a)
        fold = np.repeat(np.arange(len(frames)) * max(blocks, 1) // len(frames), np.diff(cuts))
        return g, good, fold

    def curve(grey: np.ndarray, mask: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """The mutual information (K,) at each offset of the points ``mask`` (N,) of
        ``pts`` (N,): their return strengths and their grey levels ``grey`` (K, N), each
        binned by the quantiles of those points (the grey levels' at the middle offset,
        so that the offsets compare); the samples are not copied."""
        s_bins = quantile_bins(strength[pts], bins, quantile_edges(strength[pts][mask], bins))
        g_edges = quantile_edges(grey[grey.shape[0] // 2][mask], bins)
        joint = np.zeros((bins, bins), dtype=np.int64)
        out = np.empty(grey.shape[0])
        for k, g in enumerate(grey):
            joint[:] = 0
            joint_counts(s_bins, g, g_edges, mask, joint)
            out[k] = information(joint)
        return out

    def peak(x: np.ndarray, y: np.ndarray, half: int = 6) -> float:
        """The top of a least-squares parabola through the best point and ``half``
        points either side (the curve's top is smooth; the points are not)."""
        i = int(np.argmax(y))
        lo, hi = max(0, i - half), min(y.size, i + half + 1)
        a, b, _ = np.polyfit(x[lo:hi], y[lo:hi], 2)
        return float(np.clip(-b / (2 * a), x[lo], x[hi - 1])) if a < 0 else float(x[i])

    coarse = prior_s + np.arange(-search_s, search_s + coarse_s / 2, coarse_s)
    grey, good, _ = sample(coarse)
    if good.sum() < 1000:
        return fail(f"only {int(good.sum())} laser points in view of the frames")
    pts = np.concatenate([f.points for f in frames])
    scores = curve(grey, good, pts)
    del grey
    best = int(np.argmax(scores))
    median = float(np.median(scores))
    contrast = (float(scores[best]) - median) / median if median > 0 else 0.0
    n_pts, n_frames = int(good.sum()), len(frames)
    note = ""
    if best in (0, scores.size - 1):
        note = "the best offset lies at the edge of the search; widen it (--search)"
    elif contrast < 0.02:
        note = "no peak: too little texture or motion"
    if note:
        return OffsetEstimate(
            np.nan, np.nan, coarse, scores, n_pts, n_frames, contrast, False, note
        )
    # fine grid around the coarse best: same points, so the curves compare
    fine = coarse[best] + np.arange(-2 * coarse_s, 2 * coarse_s + fine_s / 2, fine_s)
    grey_f, keep, fold = sample(fine)
    offset = peak(fine, curve(grey_f, keep, pts))
    per_fold: list[float] = []
    for r in np.unique(fold[keep]):
        sel = keep & (fold != r)
        if sel.sum() >= 1000:
            per_fold.append(peak(fine, curve(grey_f, sel, pts)))
    std = _jackknife_se(np.array(per_fold))
    return OffsetEstimate(
        offset, std, coarse, scores, n_pts, n_frames, contrast, True, folds_s=per_fold
    )
