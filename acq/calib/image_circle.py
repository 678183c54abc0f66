"""The image circle of a fisheye image: its centre and radius (paper §3.3.2).

Four estimators (:mod:`acq.calib.circle_estimators`), each on a grey image (pixel centres
at integers, as in OpenCV):

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

from acq.calib.circle_estimators import (
    Estimate,
    barycentre,
    canny_fit,
    canny_points,
    hough,
    rim_fit,
    subpixel,
)
from acq.calib.circle_fit import ImageCircle, robust_fit
from acq.calib.rim_rays import RayEdges
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
_MIN_SUPPORT = 0.35  # the share of the rays crossing a circle that must find its rim


class ImageCircleError(InputError):
    """Images in which no fisheye image circle is found, or that cannot go together; the
    message names the image and says why."""


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


# --- the disc threshold ---------------------------------------------------------------


def _threshold(black: float, noise: float) -> float:
    """The disc threshold (DN): 3 noise sigmas above black, on an image blurred by 2 px
    (where the noise is 7 times smaller, so no speck of the surround passes)."""
    return black + max(3.0 * noise, 2.0)


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
        band_pts.append(canny_points(g, band))
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
