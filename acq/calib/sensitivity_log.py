"""`acq analyze sensitivity`: the sensitivity analysis (paper §4.1, :mod:`acq.calib.sensitivity`)
of a recorded log's laser points, with its figures (:mod:`acq.calib.plots`), Table 3 and
``sensitivity.json``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from acq import json_text
from acq.atomic_write import write_text
from acq.calib.plots import sensitivity_figure, third_order_figure
from acq.calib.sensitivity import (
    CAMERA,
    MIN_CRITERION_PX,
    PAPER_THIRD_ORDER_PX,
    PARAMS,
    PIXEL_PITCH_M,
    RIGID,
    analyze,
    bin_by_theta,
    choose_sigma,
    laser_points,
    params_from_calib,
    table3,
)
from acq.camera import calibfile
from acq.camera.camera_models import KannalaBrandt
from acq.camera.selection import choose_cameras
from acq.errors import AcqError, InputValueError
from acq.log import drive_log
from acq.provenance import SOFTWARE, write_image

__all__ = ["analyze_logs"]


def _sigma_note(src: Sequence[str]) -> str:
    """Which σ came from the calibration, the defaults, the overrides."""
    what = {"calib": "calib.yaml's std", "default": "defaults", "override": "--sigma"}
    parts = []
    for key, label in what.items():
        names = [n for n, s in zip(PARAMS, src, strict=True) if s == key]
        if names:
            parts.append(f"{label}: {', '.join(names)}")
    return "sigma from " + "; ".join(parts)


def analyze_logs(
    calib: Path,
    logs: list[Path],
    out: Path,
    camera_height_m: float = 2.0,
    building_distance_m: float = 10.0,
    camera: str | None = None,
    sigma: Mapping[str, float] | None = None,
    origin: str = "principal",
    bin_deg: float = 2.0,
) -> dict[str, Any]:
    """`acq analyze sensitivity`: eq. (7) sensitivities and px per sigma of the laser
    points of ``logs`` that project into ``calib``'s camera, Figures 7-9 as PNGs, Table 3
    for the given camera height and building distance (m), ``out/sensitivity.json``.
    σ: ``sigma`` (by name, :data:`UNITS`), else the calibration's std, else the defaults
    (:func:`choose_sigma`).

    The report (as written to sensitivity.json). InputError for a bad calib, log or
    value; AcqError when no laser point projects into the image; OSError when the
    outputs cannot be written.
    """
    if not (building_distance_m > 0 and math.isfinite(camera_height_m)):
        raise InputValueError("--building-distance must be > 0 m, --camera-height finite")
    if not bin_deg > 0:
        raise InputValueError("bin width must be > 0 deg")
    cal = calibfile.load(calib)
    # the laser's points only: a log without frames takes the calibration's camera
    log = drive_log.read_log(logs, cameras=[camera] if camera else list(cal.cameras), jpegs=False)
    if log.camera_names:
        [(_, name)] = choose_cameras(
            [camera] if camera else None, log.camera_names, list(cal.cameras), one=True,
            calib=cal.label,
        )  # fmt: skip
    else:
        name = camera or ""
    cam = cal.camera(name or None)
    p = params_from_calib(cam)
    sig, src = choose_sigma(p, cam, sigma)
    lens = cam.model
    assert isinstance(lens, KannalaBrandt)
    P = laser_points(log.ranges, log.angle_min, log.angle_increment)
    a = replace(
        analyze(P, p, lens.width, lens.height, lens.theta_max, sig, origin), sigma_source=src
    )
    if a.theta.size == 0:
        raise AcqError(f"none of the {len(P)} laser points projects into the image")
    t3 = table3(p, camera_height_m, building_distance_m, theta_max=lens.theta_max)
    summary = a.summary()
    centres, counts, med_s = bin_by_theta(a.theta, a.sens, bin_deg)
    _, _, med_px = bin_by_theta(a.theta, a.shift, bin_deg)
    notes = [
        f"projection: generic model cut after theta^3 (eq. 4, 5); k1, mu split with the "
        f"paper's pixel pitch {PIXEL_PITCH_M * 1e6:.3f} um",
        "k2 from the calibration's k[0]"
        if lens.name == "kannala_brandt" and lens.k[0] != 0
        else f"k2 from the paper's Table 3 (mu k2 = {PAPER_THIRD_ORDER_PX} px)",
        f"criterion eq. (8) measured from the {origin} point "
        f"({a.origin[0]:.1f}, {a.origin[1]:.1f}) px, held fixed; points with f < "
        f"{MIN_CRITERION_PX:g} px left out of eq. (7)",
        _sigma_note(src),
        "rotation angles: R = Rz(yaw) Ry(pitch) Rx(roll) of camera_to_laser"
        + ("; |pitch| near 90 deg: roll and yaw turn about nearly the same axis"
           if abs(abs(p[1]) - math.pi / 2) < math.radians(10) else ""),
    ]  # fmt: skip
    if "calib" in src[:3]:
        notes.append(
            "rotation sigma: one std of the rotation about the axis each angle turns about "
            "(laser frame), from std.rotation_deg taken as independent; not an Euler-angle std"
        )
    figs = {
        "fig7": out / "fig7_rigid.png",
        "fig8": out / "fig8_camera.png",
        "fig9": out / "fig9_third_order.png",
    }
    report: dict[str, Any] = {
        "calib": str(calib),
        "logs": [str(x) for x in logs],
        "camera": name or next(iter(cal.cameras)),
        "model": lens.name,
        "params": list(PARAMS),
        "origin": {"name": origin, "uv_px": list(a.origin)},
        "n_points": int(a.theta.size),
        "n_laser_points": len(P),
        "theta_deg": {
            "min": math.degrees(float(a.theta.min())),
            "median": math.degrees(float(np.median(a.theta))),
            "max": math.degrees(float(a.theta.max())),
        },
        "summary": summary,
        "bins": {
            "bin_deg": bin_deg,
            "theta_deg": centres.tolist(),
            "count": counts.tolist(),
            "median_abs_s": _nan_none(med_s),
            "median_px_per_sigma": _nan_none(med_px),
        },
        "table3": t3,
        "figures": {k: str(v) for k, v in figs.items()},
        "notes": notes,
    }
    out.mkdir(parents=True, exist_ok=True)
    images = {
        "fig7": sensitivity_figure(a, RIGID, "Frame change (Figure 7)", bin_deg),
        "fig8": sensitivity_figure(a, CAMERA, "Camera (Figure 8)", bin_deg),
        "fig9": third_order_figure(p, lens.theta_max, lens=lens),
    }
    for k, path in figs.items():
        write_image(path, images[k])
    mark = {"software": SOFTWARE}  # first: what acq.provenance looks for
    write_text(
        out / "sensitivity.json", json_text.dumps(mark | report, what="sensitivity.json") + "\n"
    )
    return report


def _nan_none(a: np.ndarray) -> list[list[float | None]]:
    return [[None if not math.isfinite(x) else float(x) for x in row] for row in a]
