"""Fewer facets where the surface is flat (`acq mesh --simplify`): near-coplanar facets
merged by quadric edge collapse (pyfqmr, the Fast-Quadric-Mesh-Simplification library),
its lossless mode bounded by a tolerance in metres, the open border kept, vertex colours
carried over from the nearest original vertex; :func:`surface_distance` measures how far
the original vertices lie from the result.

Metres.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from acq.extras import needs

__all__ = ["simplify", "surface_distance"]

# pyfqmr keeps the mesh it works on in its C++ library's global state (one per process,
# whatever the Simplify object): one mesh at a time, set, collapsed and read back
_ONE_AT_A_TIME = threading.Lock()


def simplify(
    xyz: np.ndarray, rgb: np.ndarray, faces: np.ndarray, tolerance_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz (V',3) m, rgb (V',3) uint8, faces (F',3) int64) of the triangles ``faces``
    (F,3) of the vertices ``xyz`` (V,3) m coloured ``rgb`` (V,3) uint8 with edges collapsed
    while the surface moves by at most about ``tolerance_m``: a collapse is refused once
    the sum of the squared distances of the new vertex to the planes of every original
    facet merged into it passes ``tolerance_m``²; so no such plane is more than
    ``tolerance_m`` away. Vertices on the open border (a tile's first and last profile, a
    hole's rim) stay where they are and are never merged, so that tiles still meet. Each
    vertex takes the colour of the original vertex nearest to it."""
    with needs("mesh", "--simplify"):
        import pyfqmr
        from scipy.spatial import cKDTree

    if not faces.size:
        return xyz, rgb, faces
    # about the tile's first vertex: a projected CRS's 10^6 m would cost the quadrics'
    # squared distances their millimetres
    offset = xyz[0].copy()
    local = np.ascontiguousarray(xyz - offset, dtype=np.float64)
    with _ONE_AT_A_TIME:
        s = pyfqmr.Simplify()
        s.setMesh(local, np.ascontiguousarray(faces, dtype=np.int32))
        # simplify_mesh(lossless=True, preserve_border=True) collapses nothing in pyfqmr
        # 0.5; simplify_mesh_lossless takes the border flag as it should
        s.simplify_mesh_lossless(verbose=False, epsilon=tolerance_m**2, preserve_border=True)
        out, tri, _ = s.getMesh()
    gap, near = cKDTree(local).query(out)
    # a vertex that did not move keeps its coordinates to the bit (a neighbouring tile's
    # border has them too)
    placed = np.where((gap == 0)[:, None], xyz[near], out + offset)
    return placed, rgb[near], tri.astype(np.int64)


def surface_distance(
    points: np.ndarray, xyz: np.ndarray, faces: np.ndarray, exact_over_m: float = 0.0
) -> np.ndarray:
    """The distance (N,) m of each of ``points`` (N,3) m to the surface of the triangles
    ``faces`` (F,3) of ``xyz`` (V,3) m: first to the facets around its 4 nearest vertices
    (an upper bound), then, where that passes ``exact_over_m``, to every facet near enough
    to be closer (exact). With the default 0 every distance is exact; a larger value keeps
    the largest distances (and any share of them above it) exact, and is faster."""
    from scipy.spatial import cKDTree
    from trimesh import triangles

    closest_point: Any = triangles.closest_point  # trimesh has no annotations
    tri = xyz[faces]
    corner = np.argsort(faces.ravel(), kind="stable")  # facet corners by vertex
    start = np.searchsorted(faces.ravel()[corner], np.arange(xyz.shape[0] + 1))
    k = min(4, xyz.shape[0])
    near = cKDTree(xyz).query(points, k=k)[1].reshape(points.shape[0], k)
    best = np.full(points.shape[0], np.inf)
    for j in range(k):
        v = near[:, j]
        degree = start[v + 1] - start[v]
        for n in range(int(degree.max(initial=0))):
            has = np.flatnonzero(degree > n)
            f = corner[start[v[has]] + n] // 3
            d = np.linalg.norm(closest_point(tri[f], points[has]) - points[has], axis=1)
            best[has] = np.minimum(best[has], d)
    # a closer facet has a corner within (bound + its longest reach from its centroid)
    centre = tri.mean(axis=1)
    reach = float(np.linalg.norm(tri - centre[:, None], axis=2).max(initial=0.0))
    centres = cKDTree(centre)
    for i in np.flatnonzero(best > exact_over_m):
        f = np.asarray(centres.query_ball_point(points[i], best[i] + reach), dtype=np.int64)
        if f.size:
            q = np.broadcast_to(points[i], (f.size, 3))
            best[i] = min(
                best[i], float(np.linalg.norm(closest_point(tri[f], q) - q, axis=1).min())
            )
    return best
