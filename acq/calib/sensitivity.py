"""Sensitivity of the laser-to-image projection to its 12 parameters (paper §4.1).

The projection, as the paper's eq. (2), (4) and (5) compose it:

    P_c = R^T (P_laser - t)              camera_to_laser: P_laser = R P_c + t (eq. 2)
    theta = atan2(sqrt(x² + y²), z),  phi = atan2(y, x)
    r = k1 theta + k2 theta³            generic model cut after the third order (eq. 4)
    u = u0 + mu_x r cos(phi),  v = v0 + mu_y r sin(phi)          (eq. 5)

with R = Rz(yaw) Ry(pitch) Rx(roll) (``acq.geometry.rotations.rotation_from_euler``). The 12
parameters, in :data:`PARAMS` order: roll, pitch, yaw (rad), tx, ty, tz (m), k1, k2 (m:
image radius on the sensor per radian, per radian³), u0, v0 (px), mu_x, mu_y (px/m).

A calib.yaml stores only the products ``fx = k1 mu_x`` and ``fy = k1 mu_y``. The split
uses the paper's sensor (1/2" CCD, 6.47 mm for 780 px: :data:`PIXEL_PITCH_M`), so
``mu_x = 1 / PIXEL_PITCH_M``, ``k1 = fx / mu_x``, ``mu_y = fy / k1``. Eq. (7) is
invariant to that choice (scaling a parameter scales its derivative inversely). The
third-order coefficient is ``k2 = k1 · k[0]`` for a Kannala–Brandt calibration (OpenCV's
theta³ coefficient; its higher orders are left out), else the paper's own value, read
off its Table 3: ``mu k2 = 1.21 px`` (:data:`PAPER_THIRD_ORDER_PX`).

Criterion (eq. 8). As printed, ``f = sqrt(u² + v²)`` measures from pixel (0, 0), while
the text says "the distance to the centre of the image". We use the text:
``f = sqrt((u - u_c)² + (v - v_c)²)`` with (u_c, v_c) the calibrated principal point,
held fixed (it is not the parameter u0, v0, else f would not depend on them); ``origin``
"corner" gives the printed formula. Points with f < 1 px are left out of the
sensitivity statistics (eq. 7 divides by f).

Eq. (7), ``s_i = ∂f/∂p_i · p_i / f``, is a relative sensitivity: it makes parameters with
large values (u0 ≈ 390 px) look important and angles near zero look irrelevant. Beside
it, :func:`pixel_shift` gives ``|∂(u, v)/∂p_i| · σ_i``: how many pixels one standard
deviation of p_i moves a point, which is what one can act on.

σ (:func:`choose_sigma`): the caller's overrides (``--sigma NAME=VALUE``) first, then
the calibration's ``std`` (calib.yaml, from the fits' covariances: :func:`calib_sigma`),
else :func:`default_sigma` (0.1° per rotation angle, 5 mm per translation, 0.5 px for u0
and v0, 1 % of k1, mu_x, mu_y, and the whole of k2, since the paper's model drops that
term); the report says which came from where. From ``std``: u0, v0 <- cx, cy; tx, ty,
tz <- translation_m; k1, mu_x and mu_y appear only through fx = k1 mu_x and fy = k1 mu_y,
so k1 and mu_x get the relative σ of fx and mu_y that of fy (each then moves points as
one σ of fx or fy does); k2 <- k1 σ(k[0]). The rotation's σ is stored as small
rotations w about the laser axes (``R = exp([w]x) R_hat``, ``Σ_w = diag(std²)``; a full
Σ_w can be given to :func:`rotation_sigma`). It is not turned into Euler-angle σ, which
blow up near pitch ±90° where the rig sits (roll and yaw turn about nearly the same
axis): each angle i moves R about the laser-frame axis ``a_i = vee(dR_i R^T)``
(normalised), and gets ``σ_i = sqrt(a_iᵀ Σ_w a_i) / |vee(dR_i R^T)|``, so its px per σ
is the shift of a one-σ rotation about a_i.

The figures (7-9) are drawn by :mod:`acq.calib.plots`; ``acq analyze sensitivity`` runs
the analysis on a log's laser points (:mod:`acq.calib.sensitivity_log`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from acq.camera.calibfile import CameraCalib
from acq.camera.camera_models import KannalaBrandt
from acq.errors import InputValueError
from acq.geometry.rotations import rotation_from_euler, rotation_to_euler, skew

__all__ = [
    "DEFAULT_HEIGHTS_M",
    "DEFAULT_THRESHOLDS_PX",
    "PAPER_THIRD_ORDER_PX",
    "PARAMS",
    "PIXEL_PITCH_M",
    "Analysis",
    "analyze",
    "bin_by_theta",
    "calib_sigma",
    "choose_sigma",
    "criterion",
    "default_sigma",
    "format_sigma",
    "format_table3",
    "jacobian",
    "laser_points",
    "params_from_calib",
    "parse_sigma",
    "pixel_shift",
    "project",
    "rotation_axes",
    "rotation_jacobian",
    "rotation_sigma",
    "sensitivities",
    "table3",
    "third_order_px",
]

PARAMS = ("roll", "pitch", "yaw", "tx", "ty", "tz", "k1", "k2", "u0", "v0", "mu_x", "mu_y")
RIGID = PARAMS[:6]
CAMERA = PARAMS[6:]
UNITS = ("rad", "rad", "rad", "m", "m", "m", "m", "m", "px", "px", "px/m", "px/m")
PIXEL_PITCH_M = 6.47e-3 / 780  # the paper's 1/2" CCD: 6.47 mm for 780 px
PAPER_THIRD_ORDER_PX = 1.21  # mu k2, px at theta = 1 rad: 1, 2, 3, 4 px at 53.75 .. 85.4°
DEFAULT_THRESHOLDS_PX = (0.5, 1.0, 2.0, 3.0, 4.0)
DEFAULT_HEIGHTS_M = (5.0, 10.0, 15.0, 20.0, 30.0)
MIN_CRITERION_PX = 1.0


# --- the model ---------------------------------------------------------------------------


def params_from_calib(cam: CameraCalib) -> np.ndarray:
    """(12,) parameters (:data:`PARAMS` order, SI units / px) of a fisheye calibration."""
    m = cam.model
    if not isinstance(m, KannalaBrandt):
        raise InputValueError(f"{m.name}: the sensitivity analysis needs a fisheye model")
    roll, pitch, yaw = rotation_to_euler(cam.camera_to_laser.rotation)
    mu_x = 1.0 / PIXEL_PITCH_M
    k1 = m.fx / mu_x
    mu_y = m.fy / k1
    third = m.k[0] if m.name == "kannala_brandt" and m.k[0] != 0 else None
    k2 = k1 * third if third is not None else PAPER_THIRD_ORDER_PX / mu_x
    t = cam.camera_to_laser.translation
    return np.array([roll, pitch, yaw, *t, k1, k2, m.cx, m.cy, mu_x, mu_y], dtype=np.float64)


def rotation_jacobian(angles: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R = Rz(yaw) Ry(pitch) Rx(roll) and (3,3,3) dR/d(roll, pitch, yaw)."""
    r, p, y = (float(a) for a in angles)
    R = rotation_from_euler(r, p, y)
    # roll turns about the body's x, yaw about the world's z, pitch about the y axis
    # between them (Rx^T y in the body)
    axes = skew(np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)]]))
    return R, np.stack([R @ axes[0], R @ axes[1], skew([0.0, 0.0, 1.0]) @ R])


