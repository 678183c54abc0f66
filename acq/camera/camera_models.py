"""Camera models: the paper's equidistant fisheye, Kannala–Brandt and OpenCV pinhole.

Points are (N,3) metres in the camera optical frame (z along the optical axis, x right,
y down); pixels are (N,2) (u, v) with the centre of the top-left pixel at (0, 0), as in
OpenCV. The fisheye models measure the angle from the optical axis as
``theta = atan2(sqrt(x² + y²), z)``, which keeps growing past 90 degrees (OpenCV's fisheye
functions use ``atan(r)`` of the normalised point and mirror everything behind the
camera, which is wrong for a 185-degree lens).

These are the float64 reference implementations; ``acq.camera.projection`` holds the compiled
kernels of the hot path and is tested against them.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "CameraModel",
    "Equidistant",
    "KannalaBrandt",
    "Pinhole",
    "from_dict",
]


def _points(P: np.ndarray) -> np.ndarray:
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"expected (N,3) points, got shape {P.shape}")
    return P


def _pixels(uv: np.ndarray) -> np.ndarray:
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"expected (N,2) pixels, got shape {uv.shape}")
    return uv


@dataclass(frozen=True)
class CameraModel(ABC):
    """A camera model: image size (px), focal lengths and principal point (px), and
    project/unproject."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    name: ClassVar[str] = ""

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(N,) bool: pixel lies on the sensor (pixel centres at integers)."""
        u, v = uv[:, 0], uv[:, 1]
        return (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)

    @abstractmethod
    def project(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) camera-frame metres -> ((N,2) px, (N,) bool valid).

        Invalid: behind the lens or outside its field of view, or outside the image.
        Pixels of invalid points are still computed where the model is defined (NaN
        where it is not), so callers can see how far outside they fall.
        """

    @abstractmethod
    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """(N,2) px -> (N,3) unit rays in the camera frame."""

    def to_dict(self) -> dict[str, Any]:
        """The calib.yaml entry of this model (without extrinsics)."""
        return {
            "model": self.name,
            "image_size": [self.width, self.height],
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
        }


