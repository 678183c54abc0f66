"""The vehicle's pose at any time: poses (vehicle -> world) sampled on the host clock and
interpolated on SE(3) (:class:`Trajectory`), built from wheel odometry
(:func:`from_odometry`), GNSS fixes (:func:`gnss_track`, :func:`from_gnss`), both fused
(:func:`fuse`), or a post-processed GNSS/INS file (:func:`from_csv`, :func:`to_csv`).

Frames. The vehicle frame is REP-103 ``base_link``: x forward, y left, z up (as
``acq.sim.world.Trajectory``). A pose maps it into a world frame, ``P_world = R @ P_vehicle
+ t`` (an :data:`acq.geometry.transforms.PoseFn`). World frames (:class:`WorldFrame`):

- ``"odometry"``: where dead reckoning starts (the ``start`` pose, identity by default);
  x, y the plane the vehicle drives in, z up.
- ``"enu"``: the local tangent plane at ``origin`` = (latitude °, longitude °,
  ellipsoidal height m) on WGS-84: x east, y north, z up.
- a projected CRS (``"EPSG:25832"``, anything ``pyproj.CRS`` takes): x grid east, y grid
  north, z the ellipsoidal height (unless the CRS has its own vertical datum), minus the
  ``origin`` offset (x0, y0, z0), zero by default. Grid metres are not metres: the
  scale factor (UTM: 0.9996 to 1.0004) is not applied to the points around the vehicle.

Times are host ``CLOCK_MONOTONIC`` ns (int64) unless a name ends in ``_s``; UTC is
POSIX seconds (float64). Angles are radians except in files (degrees).

Interpolation (:meth:`Trajectory.pose_at`): rotations by slerp, exact for a constant
angular velocity between samples; translations linearly. Linear, not cubic Hermite:
between samples 10-20 ms apart the chord of a curve is off the curve by a v²κ dt²/8
(at 20 km/h in a 10 m radius bend sampled at 50 Hz: 0.15 mm), far below a laser's
noise, and Hermite needs velocities consistent with the positions, which fused or
post-processed files do not guarantee. :func:`from_odometry` can put arc-exact samples
between sparse inputs (``step_s``) instead. Outside the sampled span (and inside gaps
longer than ``max_gap_s``) :meth:`~Trajectory.pose_at` raises :class:`OutOfSpanError`
rather than return wrong poses; ``margin_s`` (at most :data:`MAX_EXTRAPOLATION_S`)
extrapolates the end intervals' motion a little; :meth:`~Trajectory.covers` flags.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numba
import numpy as np
import numpy.typing as npt

from acq.errors import AcqError, InputError
from acq.geometry.transforms import Rigid, euler_from_matrices, matrices_from_euler
from acq.time import gpstime

if TYPE_CHECKING:
    import pyproj

    from acq.records import Fix

__all__ = [
    "MAX_EXTRAPOLATION_S",
    "Fusion",
    "GnssTrack",
    "OutOfSpanError",
    "Trajectory",
    "TrajectoryFileError",
    "WorldFrame",
    "dead_reckon",
    "euler_from_matrices",
    "from_csv",
    "from_gnss",
    "from_odometry",
    "fuse",
    "gnss_from_fixes",
    "gnss_track",
    "host_ns_from_utc",
    "laser_poses",
    "matrices_from_euler",
    "matrix_from_quat",
    "quat_from_matrix",
    "speed_from_wheels",
    "to_csv",
    "yaw_rate_from_wheels",
]

MAX_EXTRAPOLATION_S = 0.5  # s, the most Trajectory.margin_s may extrapolate past an end

Hold = Literal["forward", "mean"]


class OutOfSpanError(AcqError, ValueError):
    """Times at which a trajectory has no pose: before its start, after its end (beyond
    ``margin_s``) or inside a gap longer than its ``max_gap_s``."""


class TrajectoryFileError(InputError, ValueError):
    """A trajectory file that cannot be read; the message names the file, line and
    column."""


# --- rotations, vectorised -------------------------------------------------------------


def quat_from_matrix(R: npt.ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) unit quaternions (w, x, y, z), w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    r00, r01, r02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    r10, r11, r12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    r20, r21, r22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # Shepperd: divide by the largest of 4|w|, 4|x|, 4|y|, 4|z|
    cands = np.stack(
        [
            np.stack([1 + r00 + r11 + r22, r21 - r12, r02 - r20, r10 - r01], axis=-1),
            np.stack([r21 - r12, 1 + r00 - r11 - r22, r01 + r10, r02 + r20], axis=-1),
            np.stack([r02 - r20, r01 + r10, 1 - r00 + r11 - r22, r12 + r21], axis=-1),
            np.stack([r10 - r01, r02 + r20, r12 + r21, 1 - r00 - r11 + r22], axis=-1),
        ],
        axis=-2,
    )  # (..., 4 cases, 4 components): case k is 4 q_k q
    k = np.argmax(np.stack([cands[..., i, i] for i in range(4)], axis=-1), axis=-1)
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def matrix_from_quat(q: npt.ArrayLike, out: np.ndarray | None = None) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotations."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty((*q.shape[:-1], 3, 3)) if out is None else out
    x2, y2, z2 = 2 * x, 2 * y, 2 * z
    xx, yy, zz = x * x2, y * y2, z * z2
    xy, xz, yz = x * y2, x * z2, y * z2
    wx, wy, wz = w * x2, w * y2, w * z2
    R[..., 0, 0] = 1 - yy - zz
    R[..., 0, 1] = xy - wz
    R[..., 0, 2] = xz + wy
    R[..., 1, 0] = xy + wz
    R[..., 1, 1] = 1 - xx - zz
    R[..., 1, 2] = yz - wx
    R[..., 2, 0] = xz - wy
    R[..., 2, 1] = yz + wx
    R[..., 2, 2] = 1 - xx - yy
    return R


def _rot_z(yaw: np.ndarray) -> np.ndarray:
    """(N,3,3) rotations about z by ``yaw`` (N,) rad."""
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((yaw.size, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


# NED/FRD attitude (heading clockwise from north, pitch nose up, roll right side down) to
# ENU/FLU: R_enu_flu = _NED_TO_ENU @ R_ned_frd @ _FLU_TO_FRD
_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def _ned_to_enu(R_ned: np.ndarray) -> np.ndarray:
    return np.einsum("ij,njk,kl->nil", _NED_TO_ENU, R_ned, _FLU_TO_FRD)


# --- world frames --------------------------------------------------------------------


@lru_cache(maxsize=16)
def _transformer(name: str, origin: tuple[float, float, float]) -> pyproj.Transformer:
    """Geodetic (lon °, lat °, h m on WGS-84) -> the frame's axes (before any offset)."""
    import pyproj

    if name == "enu":
        lat0, lon0, h0 = origin
        return pyproj.Transformer.from_pipeline(
            "+proj=pipeline +step +proj=cart +ellps=WGS84 "
            f"+step +proj=topocentric +ellps=WGS84 +lat_0={lat0!r} +lon_0={lon0!r} +h_0={h0!r}"
        )
    try:
        crs = pyproj.CRS.from_user_input(name)
    except pyproj.exceptions.CRSError as e:
        raise ValueError(f"unknown frame {name!r}: not 'odometry', 'enu' or a CRS ({e})") from e
    if not crs.is_projected:
        raise ValueError(f"frame {name!r} is not a projected CRS (metres east, north)")
    return pyproj.Transformer.from_crs("EPSG:4979", crs, always_xy=True)


