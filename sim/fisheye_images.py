"""Fisheye images whose image circle is known exactly, for the circle calibration.

The scene is the synthetic street seen through an equidistant lens centred on the true
circle and wider than the circle (so texture reaches the rim and beyond); the circle itself
is a separate mask with an anti-aliased soft edge, then come vignetting, a black level with
noise and, optionally, a saturated glare blob at the rim that blooms past it. What a real
sensor in a bright room adds is optional too: a flare ring inside the rim that clips the
scene at 255 beside it, a veiling-glare halo that brightens the dark surround gradually towards the
rim, a text overlay burnt into a corner and JPEG compression. :func:`corner_arc_images`
makes several images of one such camera whose circle is larger than the sensor, its rim
visible only as arcs in the four corners.

Truth (px, pixel centres at integers as in OpenCV): the centre ``(cx, cy)`` and the
semi-axes ``a`` (along u) and ``b = a * aspect`` (along v) of the curve where the edge
mask is 50 %. ``aspect`` is the pixel aspect ratio fy / fx (1 for square pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from acq.camera.camera_models import KannalaBrandt
from acq.sim import sensors, world

__all__ = ["CircleTruth", "corner_arc_images", "fisheye_image", "random_image"]

# sigma of a Gaussian-blurred edge whose 10-90 % rise is 1 px
_SIGMA_PER_WIDTH = 1.0 / (2.0 * 1.2815515655446004)


@dataclass(frozen=True)
class CircleTruth:
    """The image circle as drawn and the degradations applied (px, DN)."""

    width: int
    height: int
    cx: float
    cy: float
    a: float  # semi-axis along u, px
    b: float  # semi-axis along v, px (== a for square pixels)
    edge_width: float  # 10-90 % width of the soft edge, px
    rim: float  # vignetting: relative brightness at the rim (1 at the centre)
    black: float  # black level, DN
    noise: float  # Gaussian noise sigma, DN
    glare_deg: float | None  # angle of the glare blob on the rim (u axis, towards +v)
    halo: float = 0.0  # veiling glare just outside the rim, DN
    halo_px: float = 0.0  # its decay length outwards, px
    jpeg_quality: int | None = None
    overlay: str | None = None  # the text burnt into a corner

    def visible_arcs(self, step_deg: float = 0.05) -> tuple[int, float]:
        """The rim's arcs on the sensor: their count and the fraction of the
        circumference they span together."""
        phi = np.radians(np.arange(0.0, 360.0, step_deg))
        u, v = self.cx + self.a * np.cos(phi), self.cy + self.b * np.sin(phi)
        on = (u >= -0.5) & (u <= self.width - 0.5) & (v >= -0.5) & (v <= self.height - 0.5)
        if on.all():
            return 1, 1.0
        starts = int(np.sum(on & ~np.roll(on, 1)))
        return starts, float(on.mean())

    @property
    def radius(self) -> float:
        """The circle's radius, px (the u semi-axis for non-square pixels)."""
        return self.a

    @property
    def truncated(self) -> bool:
        """The circle reaches past a sensor edge."""
        return (
            self.cx - self.a < -0.5
            or self.cx + self.a > self.width - 0.5
            or self.cy - self.b < -0.5
            or self.cy + self.b > self.height - 0.5
        )


