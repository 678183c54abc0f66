"""GNSS: fixes into a world frame (:class:`GnssTrack`, :func:`gnss_track`,
:func:`gnss_from_fixes`), and a trajectory from them alone (:func:`from_gnss`). Times are
host monotonic ns (int64); positions WGS-84 degrees and ellipsoidal metres in, metres in
the frame out."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from acq.errors import InputValueError
from acq.geometry.geodesy import WorldFrame
from acq.geometry.rotations import matrices_from_euler
from acq.motion.trajectory import Trajectory

if TYPE_CHECKING:
    from acq.records import Fix

__all__ = [
    "GnssTrack",
    "NoHeadingError",
    "from_gnss",
    "gnss_from_fixes",
    "gnss_track",
    "local_quadratic",
    "usable_fixes",
]


class NoHeadingError(InputValueError):
    """GNSS alone gives no heading: the vehicle never moves fast enough (parked)."""


def usable_fixes(
    lat_deg: npt.ArrayLike,
    lon_deg: npt.ArrayLike,
    alt_m: npt.ArrayLike,
    quality: npt.ArrayLike | None = None,
    min_quality: int = 1,
) -> np.ndarray:
    """Which fixes are usable (bool): finite, latitude within ±90°, longitude within
    ±180°, and GGA fix ``quality`` at least ``min_quality`` when given."""
    lat, lon, alt = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (lat_deg, lon_deg, alt_m))
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(alt) & (np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0)
    if quality is not None:
        ok &= np.asarray(quality).reshape(-1) >= min_quality
    return np.asarray(ok, dtype=bool)


@dataclass(frozen=True, eq=False)
class GnssTrack:
    """GNSS antenna positions: ``t_ns`` (K,) int64 host ns (increasing), ``xyz`` (K,3) m
    in the world frame ``frame``/``origin``, ``sigma_m`` (K,) the horizontal 1-sigma of
    each fix, m (hdop x the user range error)."""

    t_ns: np.ndarray
    xyz: np.ndarray
    sigma_m: np.ndarray
    frame: str
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def world(self) -> WorldFrame:
        return WorldFrame(self.frame, self.origin)

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns, dtype=np.int64).reshape(-1)
        xyz = np.asarray(self.xyz, dtype=np.float64)
        sigma = np.asarray(self.sigma_m, dtype=np.float64).reshape(-1)
        if xyz.shape != (t.size, 3) or sigma.shape != t.shape:
            raise ValueError(f"{t.size} fix times need xyz ({t.size},3) and sigma_m ({t.size},)")
        if (np.diff(t) <= 0).any() or not (sigma > 0).all():
            raise ValueError("fix times must increase strictly and sigma_m be > 0")
        for name, arr in (("t_ns", t), ("xyz", xyz), ("sigma_m", sigma)):
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "origin", WorldFrame(self.frame, self.origin).origin)

    def __len__(self) -> int:
        return int(self.t_ns.size)


def gnss_track(
    t_ns: npt.ArrayLike,
    lat_deg: npt.ArrayLike,
    lon_deg: npt.ArrayLike,
    alt_m: npt.ArrayLike,
    *,
    frame: str = "enu",
    origin: tuple[float, float, float] | None = None,
    hdop: npt.ArrayLike | None = None,
    quality: npt.ArrayLike | None = None,
    min_quality: int = 1,
    uere_m: float = 1.0,
) -> GnssTrack:
    """GNSS fixes (host ns; WGS-84 °; ellipsoidal height m) into a world frame via pyproj.

    ``frame`` "enu" puts the tangent plane at ``origin`` (lat, lon, h; default the first
    usable fix) or a projected CRS (``origin`` its offset, default zero). Fixes with
    ``quality`` (GGA fix quality) below ``min_quality``, non-finite or out-of-range
    values (:func:`usable_fixes`) or a repeated time are dropped. ``sigma_m`` is
    ``hdop * uere_m`` (``uere_m`` when hdop is unknown).
    """
    t = np.asarray(t_ns)
    if t.dtype.kind not in "iu":
        raise TypeError(f"t_ns must be integer host ns, got {t.dtype}")
    t = t.astype(np.int64).reshape(-1)
    lat, lon, alt = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (lat_deg, lon_deg, alt_m))
    if not (t.size == lat.size == lon.size == alt.size):
        raise ValueError("t_ns, lat, lon, alt lengths differ")
    hd = np.ones(t.size) if hdop is None else np.asarray(hdop, dtype=np.float64).reshape(-1)
    hd = np.where(np.isfinite(hd) & (hd > 0), hd, 1.0)
    ok = usable_fixes(lat, lon, alt, quality, min_quality)
    order = np.argsort(t[ok], kind="stable")
    keep = np.flatnonzero(ok)[order]
    if keep.size == 0:
        raise InputValueError(
            "no usable GNSS fix (all invalid, non-finite, out of range or below min_quality)"
        )
    keep = keep[np.concatenate([[True], np.diff(t[keep]) > 0])]
    if origin is None:
        origin = (lat[keep[0]], lon[keep[0]], alt[keep[0]]) if frame == "enu" else (0, 0, 0)
    world = WorldFrame(frame, origin)
    xyz = world.from_geodetic(lat[keep], lon[keep], alt[keep])
    return GnssTrack(t[keep], xyz, hd[keep] * uere_m, world.name, world.origin)


def gnss_from_fixes(
    fixes: Sequence[Fix],
    *,
    utc_to_host_ns: Callable[[np.ndarray], np.ndarray] | None = None,
    **kw: Any,
) -> GnssTrack:
    """:func:`gnss_track` of :class:`acq.records.Fix` records. A fix's time is its UTC
    fix time mapped by ``utc_to_host_ns`` (e.g. ``lambda u: host_ns_from_utc(u, clock)``,
    :func:`acq.time.utc.host_ns_from_utc`) when given, else its receipt time ``recv_ns``,
    which is late by the receiver's output latency (often 50-100 ms: 0.3-0.6 m at
    20 km/h)."""
    if utc_to_host_ns is not None:
        t = np.asarray(utc_to_host_ns(np.array([f.utc_s for f in fixes])), dtype=np.int64)
    else:
        t = np.array([f.recv_ns for f in fixes], dtype=np.int64)
    return gnss_track(
        t,
        [f.latitude for f in fixes],
        [f.longitude for f in fixes],
        [f.altitude for f in fixes],
        hdop=[f.hdop for f in fixes],
        quality=[f.quality for f in fixes],
        **kw,
    )


def from_gnss(
    track: GnssTrack,
    *,
    smooth_s: float = 2.0,
    min_speed_mps: float = 1.0,
    max_gap_s: float = 2.0,
    course_rad: npt.ArrayLike | None = None,
) -> Trajectory:
    """GNSS alone: at each fix, a quadratic in time fitted to the fixes within
    ``smooth_s``/2 of it (weighted by 1/sigma²) gives the position (the antenna taken
    as the vehicle origin) and the velocity; the heading is along the velocity, held
    where slower than ``min_speed_mps``, or the receiver's ``course_rad`` (K,) (rad
    clockwise from north, NaN where not sent) where too few fixes lie in the window for
    a fit; roll and pitch zero; intervals between fixes longer than ``max_gap_s`` are
    gaps. The quadratic follows a curve without the bias a line has (10 cm lateral
    acceleration over 2 s: 2 cm); the heading is noisy with fixes of metres (1.4 m at
    5 Hz, 6 m/s, 2 s: ~0.1 rad): prefer :func:`fuse` with odometry there.

    No fix weighs more than 9 times the track's typical one (its sigma floored at a
    third of the median): a receiver's claimed accuracy is not trusted blindly. Reject
    outliers first with :func:`acq.motion.gnss_outliers.screen_fixes`.
    :class:`NoHeadingError` when the vehicle never moves (a parked drive)."""
    if len(track) < 3:
        raise InputValueError(f"GNSS alone needs at least 3 usable fixes, got {len(track)}")
    t, P = track.t_ns, track.xyz
    ts = (t - t[0]) * 1e-9
    pos, vel = local_quadratic(ts, P, 1.0 / _trusted_sigma(track.sigma_m) ** 2, smooth_s / 2)
    speed = np.hypot(vel[:, 0], vel[:, 1])
    yaw = np.full(ts.size, np.nan)
    moving = np.isfinite(speed) & (speed >= min_speed_mps)
    yaw[moving] = np.arctan2(vel[moving, 1], vel[moving, 0])
    if course_rad is not None:
        course = np.asarray(course_rad, dtype=np.float64).reshape(-1)
        if course.shape != ts.shape:
            raise ValueError(f"course_rad needs one value per fix ({ts.size}), got {course.shape}")
        take = ~np.isfinite(speed) & np.isfinite(course)
        yaw[take] = np.pi / 2 - course[take]  # clockwise from north -> from east, ENU
        moving |= take
    if not moving.any():
        raise NoHeadingError(
            f"GNSS alone gives no heading: the vehicle never moves faster than "
            f"{min_speed_mps} m/s over the {len(track)} fixes (parked?) and the receiver "
            "sends no course"
        )
    yaw = np.interp(ts, ts[moving], np.unwrap(yaw[moving]))
    return Trajectory(
        t, matrices_from_euler(0.0, 0.0, yaw), pos, track.frame, track.origin, max_gap_s=max_gap_s
    )


def _trusted_sigma(sigma_m: np.ndarray) -> np.ndarray:
    """``sigma_m`` (m) floored at a third of its median."""
    return np.asarray(np.maximum(sigma_m, np.median(sigma_m) / 3.0), dtype=np.float64)


def local_quadratic(
    ts: np.ndarray, P: np.ndarray, w: np.ndarray, half_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per sample k, the weighted least-squares quadratic in (t - t_k) through the samples
    within ``half_s`` of t_k: its value (K,3) and its first derivative (K,3) at t_k.
    Where the window holds fewer than 3 samples: the sample itself and a NaN velocity."""
    # near the ends the window is shifted inside the data, keeping its width
    first, last = float(ts[0]), float(ts[-1])
    start = np.clip(ts - half_s, first, max(first, last - 2 * half_s))
    lo = np.searchsorted(ts, start, side="left")
    hi = np.searchsorted(ts, start + 2 * half_s, side="right")
    n = hi - lo
    idx = lo[:, None] + np.arange(int(n.max()))[None, :]
    inside = idx < hi[:, None]
    idx = np.minimum(idx, ts.size - 1)
    tau = np.where(inside, ts[idx] - ts[:, None], 0.0)
    ww = np.where(inside, w[idx], 0.0)
    powers = tau[..., None] ** np.arange(3)  # (K, W, 3): 1, tau, tau^2
    A = np.einsum("kw,kwi,kwj->kij", ww, powers, powers)
    b = np.einsum("kw,kwi,kwc->kic", ww, powers, P[idx])
    pos, vel = P.astype(np.float64).copy(), np.full(P.shape, np.nan)
    ok = (n >= 3) & (np.linalg.cond(A) < 1e12)
    coef = np.linalg.solve(A[ok], b[ok])  # (k, 3 powers, 3 axes)
    pos[ok], vel[ok] = coef[:, 0], coef[:, 1]
    return pos, vel
