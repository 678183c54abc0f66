"""The projection core: laser points -> camera pixels -> colours.

Paper eq. (2) relates the frames: ``P_laser = R @ P_camera + t``, so a laser point goes
into the camera by ``R.T @ (P_laser - t)``. The kernels fuse that change of frame, the
fisheye or pinhole projection and the colour lookup in one compiled pass over the
points (numba, float32 arithmetic, vectorised, split over the cores);
``acq.camera.camera_models`` is the float64 reference they are tested against (agreement
within 1e-3 px).

Points may be float32 or float64 (N,3) metres in the laser frame; rows that are not
finite (no echo) come out invalid. Pixels are (u, v) with pixel centres at integers.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np

from acq.camera.camera_models import CameraModel, KannalaBrandt, Pinhole
from acq.geometry.transforms import Rigid

__all__ = [
    "colorize",
    "colour_into",
    "depth_and_angle",
    "kernel_args",
    "laser_to_camera",
    "pixels_read",
    "project",
    "project_block",
]

_PI = np.float32(math.pi)
_PI_2 = np.float32(math.pi / 2)
_PI_4 = np.float32(math.pi / 4)
_TAN_PI_8 = np.float32(0.41421356237309503)


@numba.njit(inline="always", fastmath=True, error_model="numpy")
def _atan01(a):  # type: ignore[no-untyped-def]
    """atan(a) for a in [0, 1], float32, about 1 ulp (Cephes atanf), branch-free."""
    big = a > _TAN_PI_8
    x = (a - np.float32(1.0)) / (a + np.float32(1.0)) if big else a
    z = x * x
    p = (
        (
            (np.float32(8.05374449538e-2) * z - np.float32(1.38776856032e-1)) * z
            + np.float32(1.99777106478e-1)
        )
        * z
        - np.float32(3.33329491539e-1)
    ) * z * x + x
    return p + _PI_4 if big else p


@numba.njit(inline="always", fastmath=True, error_model="numpy")
def _theta(rho, z):  # type: ignore[no-untyped-def]
    """atan2(rho, z) for rho >= 0, in [0, pi], float32."""
    az = abs(z)
    hi = max(rho, az)
    lo = min(rho, az)
    a = lo / hi if hi > np.float32(0.0) else np.float32(0.0)
    t = _atan01(a)
    t = _PI_2 - t if rho > az else t
    return _PI - t if z < np.float32(0.0) else t


@numba.njit(inline="always", fastmath=True, error_model="numpy")
def _kb_pixel(px, py, pz, fx, fy, cx, cy, k1, k2, k3, k4, tmax):  # type: ignore[no-untyped-def]
    """One camera-frame point through the Kannala–Brandt model: (u, v, ok)."""
    rho = math.sqrt(px * px + py * py)
    th = _theta(rho, pz)
    t2 = th * th
    rd = th * (np.float32(1.0) + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    # rd / rho -> 1 / z as rho -> 0 (on the optical axis)
    s = rd / rho if rho > np.float32(1e-12) * abs(pz) else np.float32(1.0) / pz
    u = cx + fx * s * px
    v = cy + fy * s * py
    ok = th <= tmax and (rho > np.float32(0.0) or pz > np.float32(0.0))
    return u, v, ok


@numba.njit(inline="always", fastmath=True, error_model="numpy")
def _pinhole_pixel(px, py, pz, fx, fy, cx, cy, k1, k2, p1, p2, k3):  # type: ignore[no-untyped-def]
    """One camera-frame point through OpenCV's pinhole model: (u, v, ok).

    In float64: the terms of a strong radial polynomial cancel near the image corners,
    which costs float32 a few thousandths of a pixel. Not ok past the radius where the
    distortion folds back (see ``Pinhole.project``).
    """
    iz = 1.0 / np.float64(pz)
    a = px * iz
    b = py * iz
    r2 = a * a + b * b
    radial = 1.0 + r2 * (k1 + r2 * (np.float64(k2) + r2 * k3))
    xd = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
    yd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
    monotone = radial + 2.0 * r2 * (k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)) > 0.0
    return np.float32(cx + fx * xd), np.float32(cy + fy * yd), pz > np.float32(0.0) and monotone


_BLOCK = 4096  # points per parallel task: the per-block buffers stay in L1/L2


@numba.njit(inline="always", fastmath=True, error_model="numpy")
def project_block(Pf, R, t, intr, pinhole, w, h, uvf, valid):  # type: ignore[no-untyped-def]
    """Flat (3n,) laser points -> flat (2n,) pixels uvf and (n,) valid, for a camera at
    ``R``, ``t`` with ``intr``/``pinhole`` (:func:`kernel_args`) and an image ``w`` x
    ``h`` px (float32); a numba kernel, inlined where other kernels call it.

    Flat arrays with constant strides, a loop from 0 and no early exits let LLVM
    vectorise this loop (8 points per AVX2 instruction); indexing an (N,3) array per
    row, or a loop from a run-time start, does not.
    """
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    c0, c1, c2, c3, c4 = intr[4], intr[5], intr[6], intr[7], intr[8]
    for i in range(valid.shape[0]):
        dx = np.float32(Pf[3 * i]) - t0
        dy = np.float32(Pf[3 * i + 1]) - t1
        dz = np.float32(Pf[3 * i + 2]) - t2
        # R.T @ (p - t)
        px = r00 * dx + r10 * dy + r20 * dz
        py = r01 * dx + r11 * dy + r21 * dz
        pz = r02 * dx + r12 * dy + r22 * dz
        if pinhole:
            u, v, ok = _pinhole_pixel(px, py, pz, fx, fy, cx, cy, c0, c1, c2, c3, c4)
        else:
            u, v, ok = _kb_pixel(px, py, pz, fx, fy, cx, cy, c0, c1, c2, c3, c4)
        uvf[2 * i] = u
        uvf[2 * i + 1] = v
        # NaN fails every comparison, so non-finite points come out invalid here.
        valid[i] = (
            ok
            & (u >= np.float32(-0.5))
            & (u < w - np.float32(0.5))
            & (v >= np.float32(-0.5))
            & (v < h - np.float32(0.5))
        )


@numba.njit(nogil=True, fastmath=True, cache=True, error_model="numpy")
def _project_range(Pf, lo, hi, R, t, intr, pinhole, w, h, uvf, valid):  # type: ignore[no-untyped-def]
    project_block(
        Pf[3 * lo : 3 * hi], R, t, intr, pinhole, w, h, uvf[2 * lo : 2 * hi], valid[lo:hi]
    )


@numba.njit(inline="always", fastmath=True, error_model="numpy")
def _sample(image, u, v, bilinear, out, i):  # type: ignore[no-untyped-def]
    """Write the colour at (u, v) (already known to be on the sensor) into out[i]."""
    h, w, nc = image.shape
    if not bilinear:
        iu = min(int(u + np.float32(0.5)), w - 1)
        iv = min(int(v + np.float32(0.5)), h - 1)
        for c in range(nc):
            out[i, c] = image[iv, iu, c]
        return
    uc = min(max(u, np.float32(0.0)), np.float32(w - 1))
    vc = min(max(v, np.float32(0.0)), np.float32(h - 1))
    u0 = min(int(uc), w - 2) if w > 1 else 0
    v0 = min(int(vc), h - 2) if h > 1 else 0
    u1 = min(u0 + 1, w - 1)
    v1 = min(v0 + 1, h - 1)
    a = uc - np.float32(u0)
    b = vc - np.float32(v0)
    for c in range(nc):
        top = (np.float32(1.0) - a) * np.float32(image[v0, u0, c]) + a * np.float32(
            image[v0, u1, c]
        )
        bot = (np.float32(1.0) - a) * np.float32(image[v1, u0, c]) + a * np.float32(
            image[v1, u1, c]
        )
        out[i, c] = np.uint8(min((np.float32(1.0) - b) * top + b * bot + np.float32(0.5), 255.0))


@numba.njit(nogil=True, fastmath=True, cache=True, error_model="numpy")
def _colorize_range(Pf, lo, hi, R, t, intr, pinhole, image, bilinear, out, valid):  # type: ignore[no-untyped-def]
    w = np.float32(image.shape[1])
    h = np.float32(image.shape[0])
    uvf = np.empty(2 * _BLOCK, dtype=np.float32)
    for blo in range(lo, hi, _BLOCK):
        bhi = min(blo + _BLOCK, hi)
        # Project a block (vectorised), then gather its colours (scalar).
        project_block(
            Pf[3 * blo : 3 * bhi], R, t, intr, pinhole, w, h, uvf[: 2 * (bhi - blo)], valid[blo:bhi]
        )
        for i in range(blo, bhi):
            if valid[i]:
                _sample(image, uvf[2 * (i - blo)], uvf[2 * (i - blo) + 1], bilinear, out, i)


@numba.njit(nogil=True, fastmath=True, cache=True, error_model="numpy")
def _gather(P, idx, t, blo, m, Pf):  # type: ignore[no-untyped-def]
    """``Pf[:3m]`` the points ``P[idx[blo : blo + m]]`` relative to the camera at ``t``,
    subtracted in float64 (world coordinates can be large)."""
    for i in range(m):
        k = idx[blo + i]
        Pf[3 * i] = P[k, 0] - t[0]
        Pf[3 * i + 1] = P[k, 1] - t[1]
        Pf[3 * i + 2] = P[k, 2] - t[2]


@numba.njit(nogil=True, fastmath=True, cache=True, error_model="numpy")
def _colour_into(P, idx, R, t, intr, pinhole, image, bilinear, out, valid, uv):  # type: ignore[no-untyped-def]
    w = np.float32(image.shape[1])
    h = np.float32(image.shape[0])
    zero = np.zeros(3, dtype=np.float32)
    Pf = np.empty(3 * _BLOCK, dtype=np.float32)
    uvf = np.empty(2 * _BLOCK, dtype=np.float32)
    ok = np.empty(_BLOCK, dtype=np.bool_)
    for blo in range(0, idx.size, _BLOCK):
        m = min(blo + _BLOCK, idx.size) - blo
        _gather(P, idx, t, blo, m, Pf)
        project_block(Pf[: 3 * m], R, zero, intr, pinhole, w, h, uvf[: 2 * m], ok[:m])
        for i in range(m):
            if ok[i]:
                k = idx[blo + i]
                _sample(image, uvf[2 * i], uvf[2 * i + 1], bilinear, out, k)
                valid[k] = True
                if uv.shape[0]:
                    uv[k, 0] = uvf[2 * i]
                    uv[k, 1] = uvf[2 * i + 1]


@numba.njit(nogil=True, fastmath=True, cache=True, error_model="numpy")
def _pixels_read(P, idx, R, t, intr, pinhole, w_px, h_px, rows, cols):  # type: ignore[no-untyped-def]
    """The rows and columns :func:`_colour_into` reads for ``idx``, and one more each
    side (the kernels need not round alike): ``rows`` (H,) set True, ``cols`` [lo, hi)
    widened."""
    w = np.float32(w_px)
    h = np.float32(h_px)
    zero = np.zeros(3, dtype=np.float32)
    Pf = np.empty(3 * _BLOCK, dtype=np.float32)
    uvf = np.empty(2 * _BLOCK, dtype=np.float32)
    ok = np.empty(_BLOCK, dtype=np.bool_)
    for blo in range(0, idx.size, _BLOCK):
        m = min(blo + _BLOCK, idx.size) - blo
        _gather(P, idx, t, blo, m, Pf)
        project_block(Pf[: 3 * m], R, zero, intr, pinhole, w, h, uvf[: 2 * m], ok[:m])
        for i in range(m):
            if ok[i]:
                # nearest reads round(x), bilinear floor(x) and floor(x) + 1
                u = min(max(int(uvf[2 * i]), 0), w_px - 1)
                v = min(max(int(uvf[2 * i + 1]), 0), h_px - 1)
                for r in range(max(v - 1, 0), min(v + 3, h_px)):
                    rows[r] = True
                cols[0] = min(cols[0], max(u - 1, 0))
                cols[1] = max(cols[1], min(u + 3, w_px))


@numba.njit(nogil=True, cache=True)
def _depth_theta(P, idx, R, t, depth, theta):  # type: ignore[no-untyped-def]
    for k in idx:
        dx, dy, dz = P[k, 0] - t[0], P[k, 1] - t[1], P[k, 2] - t[2]
        x = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
        y = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
        z = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
        r = math.sqrt(x * x + y * y)
        depth[k] = math.sqrt(r * r + z * z)
        theta[k] = math.atan2(r, z)


def depth_and_angle(
    P: np.ndarray,
    idx: np.ndarray,
    camera_to_points: tuple[np.ndarray, np.ndarray],
    depth: np.ndarray,
    theta: np.ndarray,
) -> None:
    """For the points ``P[idx]`` (``P`` (N,3) float64 m, ``idx`` (K,) int64), in place:
    ``depth[idx]`` their distance from the camera (m) and ``theta[idx]`` their angle from
    its optical axis (rad); ``camera_to_points`` the camera's rotation and position in
    P's frame. One pass, no GIL."""
    R, t = camera_to_points
    _depth_theta(
        P, np.asarray(idx, dtype=np.int64), np.asarray(R, dtype=np.float64),
        np.asarray(t, dtype=np.float64), depth, theta,
    )  # fmt: skip


