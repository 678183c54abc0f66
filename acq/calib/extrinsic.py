"""Camera–laser extrinsic calibration with a checkerboard (paper §3.2, Zhang & Pless).

Per board pose i the camera gives the board plane in the CAMERA frame, ``n_i · X = d_i``
(unit normal, metres), and the scanner gives laser points ``P_ij`` (laser frame, metres)
that hit the board. With paper eq. (2), ``P_laser = R @ P_camera + t``, a laser point
maps to the camera as ``R^T (P_ij - t)``, which must lie on the plane::

    r_ij = n_i · R^T (P_ij - t) - d_i        (metres)

(the paper's eq. 3 as printed applies the inverse rotation and the translation the wrong
way round; this follows eq. 2). The result is ``camera_to_laser`` as calib.yaml stores it.

Pipeline (:func:`calibrate`): Zhang & Pless's linear solution as initial guess (at least 5
poses, :mod:`acq.calib.extrinsic_linear`), Levenberg–Marquardt with a robust loss over 6
parameters, poses whose RMS residual is far above the others reported and dropped,
Levenberg–Marquardt again. When the planes come with their covariance
(``BoardPose.from_fit``), the last refinement also estimates a correction of each plane
held by that covariance, so that the result and its standard deviations account for the
camera's errors, which dominate with a low-resolution fisheye (see :func:`refine`).

The poses (:class:`~acq.calib.board_pose.BoardPose`) and their planes come from
:mod:`acq.calib.board_pose`; the residual plot is :func:`acq.calib.plots.residual_plot`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from acq.calib.board_pose import BoardPose
from acq.calib.extrinsic_linear import MIN_POSES, check_geometry, linear_solution
from acq.geometry.rotations import matrix_from_rotvec, nearest_rotation, rotation_to_euler
from acq.geometry.transforms import Rigid

__all__ = [
    "ExtrinsicResult",
    "calibrate",
    "laser_noise",
    "point_residuals",
    "refine",
]

Loss = Literal["linear", "huber", "cauchy"]


# ----------------------------------------------------------------------------- data


@dataclass(frozen=True)
class ExtrinsicResult:
    """The calibrated ``camera_to_laser`` (P_laser = R @ P_camera + t) and its quality.

    ``std``: standard deviations of the 6 parameters, a small rotation about the laser
    axes x, y, z (rad, ``R = exp([w]x) R_hat``) then tx, ty, tz (m); ``std_rot_deg`` the
    rotation part in degrees, ``std_rpy_deg`` that of ``acq.geometry.rotations.rotation_to_euler``
    (degrees; meaningless near pitch ±90°, where roll and yaw are coupled — the default
    rig is there, use ``std_rot_deg``) and ``std_t_mm`` the translation in mm.
    ``covariance`` (6,6) is in the units of ``std``. ``residuals_per_pose``: RMS
    point-to-plane residual ``n · R^T (P - t) - d`` (m, with the camera's planes as
    measured) of every input pose at the solution, dropped ones included; ``outliers``:
    indices of the dropped poses; ``rms_m`` over the kept poses' points;
    ``outlier_threshold_m``: the per-pose RMS above which a pose was dropped.
    ``plane_errors``: whether the fit modelled the planes' errors (``BoardPose.plane_cov``);
    ``laser_noise_m``: then the laser's range noise estimated for each kept pose (m).
    ``std`` is, per parameter, the larger of ``std_model`` (the fit's error model) and
    ``std_spread`` (the spread of the poses, NaN with 6 poses or fewer; see
    :func:`refine`), both in the units of ``std``.
    """

    camera_to_laser: Rigid
    std: np.ndarray
    std_rot_deg: np.ndarray
    std_rpy_deg: np.ndarray
    std_t_mm: np.ndarray
    covariance: np.ndarray
    residuals_per_pose: np.ndarray
    outliers: tuple[int, ...]
    rms_m: float
    iterations: int
    converged: bool
    n_points: int
    loss: str = "huber"
    f_scale: float = 0.01
    outlier_threshold_m: float = math.inf
    plane_errors: bool = False
    laser_noise_m: np.ndarray | None = None
    initial: Rigid | None = field(default=None, compare=False)
    std_model: np.ndarray | None = None
    std_spread: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """A JSON/YAML-ready report (calib.yaml's ``camera_to_laser`` plus statistics)."""
        rpy = np.degrees(rotation_to_euler(self.camera_to_laser.rotation))
        return {
            "camera_to_laser": self.camera_to_laser.to_dict(),
            "rpy_deg": [float(x) for x in rpy],
            "std_rot_deg": [float(x) for x in self.std_rot_deg],
            "std_rpy_deg": [float(x) for x in self.std_rpy_deg],
            "std_t_mm": [float(x) for x in self.std_t_mm],
            "std": [float(x) for x in self.std],
            "rms_mm": self.rms_m * 1e3,
            "residuals_per_pose_mm": [float(x) * 1e3 for x in self.residuals_per_pose],
            "outliers": list(self.outliers),
            "iterations": self.iterations,
            "converged": self.converged,
            "n_points": self.n_points,
            "loss": self.loss,
            "f_scale_m": self.f_scale,
            "plane_errors": self.plane_errors,
            "laser_range_noise_mm": (
                None if self.laser_noise_m is None else float(np.median(self.laser_noise_m)) * 1e3
            ),
            "std_model": _floats(self.std_model),
            "std_pose_spread": _floats(self.std_spread),
        }


def _floats(a: np.ndarray | None) -> list[float | None] | None:
    """JSON-ready values of ``a`` (None for NaN), or None."""
    return None if a is None else [float(x) if math.isfinite(x) else None for x in a]


# ----------------------------------------------------------------------------- refinement

_PRIOR_HUBER = 3.0  # plane corrections beyond 3 sigma (Mahalanobis) are down-weighted
_MIN_PLANE_STD = (1e-7, 1e-7)  # rad, m: keeps the plane priors invertible on exact data
_MIN_LASER_NOISE = 1e-4  # m (0.1 mm: no scanner is better; keeps exact data well posed)


def _rho(z: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """scipy's robust losses of z = (r / f_scale)^2: rho(z) and the IRLS weight rho'(z)."""
    if loss == "linear":
        return z, np.ones_like(z)
    if loss == "huber":
        big = z > 1.0
        sq = np.sqrt(np.where(big, z, 1.0))
        return np.where(big, 2.0 * sq - 1.0, z), np.where(big, 1.0 / sq, 1.0)
    if loss == "cauchy":
        return np.log1p(z), 1.0 / (1.0 + z)
    raise ValueError(f"unknown loss {loss!r}; expected 'linear', 'huber' or 'cauchy'")


def point_residuals(poses: Sequence[BoardPose], camera_to_laser: Rigid) -> list[np.ndarray]:
    """Per pose, the point-to-plane residuals ``n · R^T (P - t) - d`` (m)."""
    R, t = camera_to_laser.rotation, camera_to_laser.translation
    return [(p.points - t) @ (R @ p.normal) - p.distance for p in poses]


def _pose_rms(poses: Sequence[BoardPose], camera_to_laser: Rigid) -> np.ndarray:
    return np.array([math.sqrt(np.mean(r * r)) for r in point_residuals(poses, camera_to_laser)])


def _safe_cos(c: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Cosines of incidence kept away from 0 (grazing rays, > 87 degrees)."""
    return np.where(c < 0, np.minimum(c, -0.05), np.maximum(c, 0.05))


def laser_noise(poses: Sequence[BoardPose], camera_to_laser: Rigid) -> npt.NDArray[np.float64]:
    """Per pose, the laser's range noise (m, along its rays), from the data alone.

    A pose's point-to-plane residuals are an affine function of the points, so along the
    pose's laser line (a straight segment) any error of the transform or of the plane is
    a straight line: what a straight-line fit leaves is the laser's noise, here divided
    by the cosine of incidence to give the range noise. Robust (MAD) per pose; poses with
    fewer than 10 points get the median of the others.
    """
    out = np.full(len(poses), np.nan)
    R = camera_to_laser.rotation
    for i, (p, r) in enumerate(zip(poses, point_residuals(poses, camera_to_laser), strict=True)):
        if len(r) < 10:
            continue
        xy = p.points[:, :2] - p.points[:, :2].mean(axis=0)
        _, _, Vt = np.linalg.svd(xy, full_matrices=False)
        s = xy @ Vt[0]
        A = np.column_stack([np.ones_like(s), s])
        e = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]
        u = p.points / np.linalg.norm(p.points, axis=1, keepdims=True)
        e = e / np.abs(_safe_cos(u @ (R @ p.normal)))
        mad = 1.4826 * float(np.median(np.abs(e - np.median(e))))
        out[i] = mad * math.sqrt(len(r) / (len(r) - 2))
    fill = float(np.nanmedian(out)) if np.isfinite(out).any() else _MIN_LASER_NOISE
    noise: npt.NDArray[np.float64] = np.where(np.isfinite(out), out, fill)
    return np.maximum(noise, _MIN_LASER_NOISE)


def _tangent_basis(n: np.ndarray) -> np.ndarray:
    """(2,3): two unit vectors orthogonal to the unit vector n and to each other."""
    a = np.zeros(3)
    a[int(np.argmin(np.abs(n)))] = 1.0
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)])


def _euler_std_deg(R: np.ndarray, cov_w: np.ndarray) -> npt.NDArray[np.float64]:
    """Std of (roll, pitch, yaw) in degrees from the covariance of w in R = exp([w]x) R."""
    eps = 1e-6
    Jr = np.empty((3, 3))
    for k in range(3):
        dw = np.zeros(3)
        dw[k] = eps
        a = np.array(rotation_to_euler(matrix_from_rotvec(dw) @ R))
        b = np.array(rotation_to_euler(matrix_from_rotvec(-dw) @ R))
        diff = (a - b + math.pi) % (2 * math.pi) - math.pi
        Jr[:, k] = diff / (2 * eps)
    var: npt.NDArray[np.float64] = np.diag(Jr @ cov_w @ Jr.T)
    return np.degrees(np.sqrt(np.clip(var, 0.0, None)))


class _Problem:
    """The point-to-plane least-squares problem, optionally with per-pose plane corrections.

    Parameters: ``w`` (3, rad, ``R = exp([w]x) R``), ``t`` (3, m) and, with plane errors,
    per pose ``(a, b, dd)``: ``n = normalise(n0 + a e1 + b e2)``, ``d = d0 + dd``, held by
    a Gaussian prior from ``plane_cov`` (Huber beyond 3 sigma).

    Without plane errors the residuals are the point-to-plane distances, weighted so that
    every pose counts alike. With them, the residuals are measured along the laser rays
    (``r / cos(incidence)``, the range error: the scanner's noise is along its rays) and
    divided by the range noise. Along the normal, the noisy points would also be the
    regressors of the plane corrections (errors in variables), which biases the fit by
    several mrad at 10 mm range noise; along the rays the regressors are noise-free.
    """

    def __init__(
        self,
        poses: Sequence[BoardPose],
        loss: str,
        f_scale: float,
        sigma: np.ndarray | None,
    ) -> None:
        self.loss, self.f_scale = loss, f_scale
        self.K = len(poses) if sigma is not None else 0
        counts = np.array([len(p.points) for p in poses])
        self.pid = np.repeat(np.arange(len(poses)), counts)
        self.P = np.concatenate([p.points for p in poses])
        self.n0 = np.array([p.normal for p in poses])
        self.d0 = np.array([p.distance for p in poses])
        weight = np.array([p.weight for p in poses])
        if sigma is None:  # planes taken as exact: every pose counts by its weight
            self.pw = (weight * counts.mean() / counts)[self.pid]
            return
        self.pw = (weight / sigma**2)[self.pid]
        self.U = self.P / np.linalg.norm(self.P, axis=1, keepdims=True)  # unit laser rays
        self.E = np.array([_tangent_basis(n) for n in self.n0])  # (K,2,3)
        self.L = np.empty((self.K, 3, 3))  # prior residual L_i @ (a, b, dd), L^T L = C^-1
        floor = np.diag(np.square([*_MIN_PLANE_STD[:1] * 2, _MIN_PLANE_STD[1]]))
        for i, p in enumerate(poses):
            assert p.plane_cov is not None
            T = np.zeros((4, 3))
            T[:3, 0], T[:3, 1], T[3, 2] = self.E[i, 0], self.E[i, 1], 1.0
            C = T.T @ p.plane_cov @ T + floor
            self.L[i] = np.linalg.cholesky(np.linalg.inv(C)).T

    @property
    def n_params(self) -> int:
        return 6 + 3 * self.K

    def planes(self, D: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corrected normals (K,3), distances (K,) and dn/d(a,b) (K,2,3)."""
        if self.K == 0:
            return self.n0, self.d0, np.zeros((0, 2, 3))
        v = self.n0 + np.einsum("ik,ikj->ij", D[:, :2], self.E)
        nv = np.linalg.norm(v, axis=1)
        n = v / nv[:, None]
        dn = (self.E - n[:, None, :] * np.einsum("ikj,ij->ik", self.E, n)[:, :, None]) / nv[
            :, None, None
        ]
        return n, self.d0 + D[:, 2], dn

    def evaluate(
        self, R: np.ndarray, t: np.ndarray, D: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Point residuals (m), their Jacobian (M, 9) — the 6 shared parameters, then the
        point's own pose's 3 plane corrections (zero without) — and the robust cost."""
        n, d, dn = self.planes(D)
        m = n[self.pid] @ R.T  # R n per point
        q = self.P - t
        r = np.einsum("ij,ij->i", m, q) - d[self.pid]
        J = np.zeros((len(r), 9))
        J[:, :3] = np.cross(m, q)
        J[:, 3:6] = -m
        if self.K:
            X = q @ R  # points in the camera frame
            J[:, 6] = np.einsum("ij,ij->i", X, dn[self.pid, 0])
            J[:, 7] = np.einsum("ij,ij->i", X, dn[self.pid, 1])
            J[:, 8] = -1.0
            # along the ray: r / c with c = (R n) . u, the cosine of incidence
            c = _safe_cos(np.einsum("ij,ij->i", m, self.U))
            Jc = np.zeros_like(J)
            Jc[:, :3] = np.cross(m, self.U)
            Jc[:, 6] = np.einsum("ij,ij->i", dn[self.pid, 0] @ R.T, self.U)
            Jc[:, 7] = np.einsum("ij,ij->i", dn[self.pid, 1] @ R.T, self.U)
            J = J / c[:, None] - (r / (c * c))[:, None] * Jc
            r = r / c
        return r, J, self.cost(r, D)

    def _prior(self, D: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Prior residuals (K,3), their Huber cost (K,) and IRLS weights (K,)."""
        e = np.einsum("kij,kj->ki", self.L, D)
        m2 = np.sum(e * e, axis=1)
        c = _PRIOR_HUBER
        big = m2 > c * c
        m = np.sqrt(np.where(big, m2, 1.0))
        return e, np.where(big, 2 * c * m - c * c, m2), np.where(big, c / m, 1.0)

    def cost(self, r: np.ndarray, D: np.ndarray) -> float:
        f = self.f_scale
        rho, _ = _rho((r / f) ** 2, self.loss)
        total = 0.5 * f * f * float(np.sum(self.pw * rho))
        if self.K:
            total += 0.5 * float(np.sum(self._prior(D)[1]))
        return total

    def normal_equations(
        self, r: np.ndarray, J: np.ndarray, D: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IRLS ``A = J^T W J`` and ``g = J^T W r`` over all parameters (priors included),
        and the points' weights W."""
        _, w = _rho((r / self.f_scale) ** 2, self.loss)
        w = w * self.pw
        if not self.K:
            Je = J[:, :6]
            return Je.T @ (w[:, None] * Je), Je.T @ (w * r), w
        # per pose sums over its (contiguous) points of the 9x9 blocks and 9-vectors
        starts = np.flatnonzero(np.r_[True, np.diff(self.pid) != 0])
        Ab = np.add.reduceat(w[:, None, None] * J[:, :, None] * J[:, None, :], starts)
        gb = np.add.reduceat((w * r)[:, None] * J, starts)
        e, _, wp = self._prior(D)
        A = np.zeros((self.n_params, self.n_params))
        g = np.zeros(self.n_params)
        A[:6, :6] = Ab[:, :6, :6].sum(axis=0)
        g[:6] = gb[:, :6].sum(axis=0)
        for i in range(self.K):
            s = slice(6 + 3 * i, 9 + 3 * i)
            A[:6, s] = Ab[i, :6, 6:]
            A[s, :6] = Ab[i, 6:, :6]
            A[s, s] = Ab[i, 6:, 6:] + wp[i] * self.L[i].T @ self.L[i]
            g[s] = gb[i, 6:] + wp[i] * self.L[i].T @ e[i]
        return A, g, w


def _with_pose_spread(
    cov: np.ndarray,
    model: np.ndarray,
    B: np.ndarray,
    pid: np.ndarray,
    wr: np.ndarray,
    J6: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The covariance ``cov`` of the 6 parameters (``model``: its standard deviations)
    widened to the spread of the poses, and that spread's standard deviations (rad, m).

    The model's covariance assumes the laser's errors independent from point to point;
    a real scanner's are not (a pose's residuals bow by millimetres along the board:
    range errors that vary with angle and incidence), so more points on a board do not
    shrink the error as the model says. The cluster-robust ("sandwich") covariance
    ``B S B`` takes each pose's errors as one unknown: ``S`` sums the outer products of
    each pose's score (its points' ``J^T W r``, the 6 shared parameters: a pose's own
    plane corrections have zero score at the solution), ``B`` is the 6x6 block of the
    inverse normal matrix, scaled by ``K / (K - 6)`` for K poses. Each standard deviation
    is the larger of the two; the model's correlations are kept."""
    K = int(pid.max()) + 1 if len(pid) else 0
    if K <= 6:
        return cov, np.full(6, np.nan)
    starts = np.flatnonzero(np.r_[True, np.diff(pid) != 0])
    scores = np.add.reduceat(wr[:, None] * J6, starts)  # (K, 6)
    sandwich = B @ (scores.T @ scores) @ B.T * (K / (K - 6))
    spread = np.sqrt(np.clip(np.diag(sandwich), 0.0, None))
    scale = np.where(model > 0, np.maximum(spread / np.where(model > 0, model, 1.0), 1.0), 1.0)
    return cov * np.outer(scale, scale), spread


def refine(
    poses: Sequence[BoardPose],
    initial: Rigid,
    loss: Loss = "huber",
    f_scale: float = 0.01,
    plane_errors: bool | None = None,
    max_iterations: int = 100,
) -> ExtrinsicResult:
    """Levenberg–Marquardt on the point-to-plane residuals ``n · R^T (P - t) - d`` (m).

    Six parameters: a rotation vector applied on the left of the current rotation
    (``R = exp([w]x) R``, laser frame, rad) and the translation (m). Robust losses (scipy's
    definitions, ``f_scale`` in metres: residuals beyond it are down-weighted) are
    handled by iteratively re-weighted least squares inside the LM loop: each iteration
    solves ``(J^T W J + lambda diag(J^T W J)) delta = -J^T W r`` with the weights
    ``W = rho'((r / f_scale)^2)`` of the current residuals and keeps the step only if the
    robust cost decreases. No poses are dropped here.

    ``plane_errors`` (default: when every pose has ``plane_cov``): the camera's planes
    are not exact — with a fisheye their errors dominate the laser's — so each pose also
    gets a plane correction (3 more parameters) held by its covariance (a Gaussian prior,
    Huber beyond 3 sigma); the residuals are then taken along the laser rays,
    ``r / cos(incidence)`` (the range error, where the scanner's noise is; along the
    normal the noisy points would be regressors of the plane corrections, a bias of
    several mrad), divided by the range noise estimated from the data
    (:func:`laser_noise`), and the covariance of the 6 parameters is their block of
    ``(J^T W J)^-1``: it includes the planes' uncertainty and matches the spread over
    repeated calibrations (bench/extrinsic.py). Without: the planes are exact, every pose
    counts alike, and the covariance is ``sigma^2 (J^T W J)^-1`` with ``sigma^2 = sum(W
    r^2) / (N - 6)``, which assumes independent residuals and so underestimates (by ~5x
    in the simulation) when the planes have errors.

    Either way each standard deviation is then widened, where it is smaller, to the
    spread of the poses (a cluster-robust covariance, :func:`_with_pose_spread`): a real
    scanner's errors along one board are not independent (on the KiKuBoy set, the
    model's std was a quarter of the spread that leaving each pose out shows,
    bench/kikuboy.py).
    """
    if f_scale <= 0:
        raise ValueError(f"f_scale must be > 0 m, got {f_scale}")
    _rho(np.zeros(1), loss)  # validates the loss name
    with_cov = all(p.plane_cov is not None for p in poses)
    if plane_errors is None:
        plane_errors = with_cov
    if plane_errors and not with_cov:
        raise ValueError("plane_errors needs every pose's plane_cov (BoardPose.from_fit)")
    sigma = laser_noise(poses, initial) if plane_errors else None
    prob = _Problem(poses, loss, f_scale, sigma)
    R = np.array(initial.rotation)
    t = np.array(initial.translation)
    D = np.zeros((prob.K, 3))
    r, J, cost = prob.evaluate(R, t, D)
    lam = 1e-4
    iterations = 0
    converged = False
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported)
        A, g, _ = prob.normal_equations(r, J, D)
        stepped = False
        while lam < 1e12:
            delta = np.linalg.solve(A + lam * np.diag(np.diag(A)), -g)
            R_new = nearest_rotation(matrix_from_rotvec(delta[:3]) @ R)
            t_new = t + delta[3:6]
            D_new = D + delta[6:].reshape(-1, 3)
            r_new, J_new, cost_new = prob.evaluate(R_new, t_new, D_new)
            if cost_new <= cost:
                stepped = True
                break
            lam *= 10.0
        if not stepped:  # no decrease possible: at the minimum to machine precision
            converged = True
            break
        # 1e-8 rad (6e-7 degrees) and 10 nm: far below any calibration's precision; with
        # robust weights (IRLS) the steps shrink only linearly, by ~6 % an iteration on
        # real data, so a tighter tolerance costs a hundred iterations for nothing
        small_step = np.linalg.norm(delta[:6]) < 1e-8 * (1.0 + np.linalg.norm(t))
        small_gain = cost - cost_new <= 1e-15 * (cost + 1e-300)
        R, t, D, r, J, cost = R_new, t_new, D_new, r_new, J_new, cost_new
        lam = max(lam / 10.0, 1e-12)
        if small_step or small_gain:
            converged = True
            break

    A, _, w = prob.normal_equations(r, J, D)
    B = np.linalg.pinv(A)[:6, :6]
    if plane_errors:
        cov = B
    else:
        sigma2 = float(np.sum(w * r * r)) / max(len(r) - 6, 1)
        cov = sigma2 * B
    cov = 0.5 * (cov + cov.T)
    std_model = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    cov, spread = _with_pose_spread(cov, std_model, B, prob.pid, w * r, J[:, :6])
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    result = Rigid(R, t)
    raw = np.concatenate(point_residuals(poses, result))
    return ExtrinsicResult(
        camera_to_laser=result,
        std=std,
        std_rot_deg=np.degrees(std[:3]),
        std_rpy_deg=_euler_std_deg(R, cov[:3, :3]),
        std_t_mm=std[3:] * 1e3,
        covariance=cov,
        residuals_per_pose=_pose_rms(poses, result),
        outliers=(),
        rms_m=float(math.sqrt(np.mean(raw * raw))),
        iterations=iterations,
        converged=converged,
        n_points=len(r),
        loss=loss,
        f_scale=f_scale,
        plane_errors=bool(plane_errors),
        laser_noise_m=sigma,
        initial=initial,
        std_model=std_model,
        std_spread=spread,
    )


def _outlier_threshold(rms: np.ndarray, k: float, min_excess: float) -> float:
    med = float(np.median(rms))
    mad = 1.4826 * float(np.median(np.abs(rms - med)))
    return med + max(k * mad, min_excess)


def _reject(
    poses: list[BoardPose],
    result: ExtrinsicResult,
    outliers: tuple[int, ...],
    refit: Any,
    outlier_k: float,
    min_excess: float,
    max_rounds: int,
) -> tuple[ExtrinsicResult, tuple[int, ...], float, int]:
    """Rounds of outlier rejection: (result, outliers, threshold, iterations)."""
    iterations = 0
    threshold = math.inf
    for _ in range(max_rounds):
        rms = _pose_rms(poses, result.camera_to_laser)
        threshold = _outlier_threshold(rms, outlier_k, min_excess)
        found = tuple(int(i) for i in np.flatnonzero(rms > threshold))
        if found == outliers:
            break
        kept = [p for i, p in enumerate(poses) if i not in found]
        if len(kept) < MIN_POSES:
            warnings.warn(
                f"{len(found)} of {len(poses)} board poses look like outliers (RMS residual "
                f"above {threshold * 1e3:.1f} mm: poses {list(found)}) but fewer than "
                f"{MIN_POSES} would remain, so none more are dropped; check the board "
                f"detections and the laser segmentation, or add poses",
                stacklevel=3,
            )
            break
        check_geometry(kept)
        outliers = found
        result = refit(kept, result.camera_to_laser)
        iterations += result.iterations
    return result, outliers, threshold, iterations


def calibrate(
    poses: Sequence[BoardPose],
    loss: Loss = "huber",
    f_scale: float = 0.01,
    outlier_k: float = 3.5,
    min_outlier_excess: float = 0.01,
    plane_errors: bool | None = None,
    max_rounds: int = 5,
) -> ExtrinsicResult:
    """Linear solution, robust refinement, outlier poses dropped, refinement again.

    Outlier rejection: a pose is an outlier when its RMS residual (m) exceeds the median
    of all poses' by more than ``outlier_k`` times their MAD (scaled by 1.4826, a
    standard deviation for Gaussian spread) and by more than ``min_outlier_excess``
    metres (so that poses are not dropped for millimetre differences when the data are
    clean); the outliers are dropped and the rest re-solved, in rounds (at most
    ``max_rounds``) until the set no longer changes — a pose dropped in one round may
    come back in the next.

    Order: the linear solution seeds the robust refinement with the planes taken as
    exact (6 parameters: stiff, so outlier poses stand out) and the outliers are
    rejected with it; when the poses carry plane covariances (and ``plane_errors`` is not
    False) that solution seeds :func:`refine` with plane errors on the kept poses, whose
    outliers are checked again the same way. (Fitted with plane corrections first, a
    moved board can be absorbed by its own plane correction while good poses pay for
    it.) Raises ValueError when the poses are too few or degenerate; warns and keeps
    them when dropping the outliers would leave fewer than 5 poses.
    ``residuals_per_pose`` covers all input poses.
    """
    poses = list(poses)
    initial = linear_solution(poses)
    use_planes = plane_errors is not False and all(p.plane_cov is not None for p in poses)
    if plane_errors and not use_planes:
        raise ValueError("plane_errors needs every pose's plane_cov (BoardPose.from_fit)")

    def plain(ps: Sequence[BoardPose], start: Rigid) -> ExtrinsicResult:
        return refine(ps, start, loss, f_scale, plane_errors=False)

    def full(ps: Sequence[BoardPose], start: Rigid) -> ExtrinsicResult:
        return refine(ps, start, loss, f_scale, plane_errors=True)

    result = plain(poses, initial)
    iterations = result.iterations
    result, outliers, threshold, its = _reject(
        poses, result, (), plain, outlier_k, min_outlier_excess, max_rounds
    )
    iterations += its
    if use_planes:
        result = full([p for i, p in enumerate(poses) if i not in outliers], result.camera_to_laser)
        iterations += result.iterations
        result, outliers, threshold, its = _reject(
            poses, result, outliers, full, outlier_k, min_outlier_excess, max_rounds
        )
        iterations += its
    return replace(
        result,
        outliers=outliers,
        residuals_per_pose=_pose_rms(poses, result.camera_to_laser),
        iterations=iterations,
        outlier_threshold_m=threshold,
        initial=initial,
    )
