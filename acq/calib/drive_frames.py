"""Which frames and laser points of a drive the targetless checks use
(:mod:`acq.calib.time_offset`, :mod:`acq.calib.pose_check`): frames while the rig moves,
spread over the drive, each with the points measured around its time. Times host ns on
the laser's clock; metres."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from acq.geometry.transforms import PoseFn

__all__ = ["moving_frames", "points_near"]

SPEED_SPAN_NS = 50_000_000  # the rig's speed at a frame: its travel over +- this


def moving_frames(
    frame_ns: np.ndarray, pose_at: PoseFn, covers: Callable[[np.ndarray], np.ndarray], *,
    min_speed_mps: float, max_frames: int,
) -> np.ndarray:  # fmt: skip
    """Indices (sorted) of at most ``max_frames`` of the frames at ``frame_ns`` (M,),
    spread evenly over those taken while the rig moved at ``min_speed_mps`` or more
    (a pose there and 50 ms either side); empty when it never did."""
    moving = np.zeros(frame_ns.size, dtype=bool)
    ok = covers(frame_ns) & covers(frame_ns - SPEED_SPAN_NS) & covers(frame_ns + SPEED_SPAN_NS)
    if ok.any():
        _, a = pose_at(frame_ns[ok] - SPEED_SPAN_NS)
        _, b = pose_at(frame_ns[ok] + SPEED_SPAN_NS)
        moving[ok] = np.linalg.norm(b - a, axis=1) / (2e-9 * SPEED_SPAN_NS) >= min_speed_mps
    candidates = np.flatnonzero(moving)
    if candidates.size == 0:
        return candidates
    spread = np.unique(np.linspace(0, candidates.size - 1, max_frames).astype(int))
    picked: np.ndarray = candidates[spread]
    return picked


def points_near(
    time_ns: np.ndarray, usable: np.ndarray, centre_ns: np.ndarray, half_ns: float,
    max_points: int | None = None,
) -> list[np.ndarray]:  # fmt: skip
    """For each time of ``centre_ns`` (F,), the indices of the ``usable`` points measured
    at ``time_ns`` (N,) within ``half_ns`` of it (in time order), thinned evenly to at
    most ``max_points``."""
    order = np.argsort(time_ns, kind="stable")
    # in float64, as the window's ends are: once, not per frame
    t_sorted = time_ns[order].astype(np.float64)
    c = np.asarray(centre_ns).astype(np.float64)
    los = np.searchsorted(t_sorted, c - half_ns).tolist()
    his = np.searchsorted(t_sorted, c + half_ns).tolist()
    out = []
    for lo, hi in zip(los, his, strict=True):
        idx = order[lo:hi]
        idx = idx[usable[idx]]
        if max_points is not None and idx.size > max_points:
            idx = idx[np.linspace(0, idx.size - 1, max_points).astype(np.int64)]
        out.append(idx)
    return out
