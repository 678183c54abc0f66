"""Seams between views levelled (:func:`level_seams`) in an atlas of half cells
(:mod:`acq.mesh.texture`): the local form of mvs-texturing's seam levelling (Waechter et
al. 2014, "Let there be color!", §4.2).

Two neighbouring facets textured from two views (camera, frame) see their shared edge
in two frames; what the frames' colour balance leaves between them (vignetting, the
surface's brightness changing with the angle, the balance's residual) shows as a seam.
Each vertex on a seam gets, per view of the facets around it, an additive colour
correction g (levels, per channel) minimising

    sum over the vertex's pairs of views A, B:  (f^A + g^A - f^B - g^B)^2

with the least correction: every view's colour there moves to the mean of the views'
(two views: each half the way). f^X: the vertex's colour as view X sees it, the mean of
the texels along X's seam edges at the vertex, weighted by their nearness to it (1 at the
vertex, 0 at the edge's other end). Vertices off the seams keep 0, and each facet's
texels get its corners' corrections interpolated barycentrically: a correction fades out
across the facets at the seam, and a facet without a corner on a seam keeps its texels
as sampled. mvs-texturing also ties the corrections of each view's neighbouring
vertices (a sparse least-squares problem over the whole mesh, spreading them over whole
patches); here a drive has a seam edge every few facets (one per frame of the pushbroom
scan), and that problem (scipy's sparse LU) made `acq mesh --texture` of the 60 s drive
over 20 s longer, the local one under a CPU second.

Levels of the atlas (uint8 BGR); texel positions (x, y) from a cell's first texel.
"""

from __future__ import annotations

import numba
import numpy as np

from acq.mesh.texture import Atlas, cell_corners, half_texels, view_keys
from acq.mesh.view_selection import neighbours

__all__ = ["MAX_STEP", "MAX_VIEWS", "level_seams", "seam_colours"]

MAX_VIEWS = 8  # views kept per vertex (a grid vertex has six facets)
# levels (any channel) beyond which two views' colours at a seam are not levelled: what
# differs more is another surface in one of them (a facet's edge misplaced by the
# calibration's or the motion's error, an occlusion missed), not the same one's shading
MAX_STEP = 20.0


@numba.njit(cache=True, nogil=True)
def _views_at(faces, key, textured, n_vertices, max_views):  # type: ignore[no-untyped-def]
    """The views of the textured facets at each vertex where several meet: (V,) int64
    its row (-1: one view or none) in (S,max_views) int64 those views (-1: none)."""
    first = np.full(n_vertices, -1, dtype=np.int64)
    row = np.full(n_vertices, -1, dtype=np.int64)
    n = 0
    for f in range(faces.shape[0]):
        if not textured[f]:
            continue
        for c in range(3):
            v = faces[f, c]
            if first[v] < 0:
                first[v] = key[f]
            elif first[v] != key[f] and row[v] < 0:
                row[v] = n
                n += 1
    table = np.full((n, max_views), -1, dtype=np.int64)
    for f in range(faces.shape[0]):
        if not textured[f]:
            continue
        for c in range(3):
            r = row[faces[f, c]]
            if r < 0:
                continue
            for j in range(max_views):
                if table[r, j] == key[f]:
                    break
                if table[r, j] < 0:
                    table[r, j] = key[f]
                    break
    return row, table


