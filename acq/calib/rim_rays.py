"""The rim of a fisheye image circle along rays from a first centre, to a fraction of a
pixel: where the lightly blurred intensity falls fastest, accepted only with a dark
outside and a brighter inside; the sub-pixel estimator of :mod:`acq.calib.image_circle`
fits a circle to these points."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from acq.calib.circle_fit import ImageCircle

__all__ = ["RayEdges", "ray_edges"]


@dataclass(frozen=True)
class RayEdges:
    """The rim points found along rays, and how many rays were dropped and why."""

    points: np.ndarray  # (N,2) kept edge points
    cast: int
    off_sensor: int
    saturated: int
    no_edge: int


def ray_edges(
    gray: np.ndarray,
    guess: ImageCircle,
    black: float,
    noise: float,
    n_rays: int = 720,
    window_px: float | None = None,
    step_px: float = 0.25,
    blur_px: float = 1.0,
    saturation: float = 250.0,
) -> RayEdges:
    """Sub-pixel rim points along ``n_rays`` rays from the guess's centre.

    On each ray, within ``window_px`` of the guessed rim, the rim is the outermost strong
    minimum of the radial derivative of the image blurred by ``blur_px`` (parabolic
    interpolation between samples ``step_px`` apart), accepted only when the image beyond
    it is dark (near the black level) and the inside brighter than the noise. Rays whose
    window leaves the sensor, or that cross saturated pixels near the rim, are dropped.
    """
    h, w = gray.shape
    window = max(10.0, 0.05 * guess.radius) if window_px is None else window_px
    g = cv2.GaussianBlur(gray, (0, 0), blur_px)
    phi = np.arange(n_rays) * (2.0 * math.pi / n_rays)
    r_e = guess.radius_at(phi)
    s = np.arange(-window, window + step_px / 2, step_px)
    radii = r_e[:, None] + s[None, :]
    X = guess.cx + radii * np.cos(phi)[:, None]
    Y = guess.cy + radii * np.sin(phi)[:, None]
    on_sensor = np.all((X >= 1) & (X <= w - 2) & (Y >= 1) & (Y <= h - 2), axis=1)
    Xf, Yf = X.astype(np.float32), Y.astype(np.float32)
    prof = cv2.remap(g, Xf, Yf, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    raw = cv2.remap(gray, Xf, Yf, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    prof = prof.astype(np.float64)
    d = np.zeros_like(prof)
    d[:, 1:-1] = (prof[:, 2:] - prof[:, :-2]) / (2.0 * step_px)
    # noise of the derivative of the blurred, interpolated image (about)
    d_noise = noise / (blur_px**2 * math.sqrt(8.0 * math.pi))
    strongest = d.min(axis=1)
    strong = d <= np.minimum(0.35 * strongest, -4.0 * d_noise)[:, None]
    local_min = np.zeros_like(strong)
    local_min[:, 1:-1] = (d[:, 1:-1] <= d[:, :-2]) & (d[:, 1:-1] < d[:, 2:])
    cand = strong & local_min
    cand[:, :2] = cand[:, -2:] = False
    has = cand.any(axis=1)
    m = len(s)
    k = m - 1 - np.argmax(cand[:, ::-1], axis=1)  # outermost candidate
    k = np.clip(k, 1, m - 2)
    rows = np.arange(n_rays)
    d0, d1, d2 = d[rows, k - 1], d[rows, k], d[rows, k + 1]
    den = d0 - 2.0 * d1 + d2
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(den > 0, 0.5 * (d0 - d2) / den, 0.0)
    frac = np.clip(frac, -0.5, 0.5)
    r_edge = r_e + s[k] + frac * step_px
    # dark outside, bright inside
    gap = max(3.0, 2.5 * blur_px) / step_px
    idx = np.arange(m)[None, :]
    outside = idx >= (k + gap)[:, None]
    inside = (idx <= (k - gap)[:, None]) & (idx >= (k - 3 * gap)[:, None])
    out_max = np.max(np.where(outside, prof, -np.inf), axis=1)
    n_in = inside.sum(axis=1)
    in_mean = np.where(
        n_in > 0, np.sum(np.where(inside, prof, 0.0), axis=1) / np.maximum(n_in, 1), -np.inf
    )
    contrast = in_mean - black
    dark = out_max <= black + np.maximum(4.0 * noise / blur_px, 0.25 * contrast)
    bright = contrast >= np.maximum(4.0 * noise / blur_px, 3.0)
    near = np.abs(idx - k[:, None]) <= gap * 2
    saturated = np.any(near & (raw >= saturation), axis=1)
    ok = has & dark & bright
    keep = on_sensor & ~saturated & ok
    pts = np.stack([guess.cx + r_edge * np.cos(phi), guess.cy + r_edge * np.sin(phi)], axis=1)[keep]
    return RayEdges(
        points=pts,
        cast=n_rays,
        off_sensor=int(np.sum(~on_sensor)),
        saturated=int(np.sum(on_sensor & saturated)),
        no_edge=int(np.sum(on_sensor & ~saturated & ~ok)),
    )
