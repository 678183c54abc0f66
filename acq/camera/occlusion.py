"""Which points a camera really sees: a depth buffer of laser points splatted into its
image (nearer points hide farther ones). Used to pick frames (``acq colorize --view
best``) and to leave hidden points out of the time-offset estimate. Metres, pixels."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["MAX_SPLAT_CELLS", "occlusion_depths", "visible"]

MAX_SPLAT_CELLS = 8  # the farthest a point's square reaches from its own cell, cells


@numba.njit(cache=True, nogil=True)
def _splat(cu, cv, depth, radius, width, height):  # type: ignore[no-untyped-def]
    z = np.full((height, width), np.inf, dtype=np.float32)
    for i in range(cu.size):
        r = radius[i]
        d = depth[i]
        for v in range(max(cv[i] - r, 0), min(cv[i] + r + 1, height)):
            for u in range(max(cu[i] - r, 0), min(cu[i] + r + 1, width)):
                if d < z[v, u]:
                    z[v, u] = d
    return z


def occlusion_depths(
    uv: np.ndarray, depth: np.ndarray, size_m: np.ndarray, f_px: float, shape: tuple[int, int],
    cell_px: int,
) -> np.ndarray:  # fmt: skip
    """(H/cell, W/cell) float32 depth buffer (m, +inf empty) of points at pixels ``uv``
    (N,2) and ``depth`` (N,) m, each covering a square of ``size_m`` (N,) m of surface
    (its share of the scan: the larger of its spacing along the scan and the rig's
    travel between scans), i.e. about ``f_px * size_m / depth`` px each side."""
    h, w = -(-shape[0] // cell_px), -(-shape[1] // cell_px)
    cu = (uv[:, 0] / cell_px).astype(np.int64)
    cv_ = (uv[:, 1] / cell_px).astype(np.int64)
    r = np.minimum(
        np.floor(0.5 * f_px * size_m / np.maximum(depth, 1e-3) / cell_px), MAX_SPLAT_CELLS
    )
    return np.asarray(_splat(cu, cv_, depth.astype(np.float32), r.astype(np.int64), w, h))


def visible(
    zbuf: np.ndarray, uv: np.ndarray, depth: np.ndarray, cell_px: int, margin_m: float,
    margin_rel: float,
) -> np.ndarray:  # fmt: skip
    """(N,) bool: points at pixels ``uv`` (N,2) and ``depth`` (N,) m not hidden in the
    depth buffer ``zbuf`` (:func:`occlusion_depths` with ``cell_px``): no point of it
    nearer by more than ``margin_m`` + ``margin_rel`` x depth."""
    cu = np.clip((uv[:, 0] / cell_px).astype(np.int64), 0, zbuf.shape[1] - 1)
    cv_ = np.clip((uv[:, 1] / cell_px).astype(np.int64), 0, zbuf.shape[0] - 1)
    out: np.ndarray = depth <= zbuf[cv_, cu] + margin_m + margin_rel * depth
    return out
