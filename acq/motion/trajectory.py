"""The vehicle's pose at any time: poses (vehicle -> world) sampled on the host clock and
interpolated on SE(3) (:class:`Trajectory`), and the laser's pose through its lever arm
(:func:`laser_poses`). The sources of poses are beside this module: wheel odometry
(:mod:`acq.motion.odometry`), GNSS (:mod:`acq.motion.gnss`), both fused
(:mod:`acq.motion.fusion`), post-processed GNSS/INS files (:mod:`acq.motion.ins`).

Frames. The vehicle frame is REP-103 ``base_link``: x forward, y left, z up (as
``acq.sim.world.Trajectory``). A pose maps it into a world frame, ``P_world = R @ P_vehicle
+ t`` (an :data:`acq.geometry.transforms.PoseFn`). World frames
(:class:`acq.geometry.geodesy.WorldFrame`): ``"odometry"``, where dead reckoning starts (the
``start`` pose, identity by default), x, y the plane the vehicle drives in, z up;
``"enu"``, the local tangent plane at ``origin`` = (latitude °, longitude °, ellipsoidal
height m) on WGS-84; or a projected CRS (``"EPSG:25832"``), minus the ``origin`` offset.

Times are host ``CLOCK_MONOTONIC`` ns (int64) unless a name ends in ``_s``; UTC is
POSIX seconds (float64). Angles are radians except in files (degrees).

Interpolation (:meth:`Trajectory.pose_at`): rotations by slerp, exact for a constant
angular velocity between samples; translations linearly. Linear, not cubic Hermite:
between samples 10-20 ms apart the chord of a curve is off the curve by a v²κ dt²/8
(at 20 km/h in a 10 m radius bend sampled at 50 Hz: 0.15 mm), far below a laser's
noise, and Hermite needs velocities consistent with the positions, which fused or
post-processed files do not guarantee. :func:`acq.motion.odometry.from_odometry` can put
arc-exact samples between sparse inputs (``step_s``) instead. Outside the sampled span
(and inside gaps longer than ``max_gap_s``) :meth:`~Trajectory.pose_at` raises
:class:`OutOfSpanError` rather than return wrong poses; ``margin_s`` (at most
:data:`MAX_EXTRAPOLATION_S`) extrapolates the end intervals' motion a little;
:meth:`~Trajectory.covers` flags.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np
import numpy.typing as npt

from acq.errors import AcqError
from acq.geometry.geodesy import WorldFrame
from acq.geometry.rotations import quat_from_matrix
from acq.geometry.transforms import Rigid

__all__ = ["MAX_EXTRAPOLATION_S", "OutOfSpanError", "Trajectory", "laser_poses"]

MAX_EXTRAPOLATION_S = 0.5  # s, the most Trajectory.margin_s may extrapolate past an end


class OutOfSpanError(AcqError, ValueError):
    """Times at which a trajectory has no pose: before its start, after its end (beyond
    ``margin_s``) or inside a gap longer than its ``max_gap_s``."""


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
    # The quaternion -> matrix step is acq.geometry.rotations.matrix_from_quat written
    # again inline (test_trajectory checks they agree): for 2 M points Trajectory.transform
    # takes 70 ms so, 440 ms with slerped quaternions through matrix_from_quat and einsum.
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
