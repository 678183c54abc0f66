"""Simulated camera–laser calibration data with the truth (paper §3.2).

A 1 m x 1 m board carrying a 10 x 8 checkerboard of 0.1 m squares (9 x 7 inner corners,
0.1 m white margin above and below) is placed at 1–4 m from the scanner, near the scan
plane, on the camera's side, facing the camera and tilted up to ±30 degrees about each of
its axes. For each pose:

- the laser points: the scan plane (laser z = 0) cut by the board, one ray every
  ``rig.angle_increment`` (0.25 degrees), Gaussian range noise (10 mm);
- the camera's plane: the inner corners projected with the rig's fisheye lens
  (``acq.sim.world.default_rig``), Gaussian pixel noise (0.2 px), then the board's pose
  estimated by :func:`acq.calib.board_pose.board_pose_from_corners` — so the plane (n, d) has
  the errors of a real detection.

Outlier poses (``n_outliers``) are boards that moved between the image and the scan:
the camera sees the board turned by 5–15 degrees and shifted by 5–15 cm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acq.calib.board_pose import BoardFit, BoardPose, board_pose_from_corners
from acq.camera.camera_models import CameraModel
from acq.geometry.rotations import matrix_from_rotvec, rotation_from_euler
from acq.geometry.transforms import Rigid
from acq.sim.world import Rig, default_rig

__all__ = ["BoardData", "Checkerboard", "laser_points_on_board", "simulate"]


@dataclass(frozen=True)
class Checkerboard:
    """A rigid board (``width`` x ``height`` m, frame at its centre, z = its normal)
    carrying ``cols`` x ``rows`` squares of ``square`` m, centred."""

    cols: int = 10
    rows: int = 8
    square: float = 0.1
    width: float = 1.0
    height: float = 1.0

    def corners(self) -> np.ndarray:
        """((cols-1)*(rows-1), 3) inner corners in the board frame (m), row by row."""
        xs = (np.arange(1, self.cols) - self.cols / 2) * self.square
        ys = (np.arange(1, self.rows) - self.rows / 2) * self.square
        X, Y = np.meshgrid(xs, ys)
        return np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])


@dataclass(frozen=True)
class BoardData:
    """Simulated poses with the truth: ``truth`` is camera_to_laser (P_laser = R P_cam + t),
    ``boards[i]`` the board_to_laser the scanner saw, ``fits[i]`` the camera's board
    estimate (None with ``true_planes``), ``outliers`` the indices of moved boards."""

    poses: list[BoardPose]
    truth: Rigid
    boards: list[Rigid]
    fits: list[BoardFit | None]
    outliers: tuple[int, ...]
    lens: CameraModel
    board: Checkerboard


def laser_points_on_board(
    rig: Rig,
    board: Checkerboard,
    board_to_laser: Rigid,
    rng: np.random.Generator,
    noise: float,
    scans: int = 1,
) -> np.ndarray:
    """(N,3) laser-frame points (z = 0) where the scan rays hit the board, ranges noisy
    (``noise`` m; with ``scans`` > 1 the per-beam median of that many noisy scans)."""
    a = rig.angles
    dirs = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    w = board_to_laser.rotation[:, 2]
    C = board_to_laser.translation
    denom = dirs @ w
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(np.abs(denom) > 1e-9, (C @ w) / denom, np.nan)
    hit = np.isfinite(s) & (s > rig.min_range) & (s < rig.max_range)
    local = (s[:, None] * dirs - C) @ board_to_laser.rotation
    hit &= (np.abs(local[:, 0]) <= board.width / 2) & (np.abs(local[:, 1]) <= board.height / 2)
    n_hit = int(hit.sum())
    if noise > 0:
        s_noisy = s[hit] + np.median(rng.normal(0.0, noise, (max(scans, 1), n_hit)), axis=0)
    else:
        s_noisy = s[hit]
    P: npt.NDArray[np.float64] = s_noisy[:, None] * dirs[hit]
    return P


def _random_rotation(rng: np.random.Generator, lo_deg: float, hi_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return matrix_from_rotvec(axis * math.radians(rng.uniform(lo_deg, hi_deg)))


def simulate(
    n_poses: int = 20,
    seed: int = 0,
    *,
    rig: Rig | None = None,
    board: Checkerboard | None = None,
    pixel_noise: float = 0.2,
    range_noise: float = 0.01,
    distance: tuple[float, float] = (1.0, 4.0),
    max_tilt_deg: float = 30.0,
    bearing_spread_deg: float = 35.0,
    max_offset: float = 0.25,
    n_outliers: int = 0,
    true_planes: bool = False,
    parallel: bool = False,
    min_laser_points: int = 20,
    frames: int = 1,
    scans: int = 1,
) -> BoardData:
    """``n_poses`` board poses (see the module docstring) seen by ``rig`` (default_rig()).

    ``distance`` (m) from the scanner, bearing within ``bearing_spread_deg`` of the camera's
    axis in the scan plane, centre within ``max_offset`` m of the scan plane. With
    ``true_planes`` the planes are exact (no PnP; pixel noise unused); with ``parallel``
    every board has the same orientation (a degenerate set, for tests).

    A still pose seen for a while: with ``frames`` > 1 the corners are the mean of that
    many independent noisy detections, with ``scans`` > 1 each range the per-beam median
    of that many noisy scans (what ``acq calibrate extrinsic`` does with a log).
    """
    rig = rig or default_rig()
    board = board or Checkerboard()
    rng = np.random.default_rng(seed)
    truth = rig.camera_to_laser
    laser_to_camera = truth.inverse()
    cam_pos = truth.translation
    axis = truth.rotation[:, 2]  # optical axis in the laser frame
    bearing0 = math.atan2(axis[1], axis[0])
    obj = board.corners()
    outliers = tuple(sorted(int(i) for i in rng.choice(n_poses, size=n_outliers, replace=False)))
    fixed_tilt = rotation_from_euler(*np.radians(rng.uniform(-10.0, 10.0, 3)))

    poses: list[BoardPose] = []
    boards: list[Rigid] = []
    fits: list[BoardFit | None] = []
    for i in range(n_poses):
        for _attempt in range(1000):
            r = rng.uniform(*distance)
            phi = bearing0 + math.radians(rng.uniform(-bearing_spread_deg, bearing_spread_deg))
            C = np.array([r * math.cos(phi), r * math.sin(phi), rng.uniform(-1, 1) * max_offset])
            # facing the camera (parallel: facing along the optical axis), laser across u
            w0 = -axis if parallel else (cam_pos - C) / np.linalg.norm(cam_pos - C)
            u0 = np.cross([0.0, 0.0, 1.0], w0)
            u0 /= np.linalg.norm(u0)
            B0 = np.column_stack([u0, np.cross(w0, u0), w0])
            if parallel:
                B = B0 @ fixed_tilt
            else:
                tilt = np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, 3))
                B = B0 @ rotation_from_euler(*tilt)
            board_to_laser = Rigid(B, C)
            to_cam = (cam_pos - C) / np.linalg.norm(cam_pos - C)
            if to_cam @ B[:, 2] < math.cos(math.radians(70.0)):
                continue  # seen too obliquely for corner detection
            seen = board_to_laser
            if i in outliers:  # the board moved between the image and the scan
                Rm = _random_rotation(rng, 5.0, 15.0)
                shift = rng.normal(size=3)
                shift *= rng.uniform(0.05, 0.15) / np.linalg.norm(shift)
                seen = Rigid(Rm @ B, C + shift)
            board_to_camera = laser_to_camera @ seen
            uv, valid = rig.lens.project(board_to_camera.apply(obj))
            if not valid.all():
                continue
            pts = laser_points_on_board(rig, board, board_to_laser, rng, range_noise, scans)
            if len(pts) < min_laser_points:
                continue
            break
        else:
            raise RuntimeError("could not place a board in view of both sensors")
        fit: BoardFit | None = None
        if true_planes:
            poses.append(BoardPose.from_board(board_to_camera, pts, id=str(i)))
        else:
            k = max(frames, 1)
            noise = rng.normal(0.0, pixel_noise, (k, *uv.shape)).mean(axis=0)
            noisy = uv + noise if pixel_noise > 0 else uv
            fit = board_pose_from_corners(rig.lens, obj, noisy)
            poses.append(BoardPose.from_fit(fit, pts, id=str(i)))
        boards.append(board_to_laser)
        fits.append(fit)
    return BoardData(poses, truth, boards, fits, outliers, rig.lens, board)
