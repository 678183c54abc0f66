"""Facet textures: the view most of a facet's vertices were coloured from
(:func:`facet_views`; the view chosen per facet is :mod:`acq.mesh.view_selection`'s), its
corners' pixels in a facet's view (:func:`corner_pixels`), and an atlas of the facets'
texels resampled from the fisheye frames (:func:`build_atlas`).

The atlas is a grid of square cells of ``texels`` x ``texels``, two facets a cell: the
upper-left and the lower-right triangle, each corner on a texel's centre and a texel
between the two, so that bilinear filtering never mixes a facet's texels with another's.
Each texel is sampled (bilinear) from the frame at the facet's affine map of it, its
colour balanced with the frame's gains (:class:`acq.cloud.balance.Gains`) as the
vertex colours are.

Pixels: (u, v) px, the centre of the first pixel at (0, 0); texture coordinates: [0, 1],
origin bottom-left (v up, as OBJ and trimesh have them).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from acq.camera import projection
from acq.cloud.balance import Gains
from acq.cloud.chunks import NO_CAMERA
from acq.cloud.job import Job
from acq.cloud.views import camera_poses
from acq.geometry.transforms import Rigid
from acq.time.sync import on_laser_clock

__all__ = [
    "MAX_SIDE",
    "Atlas",
    "atlas_shape",
    "build_atlas",
    "cell_corners",
    "corner_pixels",
    "facet_views",
    "half_texels",
    "view_keys",
]

# the largest texture side viewers take (WebGL's MAX_TEXTURE_SIZE on desktops; JPEG's
# own limit is 65,535)
MAX_SIDE = 16384
_ROWS = 4096  # facets resampled per cv2.remap call (its maps stay small)
_TEXEL = np.dtype((np.void, 3))  # a texel's three bytes as one item

# the images of camera c's session frames (sorted), in that order (each valid until the
# next is asked for); None: not decoded
FrameImages = Callable[[int, np.ndarray], Iterator[np.ndarray | None]]


def view_keys(camera: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(V,) int64 camera << 32 | frame of each vertex's view, -1 for none."""
    ok = (camera != NO_CAMERA) & (frame >= 0)
    return np.where(ok, (camera.astype(np.int64) << 32) | frame.astype(np.int64), -1)