_MIN_SPLIT = 65536  # below this many points one thread is faster than two
_pool: ThreadPoolExecutor | None = None


def _threads() -> int:
    return max(1, min(numba.get_num_threads(), os.cpu_count() or 1))


def _run_split(kernel: Callable[..., None], n: int, *args: object) -> None:
    """Run ``kernel(lo, hi, ...)`` over 0..n split across threads (the kernels drop the GIL)."""
    global _pool
    parts = n // _MIN_SPLIT
    parts = 1 if parts < 2 else min(_threads(), parts)  # _threads() costs 10 us a call
    if parts == 1:
        kernel(args[0], 0, n, *args[1:])
        return
    if _pool is None:
        _pool = ThreadPoolExecutor(max_workers=_threads(), thread_name_prefix="acq-projection")
    # Part boundaries on block multiples, so every thread works on whole blocks.
    step = -(-n // parts // _BLOCK) * _BLOCK
    futures = [
        _pool.submit(kernel, args[0], lo, min(lo + step, n), *args[1:]) for lo in range(0, n, step)
    ]
    for f in futures:
        f.result()


def kernel_args(
    model: CameraModel, camera_to_laser: Rigid
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(R, t, intrinsics, is_pinhole) as float32 arrays for the kernels
    (:func:`project_block`)."""
    R = np.ascontiguousarray(camera_to_laser.rotation, dtype=np.float32)
    t = np.ascontiguousarray(camera_to_laser.translation, dtype=np.float32)
    return (R, t, *_intrinsics(model))


def _intrinsics(model: CameraModel) -> tuple[np.ndarray, bool]:
    """(intrinsics as float32, is_pinhole) for the kernels."""
    if isinstance(model, KannalaBrandt):
        intr = [model.fx, model.fy, model.cx, model.cy, *model.k, model.theta_max]
        return np.array(intr, dtype=np.float32), False
    if isinstance(model, Pinhole):
        intr = [model.fx, model.fy, model.cx, model.cy, *model.dist]
        return np.array(intr, dtype=np.float32), True
    raise TypeError(f"no projection kernel for {type(model).__name__}")


def _check_size(img: np.ndarray, model: CameraModel) -> None:
    if img.shape[:2] != (model.height, model.width):
        raise ValueError(
            f"image is {img.shape[1]}x{img.shape[0]}, the camera model {model.width}x{model.height}"
        )


def _as_points(P: np.ndarray) -> np.ndarray:
    P = np.asarray(P)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"expected (N,3) points, got shape {P.shape}")
    if P.dtype not in (np.float32, np.float64):
        P = P.astype(np.float64)
    return np.ascontiguousarray(P)


def laser_to_camera(P_laser: np.ndarray, camera_to_laser: Rigid) -> np.ndarray:
    """(N,3) laser-frame metres -> camera frame, float64: ``R.T @ (P - t)``."""
    return camera_to_laser.inverse().apply(P_laser)


def project(
    P_laser: np.ndarray, model: CameraModel, camera_to_laser: Rigid
) -> tuple[np.ndarray, np.ndarray]:
    """Laser-frame points -> ((N,2) float32 px, (N,) bool valid), compiled."""
    P = _as_points(P_laser)
    R, t, intr, pinhole = kernel_args(model, camera_to_laser)
    uv = np.empty((P.shape[0], 2), dtype=np.float32)
    valid = np.empty(P.shape[0], dtype=np.bool_)
    w, h = np.float32(model.width), np.float32(model.height)
    _run_split(
        _project_range, P.shape[0], P.reshape(-1), R, t, intr, pinhole, w, h, uv.reshape(-1), valid
    )
    return uv, valid


def colorize(
    P_laser: np.ndarray,
    model: CameraModel,
    camera_to_laser: Rigid,
    image: np.ndarray,
    bilinear: bool = False,
    out: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Colour of every laser point in ``image``: ((N,C) uint8, (N,) bool valid).

    ``image`` is (H,W,C) or (H,W) uint8 of the model's size; nearest pixel by default,
    bilinear on request. Colours of invalid points are left as they were in ``out``
    (zeros when ``out`` is not given).
    """
    P = _as_points(P_laser)
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.dtype != np.uint8 or img.ndim != 3:
        raise ValueError(f"expected an (H,W[,C]) uint8 image, got {img.dtype} {img.shape}")
    _check_size(img, model)
    R, t, intr, pinhole = kernel_args(model, camera_to_laser)
    if out is None:
        out = np.zeros((P.shape[0], img.shape[2]), dtype=np.uint8)
    elif out.shape != (P.shape[0], img.shape[2]) or out.dtype != np.uint8:
        raise ValueError(f"out must be ({P.shape[0]}, {img.shape[2]}) uint8")
    valid = np.empty(P.shape[0], dtype=np.bool_)
    img = np.ascontiguousarray(img)
    _run_split(
        _colorize_range, P.shape[0], P.reshape(-1), R, t, intr, pinhole, img, bilinear, out, valid
    )
    return out, valid


def colour_into(
    P: np.ndarray,
    idx: np.ndarray,
    model: CameraModel,
    camera_to_points: tuple[np.ndarray, np.ndarray],
    image: np.ndarray,
    out: np.ndarray,
    valid: np.ndarray,
    uv: np.ndarray | None = None,
    bilinear: bool = True,
) -> None:
    """Colour the points ``P[idx]`` (``P`` (N,3) float64 m, ``idx`` (K,) int64) in place:
    ``out[idx]`` (N,C) uint8 gets the colour in ``image`` (the image's channel order)
    where the point is on the sensor, ``valid[idx]`` (N,) bool True there, and ``uv``
    (N,2) float32 the pixel when given. ``camera_to_points``: the camera's rotation and
    position (m) in P's frame. Other rows are left as they were. One thread, no GIL (for
    frames coloured on a pool's threads)."""
    _check_size(image, model)
    R, t = camera_to_points
    intr, pinhole = _intrinsics(model)
    _colour_into(
        P, idx, np.ascontiguousarray(R, dtype=np.float32), np.asarray(t, dtype=np.float64),
        intr, pinhole, image, bilinear, out, valid,
        uv if uv is not None else np.empty((0, 2), dtype=np.float32),
    )  # fmt: skip


def pixels_read(
    P: np.ndarray,
    idx: np.ndarray,
    model: CameraModel,
    camera_to_points: tuple[np.ndarray, np.ndarray],
    rows: np.ndarray,
    cols: np.ndarray,
) -> None:
    """Where :func:`colour_into` of the same points reads its image (either sampling), and
    a pixel more each side: ``rows`` ((H,) bool, the model's height) set True at the rows,
    ``cols`` ((2,) int64, [lo, hi) px) widened to the columns. One thread, no GIL."""
    R, t = camera_to_points
    intr, pinhole = _intrinsics(model)
    _pixels_read(
        P, idx, np.ascontiguousarray(R, dtype=np.float32), np.asarray(t, dtype=np.float64),
        intr, pinhole, model.width, model.height, rows, cols,
    )  # fmt: skip