def _erfc(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Complementary error function (Abramowitz & Stegun 7.1.26, |error| < 1.5e-7)."""
    z = np.abs(x)
    t = 1.0 / (1.0 + 0.3275911 * z)
    poly = t * (
        0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    )
    e = poly * np.exp(-z * z)
    erfc: npt.NDArray[np.float64] = np.where(x >= 0, e, 2.0 - e)
    return erfc


def _street(
    width: int, height: int, cx: float, cy: float, a: float, aspect: float, seed: int, t: float
) -> np.ndarray:
    """(H,W) float64 grey street view (0..255) through an equidistant lens whose 185-degree
    circle has u semi-axis ``a``; rendered out to 240 degrees, so it covers the rim."""

    f = a / math.radians(92.5)
    lens = KannalaBrandt(width, height, f, f * aspect, cx, cy, fov_deg=240.0)
    rig = world.default_rig().with_camera(lens=lens)
    bgr = sensors.render_frame(world.Street.generate(seed=seed), world.Trajectory(), rig, t)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float64)


def fisheye_image(
    width: int = 780,
    height: int = 582,
    cx: float = 390.2,
    cy: float = 291.1,
    radius: float = 273.0,
    aspect: float = 1.0,
    edge_width: float = 2.0,
    rim: float = 0.3,
    black: float = 10.0,
    noise: float = 1.5,
    glare_deg: float | None = None,
    glare_radius: float = 14.0,
    gain: float = 1.0,
    seed: int = 0,
    t: float = 2.0,
    rng: np.random.Generator | None = None,
    flare: float = 0.0,
    flare_px: float = 60.0,
    halo: float = 0.0,
    halo_px: float = 20.0,
    overlay: str | None = None,
    overlay_corner: int = 0,
    jpeg_quality: int | None = None,
) -> tuple[np.ndarray, CircleTruth]:
    """A (H,W) uint8 grey fisheye image and its truth.

    ``radius`` is the u semi-axis (px), ``aspect`` = fy / fx; ``edge_width`` the 10-90 %
    width of the soft edge (px); ``rim`` the brightness at the rim relative to the centre
    (cos^4-like falloff, 1 = none); ``black`` (DN) and ``noise`` (sigma, DN) the sensor's
    offset and read noise; ``glare_deg`` puts a saturated blob of ``glare_radius`` px on the
    rim at that angle; ``gain`` scales the scene. ``seed`` and ``t`` pick the street view,
    ``rng`` the noise (default: seeded from ``seed``).

    A real sensor's defects: ``flare`` (DN) brightens the scene at the rim, fading inwards
    as exp(-d / ``flare_px``) (past 255 it clips); ``halo`` (DN) is the veiling glare at
    the rim, falling off outwards as exp(-d / ``halo_px``) and flat inside; ``overlay``
    is white text burnt into a corner (``overlay_corner`` 0-3: top-left, top-right, bottom-right,
    bottom-left); ``jpeg_quality`` compresses the result.
    """
    if not 0.0 < rim <= 1.0:
        raise ValueError(f"rim {rim}: expected in (0, 1]")
    if edge_width <= 0 or radius <= 0 or aspect <= 0:
        raise ValueError("edge_width, radius and aspect must be > 0")
    rng = np.random.default_rng(seed) if rng is None else rng
    b = radius * aspect
    scene = _street(width, height, cx, cy, radius, aspect, seed, t) * gain
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    # normalised radius (1 on the true curve) and the edge distance in px along the normal
    # (for an ellipse: the radial distance scaled by the local radius, exact on the axes)
    rho = np.hypot((u - cx) / radius, (v - cy) / b)
    local = np.hypot(u - cx, v - cy) / np.maximum(rho, 1e-12)
    dist = (rho - 1.0) * local
    # anti-aliased: blur of the edge combined with the pixel's own box (variance 1/12)
    sigma = math.hypot(edge_width * _SIGMA_PER_WIDTH, math.sqrt(1.0 / 12.0))
    edge = 0.5 * _erfc(dist / (math.sqrt(2.0) * sigma))
    alpha = math.acos(rim**0.25)
    vignette = np.cos(alpha * np.minimum(rho, 1.5)) ** 4
    img = (scene + flare * np.exp(np.minimum(dist, 0.0) / flare_px)) * vignette * edge
    if halo > 0.0:
        img = img + halo * np.exp(-np.maximum(dist, 0.0) / halo_px)
    if glare_deg is not None:
        ang = math.radians(glare_deg)
        gx, gy = cx + radius * math.cos(ang), cy + b * math.sin(ang)
        d2 = (u - gx) ** 2 + (v - gy) ** 2
        # a saturated core that blooms past the rim
        img = img + 600.0 * np.exp(-d2 / (2.0 * glare_radius**2))
    img = img + black + rng.normal(0.0, noise, img.shape)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if overlay:
        _burn_text(out, overlay, overlay_corner)
    if jpeg_quality is not None:
        _, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    truth = CircleTruth(
        width, height, cx, cy, radius, b, edge_width, rim, black, noise, glare_deg,
        halo, halo_px if halo > 0.0 else 0.0, jpeg_quality, overlay,
    )  # fmt: skip
    return out, truth


def _burn_text(img: np.ndarray, text: str, corner: int) -> None:
    """White text (a camera's time stamp) drawn into ``corner`` of ``img`` in place."""
    h, w = img.shape
    scale = h / 900.0
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    margin = 8
    x = margin if corner in (0, 3) else w - margin - tw
    y = margin + th if corner in (0, 1) else h - margin
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, 255, 1, cv2.LINE_AA)


def random_image(
    rng: np.random.Generator,
    truncated: bool = False,
    glare: bool = False,
    aspect: float = 1.0,
    width: int = 780,
    height: int = 582,
) -> tuple[np.ndarray, CircleTruth]:
    """A random image like the simulated camera's (radius about 273 px on 780x582).

    ``truncated``: the circle is cut, either at top and bottom (a radius larger than half
    the height, like the real 748x480 images) or on one side (the centre moved).
    """
    cx = width / 2 + rng.uniform(-8, 8)
    cy = height / 2 + rng.uniform(-8, 8)
    radius = rng.uniform(255, 285)
    if truncated:
        if rng.random() < 0.5:
            radius = rng.uniform(height / 2 + 15, height / 2 + 45) / max(aspect, 1.0)
        else:
            side = rng.choice([-1.0, 1.0])
            if rng.random() < 0.5:
                cx += side * rng.uniform(140, 180)
            else:
                cy += side * rng.uniform(40, 70)
    return fisheye_image(
        width,
        height,
        cx,
        cy,
        radius,
        aspect=aspect,
        edge_width=rng.uniform(1.0, 4.0),
        rim=rng.uniform(0.15, 0.5),
        black=rng.uniform(4, 20),
        noise=rng.uniform(0.8, 3.0),
        glare_deg=rng.uniform(0, 360) if glare else None,
        gain=rng.uniform(0.8, 1.2),
        seed=int(rng.integers(0, 4)),
        t=rng.uniform(0.5, 20.0),
        rng=rng,
    )


def corner_arc_images(
    rng: np.random.Generator, n: int = 4, width: int = 780, height: int = 582
) -> tuple[list[np.ndarray], CircleTruth]:
    """``n`` images of one camera whose circle is larger than the sensor: its rim shows
    only as four corner arcs spanning 10-24 % of the circumference together. What a real
    sensor in a bright room adds: the scene clipped at 255 beside the rim along most of
    each arc, a dark surround of 15-22 DN brightened by a 40-90 DN veiling-glare halo that
    fades over 10-25 px, JPEG at quality 70-90 and a time stamp burnt into one corner.
    The scene changes from image to image, the camera (and so the truth) does not. A
    landscape sensor (width >= height)."""
    if width < height:
        raise ValueError(f"{width}x{height}: expected a landscape sensor (width >= height)")
    half_diag = math.hypot(width, height) / 2.0
    cx = width / 2.0 + rng.uniform(-6.0, 6.0)
    cy = height / 2.0 + rng.uniform(-6.0, 6.0)
    # between the radius whose corner arcs span 24 % of the rim and the one spanning 10 %
    lo, hi = _radius_for_span(width, height, 0.24), _radius_for_span(width, height, 0.10)
    radius = rng.uniform(lo, min(hi, half_diag - 12.0))
    edge_width, rim = rng.uniform(1.5, 3.5), rng.uniform(0.75, 0.95)
    black, noise = rng.uniform(15.0, 22.0), rng.uniform(1.0, 2.5)
    halo, halo_px = rng.uniform(40.0, 90.0), rng.uniform(10.0, 25.0)
    corner = int(rng.integers(0, 4))
    shots = [
        fisheye_image(
            width,
            height,
            cx,
            cy,
            radius,
            edge_width=edge_width,
            rim=rim,
            black=black,
            noise=noise,
            gain=rng.uniform(1.0, 1.4),
            flare=rng.uniform(200.0, 300.0),
            halo=halo,
            halo_px=halo_px,
            seed=int(rng.integers(0, 4)),
            t=rng.uniform(0.5, 20.0),
            rng=rng,
            overlay=f"CAM1 2026-12-02 06:{10 + i:02d}:{int(rng.integers(0, 60)):02d}",
            overlay_corner=corner,
            jpeg_quality=int(rng.integers(70, 91)),
        )
        for i in range(max(n, 1))
    ]
    return [img for img, _ in shots], shots[0][1]


def _radius_for_span(width: int, height: int, fraction: float) -> float:
    """The radius of a circle centred on the sensor whose four corner arcs span
    ``fraction`` of its circumference (bisection: the span falls as the radius grows)."""
    lo, hi = max(width, height) / 2.0, math.hypot(width, height) / 2.0
    for _ in range(50):
        r = 0.5 * (lo + hi)
        # each corner's arc runs from where it leaves the sides to where it meets top/bottom
        span = 4.0 * (math.asin(min(1.0, height / (2.0 * r))) - math.acos(width / (2.0 * r)))
        if span / (2.0 * math.pi) > fraction:
            lo = r
        else:
            hi = r
    return 0.5 * (lo + hi)
