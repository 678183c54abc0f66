"""Circles and axis-aligned ellipses in an image, and their fits to edge points (px, pixel
centres at integers): an algebraic fit (Kåsa), a geometric refinement on radial distances,
RANSAC, and the three chained (:func:`robust_fit`). The image circle's estimators
(:mod:`acq.calib.image_circle`) fit their rim points with these.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["ImageCircle", "fit_conic", "ransac_fit", "refine_fit", "robust_fit"]


@dataclass(frozen=True)
class ImageCircle:
    """An image circle, or an axis-aligned ellipse (non-square pixels), px."""

    cx: float
    cy: float
    rx: float  # semi-axis along u
    ry: float  # semi-axis along v (== rx for a circle)

    def __post_init__(self) -> None:
        for name in ("cx", "cy", "rx", "ry"):
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def radius(self) -> float:
        """The radius; for an ellipse the mean of the semi-axes."""
        return 0.5 * (self.rx + self.ry)

    def radius_at(self, phi: np.ndarray) -> npt.NDArray[np.float64]:
        """Distance from the centre to the curve in direction ``phi`` (rad, from +u to +v)."""
        r: npt.NDArray[np.float64] = 1.0 / np.hypot(np.cos(phi) / self.rx, np.sin(phi) / self.ry)
        return r

    def residuals(self, points: np.ndarray) -> npt.NDArray[np.float64]:
        """(N,) radial distance of (N,2) points from the curve, px (+ outside)."""
        d = points - (self.cx, self.cy)
        r: npt.NDArray[np.float64] = np.hypot(d[:, 0], d[:, 1])
        return r - self.radius_at(np.arctan2(d[:, 1], d[:, 0]))

    def cut_sides(self, width: int, height: int, margin: float = 0.5) -> tuple[str, ...]:
        """The sensor edges the curve reaches past (left, right, top, bottom)."""
        sides = []
        if self.cx - self.rx < -0.5 - margin:
            sides.append("left")
        if self.cx + self.rx > width - 0.5 + margin:
            sides.append("right")
        if self.cy - self.ry < -0.5 - margin:
            sides.append("top")
        if self.cy + self.ry > height - 0.5 + margin:
            sides.append("bottom")
        return tuple(sides)

    def to_dict(self) -> dict[str, float]:
        d = {"cx": self.cx, "cy": self.cy, "radius": self.radius}
        if self.rx != self.ry:
            d |= {"rx": self.rx, "ry": self.ry}
        return {k: round(float(v), 4) for k, v in d.items()}


# --- fitting ----------------------------------------------------------------------------


def _design(points: np.ndarray, ellipse: bool) -> np.ndarray:
    x, y = points[..., 0], points[..., 1]
    one = np.ones_like(x)
    if ellipse:
        return np.stack([x * x, y * y, x, y, one], axis=-1)
    return np.stack([x * x + y * y, x, y, one], axis=-1)


def _conic_to_circle(c: np.ndarray, ellipse: bool) -> np.ndarray:
    """(..., 4|5) conic coefficients -> (..., 4) cx, cy, rx, ry (NaN where not an ellipse)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        if ellipse:
            A, C, D, E, F = np.moveaxis(c, -1, 0)
        else:
            A, D, E, F = np.moveaxis(c, -1, 0)
            C = A
        cx, cy = -D / (2 * A), -E / (2 * C)
        G = D * D / (4 * A) + E * E / (4 * C) - F
        rx, ry = np.sqrt(G / A), np.sqrt(G / C)
    return np.stack([cx, cy, rx, ry], axis=-1)


def fit_conic(points: np.ndarray, ellipse: bool = False) -> ImageCircle:
    """Algebraic least-squares circle (Kåsa) or axis-aligned ellipse through (N,2) points."""
    pts = np.asarray(points, np.float64)
    mean = pts.mean(axis=0)
    scale = max(float(np.std(pts - mean)), 1e-9)
    q = (pts - mean) / scale
    _, _, vt = np.linalg.svd(_design(q, ellipse), full_matrices=False)
    cx, cy, rx, ry = _conic_to_circle(vt[-1], ellipse)
    if not np.all(np.isfinite([cx, cy, rx, ry])):
        raise ValueError("the points do not lie on an ellipse")
    return ImageCircle(
        float(cx * scale + mean[0]),
        float(cy * scale + mean[1]),
        float(rx * scale),
        float(ry * scale),
    )


