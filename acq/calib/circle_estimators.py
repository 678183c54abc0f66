"""The image circle's estimators, each on one grey image (pixel centres at integers, as
in OpenCV): the paper's three (:func:`barycentre` of the disc, :func:`canny_fit` of the
rim's Canny edge pixels, :func:`hough`) and the sub-pixel one (:func:`subpixel`: the rim
along rays, :mod:`acq.calib.rim_rays`, fitted by :func:`rim_fit`). Each returns an
:class:`Estimate` with notes where it is not to be trusted on that image;
:mod:`acq.calib.image_circle` runs them on one or several images and compares them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from acq.calib.circle_fit import ImageCircle, fit_conic, ransac_fit, refine_fit, robust_fit
from acq.calib.rim_rays import RayEdges, ray_edges

__all__ = [
    "Estimate",
    "barycentre",
    "canny_fit",
    "canny_points",
    "hough",
    "rim_fit",
    "subpixel",
]

_HOUGH_SPREAD_PX = 1.5  # a Hough vote peak wider than this does not fix the centre
_CANNY_RMS_PX = 1.0  # Canny pixels scattering more than this do not fix the rim


@dataclass(frozen=True)
class Estimate:
    """One estimator's circle, with the count of points it used and its fit quality."""

    name: str
    circle: ImageCircle
    n_points: int  # edge points in the fit (disc pixels for the barycentre)
    rms_px: float = math.nan  # RMS radial residual of the fitted points
    sigma_px: tuple[float, ...] = ()  # standard errors of (cx, cy, rx[, ry]) from the fit
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {**self.circle.to_dict(), "n_points": self.n_points}
        if math.isfinite(self.rms_px):
            d["rms_px"] = round(self.rms_px, 4)
        if self.sigma_px:
            d["sigma_px"] = [round(float(s), 4) for s in self.sigma_px]
        if self.notes:
            d["notes"] = list(self.notes)
        return d


# --- the paper's estimators -------------------------------------------------------------


def barycentre(mask: np.ndarray, ellipse: bool = False) -> Estimate:
    """Centre of the disc pixels; radius from the area (circle) or from the second moments
    (ellipse: a uniform ellipse has variance rx²/4 along u)."""
    v, u = np.nonzero(mask)
    if len(u) < 10:
        raise ValueError("no disc found: the image is black")
    cx, cy = float(u.mean()), float(v.mean())
    if ellipse:
        rx, ry = 2.0 * float(u.std()), 2.0 * float(v.std())
    else:
        rx = ry = math.sqrt(len(u) / math.pi)
    return Estimate("barycentre", ImageCircle(cx, cy, rx, ry), len(u))


def _off_border(
    points: npt.NDArray[np.float64], width: int, height: int, margin: float
) -> npt.NDArray[np.bool_]:
    x, y = points[:, 0], points[:, 1]
    return (x >= margin) & (x <= width - 1 - margin) & (y >= margin) & (y <= height - 1 - margin)


