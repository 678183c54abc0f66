"""Projection + nearest-pixel colouring of 4 million laser points (issue 2).

Three implementations do the same work in the same process, interleaved, after a
warm-up: acq's compiled kernel, ``cv2.fisheye.projectPoints`` plus a numpy lookup, and a
plain vectorised numpy float32 version. One JSON line per implementation (median points
per second over the repeats) and one with the ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable

import cv2
import numpy as np

from acq.camera import projection
from acq.camera.camera_models import Equidistant
from acq.geometry.rotations import rotation_from_euler
from acq.geometry.transforms import Rigid

CAM = Equidistant.from_f(169.3, 390.2, 291.1, 780, 582, 185.0)
EXTR = Rigid(rotation_from_euler(1.55, 0.02, -0.03), [0.35, -0.12, -0.2])


def make_points(n: int, seed: int = 0) -> np.ndarray:
    """(n,3) float32 laser-frame points at street distances (1-30 m), all directions."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v *= rng.uniform(1.0, 30.0, (n, 1)) / np.linalg.norm(v, axis=1, keepdims=True)
    return v.astype(np.float32)


def ours(P: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return projection.colorize(P, CAM, EXTR, image)


def lookup(uv: np.ndarray, valid: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Nearest-pixel colours of the valid points, zeros elsewhere (numpy)."""
    h, w = image.shape[:2]
    iu = np.clip(np.rint(uv[:, 0]), 0, w - 1).astype(np.intp)
    iv = np.clip(np.rint(uv[:, 1]), 0, h - 1).astype(np.intp)
    out = np.zeros((uv.shape[0], image.shape[2]), np.uint8)
    out[valid] = image[iv[valid], iu[valid]]
    return out


def in_image(uv: np.ndarray) -> np.ndarray:
    u, v = uv[:, 0], uv[:, 1]
    return (u >= -0.5) & (u < CAM.width - 0.5) & (v >= -0.5) & (v < CAM.height - 0.5)


_inv = EXTR.inverse()
_RVEC = cv2.Rodrigues(_inv.rotation)[0]
_TVEC = _inv.translation.reshape(3, 1)
_K = np.array([[CAM.fx, 0, CAM.cx], [0, CAM.fy, CAM.cy], [0, 0, 1]], dtype=np.float64)


def opencv(P: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cv2.fisheye.projectPoints (which mirrors points past 90 degrees) + numpy lookup.

    Its Python binding always returns the (2N, 15) Jacobian too, which OpenCV computes
    whether or not it is used: that is the price a user of this path pays.
    """
    uv, _ = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), _RVEC, _TVEC, _K, np.zeros(4))
    uv = uv.reshape(-1, 2)
    # OpenCV cannot say which points lie behind the fov; the camera-frame z is needed.
    z = (P - _TVEC_LASER) @ _R_COL2
    valid = in_image(uv) & (z > -0.08 * np.abs(z))  # front half-space, as close as it gets
    return lookup(uv, valid, image), valid


_R32 = EXTR.rotation.astype(np.float32)
_T32 = EXTR.translation.astype(np.float32)
_TVEC_LASER = _T32
_R_COL2 = _R32[:, 2]


def numpy_f32(P: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same model in plain vectorised numpy, float32."""
    Pc = (P - _T32) @ _R32  # rows: R.T @ (p - t)
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    rho = np.hypot(x, y)
    theta = np.arctan2(rho, z)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.float32(CAM.f) * theta / rho
    uv = np.stack([CAM.cx + s * x, CAM.cy + s * y], axis=1)
    valid = (theta <= np.float32(CAM.theta_max)) & in_image(uv)
    return lookup(uv, valid, image), valid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=4_000_000)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    P = make_points(args.points)
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (CAM.height, CAM.width, 3), dtype=np.uint8)
    impls: dict[str, Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]] = {
        "acq_numba": ours,
        "opencv_fisheye": opencv,
        "numpy_float32": numpy_f32,
    }
    # Warm-up (compiles the kernel) and a check that the three agree on what they see.
    results = {name: f(P, image) for name, f in impls.items()}
    agree = float(np.mean(results["acq_numba"][1] == results["numpy_float32"][1]))
    times: dict[str, list[float]] = {name: [] for name in impls}
    for _ in range(args.repeats):
        for name, f in impls.items():
            t0 = time.perf_counter()
            f(P, image)
            times[name].append(time.perf_counter() - t0)
    rate = {name: args.points / statistics.median(ts) for name, ts in times.items()}
    common = {
        "bench": "projection_colorize",
        "model": "equidistant",
        "points": args.points,
        "repeats": args.repeats,
        "cpus": os.cpu_count(),
    }
    for name, ts in times.items():
        line = {
            **common,
            "impl": name,
            "points_per_s": round(rate[name]),
            "median_s": round(statistics.median(ts), 5),
            "min_s": round(min(ts), 5),
        }
        print(json.dumps(line))
    print(
        json.dumps(
            {
                **common,
                "impl": "ratios",
                "vs_opencv": round(rate["acq_numba"] / rate["opencv_fisheye"], 2),
                "vs_numpy": round(rate["acq_numba"] / rate["numpy_float32"], 2),
                "valid_agreement_numpy": round(agree, 6),
                "targets": {"vs_opencv": 10, "vs_numpy": 4},
            }
        )
    )


if __name__ == "__main__":
    main()
