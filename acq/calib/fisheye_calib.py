"""`acq calibrate fisheye`: the fisheye's intrinsics from its image circle (paper §3.3.2),
optionally refined on a checkerboard with the generic Kannala–Brandt model.

From the circle: ``(u0, v0)`` is its centre and ``f = r / theta_max`` with ``theta_max``
half the lens's aperture (``--fov``), the paper's equidistant model; with ``--ellipse``
(non-square pixels) ``fx = rx / theta_max`` and ``fy = ry / theta_max``, written as a
Kannala–Brandt model with zero coefficients.

With ``--board COLSxROWSxSQUARE`` (inner corners, square side in metres) the Kannala–Brandt
model (fx, fy, cx, cy, k1..k4) is fitted to the board's corners by Levenberg–Marquardt on
reprojection errors, initialised from the circle. Angles are ``atan2(rho, z)``, so corners
seen more than 90 degrees off the axis are modelled correctly (OpenCV's fisheye
calibration mirrors them). Its standard deviations (from the covariance of the fit,
scaled by the residuals' variance) go into calib.yaml's ``std``. The circle alone writes
none: its fit's σ of the centre (hundredths of a pixel) says nothing of how far the
principal point is from the circle's centre (1.2 px on the real images).

The circle's f rests on two assumptions the circle cannot check: the data sheet's
aperture and an equidistant lens. Alone, it says so (:func:`circle_assumptions`: the
range of f for an aperture :data:`APERTURE_TOLERANCE_DEG` off, and a note kept in
calib.yaml); with a board, :func:`circle_check` says how far the circle's model is from
the board's and which assumption put it there.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import imagesize
import numpy as np
import numpy.typing as npt

from acq.calib.checkerboard import BoardSpec, board_hint, detect_corners, parse_board
from acq.calib.image_circle import CircleResult
from acq.camera import calibfile
from acq.camera.calibfile import CalibFileError, Calibration, CalibStd, CameraCalib
from acq.camera.camera_models import Equidistant, KannalaBrandt
from acq.errors import InputValueError
from acq.geometry.rotations import matrix_from_rotvec, rotation_between, rotvec_from_matrix

__all__ = [
    "APERTURE_TOLERANCE_DEG",
    "BoardFit",
    "BoardSpec",
    "CircleAssumptions",
    "CircleCheck",
    "calibrate_board",
    "circle_assumptions",
    "circle_check",
    "circle_model",
    "detect_corners",
    "fit_kannala_brandt",
    "model_gap_px",
    "parse_board",
    "project_kb",
    "read_images",
    "update_calibration",
]

METHOD_CIRCLE = "image_circle"
METHOD_BOARD = "checkerboard (kannala_brandt, from image_circle)"
APERTURE_TOLERANCE_DEG = 5.0
"""How far a data sheet's full aperture (``--fov``) is taken to be off, degrees: the
range of f the circle alone states."""


# --- from the circle --------------------------------------------------------------------


def circle_model(result: CircleResult, fov_deg: float) -> KannalaBrandt:
    """The paper's model from the circle: equidistant, ``f = r / theta_max`` (px/rad).

    An ellipse (``rx != ry``) gives a Kannala–Brandt model with zero coefficients and
    ``fx = rx / theta_max``, ``fy = ry / theta_max``.
    """
    if not 0.0 < fov_deg < 360.0:
        raise ValueError(f"fov {fov_deg}: expected degrees in (0, 360)")
    theta_max = math.radians(fov_deg) / 2.0
    c = result.circle
    if c.rx == c.ry:
        return Equidistant.from_f(
            c.rx / theta_max, c.cx, c.cy, result.width, result.height, fov_deg
        )
    return KannalaBrandt(
        result.width,
        result.height,
        c.rx / theta_max,
        c.ry / theta_max,
        c.cx,
        c.cy,
        fov_deg=fov_deg,
    )


@dataclass(frozen=True)
class CircleAssumptions:
    """What the circle's ``f = r / theta_max`` rests on, unchecked: the aperture
    ``fov_deg`` (degrees, full) and an equidistant lens. ``f_px`` the circle's f (mean of
    fx, fy), ``f_range_px`` its values for an aperture ``tolerance_deg`` wider and
    narrower (px/rad)."""

    fov_deg: float
    tolerance_deg: float
    f_px: float
    f_range_px: tuple[float, float]

    def note(self) -> str:
        """One line for calib.yaml's ``note`` and the printed result."""
        lo, hi = self.f_range_px
        a, t = self.fov_deg, self.tolerance_deg
        return (
            f"f = r / theta_max from the image circle alone, not checked: it assumes an "
            f"aperture of {a:g} deg (--fov) and an equidistant lens (r = f theta); an "
            f"aperture {t:g} deg off ({a - t:g}..{a + t:g} deg) gives f {lo:.1f}..{hi:.1f} "
            f"px/rad ({lo - self.f_px:+.1f}/{hi - self.f_px:+.1f}), a lens that is not "
            "equidistant can be further off (--board checks both on a checkerboard)"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "fov_deg": self.fov_deg,
            "tolerance_deg": self.tolerance_deg,
            "f_px": round(self.f_px, 3),
            "f_range_px": [round(f, 3) for f in self.f_range_px],
            "note": self.note(),
        }


