"""The image circle of a fisheye image: its centre and radius (paper §3.3.2).

Four estimators, each on a grey image (pixel centres at integers, as in OpenCV):

- ``barycentre``: centroid and area of the non-black (filled) disc; the paper's first. It
  assumes a whole disc: biased when the circle is cut by the sensor edges.
- ``canny_fit``: least-squares circle through the Canny edge pixels of the rim, minus those
  on the sensor edges, from their RANSAC inliers on.
- ``hough``: a Hough circle transform of those edge pixels, each voting along its
  gradient (whole pixels; OpenCV's ``HoughCircles`` strays by 10 px on the real images).
- ``subpixel``: along rays from a first centre (:mod:`acq.calib.rim_rays`), the rim is
  where the intensity falls fastest (the extremum of the radial derivative of the lightly
  blurred image, to a fraction of a pixel); rays with no such fall on the sensor, a
  saturated bloom past it or no darker outside are dropped, a rim beside clipped pixels
  is kept, RANSAC rejects the rest of the outliers, and a geometric least squares fit
  (radial distances) gives the circle. Twice, the second time from the refined centre.

The first centre comes from the Canny pixels near the disc's edge at a low threshold and,
separately, at a mid one (a veiling-glare halo moves the first outwards); the sub-pixel
rim from each, the one found along most rays (or one a pixel outside it) wins. A circle
whose rim shows only as arcs in the sensor's corners is found like any other.

With ``ellipse=True`` every estimator fits an axis-aligned ellipse instead (non-square
pixels: semi-axes ``rx`` along u and ``ry`` along v). Several images of the same camera
are combined: their edge points are pooled for the fits, the other estimators averaged.
The curves (:class:`~acq.calib.circle_fit.ImageCircle`) and their fits to edge points
are in :mod:`acq.calib.circle_fit`.

The black level and noise are measured on the darkest part of the image border, not
assumed zero, and the disc threshold sits a few noise sigmas above it, so the paper's
threshold estimators move little with noise; they still move with vignetting and soft
edges (a threshold meets a faded rim further in or out), which the gradient-based
sub-pixel estimator does not. Each estimate carries notes when it is not to be trusted on
an image (a truncated circle's barycentre, a Hough vote peak spread over pixels, Canny
pixels scattered by a soft rim, two sub-pixel rims), and the result warns, per image,
when a fit is more than 1.5 px off the sub-pixel circle, with that note.

An image with no image circle (an ordinary photograph, a uniform or black frame, one too
small, one whose circle covers the whole sensor) raises :class:`ImageCircleError` naming
the image and saying what is missing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from acq.calib.circle_fit import ImageCircle, fit_conic, ransac_fit, refine_fit, robust_fit
from acq.calib.rim_rays import RayEdges, ray_edges
from acq.errors import InputError

__all__ = [
    "ESTIMATORS",
    "MIN_SIDE_PX",
    "CircleResult",
    "EdgePoints",
    "Estimate",
    "ImageCircleError",
    "barycentre",
    "black_level",
    "canny_fit",
    "detect",
    "disc_mask",
    "hough",
    "subpixel",
    "to_gray",
]

ESTIMATORS = ("barycentre", "canny_fit", "hough", "subpixel")
MIN_SIDE_PX = 32
"""The smallest image width and height that can hold an image circle, px."""
_DARK_DN = 48.0  # a border darker than this is black: the image shows nothing
_AGREE_PX = 1.5  # estimators farther apart than this on one image need a reason
_HOUGH_SPREAD_PX = 1.5  # a Hough vote peak wider than this does not fix the centre
_CANNY_RMS_PX = 1.0  # Canny pixels scattering more than this do not fix the rim
_MIN_SUPPORT = 0.35  # the share of the rays crossing a circle that must find its rim


class ImageCircleError(InputError):
    """Images in which no fisheye image circle is found, or that cannot go together; the
    message names the image and says why."""


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


@dataclass(frozen=True)
class EdgePoints:
    """Sub-pixel rim points (N,2) px, which the final fit kept, and which image each is from."""

    points: np.ndarray
    inlier: np.ndarray  # (N,) bool
    image: np.ndarray  # (N,) int


@dataclass(frozen=True)
class CircleResult:
    """The image circle from one or more images, with every estimator's answer."""

    circle: ImageCircle  # the sub-pixel estimate
    estimates: dict[str, Estimate]  # all images combined, by estimator
    per_image: list[dict[str, Estimate]]
    width: int
    height: int
    black_level: float  # DN, median over images
    noise: float  # DN sigma of the black level
    threshold: float  # DN, the disc threshold of the barycentre and the masks
    truncated: tuple[str, ...]  # sensor edges the circle is cut by
    edges: EdgePoints
    warnings: tuple[str, ...] = ()
    rays: dict[str, int] = field(default_factory=dict)  # ray counts: cast, kept, dropped by cause

    @property
    def unbiased(self) -> list[Estimate]:
        """The estimates not known to be biased here (the barycentre of a cut circle)."""
        return [e for e in self.estimates.values() if not any("biased" in n for n in e.notes)]

    @property
    def spread_centre_px(self) -> float:
        """Largest distance between two unbiased estimators' centres, px."""
        c = np.array([(e.circle.cx, e.circle.cy) for e in self.unbiased])
        return float(np.max(np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))))

    @property
    def spread_radius_px(self) -> float:
        """Largest minus smallest radius over the unbiased estimators, px."""
        r = [e.circle.radius for e in self.unbiased]
        return float(max(r) - min(r))

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.circle.to_dict(),
            "estimator": "subpixel",
            "image_size": [self.width, self.height],
            "truncated": list(self.truncated),
            "estimators": {k: e.to_dict() for k, e in self.estimates.items()},
            "spread": {
                "centre_px": round(self.spread_centre_px, 4),
                "radius_px": round(self.spread_radius_px, 4),
            },
            "per_image": [
                {k: e.circle.to_dict() for k, e in est.items()} for est in self.per_image
            ],
            "black_level": round(self.black_level, 3),
            "noise": round(self.noise, 3),
            "threshold": round(self.threshold, 3),
            "rays": self.rays,
            "warnings": list(self.warnings),
        }


