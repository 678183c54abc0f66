"""Image-circle estimators against simulated truth (issue 7), and on the real images.

Random simulated fisheye images (780x582, radius 255-285 px, soft edge 1-4 px, rim
vignetting 0.15-0.5, black level 4-20 DN with 0.8-3 DN noise), half of them truncated
(radius past half the height, or the centre moved towards a side), a third with a
saturated glare blob on the rim; then a few with non-square pixels (``--ellipse``). One
JSON line per estimator and set: centre error (px, distance) and radius error (px,
signed), over all images and over the truncated ones. Then, if ../shared/data is there,
one line for the real 748x480 images against their checkerboard reference, with our own
Kannala-Brandt board fit (initialised from the circle) beside it.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from acq.calib import image_circle
from acq.sim.fisheye_images import random_image

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "fisheye"
REFERENCE_PP = (384.8, 240.0)  # px, data README (Kannala-Brandt checkerboard fit)
REFERENCE_F = 209.0  # px/rad


def _stats(e: np.ndarray) -> dict[str, float]:
    return {
        "median": round(float(np.median(e)), 3),
        "p90": round(float(np.percentile(e, 90)), 3),
        "max": round(float(np.max(e)), 3),
    }


def run_set(n: int, seed: int, aspect: float, label: str) -> None:
    rng = np.random.default_rng(seed)
    errs: dict[str, list[tuple[float, float, float, bool]]] = {
        k: [] for k in image_circle.ESTIMATORS
    }
    seconds = 0.0
    for i in range(n):
        img, truth = random_image(rng, truncated=i % 2 == 1, glare=i % 3 == 2, aspect=aspect)
        t0 = time.perf_counter()
        res = image_circle.detect([img], ellipse=aspect != 1.0)
        seconds += time.perf_counter() - t0
        for name, est in res.estimates.items():
            c = est.circle
            dc = math.hypot(c.cx - truth.cx, c.cy - truth.cy)
            dr = c.rx - truth.a
            dry = c.ry - truth.b
            errs[name].append((dc, dr, dry, truth.truncated))
    for name, rows in errs.items():
        a = np.array([r[:3] for r in rows])
        cut = np.array([r[3] for r in rows])
        line = {
            "bench": "image_circle",
            "set": label,
            "estimator": name,
            "images": n,
            "truncated_images": int(cut.sum()),
            "centre_err_px": _stats(a[:, 0]),
            "radius_err_px": {
                "mean": round(float(a[:, 1].mean()), 3),
                "max_abs": round(float(np.abs(a[:, 1]).max()), 3),
            },
            "truncated_centre_err_max_px": round(float(a[cut, 0].max()), 3) if cut.any() else None,
            "truncated_radius_err_max_abs_px": (
                round(float(np.abs(a[cut, 1]).max()), 3) if cut.any() else None
            ),
        }
        if aspect != 1.0:
            line["ry_err_max_abs_px"] = round(float(np.abs(a[:, 2]).max()), 3)
        line["detect_ms_per_image"] = round(1000 * seconds / n, 1)
        print(json.dumps(line), flush=True)


def run_real(fov_deg: float) -> None:
    from acq.calib import fisheye_calib

    paths = sorted(REAL.glob("*.jpg"))
    if not paths:
        print(json.dumps({"bench": "image_circle", "set": "real", "skipped": f"{REAL} absent"}))
        return
    images = fisheye_calib.read_images(paths)
    res = image_circle.detect(images)
    c = res.circle
    model = fisheye_calib.circle_model(res, fov_deg)
    board = fisheye_calib.parse_board("8x6x0.117")
    fit, _ = fisheye_calib.calibrate_board([image_circle.to_gray(i) for i in images], board, model)
    kb = fit.model
    theta_rim = float(kb.undistort_theta(np.array([c.radius / kb.fx]))[0])
    gap = fisheye_calib.model_gap_px(model, kb, math.radians(fit.max_theta_deg))
    ref = REFERENCE_PP
    line = {
        "bench": "image_circle",
        "set": "real",
        "images": len(paths),
        "centre_px": [round(c.cx, 2), round(c.cy, 2)],
        "radius_px": round(c.radius, 2),
        "reference_pp_px": list(ref),
        "centre_to_reference_px": round(math.hypot(c.cx - ref[0], c.cy - ref[1]), 2),
        "estimators": {
            k: [round(e.circle.cx, 2), round(e.circle.cy, 2), round(e.circle.radius, 2)]
            for k, e in res.estimates.items()
        },
        "truncated": list(res.truncated),
        "fov_deg": fov_deg,
        "f_circle_px_per_rad": round(model.fx, 2),
        "reference_f_px_per_rad": REFERENCE_F,
        "board_kb": {
            "fx": round(kb.fx, 2),
            "fy": round(kb.fy, 2),
            "pp_px": [round(kb.cx, 2), round(kb.cy, 2)],
            "pp_to_reference_px": round(math.hypot(kb.cx - ref[0], kb.cy - ref[1]), 2),
            "rms_px": round(fit.rms_px, 3),
            "fov_deg_at_circle_rim": round(math.degrees(2 * theta_rim), 1),
            "circle_model_gap_px": round(gap, 1),
        },
    }
    print(json.dumps(line), flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--images", type=int, default=20, help="random images per set (default 20)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    run_set(args.images, args.seed, 1.0, "square pixels")
    run_set(max(args.images // 2, 2), args.seed + 1, 1.06, "pixel aspect 1.06, --ellipse")
    run_real(185.0)


if __name__ == "__main__":
    main()
