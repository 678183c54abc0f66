"""Rigid transforms ``P_to = R @ P_from + t`` (metres), as calib.yaml stores them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["PoseFn", "Rigid", "world_to_laser", "world_to_laser_each"]


_KERNEL_POINTS = 50_000  # from this many points on, Rigid.apply runs a compiled loop


@dataclass(frozen=True)
class Rigid:
    """A proper rigid transform: ``apply(P) = P @ R.T + t`` for (N,3) points."""

    rotation: npt.NDArray[np.float64]  # (3,3), orthonormal, det +1
    translation: npt.NDArray[np.float64]  # (3,) metres

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

    def apply(self, P: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """(N,3) or (3,) points in the source frame -> the target frame."""
        P = np.asarray(P, dtype=np.float64)
        if P.ndim == 2 and P.shape[0] >= _KERNEL_POINTS and P.shape[1] == 3:
            from acq.geometry.rigid_kernels import apply_rigid  # numba: only when it pays

            return apply_rigid(P, self.rotation, self.translation)
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

    def to_dict(self) -> dict[str, list[list[float]] | list[float]]:
        return {
            "rotation": [[float(x) for x in row] for row in self.rotation],
            "translation": [float(x) for x in self.translation],
        }


PoseFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Vehicle pose at host times: (N,) int64 ns -> rotations (N,3,3), translations (N,3) m,
``P_world = R @ P_vehicle + t``."""


def world_to_laser(
    P_world: npt.ArrayLike, R: np.ndarray, t: np.ndarray, vehicle_to_laser: Rigid
) -> npt.NDArray[np.float64]:
    """World points (N,3) m in the laser frame as the rig stood at the vehicle pose
    ``R`` (3,3), ``t`` (3,) (vehicle -> world): motion compensation, world -> vehicle
    -> laser."""
    return vehicle_to_laser.apply((np.asarray(P_world, dtype=np.float64) - t) @ R)


def world_to_laser_each(
    P_world: np.ndarray, R: np.ndarray, t: np.ndarray, vehicle_to_laser: Rigid
) -> npt.NDArray[np.float64]:
    """:func:`world_to_laser` of the points (N,3) m at each of K poses ``R`` (K,3,3),
    ``t`` (K,3): (K,N,3)."""
    # (P - t) @ R @ A.T + b for A, b vehicle -> laser: P @ M + c, one product a pose
    M = R @ vehicle_to_laser.rotation.T
    c = vehicle_to_laser.translation - (t[:, None, :] @ M)[:, 0, :]
    out: npt.NDArray[np.float64] = np.asarray(P_world, dtype=np.float64)[None] @ M
    out += c[:, None, :]
    return out