# --- the image --------------------------------------------------------------------------


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H,W) float32 grey levels (DN) of a grey or BGR image."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ValueError(f"expected a grey or BGR image, got shape {img.shape}")
    return img.astype(np.float32)


def black_level(gray: np.ndarray, frame_px: int = 3) -> tuple[float, float]:
    """Black level and noise sigma (DN) of the dark surround, from the image's outer frame.

    The level is the mode of the darkest part of the frame's histogram (within 40 DN of
    its 1st percentile: a circle larger than the sensor leaves only the frame's corners
    dark, and a veiling-glare halo brightens them towards the rim), sigma the RMS spread
    below the mode.
    """
    f = frame_px
    frame = np.concatenate(
        [gray[:f].ravel(), gray[-f:].ravel(), gray[f:-f, :f].ravel(), gray[f:-f, -f:].ravel()]
    ).astype(np.float64)
    lo = float(frame.min())
    hi = min(float(np.percentile(frame, 60)), float(np.percentile(frame, 1)) + 40.0)
    bins = max(8, min(256, math.ceil(hi - lo) + 1))
    hist, edges = np.histogram(frame, bins=bins, range=(lo, hi + 1.0))
    k = int(np.argmax(hist))
    mode = 0.5 * (edges[k] + edges[k + 1])
    below = frame[frame <= mode] - mode
    sigma = max(float(np.sqrt(np.mean(below**2))) if below.size else 0.0, 0.5)
    near = frame[np.abs(frame - mode) <= 3.0 * sigma]
    return float(np.median(near)), sigma


