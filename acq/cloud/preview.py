"""The preview of a coloured cloud: both sides of the street seen from it, the view from
above, and which camera coloured what."""

from __future__ import annotations

import math
import os
import re
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numba
import numpy as np
import numpy.typing as npt

from acq.cloud.points import Cloud
from acq.provenance import write_image

UNCOLOURED_RGB = (128, 128, 128)  # what the preview draws for a point no frame sees

_BG = (24, 24, 24)  # BGR background
_TEXT = (235, 235, 235)
# BGR per camera index (cycled): orange, azure, magenta, green, yellow, pink
_CAMERA_BGR = ((0, 140, 255), (255, 170, 40), (200, 80, 210), (70, 200, 70), (0, 220, 230))
_NO_CAMERA = 255  # Cloud.camera of a point no camera coloured
_SAMPLE = 200_000  # about this many points are enough for the panels' extents
_EDGE_M = 0.5  # points nearer the track than this sideways belong to neither facade
_STRIP_PX = 6  # height of the strip under a facade showing which camera coloured it
_SQUEEZE = 4  # the view from above by camera: this many times fewer rows (a small inset)


def _axes(cloud: Cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along-track, left of the track, origin): horizontal unit vectors in the world
    from the laser's first to its last position, and the first."""
    track = cloud.scan_origin
    along = track[-1] - track[0] if len(track) > 1 else np.array([1.0, 0.0, 0.0])
    along = np.array([along[0], along[1], 0.0])
    if np.linalg.norm(along) < 1e-6:
        along = np.array([1.0, 0.0, 0.0])
    along /= np.linalg.norm(along)
    left = np.cross([0.0, 0.0, 1.0], along)
    origin = np.asarray(track[0] if len(track) else np.zeros(3), dtype=np.float64)
    return along, left, origin