def refine_fit(
    points: np.ndarray, init: ImageCircle, ellipse: bool = False, iterations: int = 20
) -> tuple[ImageCircle, np.ndarray, tuple[float, ...]]:
    """Geometric least squares (radial distances, Gauss-Newton) from ``init``.

    Returns the circle, the (N,) residuals (px) and the parameters' standard errors (px;
    optimistic, as neighbouring edge points share blur and noise).
    """
    pts = np.asarray(points, np.float64)
    p = np.array([init.cx, init.cy, init.rx] + ([init.ry] if ellipse else []), np.float64)

    def circ(p: np.ndarray) -> ImageCircle:
        return ImageCircle(p[0], p[1], p[2], p[3] if ellipse else p[2])

    def jac(p: np.ndarray, res: np.ndarray) -> np.ndarray:
        d = pts - p[:2]
        dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
        if not ellipse:
            return np.stack([-d[:, 0] / dist, -d[:, 1] / dist, -np.ones(len(pts))], axis=1)
        cols = []
        for i in range(len(p)):
            h = 1e-4 * max(1.0, abs(p[i]))
            q = p.copy()
            q[i] += h
            cols.append((circ(q).residuals(pts) - res) / h)
        return np.stack(cols, axis=1)

    res = circ(p).residuals(pts)
    for _ in range(iterations):
        J = jac(p, res)
        step, *_ = np.linalg.lstsq(J, -res, rcond=None)
        p = p + step
        res = circ(p).residuals(pts)
        if np.max(np.abs(step)) < 1e-7:
            break
    J = jac(p, res)
    dof = max(len(pts) - len(p), 1)
    try:
        cov = np.linalg.inv(J.T @ J) * float(res @ res) / dof
        sigma = tuple(float(math.sqrt(max(v, 0.0))) for v in np.diag(cov))
    except np.linalg.LinAlgError:
        sigma = tuple(math.nan for _ in p)
    return circ(p), res, sigma


def ransac_fit(
    points: np.ndarray,
    threshold_px: float = 1.5,
    ellipse: bool = False,
    iterations: int = 300,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """(N,) bool inliers of the circle (ellipse) with the most points within
    ``threshold_px`` of it, over random minimal samples (3 points; 4 for an ellipse)."""
    pts = np.asarray(points, np.float64)
    n_min = 4 if ellipse else 3
    if len(pts) < n_min + 1:
        return np.ones(len(pts), bool)
    rng = np.random.default_rng(0) if rng is None else rng
    mean = pts.mean(axis=0)
    scale = max(float(np.std(pts - mean)), 1e-9)
    q = (pts - mean) / scale
    idx = rng.integers(0, len(pts), (iterations, n_min))  # repeats give NaN, dropped
    with np.errstate(invalid="ignore", divide="ignore"):
        _, _, vt = np.linalg.svd(_design(q[idx], ellipse))  # (K, n_min, n_min + 1)
        params = _conic_to_circle(vt[:, -1, :], ellipse)  # (K, 4) in scaled units
    ok = np.all(np.isfinite(params), axis=1) & np.all(params[:, 2:] > 0, axis=1)
    if not np.any(ok):
        return np.ones(len(pts), bool)
    params = params[ok]
    # score on at most 500 points, then the inliers of the best among all
    sub = q if len(q) <= 500 else q[rng.choice(len(q), 500, replace=False)]

    def residuals(
        p: npt.NDArray[np.float64], x: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        d = x[None, :, :] - p[:, None, :2]
        dist = np.hypot(d[..., 0], d[..., 1])
        rho = np.hypot(d[..., 0] / p[:, None, 2], d[..., 1] / p[:, None, 3])
        r: npt.NDArray[np.float64] = np.abs(dist - dist / np.maximum(rho, 1e-12)) * scale
        return r

    counts = np.sum(residuals(params, sub) < threshold_px, axis=1)
    best = params[int(np.argmax(counts))][None, :]
    inliers: npt.NDArray[np.bool_] = residuals(best, q)[0] < threshold_px
    return inliers


def robust_fit(
    points: np.ndarray, ellipse: bool, threshold_px: float, rng: np.random.Generator
) -> tuple[ImageCircle, np.ndarray, np.ndarray, tuple[float, ...]]:
    """RANSAC, geometric refinement on its inliers, then inliers again within
    max(3 robust sigma, 0.5 px) and a last refinement. Returns circle, inliers, residuals
    of all points, standard errors."""
    inl = ransac_fit(points, threshold_px, ellipse, rng=rng)
    circle = fit_conic(points[inl], ellipse)
    circle, _, sigma = refine_fit(points[inl], circle, ellipse)
    for _ in range(2):
        res = circle.residuals(points)
        mad = float(np.median(np.abs(res[inl] - np.median(res[inl])))) * 1.4826
        inl = np.abs(res) < max(3.0 * mad, 0.5)
        circle, _, sigma = refine_fit(points[inl], circle, ellipse)
    return circle, inl, circle.residuals(points), sigma
