"""A simulated pushbroom scanner sweeping planes, as plain arrays: each point the exact
hit of its beam (the tests of acq.mesh)."""

from __future__ import annotations

import numpy as np

SPEED_M = 0.14  # the vehicle's advance between scans: 20 km/h at 40 scans/s
HEIGHT_M = 2.0  # the scanner's height


def sweep(
    n_scans: int,
    beams_deg: np.ndarray,
    plane_n: tuple[float, float, float] = (0.0, -1.0, 0.0),
    plane_d: float = -5.0,
    advance_m: float = SPEED_M,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(scan, step, xyz, origin) of a scanner moving along +x at HEIGHT_M, its beams in
    the y-z plane at ``beams_deg`` above +y, hitting the plane n . p = d (default: a wall
    at y = 5 m), ``advance_m`` apart. Rays that miss (or hit behind) are left out."""
    s, k = np.meshgrid(np.arange(n_scans), np.arange(beams_deg.size), indexing="ij")
    s, k = s.ravel(), k.ravel()
    origin = np.stack([s * advance_m, np.zeros(s.size), np.full(s.size, HEIGHT_M)], axis=1)
    a = np.radians(beams_deg[k])
    ray = np.stack([np.zeros(s.size), np.cos(a), np.sin(a)], axis=1)
    n = np.asarray(plane_n, float)
    with np.errstate(divide="ignore"):
        t = (plane_d - origin @ n) / (ray @ n)
    hit = np.isfinite(t) & (t > 0)
    xyz = origin + t[:, None] * ray
    return s[hit], k[hit], xyz[hit], origin[hit]


def beams(lo: float, hi: float, step: float = 0.25) -> np.ndarray:
    return np.arange(lo, hi + step / 2, step)
