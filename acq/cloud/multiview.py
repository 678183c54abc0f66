"""Which camera colours each point (``acq colorize`` with several cameras).

Every camera colours the points on its own (:func:`acq.cloud.views.start_colouring`:
its nearest or best frame, not hidden in its depth buffer); then each point takes the
colour of the camera whose view of it is best, by a cost that adds

- the log of the pixel's footprint on the surface, ``depth / f`` (m per pixel at the
  point; a nearer camera or a longer lens sees it in more detail);
- a rim term, ``RIM * (theta / theta_max)**4``: small near the optical axis, steep
  toward the image circle's rim, where a fisheye's resolution and calibration are worst;
- the time between the point and the frame, as a share of ``max_dt_s``.

With ``blend``, the colours of every camera that sees a point are averaged with
weights ``exp(-(cost - best cost) / BLEND_SCALE)``; the source camera is still the best.
Colours RGB uint8; angles rad; metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from acq.camera.camera_models import CameraModel
from acq.cloud.views import Coloured

__all__ = ["BLEND_SCALE", "RIM", "Choice", "choose", "half_aperture"]

RIM = 2.0
BLEND_SCALE = 0.3


def half_aperture(model: CameraModel) -> float:
    """The largest angle from the optical axis the model sees, rad: a fisheye's
    ``theta_max``, a pinhole's to its image corner."""
    theta_max = getattr(model, "theta_max", None)
    if theta_max is not None:
        return float(theta_max)
    corner = math.hypot(max(model.cx, model.width - model.cx) / model.fx,
                        max(model.cy, model.height - model.cy) / model.fy)  # fmt: skip
    return math.atan(corner)


@dataclass(frozen=True)
class Choice:
    """Per point: ``camera`` (N,) int64 the index of the camera chosen (-1 none),
    ``rgb`` (N,3) uint8 its colour (or the blend), ``coloured`` (N,) bool."""

    camera: np.ndarray
    rgb: np.ndarray
    coloured: np.ndarray


def choose(
    views: Sequence[Coloured],
    rgbs: Sequence[np.ndarray],
    models: Sequence[CameraModel],
    max_dt_s: float,
    blend: bool = False,
) -> Choice:
    """The best camera for each point (module docstring) of ``views`` (one per camera,
    over the same points), coloured ``rgbs`` (per camera, e.g. balanced), through the
    cameras' ``models``."""
    n = views[0].coloured.size
    cost = np.full((len(views), n), np.inf)
    for c, (v, model) in enumerate(zip(views, models, strict=True)):
        f = 0.5 * (model.fx + model.fy)
        ok = v.coloured
        with np.errstate(invalid="ignore", divide="ignore"):
            c_ = (
                np.log(np.maximum(v.depth[ok].astype(np.float64), 1e-3) / f)  # type: ignore[index]
                + RIM * (v.theta[ok].astype(np.float64) / half_aperture(model)) ** 4
                + np.abs(v.dt_s[ok].astype(np.float64)) / max_dt_s
            )
        cost[c, ok] = np.where(np.isfinite(c_), c_, 1e9)
    camera = np.argmin(cost, axis=0)
    coloured = np.isfinite(cost[camera, np.arange(n)])
    camera = np.where(coloured, camera, -1)
    stack = np.stack([np.asarray(r) for r in rgbs])  # (C,N,3)
    if blend and len(views) > 1:
        best = np.min(cost, axis=0)
        with np.errstate(invalid="ignore"):
            w = np.where(np.isfinite(cost), np.exp(-(cost - best) / BLEND_SCALE), 0.0)
        total = w.sum(axis=0)
        mixed = (
            np.einsum("cn,cnk->nk", w, stack.astype(np.float64)) / np.maximum(total, 1e-12)[:, None]
        )
        rgb = np.where(coloured[:, None], np.clip(mixed + 0.5, 0, 255), 0).astype(np.uint8)
    else:
        rgb = np.where(coloured[:, None], stack[np.maximum(camera, 0), np.arange(n)], 0).astype(
            np.uint8
        )
    return Choice(camera, rgb, coloured)
