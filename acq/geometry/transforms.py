"""Rigid transforms ``P_to = R @ P_from + t`` (metres), as calib.yaml stores them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "PoseFn",
    "Rigid",
    "euler_from_matrices",
    "matrices_from_euler",
    "rotation_from_euler",
    "rotation_to_euler",
]


@dataclass(frozen=True)
class Rigid:
    """A proper rigid transform: ``apply(P) = P @ R.T + t`` for (N,3) points."""

    rotation: np.ndarray  # (3,3) float64, orthonormal, det +1
    translation: np.ndarray  # (3,) float64, metres

    def __post_init__(self) -> None:
        R = np.array(self.rotation, dtype=np.float64)
        t = np.array(self.translation, dtype=np.float64).reshape(-1)
        if R.shape != (3, 3):
            raise ValueError(f"rotation must be 3x3, got shape {R.shape}")
        if t.shape != (3,):
            raise ValueError(f"translation must have 3 values, got {t.size}")
        err = np.abs(R @ R.T - np.eye(3)).max()
        if err > 1e-6 or np.linalg.det(R) < 0:
            raise ValueError(
                f"rotation is not a proper rotation (|R R^T - I| = {err:.2g}, "
                f"det = {np.linalg.det(R):.6f})"
            )
        R.flags.writeable = False
        t.flags.writeable = False
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)

    @classmethod
    def identity(cls) -> Rigid:
        return cls(np.eye(3), np.zeros(3))

    def apply(self, P: npt.ArrayLike) -> np.ndarray:
        """(N,3) or (3,) points in the source frame -> the target frame."""
        P = np.asarray(P, dtype=np.float64)
        return P @ self.rotation.T + self.translation

    def inverse(self) -> Rigid:
        Rt = self.rotation.T
        return Rigid(Rt, -Rt @ self.translation)

    def __matmul__(self, other: Rigid) -> Rigid:
        """Composition: ``(a @ b).apply(P) == a.apply(b.apply(P))``."""
        return Rigid(
            self.rotation @ other.rotation, self.rotation @ other.translation + self.translation
        )

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous matrix."""
        M = np.eye(4)
        M[:3, :3] = self.rotation
        M[:3, 3] = self.translation
        return M

    def to_dict(self) -> dict[str, list]:
        return {
            "rotation": [[float(x) for x in row] for row in self.rotation],
            "translation": [float(x) for x in self.translation],
        }


def rotation_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (rad), the ROS fixed-axis xyz convention."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def rotation_to_euler(R: npt.ArrayLike) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad with ``rotation_from_euler(*result) == R`` (pitch in ±90°)."""
    R = np.asarray(R, dtype=np.float64)
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    return roll, pitch, yaw


def matrices_from_euler(
    roll: npt.ArrayLike, pitch: npt.ArrayLike, yaw: npt.ArrayLike
) -> np.ndarray:
    """(N,3,3) ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (rad): the convention of
    :func:`acq.geometry.transforms.rotation_from_euler`, for arrays."""
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
    """(N,3,3) -> (roll, pitch, yaw) rad arrays, as :func:`rotation_to_euler`."""
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    pitch = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
    return np.arctan2(R[:, 2, 1], R[:, 2, 2]), pitch, np.arctan2(R[:, 1, 0], R[:, 0, 0])


PoseFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Vehicle pose at host times: (N,) int64 ns -> rotations (N,3,3), translations (N,3) m,
``P_world = R @ P_vehicle + t``."""