@dataclass(frozen=True)
class KannalaBrandt(CameraModel):
    """Generic fisheye (paper eq. 4): ``r = theta (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``.

    OpenCV's fisheye polynomial and intrinsics (fx, fy in px per radian), with theta
    measured as ``atan2(rho, z)`` so points up to ``fov_deg / 2`` from the axis, past 90
    degrees included, project correctly.
    """

    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    fov_deg: float = 185.0

    name: ClassVar[str] = "kannala_brandt"

    def __post_init__(self) -> None:
        object.__setattr__(self, "k", tuple(float(x) for x in self.k))
        if len(self.k) != 4:
            raise ValueError(f"k needs 4 coefficients, got {len(self.k)}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError("fx and fy must be > 0")
        if not (0 < self.fov_deg < 360):
            raise ValueError("fov_deg must be in (0, 360)")
        th = np.linspace(0.0, self.theta_max, 512)
        if np.any(np.diff(self.distort_theta(th)) <= 0):
            raise ValueError("the lens polynomial is not increasing up to fov_deg / 2")

    @property
    def theta_max(self) -> float:
        """Half the full aperture, rad."""
        return math.radians(self.fov_deg) / 2.0

    def distort_theta(self, theta: np.ndarray) -> np.ndarray:
        """Image radius per unit focal length, ``theta_d(theta)``."""
        k1, k2, k3, k4 = self.k
        t2 = theta * theta
        theta_d: np.ndarray = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        return theta_d

    def undistort_theta(self, theta_d: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`distort_theta` by Newton's method (float64, to 1e-14 rad)."""
        k1, k2, k3, k4 = self.k
        theta = np.array(theta_d, dtype=np.float64, copy=True)
        if not any(self.k):
            return theta
        for _ in range(50):
            t2 = theta * theta
            f = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - theta_d
            df = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            step = f / df
            theta -= step
            if np.all(np.abs(step) < 1e-15):
                break
        return theta

    def project(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = _points(P)
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        rho = np.hypot(x, y)
        theta = np.arctan2(rho, z)
        rd = self.distort_theta(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rho > 0, rd / rho, 0.0)
        uv = np.stack([self.cx + self.fx * scale * x, self.cy + self.fy * scale * y], axis=1)
        nonzero = (rho > 0) | (z > 0)
        valid = nonzero & (theta <= self.theta_max) & self.in_image(uv)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        uv = _pixels(uv)
        mx = (uv[:, 0] - self.cx) / self.fx
        my = (uv[:, 1] - self.cy) / self.fy
        rd = np.hypot(mx, my)
        theta = self.undistort_theta(rd)
        s = np.sin(theta)
        with np.errstate(invalid="ignore", divide="ignore"):
            ux = np.where(rd > 0, mx / rd, 0.0)
            uy = np.where(rd > 0, my / rd, 0.0)
        return np.stack([s * ux, s * uy, np.cos(theta)], axis=1)

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "fov_deg": self.fov_deg, "k": list(self.k)}


@dataclass(frozen=True)
class Equidistant(KannalaBrandt):
    """The paper's 3-parameter fisheye (§3.3.1): ``r = f·theta``, square pixels.

    A Kannala–Brandt model with zero coefficients and ``fx == fy == f``.
    """

    name: ClassVar[str] = "equidistant"

    def __post_init__(self) -> None:
        if any(self.k):
            raise ValueError("the equidistant model has no distortion coefficients")
        if self.fx != self.fy:
            raise ValueError(
                f"the equidistant model has square pixels: fx {self.fx} != fy {self.fy}"
            )
        super().__post_init__()

    @classmethod
    def from_f(
        cls, f: float, cx: float, cy: float, width: int, height: int, fov_deg: float = 185.0
    ) -> Equidistant:
        """The model from the paper's three parameters ``(f·mu, u0, v0)``."""
        return cls(width=width, height=height, fx=f, fy=f, cx=cx, cy=cy, fov_deg=fov_deg)

    @property
    def f(self) -> float:
        return self.fx

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d["k"] = [0.0, 0.0, 0.0, 0.0]
        return d


@dataclass(frozen=True)
class Pinhole(CameraModel):
    """OpenCV's pinhole model with distortion ``(k1, k2, p1, p2, k3)``.

    For the regular lens the paper mounts during the extrinsic calibration. Points with
    ``z <= 0`` are invalid, and so are points past the radius where the radial
    polynomial folds back (``d r_d / d r <= 0``): OpenCV projects those far-off points
    into the image as if they were near its corners.
    """

    dist: tuple[float, float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    name: ClassVar[str] = "pinhole"

    def __post_init__(self) -> None:
        object.__setattr__(self, "dist", tuple(float(x) for x in self.dist))
        if len(self.dist) != 5:
            raise ValueError(f"pinhole distortion needs 5 coefficients, got {len(self.dist)}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError("fx and fy must be > 0")

    def distort(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised undistorted (a, b) = (x/z, y/z) -> distorted normalised coordinates."""
        k1, k2, p1, p2, k3 = self.dist
        r2 = a * a + b * b
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        yd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        return xd, yd

    def project(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = _points(P)
        z = P[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            a = P[:, 0] / z
            b = P[:, 1] / z
        xd, yd = self.distort(a, b)
        uv = np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=1)
        k1, k2, _, _, k3 = self.dist
        r2 = a * a + b * b
        monotone = 1.0 + r2 * (3 * k1 + r2 * (5 * k2 + r2 * 7 * k3)) > 0
        valid = (z > 0) & monotone & np.isfinite(uv).all(axis=1) & self.in_image(uv)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        uv = _pixels(uv)
        xd = (uv[:, 0] - self.cx) / self.fx
        yd = (uv[:, 1] - self.cy) / self.fy
        k1, k2, p1, p2, k3 = self.dist
        a, b = xd.copy(), yd.copy()
        # Newton on the 2x2 distortion map; converges in a few steps for real lenses.
        for _ in range(30):
            r2 = a * a + b * b
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = k1 + r2 * (2 * k2 + r2 * 3 * k3)  # d radial / d r2
            fx_, fy_ = self.distort(a, b)
            ex, ey = fx_ - xd, fy_ - yd
            j11 = radial + 2 * a * a * dradial + 2 * p1 * b + 6 * p2 * a
            j12 = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
            j21 = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
            j22 = radial + 2 * b * b * dradial + 6 * p1 * b + 2 * p2 * a
            det = j11 * j22 - j12 * j21
            da = (j22 * ex - j12 * ey) / det
            db = (-j21 * ex + j11 * ey) / det
            a -= da
            b -= db
            if np.all(np.abs(da) + np.abs(db) < 1e-16):
                break
        rays = np.stack([a, b, np.ones_like(a)], axis=1)
        unit: np.ndarray = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        return unit

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "k": list(self.dist)}


MODELS: dict[str, type[CameraModel]] = {
    "equidistant": Equidistant,
    "kannala_brandt": KannalaBrandt,
    "pinhole": Pinhole,
}


def from_dict(d: dict[str, Any]) -> CameraModel:
    """A model from a validated calib.yaml camera entry (see ``acq.camera.calibfile``)."""
    model = d["model"]
    width, height = (int(x) for x in d["image_size"])
    fx, fy, cx, cy = (float(d[key]) for key in ("fx", "fy", "cx", "cy"))
    fov = float(d.get("fov_deg", 185.0))
    if model == "equidistant":
        return Equidistant(width, height, fx, fy, cx, cy, fov_deg=fov)
    if model == "kannala_brandt":
        k1, k2, k3, k4 = (float(x) for x in d.get("k", [0.0] * 4))
        return KannalaBrandt(width, height, fx, fy, cx, cy, (k1, k2, k3, k4), fov)
    if model == "pinhole":
        k1, k2, p1, p2, k3 = (float(x) for x in d.get("k", [0.0] * 5))
        return Pinhole(width, height, fx, fy, cx, cy, (k1, k2, p1, p2, k3))
    raise ValueError(f"unknown camera model {model!r}; expected one of {sorted(MODELS)}")