@numba.njit(cache=True, nogil=True)
def _project(
    xyz: np.ndarray, origin: np.ndarray, along: np.ndarray, left: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per point (along-track, leftwards), m: one pass, no (P,3) temporaries (the height
    is the points' own z)."""
    n = xyz.shape[0]
    u = np.empty(n)
    lat = np.empty(n)
    for i in range(n):
        x, y = xyz[i, 0] - origin[0], xyz[i, 1] - origin[1]
        u[i] = x * along[0] + y * along[1]
        lat[i] = x * left[0] + y * left[1]
    return u, lat


@numba.njit(cache=True, nogil=True)
def _block_heights(
    v: np.ndarray, scan: np.ndarray, step: np.ndarray, res: float, most: int
) -> np.ndarray:
    """Block heights, px, 1 to ``most``: a pixel more than how far apart in ``v`` a
    scan's points are around each point (the larger difference to the previous and next
    step, but at most twice the smaller: an edge of a surface is not a spacing); 1 for a
    point without neighbours."""
    n = v.size
    out = np.ones(n, dtype=np.int32)
    for i in range(n):
        lo, hi = math.inf, -math.inf
        if i > 0 and scan[i - 1] == scan[i] and step[i - 1] + 1 == step[i]:
            d = abs(v[i] - v[i - 1])
            if d == d:
                lo, hi = min(lo, d), max(hi, d)
        if i + 1 < n and scan[i + 1] == scan[i] and step[i] + 1 == step[i + 1]:
            d = abs(v[i + 1] - v[i])
            if d == d:
                lo, hi = min(lo, d), max(hi, d)
        if hi >= 0:
            px = math.ceil(min(hi, 2.0 * lo) / res) + 1
            out[i] = max(1, min(px, most))
    return out


@numba.njit(cache=True, nogil=True)
def _zbuffer(
    h: int,
    w: int,
    u: np.ndarray,
    u_lo: float,
    v: np.ndarray,
    v_hi: float,
    res: float,
    width: int,
    heights: np.ndarray,
    depth: np.ndarray,
    sign: float,
    sel: np.ndarray,
    sel_lo: float,
    sel_hi: float,
) -> np.ndarray:
    """(H,W) int32: per pixel the index of the point drawn there, -1 none.

    Point i, kept when ``sel_lo < sel[i] < sel_hi``, is a block from column
    ``(u[i] - u_lo) / res`` ``width`` px rightwards and ``heights[i]`` px centred on row
    ``(v_hi - v[i]) / res``; the smallest ``sign * depth`` wins a pixel, the earlier
    point a tie. Points in scan order, no sort: their blocks fall near each other's.
    """
    idx = np.full(h * w, -1, dtype=np.int32)
    best = np.full(h * w, np.inf, dtype=np.float32)
    for i in range(u.size):
        s = sel[i]
        d = np.float32(sign * depth[i])
        if not (sel_lo < s < sel_hi) or not (math.isfinite(u[i]) and math.isfinite(v[i])):
            continue
        if not math.isfinite(d):
            continue
        c0 = math.floor((u[i] - u_lo) / res)
        r0 = math.floor((v_hi - v[i]) / res) - heights[i] // 2
        for r in range(max(r0, 0), min(r0 + heights[i], h)):
            base = r * w
            for c in range(max(c0, 0), min(c0 + width, w)):
                p = base + c
                if d < best[p]:
                    best[p] = d
                    idx[p] = i
    return idx.reshape(h, w)


@dataclass(frozen=True)
class Panels:
    """The preview's pictures before captions, (H,W,3) uint8 BGR, W along the drive:
    ``left`` and ``right`` the two sides seen from the street (height up), ``top`` the
    view from above (left of the track up); with two cameras or more (else None)
    ``top_camera`` the same by source camera with 4 times fewer rows (each the camera
    that coloured most of its 4) and ``strips`` per side a strip coloured by the camera
    that coloured most of each column; ``cameras`` (name, share of the points) per
    camera and then ``("none", share)``; ``res`` m per px."""

    left: np.ndarray
    right: np.ndarray
    top: np.ndarray
    top_camera: np.ndarray | None
    strips: tuple[np.ndarray, np.ndarray] | None
    cameras: list[tuple[str, float]]
    res: float


def _camera_index(cloud: Cloud) -> npt.NDArray[np.uint8]:
    """Per point its source camera's index, 255 none (a cloud without them: 0 where
    coloured)."""
    if cloud.camera.size == cloud.size:
        return cloud.camera
    return np.where(cloud.coloured, 0, _NO_CAMERA).astype(np.uint8)


def _camera_shares(cloud: Cloud, camera: np.ndarray) -> list[tuple[str, float]]:
    """(name, share of the points) per camera of the cloud, then ("none", share)."""
    counts = np.bincount(camera, minlength=256)
    used = np.flatnonzero(counts[:_NO_CAMERA])
    n = max(len(cloud.camera_names), int(used[-1]) + 1 if used.size else 0)
    names = [
        cloud.camera_names[k] if k < len(cloud.camera_names) else f"camera {k}" for k in range(n)
    ]
    total = max(cloud.size, 1)
    return [(names[k], counts[k] / total) for k in range(n)] + [
        ("none", counts[_NO_CAMERA] / total)
    ]


def _paint(idx: np.ndarray, cloud: Cloud) -> np.ndarray:
    """The cloud's colours (grey where not coloured) where ``idx`` names a point."""
    return _paint_points(idx, cloud.rgb, cloud.coloured, np.array(_BG, dtype=np.uint8),
                         np.array(UNCOLOURED_RGB, dtype=np.uint8))  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _paint_points(
    idx: np.ndarray, rgb: np.ndarray, coloured: np.ndarray, bg: np.ndarray, grey: np.ndarray
) -> np.ndarray:
    """(H,W,3) BGR: per pixel of ``idx`` (H,W) its point's ``rgb`` reversed, ``grey``
    when not ``coloured``, ``bg`` when none."""
    h, w = idx.shape
    img = np.empty((h, w, 3), dtype=np.uint8)
    for r in range(h):
        for c in range(w):
            i = idx[r, c]
            for k in range(3):
                if i < 0:
                    img[r, c, k] = bg[k]
                elif coloured[i]:
                    img[r, c, k] = rgb[i, 2 - k]
                else:
                    img[r, c, k] = grey[k]
    return img


def _palette(k: int) -> tuple[int, int, int]:
    return _CAMERA_BGR[k % len(_CAMERA_BGR)]


def _by_camera(idx: np.ndarray, camera: np.ndarray, n: int, rows: int) -> np.ndarray:
    """(``rows``,W,3) BGR: ``idx`` (H,W) in ``rows`` bands of its rows, each pixel the
    colour of the camera that coloured most of its band's points (grey: none did,
    background: no points)."""
    h, w = idx.shape
    k = max(1, math.ceil(h / rows))
    cam = np.full((rows * k, w), -2, dtype=np.int32)  # -2: no point, -1: not coloured
    hit = idx >= 0
    src = camera[idx[hit]].astype(np.int32)
    src[src == _NO_CAMERA] = -1
    cam[:h][hit] = src
    cam = cam.reshape(rows, k, w)
    counts = np.stack([np.count_nonzero(cam == c, axis=1) for c in range(n)])
    img = np.empty((rows, w, 3), dtype=np.uint8)
    img[:] = _BG
    img[(cam >= -1).any(axis=1)] = UNCOLOURED_RGB
    some = counts.sum(axis=0) > 0
    best = counts.argmax(axis=0)
    for c in range(n):
        img[some & (best == c)] = _palette(c)
    return img


def _strip(idx: np.ndarray, camera: np.ndarray, n: int) -> np.ndarray:
    """A strip to go under a facade: per column the camera that coloured most of it."""
    strip = np.empty((_STRIP_PX, idx.shape[1], 3), dtype=np.uint8)
    strip[:] = _BG
    strip[1:] = _by_camera(idx, camera, n, 1)
    return strip


def preview_panels(
    cloud: Cloud,
    *,
    metres_per_px: float = 0.03,
    max_width: int = 2400,
    top_half_width_m: float = 12.0,
) -> Panels:
    """The pictures of :func:`preview_image`, without captions (``cloud`` not empty)."""
    along, left, origin = _axes(cloud)
    xyz = np.ascontiguousarray(cloud.xyz, dtype=np.float64)
    u, lat = _project(xyz, origin, along, left)
    z = xyz[:, 2]  # a view: the preview's peak is the run's
    # extents from a sample: percentiles of millions of points cost more than all drawing
    every = max(1, cloud.size // _SAMPLE)
    us, ls, zs = u[::every], lat[::every], z[::every]
    u0, u1 = np.nanpercentile(us, [0.1, 99.9])
    span = max(u1 - u0, 1.0) + 1.0
    res = max(metres_per_px, span / max_width)
    w = math.ceil(span / res)
    u_lo = u0 - 0.5
    steps = np.linalg.norm(np.diff(cloud.scan_origin, axis=0), axis=1)
    step_m = float(np.median(steps)) if steps.size else math.nan
    block = int(np.clip(math.ceil(step_m / res) + 1, 1, 12)) if math.isfinite(step_m) else 1
    scan, step = cloud.scan, cloud.step
    zbot = min(float(np.nanpercentile(zs, 0.5)), 0.0) - 0.2
    l0, l1 = np.nanpercentile(ls, [0.5, 99.5])
    l0, l1 = max(l0, -top_half_width_m), min(l1, top_half_width_m)
    th = math.ceil((l1 - l0) / res) + 1
    # the compiled passes over every point run without the GIL: two at a time
    with ThreadPoolExecutor(max_workers=2) as pool:
        hz_f = pool.submit(_block_heights, z, scan, step, res, 20)
        hl_f = pool.submit(_block_heights, lat, scan, step, res, 20)

        def facade(sign: float) -> Future[np.ndarray]:
            on = zs[sign * ls > _EDGE_M]
            ztop = float(np.nanpercentile(on, 99.5)) + 0.5 if on.size else 10.0
            fh = max(math.ceil((ztop - zbot) / res), 1)
            lo, hi = (_EDGE_M, math.inf) if sign > 0 else (-math.inf, -_EDGE_M)
            return pool.submit(_zbuffer, fh, w, u, u_lo, z, ztop, res, block, hz_f.result(), lat,
                               sign, lat, lo, hi)  # fmt: skip

        left_f, right_f = facade(1.0), facade(-1.0)
        top_f = pool.submit(_zbuffer, th, w, u, u_lo, lat, l1, res, block, hl_f.result(), z,
                            -1.0, lat, -math.inf, math.inf)  # fmt: skip
        left_idx, right_idx, top_idx = left_f.result(), right_f.result(), top_f.result()

    camera = _camera_index(cloud)
    shares = _camera_shares(cloud, camera)
    n = len(shares) - 1
    several = n >= 2
    return Panels(
        left=_paint(left_idx, cloud),
        right=_paint(right_idx, cloud),
        top=_paint(top_idx, cloud),
        top_camera=_by_camera(top_idx, camera, n, math.ceil(th / _SQUEEZE)) if several else None,
        strips=(_strip(left_idx, camera, n), _strip(right_idx, camera, n)) if several else None,
        cameras=shares,
        res=res,
    )


def _label(
    img: np.ndarray,
    text: str,
    x: int = 10,
    scale: float = 0.55,
    colour: tuple[int, ...] = _TEXT,
    y: int = 23,
) -> int:
    """Write ``text`` at ``x`` on the baseline ``y``; returns the x just after it, px."""
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)
    return x + _width(text, scale)


def _width(text: str, scale: float) -> int:
    return int(cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0])


def _wrapped(text: str, width: int, scale: float) -> list[str]:
    """``text`` in lines of at most ``width`` px, broken after a "; " or ", " where
    that is enough, else between words (never before a unit or a closing bracket)."""
    lines: list[str] = []
    for phrase in re.split(r"(?<=[;,]) ", text):
        words = [phrase] if _width(phrase, scale) <= width else re.split(r" (?![%)]|cm/)", phrase)
        for word in words:
            if lines and _width(f"{lines[-1]} {word}", scale) <= width:
                lines[-1] = f"{lines[-1]} {word}"
            else:
                lines.append(word)
    return lines


def _band(w: int, text: str, res: float = 0.0, scale: float = 0.55) -> np.ndarray:
    """A caption strip (34 px, and 22 px more a line where the text is wrapped), with a
    10 m scale bar at its right when ``res`` is given: the text is wrapped to end before
    the bar (or the strip's edge)."""
    bar = round(10.0 / res) if res > 0 else 0
    if not (bar and bar + 80 < w // 2):
        bar = 0
    x1 = w - 60
    room = (x1 - bar - 16 if bar else w - 10) - 10
    lines = _wrapped(text, room, scale)
    band = np.full((34 + 22 * (len(lines) - 1), w, 3), _BG, dtype=np.uint8)
    for k, line in enumerate(lines):
        _label(band, line, scale=scale, y=23 + 22 * k)
    if bar:
        cv2.line(band, (x1 - bar, 17), (x1, 17), _TEXT, 2)
        _label(band, "10 m", x1 + 8, 0.5)
    return band


def _legend(w: int, text: str, cameras: list[tuple[str, float]]) -> np.ndarray:
    """A caption strip: ``text``, then per camera a swatch of its colour, its name and
    its share of the points, then the share no camera coloured; on further lines where
    the strip is too narrow."""
    scale = 0.55
    lines = _wrapped(text, w - 20, scale)
    x, k = 10 + _width(lines[-1], scale) + 24, len(lines) - 1
    places = []
    for name, share in cameras:
        label = f"{name} {100 * share:.1f} %"
        if x + 20 + _width(label, scale) > w - 10:
            x, k = 10, k + 1
        places.append((x, k, label))
        x += 20 + _width(label, scale) + 24
    band = np.full((34 + 22 * k, w, 3), _BG, dtype=np.uint8)
    for n, line in enumerate(lines):
        _label(band, line, scale=scale, y=23 + 22 * n)
    for c, (x, n, label) in enumerate(places):
        colour = UNCOLOURED_RGB if c == len(cameras) - 1 else _palette(c)
        cv2.rectangle(band, (x, 11 + 22 * n), (x + 14, 25 + 22 * n), colour, -1)
        _label(band, label, x + 20, scale, y=23 + 22 * n)
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

    From the top: the left side of the street and then its right side, each seen from
    the street (orthographic; height up; the point nearest the track wins each pixel;
    points within 0.5 m of the track on neither); the view from above (left of the track
    up; the highest point wins), ``top_half_width_m`` m either side of the track. Every
    panel runs along the drive to the right, so that they line up: the right side is
    seen as in a mirror. Uncoloured points are grey. With two cameras or more, a strip
    under each side shows the camera that coloured most of each column, and a last panel
    the view from above by source camera (4 times smaller across the street), with each
    camera's share of the points; with one camera both sides are drawn all the same (the
    side it does not see grey). The scale is ``metres_per_px``, coarser when the drive
    would be wider than ``max_width`` px. Each point is drawn as a block a pixel wider
    than the spacing between scans and a pixel taller than the spacing between its
    scan's points (up to 20 px), so that surfaces close up.
    """
    if cloud.size == 0:
        return _band(640, title or "no points")
    p = preview_panels(
        cloud, metres_per_px=metres_per_px, max_width=max_width, top_half_width_m=top_half_width_m
    )
    w, res, cm = p.left.shape[1], p.res, p.res * 100
    left = [p.left] + ([p.strips[0]] if p.strips else [])
    right = [p.right] + ([p.strips[1]] if p.strips else [])
    none = p.cameras[-1][1]
    strip = "; the strip under it: the camera that coloured most of each column" if p.strips else ""
    parts = [
        _band(w, title, scale=0.6),
        _band(w, f"left side seen from the street ({cm:.0f} cm/px){strip}", res),
        *left,
        _band(w, f"right side seen from the street, as in a mirror ({cm:.0f} cm/px){strip}", res),
        *right,
        _band(
            w,
            f"seen from above, left side up ({cm:.0f} cm/px); the drive runs to the right; "
            f"grey: points no frame saw ({100 * none:.1f} %)",
            res,
        ),
        p.top,
    ]
    if p.top_camera is not None:
        text = "by camera, from above (across the street 4 times smaller):"
        parts += [_legend(w, text, p.cameras), p.top_camera]
    return np.vstack(parts)


def preview_png(
    path: str | os.PathLike[str], cloud: Cloud, *, title: str = "", metres_per_px: float = 0.03
) -> tuple[int, int]:
    """Write :func:`preview_image` as a PNG; returns its (width, height), px."""
    img = preview_image(cloud, metres_per_px=metres_per_px, title=title)
    write_image(path, img)
    return int(img.shape[1]), int(img.shape[0])
