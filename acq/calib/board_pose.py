"""A checkerboard's pose in the camera from its image corners, and the board poses of the
camera–laser calibration (:mod:`acq.calib.extrinsic`).

:func:`board_pose_from_corners` is a PnP on reprojection error with any of our camera
models (fisheye points past 90 degrees included); its :class:`BoardFit` gives the board
plane in the camera frame and the plane's covariance. A :class:`BoardPose` is one pose of
the calibration: that plane and the laser points that hit the board.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from acq.camera.camera_models import CameraModel
from acq.geometry.rotations import matrix_from_rotvec, nearest_rotation, rotation_between, skew
from acq.geometry.transforms import Rigid

__all__ = ["BoardFit", "BoardPose", "board_pose_from_corners"]


@dataclass(frozen=True)
class BoardPose:
    """One board pose: its plane in the camera frame and the laser points on it.

    ``normal`` (3,) and ``distance`` (m) give the plane ``normal · X = distance`` in the
    camera frame (the normal is normalised here, the distance scaled with it);
    ``points`` (N,3) are the laser-frame points (m, z = 0 for a 2-D scanner) that hit
    the board, at least 2. ``weight`` scales the pose's residuals in the fit; ``id``
    names it in reports (e.g. the image's timestamp). ``plane_cov`` (4,4), optional: the
    covariance of ``(n_x, n_y, n_z, d)`` from the camera's board estimate (see
    :meth:`BoardFit.plane_covariance`); with it :func:`acq.calib.extrinsic.refine`
    accounts for the plane's errors instead of taking the plane as exact.
    """

    normal: np.ndarray
    distance: float
    points: np.ndarray
    weight: float = 1.0
    id: str = ""
    plane_cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.array(self.normal, dtype=np.float64).reshape(-1)
        P = np.array(self.points, dtype=np.float64)
        if n.shape != (3,):
            raise ValueError(f"normal must have 3 values, got {n.size}")
        norm = float(np.linalg.norm(n))
        if not (np.isfinite(norm) and norm > 0):
            raise ValueError(f"normal must be finite and non-zero, got {n}")
        if P.ndim != 2 or P.shape[1] != 3:
            raise ValueError(f"points must be (N,3), got shape {P.shape}")
        if len(P) < 2:
            raise ValueError(f"a board pose needs at least 2 laser points, got {len(P)}")
        if not np.isfinite(P).all() or not math.isfinite(self.distance):
            raise ValueError("points and distance must be finite")
        if not self.weight > 0:
            raise ValueError(f"weight must be > 0, got {self.weight}")
        if self.plane_cov is not None:
            C = np.array(self.plane_cov, dtype=np.float64)
            if C.shape != (4, 4) or not np.isfinite(C).all():
                raise ValueError(f"plane_cov must be a finite 4x4 matrix, got {C.shape}")
            C = 0.5 * (C + C.T) / norm**2
            C.flags.writeable = False
            object.__setattr__(self, "plane_cov", C)
        n = n / norm
        n.flags.writeable = False
        P.flags.writeable = False
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "distance", float(self.distance) / norm)
        object.__setattr__(self, "points", P)

    @classmethod
    def from_board(
        cls, board_to_camera: Rigid, points: npt.ArrayLike, weight: float = 1.0, id: str = ""
    ) -> BoardPose:
        """The pose of a board whose plane is its frame's z = 0 (``board_to_camera``)."""
        n = board_to_camera.rotation[:, 2]
        return cls(n, float(n @ board_to_camera.translation), np.asarray(points), weight, id)

    @classmethod
    def from_fit(
        cls, fit: BoardFit, points: npt.ArrayLike, weight: float = 1.0, id: str = ""
    ) -> BoardPose:
        """The pose from :func:`board_pose_from_corners`, with its plane covariance."""
        n, d = fit.plane()
        return cls(n, d, np.asarray(points), weight, id, fit.plane_covariance())