def _camera_points(P_laser: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,3) P_c = R^T (P_laser - t) and (N,3) P_laser - t."""
    R = rotation_from_euler(*p[:3])
    d = np.asarray(P_laser, dtype=np.float64) - p[3:6]
    return d @ R, d


def project(P_laser: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,3) laser-frame m -> ((N,2) px (u, v), (N,) theta rad) with parameters ``p``."""
    Pc, _ = _camera_points(P_laser, p)
    x, y, z = Pc.T
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    phi = np.arctan2(y, x)
    k1, k2, u0, v0, mu_x, mu_y = p[6:]
    r = k1 * theta + k2 * theta**3
    uv = np.stack([u0 + mu_x * r * np.cos(phi), v0 + mu_y * r * np.sin(phi)], axis=1)
    return uv, theta


def jacobian(P_laser: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic ((N,2) px, (N,) theta rad, (N,2,12) d(u, v)/dp) by the chain rule.

    Undefined (NaN) for points on the optical axis (x = y = 0).
    """
    p = np.asarray(p, dtype=np.float64)
    R, dR = rotation_jacobian(p[:3])
    d = np.asarray(P_laser, dtype=np.float64) - p[3:6]
    x, y, z = (d @ R).T
    k1, k2, u0, v0, mu_x, mu_y = p[6:]
    rho2 = x * x + y * y
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.sqrt(rho2)
        n2 = rho2 + z * z
        theta = np.arctan2(rho, z)
        c, s = x / rho, y / rho
        r = k1 * theta + k2 * theta**3
        dr = k1 + 3 * k2 * theta**2
        rho3 = rho2 * rho
        dtheta = np.stack([z * x / (rho * n2), z * y / (rho * n2), -rho / n2], axis=1)
        dc = np.stack([y * y / rho3, -x * y / rho3, np.zeros_like(x)], axis=1)
        ds = np.stack([-x * y / rho3, x * x / rho3, np.zeros_like(x)], axis=1)
    JP = np.empty((x.size, 2, 3))  # d(u, v) / d P_c
    JP[:, 0] = mu_x * ((dr * c)[:, None] * dtheta + r[:, None] * dc)
    JP[:, 1] = mu_y * ((dr * s)[:, None] * dtheta + r[:, None] * ds)
    J = np.zeros((x.size, 2, 12))
    for j in range(3):  # dP_c / d angle_j = dR_j^T (P_laser - t)
        J[:, :, j] = np.einsum("nik,nk->ni", JP, d @ dR[j])
    J[:, :, 3:6] = -JP @ R.T  # dP_c / dt = -R^T
    J[:, 0, 6], J[:, 1, 6] = mu_x * theta * c, mu_y * theta * s
    J[:, 0, 7], J[:, 1, 7] = mu_x * theta**3 * c, mu_y * theta**3 * s
    J[:, 0, 8] = 1.0
    J[:, 1, 9] = 1.0
    J[:, 0, 10] = r * c
    J[:, 1, 11] = r * s
    uv = np.stack([u0 + mu_x * r * c, v0 + mu_y * r * s], axis=1)
    return uv, theta, J


def criterion(uv: np.ndarray, origin: tuple[float, float]) -> np.ndarray:
    """(N,) eq. (8): px distance of each pixel from ``origin`` (u_c, v_c)."""
    return np.hypot(uv[:, 0] - origin[0], uv[:, 1] - origin[1])


def sensitivities(
    uv: np.ndarray, J: np.ndarray, p: np.ndarray, origin: tuple[float, float]
) -> npt.NDArray[np.float64]:
    """(N,12) eq. (7): ``∂f/∂p_i · p_i / f`` with f of :func:`criterion`; NaN where
    f < :data:`MIN_CRITERION_PX`."""
    f = criterion(uv, origin)
    du, dv = uv[:, 0] - origin[0], uv[:, 1] - origin[1]
    with np.errstate(invalid="ignore", divide="ignore"):
        df = (du[:, None] * J[:, 0] + dv[:, None] * J[:, 1]) / f[:, None]
        s = df * np.asarray(p)[None, :] / f[:, None]
    s[f < MIN_CRITERION_PX] = np.nan
    sens: npt.NDArray[np.float64] = s
    return sens


def pixel_shift(J: np.ndarray, sigma: np.ndarray) -> npt.NDArray[np.float64]:
    """(N,12) px a point moves for one standard deviation ``sigma`` (12,) of each
    parameter: ``|∂(u, v)/∂p_i| · σ_i``."""
    shift: npt.NDArray[np.float64] = np.hypot(J[:, 0], J[:, 1]) * np.abs(np.asarray(sigma))[None, :]
    return shift


def default_sigma(p: np.ndarray, overrides: Mapping[str, float] | None = None) -> np.ndarray:
    """(12,) standard deviations: 0.1° per angle, 5 mm per translation, 1 % of k1, mu_x,
    mu_y, all of k2, 0.5 px for u0, v0; ``overrides`` by name in the parameters' units."""
    sig = np.array(
        [math.radians(0.1)] * 3
        + [0.005] * 3
        + [0.01 * abs(p[6]), abs(p[7]), 0.5, 0.5, 0.01 * abs(p[10]), 0.01 * abs(p[11])]
    )
    for name, value in (overrides or {}).items():
        if name not in PARAMS:
            raise ValueError(f"--sigma {name}: unknown parameter; expected one of {PARAMS}")
        sig[PARAMS.index(name)] = float(value)
    return sig


def parse_sigma(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` of ``--sigma`` (VALUE in the parameter's unit, see :data:`UNITS`)."""
    name, sep, value = text.partition("=")
    try:
        if not sep:
            raise ValueError
        x = float(value)
    except ValueError:
        raise InputValueError(f"--sigma {text!r}: expected NAME=VALUE, e.g. yaw=0.002") from None
    if name not in PARAMS:
        raise InputValueError(f"--sigma {name}: unknown parameter; expected one of {PARAMS}")
    if not (math.isfinite(x) and x >= 0):
        raise InputValueError(f"--sigma {text!r}: expected a finite value >= 0")
    return name, x


def rotation_axes(angles: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((3,3) rows a_i, (3,) rate_i) for roll, pitch, yaw: the laser-frame unit axis about
    which changing angle i turns R, ``dR_i = rate_i [a_i]x R``, and the rate (rad of
    rotation per rad of the angle, ``|vee(dR_i R^T)|``; 1 for this Euler convention)."""
    R, dR = rotation_jacobian(angles)
    w = np.empty((3, 3))
    for i in range(3):
        S = dR[i] @ R.T
        w[i] = 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])
    rate = np.linalg.norm(w, axis=1)
    return w / rate[:, None], rate


def rotation_sigma(
    angles: Sequence[float] | np.ndarray, cov_w: np.ndarray
) -> npt.NDArray[np.float64]:
    """(3,) σ (rad) of roll, pitch, yaw from the (3,3) covariance (rad²) of the small
    rotation w about the laser axes (``R = exp([w]x) R_hat``): the σ of the rotation about
    each angle's axis a_i (:func:`rotation_axes`), ``sqrt(a_iᵀ Σ_w a_i) / rate_i``."""
    a, rate = rotation_axes(angles)
    var: npt.NDArray[np.float64] = np.einsum(
        "ij,jk,ik->i", a, np.asarray(cov_w, dtype=np.float64), a
    )
    sigma: npt.NDArray[np.float64] = np.sqrt(np.maximum(var, 0.0)) / rate
    return sigma


def calib_sigma(cam: CameraCalib, p: np.ndarray) -> dict[str, float]:
    """σ (:data:`UNITS`) of the parameters ``p`` (:func:`params_from_calib`) that
    ``cam.std`` gives, by name (see the module docstring for the mapping)."""
    std = cam.std
    out: dict[str, float] = {}
    if std.rotation_deg is not None:
        cov_w = np.diag(np.radians(std.rotation_deg) ** 2)
        out |= dict(zip(RIGID[:3], rotation_sigma(p[:3], cov_w).tolist(), strict=True))
    if std.translation_m is not None:
        out |= dict(zip(RIGID[3:], std.translation_m, strict=True))
    m = cam.model
    if std.fx is not None:
        out["k1"] = abs(p[6]) * std.fx / m.fx
        out["mu_x"] = abs(p[10]) * std.fx / m.fx
    if std.fy is not None:
        out["mu_y"] = abs(p[11]) * std.fy / m.fy
    if std.k is not None:
        out["k2"] = abs(p[6]) * std.k[0]
    if std.cx is not None:
        out["u0"] = std.cx
    if std.cy is not None:
        out["v0"] = std.cy
    return out


def choose_sigma(
    p: np.ndarray, cam: CameraCalib, overrides: Mapping[str, float] | None = None
) -> tuple[np.ndarray, tuple[str, ...]]:
    """(12,) σ and where each came from: "override" (``overrides`` by name, in
    :data:`UNITS`), else "calib" (:func:`calib_sigma`), else "default"
    (:func:`default_sigma`)."""
    sig = default_sigma(p, overrides)
    given = calib_sigma(cam, p)
    src = []
    for i, name in enumerate(PARAMS):
        if overrides and name in overrides:
            src.append("override")
        elif name in given:
            sig[i] = given[name]
            src.append("calib")
        else:
            src.append("default")
    return sig, tuple(src)


def format_sigma(s: float, i: int, value: float | None = None) -> str:
    """One σ of parameter ``i`` for people: % of ``value`` for k1, k2, mu_x and mu_y, deg
    for the angles, mm for the translations, else its unit (:data:`UNITS`)."""
    if PARAMS[i] in ("k1", "k2", "mu_x", "mu_y") and value:
        return f"{100 * s / abs(value):.3g} %"
    if UNITS[i] == "rad":
        return f"{math.degrees(s):.2g} deg"
    if UNITS[i] == "m" and PARAMS[i].startswith("t"):
        return f"{s * 1000:.3g} mm"
    if UNITS[i] == "px":
        return f"{s:.2g} px"
    return f"{s:.3g} {UNITS[i]}"


# --- the third-order term (§4.1.2) -------------------------------------------------------


def third_order_px(
    theta: np.ndarray, p: np.ndarray, phi: float = -math.pi / 2
) -> npt.NDArray[np.float64]:
    """px error of dropping ``k2 theta³`` at theta (rad) in image direction phi (rad,
    -pi/2 = up): ``k2 theta³ sqrt((mu_x cos phi)² + (mu_y sin phi)²)``."""
    mu = math.hypot(p[10] * math.cos(phi), p[11] * math.sin(phi))
    return abs(float(p[7])) * mu * np.asarray(theta, dtype=np.float64) ** 3


def table3(
    p: np.ndarray,
    camera_height_m: float = 2.0,
    building_distance_m: float = 10.0,
    thresholds_px: Sequence[float] = DEFAULT_THRESHOLDS_PX,
    heights_m: Sequence[float] = DEFAULT_HEIGHTS_M,
    theta_max: float = math.radians(92.5),
) -> dict[str, Any]:
    """The paper's Table 3 for a camera at ``camera_height_m`` whose optical axis is
    horizontal and perpendicular to a facade ``building_distance_m`` away: a point of the
    facade at height H is at theta = atan((H - h) / D), straight up in the image.

    ``thresholds``: the theta and height at which the third-order error reaches each
    px value (height None when that theta is past 90° or the field of view);
    ``heights``: the error at each height.
    """
    if not (building_distance_m > 0 and math.isfinite(camera_height_m)):
        raise ValueError("building distance must be > 0 m and camera height finite")
    per_rad3 = float(third_order_px(np.array(1.0), p))
    rows = []
    prev = 0.0
    for e in thresholds_px:
        th = (e / per_rad3) ** (1 / 3) if per_rad3 > 0 else math.inf
        seen = th < min(math.pi / 2, theta_max)
        height = camera_height_m + building_distance_m * math.tan(th) if seen else None
        rows.append(
            {
                "error_px": e,
                "theta_from_deg": math.degrees(prev),
                "theta_deg": math.degrees(th) if math.isfinite(th) else None,
                "height_m": height,
            }
        )
        prev = th
    at = []
    for H in heights_m:
        th = math.atan2(H - camera_height_m, building_distance_m)
        at.append(
            {
                "height_m": H,
                "theta_deg": math.degrees(th),
                "error_px": float(third_order_px(np.array(abs(th)), p)),
            }
        )
    return {
        "camera_height_m": camera_height_m,
        "building_distance_m": building_distance_m,
        "third_order_px_at_1rad": per_rad3,
        "thresholds": rows,
        "heights": at,
    }


def format_table3(t: dict[str, Any]) -> list[str]:
    """Table 3 as text lines, the paper's layout plus the error at given heights."""
    lines = [
        f"Table 3: neglecting k2·theta³ ({t['third_order_px_at_1rad']:.3f} px at 1 rad); "
        f"camera {t['camera_height_m']:g} m high, facade {t['building_distance_m']:g} m away",
        f"  {'angle interval':>22}  {'height':>8}  difference",
    ]
    for row in t["thresholds"]:
        th = row["theta_deg"]
        interval = f"{row['theta_from_deg']:.2f}° - " + (f"{th:.2f}°" if th is not None else "-")
        h = f"{row['height_m']:.1f} m" if row["height_m"] is not None else "not seen"
        lines.append(f"  {interval:>22}  {h:>8}  < {row['error_px']:g} px")
    lines.append(
        "  " + "  ".join(f"{r['height_m']:g} m: {r['error_px']:.2f} px" for r in t["heights"])
    )
    return lines


# --- points and statistics ---------------------------------------------------------------


def laser_points(
    ranges: np.ndarray, angle_min: float, angle_increment: float, max_points: int = 200_000
) -> np.ndarray:
    """(N,3) laser-frame m of the finite returns of (S, B) ``ranges`` (REP-103: the scan
    in the x-y plane), evenly thinned to at most ``max_points``."""
    rng = np.asarray(ranges, dtype=np.float64)
    a = angle_min + angle_increment * np.arange(rng.shape[-1])
    a = np.broadcast_to(a, rng.shape)
    ok = np.isfinite(rng) & (rng > 0)
    r, a = rng[ok], a[ok]
    P = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)
    if len(P) > max_points:
        P = P[np.linspace(0, len(P) - 1, max_points).astype(np.int64)]
    return P


def bin_by_theta(
    theta: np.ndarray, values: np.ndarray, bin_deg: float = 2.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """((B,) bin centres deg, (B,) counts, (B,K) NaN-median of |values| (N,K) per bin)."""
    deg = np.degrees(theta)
    edges = np.arange(0.0, deg.max() + bin_deg, bin_deg) if deg.size else np.zeros(1)
    idx = np.clip(np.digitize(deg, edges) - 1, 0, max(len(edges) - 2, 0))
    nb = max(len(edges) - 1, 0)
    med = np.full((nb, values.shape[1]), np.nan)
    counts = np.bincount(idx, minlength=nb)[:nb]
    for b in np.flatnonzero(counts):
        v = np.abs(values[idx == b])
        with np.errstate(all="ignore"):
            if np.isfinite(v).any():
                med[b] = np.nanmedian(np.where(np.isfinite(v), v, np.nan), axis=0)
    return edges[:-1] + bin_deg / 2, counts, med


@dataclass(frozen=True)
class Analysis:
    """Per-point results of :func:`analyze` for the N points that project into the image."""

    params: np.ndarray  # (12,)
    sigma: np.ndarray  # (12,)
    origin: tuple[float, float]  # (u_c, v_c) px of the criterion
    theta: np.ndarray  # (N,) rad
    uv: np.ndarray  # (N,2) px
    jac: np.ndarray  # (N,2,12)
    sens: np.ndarray  # (N,12) eq. 7 (NaN where f < 1 px)
    shift: np.ndarray  # (N,12) px per sigma
    notes: list[str] = field(default_factory=list)
    sigma_source: tuple[str, ...] = ()  # per parameter: "calib", "default" or "override"

    def summary(self) -> list[dict[str, Any]]:
        """Per parameter: value, sigma, median |s|, px per sigma at median and max theta."""
        centres, counts, med = bin_by_theta(self.theta, self.shift)
        th_med = math.degrees(float(np.median(self.theta)))
        b_med = int(np.argmin(np.abs(centres - th_med)))
        b_max = int(np.flatnonzero(counts)[-1])
        out = []
        for i, name in enumerate(PARAMS):
            s = np.abs(self.sens[:, i])
            out.append(
                {
                    "param": name,
                    "unit": UNITS[i],
                    "value": float(self.params[i]),
                    "sigma": float(self.sigma[i]),
                    "sigma_source": self.sigma_source[i] if self.sigma_source else None,
                    "median_abs_s": float(np.nanmedian(s)) if np.isfinite(s).any() else None,
                    "px_per_sigma_median_theta": float(med[b_med, i]),
                    "px_per_sigma_max_theta": float(med[b_max, i]),
                    "px_per_sigma_max": float(self.shift[:, i].max()),
                }
            )
        return out


def analyze(
    P_laser: np.ndarray,
    p: np.ndarray,
    width: int,
    height: int,
    theta_max: float,
    sigma: np.ndarray | None = None,
    origin: str = "principal",
) -> Analysis:
    """Project (N,3) laser points, keep those that land in the (width, height) image
    within ``theta_max`` rad of the axis, and compute eq. (7) and the px per sigma.

    ``origin`` of eq. (8): "principal" (the nominal u0, v0, the default), "centre"
    ((width - 1) / 2, (height - 1) / 2) or "corner" (pixel (0, 0), eq. 8 as printed).
    """
    origins = {
        "principal": (float(p[8]), float(p[9])),
        "centre": ((width - 1) / 2, (height - 1) / 2),
        "corner": (0.0, 0.0),
    }
    if origin not in origins:
        raise ValueError(f"origin {origin!r}: expected one of {sorted(origins)}")
    uv, theta, J = jacobian(P_laser, p)
    u, v = uv[:, 0], uv[:, 1]
    ok = np.isfinite(u) & np.isfinite(v) & (theta <= theta_max)
    ok &= (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)
    ok &= np.isfinite(J).all(axis=(1, 2))
    uv, theta, J = uv[ok], theta[ok], J[ok]
    sig = default_sigma(p) if sigma is None else np.asarray(sigma, dtype=np.float64)
    o = origins[origin]
    return Analysis(
        params=np.asarray(p, dtype=np.float64),
        sigma=sig,
        origin=o,
        theta=theta,
        uv=uv,
        jac=J,
        sens=sensitivities(uv, J, p, o),
        shift=pixel_shift(J, sig),
    )
