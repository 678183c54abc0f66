"""Facets of a pushbroom scanner's grid (scan x step): a stand-in that joins every
complete grid cell into two triangles, with no rules; the rules of organised-cloud
meshing (missing returns, range jumps, grazing edges, long edges) replace it.

Metres; indices into the points given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FacetRules", "grid_facets"]


@dataclass(frozen=True)
class FacetRules:
    """When two grid neighbours are joined: an edge within ``max_grazing_deg`` of the
    viewing ray is refused, as is one longer than ``edge_a_m + edge_b * range`` (m)."""

    max_grazing_deg: float = 12.5
    edge_a_m: float = 0.05
    edge_b: float = 0.05


def grid_facets(
    scan: np.ndarray,
    step: np.ndarray,
    xyz: np.ndarray,
    origin: np.ndarray,
    rules: FacetRules = FacetRules(),
) -> np.ndarray:
    """Triangles (F,3) int64 indexing the P points: ``scan`` (P,) scan index
    (consecutive scans are neighbours), ``step`` (P,) beam index, ``xyz`` (P,3) m,
    ``origin`` (P,3) m the sensor's position at each point. Each grid cell whose four
    corners are all present gives two triangles; ``rules`` and ``origin`` are not used
    by this stand-in."""
    scan = np.asarray(scan, dtype=np.int64)
    step = np.asarray(step, dtype=np.int64)
    if not (scan.shape == step.shape == xyz.shape[:1] == origin.shape[:1]):
        raise ValueError(
            f"grid_facets: scan {scan.shape}, step {step.shape}, xyz {xyz.shape} and "
            f"origin {origin.shape} differ in length"
        )
    if scan.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    finite = np.isfinite(xyz).all(axis=1)
    s0, k0 = int(scan.min()), int(step.min())
    width = int(step.max()) - k0 + 2
    key = (scan - s0) * width + (step - k0)
    order = np.argsort(key, kind="stable")
    keys = key[order]

    def find(k: np.ndarray) -> np.ndarray:
        """The index of the point at each grid key, -1 where there is none."""
        at = np.searchsorted(keys, k)
        ok = at < keys.size
        ok[ok] = keys[at[ok]] == k[ok]
        out = np.full(k.shape, -1, dtype=np.int64)
        out[ok] = order[at[ok]]
        out[ok] = np.where(finite[out[ok]], out[ok], -1)
        return out

    a = find(key)  # this point, -1 when NaN or a duplicate cell
    b, c, d = find(key + 1), find(key + width), find(key + width + 1)
    cell = (a >= 0) & (a == np.arange(a.size)) & (b >= 0) & (c >= 0) & (d >= 0)
    a, b, c, d = a[cell], b[cell], c[cell], d[cell]
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
