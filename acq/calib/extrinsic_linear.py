"""Zhang & Pless's linear solution of the camera–laser extrinsics, and the check that the
board poses can determine them (paper §3.2; :mod:`acq.calib.extrinsic` refines it).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np

from acq.calib.board_pose import BoardPose
from acq.geometry.rotations import nearest_rotation
from acq.geometry.transforms import Rigid

__all__ = ["MIN_POSES", "check_geometry", "linear_solution"]

MIN_POSES = 5  # 9 unknowns in the linear solution, 2 independent constraints per pose

# board normals (rows of an (n,3) matrix) must span 3-D: singular value ratios below these
# raise (degenerate), below _WARN_SPREAD warn (poorly conditioned)
_DEGENERATE_SPREAD = 0.02  # ~1 degree
_WARN_SPREAD = 0.08  # ~5 degrees


def check_geometry(poses: Sequence[BoardPose]) -> None:
    """Raise ValueError when the poses cannot determine the transform; warn when weak.

    At least :data:`MIN_POSES` poses, and board normals that span 3-D: all normals
    parallel leaves the rotation about the normal and two translations free; normals all
    perpendicular to one direction (boards only turned about one axis) leave the
    translation along that direction free.
    """
    if len(poses) < MIN_POSES:
        raise ValueError(
            f"the camera-laser calibration needs at least {MIN_POSES} board poses "
            f"(the linear solution has 9 unknowns, each pose gives 2 constraints), "
            f"got {len(poses)}; the paper recommends 15 or more"
        )
    N = np.array([p.normal for p in poses])
    s = np.linalg.svd(N, compute_uv=False)
    if s[1] / s[0] < _DEGENERATE_SPREAD:
        raise ValueError(
            f"degenerate board poses: all {len(poses)} board normals are parallel "
            f"(spread ratio {s[1] / s[0]:.3g}); tilt the board about different axes "
            f"between poses (±30 degrees)"
        )
    if s[2] / s[0] < _DEGENERATE_SPREAD:
        raise ValueError(
            f"degenerate board poses: the board normals all lie in one plane (spread ratio "
            f"{s[2] / s[0]:.3g}), so the translation along its normal is undetermined; tilt "
            f"the board about a second axis too"
        )
    if s[2] / s[0] < _WARN_SPREAD:
        warnings.warn(
            f"board normals span 3-D poorly (spread ratio {s[2] / s[0]:.3g} < "
            f"{_WARN_SPREAD}); the result will be imprecise, tilt the board more",
            stacklevel=2,
        )


def linear_solution(poses: Sequence[BoardPose]) -> Rigid:
    """Zhang & Pless's linear least-squares estimate of ``camera_to_laser``.

    For a laser point ``p = (x, y, 0)``, ``n · R^T (p - t) = d`` is ``n^T H (x, y, 1)^T =
    d`` with ``H = R^T [e1 e2 -t]``: linear in the 9 entries of H. R^T's first two columns
    are orthonormalised (closest orthonormal pair by SVD), the third is their cross
    product, and ``t = -R h3``. Needs at least 5 poses with normals spanning 3-D and laser
    points in the plane z = 0 (|z| <= 1 mm).
    """
    check_geometry(poses)
    rows, rhs, wts = [], [], []
    for p in poses:
        if np.abs(p.points[:, 2]).max() > 1e-3:
            raise ValueError("the linear solution needs laser points in the scan plane z = 0")
        q = np.column_stack([p.points[:, :2], np.ones(len(p.points))])  # (N,3) = (x, y, 1)
        # n^T H q = sum_{a,b} n_a H_ab q_b: row-major vec(H) coefficients n_a q_b
        rows.append((p.normal[None, :, None] * q[:, None, :]).reshape(len(q), 9))
        rhs.append(np.full(len(q), p.distance))
        wts.append(np.full(len(q), math.sqrt(p.weight / len(q))))  # each pose counts alike
    w = np.concatenate(wts)
    A = np.concatenate(rows) * w[:, None]
    b = np.concatenate(rhs) * w
    h, *_ = np.linalg.lstsq(A, b, rcond=None)
    H = h.reshape(3, 3)
    U, _, Vt = np.linalg.svd(H[:, :2], full_matrices=False)
    c12 = U @ Vt  # closest 3x2 matrix with orthonormal columns
    Rt = np.column_stack([c12, np.cross(c12[:, 0], c12[:, 1])])
    R = nearest_rotation(Rt.T)
    return Rigid(R, -R @ H[:, 2])