@dataclass(frozen=True)
class WorldFrame:
    """A world frame by name (``"odometry"``, ``"enu"``, a CRS) and its ``origin``
    ((lat °, lon °, h m) of an ENU plane; the (x0, y0, z0) offset of a projected CRS)."""

    name: str = "odometry"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        o = tuple(float(v) for v in self.origin)
        if len(o) != 3 or not all(math.isfinite(v) for v in o):
            raise ValueError(f"origin must be 3 finite numbers, got {self.origin!r}")
        object.__setattr__(self, "origin", o)
        if self.name == "enu" and not (-90.0 <= o[0] <= 90.0):
            raise ValueError(f"an ENU origin is (lat, lon, h); latitude {o[0]} is out of range")
        if self.georeferenced:
            _transformer(self.name, self._key())  # fail early on an unknown CRS

    @property
    def georeferenced(self) -> bool:
        """False for the odometry frame (no relation to the Earth)."""
        return self.name != "odometry"

    def _key(self) -> tuple[float, float, float]:
        return self.origin if self.name == "enu" else (0.0, 0.0, 0.0)

    def _offset(self) -> np.ndarray:
        return np.zeros(3) if self.name == "enu" else np.asarray(self.origin)

    def _need_geo(self) -> None:
        if not self.georeferenced:
            raise ValueError("the odometry frame is not tied to the Earth: no geodetic coordinates")

    def from_geodetic(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
    ) -> np.ndarray:
        """WGS-84 latitude, longitude (°), ellipsoidal height (m) -> (N,3) m in this frame."""
        self._need_geo()
        lat, lon, h = np.broadcast_arrays(
            *(np.asarray(a, dtype=np.float64).reshape(-1) for a in (lat_deg, lon_deg, h_m))
        )
        x, y, z = _transformer(self.name, self._key()).transform(lon, lat, h)
        return np.stack([x, y, z], axis=1) - self._offset()

    def to_geodetic(self, xyz: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N,3) m in this frame -> (latitude °, longitude °, ellipsoidal height m)."""
        self._need_geo()
        P = np.asarray(xyz, dtype=np.float64).reshape(-1, 3) + self._offset()
        lon, lat, h = _transformer(self.name, self._key()).transform(
            P[:, 0], P[:, 1], P[:, 2], direction="INVERSE"
        )
        return np.asarray(lat), np.asarray(lon), np.asarray(h)

    def rotation_from_local_enu(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
    ) -> np.ndarray:
        """(N,3,3) rotations taking vectors in the local ENU at each point into this
        frame's axes: exact for an ENU frame (the tangent planes' tilt); for a projected
        CRS the turn from true to grid north (meridian convergence), by differences."""
        self._need_geo()
        lat, lon, h = np.broadcast_arrays(
            *(np.asarray(a, dtype=np.float64).reshape(-1) for a in (lat_deg, lon_deg, h_m))
        )
        if self.name == "enu":
            return _ecef_to_enu(self.origin[0], self.origin[1])[None] @ np.swapaxes(
                _ecef_to_enu(lat, lon), -1, -2
            )
        d = 1e-6  # degrees of latitude, ~0.1 m
        n = self.from_geodetic(lat + d, lon, h) - self.from_geodetic(lat - d, lon, h)
        # local north (ENU angle pi/2) points along n in the grid
        return _rot_z(np.arctan2(n[:, 1], n[:, 0]) - math.pi / 2)


def _ecef_to_enu(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotation ECEF -> local ENU at geodetic (lat, lon) degrees."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    zero = np.zeros_like(sl)
    return np.stack(
        [
            np.stack([-so, co, zero], axis=-1),
            np.stack([-sl * co, -sl * so, cl], axis=-1),
            np.stack([cl * co, cl * so, sl], axis=-1),
        ],
        axis=-2,
    )


# --- the trajectory ------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Vehicle -> world poses at host times, interpolated between them.

    ``t_ns`` (N,) int64 strictly increasing host monotonic ns, N >= 2; ``rotation``
    (N,3,3) and ``translation`` (N,3) m: ``P_world = R @ P_vehicle + t``. ``frame`` and
    ``origin`` name the world (:class:`WorldFrame`). ``max_gap_s``: intervals longer than
    this have no pose inside them (a gap in the source data); ``margin_s`` (s, at most
    :data:`MAX_EXTRAPOLATION_S`): how far past the ends the first and last intervals'
    motion is extrapolated. Arrays are stored read-only.
    """

    t_ns: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    frame: str = "odometry"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_gap_s: float = math.inf
    margin_s: float = 0.0
    _table: np.ndarray = field(init=False, repr=False)
    _gap: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns)
        if not np.issubdtype(t.dtype, np.integer):
            raise ValueError(f"t_ns must be integer ns, got {t.dtype}")
        t = t.astype(np.int64).reshape(-1)
        R = np.asarray(self.rotation, dtype=np.float64)
        p = np.asarray(self.translation, dtype=np.float64)
        n = t.size
        if n < 2:
            raise ValueError(f"a trajectory needs at least 2 poses, got {n}")
        if R.shape != (n, 3, 3) or p.shape != (n, 3):
            raise ValueError(
                f"{n} times need rotation ({n},3,3) and translation ({n},3), "
                f"got {R.shape} and {p.shape}"
            )
        dt = np.diff(t)
        if (dt <= 0).any():
            i = int(np.argmax(dt <= 0))
            raise ValueError(f"t_ns must increase strictly: sample {i + 1} is not after {i}")
        if not (np.isfinite(R).all() and np.isfinite(p).all()):
            raise ValueError("rotation and translation must be finite")
        err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max()
        if err > 1e-6 or (np.linalg.det(R) < 0).any():
            raise ValueError(f"rotations must be proper rotations (|R R^T - I| = {err:.2g})")
        if not 0.0 <= self.margin_s <= MAX_EXTRAPOLATION_S:
            raise ValueError(f"margin_s must be in [0, {MAX_EXTRAPOLATION_S}] s")
        if not self.max_gap_s > 0:
            raise ValueError("max_gap_s must be > 0")
        world = WorldFrame(self.frame, self.origin)  # validates
        for name, arr in (("t_ns", t), ("rotation", R), ("translation", p)):
            arr = arr.copy() if arr is getattr(self, name) else arr
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "origin", world.origin)
        object.__setattr__(self, "_table", _interval_table(self.t_ns, R, p))
        gap = dt > self.max_gap_s * 1e9
        gap.flags.writeable = False
        object.__setattr__(self, "_gap", gap)

    def __len__(self) -> int:
        return int(self.t_ns.size)

    @property
    def world(self) -> WorldFrame:
        return WorldFrame(self.frame, self.origin)

    @property
    def start_ns(self) -> int:
        return int(self.t_ns[0])

    @property
    def end_ns(self) -> int:
        return int(self.t_ns[-1])

    @property
    def gaps(self) -> list[tuple[int, int]]:
        """(start ns, end ns) of the intervals longer than ``max_gap_s``."""
        i = np.flatnonzero(self._gap)
        return [(int(self.t_ns[k]), int(self.t_ns[k + 1])) for k in i]

    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interval index (clipped to the ends) and the out-of-span mask of flat ``t``."""
        idx = np.searchsorted(self.t_ns, t, side="right") - 1
        np.clip(idx, 0, self.t_ns.size - 2, out=idx)
        m = round(self.margin_s * 1e9)
        bad = (t < self.t_ns[0] - m) | (t > self.t_ns[-1] + m)
        if self._gap.any():
            g = self._gap[idx]
            if g.any():
                bad |= g & (t != self.t_ns[idx]) & (t != self.t_ns[idx + 1])
        return idx, bad

    def covers(self, t_ns: npt.ArrayLike) -> np.ndarray:
        """Bool mask (shape of ``t_ns``): True where :meth:`pose_at` gives a pose."""
        t = np.asarray(t_ns)
        if t.dtype.kind not in "iu":
            raise TypeError(f"t_ns must be integer host ns, got {t.dtype}")
        t = t.astype(np.int64, copy=False)
        return ~self._locate(t.reshape(-1))[1].reshape(t.shape)

    def pose_at(self, t_ns: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Poses at host ns ``t_ns`` (any shape S): rotations S+(3,3), translations S+(3,)
        m, vehicle -> world. Raises :class:`OutOfSpanError` if any time is not covered."""
        t = np.asarray(t_ns)
        if t.dtype.kind not in "iu":
            raise TypeError(f"t_ns must be integer host ns, got {t.dtype}")
        shape = t.shape
        flat = t.astype(np.int64, copy=False).reshape(-1)
        idx, bad = self._locate(flat)
        if bad.any():
            raise OutOfSpanError(self._describe(flat, bad))
        R = np.empty((flat.size, 3, 3))
        trans = np.empty((flat.size, 3))
        _slerp_lerp(flat, idx, self.t_ns, self._table, R, trans)
        return R.reshape((*shape, 3, 3)), trans.reshape((*shape, 3))

    __call__ = pose_at

    def transform(self, t_ns: npt.ArrayLike, points: npt.ArrayLike) -> np.ndarray:
        """Vehicle-frame ``points`` (N,3) m, each measured at its host ns ``t_ns`` (N,),
        into the world: ``R(t) p + t(t)`` as :meth:`pose_at` gives, without the (N,3,3)
        rotations in memory (2 M points: a fifth of the time). Raises
        :class:`OutOfSpanError` as :meth:`pose_at`."""
        t = np.asarray(t_ns)
        if t.dtype.kind not in "iu":
            raise TypeError(f"t_ns must be integer host ns, got {t.dtype}")
        flat = t.astype(np.int64, copy=False).reshape(-1)
        P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        if P.shape[0] != flat.size:
            raise ValueError(f"{flat.size} times but {P.shape[0]} points")
        idx, bad = self._locate(flat)
        if bad.any():
            raise OutOfSpanError(self._describe(flat, bad))
        out = np.empty_like(P)
        _slerp_apply(flat, idx, self.t_ns, self._table, P, out)
        return out

    def _describe(self, t: np.ndarray, bad: np.ndarray) -> str:
        i = int(np.argmax(bad))
        t0, t1 = self.start_ns, self.end_ns
        k = float(t[i])
        if k < t0:
            where = f"{(t0 - k) * 1e-9:.3f} s before the start"
        elif k > t1:
            where = f"{(k - t1) * 1e-9:.3f} s after the end"
        else:
            j = int(np.searchsorted(self.t_ns, t[i], side="right")) - 1
            gap = (self.t_ns[j + 1] - self.t_ns[j]) * 1e-9
            where = (
                f"in a gap of {gap:.3f} s at {(self.t_ns[j] - t0) * 1e-9:.3f} s "
                f"(max_gap_s {self.max_gap_s} s)"
            )
        return (
            f"{int(bad.sum())} of {bad.size} times have no pose: the first, {int(t[i])} ns, "
            f"is {where}; the trajectory spans {t0} .. {t1} ns ({(t1 - t0) * 1e-9:.3f} s, "
            f"margin {self.margin_s} s); use covers() to flag such times"
        )

    def resample(self, t_ns: npt.ArrayLike) -> Trajectory:
        """The same trajectory sampled at ``t_ns`` (strictly increasing, covered)."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        R, p = self.pose_at(t)
        return Trajectory(t, R, p, self.frame, self.origin, self.max_gap_s, self.margin_s)

    def with_lever_arm(
        self, laser_to_vehicle: Rigid
    ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """A pose function of the laser (laser -> world) at host ns; see :func:`laser_poses`."""

        def poses(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return laser_poses(self, t_ns, laser_to_vehicle)

        return poses


def _interval_table(t: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N-1, 16) per interval: q0 (4), q_perp (4), half-angle theta, p0 (3), p1 (3),
    dt (ns). Slerp: ``q(a) = cos(a theta) q0 + sin(a theta) q_perp``, q_perp the unit
    quaternion orthogonal to q0 in the plane of q0 and q1 (zero when they coincide)."""
    q = quat_from_matrix(R)
    q0, q1 = q[:-1], q[1:].copy()
    d = np.einsum("ij,ij->i", q0, q1)
    q1[d < 0] *= -1  # the shorter way round
    d = np.abs(d)
    perp = q1 - d[:, None] * q0
    norm = np.linalg.norm(perp, axis=1)
    theta = np.arctan2(norm, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        perp = np.where(norm[:, None] > 0, perp / norm[:, None], 0.0)
    tab = np.empty((t.size - 1, 16))
    tab[:, 0:4], tab[:, 4:8], tab[:, 8] = q0, perp, theta
    tab[:, 9:12], tab[:, 12:15] = p[:-1], p[1:]
    tab[:, 15] = np.diff(t).astype(np.float64)
    return tab


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _pose_in(t, t_samples, tab, i):  # type: ignore[no-untyped-def]
    """The pose at time t in interval i of the table (see _interval_table): the rotation
    matrix's nine entries row by row, then the position's three."""
    a = np.float64(t - t_samples[i]) / tab[i, 15]  # exactly 1 at the end
    ang = a * tab[i, 8]
    c = np.cos(ang)
    s = np.sin(ang)
    w = c * tab[i, 0] + s * tab[i, 4]
    x = c * tab[i, 1] + s * tab[i, 5]
    y = c * tab[i, 2] + s * tab[i, 6]
    z = c * tab[i, 3] + s * tab[i, 7]
    x2, y2, z2 = 2.0 * x, 2.0 * y, 2.0 * z
    xx, yy, zz = x * x2, y * y2, z * z2
    xy, xz, yz = x * y2, x * z2, y * z2
    wx, wy, wz = w * x2, w * y2, w * z2
    b = 1.0 - a  # exact at both ends
    return (
        1.0 - yy - zz, xy - wz, xz + wy,
        xy + wz, 1.0 - xx - zz, yz - wx,
        xz - wy, yz + wx, 1.0 - xx - yy,
        b * tab[i, 9] + a * tab[i, 12], b * tab[i, 10] + a * tab[i, 13],
        b * tab[i, 11] + a * tab[i, 14],
    )  # fmt: skip


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _slerp_lerp(t, idx, t_samples, tab, R, p):  # type: ignore[no-untyped-def]
    """Pose n at time t[n] in interval idx[n] of the table (see _interval_table)."""
    for n in range(t.size):
        r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = _pose_in(
            t[n], t_samples, tab, idx[n]
        )
        R[n, 0, 0], R[n, 0, 1], R[n, 0, 2] = r00, r01, r02
        R[n, 1, 0], R[n, 1, 1], R[n, 1, 2] = r10, r11, r12
        R[n, 2, 0], R[n, 2, 1], R[n, 2, 2] = r20, r21, r22
        p[n, 0], p[n, 1], p[n, 2] = px, py, pz


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _slerp_apply(t, idx, t_samples, tab, P, out):  # type: ignore[no-untyped-def]
    """out[n] = R(t[n]) P[n] + p(t[n]), the pose as in _slerp_lerp."""
    for n in range(t.size):
        r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = _pose_in(
            t[n], t_samples, tab, idx[n]
        )
        x, y, z = P[n, 0], P[n, 1], P[n, 2]
        out[n, 0] = r00 * x + r01 * y + r02 * z + px
        out[n, 1] = r10 * x + r11 * y + r12 * z + py
        out[n, 2] = r20 * x + r21 * y + r22 * z + pz


def laser_poses(
    traj: Trajectory, t_ns: npt.ArrayLike, laser_to_vehicle: Rigid
) -> tuple[np.ndarray, np.ndarray]:
    """Laser -> world at host ns: the vehicle's interpolated pose composed with the
    lever arm and boresight (calib.yaml ``laser_to_vehicle``, ``P_vehicle = R P_laser +
    t``), so a lever arm swings exactly with the vehicle's rotation."""
    R, p = traj.pose_at(t_ns)
    return R @ laser_to_vehicle.rotation, p + R @ laser_to_vehicle.translation


# --- odometry --------------------------------------------------------------------------

_WHEELS = {"front": (0, 1), "rear": (2, 3), "all": (0, 1, 2, 3)}


def speed_from_wheels(
    wheel_speeds: npt.ArrayLike, which: Literal["rear", "front", "all"] = "rear"
) -> np.ndarray:
    """(N,) vehicle speed, m/s, from (N,4) wheel speeds (m/s) ordered front-left,
    front-right, rear-left, rear-right: the mean of the ``which`` wheels. The rear
    wheels' mean is the speed of the rear axle's centre, where a car's velocity points
    along x (no sideslip: :func:`from_odometry`'s ``rear_axle_x_m``); the front wheels
    run wider in a bend (by 1/cos of the steering angle)."""
    w = np.asarray(wheel_speeds, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 4:
        raise ValueError(f"wheel_speeds must be (N,4) FL, FR, RL, RR, got shape {w.shape}")
    if which not in _WHEELS:
        raise ValueError(f"which must be one of {', '.join(_WHEELS)}, got {which!r}")
    return w[:, list(_WHEELS[which])].mean(axis=1)


def yaw_rate_from_wheels(
    wheel_speeds: npt.ArrayLike, track_m: float, which: Literal["rear", "front"] = "rear"
) -> np.ndarray:
    """(N,) yaw rate, rad/s counter-clockwise, from the ``which`` axle's wheel speeds
    ((N,4) m/s, FL FR RL RR) and its track width (m): ``(right - left) / track``. Wheel
    slip and tyre radius differences bias it; a gyro's yaw rate is better."""
    w = np.asarray(wheel_speeds, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 4:
        raise ValueError(f"wheel_speeds must be (N,4) FL, FR, RL, RR, got shape {w.shape}")
    if which not in ("rear", "front") or not track_m > 0:
        raise ValueError("which must be 'rear' or 'front' and track_m > 0")
    left, right = _WHEELS[which]
    return (w[:, right] - w[:, left]) / track_m


def dead_reckon(
    dt_s: np.ndarray, speed: np.ndarray, yaw_rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planar dead reckoning over intervals ``dt_s`` (M,) s with constant ``speed`` (m/s)
    and ``yaw_rate`` (rad/s) in each: exact arcs (``chord = v dt sinc(w dt / 2)`` at the
    mid heading). Returns x, y (m) and heading (rad) (M+1,) from (0, 0, 0)."""
    dpsi = yaw_rate * dt_s
    psi = np.concatenate([[0.0], np.cumsum(dpsi)])
    chord = speed * dt_s * np.sinc(dpsi / (2 * math.pi))
    mid = psi[:-1] + 0.5 * dpsi
    x = np.concatenate([[0.0], np.cumsum(chord * np.cos(mid))])
    y = np.concatenate([[0.0], np.cumsum(chord * np.sin(mid))])
    return x, y, psi


def _odometry_arrays(
    t_ns: npt.ArrayLike, speed_mps: npt.ArrayLike, yaw_rate_rps: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(t_ns)
    if t.dtype.kind not in "iu":
        raise TypeError(f"t_ns must be integer host ns, got {t.dtype}")
    t = t.astype(np.int64).reshape(-1)
    v = np.asarray(speed_mps, dtype=np.float64).reshape(-1)
    w = np.asarray(yaw_rate_rps, dtype=np.float64).reshape(-1)
    if not (t.size == v.size == w.size):
        raise ValueError(f"t_ns, speed, yaw_rate lengths differ: {t.size}, {v.size}, {w.size}")
    if t.size < 2:
        raise ValueError(f"odometry needs at least 2 samples, got {t.size}")
    if not (np.isfinite(v).all() and np.isfinite(w).all()):
        i = int(np.argmin(np.isfinite(v) & np.isfinite(w)))
        raise ValueError(f"odometry sample {i} is not finite (speed {v[i]}, yaw rate {w[i]})")
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise ValueError(f"odometry times must increase strictly: sample {i + 1} is not after {i}")
    return t, v, w


def _integrate(
    t: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    hold: Hold,
    max_gap_s: float,
    on_gap: str,
    step_s: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Host ns of the output samples and the rear axle's x, y (m), heading (rad) there."""
    if hold not in ("forward", "mean"):
        raise ValueError(f"hold must be 'forward' or 'mean', got {hold!r}")
    if on_gap not in ("raise", "flag"):
        raise ValueError(f"on_gap must be 'raise' or 'flag', got {on_gap!r}")
    dt_ns = np.diff(t)
    gap = dt_ns > max_gap_s * 1e9
    if gap.any() and on_gap == "raise":
        i = int(np.argmax(gap))
        raise ValueError(
            f"odometry gap of {dt_ns[i] * 1e-9:.3f} s after sample {i} "
            f"({(t[i] - t[0]) * 1e-9:.3f} s in; max_gap_s {max_gap_s} s): "
            "dead reckoning across it is a guess (on_gap='flag' bridges and flags it)"
        )
    if hold == "forward":
        vi, wi = v[:-1], w[:-1]
    else:
        vi, wi = 0.5 * (v[:-1] + v[1:]), 0.5 * (w[:-1] + w[1:])
    t_out = t
    if step_s is not None:
        if not step_s > 0:
            raise ValueError("step_s must be > 0")
        n_sub = np.where(gap, 1, np.ceil(dt_ns / (step_s * 1e9))).astype(np.int64)
        n_sub = np.maximum(n_sub, 1)
        k = np.arange(int(n_sub.sum())) - np.repeat(np.cumsum(n_sub) - n_sub, n_sub)
        sub = (np.repeat(dt_ns, n_sub) * k) // np.repeat(n_sub, n_sub)
        t_out = np.append(np.repeat(t[:-1], n_sub) + sub, t[-1])
        vi, wi = np.repeat(vi, n_sub), np.repeat(wi, n_sub)
    x, y, psi = dead_reckon(np.diff(t_out) * 1e-9, vi, wi)
    return t_out, x, y, psi


def from_odometry(
    t_ns: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    *,
    start: Rigid | None = None,
    hold: Hold = "mean",
    max_gap_s: float = 0.5,
    on_gap: Literal["raise", "flag"] = "raise",
    step_s: float | None = None,
    rear_axle_x_m: float = 0.0,
) -> Trajectory:
    """Planar dead reckoning of speed (m/s, of the rear axle's centre, along the
    vehicle's x) and yaw rate (rad/s, counter-clockwise) sampled at host ns ``t_ns``.

    Each interval is integrated exactly as an arc with constant inputs: ``hold``
    "forward" takes a sample's values until the next sample (exact for piecewise-constant
    inputs), "mean" the mean of the interval's two ends (second order for smooth
    inputs). Irregular sampling is fine. An interval longer than ``max_gap_s`` raises
    ValueError (``on_gap="raise"``) or is bridged with the held inputs and flagged: the
    trajectory has no pose inside it, and the poses after it carry the guess's error
    (``"flag"``). ``step_s`` adds arc-exact samples so that no other interval is longer.
    ``rear_axle_x_m``: the vehicle-frame x of the rear axle's centre (the one point of a
    car that moves along x without sideslip); the pose is the vehicle origin's. The first
    pose is ``start`` (frame "odometry", identity by default); roll and pitch stay
    ``start``'s.
    """
    t, v, w = _odometry_arrays(t_ns, speed_mps, yaw_rate_rps)
    t_out, x, y, psi = _integrate(t, v, w, hold, max_gap_s, on_gap, step_s)
    if rear_axle_x_m:  # origin = axle - Rz(psi) (rear_axle_x_m, 0), and (0, 0) at start
        x = x - rear_axle_x_m * (np.cos(psi) - 1.0)
        y = y - rear_axle_x_m * np.sin(psi)
    start = Rigid.identity() if start is None else start
    R = start.rotation @ _rot_z(psi)
    p = np.stack([x, y, np.zeros_like(x)], axis=1) @ start.rotation.T + start.translation
    return Trajectory(t_out, R, p, "odometry", max_gap_s=max_gap_s)


# --- GNSS ----------------------------------------------------------------------------


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
    ``quality`` (GGA fix quality) below ``min_quality``, non-finite values or a repeated
    time are dropped. ``sigma_m`` is ``hdop * uere_m`` (``uere_m`` when hdop is unknown).
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
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(alt)
    if quality is not None:
        ok &= np.asarray(quality).reshape(-1) >= min_quality
    order = np.argsort(t[ok], kind="stable")
    keep = np.flatnonzero(ok)[order]
    if keep.size == 0:
        raise ValueError("no usable GNSS fix (all invalid, non-finite or below min_quality)")
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
    fix time mapped by ``utc_to_host_ns`` (e.g. ``lambda u: host_ns_from_utc(u, clock)``)
    when given, else its receipt time ``recv_ns``, which is late by the receiver's output
    latency (often 50-100 ms: 0.3-0.6 m at 20 km/h)."""
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
) -> Trajectory:
    """GNSS alone: positions at the fixes (the antenna taken as the vehicle origin),
    heading along the velocity of a line fitted to the fixes within ``smooth_s``/2 of
    each (weighted by 1/sigma²), held where slower than ``min_speed_mps``; roll and
    pitch zero; intervals between fixes longer than ``max_gap_s`` are gaps. The heading
    is noisy (1.4 m fixes at 5 Hz, 6 m/s, 2 s: ~0.1 rad) and lags in turns by nothing
    but bends by the curvature within the window: prefer :func:`fuse` with odometry."""
    if len(track) < 3:
        raise ValueError("from_gnss needs at least 3 fixes")
    t, P = track.t_ns, track.xyz
    ts = (t - t[0]) * 1e-9
    w = 1.0 / track.sigma_m**2
    lo = np.searchsorted(ts, ts - smooth_s / 2, side="left")
    hi = np.searchsorted(ts, ts + smooth_s / 2, side="right")

    def window_sum(x: np.ndarray) -> np.ndarray:
        c = np.concatenate([[0.0], np.cumsum(x)])
        return c[hi] - c[lo]

    sw, st, stt = window_sum(w), window_sum(w * ts), window_sum(w * ts * ts)
    # centred about each fix's own time for conditioning: sum w (t - t_k)^2 etc.
    st_c = st - sw * ts
    stt_c = stt - 2 * ts * st + sw * ts**2
    den = sw * stt_c - st_c**2
    vel = np.zeros((ts.size, 2))
    for k in range(2):
        sx, stx = window_sum(w * P[:, k]), window_sum(w * ts * P[:, k])
        stx_c = stx - ts * sx
        with np.errstate(invalid="ignore", divide="ignore"):
            vel[:, k] = (sw * stx_c - st_c * sx) / den
    moving = np.isfinite(vel).all(axis=1) & (np.hypot(vel[:, 0], vel[:, 1]) >= min_speed_mps)
    if not moving.any():
        raise ValueError(f"the vehicle never moves faster than {min_speed_mps} m/s: no heading")
    yaw = np.unwrap(np.arctan2(vel[moving, 1], vel[moving, 0]))
    yaw = np.interp(ts, ts[moving], yaw)
    return Trajectory(t, _rot_z(yaw), P, track.frame, track.origin, max_gap_s=max_gap_s)


@dataclass(frozen=True, eq=False)
class Fusion:
    """The result of :func:`fuse`: the ``trajectory`` (in the GNSS frame), the odometry's
    estimated ``speed_scale`` and ``yaw_rate_bias_rps`` (subtracted), ``used`` (K,) the
    fixes that entered the fit (inside the odometry's span, not rejected), the
    horizontal ``residual_rms_m`` of the used fixes, and ``outages``: (start, end) host
    ns of the spans longer than ``window_s``/4 without a used fix (the odometry's ends
    included), bridged by calibrated odometry alone."""

    trajectory: Trajectory
    speed_scale: float
    yaw_rate_bias_rps: float
    used: np.ndarray
    residual_rms_m: float
    outages: list[tuple[int, int]]


def _procrustes_2d(
    src: np.ndarray, dst: np.ndarray, w: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted rigid 2D fit ``dst ~ c_dst + Rz(theta) (src - c_src)``: theta, c_src, c_dst."""
    ws = w / w.sum()
    cs, cd = ws @ src, ws @ dst
    a, b = src - cs, dst - cd
    cross = ws @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    dot = ws @ (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    return math.atan2(cross, dot), cs, cd


def _rot2(theta: np.ndarray | float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _window_weights(t: np.ndarray, knots: np.ndarray, half_s: float) -> np.ndarray:
    """(J, K) triangular weights of fix times ``t`` (s) around knot times (s)."""
    return np.clip(1.0 - np.abs(t[None, :] - knots[:, None]) / half_s, 0.0, None)


def fuse(
    t_ns: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    gnss: GnssTrack,
    *,
    antenna_m: npt.ArrayLike = (0.0, 0.0, 0.0),
    window_s: float = 40.0,
    calibrate: bool = True,
    min_fixes: int = 5,
    heading_prior_rad: float = 0.05,
    reject: float = 4.0,
    hold: Hold = "mean",
    max_gap_s: float = 0.5,
    on_gap: Literal["raise", "flag"] = "raise",
    step_s: float | None = None,
) -> Fusion:
    """Odometry (as :func:`from_odometry`, ``rear_axle_x_m`` 0) fitted to GNSS fixes: a
    drift-correcting, piecewise rigid alignment weighted by each fix's ``sigma_m``.

    1. Calibration (``calibrate``): one speed scale and one yaw-rate bias for the whole
       drive, with the heading and offset that best align the dead-reckoned antenna
       track (``antenna_m``: the antenna in the vehicle frame, m) to the fixes, by
       weighted Gauss-Newton, the bias started from the trend of per-window headings.
       Without it, the heading and offset alone.
    2. Windows: knots every ``window_s``/2; at each, the fixes within ``window_s``/2 of
       it (triangular weights, so every fix counts in two windows, its weights summing
       to 1) give a small rigid correction: a turn about the window's
       centroid (with a prior of ``heading_prior_rad``, so that a window too short or
       straight to fix it leaves it near zero) and a horizontal and vertical offset.
       Between knots the corrected positions and headings blend linearly; a knot whose
       window has fewer than ``min_fixes`` fixes is skipped (an outage: odometry bridges
       it). Fixes off by more than ``reject`` robust sigmas are dropped and all refitted.

    The result is sampled at the odometry's times, in the GNSS frame. Limits (it is not
    an INS): roll and pitch stay zero (on a 5 % grade a point 20 m away is ~1 m too high
    or low); heights are the windows' mean GNSS heights; the speed scale and bias are
    constant over the drive; within a window the odometry's own errors remain; a fix's
    time must be right (latency x speed is a position error); the fixes' errors are
    taken as independent, which multipath and atmospheric errors are not.
    """
    t, v, w = _odometry_arrays(t_ns, speed_mps, yaw_rate_rps)
    if not window_s > 0 or min_fixes < 2:
        raise ValueError("window_s must be > 0 and min_fixes >= 2")
    ant = np.asarray(antenna_m, dtype=np.float64).reshape(3)
    base = from_odometry(t, v, w, hold=hold, max_gap_s=max_gap_s, on_gap=on_gap, step_s=step_s)
    inside = base.covers(gnss.t_ns)
    if int(inside.sum()) < min_fixes:
        raise ValueError(
            f"only {int(inside.sum())} GNSS fixes fall inside the odometry's span "
            f"(need {min_fixes}): are both on the same host clock?"
        )
    tk, zk, sk = gnss.t_ns[inside], gnss.xyz[inside], gnss.sigma_m[inside]
    wk = 1.0 / sk**2
    ts = (tk - t[0]) * 1e-9
    span_s = (t[-1] - t[0]) * 1e-9
    knots = np.linspace(0.0, span_s, max(1, math.ceil(span_s / (window_s / 2))) + 1)
    W = _window_weights(ts, knots, window_s / 2)

    def antenna_xy(scale: float, bias: float) -> np.ndarray:
        """The antenna's dead-reckoned x, y at the fix times (odometry frame)."""
        t_out, x, y, psi = _integrate(t, v * scale, w - bias, hold, max_gap_s, on_gap, step_s)
        x, y, psi = (np.interp(tk, t_out, a) for a in (x, y, psi))
        c, s = np.cos(psi), np.sin(psi)
        return np.column_stack([x + c * ant[0] - s * ant[1], y + s * ant[0] + c * ant[1]])

    scale, bias = 1.0, 0.0
    active = np.ones(tk.size, dtype=bool)
    if calibrate:
        bias = _initial_bias(antenna_xy(1.0, 0.0), zk[:, :2], wk, ts, W)
    for rnd in range(3):  # fit, drop outliers, fit again
        wa = wk * active
        if calibrate:
            scale, bias = _calibrate(antenna_xy, zk[:, :2], wa, W, scale, bias)
        a_xy = antenna_xy(scale, bias)
        theta0, cs, cd = _procrustes_2d(a_xy, zk[:, :2], wa)
        dz0 = float(wa @ (zk[:, 2] - ant[2]) / wa.sum())
        align = _Knot(theta0, cs, np.array([*(cd - cs), dz0]))  # p -> cd + R (p - cs)
        a1 = align.apply(np.column_stack([a_xy, np.full(tk.size, ant[2])]))
        fits = _knot_fits(a1, zk, wa, W, min_fixes, heading_prior_rad)
        fused = _blend(fits, knots, ts, a1)
        r = np.hypot(*(fused[:, :2] - zk[:, :2]).T) / sk
        robust = float(np.median(r[active])) / 1.1774  # Rayleigh: median = 1.1774 sigma
        keep = r <= reject * max(robust, 1.0)
        if rnd == 2 or (keep == active).all():
            break
        active = keep

    traj = from_odometry(
        t, v * scale, w - bias, hold=hold, max_gap_s=max_gap_s, on_gap=on_gap, step_s=step_s
    )
    t_s = (traj.t_ns - t[0]) * 1e-9
    p = _blend(fits, knots, t_s, align.apply(traj.translation))
    R = _rot_z(theta0 + _blend_theta(fits, knots, t_s)) @ traj.rotation
    out = Trajectory(traj.t_ns, R, p, gnss.frame, gnss.origin, max_gap_s=traj.max_gap_s)
    used = np.zeros(len(gnss), dtype=bool)
    used[np.flatnonzero(inside)[active]] = True
    res = np.hypot(*(fused[active, :2] - zk[active, :2]).T)
    edges = np.concatenate([[t[0]], tk[active], [t[-1]]])
    long = np.flatnonzero(np.diff(edges) > window_s / 4 * 1e9)
    outages = [(int(edges[i]), int(edges[i + 1])) for i in long]
    return Fusion(out, scale, bias, used, float(np.sqrt(np.mean(res**2))), outages)


def _initial_bias(
    a: np.ndarray, z: np.ndarray, w: np.ndarray, ts: np.ndarray, W: np.ndarray
) -> float:
    """A yaw-rate bias guess (rad/s) from the trend of per-window headings: a bias b
    turns the dead-reckoned track by b t, so the windows' corrections go as -b t."""
    th, tc, wt = [], [], []
    for row in W:
        ww = row * w
        sel = ww > 0
        if sel.sum() < 3 or np.ptp(a[sel], axis=0).max() < 5.0:
            continue  # heading unobservable: too few fixes, or standing still
        theta, _, _ = _procrustes_2d(a[sel], z[sel], ww[sel])
        th.append(theta)
        tc.append(float(ww @ ts / ww.sum()))
        wt.append(float(ww.sum()))
    if len(th) < 2:
        return 0.0
    slope = np.polyfit(np.array(tc), np.unwrap(np.array(th)), 1, w=np.sqrt(np.array(wt)))[0]
    return float(-slope)


def _calibrate(
    antenna_xy: Callable[[float, float], np.ndarray],
    z: np.ndarray,
    w: np.ndarray,
    W: np.ndarray,
    scale: float,
    bias: float,
) -> tuple[float, float]:
    """Gauss-Newton on (speed scale, yaw-rate bias), each window's best rigid 2D
    alignment of the trial track to its fixes solved inside (a variable projection):
    the scale shows in the windows' lengths, the bias in their curvature, so a slowly
    wandering bias does not bend the scale as one alignment of the whole drive would."""
    knot, fix = np.nonzero(W * (w > 0))
    pw = W[knot, fix] * w[fix]  # a fix counts in two windows, its weights summing to 1
    n_knots = W.shape[0]
    enough = np.bincount(knot, minlength=n_knots) >= 3
    sel = enough[knot]
    knot, fix, pw = knot[sel], fix[sel], pw[sel]
    sq = np.sqrt(pw)
    zc = z - z.mean(axis=0)  # Procrustes ignores shifts; large CRS numbers cancel badly
    Z = zc[fix]

    def wsum(x: np.ndarray) -> np.ndarray:
        return np.bincount(knot, weights=pw * x, minlength=n_knots)

    sw = np.maximum(wsum(np.ones(knot.size)), 1e-300)
    cd = np.column_stack([wsum(Z[:, 0]), wsum(Z[:, 1])]) / sw[:, None]

    def residual(s: float, b: float) -> np.ndarray:
        a = antenna_xy(s, b)
        A = (a - a.mean(axis=0))[fix]
        cs = np.column_stack([wsum(A[:, 0]), wsum(A[:, 1])]) / sw[:, None]
        cross = wsum(A[:, 0] * Z[:, 1] - A[:, 1] * Z[:, 0]) / sw - (
            cs[:, 0] * cd[:, 1] - cs[:, 1] * cd[:, 0]
        )
        dot = wsum(A[:, 0] * Z[:, 0] + A[:, 1] * Z[:, 1]) / sw - np.einsum("ij,ij->i", cs, cd)
        th = np.arctan2(cross, dot)[knot]
        c, si = np.cos(th), np.sin(th)
        d = A - cs[knot]
        rx = c * d[:, 0] - si * d[:, 1] + cd[knot, 0] - Z[:, 0]
        ry = si * d[:, 0] + c * d[:, 1] + cd[knot, 1] - Z[:, 1]
        return np.concatenate([rx * sq, ry * sq])

    r0 = residual(scale, bias)
    for _ in range(20):
        hs, hb = 1e-4, 1e-5
        J = np.column_stack(
            [
                (residual(scale + hs, bias) - residual(scale - hs, bias)) / (2 * hs),
                (residual(scale, bias + hb) - residual(scale, bias - hb)) / (2 * hb),
            ]
        )
        step = np.linalg.lstsq(J, -r0, rcond=None)[0]
        lam = 1.0
        while True:  # halve the step until the cost drops
            r1 = residual(scale + lam * step[0], bias + lam * step[1])
            if r1 @ r1 <= r0 @ r0 or lam < 1e-3:
                break
            lam /= 2
        if r1 @ r1 > r0 @ r0:
            break
        scale, bias, r0 = scale + lam * step[0], bias + lam * step[1], r1
        if abs(lam * step[0]) < 1e-9 and abs(lam * step[1]) < 1e-10:
            break
    if not 0.5 < scale < 2.0:
        raise ValueError(f"odometry speed scale {scale:.3f} against GNSS: wrong units or data?")
    return float(scale), float(bias)


@dataclass(frozen=True)
class _Knot:
    theta: float  # rad, turn about centre
    centre: np.ndarray  # (2,) m
    offset: np.ndarray  # (3,) m, added after the turn

    def apply(self, P: np.ndarray) -> np.ndarray:
        out = np.empty_like(P)
        out[:, :2] = (P[:, :2] - self.centre) @ _rot2(self.theta).T + self.centre + self.offset[:2]
        out[:, 2] = P[:, 2] + self.offset[2]
        return out


def _knot_fits(
    a: np.ndarray,
    z: np.ndarray,
    w: np.ndarray,
    W: np.ndarray,
    min_fixes: int,
    prior: float,
) -> list[_Knot | None]:
    """Per knot (row of ``W``): the turn (with a zero-mean prior of sd ``prior`` rad)
    about the window's weighted centroid and the offset taking the antenna points ``a``
    to the fixes ``z``; None where fewer than ``min_fixes`` fixes have weight."""
    out: list[_Knot | None] = []
    for row in W:
        ww = row * w
        sel = ww > 0
        if int(sel.sum()) < min_fixes:
            out.append(None)
            continue
        aa, zz, ws = a[sel], z[sel], ww[sel] / ww[sel].sum()
        c = ws @ aa[:, :2]
        d = aa[:, :2] - c
        wsum = float(ww[sel].sum())
        theta = 0.0
        for _ in range(3):  # Gauss-Newton, the turn linearised about theta
            rd = d @ _rot2(theta).T
            r = zz[:, :2] - c - rd
            r -= ws @ r  # the offset (uncorrelated with the turn about the centroid)
            g = np.column_stack([-rd[:, 1], rd[:, 0]])
            num = wsum * float(ws @ np.einsum("ij,ij->i", g, r)) - theta / prior**2
            den = wsum * float(ws @ np.einsum("ij,ij->i", g, g)) + 1.0 / prior**2
            theta += num / den
        off = ws @ (zz[:, :2] - c - d @ _rot2(theta).T)
        dz = float(ws @ (zz[:, 2] - aa[:, 2]))
        out.append(_Knot(theta, c, np.array([off[0], off[1], dz])))
    return out


def _valid(fits: list[_Knot | None], knots: np.ndarray) -> tuple[np.ndarray, list[_Knot]]:
    idx = [i for i, k in enumerate(fits) if k is not None]
    if not idx:
        raise ValueError("no window has enough GNSS fixes to align the odometry")
    return knots[idx], [fits[i] for i in idx]  # type: ignore[misc]


def _blend(fits: list[_Knot | None], knots: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Points ``P`` (N,3) at times ``t`` (s) through the two nearest knots' transforms,
    weighted linearly in time (held at the ends; outages bridged)."""
    times, valid = _valid(fits, knots)
    out = np.zeros_like(P)
    if len(valid) == 1:
        return valid[0].apply(P)
    j = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
    a = np.clip((t - times[j]) / (times[j + 1] - times[j]), 0.0, 1.0)
    for i, k in enumerate(valid):  # a loop over knots, not points
        wi = np.where(j == i, 1.0 - a, 0.0) + np.where(j + 1 == i, a, 0.0)
        sel = np.flatnonzero(wi > 0)
        if sel.size:
            out[sel] += wi[sel, None] * k.apply(P[sel])
    return out


def _blend_theta(fits: list[_Knot | None], knots: np.ndarray, t: np.ndarray) -> np.ndarray:
    times, valid = _valid(fits, knots)
    return np.interp(t, times, [k.theta for k in valid])


# --- clocks ----------------------------------------------------------------------------


def host_ns_from_utc(utc_s: npt.ArrayLike, clock: np.ndarray) -> np.ndarray:
    """UTC seconds (POSIX, float64) -> host monotonic ns (int64) with the log's (monotonic
    ns, realtime ns) pairs: the inverse of :func:`acq.time.utc.utc_seconds` (offset
    interpolated between pairs, held at the ends). Good to the float's resolution
    (~0.25 µs today). Raises ValueError without pairs, or where the wall clock was
    stepped back so far that a UTC time names two host times."""
    u = np.asarray(utc_s, dtype=np.float64)
    clock = np.asarray(clock, dtype=np.int64).reshape(-1, 2)
    if clock.shape[0] == 0:
        raise ValueError("no (monotonic, realtime) clock pairs: UTC cannot be mapped to host time")
    if not np.isfinite(u).all():
        raise ValueError("UTC times must be finite")
    order = np.argsort(clock[:, 0], kind="stable")
    mono = clock[order, 0]
    off = clock[order, 1] - mono
    u_pair = mono + off
    if (np.diff(u_pair) <= 0).any():
        i = int(np.argmax(np.diff(u_pair) <= 0))
        raise ValueError(
            f"the wall clock went back between clock pairs {i} and {i + 1}: UTC is ambiguous there"
        )
    sec = np.floor(u)
    u_ns = sec.astype(np.int64) * 10**9 + np.rint((u - sec) * 1e9).astype(np.int64)
    rel = (u_ns - u_pair[0]).astype(np.float64)
    m = mono[0] + np.rint(
        np.interp(rel, (u_pair - u_pair[0]).astype(np.float64), (mono - mono[0]).astype(np.float64))
    ).astype(np.int64)
    m = np.where(u_ns < u_pair[0], u_ns - off[0], m)
    return np.where(u_ns > u_pair[-1], u_ns - off[-1], m)


# --- files -----------------------------------------------------------------------------

_TIME_COLS = (("time",), ("gps_week", "gps_sow"))
_POS_COLS = (("x", "y", "z"), ("lat", "lon", "h"))
_ATT_COLS = (("roll", "pitch", "yaw"), ("roll", "pitch", "heading"))


def _fail(path: Path, line: int, msg: str) -> TrajectoryFileError:
    return TrajectoryFileError(f"{path}:{line}: {msg}")


def _pick_cols(
    path: Path, line: int, header: list[str], sets: tuple[tuple[str, ...], ...], what: str
) -> tuple[str, ...]:
    found = [s for s in sets if all(c in header for c in s)]
    if not found:
        want = " or ".join(",".join(s) for s in sets)
        raise _fail(path, line, f"no {what} columns: the header needs {want}")
    if what == "position" and len(found) > 1:
        raise _fail(path, line, "both x,y,z and lat,lon,h columns: keep one set")
    if what == "attitude" and len(found) > 1:
        raise _fail(path, line, "both yaw and heading columns: keep one")
    return found[0]


def _parse_time(s: str) -> float:
    try:
        return float(s)
    except ValueError:
        pass
    dt = datetime.fromisoformat(s)
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def _read_rows(
    path: Path, names: list[str], header_line: int, header: list[str]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Columns ``names`` as float64 arrays (``time`` may be ISO-8601) and each row's line
    number; errors name the line and column."""
    cols = {n: header.index(n) for n in names}
    values: dict[str, list[float]] = {n: [] for n in names}
    lines: list[int] = []
    with path.open(newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        for row in reader:
            line = reader.line_num
            if line <= header_line or not row or row[0].lstrip().startswith("#"):
                continue
            if len(row) < len(header):
                raise _fail(path, line, f"{len(row)} fields, the header has {len(header)}")
            for n, i in cols.items():
                s = row[i].strip()
                try:
                    x = _parse_time(s) if n == "time" else float(s)
                except ValueError:
                    kind = "UTC seconds or an ISO-8601 time" if n == "time" else "a number"
                    raise _fail(
                        path, line, f"column {n!r} (column {i + 1}): {s!r} is not {kind}"
                    ) from None
                if not math.isfinite(x):
                    raise _fail(path, line, f"column {n!r} (column {i + 1}): {s!r} is not finite")
                values[n].append(x)
            lines.append(line)
    return {n: np.array(v, dtype=np.float64) for n, v in values.items()}, np.array(lines)


def _header(path: Path) -> tuple[int, list[str], dict[str, tuple[str, int]]]:
    """(line number of the header, lower-case column names, ``# key: value`` comments
    before it with their line numbers)."""
    meta: dict[str, tuple[str, int]] = {}
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            for n, text in enumerate(f, start=1):
                s = text.strip()
                if not s:
                    continue
                if s.startswith("#"):
                    key, sep, val = s[1:].partition(":")
                    if sep:
                        meta[key.strip().lower()] = (val.strip(), n)
                    continue
                header = [c.strip().lower() for c in next(csv.reader([s]))]
                dup = sorted({c for c in header if header.count(c) > 1})
                if dup:
                    raise _fail(path, n, f"repeated column {dup[0]!r}")
                return n, header, meta
    except UnicodeDecodeError as e:
        raise TrajectoryFileError(f"{path}: not a text file ({e})") from None
    raise TrajectoryFileError(f"{path}: empty: no header line")


def from_csv(
    path: str | os.PathLike[str],
    *,
    utc_to_host_ns: Callable[[np.ndarray], np.ndarray],
    frame: str | None = None,
    origin: tuple[float, float, float] | None = None,
    max_gap_s: float = math.inf,
    margin_s: float = 0.0,
) -> Trajectory:
    """A post-processed GNSS/INS trajectory from a CSV file with a header.

    Columns (case-insensitive, in any order, others ignored):

    - time: ``time`` (UTC: POSIX seconds, or ISO-8601 such as 2024-05-02T10:00:00.25Z;
      without a zone, UTC) or ``gps_week,gps_sow`` (full GPS week, seconds of week);
    - position: ``x,y,z`` (m, in ``frame``; a projected CRS's full coordinates) or
      ``lat,lon,h`` (WGS-84 °, ellipsoidal m, put into ``frame``, default "enu" at the
      first row);
    - attitude, degrees, of the vehicle frame (x forward, y left, z up): ``roll,pitch,yaw``
      as :func:`acq.geometry.transforms.rotation_from_euler` (``Rz(yaw) Ry(pitch) Rx(roll)``; yaw
      counter-clockwise from east, or from the frame's x axis with x,y,z) or
      ``roll,pitch,heading``, the NED convention of most INS (heading clockwise from
      north, or from the frame's y axis with x,y,z; pitch nose up; roll right side down;
      of a forward-right-down body).

    ``# frame: NAME`` and ``# origin: a, b, c`` comment lines before the header (what
    :func:`to_csv` writes) give the frame where the arguments do not. UTC becomes host
    ns by ``utc_to_host_ns`` (e.g. ``lambda u: host_ns_from_utc(u, clock)``). Raises
    :class:`TrajectoryFileError` naming the file, line and column.
    """
    path = Path(path)
    try:
        header_line, header, meta = _header(path)
    except OSError as e:
        raise TrajectoryFileError(f"{path}: {e.strerror or e}") from None
    tcols = _pick_cols(path, header_line, header, _TIME_COLS, "time")
    pcols = _pick_cols(path, header_line, header, _POS_COLS, "position")
    acols = _pick_cols(path, header_line, header, _ATT_COLS, "attitude")
    data, lines = _read_rows(path, [*tcols, *pcols, *acols], header_line, header)
    if lines.size < 2:
        raise _fail(path, header_line, f"{lines.size} data rows: a trajectory needs 2")
    if tcols == ("time",):
        utc = data["time"]
    else:
        utc = gpstime.gps_week_sow_to_utc(data["gps_week"], data["gps_sow"])
    t = np.asarray(utc_to_host_ns(utc), dtype=np.int64).reshape(-1)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise _fail(path, int(lines[i]), f"time {float(utc[i])!r} is not after the previous row's")

    file_frame = meta["frame"][0] if "frame" in meta else None
    name = frame if frame is not None else file_frame
    if origin is None and "origin" in meta and (frame is None or frame == file_frame):
        text, line = meta["origin"]
        try:
            parsed = [float(v) for v in text.split(",")]
        except ValueError:
            parsed = []
        if len(parsed) != 3:
            raise _fail(path, line, f"'# origin: {text}' is not 3 numbers")
        origin = (parsed[0], parsed[1], parsed[2])
    if pcols == ("lat", "lon", "h"):
        lat, lon, h = data["lat"], data["lon"], data["h"]
        if name is None:
            name = "enu"
        if origin is None:
            origin = (lat[0], lon[0], h[0]) if name == "enu" else (0.0, 0.0, 0.0)
        try:
            world = WorldFrame(name, origin)
            P = world.from_geodetic(lat, lon, h)
            to_frame = world.rotation_from_local_enu(lat, lon, h)
        except ValueError as e:
            raise TrajectoryFileError(f"{path}: {e}") from None
    else:
        if name is None:
            raise _fail(
                path,
                header_line,
                "x,y,z columns need a frame: frame='EPSG:...' (or 'enu' with its origin, "
                "or 'odometry'), or a '# frame:' line",
            )
        if frame is not None and file_frame not in (None, frame):
            raise _fail(
                path,
                meta["frame"][1],
                f"the file's frame is {file_frame!r}, not {frame!r} (x,y,z are not reprojected)",
            )
        if name == "enu" and origin is None:
            raise _fail(path, header_line, "x,y,z in 'enu' need its origin (lat, lon, h)")
        try:
            world = WorldFrame(name, origin if origin is not None else (0.0, 0.0, 0.0))
        except ValueError as e:
            raise TrajectoryFileError(f"{path}: {e}") from None
        offset = np.zeros(3) if world.name in ("enu", "odometry") else np.asarray(world.origin)
        P = np.column_stack([data["x"], data["y"], data["z"]]) - offset
        to_frame = None
    roll, pitch = np.radians(data["roll"]), np.radians(data["pitch"])
    if "yaw" in acols:
        R = matrices_from_euler(roll, pitch, np.radians(data["yaw"]))
    else:
        R = _ned_to_enu(matrices_from_euler(roll, pitch, np.radians(data["heading"])))
    if to_frame is not None:
        R = to_frame @ R
    return Trajectory(t, R, P, world.name, world.origin, max_gap_s=max_gap_s, margin_s=margin_s)


def to_csv(
    path: str | os.PathLike[str],
    traj: Trajectory,
    *,
    host_to_utc: Callable[[np.ndarray], np.ndarray],
    t_ns: npt.ArrayLike | None = None,
) -> int:
    """Write ``traj`` (at its samples, or at ``t_ns``) as ``time,x,y,z,roll,pitch,yaw``:
    UTC POSIX seconds by ``host_to_utc`` (e.g. ``lambda t: utc_seconds(t, clock)``),
    metres in the trajectory's frame (a CRS's full coordinates), degrees as
    :func:`from_csv` reads them, with ``# frame:`` and ``# origin:`` lines. Returns the
    number of rows."""
    t = traj.t_ns if t_ns is None else np.asarray(t_ns, dtype=np.int64).reshape(-1)
    R, p = traj.pose_at(t)
    world = traj.world
    if world.name not in ("enu", "odometry"):
        p = p + np.asarray(world.origin)
    utc = np.asarray(host_to_utc(t), dtype=np.float64)
    if not np.isfinite(utc).all():
        raise ValueError("host_to_utc gave non-finite UTC times (a log without clock pairs?)")
    roll, pitch, yaw = (np.degrees(a) for a in euler_from_matrices(R))
    with Path(path).open("w", newline="") as f:
        f.write(f"# frame: {world.name}\n")
        if world.name != "odometry":
            f.write("# origin: " + ", ".join(repr(v) for v in world.origin) + "\n")
        f.write("time,x,y,z,roll,pitch,yaw\n")
        for i in range(t.size):
            f.write(
                f"{float(utc[i])!r},{p[i, 0]:.6f},{p[i, 1]:.6f},{p[i, 2]:.6f},"
                f"{roll[i]:.9f},{pitch[i]:.9f},{yaw[i]:.9f}\n"
            )
    return int(t.size)
