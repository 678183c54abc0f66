"""Seams between views levelled (acq/mesh/seams.py) on atlases built from synthetic
frames (a linear gradient, which bilinear sampling reproduces exactly): a flat strip
seen by two views whose colours differ by a known offset."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from acq.mesh import seams, texture

T = 8
OFFSET = np.array([14.0, -10.0, 18.0])  # BGR levels view 1 has over view 0 (< seams.MAX_STEP)


def _gradient(h: int = 120, w: int = 200) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([60 + u / 2, 80 + v / 2, 150 - u / 4], axis=-1)


def _frames(*images: np.ndarray) -> texture.FrameImages:
    def images_of(camera: int, frames: np.ndarray) -> Any:
        return iter(images[f] for f in frames.tolist())

    return images_of


def _strip(cols: int = 20, rows: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat grid of vertices (cols+1) x (rows+1), 8 px apart in both frames: the
    facets (F,3), their corners' pixels (F,3,2) and each facet's column."""
    i, j = np.meshgrid(np.arange(cols + 1), np.arange(rows + 1), indexing="ij")
    pix = np.stack([10.0 + 8 * i, 10.0 + 8 * j], axis=-1).reshape(-1, 2)
    vid = np.arange(pix.shape[0]).reshape(cols + 1, rows + 1)
    faces, col = [], []
    for a in range(cols):
        for b in range(rows):
            faces += [[vid[a, b], vid[a + 1, b], vid[a, b + 1]],
                      [vid[a + 1, b + 1], vid[a, b + 1], vid[a + 1, b]]]  # fmt: skip
            col += [a, a]
    f = np.array(faces)
    return f, pix[f].astype(np.float32), np.array(col)


def _atlas(view_frame: np.ndarray, px: np.ndarray, offset: np.ndarray = OFFSET) -> texture.Atlas:
    img = _gradient()
    shifted = np.clip(img + offset, 0, 255).astype(np.uint8)
    view_cam = np.zeros(view_frame.size, dtype=np.int64)
    fill = np.zeros((view_frame.size, 3), np.uint8)
    return texture.build_atlas(px, view_cam, view_frame,
                               _frames(img.astype(np.uint8), shifted), None, fill, T)  # fmt: skip


def _texels(atlas: texture.Atlas, f: int) -> np.ndarray:
    cols = atlas.bgr.shape[1] // T
    s = atlas.slot[f]
    cy, cx = divmod(s // 2, cols)
    xs, ys = texture.half_texels(T)[s % 2]
    return atlas.bgr[cy * T + ys, cx * T + xs]


def test_two_views_offset_by_a_known_colour_meet_level_at_the_seam() -> None:
    faces, px, col = _strip()
    view_frame = (col >= 10).astype(np.int64)  # columns 0-9 in frame 0, 10-19 in frame 1
    view_cam = np.zeros_like(view_frame)
    atlas = _atlas(view_frame, px)
    a, b, ends, fa, fb = seams.seam_colours(atlas, faces, view_cam, view_frame, T)
    diff = (fa - fb).reshape(-1, 3)
    # the seam: the 6 grid edges between columns 9 and 10, both ends of each
    assert ends.shape == (6, 2)
    assert set(col[a].tolist()) | set(col[b].tolist()) == {9, 10}
    sign = np.repeat(np.where(view_frame[a] == 0, 1.0, -1.0), 2)[
        :, None
    ]  # diff as frame 0 - frame 1
    assert np.abs(diff * sign + OFFSET).max() <= 1.0, diff
    levelled = replace(atlas, bgr=atlas.bgr.copy())
    assert seams.level_seams(levelled, faces, view_cam, view_frame, T) == 6
    _, _, _, la, lb = seams.seam_colours(levelled, faces, view_cam, view_frame, T)
    after = la - lb
    assert np.abs(after).max() <= 1.5, after  # the seam is gone
    # the facets either side each take about half the offset
    f9 = np.flatnonzero(col == 9)[0]
    f10 = np.flatnonzero(col == 10)[0]
    assert 0 < np.abs(levelled.bgr.astype(int) - atlas.bgr.astype(int)).max() <= OFFSET.max()
    assert not np.array_equal(_texels(levelled, f9), _texels(atlas, f9))
    assert not np.array_equal(_texels(levelled, f10), _texels(atlas, f10))
    # the facets without a corner on the seam (column 10's vertices) keep their texels,
    # byte for byte
    far = np.flatnonzero((col < 9) | (col > 10))
    for f in far:
        assert np.array_equal(_texels(levelled, f), _texels(atlas, f)), f


def test_levelling_leaves_the_texture_continuous_across_the_seam() -> None:
    """Along a row, the levelled colour changes by no more than the gradient's own step
    plus the offset spread over the rings: no step left at the seam."""
    faces, px, col = _strip()
    view_frame = (col >= 10).astype(np.int64)
    view_cam = np.zeros_like(view_frame)
    _, _, _, fa, fb = seams.seam_colours(_atlas(view_frame, px), faces, view_cam, view_frame, T)
    levelled = _atlas(view_frame, px)
    seams.level_seams(levelled, faces, view_cam, view_frame, T)
    _, _, _, la, lb = seams.seam_colours(levelled, faces, view_cam, view_frame, T)
    assert np.abs(fa - fb).max(axis=-1).mean() > 10 * max(1.0, np.abs(la - lb).max(axis=-1).mean())


def test_a_tile_without_seams_is_unchanged() -> None:
    faces, px, col = _strip()
    one_view = np.zeros(col.size, dtype=np.int64)
    atlas = _atlas(one_view, px)
    kept = atlas.bgr.copy()
    assert seams.level_seams(atlas, faces, one_view, one_view, T) == 0
    assert atlas.bgr.tobytes() == kept.tobytes()
    # two views that only meet at facets without a texture (filled): no seam either
    view_frame = (col >= 10).astype(np.int64)
    view_cam = np.where((col == 9) | (col == 10), -1, 0)
    view_frame = np.where(view_cam < 0, -1, view_frame)
    holed = px.copy()
    holed[view_cam < 0] = np.nan
    atlas = texture.build_atlas(holed, view_cam, view_frame,
                                _frames(_gradient().astype(np.uint8),
                                        _gradient().astype(np.uint8)),
                                None, np.zeros((col.size, 3), np.uint8), T)  # fmt: skip
    kept = atlas.bgr.copy()
    assert seams.level_seams(atlas, faces, view_cam, view_frame, T) == 0
    assert atlas.bgr.tobytes() == kept.tobytes()


def test_views_differing_beyond_max_step_are_another_surface_left_alone() -> None:
    faces, px, col = _strip()
    view_frame = (col >= 10).astype(np.int64)
    view_cam = np.zeros_like(view_frame)
    offset = np.array([0.0, seams.MAX_STEP + 5, 0.0])
    atlas = _atlas(view_frame, px, offset)
    kept = atlas.bgr.copy()
    assert seams.level_seams(atlas, faces, view_cam, view_frame, T) == 6  # found, not levelled
    assert atlas.bgr.tobytes() == kept.tobytes()
    # the same with a looser bound levels them
    seams.level_seams(atlas, faces, view_cam, view_frame, T, max_step=seams.MAX_STEP + 10)
    _, _, _, la, lb = seams.seam_colours(atlas, faces, view_cam, view_frame, T)
    assert np.abs(la - lb).max() <= 1.5
