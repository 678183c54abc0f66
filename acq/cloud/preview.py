"""The preview of a coloured cloud: the facade seen from the street, and a top view."""

from __future__ import annotations

import math
import os

import cv2
import numba
import numpy as np
import numpy.typing as npt

from acq.cloud.points import Cloud
from acq.provenance import write_image

UNCOLOURED_RGB = (128, 128, 128)  # what the preview draws for a point no frame sees

_BG = (24, 24, 24)  # BGR background
_TEXT = (235, 235, 235)


def _axes(cloud: Cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along-track, toward the camera's side, origin): horizontal unit vectors in the
    world, from the laser's track and the camera's mean axis."""
    track = cloud.scan_origin
    along = track[-1] - track[0] if len(track) > 1 else np.array([1.0, 0.0, 0.0])
    along = np.array([along[0], along[1], 0.0])
    if np.linalg.norm(along) < 1e-6:
        along = np.array([1.0, 0.0, 0.0])
    along /= np.linalg.norm(along)
    side = np.cross([0.0, 0.0, 1.0], along)  # left of the track
    if float(side @ cloud.view_axis) < 0:
        side = -side
    origin = track[0] if len(track) else np.zeros(3)
    return along, side, origin


def _splat(
    shape: tuple[int, int],
    col: np.ndarray,
    row: np.ndarray,
    depth: np.ndarray,
    colour: np.ndarray,
    width: int,
    heights: np.ndarray,
) -> np.ndarray:
    """(H,W,3) uint8 of points drawn as blocks, the smallest depth winning each pixel.

    Point i covers ``width`` px from its column rightwards and ``heights[i]`` px
    centred on its row; the background shows elsewhere.
    """
    h, w = shape
    img = np.empty((h * w, 3), dtype=np.uint8)
    img[:] = _BG
    nearest_first = np.argsort(depth, kind="stable")
    _paint_blocks(img, h, w, nearest_first, col, row, heights, width, colour)
    return img.reshape(h, w, 3)


@numba.njit(cache=True, nogil=True)
def _paint_blocks(
    img: np.ndarray,
    h: int,
    w: int,
    order: np.ndarray,
    col: np.ndarray,
    row: np.ndarray,
    heights: np.ndarray,
    width: int,
    colour: np.ndarray,
) -> None:
    """Paint each point's block into ``img`` (H*W,3) in ``order``, a pixel keeping the
    first colour painted there (one pass, no per-pixel temporaries: a 60 s drive's
    blocks cover tens of millions of pixels)."""
    painted = np.zeros(h * w, dtype=np.bool_)
    for i in order:
        top = row[i] - heights[i] // 2
        for r in range(max(top, 0), min(top + heights[i], h)):
            for c in range(max(col[i], 0), min(col[i] + width, w)):
                p = r * w + c
                if not painted[p]:
                    painted[p] = True
                    img[p] = colour[i]


def _spacing(v: np.ndarray, scan: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Per point, how far apart in ``v`` its scan's points are around it: the larger
    |difference| to the previous and next step, but at most twice the smaller (an edge
    of a surface is not a spacing); NaN where it has no neighbour."""
    same = (scan[1:] == scan[:-1]) & (step[1:] == step[:-1] + 1)
    d = np.where(same, np.abs(np.diff(v)), np.nan)
    before = np.concatenate([[np.nan], d])
    after = np.concatenate([d, [np.nan]])
    with np.errstate(invalid="ignore"):
        lo = np.fmin(before, after)
        gap: npt.NDArray[np.float64] = np.fmin(np.fmax(before, after), 2.0 * lo)
    return gap


def _heights(gap: np.ndarray, res: float, most: int = 20) -> npt.NDArray[np.int64]:
    """Block heights, px: a pixel more than the spacing between a scan's points, 1 to
    ``most``."""
    px: npt.NDArray[np.float64] = np.ceil(np.nan_to_num(gap, nan=0.0) / res) + 1
    return np.clip(px, 1, most).astype(np.int64)


def _label(img: np.ndarray, text: str, x: int = 10, scale: float = 0.55) -> None:
    cv2.putText(img, text, (x, 23), cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT, 1, cv2.LINE_AA)


def _band(w: int, text: str, res: float = 0.0, scale: float = 0.55) -> np.ndarray:
    """A 34 px caption strip, with a 10 m scale bar at its right when ``res`` is given."""
    band = np.full((34, w, 3), _BG, dtype=np.uint8)
    _label(band, text, scale=scale)
    bar = round(10.0 / res) if res > 0 else 0
    if bar and bar + 80 < w // 2:
        x1 = w - 60
        cv2.line(band, (x1 - bar, 17), (x1, 17), _TEXT, 2)
        _label(band, "10 m", x1 + 8, 0.5)
    return band


def preview_image(
    cloud: Cloud,
    *,
    metres_per_px: float = 0.03,
    max_width: int = 2400,
    top_half_width_m: float = 12.0,
    title: str = "",
) -> np.ndarray:
    """A picture of the cloud to judge at a glance: (H,W,3) uint8 BGR.

    Top: the side the camera looks at, seen from the street (orthographic; along-track
    distance to the right, height up; the nearest point wins each pixel). Bottom: the
    view from above (along-track to the right, the camera's side up; the highest point
    wins), ``top_half_width_m`` m either side of the track. Uncoloured points are grey.
    The scale is ``metres_per_px``, coarser when the drive would be wider than
    ``max_width`` px. Each point is drawn as a block a pixel wider than the spacing
    between scans and a pixel taller than the spacing between its scan's points (up to
    20 px), so that surfaces close up.
    """
    if cloud.size == 0:
        return _band(640, title or "no points")
    along, side, origin = _axes(cloud)
    rel = cloud.xyz - origin
    u = rel @ along
    lat = rel @ side
    z = cloud.xyz[:, 2]
    colour = np.where(cloud.coloured[:, None], cloud.rgb[:, ::-1], np.array(UNCOLOURED_RGB))
    colour = colour.astype(np.uint8)
    u0, u1 = np.percentile(u, [0.1, 99.9])
    span = max(u1 - u0, 1.0) + 1.0
    res = max(metres_per_px, span / max_width)
    w = math.ceil(span / res)
    step_m = float(np.median(np.linalg.norm(np.diff(cloud.scan_origin, axis=0), axis=1)))
    block = int(np.clip(math.ceil(step_m / res) + 1, 1, 12)) if math.isfinite(step_m) else 1
    col = np.floor((u - u0 + 0.5) / res).astype(np.int64)

    # the facade panel: the camera's side, above the road
    on = lat > 0.5
    ztop = float(np.percentile(z[on], 99.5)) + 0.5 if on.any() else 10.0
    zbot = min(float(np.percentile(z, 0.5)), 0.0) - 0.2
    fh = math.ceil((ztop - zbot) / res)
    row = np.floor((ztop - z) / res).astype(np.int64)
    hz = _heights(_spacing(z, cloud.scan, cloud.step), res)
    facade = _splat((fh, w), col[on], row[on], lat[on], colour[on], block, hz[on])
    # the top panel: highest point wins
    l0, l1 = np.percentile(lat, [0.5, 99.5])
    l0, l1 = max(l0, -top_half_width_m), min(l1, top_half_width_m)
    th = math.ceil((l1 - l0) / res) + 1
    trow = np.floor((l1 - lat) / res).astype(np.int64)
    hl = _heights(_spacing(lat, cloud.scan, cloud.step), res)
    top = _splat((th, w), col, trow, -z, colour, block, hl)

    cm = res * 100
    return np.vstack(
        [
            _band(w, title, scale=0.6),
            _band(w, f"the camera's side seen from the street ({cm:.0f} cm/px)", res),
            facade,
            _band(w, f"seen from above ({cm:.0f} cm/px); grey: points no frame saw", res),
            top,
        ]
    )


def preview_png(
    path: str | os.PathLike[str], cloud: Cloud, *, title: str = "", metres_per_px: float = 0.03
) -> tuple[int, int]:
    """Write :func:`preview_image` as a PNG; returns its (width, height), px."""
    img = preview_image(cloud, metres_per_px=metres_per_px, title=title)
    write_image(path, img)
    return int(img.shape[1]), int(img.shape[0])
