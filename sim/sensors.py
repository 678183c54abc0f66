"""The simulated fisheye camera and laser scanner, with their ground truth.

A frame is rendered instantaneously at its time (the middle of its exposure). A scan
casts step i from the laser's pose at ``t0 + i * time_increment``, so the vehicle's motion
during the scan is in the data. World frame and units as in ``acq.sim.world``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from acq.camera.camera_models import KannalaBrandt
from acq.geometry.transforms import Rigid
from acq.sim.raycast import cast
from acq.sim.world import Rig, Street, Trajectory

__all__ = [
    "FrameTruth",
    "ScanTruth",
    "apply_gains",
    "camera_to_world",
    "laser_to_world",
    "pixel_rays",
    "render_frame",
    "render_frame_truth",
    "render_scan",
    "seen_in_frame",
    "true_pixels",
]

# A point counts as seen by a frame when nothing in the rendered depth at its pixel lies
# nearer than its own distance by more than this (m, plus a share of the distance).
SEEN_TOLERANCE_M = 0.05
SEEN_TOLERANCE_REL = 0.02


@lru_cache(maxsize=8)
def pixel_rays(lens: KannalaBrandt) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame unit rays (M,3) float64 of the pixels inside the image circle
    (theta <= fov/2), and their flat pixel indices (M,) int64 (``v * width + u``).

    Cached per lens: do not modify the arrays."""
    v, u = np.mgrid[0 : lens.height, 0 : lens.width]
    uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    mx = (uv[:, 0] - lens.cx) / lens.fx
    my = (uv[:, 1] - lens.cy) / lens.fy
    rd_max = float(lens.distort_theta(np.array([lens.theta_max]))[0])
    inside = np.hypot(mx, my) <= rd_max
    rays = np.ascontiguousarray(lens.unproject(uv[inside]))
    return rays, np.flatnonzero(inside).astype(np.int64)


def camera_to_world(trajectory: Trajectory, rig: Rig, t: float, camera: str | None = None) -> Rigid:
    """Camera ``camera``'s (None: the rig's first) optical frame -> world at time t (s)."""
    return trajectory.pose(t) @ rig.camera_to_vehicle(camera)