@dataclass(frozen=True)
class BoardFit:
    """A board's pose from its corners: ``board_to_camera`` (P_camera = R @ P_board + t),
    the RMS reprojection error (px, per corner, both axes), the number of iterations and
    ``covariance`` (6,6) of a left rotation vector (camera frame, rad) and the translation
    (m), from the Jacobian with the pixel noise estimated from the residuals."""

    board_to_camera: Rigid
    rms_px: float
    iterations: int
    covariance: np.ndarray

    def plane(self) -> tuple[np.ndarray, float]:
        """The board plane (board z = 0) in the camera frame: unit normal, distance (m)."""
        n = self.board_to_camera.rotation[:, 2]
        return n.copy(), float(n @ self.board_to_camera.translation)

    def plane_covariance(self) -> np.ndarray:
        """(4,4) covariance of ``(n_x, n_y, n_z, d)`` of :meth:`plane` (rank 3)."""
        n, _ = self.plane()
        t = self.board_to_camera.translation
        G = np.zeros((4, 6))
        G[:3, :3] = -skew(n)  # n' = exp([w]x) n = n + w x n
        G[3, :3] = np.cross(n, t)  # d = n . t
        G[3, 3:] = n
        cov: npt.NDArray[np.float64] = G @ self.covariance @ G.T
        return cov


def _initial_pnp(model: CameraModel, obj: np.ndarray, uv: np.ndarray) -> list[Rigid]:
    """Candidate poses from cv2 on undistorted rays, in a virtual pinhole camera turned
    towards the rays' mean direction so that boards near or past 90 degrees off-axis have
    z > 0. Flat boards: IPPE's two solutions (a small or distant board's tilt is
    ambiguous) unless the second reprojects 3x worse; other targets: SQPnP's one."""
    rays = model.unproject(uv)
    m = rays.mean(axis=0)
    m /= np.linalg.norm(m)
    Rv = rotation_between(m, [0.0, 0.0, 1.0])  # camera -> virtual
    rv = rays @ Rv.T
    ok = rv[:, 2] > 0.05
    if ok.sum() < 4:
        raise ValueError("fewer than 4 corners usable for the initial PnP (board too wide)")
    xy = np.ascontiguousarray(rv[ok, :2] / rv[ok, 2:3])
    o = np.ascontiguousarray(obj[ok])
    planar = np.ptp(o[:, 2]) < 1e-9
    flag = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(o, xy, np.eye(3), None, flags=flag)
    if not n:
        raise ValueError("cv2.solvePnPGeneric found no board pose")
    errs = np.asarray(errs, dtype=np.float64).reshape(-1)
    out: list[Rigid] = []
    for rvec, tvec, err in zip(rvecs, tvecs, errs, strict=True):
        if out and err > 3.0 * errs[0] + 1e-12:
            continue
        Rp = matrix_from_rotvec(np.asarray(rvec).reshape(3))
        out.append(Rigid(Rv.T @ Rp, Rv.T @ np.asarray(tvec, dtype=np.float64).reshape(3)))
    return out


def board_pose_from_corners(
    model: CameraModel,
    object_points: npt.ArrayLike,
    image_points: npt.ArrayLike,
    initial: Rigid | None = None,
    max_iterations: int = 50,
) -> BoardFit:
    """The board's pose from its corners by Levenberg–Marquardt on reprojection error.

    ``object_points`` (N,3) board-frame metres (a flat board: z = 0), ``image_points``
    (N,2) px. Uses ``model.project``, so it works with any camera model and past 90
    degrees off-axis (OpenCV's solvePnP assumes a pinhole). Initial pose: ``initial``
    (board_to_camera), else cv2.solvePnPGeneric (IPPE for flat boards: both of its
    solutions are refined when the tilt is ambiguous, the better kept) on the
    unprojected rays expressed in a virtual pinhole camera looking along their mean
    direction. Six parameters: a rotation vector applied on the left (camera frame) and
    the translation; the projection's derivatives by central differences (one batched
    ``project`` call). The covariance uses the pixel noise estimated from the residuals.
    """
    obj = np.asarray(object_points, dtype=np.float64)
    uv = np.asarray(image_points, dtype=np.float64)
    if obj.ndim != 2 or obj.shape[1] != 3 or uv.shape != (len(obj), 2):
        raise ValueError(f"need (N,3) object and (N,2) image points, got {obj.shape}, {uv.shape}")
    if len(obj) < 4:
        raise ValueError(f"a board pose needs at least 4 corners, got {len(obj)}")
    starts = [initial] if initial is not None else _initial_pnp(model, obj, uv)
    fits = [_pnp_lm(model, obj, uv, start, max_iterations) for start in starts]
    return min(fits, key=lambda f: f.rms_px)


