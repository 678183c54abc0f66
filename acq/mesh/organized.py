"""Facets from a pushbroom scanner's organised grid (scan x step), the rules of organised
cloud meshing (PCL's OrganizedFastMesh) adapted to a sensor that moves between scans.

Every grid cell (s, k), (s, k+1), (s+1, k), (s+1, k+1) gives up to two triangles. An edge
between two returns is refused when one end is missing or not finite; when it is longer
than ``edge_a_m + edge_b * range`` (range: the nearer end's distance from its own sensor
origin) plus the sensor's travel between the two measurements (consecutive profiles lie
that far apart on any surface, at any speed); or when it is seen at grazing incidence:
the angle between the edge and the viewing ray from *either* end's own sensor origin is
below ``max_grazing_deg`` (a range jump, a depth discontinuity, shows as an edge running
along the rays). A triangle needs its three edges; of a cell's two diagonals the one
giving more triangles wins, the shorter one when both give as many. Distances are
metres, angles degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from acq.errors import InputValueError

__all__ = ["BLOCK_POINTS", "FacetRules", "grid_facets"]

BLOCK_POINTS = 1 << 18  # points meshed at once (about 400 bytes each while they are)


@dataclass(frozen=True)
class FacetRules:
    """When two neighbouring returns may share a facet (module docstring).

    An edge's length bound is ``edge_a_m + edge_b * range`` plus the sensor's own travel
    between its two ends' measurements (the spacing of consecutive profiles, whatever the
    speed; nothing within a profile). ``edge_b`` = 0.05 leaves room for a surface seen at
    the grazing limit by a scanner with beams up to 0.5 degrees apart (their spacing
    there: range x 0.0087 / sin 12.5 degrees = 0.04 x range). On the simulated street
    (``bench/mesh_facets.py``, 60 s) the defaults put 99 % of the returns on continuous
    surfaces in a facet, and no facet across a depth step of more than 0.5 m.
    """

    max_grazing_deg: float = 12.5  # an edge more nearly parallel to the viewing ray is refused
    edge_a_m: float = 0.05  # an edge longer than edge_a_m + edge_b * range (m) + travel is refused
    edge_b: float = 0.05

    def __post_init__(self) -> None:
        if not 0.0 <= self.max_grazing_deg < 90.0:
            raise InputValueError(f"max_grazing_deg must be in [0, 90), got {self.max_grazing_deg}")
        if not (self.edge_a_m >= 0.0 and self.edge_b >= 0.0):
            raise InputValueError(
                f"edge_a_m and edge_b must be >= 0, got {self.edge_a_m} and {self.edge_b}"
            )


def _check_inputs(
    scan: np.ndarray, step: np.ndarray, xyz: np.ndarray, origin: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The arrays as int64 (P,), int64 (P,), float64 (P,3), float64 (P,3); ValueError
    naming the argument when a shape does not fit."""
    scan_a = np.asarray(scan)
    step_a = np.asarray(step)
    xyz_a = np.asarray(xyz, dtype=np.float64)
    origin_a = np.asarray(origin, dtype=np.float64)
    for name, a in (("scan", scan_a), ("step", step_a)):
        if a.ndim != 1:
            raise ValueError(f"{name} must be one-dimensional (P,), got shape {a.shape}")
        if a.size and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{name} must hold integers, got {a.dtype}")
    P = scan_a.shape[0]
    for name, a in (("xyz", xyz_a), ("origin", origin_a)):
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name} must have shape (P, 3), got {a.shape}")
    lengths = {
        "scan": P,
        "step": step_a.shape[0],
        "xyz": xyz_a.shape[0],
        "origin": origin_a.shape[0],
    }
    if len(set(lengths.values())) != 1:
        told = ", ".join(f"{k} {v}" for k, v in lengths.items())
        raise ValueError(f"scan, step, xyz and origin must have one length P, got {told}")
    return scan_a.astype(np.int64), step_a.astype(np.int64), xyz_a, origin_a


