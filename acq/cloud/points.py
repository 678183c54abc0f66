"""Coloured points (:class:`Cloud`), and the single-camera placing and colouring of a
whole drive held in memory (:func:`colorize`).

Placement (:func:`colorize`): point ``i`` of a scan was measured at
``scan start + i * time_increment``; ``pose_at`` gives the vehicle's pose (vehicle ->
world) at those host times, and the calibration's ``laser_to_vehicle`` puts the laser on
the vehicle. Colour: each point goes back into the nearest frame's instant (world ->
vehicle at the frame's time -> laser -> camera, paper eq. 2 inverted) and takes the
bilinear colour of its pixel; points no frame sees (behind the camera, outside its field
of view or the image, or too far in time from any frame) are kept and flagged.
Occlusion is not checked: a point hidden from the camera by something nearer takes that
thing's colour.

Times are host ``CLOCK_MONOTONIC`` ns (int64) unless a name ends in ``_s``; positions
are metres in the frame ``pose_at`` maps to (``world``); colours RGB uint8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acq.camera import projection
from acq.camera.calibfile import Calibration
from acq.cloud import views
from acq.cloud.drive_log import DriveLog
from acq.geometry.transforms import PoseFn, Rigid
from acq.time import sync


@dataclass(frozen=True)
class Cloud:
    """Coloured points, one per laser return, in scan order.

    Per point: ``xyz`` (P,3) float64 m in the world frame; ``rgb`` (P,3) uint8 (zero
    where not coloured); ``coloured`` (P,) bool; ``time_ns`` (P,) int64 host monotonic
    ns of the measurement; ``scan`` (P,) uint32 index of its scan in the log; ``step``
    (P,) uint32 its index within the scan; ``intensity`` (P,) float32 device units;
    ``dt_s`` (P,) float32 its time minus its frame's (NaN where not coloured).
    Per scan: ``scan_origin`` (S,3) the laser's position in the world at point 0.
    ``view_axis`` (3,) the camera's mean optical axis in the world (unit). ``clock``
    (K,2) the log's (monotonic ns, realtime ns) pairs. ``frames`` frames in the log,
    ``frames_used`` decoded and used, ``frames_failed`` not decodable.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    coloured: np.ndarray
    time_ns: np.ndarray
    scan: np.ndarray
    step: np.ndarray
    intensity: np.ndarray
    dt_s: np.ndarray
    scan_origin: np.ndarray
    view_axis: np.ndarray
    clock: np.ndarray
    frames: int = 0
    frames_used: int = 0
    frames_failed: int = 0

    @property
    def size(self) -> int:
        return int(self.time_ns.size)

    @property
    def coloured_share(self) -> float:
        return float(self.coloured.mean()) if self.size else 0.0


def _transform(R: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per-point rigid transforms: R (N,3,3), t (N,3), P (N,3) -> R @ P + t."""
    return np.einsum("nij,nj->ni", R, P) + t


def _inverse_transform(R: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per-point inverse: R.T @ (P - t)."""
    return np.einsum("nji,nj->ni", R, P - t)


def colorize(
    log: DriveLog,
    calib: Calibration,
    pose_at: PoseFn,
    *,
    camera: str | None = None,
    max_dt_s: float = 0.1,
    bilinear: bool = True,
    threads: int = 2,
) -> Cloud:
    """Every laser return of ``log`` placed in the world and coloured (see module doc).

    ``calib`` gives the camera (``camera``, default the log's camera) with its
    ``camera_to_laser`` and ``time_offset_s`` (camera time minus laser time), and
    ``laser_to_vehicle`` (identity when absent). ``pose_at`` maps host ns to vehicle
    poses. A point is coloured by its nearest frame in time when that frame is within
    ``max_dt_s`` s and sees it. JPEGs are decoded once each, on ``threads`` threads.
    """
    cam = calib.camera(camera if camera is not None else (log.camera or None))
    l2v = calib.laser_to_vehicle if calib.laser_to_vehicle is not None else Rigid.identity()
    # the points and their times
    valid = np.isfinite(log.ranges)
    scan_idx, step = np.nonzero(valid)
    r = log.ranges[scan_idx, step].astype(np.float64)
    a = log.angle_min + log.angle_increment * step
    P_laser = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)
    time_ns = sync.point_times_ns(log.scan_ns[scan_idx], log.time_increment, step)
    # placed at their own time
    Rv, tv = pose_at(time_ns)
    P_vehicle = l2v.apply(P_laser)
    xyz = _transform(Rv, tv, P_vehicle)
    Rs, ts = pose_at(log.scan_ns)
    scan_origin = _transform(Rs, ts, np.broadcast_to(l2v.translation, ts.shape))
    cam_axis_vehicle = (l2v @ cam.camera_to_laser).rotation[:, 2]
    view = np.einsum("nij,j->ni", Rs, cam_axis_vehicle).mean(axis=0)
    view_axis = view / max(float(np.linalg.norm(view)), 1e-12)

    # the nearest frame of each point, in the laser's time
    n = time_ns.size
    rgb = np.zeros((n, 3), dtype=np.uint8)
    coloured = np.zeros(n, dtype=bool)
    dt_s = np.full(n, np.nan, dtype=np.float32)
    frames_used = frames_failed = 0
    if log.n_frames:
        frame_ns = log.frame_ns - round(cam.time_offset_s * 1e9)
        # by time alone: the driver's sequence numbers restart when the camera reconnects
        pairing = sync.pair_frames(time_ns, frame_ns)
        near = pairing.nearest
        candidate = np.flatnonzero((near >= 0) & (np.abs(pairing.dt_s) <= max_dt_s))
        order = candidate[np.argsort(near[candidate], kind="stable")]
        used, first, counts = np.unique(near[order], return_index=True, return_counts=True)
        # every candidate point into the laser frame at its frame's instant
        Rf, tf = pose_at(frame_ns[used])
        k = np.repeat(np.arange(used.size), counts)
        P_lf = l2v.inverse().apply(_inverse_transform(Rf[k], tf[k], xyz[order]))
        bgr = np.zeros((order.size, 3), dtype=np.uint8)
        seen = np.zeros(order.size, dtype=bool)
        images = views.decoded_frames(log.jpegs, used, threads)
        for lo, count, image in zip(first, counts, images, strict=True):
            if image is None:
                frames_failed += 1
                continue
            frames_used += 1
            hi = lo + count
            bgr[lo:hi], seen[lo:hi] = projection.colorize(
                P_lf[lo:hi], cam.model, cam.camera_to_laser, image, bilinear=bilinear
            )
        hit = order[seen]
        rgb[hit] = bgr[seen][:, ::-1]
        coloured[hit] = True
        dt_s[hit] = pairing.dt_s[hit]
    intensity = log.intensities[scan_idx, step]
    return Cloud(
        xyz=xyz,
        rgb=rgb,
        coloured=coloured,
        time_ns=time_ns,
        scan=scan_idx.astype(np.uint32),
        step=step.astype(np.uint32),
        intensity=intensity.astype(np.float32),
        dt_s=dt_s,
        scan_origin=scan_origin,
        view_axis=view_axis,
        clock=log.clock,
        frames=log.n_frames,
        frames_used=frames_used,
        frames_failed=frames_failed,
    )


# --- writing ---------------------------------------------------------------------------
