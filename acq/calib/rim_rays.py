"""The rim of a fisheye image circle along rays from a first centre, to a fraction of a
pixel: where the lightly blurred intensity falls fastest, accepted only with a dark outside,
or one darker than halfway that does not brighten again further out (a veiling-glare halo
fading outwards: such points are flagged), and a brighter inside; the sub-pixel estimator
of :mod:`acq.calib.image_circle` fits a circle to these points.

A rim beside clipped (saturated) pixels is kept: the fall from the clipped inside to the
dark outside still locates the rim (a clip that ends before the edge's midpoint leaves the
steepest fall where it was; a stronger one moves it outwards by at most the edge's blur).
Only saturated pixels *outside* the edge (bloom or an overlay past the rim) drop a ray.
"""

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
    clipped: np.ndarray  # (N,) bool: the point has saturated pixels right inside it
    haloed: np.ndarray  # (N,) bool: its outside is a fading halo, not dark at once
    cast: int
    off_sensor: int  # too little of the ray's window on the sensor
    saturated: int  # saturated pixels outside the edge found
    no_edge: int


def _runs_ok(valid: np.ndarray, before: int, after: int) -> np.ndarray:
    """(R,M) bool: sample k has ``before`` valid samples before it and ``after`` after it
    (inclusive of k), all valid."""
    bad = np.concatenate([np.zeros((len(valid), 1)), np.cumsum(~valid, axis=1)], axis=1)
    m = valid.shape[1]
    k = np.arange(m)
    lo = np.clip(k - before, 0, m)
    hi = np.clip(k + after + 1, 0, m)
    ok = (bad[:, hi] - bad[:, lo]) == 0
    ok &= (k - before >= 0) & (k + after + 1 <= m)
    return np.asarray(ok)


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
    border_px: float = 8.0,
) -> RayEdges:
    """Sub-pixel rim points along rays from the guess's centre: ``n_rays`` of them, or more
    so that they are at most 1 px apart on the rim.

    On each ray, within ``window_px`` of the guessed rim, the rim is the outermost strong
    minimum (a fifth of the ray's steepest fall or more: a soft rim falls less steeply
    than a scene edge inside it) of the radial derivative of the image blurred by
    ``blur_px`` (parabolic interpolation between samples ``step_px`` apart) whose
    surroundings lie on the sensor,
    accepted only when the image beyond it is darker than halfway to the inside's level
    and does not brighten again further out, and the inside is brighter than the noise.
    Rays with no such stretch on the sensor, or saturated pixels beyond the edge, are
    dropped, and so are edges within ``border_px`` of the sensor's edges (where the
    sensor, not the lens, cuts the disc, and the rim is shaded differently).
    """
    h, w = gray.shape
    window = max(10.0, 0.05 * guess.radius) if window_px is None else window_px
    g = cv2.GaussianBlur(gray, (0, 0), blur_px)
    n = min(max(n_rays, math.ceil(2.0 * math.pi * max(guess.rx, guess.ry))), 8 * n_rays)
    phi = np.arange(n) * (2.0 * math.pi / n)
    r_e = guess.radius_at(phi)
    gap = math.ceil(max(3.0, 2.5 * blur_px) / step_px)
    # the window, and beyond it the inside (3 gaps) and outside (2 gaps) an edge needs
    s = np.arange(-window - 3 * gap * step_px, window + (2 * gap + 0.5) * step_px, step_px)
    radii = r_e[:, None] + s[None, :]
    X = guess.cx + radii * np.cos(phi)[:, None]
    Y = guess.cy + radii * np.sin(phi)[:, None]
    valid = (X >= 1) & (X <= w - 2) & (Y >= 1) & (Y <= h - 2)
    Xf, Yf = X.astype(np.float32), Y.astype(np.float32)
    prof = cv2.remap(g, Xf, Yf, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    raw = cv2.remap(gray, Xf, Yf, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    prof = prof.astype(np.float64)
    m = len(s)
    d = np.zeros_like(prof)
    d[:, 1:-1] = (prof[:, 2:] - prof[:, :-2]) / (2.0 * step_px)
    # an edge needs its inside and outside on the sensor
    room = _runs_ok(valid, 3 * gap, 2 * gap) & (np.abs(s) <= window + 1e-9)[None, :]
    b = border_px - 0.5
    room &= (X >= b) & (X <= w - 1 - b) & (Y >= b) & (Y <= h - 1 - b)
    on_sensor = room.any(axis=1)
    # noise of the derivative of the blurred, interpolated image (about)
    d_noise = noise / (blur_px**2 * math.sqrt(8.0 * math.pi))
    strongest = np.where(room, d, np.inf).min(axis=1)
    strong = d <= np.minimum(0.2 * strongest, -4.0 * d_noise)[:, None]
    local_min = np.zeros_like(strong)
    local_min[:, 1:-1] = (d[:, 1:-1] <= d[:, :-2]) & (d[:, 1:-1] < d[:, 2:])
    cand = strong & local_min & room
    has = cand.any(axis=1)
    k = m - 1 - np.argmax(cand[:, ::-1], axis=1)  # outermost candidate
    k = np.clip(k, 1, m - 2)
    rows = np.arange(n)
    d0, d1, d2 = d[rows, k - 1], d[rows, k], d[rows, k + 1]
    den = d0 - 2.0 * d1 + d2
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(den > 0, 0.5 * (d0 - d2) / den, 0.0)
    frac = np.clip(frac, -0.5, 0.5)
    r_edge = r_e + s[k] + frac * step_px
    idx = np.arange(m)[None, :]
    outside = (idx >= (k + gap)[:, None]) & valid
    inside = (idx <= (k - gap)[:, None]) & (idx >= (k - 3 * gap)[:, None])
    out_first = prof[rows, np.clip(k + gap, 0, m - 1)]
    out_max = np.max(np.where(outside, prof, -np.inf), axis=1)
    n_in = inside.sum(axis=1)
    in_mean = np.where(
        n_in > 0, np.sum(np.where(inside, prof, 0.0), axis=1) / np.maximum(n_in, 1), -np.inf
    )
    contrast = in_mean - black
    floor = 4.0 * noise / blur_px
    # dark at once beyond the edge, or a halo: darker than halfway, fading outwards
    dark_now = out_max <= black + np.maximum(floor, 0.25 * contrast)
    dark = dark_now | (
        (out_first <= black + np.maximum(floor, 0.5 * contrast))
        & (out_max <= out_first + np.maximum(floor, 0.1 * contrast))
    )
    bright = contrast >= np.maximum(floor, 3.0)
    beyond = (idx > k[:, None]) & (idx <= (k + 2 * gap)[:, None]) & valid
    saturated = np.any(beyond & (raw >= saturation), axis=1)
    near_in = (idx <= k[:, None]) & (idx >= (k - 2 * gap)[:, None])
    clipped = np.any(near_in & (raw >= saturation), axis=1)
    ok = has & dark & bright
    keep = on_sensor & ~saturated & ok
    pts = np.stack([guess.cx + r_edge * np.cos(phi), guess.cy + r_edge * np.sin(phi)], axis=1)
    return RayEdges(
        points=pts[keep],
        clipped=clipped[keep],
        haloed=~dark_now[keep],
        cast=n,
        off_sensor=int(np.sum(~on_sensor)),
        saturated=int(np.sum(on_sensor & saturated & ok)),
        no_edge=int(np.sum(on_sensor & ~ok)),
    )