def circle_assumptions(
    model: KannalaBrandt, tolerance_deg: float = APERTURE_TOLERANCE_DEG
) -> CircleAssumptions:
    """The circle model's (:func:`circle_model`) f and its range for an aperture
    ``tolerance_deg`` (full, degrees) off: ``f = r / theta_max`` scales as
    ``1 / theta_max``."""
    fov = model.fov_deg
    f = (model.fx + model.fy) / 2
    wide, narrow = fov + tolerance_deg, max(fov - tolerance_deg, 1e-6)
    return CircleAssumptions(fov, tolerance_deg, f, (f * fov / wide, f * fov / narrow))


@dataclass(frozen=True)
class CircleCheck:
    """The circle's model against a board's fit of the same lens: ``f_circle_px`` and
    ``f_board_px`` (means of fx, fy, px/rad) and how far apart (``off_percent``, the
    circle's relative to the board's); ``rim_deg`` the angle off the axis at which the
    board's lens images the circle's rim (``radius_px``), against the stated
    ``fov_deg`` / 2; ``off_percent`` split into the aperture's part (rim angle against
    the stated one) and the lens's departure from equidistance (the rest, so that
    ``(1 + aperture) (1 + equidistance) = 1 + off``); ``gap_px`` the largest distance
    between the two models' images of a ray up to ``max_theta_deg`` (the board's)."""

    f_circle_px: float
    f_board_px: float
    off_percent: float
    radius_px: float
    rim_deg: float
    fov_deg: float
    aperture_percent: float
    equidistance_percent: float
    gap_px: float
    max_theta_deg: float

    def line(self) -> str:
        if not math.isfinite(self.rim_deg):
            return (
                f"the circle's model against the board's: f {self.f_circle_px:.2f} px/rad is "
                f"{abs(self.off_percent):.1f} % {'below' if self.off_percent < 0 else 'above'} "
                f"the board's {self.f_board_px:.2f}; the board's lens model does not reach the "
                f"rim (r {self.radius_px:.1f} px); up to {self.gap_px:.1f} px apart over the "
                f"board's angles (to {self.max_theta_deg:.1f} deg)"
            )
        return (
            f"the circle's model against the board's: f {self.f_circle_px:.2f} px/rad is "
            f"{abs(self.off_percent):.1f} % {'below' if self.off_percent < 0 else 'above'} "
            f"the board's {self.f_board_px:.2f}; the board's lens images the rim (r "
            f"{self.radius_px:.1f} px) at {self.rim_deg:.1f} deg off the axis (aperture "
            f"{2 * self.rim_deg:.1f} deg against --fov {self.fov_deg:g}): the aperture "
            f"accounts for {self.aperture_percent:+.1f} %, the lens not being equidistant "
            f"for {self.equidistance_percent:+.1f} %; up to {self.gap_px:.1f} px apart over "
            f"the board's angles (to {self.max_theta_deg:.1f} deg)"
        )

    def to_dict(self) -> dict[str, float]:
        return {k: round(float(v), 3) for k, v in vars(self).items()}


