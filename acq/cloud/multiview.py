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

import numba
import numpy as np

from acq.camera.camera_models import CameraModel
from acq.cloud.views import Coloured

__all__ = ["BLEND_SCALE", "RIM", "Choice", "Picked", "choose", "half_aperture", "pick"]

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


def _cost(v: Coloured, model: CameraModel, max_dt_s: float) -> np.ndarray:
    """The cost (module docstring) of each point ``v`` coloured, in their order (K,)
    float64; 1e9 where it is not finite."""
    ok = v.coloured
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = (
            np.log(np.maximum(v.depth[ok].astype(np.float64), 1e-3) / (0.5 * (model.fx + model.fy)))  # type: ignore[index]
            + RIM * (v.theta[ok].astype(np.float64) / half_aperture(model)) ** 4
            + np.abs(v.dt_s[ok].astype(np.float64)) / max_dt_s
        )
    return np.where(np.isfinite(cost), cost, 1e9)


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
        cost[c, v.coloured] = _cost(v, model, max_dt_s)
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


@dataclass(frozen=True)
class Picked(Choice):
    """A :class:`Choice` (``rgb`` with the gains divided out) and, per point, what the
    camera chosen (:func:`pick`) gives it: ``frame`` (N,) int64 (-1 none), ``dt_s`` and
    ``theta`` (N,) float32 (NaN), ``hidden`` (N,) (seen by a camera but hidden in every
    frame)."""

    frame: np.ndarray
    dt_s: np.ndarray
    theta: np.ndarray
    hidden: np.ndarray


def pick(
    views: Sequence[Coloured],
    models: Sequence[CameraModel],
    max_dt_s: float,
    scales: Sequence[np.ndarray | None],
) -> Picked:
    """The best camera for each point of ``views`` (one per camera, over the same points;
    through the cameras' ``models``), as :func:`choose` without blending, and what that
    camera gives it, in one pass per camera: its colour with the gains of its frame
    divided out (``scales``: per camera, (F,3) float32 ``exp(-log_gain)`` of its frames;
    None: as taken), the same bytes as :meth:`acq.cloud.balance.Gains.apply` and then
    :func:`choose` give."""
    n = views[0].coloured.size
    best = np.full(n, np.inf)
    camera = np.full(n, -1, dtype=np.int64)
    rgb = np.zeros((n, 3), dtype=np.uint8)
    frame = np.full(n, -1, dtype=np.int64)
    dt_s = np.full(n, np.nan, dtype=np.float32)
    theta = np.full(n, np.nan, dtype=np.float32)
    seen = np.zeros(n, dtype=bool)
    none = np.zeros((0, 3), dtype=np.float32)
    for c, (v, model, scale) in enumerate(zip(views, models, scales, strict=True)):
        _take(
            c, np.flatnonzero(v.coloured), _cost(v, model, max_dt_s), v.rgb, v.frame, v.dt_s,
            v.theta, none if scale is None else np.asarray(scale, dtype=np.float32),
            best, camera, rgb, frame, dt_s, theta,
        )  # fmt: skip
        seen |= v.hidden
    coloured = camera >= 0
    return Picked(camera, rgb, coloured, frame, dt_s, theta, seen & ~coloured)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _take(  # type: ignore[no-untyped-def]
    c, idx, cost, rgb_c, frame_c, dt_c, theta_c, scale, best, camera, rgb, frame, dt_s, theta
):
    """Camera ``c`` takes the points ``idx`` whose ``cost`` (in idx's order) is below the
    best so far (the first camera keeps a tie, as argmin does): its colour (times its
    frame's ``scale``, rounded as numpy's float32 does, when there are scales), frame,
    dt and theta."""
    for k in range(idx.size):
        i = idx[k]
        if not cost[k] < best[i]:
            continue
        best[i] = cost[k]
        camera[i] = c
        f = frame_c[i]
        if scale.shape[0] and f >= 0:
            for ch in range(3):
                x = np.float32(rgb_c[i, ch]) * scale[f, ch] + np.float32(0.5)
                rgb[i, ch] = np.uint8(min(max(x, np.float32(0.0)), np.float32(255.0)))
        else:
            for ch in range(3):
                rgb[i, ch] = rgb_c[i, ch]
        frame[i] = f
        dt_s[i] = dt_c[i]
        theta[i] = theta_c[i]