def canny_points(
    gray: np.ndarray, masks: Sequence[np.ndarray], band_px: int = 10
) -> npt.NDArray[np.float64]:
    """(N,2) Canny edge pixels of the image within ``band_px`` of the rim of one of the
    ``masks`` (the disc at a low and at a mid threshold: a glare halo outside the rim
    moves the first outwards, a dark scene inside it the second inwards), without those
    near the image border (where the disc is cut by the sensor, not by the lens)."""
    smooth = cv2.GaussianBlur(gray, (0, 0), 1.5)
    img8 = np.clip(smooth, 0, 255).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    mask = masks[0]
    rim = np.zeros(mask.shape, np.uint8)
    for m in masks:
        m8 = m.astype(np.uint8)
        rim = np.maximum(rim, cv2.morphologyEx(m8, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)))
    # the image border is not the rim
    h, w = mask.shape
    rim[:2], rim[-2:], rim[:, :2], rim[:, -2:] = 0, 0, 0, 0
    band = cv2.dilate(rim, kernel) > 0
    gx = cv2.Sobel(img8, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(img8, cv2.CV_32F, 0, 1)
    mag = np.hypot(gx, gy)[band]
    if mag.size == 0:
        return np.zeros((0, 2))
    hi = max(float(np.percentile(mag, 90)) * 0.5, 10.0)
    edges = cv2.Canny(img8, 0.4 * hi, hi, L2gradient=True) > 0
    v, u = np.nonzero(edges & band)
    pts = np.stack([u, v], axis=1).astype(np.float64)
    return pts[_off_border(pts, w, h, band_px + 2.0)]


def canny_fit(
    gray: np.ndarray, mask: np.ndarray, ellipse: bool = False, points: np.ndarray | None = None
) -> tuple[Estimate, np.ndarray]:
    """Least-squares circle (ellipse) through the rim's Canny edge pixels (paper: "best
    fitting circle by mean squared estimation"), with 3-sigma clipping of stray scene edges
    from the RANSAC inliers on (scene and overlay edges can outnumber a short rim's).
    Returns the estimate and its edge points (N,2)."""
    pts = canny_points(gray, [mask]) if points is None else points
    if len(pts) < 10:
        raise ValueError("too few rim edge pixels for a circle fit")
    keep = ransac_fit(pts, 2.0, ellipse)
    circle = fit_conic(pts[keep], ellipse)
    for _ in range(3):
        circle, res, sigma = refine_fit(pts[keep], circle, ellipse)
        res = circle.residuals(pts)
        s = float(np.std(res[keep]))
        keep = np.abs(res) < max(3.0 * s, 1.0)
    circle, res, sigma = refine_fit(pts[keep], circle, ellipse)
    rms = float(np.sqrt(np.mean(res**2)))
    notes: tuple[str, ...] = ()
    if rms > _CANNY_RMS_PX:
        notes = (f"its edge pixels scatter by {rms:.1f} px RMS about the circle (a soft rim)",)
    return Estimate("canny_fit", circle, int(keep.sum()), rms, sigma, notes), pts


def hough(
    gray: np.ndarray,
    points: np.ndarray,
    radius_range: tuple[float, float],
    aspect: float = 1.0,
) -> Estimate:
    """Hough circle transform of the rim's edge pixels (paper [13]), whole pixels.

    Each edge pixel votes for the centres along its gradient at every radius in
    ``radius_range`` (px); the most voted centre wins, then the most common distance from
    it to the edge pixels is the radius. ``aspect`` (ry / rx, for non-square pixels)
    stretches u first so the ellipse becomes a circle, and the answer back.
    """
    if len(points) < 10:
        raise ValueError("too few rim edge pixels for the Hough transform")
    smooth = cv2.GaussianBlur(gray, (0, 0), 3.0)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1)
    iu, iv = points[:, 0].astype(np.intp), points[:, 1].astype(np.intp)
    g = np.stack([gx[iv, iu] / aspect, gy[iv, iu]], axis=1).astype(np.float64)
    g /= np.maximum(np.hypot(g[:, 0], g[:, 1]), 1e-12)[:, None]  # towards the bright inside
    pts = np.stack([(points[:, 0] + 0.5) * aspect - 0.5, points[:, 1]], axis=1)
    h, w = gray.shape
    w = math.ceil(w * aspect)
    r0, r1 = (r * aspect for r in radius_range)
    radii = np.arange(math.floor(r0), math.ceil(r1) + 1.0)
    centres = pts[:, None, :] + radii[None, :, None] * g[:, None, :]
    cu = np.rint(centres[..., 0]).astype(np.intp).ravel()
    cv = np.rint(centres[..., 1]).astype(np.intp).ravel()
    ok = (cu >= 0) & (cu < w) & (cv >= 0) & (cv < h)
    votes = np.bincount(cv[ok] * w + cu[ok], minlength=h * w).reshape(h, w)
    acc = cv2.GaussianBlur(votes.astype(np.float32), (0, 0), 3.0)
    v, u = np.unravel_index(int(np.argmax(acc)), acc.shape)
    dist = np.hypot(pts[:, 0] - u, pts[:, 1] - v)
    hist = np.bincount(np.rint(dist).astype(np.intp))
    lo, hi = int(radii[0]), min(int(radii[-1]) + 1, len(hist))
    if hi <= lo:
        raise ValueError("the Hough transform found no circle")
    r = float(lo + int(np.argmax(hist[lo:hi])))
    cx = (u + 0.5) / aspect - 0.5
    support = int(hist[int(r)])
    # how far the votes within 10 % of the peak's spread: the centre's uncertainty
    _, peak = cv2.connectedComponents((acc >= 0.9 * acc[v, u]).astype(np.uint8))
    pv, pu = np.nonzero(peak == peak[v, u])
    eu, ev = float(np.abs(pu - u).max()) / aspect, float(np.abs(pv - v).max())
    notes: tuple[str, ...] = ()
    if max(eu, ev) > _HOUGH_SPREAD_PX:
        notes = (f"its vote peak spreads over +-{eu:.0f} px along u, +-{ev:.0f} px along v",)
    circle = ImageCircle(float(cx), float(v), r / aspect, r)
    return Estimate("hough", circle, support, sigma_px=(eu, ev), notes=notes)