def _seam_edges(
    faces: np.ndarray, key: np.ndarray, textured: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The edges joining two textured facets of two views: (E,) facets a and b, (E,2)
    the shared corners' indices (0..2) in a and in b (the same vertices, in order), and
    the views at the vertices (:func:`_views_at`)."""
    n_v = int(faces.max(initial=-1)) + 1
    row, table = _views_at(faces, key, textured, n_v, MAX_VIEWS)
    several = row >= 0
    # a seam edge's facets each have two corners where several views meet
    cand = np.flatnonzero(textured & (several[faces].sum(axis=1) >= 2))
    a, b = neighbours(faces[cand])
    a, b = cand[a], cand[b]
    seam = key[a] != key[b]
    a, b = a[seam], b[seam]
    eq = faces[a][:, :, None] == faces[b][:, None, :]  # (E,3,3): a's corner i is b's j
    shared = eq.any(axis=2)
    ok = shared.sum(axis=1) == 2  # a degenerate facet may share more
    a, b, eq, shared = a[ok], b[ok], eq[ok], shared[ok]
    ca = np.nonzero(shared)[1].reshape(-1, 2)
    cb = np.argmax(eq[np.arange(a.size)[:, None], ca], axis=2)
    return a, b, ca, cb, (row, table)


@numba.njit(cache=True, nogil=True)
def _edge_means(bgr, slot, texels, corners, f, ci, cj):  # type: ignore[no-untyped-def]
    """(E,2,3) float64: the colour of each edge of facets ``f`` (E,) from corner ``ci``
    to ``cj`` (E,) near each end (``ci`` first): its texels weighted by nearness."""
    cols = bgr.shape[1] // texels
    out = np.zeros((f.size, 2, 3))
    for e in range(f.size):
        s = slot[f[e]]
        h = s % 2
        y0 = (s // 2) // cols * texels
        x0 = (s // 2) % cols * texels
        px, py = corners[h, ci[e], 0], corners[h, ci[e], 1]
        qx, qy = corners[h, cj[e], 0], corners[h, cj[e], 1]
        n = max(abs(qx - px), abs(qy - py))
        sx, sy = (qx - px) // n, (qy - py) // n
        wsum = 0.0
        for k in range(n + 1):
            w = 1.0 - k / n
            wsum += w
            for ch in range(3):
                level = bgr[y0 + py + k * sy, x0 + px + k * sx, ch]
                out[e, 0, ch] += w * level
                out[e, 1, ch] += (1.0 - w) * level
        for ch in range(3):
            out[e, 0, ch] /= wsum
            out[e, 1, ch] /= n + 1 - wsum
    return out


def _seams(
    atlas: Atlas, faces: np.ndarray, key: np.ndarray, texels: int
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]
]:
    """:func:`seam_colours` of the facets in the views ``key`` (F,), and the views at
    the vertices (:func:`_views_at`)."""
    a, b, ca, cb, table = _seam_edges(faces, key, atlas.textured)
    corners = cell_corners(texels).astype(np.int64)
    fa = _edge_means(atlas.bgr, atlas.slot, texels, corners, a, ca[:, 0], ca[:, 1])
    fb = _edge_means(atlas.bgr, atlas.slot, texels, corners, b, cb[:, 0], cb[:, 1])
    return a, b, faces[a[:, None], ca], fa, fb, table


def seam_colours(
    atlas: Atlas, faces: np.ndarray, view_cam: np.ndarray, view_frame: np.ndarray, texels: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each seam edge's colours near its ends on either side, from the atlas of the
    facets ``faces`` (F,3) in the views ``view_cam``, ``view_frame`` (F,): (E,) its
    facets a and b (of two views), (E,2) the ends' vertices, (E,2,3) the colours in a
    and in b (levels, BGR)."""
    return _seams(atlas, faces, view_keys(view_cam, view_frame), texels)[:5]


@numba.njit(cache=True, nogil=True)
def _corrections(row, table, ends, key_a, key_b, fa, fb, max_step):  # type: ignore[no-untyped-def]
    """(S,max_views,3) float64: the correction of each view at the vertices where
    several meet (``row``, ``table``: :func:`_views_at`): every view's colour moved to
    the mean of the views' there, from the seam edges' ends ``ends`` (E,2) between views
    ``key_a`` and ``key_b`` (E,) and their colours ``fa``, ``fb`` (E,2,3), those that
    differ by at most ``max_step`` levels in every channel."""
    n, m = table.shape
    g = np.zeros((n, m, 3))  # the sums of each view's colours, then the corrections
    count = np.zeros((n, m))
    for e in range(ends.shape[0]):
        for k in range(2):
            step = 0.0
            for ch in range(3):
                step = max(step, abs(fa[e, k, ch] - fb[e, k, ch]))
            if step > max_step:
                continue
            r = row[ends[e, k]]
            for j in range(m):
                if table[r, j] == key_a[e]:
                    count[r, j] += 1.0
                    for ch in range(3):
                        g[r, j, ch] += fa[e, k, ch]
                elif table[r, j] == key_b[e]:
                    count[r, j] += 1.0
                    for ch in range(3):
                        g[r, j, ch] += fb[e, k, ch]
    for r in range(n):
        views = 0
        m0 = m1 = m2 = 0.0
        for j in range(m):
            if count[r, j] > 0:
                views += 1
                m0 += g[r, j, 0] / count[r, j]
                m1 += g[r, j, 1] / count[r, j]
                m2 += g[r, j, 2] / count[r, j]
        for j in range(m):
            if views < 2 or count[r, j] == 0:
                g[r, j, 0] = g[r, j, 1] = g[r, j, 2] = 0.0
                continue
            g[r, j, 0] = m0 / views - g[r, j, 0] / count[r, j]
            g[r, j, 1] = m1 / views - g[r, j, 1] / count[r, j]
            g[r, j, 2] = m2 / views - g[r, j, 2] / count[r, j]
    return g


@numba.njit(cache=True, nogil=True)
def _apply(bgr, slot, texels, faces, key, textured, row, table, g, xs, ys, counts, bary):  # type: ignore[no-untyped-def]
    """Add each textured facet's corners' corrections ``g`` (:func:`_corrections`) to
    its half's texels (``xs``, ``ys`` (2,T) per half, the first ``counts`` of each;
    weights ``bary`` (2,T,3)) in ``bgr``."""
    cols = bgr.shape[1] // texels
    corner = np.zeros((3, 3))
    by_slot = np.empty(slot.size, dtype=np.int64)  # the facets in the atlas's order
    by_slot[slot] = np.arange(slot.size)
    for f in by_slot:
        if not textured[f]:
            continue
        big = False
        corner[:] = 0.0
        for c in range(3):
            r = row[faces[f, c]]
            if r < 0:
                continue
            for j in range(table.shape[1]):
                if table[r, j] == key[f]:
                    for ch in range(3):
                        corner[c, ch] = g[r, j, ch]
                        big |= abs(g[r, j, ch]) >= 0.5
                    break
        if not big:
            continue
        s = slot[f]
        h = s % 2
        y0 = (s // 2) // cols * texels
        x0 = (s // 2) % cols * texels
        for t in range(counts[h]):
            y, x = y0 + ys[h, t], x0 + xs[h, t]
            for ch in range(3):
                level = bgr[y, x, ch] + 0.5 + bary[h, t, 0] * corner[0, ch]
                level += bary[h, t, 1] * corner[1, ch] + bary[h, t, 2] * corner[2, ch]
                bgr[y, x, ch] = min(255.0, max(0.0, level))


def level_seams(
    atlas: Atlas,
    faces: np.ndarray,
    view_cam: np.ndarray,
    view_frame: np.ndarray,
    texels: int,
    max_step: float = MAX_STEP,
) -> int:
    """Level the seams of ``atlas`` (:func:`acq.mesh.texture.build_atlas`'s, of the
    facets ``faces`` (F,3) in the views ``view_cam``, ``view_frame`` (F,)) in place, its
    :attr:`~acq.mesh.texture.Atlas.image` not yet made (module docstring); the number of
    seam edges found (0: the atlas left as it is)."""
    key = view_keys(view_cam, view_frame)
    a, b, ends, fa, fb, views = _seams(atlas, faces, key, texels)
    if a.size == 0:
        return 0
    g = _corrections(*views, ends, key[a], key[b], fa, fb, max_step)
    # each half's texels (x, y), the lower right's padded to the upper left's count,
    # and their barycentric weights in the half's triangle
    halves = half_texels(texels)
    n = halves[0][0].size
    xs = np.stack([np.pad(x, (0, n - x.size), mode="edge") for x, _ in halves])
    ys = np.stack([np.pad(y, (0, n - y.size), mode="edge") for _, y in halves])
    cc = cell_corners(texels)
    bary = np.stack([
        np.linalg.solve(np.vstack([cc[h].T, np.ones(3)]), np.vstack([xs[h], ys[h], np.ones(n)])).T
        for h in (0, 1)
    ])  # fmt: skip
    counts = np.array([x.size for x, _ in halves])
    _apply(atlas.bgr, atlas.slot, texels, faces, key, atlas.textured, *views, g, xs, ys, counts,
           bary)  # fmt: skip
    return int(a.size)