def disc_mask(gray: np.ndarray, threshold: float) -> npt.NDArray[np.bool_]:
    """(H,W) bool: the image disc, pixels above ``threshold`` after a light blur, with the
    dark parts of the scene inside it filled (dark regions not touching the image border)."""
    smooth = cv2.GaussianBlur(gray, (0, 0), 2.0)
    above = (smooth > threshold).astype(np.uint8)
    opened = cv2.morphologyEx(above, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    # keep the largest bright component (drop specks in the dark surround)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(opened, connectivity=8)
    if n <= 1:
        return np.zeros(gray.shape, bool)
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    disc = labels == big
    # fill holes: dark components that do not touch the image border
    n, labels = cv2.connectedComponents((~disc).astype(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    outside: npt.NDArray[np.bool_] = np.isin(labels, border) & ~disc
    return ~outside


# --- the paper's estimators -------------------------------------------------------------


def _threshold(black: float, noise: float) -> float:
    """The disc threshold (DN): 3 noise sigmas above black, on an image blurred by 2 px
    (where the noise is 7 times smaller, so no speck of the surround passes)."""
    return black + max(3.0 * noise, 2.0)


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


def _canny_points(
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
    pts = _canny_points(gray, [mask]) if points is None else points
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


# --- several images ---------------------------------------------------------------------


def _mean_circle(circles: Sequence[ImageCircle], median: bool = False) -> ImageCircle:
    a = np.array([(c.cx, c.cy, c.rx, c.ry) for c in circles])
    v = np.median(a, axis=0) if median else a.mean(axis=0)
    return ImageCircle(*(float(x) for x in v))


def _largest_gap_deg(points: np.ndarray, centre: ImageCircle) -> float:
    ang = np.sort(np.degrees(np.arctan2(points[:, 1] - centre.cy, points[:, 0] - centre.cx)))
    if len(ang) < 2:
        return 360.0
    gaps = np.diff(np.concatenate([ang, ang[:1] + 360.0]))
    return float(gaps.max())


def _plausible(circle: ImageCircle, width: int, height: int) -> bool:
    """A lens's image circle: centre on the sensor, radius between a tenth of the sensor's
    shorter side (smaller is a letter of an overlay, a lamp) and its diagonal."""
    return (
        0.0 <= circle.cx <= width
        and 0.0 <= circle.cy <= height
        and max(4.0, 0.1 * min(width, height)) <= min(circle.rx, circle.ry)
        and max(circle.rx, circle.ry) <= math.hypot(width, height)
    )


def _no_disc(gray: np.ndarray, black: float, threshold: float) -> str:
    """Why an image has no bright disc on a dark surround."""
    if black > _DARK_DN:
        return (
            f"no dark surround: even the darkest part of its border is at {black:.0f} DN "
            "(a fisheye's image circle lies in a black surround: this image's circle "
            "covers the whole sensor, no rim shows, or it is no fisheye image)"
        )
    if float(gray.max()) <= threshold:
        return f"the image is black (nothing above {threshold:.0f} DN)"
    return "no bright disc stands out from its dark border"


def _centre_gap(a: ImageCircle, b: ImageCircle) -> float:
    """Distance between two circles' centres, px."""
    return math.hypot(a.cx - b.cx, a.cy - b.cy)


def _band_rim(
    g: np.ndarray,
    pts: np.ndarray,
    black: float,
    noise: float,
    ellipse: bool,
    n_rays: int,
    rng: np.random.Generator,
) -> tuple[Estimate, np.ndarray, np.ndarray, RayEdges]:
    """The sub-pixel estimate from the circle the Canny rim pixels ``pts`` agree on.
    ValueError saying why when there is no circle."""
    h, w = g.shape
    if len(pts) < 10:
        raise ValueError("too few rim edge pixels for a circle fit")
    guess, *_ = robust_fit(pts, ellipse, 2.0, rng)
    if not _plausible(guess, w, h):
        raise ValueError(
            f"the edges of its bright part do not outline a circle on the sensor (their best "
            f"circle: centre ({guess.cx:.0f}, {guess.cy:.0f}), radius {guess.radius:.0f} px; "
            "no rim shows if the image circle covers the whole sensor)"
        )
    sub = subpixel(g, guess, black, noise, ellipse, n_rays, rng=rng)
    c = sub[0].circle
    if not _plausible(c, w, h):
        raise ValueError(
            f"its rim points do not outline a circle on the sensor (their best circle: "
            f"centre ({c.cx:.0f}, {c.cy:.0f}), radius {c.radius:.0f} px)"
        )
    # a lens's rim shows along most rays that cross it on the sensor, a scene's edges
    # agree on a circle along few
    crossing = sub[3].cast - sub[3].off_sensor
    if sub[0].n_points < _MIN_SUPPORT * crossing:
        raise ValueError(
            f"its rim points do not outline a circle on the sensor (their best circle, centre "
            f"({c.cx:.0f}, {c.cy:.0f}), radius {c.radius:.0f} px, is found along only "
            f"{sub[0].n_points} of the {crossing} rays that cross it; no rim shows if the "
            "image circle covers the whole sensor)"
        )
    return sub


def _estimate(
    g: np.ndarray,
    black: float,
    noise: float,
    ellipse: bool,
    n_rays: int,
    rng: np.random.Generator,
) -> tuple[dict[str, Estimate], np.ndarray, np.ndarray, np.ndarray, RayEdges]:
    """Every estimator on one grey image: the estimates, the Canny rim pixels, the
    sub-pixel rim points and their inliers, the ray counts. ValueError saying why when
    the image shows no image circle."""
    h, w = g.shape
    if min(h, w) < MIN_SIDE_PX:
        raise ValueError(
            f"{w}x{h} px is too small to hold one (at least {MIN_SIDE_PX}x{MIN_SIDE_PX})"
        )
    thr = _threshold(black, noise)
    mask = disc_mask(g, thr)
    if black > _DARK_DN or np.count_nonzero(mask) < 10:
        raise ValueError(_no_disc(g, black, thr))
    est = {"barycentre": barycentre(mask, ellipse)}
    # the rim's Canny pixels near the disc's edge at a low threshold, then also at a mid
    # one (a glare halo moves the first outwards); the first guess is the circle they
    # agree on (RANSAC), and the band whose rim points agree best wins
    level = float(np.median(g[mask]))
    bands = ([mask], [mask, disc_mask(g, 0.5 * (thr + level))])
    found: list[tuple[Estimate, np.ndarray, np.ndarray, RayEdges]] = []
    failure: ValueError | None = None
    band_pts = []
    for band in bands:
        band_pts.append(_canny_points(g, band))
        try:
            found.append(_band_rim(g, band_pts[-1], black, noise, ellipse, n_rays, rng))
        except ValueError as e:  # numpy's LinAlgError too
            failure = failure or e
    if not found:
        raise failure or ValueError("no rim found")
    # the rim found along most rays, unless one found along nearly as many lies a pixel or
    # more outside it: a soft rim can show a scene edge or a shading ring inside it,
    # nothing bright outside it
    best = max(found, key=lambda f: f[0].n_points)
    for f in found:
        if f[0].n_points >= 0.8 * best[0].n_points:
            if f[0].circle.radius > best[0].circle.radius + 1.0:
                best = f
    est["subpixel"], spts, sinl, rays = best
    far = max(_centre_gap(f[0].circle, best[0].circle) for f in found)
    if far > 1.5:
        # from the two first guesses the rim points settle on rims that far apart
        sub = est["subpixel"]
        note = f"uncertain by {far:.1f} px: a soft or double rim (two rims fit)"
        est["subpixel"] = replace(sub, notes=(*sub.notes, note))
    # the Canny pixels of the band that lie on that rim
    on_rim = [np.sum(np.abs(best[0].circle.residuals(p)) < 2.0) for p in band_pts]
    pts = band_pts[int(np.argmax(on_rim))]
    est["canny_fit"], _ = canny_fit(g, mask, ellipse, pts)
    guess = est["subpixel"].circle
    r0, r1 = sorted((est["barycentre"].circle.radius, guess.radius))
    aspect = guess.ry / guess.rx if ellipse else 1.0
    est["hough"] = hough(g, pts, (0.7 * r0, 1.3 * r1), aspect)
    return est, pts, spts, sinl, rays


def _median_hough(estimates: Sequence[Estimate]) -> Estimate:
    """The median of several images' Hough circles, noting the widest vote peak among
    them when one does not fix its centre."""
    circle = _mean_circle([e.circle for e in estimates], median=True)
    eu = max(e.sigma_px[0] for e in estimates)
    ev = max(e.sigma_px[1] for e in estimates)
    notes: tuple[str, ...] = ()
    if any(e.notes for e in estimates):
        notes = (f"vote peaks spread over up to +-{eu:.0f} px along u, +-{ev:.0f} px along v",)
    n = int(sum(e.n_points for e in estimates))
    return Estimate("hough", circle, n, sigma_px=(eu, ev), notes=notes)


def _disagreement(image: str, est: dict[str, Estimate]) -> list[str]:
    """Warnings for one image: the sub-pixel circle's own doubts, and each other fit (the
    barycentre aside) more than 1.5 px from it, with why it is not to be trusted there."""
    sub = est["subpixel"]
    out = [f"{image}: subpixel {n}" for n in sub.notes]
    for k in ("canny_fit", "hough"):
        e = est[k]
        off = max(_centre_gap(e.circle, sub.circle), abs(e.circle.radius - sub.circle.radius))
        if off > _AGREE_PX:
            why = "; ".join(e.notes) or "no reason found"
            out.append(f"{image}: {k} is {off:.1f} px off the sub-pixel circle: {why}")
    return out


def detect(
    images: Sequence[np.ndarray],
    ellipse: bool = False,
    n_rays: int = 720,
    names: Sequence[str] | None = None,
) -> CircleResult:
    """The image circle of one camera from one or more of its images (same size);
    ``names``: the images' files, for messages (default ``image 1``, ...).

    Raises ImageCircleError naming the image when one shows no image circle, or the images
    differ in size.
    """

    def name(i: int) -> str:
        return names[i] if names is not None and i < len(names) else f"image {i + 1}"

    if not images:
        raise ImageCircleError("no images")
    grays = [to_gray(im) for im in images]
    h, w = grays[0].shape
    for i, g in enumerate(grays):
        if g.shape != (h, w):
            raise ImageCircleError(
                f"{name(i)}: {g.shape[1]}x{g.shape[0]} px, {name(0)} {w}x{h}: the images of "
                "one camera have one size"
            )
    rng = np.random.default_rng(0)
    per_image: list[dict[str, Estimate]] = []
    canny_pts: list[np.ndarray] = []
    sub_pts: list[np.ndarray] = []
    sub_inl: list[np.ndarray] = []
    sub_img: list[np.ndarray] = []
    sub_clip: list[np.ndarray] = []
    sub_halo: list[np.ndarray] = []
    levels = [black_level(g) for g in grays]
    counts = {"cast": 0, "kept": 0, "off_sensor": 0, "saturated": 0, "no_edge": 0}
    for i, (g, (black, noise)) in enumerate(zip(grays, levels, strict=True)):
        try:
            est, pts, spts, sinl, rays = _estimate(g, black, noise, ellipse, n_rays, rng)
        except ValueError as e:  # numpy's LinAlgError too
            raise ImageCircleError(f"{name(i)}: no image circle found: {e}") from None
        canny_pts.append(pts)
        sub_pts.append(spts)
        sub_inl.append(sinl)
        sub_img.append(np.full(len(spts), i))
        sub_clip.append(rays.clipped)
        sub_halo.append(rays.haloed)
        counts["cast"] += rays.cast
        counts["kept"] += len(rays.points)
        counts["off_sensor"] += rays.off_sensor
        counts["saturated"] += rays.saturated
        counts["no_edge"] += rays.no_edge
        per_image.append(est)
    black = float(np.median([b for b, _ in levels]))
    noise = float(np.median([n for _, n in levels]))
    if len(grays) == 1:
        combined = dict(per_image[0])
        all_sub, inl = sub_pts[0], sub_inl[0]
    else:
        combined = {
            "barycentre": Estimate(
                "barycentre",
                _mean_circle([e["barycentre"].circle for e in per_image]),
                int(sum(e["barycentre"].n_points for e in per_image)),
            ),
            "hough": _median_hough([e["hough"] for e in per_image]),
        }
        all_sub = np.concatenate(sub_pts)
        try:
            combined["canny_fit"], _ = canny_fit(
                grays[0], np.ones((h, w), bool), ellipse, points=np.concatenate(canny_pts)
            )
            circle, inl, res, sigma = rim_fit(
                all_sub, np.concatenate(sub_halo), ellipse, np.random.default_rng(1)
            )
        except ValueError as e:
            raise ImageCircleError(
                f"{name(0)} .. {name(len(grays) - 1)}: no image circle common to the images: {e}"
            ) from None
        rms = float(np.sqrt(np.mean(res[inl] ** 2)))
        combined["subpixel"] = Estimate("subpixel", circle, int(inl.sum()), rms, sigma)
    combined = {k: combined[k] for k in ESTIMATORS}
    circle = combined["subpixel"].circle
    truncated = circle.cut_sides(w, h)
    warnings = []
    if truncated:
        warnings.append(
            f"the image circle is cut by the sensor ({', '.join(truncated)}): the barycentre "
            "is biased (it assumes a whole disc); the fits use rim points away from the "
            "sensor edges only"
        )
        notes = ("biased: the circle is truncated",)
        b = combined["barycentre"]
        combined["barycentre"] = Estimate(b.name, b.circle, b.n_points, notes=notes)
    gap = _largest_gap_deg(all_sub[inl], circle)
    if gap > 200.0:
        warnings.append(f"rim points span only {360 - gap:.0f} degrees: radius poorly fixed")
    if counts["saturated"]:
        warnings.append(
            f"{counts['saturated']} rays with saturated pixels just outside the rim (bloom, "
            "an overlay) dropped"
        )
    clip = np.concatenate(sub_clip)
    counts["clipped"] = int(clip.sum())
    counts["clipped_inliers"] = int(np.sum(clip & inl))
    kept = int(inl.sum())
    if kept < 0.5 * len(all_sub):
        warnings.append(f"only {kept} of {len(all_sub)} rim points agree on one circle")
    counts["inliers"] = kept
    for i, est in enumerate(per_image):
        warnings += _disagreement(name(i), est)
    result = CircleResult(
        circle=circle,
        estimates=combined,
        per_image=per_image,
        width=w,
        height=h,
        black_level=black,
        noise=noise,
        threshold=_threshold(black, noise),
        truncated=truncated,
        edges=EdgePoints(all_sub, inl, np.concatenate(sub_img)),
        warnings=(),
        rays=counts,
    )
    # disagreement among the estimators not known to be biased here
    fair = {k: e for k, e in combined.items() if not e.notes}
    spread = replace(result, estimates=fair)
    spread_c = spread.spread_centre_px if len(fair) > 1 else 0.0
    spread_r = spread.spread_radius_px if len(fair) > 1 else 0.0
    if spread_c > _AGREE_PX or spread_r > _AGREE_PX:
        warnings.append(
            f"the estimators ({', '.join(fair)}) disagree by {spread_c:.1f} px in centre and "
            f"{spread_r:.1f} px in radius (see the per-estimator results)"
        )
    return replace(result, warnings=tuple(warnings))
