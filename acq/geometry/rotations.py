"""Rotations: 3x3 matrices, unit quaternions, rotation vectors, Euler angles.

One quaternion order everywhere: (w, x, y, z), the scalar first, w >= 0 where a matrix is
converted. Wire formats that order it otherwise (Foxglove's ``x, y, z, w`` fields)
convert where they are written. Angles are radians. Functions take stacks: a leading
shape ``...`` is kept.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

__all__ = [
    "euler_from_matrices",
    "matrices_from_euler",
    "matrix_from_quat",
    "matrix_from_rotvec",
    "nearest_rotation",
    "quat_from_matrix",
    "rotation_angle",
    "rotation_between",
    "rotation_from_euler",
    "rotation_to_euler",
    "rotvec_from_matrix",
    "skew",
]


# --- quaternions -------------------------------------------------------------------------


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
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3) rotations (into ``out`` if
    given)."""
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


# --- rotation vectors (axis * angle) -----------------------------------------------------


def skew(w: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(..., 3) vectors -> (..., 3, 3) cross-product matrices: ``skew(w) @ v == w x v``."""
    w = np.asarray(w, dtype=np.float64)
    K = np.zeros((*w.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return K


def matrix_from_rotvec(w: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(..., 3) rotation vectors (axis * angle, rad) -> (..., 3, 3) rotations (Rodrigues;
    second order in the angle below 1e-8 rad)."""
    w = np.asarray(w, dtype=np.float64)
    theta: npt.NDArray[np.float64] = np.linalg.norm(w, axis=-1)[..., None, None]
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(th) / th)
    b = np.where(small, 0.5, (1.0 - np.cos(th)) / th**2)
    K = skew(w)
    return np.eye(3) + a * K + b * (K @ K)


def rotvec_from_matrix(R: npt.ArrayLike) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 3) rotation vectors, angle in [0, pi] (accurate near
    0 and near pi)."""
    q = quat_from_matrix(R)
    w, v = q[..., 0], q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    tiny = s < 1e-12
    # angle / s, with its limit 2 / w for a vanishing angle
    scale = np.where(
        tiny, 2.0 / np.where(tiny, w, 1.0), 2.0 * np.arctan2(s, w) / np.where(tiny, 1.0, s)
    )
    return v * scale[..., None]


def rotation_between(a: npt.ArrayLike, b: npt.ArrayLike) -> np.ndarray:
    """(3,3) the smallest rotation turning the direction of (3,) ``a`` onto that of ``b``
    (the identity where they are parallel, or opposite: then any half turn would do)."""
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s = float(np.linalg.norm(axis))
    if s <= 1e-12:
        return np.eye(3)
    return matrix_from_rotvec(axis / s * math.atan2(s, float(a @ b)))


def rotation_angle(R: npt.ArrayLike) -> float:
    """Geodesic angle of a rotation matrix, rad (accurate near 0 and near pi)."""
    R = np.asarray(R, dtype=np.float64)
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = 0.5 * (np.trace(R) - 1.0)
    return float(math.atan2(s, c))


def nearest_rotation(M: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """(3,3) the rotation nearest to a 3x3 matrix (Frobenius norm, by SVD): removes the
    drift of products of rotations and the noise of estimated ones."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    Q: npt.NDArray[np.float64] = U @ Vt
    if np.linalg.det(Q) < 0:
        Q = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return Q


# --- Euler angles ------------------------------------------------------------------------


def matrices_from_euler(
    roll: npt.ArrayLike, pitch: npt.ArrayLike, yaw: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """(N,3,3) ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (rad, broadcast to (N,)), the ROS
    fixed-axis xyz convention. ``matrices_from_euler(0, 0, yaw)`` is a heading alone."""
    r, p, y = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64).reshape(-1) for a in (roll, pitch, yaw))
    )
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = np.empty((r.size, 3, 3))
    R[:, 0, 0] = cy * cp
    R[:, 0, 1] = cy * sp * sr - sy * cr
    R[:, 0, 2] = cy * sp * cr + sy * sr
    R[:, 1, 0] = sy * cp
    R[:, 1, 1] = sy * sp * sr + cy * cr
    R[:, 1, 2] = sy * sp * cr - cy * sr
    R[:, 2, 0] = -sp
    R[:, 2, 1] = cp * sr
    R[:, 2, 2] = cp * cr
    return R


def euler_from_matrices(R: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N,3,3) -> (roll, pitch, yaw) rad arrays with ``matrices_from_euler(*result) == R``
    (pitch in ±90°)."""
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    pitch = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
    return np.arctan2(R[:, 2, 1], R[:, 2, 2]), pitch, np.arctan2(R[:, 1, 0], R[:, 0, 0])


def rotation_from_euler(roll: float, pitch: float, yaw: float) -> npt.NDArray[np.float64]:
    """(3,3) ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (rad): :func:`matrices_from_euler` of one."""
    R: npt.NDArray[np.float64] = matrices_from_euler(roll, pitch, yaw)[0]
    return R


def rotation_to_euler(R: npt.ArrayLike) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of one (3,3) rotation: :func:`euler_from_matrices` of one."""
    roll, pitch, yaw = euler_from_matrices(R)
    return float(roll[0]), float(pitch[0]), float(yaw[0])