def circle_check(circle: KannalaBrandt, radius_px: float, fit: BoardFit) -> CircleCheck:
    """How far the circle's model (:func:`circle_model`, rim ``radius_px``) is from the
    board's fit ``fit`` (:class:`CircleCheck`)."""
    board = fit.model
    f_c, f_b = (circle.fx + circle.fy) / 2, (board.fx + board.fy) / 2
    stated = math.radians(circle.fov_deg) / 2
    with np.errstate(all="ignore"):  # a lens polynomial that cannot reach the rim: NaN
        rim = float(board.undistort_theta(np.array([radius_px / f_b]))[0])
    if not (math.isfinite(rim) and 0 < rim <= math.pi):
        rim = math.nan
    aperture = stated / rim  # f_c = r / stated = (r / rim) (rim / stated)
    equidistance = radius_px / rim / f_b
    return CircleCheck(
        f_circle_px=f_c,
        f_board_px=f_b,
        off_percent=100 * (f_c / f_b - 1),
        radius_px=radius_px,
        rim_deg=math.degrees(rim),
        fov_deg=circle.fov_deg,
        aperture_percent=100 * (1 / aperture - 1),
        equidistance_percent=100 * (equidistance - 1),
        gap_px=model_gap_px(circle, board, math.radians(fit.max_theta_deg)),
        max_theta_deg=fit.max_theta_deg,
    )


def update_calibration(
    path: Path,
    camera: str | None,
    model: KannalaBrandt,
    method: str,
    std: CalibStd | None = None,
    note: str = "",
) -> tuple[Calibration, str, list[str]]:
    """The calibration in ``path`` (a new one if absent) with ``camera``'s intrinsics set.

    ``std``: the intrinsics' standard deviations (its fx, fy, cx, cy, k; none if None),
    which replace the old ones, as ``note`` (what they rest on) replaces the old note.
    The camera's extrinsics, their std and time offset, the
    other cameras and the laser entries are kept; a new camera has no ``camera_to_laser``
    (``acq calibrate extrinsic`` adds it). ``camera`` None: the file's only camera, or
    ``camera`` for a new file. Returns the calibration, the camera's name and notes for
    the user (among them how far the new f is from the one it replaces). Raises
    CalibFileError.
    """
    intr = (std or CalibStd()).merged(CalibStd(), CalibStd.EXTRINSICS)
    notes: list[str] = []
    if path.exists():
        old = calibfile.load(path, intrinsics_only=True)
        if camera is None:
            if len(old.cameras) != 1:
                raise CalibFileError(
                    f"{path}: has cameras {', '.join(old.cameras)}; name one with --camera"
                )
            camera = next(iter(old.cameras))
        cameras = dict(old.cameras)
        prev = cameras.get(camera)
        if prev is None:
            entry = CameraCalib(model, None, method=method, std=intr, note=note)
            notes.append(f"camera {camera!r} added to {path}")
        else:
            size = (prev.model.width, prev.model.height)
            if size != (model.width, model.height):
                notes.append(
                    f"camera {camera!r}: image size {size[0]}x{size[1]} replaced by "
                    f"{model.width}x{model.height}; check its extrinsics"
                )
            elif isinstance(prev.model, KannalaBrandt):  # a second estimate of f: compared
                f_old, f_new = (prev.model.fx + prev.model.fy) / 2, (model.fx + model.fy) / 2
                if abs(f_new / f_old - 1) > 0.005:
                    notes.append(
                        f"camera {camera!r}: f {f_new:.2f} px/rad ({method}) replaces "
                        f"{f_old:.2f} ({prev.method or 'no method'}) in {path}, "
                        f"{100 * (f_new / f_old - 1):+.1f} %"
                    )
            kept = prev.std.merged(intr, CalibStd.INTRINSICS)
            entry = CameraCalib(model, prev.extrinsics, prev.time_offset_s, method, kept, note)
        cameras[camera] = entry
        calib = Calibration(old.laser, cameras, old.laser_to_vehicle)
    else:
        camera = camera or "camera"
        entry = CameraCalib(model, None, method=method, std=intr, note=note)
        calib = Calibration(cameras={camera: entry})
    return calib, camera, notes