def facet_views(
    camera: np.ndarray, frame: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each facet's vertices' view: ((F,) camera index, (F,) session frame), -1 for none,
    from its vertices' ``camera`` (V,) (``NO_CAMERA`` none) and ``frame`` (V,) (-1 none):
    the one most of them have, a tie to the first vertex."""
    k = view_keys(camera, frame)[faces]
    rows = np.arange(k.shape[0])
    votes = np.where(k >= 0, (k[:, :, None] == k[:, None, :]).sum(axis=2), -100.0)
    votes = votes - np.array([0.0, 0.01, 0.02])
    chosen = k[rows, np.argmax(votes, axis=1)]
    return np.where(chosen >= 0, chosen >> 32, -1), np.where(chosen >= 0, chosen & 0xFFFFFFFF, -1)


def corner_pixels(
    job: Job, xyz: np.ndarray, camera: np.ndarray, frame: np.ndarray, uv: np.ndarray,
    faces: np.ndarray, view_cam: np.ndarray, view_frame: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """(F,3,2) float32 px: each facet corner's pixel in the facet's view (NaN: none, or
    off the sensor). A vertex coloured from that view keeps the pixel the colouring found
    (``uv`` (V,2)); another is projected into it as the colouring projects (the camera
    where the rig stood at the frame's time, in the world frame of ``xyz`` (V,3) m)."""
    px: np.ndarray = uv[faces].astype(np.float32)
    mine = (view_cam >= 0)[:, None]
    key = view_keys(camera, frame)[faces]
    want = np.where(mine[:, 0], (view_cam << 32) | np.maximum(view_frame, 0), -2)
    odd = mine & (key != want[:, None])
    px[~mine[:, 0]] = np.nan
    f_idx, c_idx = np.nonzero(odd)
    for c, cj in enumerate(job.cameras):
        sel = view_cam[f_idx] == c
        if not sel.any():
            continue
        fi, ci = f_idx[sel], c_idx[sel]
        t_ns = on_laser_clock(cj.frame_new[view_frame[fi]], cj.time_offset_ns)
        R, t = camera_poses(cj.cam, job.laser_to_vehicle, job.trajectory.pose_at, t_ns)
        P_cam = np.einsum("nji,nj->ni", R, xyz[faces[fi, ci]] - t)
        got, ok = projection.project(P_cam, cj.cam.model, Rigid.identity())
        got[~ok] = np.nan
        px[fi, ci] = got
    return px


def atlas_shape(n_facets: int, texels: int) -> tuple[int, int]:
    """(height, width) texels of the atlas of ``n_facets``: two a cell of ``texels`` a
    side, the cells as near a square as whole rows make it."""
    cells = max(1, (n_facets + 1) // 2)
    cols = math.ceil(math.sqrt(cells))
    return math.ceil(cells / cols) * texels, cols * texels


def cell_corners(texels: int) -> np.ndarray:
    """(2,3,2) float64: a cell's two triangles' corners (x, y) texels from the cell's
    first texel's centre (the upper-left one, then the lower-right one); one texel
    between their long sides."""
    n = texels - 1
    return np.array([[[0, 0], [n - 1, 0], [0, n - 1]], [[n, n], [2, n], [n, 2]]], dtype=np.float64)


def half_texels(texels: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(x, y) of the texels of each half of a cell: x + y < texels, and the rest."""
    y, x = np.mgrid[0:texels, 0:texels]
    upper = (x + y) < texels
    return [(x[upper], y[upper]), (x[~upper], y[~upper])]


def _level_tables(gains: Gains | None, camera: int, frames: np.ndarray) -> np.ndarray | None:
    """(M,1,256,3) uint8: for each of ``camera``'s ``frames`` (M,), each BGR level's
    balanced level (exactly :meth:`Gains.apply`'s), as cv2.LUT takes it; None: no gains."""
    if gains is None:
        return None
    ramp = np.tile(np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1), (frames.size, 1))
    rgb = gains.apply(camera, ramp, np.repeat(frames, 256))
    return np.ascontiguousarray(rgb.reshape(frames.size, 1, 256, 3)[..., ::-1])


@dataclass(frozen=True)
class Atlas:
    """A tile's texture: ``bgr`` (H,W,3) uint8 (as the frames and the JPEG encoder have
    it; :attr:`image` RGB), cells of ``texels`` a side, row by row; ``uv`` (F,3,2)
    float32 each facet corner's texture coordinates; ``textured`` (F,) bool: facets
    sampled from a frame (the others filled with their vertices' mean colour)."""

    bgr: np.ndarray
    uv: np.ndarray
    textured: np.ndarray
    slot: np.ndarray  # (F,) int64: each facet's cell (slot // 2, row by row) and half

    @cached_property
    def image(self) -> np.ndarray:
        """(H,W,3) uint8 RGB (made when first asked)."""
        return np.ascontiguousarray(self.bgr[..., ::-1])


def build_atlas(
    corner_px: np.ndarray, view_cam: np.ndarray, view_frame: np.ndarray,
    images: FrameImages, gains: Gains | None, fill: np.ndarray, texels: int,
) -> Atlas:  # fmt: skip
    """The atlas of F facets, each in a half cell (:attr:`Atlas.slot`), sampled from the
    frame ``view_frame`` of camera ``view_cam`` (F,) at its corners' pixels
    ``corner_px`` (F,3,2) (:func:`corner_pixels`), each frame's image asked once from
    ``images``, balanced by ``gains`` (per camera, rows by session frame; None: as they
    are); a facet without a view or pixels is filled with ``fill`` (F,3) uint8."""
    if texels < 4:
        raise ValueError(f"a cell of {texels} texels: at least 4 expected")
    n_facets = corner_px.shape[0]
    bgr = np.zeros((*atlas_shape(n_facets, texels), 3), dtype=np.uint8)  # as the frames are
    cols = bgr.shape[1] // texels
    corners = cell_corners(texels)
    halves = half_texels(texels)
    # the affine map of a half's texels (x, y, 1) to the frame: corner_px^T @ inv(Q)
    q_inv = [np.linalg.inv(np.vstack([c.T, np.ones(3)])).astype(np.float32) for c in corners]
    halves_f = [(xs.astype(np.float32), ys.astype(np.float32)) for xs, ys in halves]
    textured = (view_cam >= 0) & np.isfinite(corner_px).all(axis=(1, 2))
    done = np.zeros(n_facets, dtype=bool)
    use = np.flatnonzero(textured)
    order = use[np.lexsort((view_frame[use], view_cam[use]))]
    # places in the order sampled: a frame's facets fill neighbouring cells (the atlas
    # written in order, and a smoother image to compress)
    slot = np.empty(n_facets, dtype=np.int64)
    slot[np.r_[order, np.flatnonzero(~textured)]] = np.arange(n_facets)
    half_of = slot % 2
    cy, cx = np.divmod(slot // 2, cols)
    flat = bgr.reshape(-1).view(_TEXEL)  # a texel a item: one index a texel
    width = bgr.shape[1]
    cell_at = (cy * texels) * width + cx * texels  # each facet's cell's first texel in flat
    at_half = [ys * width + xs for xs, ys in halves]
    for c in np.unique(view_cam[order]).tolist():
        # the camera's facets by frame, then half: each frame's halves are runs
        mine = order[view_cam[order] == c]
        mine = mine[np.lexsort((half_of[mine], view_frame[mine]))]
        half = half_of[mine]
        M = np.empty((mine.size, 2, 3), dtype=np.float32)  # each facet's map, all at once
        for h in (0, 1):
            M[half == h] = np.einsum("fci,cj->fij", corner_px[mine[half == h]], q_inv[h])
        got = [np.empty((int(np.count_nonzero(half == h)), xs.size, 3), np.uint8)
               for h, (xs, _) in enumerate(halves_f)]  # fmt: skip
        # each facet's row in its half's got
        row_of = np.empty(mine.size, dtype=np.int64)
        for h in (0, 1):
            row_of[half == h] = np.arange(np.count_nonzero(half == h))
        frames, first = np.unique(view_frame[mine], return_index=True)
        ends = np.r_[first[1:], mine.size]
        mids = first + np.add.reduceat((half == 0).astype(np.int64), first) if first.size else first
        luts = _level_tables(gains, c, frames)
        for j, (lo, mid, hi, img) in enumerate(zip(first, mids, ends, images(c, frames),
                                                  strict=True)):  # fmt: skip
            if img is None:  # its facets' rows of got are not used: they are filled
                continue
            done[mine[lo:hi]] = True
            for h, (a, b) in enumerate([(lo, mid), (mid, hi)]):
                xs, ys = halves_f[h]
                for k in range(a, b, _ROWS):
                    m = M[k : min(k + _ROWS, b)]
                    mx = m[:, 0, 0:1] * xs + m[:, 0, 1:2] * ys + m[:, 0, 2:3]
                    my = m[:, 1, 0:1] * xs + m[:, 1, 1:2] * ys + m[:, 1, 2:3]
                    part = cv2.remap(img, mx, my, cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
                    if luts is not None:
                        part = cv2.LUT(part, luts[j])
                    row = row_of[k]
                    got[h][row : row + part.shape[0]] = part
        for h in (0, 1):
            fs = mine[half == h]
            flat[cell_at[fs, None] + at_half[h]] = (
                got[h].reshape(-1).view(_TEXEL).reshape(fs.size, at_half[h].size)
            )
    for h, (xs, ys) in enumerate(halves):
        rest = np.flatnonzero(~done & (half_of == h))
        bgr[cy[rest, None] * texels + ys, cx[rest, None] * texels + xs] = fill[rest, None, ::-1]
    origin = np.stack([cx * texels, cy * texels], axis=1)[:, None, :].astype(np.float64)
    at = origin + corners[half_of] + 0.5  # pixel edges: the first texel spans 0..1
    uv = np.stack([at[..., 0] / bgr.shape[1], 1.0 - at[..., 1] / bgr.shape[0]], axis=-1)
    return Atlas(bgr, uv.astype(np.float32), done, slot)