# --- the sub-pixel estimator ------------------------------------------------------------


def subpixel(
    gray: np.ndarray,
    guess: ImageCircle,
    black: float,
    noise: float,
    ellipse: bool = False,
    n_rays: int = 720,
    passes: int = 2,
    rng: np.random.Generator | None = None,
) -> tuple[Estimate, np.ndarray, np.ndarray, RayEdges]:
    """The sub-pixel rim of one image (see :func:`ray_edges`), RANSAC and geometric fit,
    repeated from the refined centre. Returns the estimate, the edge points, their inlier
    mask and the last pass's ray counts."""
    rng = np.random.default_rng(0) if rng is None else rng
    circle = guess
    for i in range(passes):
        rays = ray_edges(gray, circle, black, noise, n_rays, window_px=None if i == 0 else 6.0)
        if len(rays.points) < 8:
            raise ValueError(
                f"only {len(rays.points)} of {rays.cast} rays from the centre of its edges "
                "found a rim (a sharp fall to a dark surround)"
            )
        circle, inl, res, sigma = rim_fit(rays.points, rays.haloed, ellipse, rng)
    rms = float(np.sqrt(np.mean(res[inl] ** 2)))
    est = Estimate("subpixel", circle, int(inl.sum()), rms, sigma)
    return est, rays.points, inl, rays


def rim_fit(
    points: np.ndarray, haloed: np.ndarray, ellipse: bool, rng: np.random.Generator
) -> tuple[ImageCircle, np.ndarray, np.ndarray, tuple[float, ...]]:
    """The circle (ellipse) of sub-pixel rim points (:func:`robust_fit`), from the points
    with a dark outside when they are enough (at least 30 and a quarter of all), then
    with every point within 1.5 px of it: a soft vignetted rim may show a scene edge
    inside it with a halo-like fall beyond, a real halo only shows where the rim is.
    Returns circle, inliers, residuals of all points, standard errors."""
    dark = ~haloed
    n_dark = int(dark.sum())
    if n_dark < max(30, len(points) // 4) or n_dark == len(points):
        return robust_fit(points, ellipse, 1.5, rng)
    circle, inl_dark, _, sigma = robust_fit(points[dark], ellipse, 1.5, rng)
    inl = np.abs(circle.residuals(points)) < 1.5
    inl[dark] = inl_dark
    circle, _, sigma = refine_fit(points[inl], circle, ellipse)
    return circle, inl, circle.residuals(points), sigma