def laser_to_world(
    trajectory: Trajectory, rig: Rig, ts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Laser -> world at times ts (s): rotations (N,3,3) and origins (N,3) m."""
    Rv, tv = trajectory.poses(ts)
    Rl = rig.laser_to_vehicle.rotation
    tl = rig.laser_to_vehicle.translation
    return Rv @ Rl, np.einsum("nij,j->ni", Rv, tl) + tv


@dataclass(frozen=True)
class FrameTruth:
    """A rendered frame and its truth, per pixel (pixel centres' rays)."""

    t: float  # s, the middle of the exposure
    image: np.ndarray  # (H,W,3) uint8 BGR, black outside the image circle
    depth: np.ndarray  # (H,W) float64 m along the ray; +inf sky, NaN outside the circle
    material: np.ndarray  # (H,W) uint8 acq.sim.world.Material, raycast.NO_RAY outside
    gains: np.ndarray  # (3,) BGR: the camera's exposure and white balance at t


def render_frame_truth(
    street: Street, trajectory: Trajectory, rig: Rig, t: float, camera: str | None = None
) -> FrameTruth:
    """Camera ``camera``'s (None: the rig's first) fisheye view at time t (s) with
    per-pixel depth and material: the surface colours times the camera's gains at t
    (:class:`acq.sim.world.Photometry`), rounded and clipped to 0-255."""
    cam = rig.camera(camera)
    lens = cam.lens
    rays, index = pixel_rays(lens)
    pose = camera_to_world(trajectory, rig, t, camera)
    hit = cast(street, pose.translation, rays, pose.rotation, index, lens.width * lens.height)
    shape = (lens.height, lens.width)
    image = hit.colour.reshape(*shape, 3)
    gains = cam.photometry.gains(t)
    if not cam.photometry.constant:
        image = apply_gains(image, gains)
    return FrameTruth(
        t=float(t),
        image=image,
        depth=hit.distance.reshape(shape),
        material=hit.material.reshape(shape),
        gains=gains,
    )


def apply_gains(bgr: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``bgr`` (..., 3) uint8 times ``gains`` (3,), rounded and clipped: uint8."""
    out = np.asarray(bgr, dtype=np.float32) * np.asarray(gains, dtype=np.float32)
    clipped: np.ndarray = np.clip(out + 0.5, 0, 255).astype(np.uint8)
    return clipped


def render_frame(
    street: Street, trajectory: Trajectory, rig: Rig, t: float, camera: str | None = None
) -> np.ndarray:
    """Camera ``camera``'s (None: the rig's first) fisheye image at time t (s): (H,W,3)
    uint8 BGR, black outside the image circle."""
    return render_frame_truth(street, trajectory, rig, t, camera).image


@dataclass(frozen=True)
class ScanTruth:
    """One simulated scan and its truth.

    ``ranges`` are what the device reports (m, noisy, float32; +inf no echo or beyond
    ``max_range``, -inf closer than ``min_range``). ``points`` are the noise-free world hit
    points (m, NaN where there is no echo), ``colours`` the BGR surface colour there (sky
    colour where there is none), ``material`` the ``acq.sim.world.Material`` id.
    """

    t0: float  # s, time of step 0
    angles: np.ndarray  # (N,) rad, REP-103 laser frame
    times: np.ndarray  # (N,) s, t0 + i * time_increment
    ranges: np.ndarray  # (N,) float32 m
    true_ranges: np.ndarray  # (N,) float64 m, noise-free, +inf for no hit
    points: np.ndarray  # (N,3) float64 world m
    colours: np.ndarray  # (N,3) uint8 BGR
    material: np.ndarray  # (N,) uint8
    origins: np.ndarray  # (N,3) float64 world m, the laser centre at each step


def render_scan(
    street: Street, trajectory: Trajectory, rig: Rig, t0: float, rng: np.random.Generator
) -> ScanTruth:
    """One scan starting at t0 (s), each step cast from the laser pose at its own time.

    Range noise is Gaussian with ``rig.range_noise`` m (drawn from ``rng``; set the rig's
    noise to 0 for exact ranges).
    """
    angles = rig.angles
    times = t0 + rig.time_increment * np.arange(rig.n_steps)
    Rw, origins = laser_to_world(trajectory, rig, times)
    d_laser = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    dirs = np.einsum("nij,nj->ni", Rw, d_laser)
    hit = cast(street, origins, dirs)
    true = hit.distance
    noisy = true + rng.normal(0.0, rig.range_noise, true.shape) if rig.range_noise else true
    # the device applies its limits to what it measured, noise included
    with np.errstate(invalid="ignore"):
        echo = np.isfinite(true) & (noisy <= rig.max_range)
        ranges = np.where(echo, noisy, np.inf)
        ranges = np.where(echo & (noisy < rig.min_range), -np.inf, ranges)
    points = np.where(echo[:, None], origins + dirs * np.where(echo, true, 0.0)[:, None], np.nan)
    return ScanTruth(
        t0=float(t0),
        angles=angles,
        times=times,
        ranges=ranges.astype(np.float32),
        true_ranges=true,
        points=points,
        colours=hit.colour,
        material=hit.material,
        origins=origins,
    )


def return_strength(
    ranges: np.ndarray,
    colours: np.ndarray,
    rng: np.random.Generator | None = None,
    noise: float = 0.0,
) -> np.ndarray:
    """A plausible return strength (device units, float64; 0 without an echo) of hits at
    ``ranges`` (m) on surfaces of BGR ``colours`` (N,3) uint8: brighter and nearer
    surfaces return more; ``noise`` a relative Gaussian spread drawn from ``rng``."""
    ranges = np.asarray(ranges, dtype=np.float64)
    brightness = np.asarray(colours, dtype=np.float64).mean(axis=-1) / 255.0
    with np.errstate(divide="ignore", invalid="ignore"):
        strength = 8000.0 * (0.2 + brightness) / np.maximum(ranges, 1.0) ** 0.5
    if noise and rng is not None:
        strength = strength * (1.0 + rng.normal(0.0, noise, strength.shape))
    return np.where(np.isfinite(ranges), np.maximum(strength, 0.0), 0.0)


def true_pixels(
    world_points: np.ndarray,
    trajectory: Trajectory,
    rig: Rig,
    t: float,
    camera: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Where world points (N,3) m fall in the frame at time t with the true lens:
    (N,2) px and (N,) valid (inside the lens's fov and the image; occlusion not checked)."""
    P_cam = camera_to_world(trajectory, rig, t, camera).inverse().apply(world_points)
    return rig.camera(camera).lens.project(P_cam)


def seen_in_frame(
    world_points: np.ndarray,
    frame: FrameTruth,
    trajectory: Trajectory,
    rig: Rig,
    camera: str | None = None,
) -> np.ndarray:
    """Whether camera ``camera`` (None: the rig's first) really sees world points (N,3)
    m in ``frame`` (rendered through it at ``frame.t``): (N,) bool.

    Seen: a finite point inside the lens's fov and the image, and not hidden: its
    distance from the camera is at most the frame's depth at its true pixel plus
    ``SEEN_TOLERANCE_M`` + ``SEEN_TOLERANCE_REL`` times the distance, the depth being the
    farthest of the 3x3 pixels around (so a point beside a depth edge does not flicker
    between seen and hidden with sub-pixel motion)."""
    P = np.asarray(world_points, dtype=np.float64).reshape(-1, 3)
    P_cam = camera_to_world(trajectory, rig, frame.t, camera).inverse().apply(P)
    uv, seen = rig.camera(camera).lens.project(P_cam)
    seen &= np.isfinite(P_cam).all(axis=1)
    idx = np.flatnonzero(seen)
    if idx.size == 0:
        return seen
    height, width = frame.depth.shape
    u = np.rint(uv[idx, 0]).astype(np.int64)
    v = np.rint(uv[idx, 1]).astype(np.int64)
    d = np.arange(-1, 2)
    uu = np.clip(u[:, None, None] + d[None, None, :], 0, width - 1)
    vv = np.clip(v[:, None, None] + d[None, :, None], 0, height - 1)
    around = frame.depth[vv, uu].reshape(idx.size, -1)
    farthest = np.where(np.isnan(around), -np.inf, around).max(axis=1)  # NaN: off the circle
    dist = np.linalg.norm(P_cam[idx], axis=1)
    seen[idx] = dist <= farthest + SEEN_TOLERANCE_M + SEEN_TOLERANCE_REL * dist
    return seen
