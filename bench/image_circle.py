"""Image-circle estimators against simulated truth (issue 7), and on the real images.

Random simulated fisheye images (780x582, radius 255-285 px, soft edge 1-4 px, rim
vignetting 0.15-0.5, black level 4-20 DN with 0.8-3 DN noise), half of them truncated
(radius past half the height, or the centre moved towards a side), a third with a
saturated glare blob on the rim; then a few with non-square pixels (``--ellipse``). One
JSON line per estimator and set: centre error (px, distance) and radius error (px,
signed), over all images and over the truncated ones. Then, if ../shared/data is there,
one line for the real 748x480 images against their checkerboard reference, with our own
Kannala-Brandt board fit (initialised from the circle) beside it. Also: cameras whose circle
shows only as four corner arcs under a glare halo, clipped inside, JPEG-compressed, with a
burnt-in time stamp (one line per sensor size), and each real image alone (one line each,
with its estimators' disagreement).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from acq.calib import image_circle
from acq.sim.fisheye_images import corner_arc_images, random_image

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


def run_corner_arcs(cameras: int, n_images: int, seed: int) -> None:
    """Cameras whose circle shows only as corner arcs (sim.fisheye_images.corner_arc_images:
    clipped inside the rim, glare halo, JPEG, overlay), ``n_images`` each, detected
    together: one line per size with every estimator's worst errors over the cameras."""
    for width, height in ((780, 582), (1032, 778)):
        rng = np.random.default_rng(seed)
        errs: dict[str, list[tuple[float, float]]] = {k: [] for k in image_circle.ESTIMATORS}
        spans, failures, seconds = [], [], 0.0
        for _ in range(cameras):
            images, truth = corner_arc_images(rng, n_images, width, height)
            spans.append(truth.visible_arcs()[1])
            t0 = time.perf_counter()
            try:
                res = image_circle.detect(images)
            except image_circle.ImageCircleError as e:
                failures.append(str(e))
                continue
            seconds += time.perf_counter() - t0
            for name, est in res.estimates.items():
                c = est.circle
                errs[name].append((math.hypot(c.cx - truth.cx, c.cy - truth.cy), c.rx - truth.a))
        line = {
            "bench": "image_circle",
            "set": "corner arcs",
            "size": [width, height],
            "cameras": cameras,
            "images_per_camera": n_images,
            "rim_span_on_sensor": [round(min(spans), 3), round(max(spans), 3)],
            "failures": failures,
            "detect_s_per_camera": round(seconds / max(cameras - len(failures), 1), 2),
        }
        for name, rows in errs.items():
            if rows:
                a = np.array(rows)
                line[name] = {
                    "centre_err_max_px": round(float(a[:, 0].max()), 3),
                    "centre_err_median_px": round(float(np.median(a[:, 0])), 3),
                    "radius_err_px": [
                        round(float(a[:, 1].min()), 3),
                        round(float(a[:, 1].max()), 3),
                    ],
                }
        print(json.dumps(line), flush=True)


def run_real_per_image() -> None:
    """Each real image alone: every estimator's circle, their disagreement (the barycentre
    left out: the circle is truncated) and the command's warnings."""
    from acq.calib import fisheye_calib

    for path in sorted(REAL.glob("*.jpg")):
        res = image_circle.detect(fisheye_calib.read_images([path]))
        fair = {k: e.circle for k, e in res.estimates.items() if k != "barycentre"}
        c = np.array([(e.cx, e.cy) for e in fair.values()])
        spread_c = float(np.max(np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))))
        r = [e.radius for e in fair.values()]
        line = {
            "bench": "image_circle",
            "set": "real, per image",
            "image": path.name,
            "estimators": {
                k: [round(e.cx, 2), round(e.cy, 2), round(e.radius, 2)] for k, e in fair.items()
            },
            "spread_centre_px": round(spread_c, 2),
            "spread_radius_px": round(max(r) - min(r), 2),
            "subpixel_to_reference_px": round(
                math.hypot(
                    fair["subpixel"].cx - REFERENCE_PP[0], fair["subpixel"].cy - REFERENCE_PP[1]
                ),
                2,
            ),
            "warnings": [w for w in res.warnings if "barycentre is biased" not in w],
        }
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
    p.add_argument(
        "--cameras", type=int, default=10, help="corner-arc cameras per size (default 10)"
    )
    args = p.parse_args()
    run_set(args.images, args.seed, 1.0, "square pixels")
    run_set(max(args.images // 2, 2), args.seed + 1, 1.06, "pixel aspect 1.06, --ellipse")
    run_corner_arcs(args.cameras, 4, args.seed)
    if REAL.is_dir():
        run_real_per_image()
    run_real(185.0)


if __name__ == "__main__":
    main()