# --- Kannala-Brandt on the checkerboard (acq.calib.checkerboard) ------------------------


def project_kb(intr: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(N,3) camera-frame points -> (N,2) px with ``intr = (fx, fy, cx, cy, k1..k4)``;
    ``theta = atan2(rho, z)``, valid past 90 degrees."""
    fx, fy, cx, cy, k1, k2, k3, k4 = intr
    rho = np.hypot(P[:, 0], P[:, 1])
    th = np.arctan2(rho, P[:, 2])
    t2 = th * th
    rd = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    s = np.where(rho > 0, rd / np.maximum(rho, 1e-300), 0.0)
    return np.stack([fx * s * P[:, 0] + cx, fy * s * P[:, 1] + cy], axis=1)


def _levenberg_marquardt(
    fun: Callable[[np.ndarray], np.ndarray],
    jac: Callable[[np.ndarray, np.ndarray], np.ndarray],
    x0: np.ndarray,
    iterations: int = 200,
) -> tuple[np.ndarray, np.ndarray]:
    """Minimise ``|fun(x)|²`` from x0. Returns x and J at x."""
    x = x0.astype(np.float64).copy()
    r = fun(x)
    cost = float(r @ r)
    lam = 1e-3
    J = jac(x, r)
    for _ in range(iterations):
        A = J.T @ J
        g = J.T @ r
        improved = False
        for _ in range(20):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            x_new = x + step
            r_new = fun(x_new)
            c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new < cost:
                done = cost - c_new < 1e-12 * cost or np.max(np.abs(step)) < 1e-12
                x, r, cost = x_new, r_new, c_new
                lam = max(lam / 10, 1e-12)
                improved = True
                break
            lam *= 10
        if not improved:
            break
        J = jac(x, r)
        if done:
            break
    return x, J


@dataclass(frozen=True)
class BoardFit:
    """A Kannala–Brandt fit to checkerboard corners."""

    model: KannalaBrandt
    rms_px: float  # RMS reprojection error over all corners (2-D distance)
    view_rms_px: list[float]  # per view
    views: list[int]  # indices of the images used (the board was found)
    sigma: dict[str, float]  # standard errors of the intrinsics
    max_theta_deg: float  # the largest angle off the axis among the corners
    poses: list[tuple[np.ndarray, np.ndarray]]  # board -> camera (rvec, tvec) per view

    def std(self) -> CalibStd:
        """The intrinsics' standard deviations for calib.yaml (3 significant digits);
        none when the fit's covariance is singular."""
        s = self.sigma
        k = tuple(s[f"k{i}"] for i in range(1, 5))
        if not all(math.isfinite(v) for v in s.values()):
            return CalibStd()
        return CalibStd(fx=s["fx"], fy=s["fy"], cx=s["cx"], cy=s["cy"], k=k).rounded()

    def to_dict(self) -> dict[str, Any]:
        m = self.model
        return {
            "model": "kannala_brandt",
            "fx": round(m.fx, 4),
            "fy": round(m.fy, 4),
            "cx": round(m.cx, 4),
            "cy": round(m.cy, 4),
            "k": [float(f"{k:.6g}") for k in m.k],
            "rms_px": round(self.rms_px, 4),
            "view_rms_px": [round(v, 4) for v in self.view_rms_px],
            "views": self.views,
            "sigma": {k: float(f"{v:.3g}") for k, v in self.sigma.items()},
            "max_theta_deg": round(self.max_theta_deg, 2),
        }


def _initial_pose(
    init: KannalaBrandt, obj: np.ndarray, uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Board -> camera pose (rvec, tvec) from the corners' rays under the initial model:
    planar PnP in a virtual camera turned towards the board (so a board seen 90 degrees
    or more off the axis is handled like one in front)."""
    rays = init.unproject(uv)
    m = rays.mean(axis=0)
    m /= np.linalg.norm(m)
    R_v = rotation_between(m, [0.0, 0.0, 1.0])
    rv = rays @ R_v.T
    if np.any(rv[:, 2] <= 0.05):
        raise ValueError("the board spans too wide an angle for an initial pose")
    norm = rv[:, :2] / rv[:, 2:3]
    ok, rvec, tvec = cv2.solvePnP(
        obj, norm.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE
    )
    if not ok or not np.all(np.isfinite(rvec)):
        raise ValueError("no initial board pose")
    R = R_v.T @ matrix_from_rotvec(rvec.ravel())
    t = R_v.T @ tvec.ravel()
    return rotvec_from_matrix(R), t


def fit_kannala_brandt(
    obj: np.ndarray,
    corners: Sequence[np.ndarray],
    init: KannalaBrandt,
    fov_deg: float | None = None,
) -> BoardFit:
    """Kannala–Brandt intrinsics and board poses minimising the corners' reprojection
    error (px), from the ``init`` model (e.g. the circle's). ``obj`` (N,3) board points m,
    ``corners`` one (N,2) array per view."""
    V = len(corners)
    if V == 0:
        raise ValueError("no views")
    poses = [_initial_pose(init, obj, uv) for uv in corners]
    x0 = np.concatenate(
        [[init.fx, init.fy, init.cx, init.cy, *init.k], *[np.r_[r, t] for r, t in poses]]
    )

    def cam_points(x: npt.NDArray[np.float64], v: int) -> npt.NDArray[np.float64]:
        p = x[8 + 6 * v : 14 + 6 * v]
        P: npt.NDArray[np.float64] = obj @ matrix_from_rotvec(p[:3]).T + p[3:]
        return P

    def view_res(x: npt.NDArray[np.float64], v: int) -> npt.NDArray[np.float64]:
        r: npt.NDArray[np.float64] = (project_kb(x[:8], cam_points(x, v)) - corners[v]).ravel()
        return r

    def fun(x: np.ndarray) -> np.ndarray:
        return np.concatenate([view_res(x, v) for v in range(V)])

    n = len(obj) * 2

    def jac(x: np.ndarray, r: np.ndarray) -> np.ndarray:
        J = np.zeros((len(r), len(x)))
        for i in range(len(x)):
            h = 1e-6 * max(1.0, abs(x[i]))
            xp, xm = x.copy(), x.copy()
            xp[i] += h
            xm[i] -= h
            if i < 8:
                J[:, i] = (fun(xp) - fun(xm)) / (2 * h)
            else:
                v = (i - 8) // 6
                J[v * n : (v + 1) * n, i] = (view_res(xp, v) - view_res(xm, v)) / (2 * h)
        return J

    x, J = _levenberg_marquardt(fun, jac, x0)
    res = fun(x).reshape(-1, 2)
    d = np.hypot(res[:, 0], res[:, 1])
    dof = max(res.size - len(x), 1)
    s2 = float(np.sum(res**2)) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        sd = np.sqrt(np.maximum(np.diag(cov)[:8], 0.0))
    except np.linalg.LinAlgError:
        sd = np.full(8, math.nan)
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")
    thetas = []
    for v in range(V):
        P = cam_points(x, v)
        thetas.append(np.degrees(np.arctan2(np.hypot(P[:, 0], P[:, 1]), P[:, 2])).max())
    fx, fy, cx, cy, *k = (float(a) for a in x[:8])
    fov = fov_deg or init.fov_deg
    try:
        model = KannalaBrandt(
            init.width, init.height, fx, fy, cx, cy, (k[0], k[1], k[2], k[3]), fov
        )
    except ValueError as e:
        raise ValueError(
            f"the board fit is not a usable lens up to {fov / 2:g} deg ({e}); its corners "
            f"reach {max(thetas):.1f} deg off the axis: show the board nearer the rim"
        ) from None
    view_rms = [
        float(np.sqrt(np.mean(d[v * len(obj) : (v + 1) * len(obj)] ** 2))) for v in range(V)
    ]
    return BoardFit(
        model=model,
        rms_px=float(np.sqrt(np.mean(d**2))),
        view_rms_px=view_rms,
        views=list(range(V)),
        sigma=dict(zip(names, (float(s) for s in sd), strict=True)),
        max_theta_deg=float(max(thetas)),
        poses=[
            (x[8 + 6 * v : 11 + 6 * v].copy(), x[11 + 6 * v : 14 + 6 * v].copy()) for v in range(V)
        ],
    )


def calibrate_board(
    grays: Sequence[np.ndarray], board: BoardSpec, init: KannalaBrandt
) -> tuple[BoardFit, np.ndarray]:
    """Find the board in each image and fit Kannala–Brandt; returns the fit and which
    images had the board (bool per image). InputValueError when none shows ``board``
    but a board of another size is found (:func:`board_hint`), ValueError when none
    shows a board."""
    found: list[np.ndarray] = []
    used = np.zeros(len(grays), bool)
    for i, g in enumerate(grays):
        c = detect_corners(g, board)
        if c is not None:
            found.append(c)
            used[i] = True
    if not found:
        hint = board_hint(grays, board)
        what = f"no image shows the {board.cols}x{board.rows} board"
        if hint:  # the board is there, of another size: --board is wrong
            raise InputValueError(f"--board {board.text()}: {what}{hint}")
        raise ValueError(what)
    fit = fit_kannala_brandt(board.object_points(), found, init)
    fit = replace(fit, views=[int(i) for i in np.flatnonzero(used)])
    return fit, used


# --- comparing models, reading images ---------------------------------------------------


def model_gap_px(a: KannalaBrandt, b: KannalaBrandt, theta_max: float) -> float:
    """Largest distance (px) between where two models put the same ray, over rays up to
    ``theta_max`` (rad) off the axis in every direction."""
    th, ph = np.meshgrid(np.linspace(0.0, theta_max, 64), np.linspace(0, 2 * np.pi, 72))
    rays = np.stack(
        [np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1
    ).reshape(-1, 3)
    d = a.project(rays)[0] - b.project(rays)[0]
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


# 4 times the largest fisheye sensors' 25 MP: a 16-bit colour image of it decodes to 600 MB
MAX_IMAGE_PIXELS = 100_000_000


def read_images(paths: Sequence[Path]) -> list[np.ndarray]:
    """The images as stored (grey or BGR uint8, 16-bit scaled down, alpha dropped);
    InputValueError naming a file that is not an 8- or 16-bit grey or colour image, or
    whose header declares more than :data:`MAX_IMAGE_PIXELS` (checked before decoding,
    for every format ``imagesize`` reads: PNG, JPEG, BMP, TIFF, WebP, Netpbm...)."""
    images = []
    for p in paths:
        path = Path(p)
        if path.is_dir():
            raise InputValueError(f"{p}: a directory, not an image")
        if not path.is_file():
            raise InputValueError(f"{p}: no such file")
        width, height = imagesize.get(path)
        if width * height > MAX_IMAGE_PIXELS and width > 0 and height > 0:
            raise InputValueError(
                f"{p}: declares {width}x{height} pixels ({width * height / 1e6:.0f} MP), more"
                f" than the {MAX_IMAGE_PIXELS / 1e6:.0f} MP an image may have; not decoded"
            )
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None or img.size == 0:
            raise InputValueError(f"{p}: cannot read as an image")
        if img.dtype == np.uint16:
            img = (img / 257.0).astype(np.uint8)
        if img.dtype != np.uint8:
            raise InputValueError(f"{p}: {img.dtype} pixels; expected an 8- or 16-bit image")
        if img.ndim == 3 and img.shape[2] in (2, 4):  # grey or colour with alpha
            img = img[:, :, : img.shape[2] - 1]
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        if img.ndim != 2 and not (img.ndim == 3 and img.shape[2] == 3):
            raise InputValueError(f"{p}: {img.shape} pixels; expected a grey or colour image")
        images.append(img)
    return images