def _ranks(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each value's rank among the distinct values (P,), and per rank whether the next
    rank's value is this one + 1 (the next scan or beam is a neighbour)."""
    distinct, rank = np.unique(values, return_inverse=True)
    follows = np.zeros(distinct.size, dtype=bool)
    follows[:-1] = np.diff(distinct) == 1
    return rank.astype(np.int64), follows


def _neighbour(keys_sorted: np.ndarray, order: np.ndarray, want: np.ndarray) -> np.ndarray:
    """Index of the point whose grid key is ``want`` (-1 where there is none)."""
    pos = np.searchsorted(keys_sorted, want)
    pos_c = np.minimum(pos, keys_sorted.size - 1)
    found = keys_sorted[pos_c] == want
    return np.where(found, order[pos_c], -1)


def _at(ok: np.ndarray, where: np.ndarray) -> np.ndarray:
    """``ok`` of the edges starting at points ``where`` (False where -1: no point)."""
    out: np.ndarray = (where >= 0) & ok[where]
    return out


class _Edges(NamedTuple):
    """The edge from every point to one of its neighbours: ``ok`` (P,) accepted, ``vec``
    the three (P,) coordinates of the vector to the neighbour (0 where none), ``len2``
    (P,) its squared length (m, m^2)."""

    ok: np.ndarray
    vec: list[np.ndarray]
    len2: np.ndarray


class _Points:
    """The finite points as separate coordinate arrays (gathers and arithmetic on 1-D
    arrays are the fast ones): position, viewing ray from the point's own origin, and
    range (m)."""

    def __init__(self, xyz: np.ndarray, origin: np.ndarray) -> None:
        self.p = [np.ascontiguousarray(xyz[:, i]) for i in range(3)]
        self.o = [np.ascontiguousarray(origin[:, i]) for i in range(3)]
        self.ray = [p - o for p, o in zip(self.p, self.o, strict=True)]
        self.dist = np.sqrt(sum(r * r for r in self.ray))
        self.index = np.arange(self.dist.size)

    def edges(self, to: np.ndarray, rules: FacetRules) -> _Edges:
        """The edges from every point to its neighbour ``to`` (P,) (-1: none)."""
        has = to >= 0
        j = np.where(has, to, self.index)  # none: an edge to itself, refused
        d = [p[j] - p for p in self.p]
        len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        length = np.sqrt(len2)
        ra, rb = self.dist, self.dist[j]
        ok = has & (length > 0.0) & (ra > 0.0) & (rb > 0.0)
        # the sensor's own travel between the two measurements is the grid's spacing
        # along the track: allowed on top, whatever the speed
        travel = np.sqrt(sum((o[j] - o) ** 2 for o in self.o))
        ok &= length <= rules.edge_a_m + rules.edge_b * np.minimum(ra, rb) + travel
        # |cos| of the angle between the edge's line and each end's viewing ray
        cos_max = math.cos(math.radians(rules.max_grazing_deg))
        dot_a = d[0] * self.ray[0] + d[1] * self.ray[1] + d[2] * self.ray[2]
        ok &= np.abs(dot_a) <= cos_max * length * ra
        dot_b = d[0] * self.ray[0][j] + d[1] * self.ray[1][j] + d[2] * self.ray[2][j]
        ok &= np.abs(dot_b) <= cos_max * length * rb
        return _Edges(ok, d, len2)

    def triangles(
        self, mask: np.ndarray, v1: np.ndarray, v2: np.ndarray, e1: _Edges, e2: _Edges
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The triangles (p, v1[p], v2[p]) of the points p in ``mask`` (P,), whose sides
        from p are ``e1`` and ``e2``, as (v0, v1, v2) index arrays: those of non-zero
        area, each counter-clockwise seen from p's sensor origin (accepted edges are not
        seen edge-on, so every vertex sees the same side)."""
        v0 = np.flatnonzero(mask)
        a = [c[mask] for c in e1.vec]
        b = [c[mask] for c in e2.vec]
        n = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
        n2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
        keep = n2 > 1e-12 * e1.len2[mask] * e2.len2[mask]  # the angle's sine above 1e-6
        facing = n[0] * self.ray[0][mask] + n[1] * self.ray[1][mask] + n[2] * self.ray[2][mask]
        flip = facing[keep] > 0.0  # the normal must point against the ray
        v0 = v0[keep]
        w1, w2 = v1[v0], v2[v0]
        return v0, np.where(flip, w2, w1), np.where(flip, w1, w2)


def grid_facets(
    scan: np.ndarray,
    step: np.ndarray,
    xyz: np.ndarray,
    origin: np.ndarray,
    rules: FacetRules = FacetRules(),
    *,
    block_points: int = BLOCK_POINTS,
) -> np.ndarray:
    """Triangles (F,3) int64 indexing the P points given: ``scan`` (P,) int scan index
    (consecutive scans are neighbours; any ints, not necessarily from 0), ``step`` (P,)
    int beam index within its scan (neighbour beams differ by 1), ``xyz`` (P,3) float m
    (the points placed, world or laser frame), ``origin`` (P,3) float m: the sensor's
    position when THAT point was measured (per point, so the caller may give the scan's
    origin repeated, or a per-point one). Points missing from the grid (no return) are
    simply absent from the arrays; points with a non-finite coordinate or origin are in
    no facet. Triangles are consistently oriented (counter-clockwise seen from the sensor
    side). ValueError on arrays of mismatched lengths or shapes, or a (scan, step) pair
    given twice.

    Worked in blocks of whole scans of about ``block_points`` points (each with the next
    scan, whose cells the next block makes): the same triangles, in less memory."""
    scan_i, step_i, xyz_f, origin_f = _check_inputs(scan, step, xyz, origin)
    finite = np.isfinite(xyz_f).all(axis=1) & np.isfinite(origin_f).all(axis=1)
    idx = np.flatnonzero(finite)
    if idx.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    idx = idx[np.argsort(scan_i[idx], kind="stable")]
    rows = np.flatnonzero(np.diff(scan_i[idx])) + 1
    row_start = np.concatenate([[0], rows])
    row_end = np.concatenate([rows, [idx.size]])
    parts = []
    first = 0  # the block's first row
    while first < row_start.size:
        last = max(
            first, int(np.searchsorted(row_end, row_start[first] + block_points, "right")) - 1
        )
        block = idx[row_start[first] : row_end[min(last + 1, row_end.size - 1)]]
        parts.append(block[_block_facets(scan_i[block], step_i[block], xyz_f[block],
                                         origin_f[block], rules)])  # fmt: skip
        first = last + 1
    out: np.ndarray = np.concatenate(parts) if len(parts) > 1 else parts[0]
    return out


def _block_facets(
    scan_i: np.ndarray, step_i: np.ndarray, xyz_f: np.ndarray, origin_f: np.ndarray,
    rules: FacetRules,
) -> np.ndarray:  # fmt: skip
    """:func:`grid_facets` of finite points: (F,3) indices into the arrays given."""
    n = scan_i.size
    s_rank, s_follows = _ranks(scan_i)
    k_rank, k_follows = _ranks(step_i)
    width = int(k_rank.max()) + 2  # a key one past a row's end never matches the next row
    keys = s_rank * width + k_rank
    order = np.argsort(keys, kind="stable")
    keys_sorted = keys[order]
    if keys_sorted.size > 1 and (np.diff(keys_sorted) == 0).any():
        dup = order[np.flatnonzero(np.diff(keys_sorted) == 0)[0]]
        raise ValueError(f"(scan, step) = ({scan_i[dup]}, {step_i[dup]}) is given more than once")
    # each point's neighbours (s, k+1), (s+1, k), (s+1, k+1), (s+1, k-1), as positions
    # (-1: none); only true neighbours (value + 1) count, not merely the next
    # distinct value
    k_next = k_follows[k_rank]
    k_prev = np.zeros(k_rank.size, dtype=bool)
    k_prev[k_rank > 0] = k_follows[k_rank[k_rank > 0] - 1]
    s_next = s_follows[s_rank]
    right = np.where(k_next, _neighbour(keys_sorted, order, keys + 1), -1)
    down = np.where(s_next, _neighbour(keys_sorted, order, keys + width), -1)
    diag = np.where(k_next & s_next, _neighbour(keys_sorted, order, keys + width + 1), -1)
    anti = np.where(k_prev & s_next, _neighbour(keys_sorted, order, keys + width - 1), -1)

    pts = _Points(xyz_f, origin_f)
    R, Dn = pts.edges(right, rules), pts.edges(down, rules)
    D, A = pts.edges(diag, rules), pts.edges(anti, rules)

    # the cell whose first corner a = (s, k) exists: b = (s, k+1), c = (s+1, k), d = (s+1, k+1)
    b, c = right, down
    ab, ac, bd, cd = R.ok, Dn.ok, _at(Dn.ok, b), _at(R.ok, c)
    ad, bc = D.ok, _at(A.ok, b)
    abd, adc = ab & bd & ad, ad & cd & ac  # split along a-d
    abc, bdc = ab & bc & ac, bd & cd & bc  # split along b-c
    n_ad = abd.astype(np.int8) + adc
    n_bc = abc.astype(np.int8) + bdc
    len2_bc = np.where(bc, A.len2[b], np.inf)
    use_ad = (n_ad > n_bc) | ((n_ad == n_bc) & (np.where(ad, D.len2, np.inf) <= len2_bc))
    # b, d, c is found from b = p: for the cells above, and for the cell whose first
    # corner is missing
    from_b = np.zeros(n, dtype=bool)
    from_b[b[bdc & ~use_ad]] = True
    no_left = np.ones(n, dtype=bool)
    no_left[right[right >= 0]] = False
    from_b |= no_left & Dn.ok & A.ok & _at(R.ok, anti)
    parts = [
        pts.triangles(abd & use_ad, right, diag, R, D),
        pts.triangles(adc & use_ad, diag, down, D, Dn),
        pts.triangles(abc & ~use_ad, right, down, R, Dn),
        pts.triangles(from_b, down, anti, Dn, A),
    ]
    tri = np.empty((sum(p[0].size for p in parts), 3), dtype=np.int64)
    start = 0
    for v0, v1, v2 in parts:
        rows = slice(start, start + v0.size)
        tri[rows, 0], tri[rows, 1], tri[rows, 2] = v0, v1, v2
        start += v0.size
    return tri