def _pnp_lm(
    model: CameraModel, obj: np.ndarray, uv: np.ndarray, start: Rigid, max_iterations: int
) -> BoardFit:
    R, t = np.array(start.rotation), np.array(start.translation)
    N = len(obj)

    def resid(R_: np.ndarray, t_: np.ndarray) -> np.ndarray:
        proj, _ = model.project(obj @ R_.T + t_)
        r: npt.NDArray[np.float64] = (proj - uv).reshape(-1)
        return r

    def jacobian(R_: np.ndarray, t_: np.ndarray) -> np.ndarray:
        RX = obj @ R_.T
        X = RX + t_
        h = 1e-6 * np.maximum(np.linalg.norm(X, axis=1), 1e-3)
        steps = [X + s * h[:, None] * e for e in np.eye(3) for s in (1.0, -1.0)]
        proj, _ = model.project(np.concatenate(steps))
        proj = proj.reshape(6, N, 2)
        D = (proj[0::2] - proj[1::2]) / (2 * h[None, :, None])  # (3,N,2) d uv / d X_k
        dX = np.zeros((N, 3, 6))  # dX/d(w, t): -[RX]x and I
        dX[:, 0, 1], dX[:, 0, 2] = RX[:, 2], -RX[:, 1]  # -[RX]x, row by row
        dX[:, 1, 0], dX[:, 1, 2] = -RX[:, 2], RX[:, 0]
        dX[:, 2, 0], dX[:, 2, 1] = RX[:, 1], -RX[:, 0]
        dX[:, :, 3:] = np.eye(3)
        J: npt.NDArray[np.float64] = np.einsum("knc,nkp->ncp", D, dX).reshape(2 * N, 6)
        return J

    r = resid(R, t)
    cost = float(r @ r) if np.isfinite(r).all() else math.inf
    lam = 1e-3
    it = 0
    for it in range(1, max_iterations + 1):  # noqa: B007 (reported)
        J = jacobian(R, t)
        if not (np.isfinite(J).all() and math.isfinite(cost)):
            break
        A, g = J.T @ J, J.T @ r
        stepped = False
        while lam < 1e12:
            delta = np.linalg.solve(A + lam * np.diag(np.diag(A)), -g)
            R_new = nearest_rotation(matrix_from_rotvec(delta[:3]) @ R)
            t_new = t + delta[3:]
            r_new = resid(R_new, t_new)
            cost_new = float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                stepped = True
                break
            lam *= 10.0
        if not stepped:
            break
        gain = cost - cost_new
        R, t, r, cost = R_new, t_new, r_new, cost_new
        lam = max(lam / 10.0, 1e-12)
        if gain <= 1e-14 * (cost + 1e-300) or np.linalg.norm(delta) < 1e-13:
            break
    J = jacobian(R, t)
    sigma2 = cost / max(2 * N - 6, 1)
    cov = sigma2 * np.linalg.pinv(J.T @ J) if np.isfinite(J).all() else np.full((6, 6), np.inf)
    return BoardFit(Rigid(R, t), float(math.sqrt(cost / N)), it, 0.5 * (cov + cov.T))
