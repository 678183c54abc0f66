"""A long drive's coloured cloud, synthesised part by part as ``acq colorize`` writes it
(for the cloud writers' memory bench and tests): a profile scanner on a vehicle along a
curved line (an arc of 10 km radius) through a street of 16 m between walls, with the
2-camera demo rig's density.

Each part has the fields :meth:`acq.cloud.copc.CopcStream.write` takes, in time order;
the same ``seed`` gives the same points.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

__all__ = ["POINTS_PER_S", "SPEED", "parts"]

POINTS_PER_S = 35_000  # the demo's 340 k points per 10 s, rounded: 126 M an hour
SPEED = 8.33  # m/s: 30 km an hour
_SCAN_HZ = 25
_RADIUS = 10_000.0  # m, of the arc driven
_HALF_STREET, _SCANNER_UP = 8.0, 2.0  # m: walls each side, the scanner above the road
_START_UTC = 1.7e9  # s


def parts(seconds: float, part_s: float = 10.0, seed: int = 0) -> Iterator[tuple[np.ndarray, ...]]:
    """The drive's points ``part_s`` seconds at a time: (xyz (N,3) m, rgb (N,3) uint8,
    utc_s, intensity, scan, coloured, camera (0, 1; 255 none), frame (-1 none))."""
    per_scan = POINTS_PER_S // _SCAN_HZ
    scans = round(seconds * _SCAN_HZ)
    step = max(1, round(part_s * _SCAN_HZ))
    for first in range(0, scans, step):
        rng = np.random.default_rng([seed, first])
        scan = np.repeat(np.arange(first, min(first + step, scans)), per_scan)
        n = scan.size
        t = scan / _SCAN_HZ + np.tile(np.arange(per_scan) / (per_scan * _SCAN_HZ), n // per_scan)
        s = SPEED * t  # m along the arc
        heading = s / _RADIUS
        # the profile across the road: angle from straight down, to the road or a wall
        phi = np.tile(np.linspace(-2.3, 2.3, per_scan), n // per_scan)
        down, side = np.cos(phi), np.sin(phi)
        with np.errstate(divide="ignore"):
            r = np.minimum(
                np.where(down > 0, _SCANNER_UP / np.abs(down), np.inf),
                _HALF_STREET / np.abs(side),
            )
        r = np.minimum(r, 30.0) + rng.normal(0, 0.01, n)
        lateral, up = r * side, -r * down + _SCANNER_UP
        x = _RADIUS * np.sin(heading) - lateral * np.sin(heading)
        y = _RADIUS * (1 - np.cos(heading)) + lateral * np.cos(heading)
        z = 5 * np.sin(s / 500) + up
        xyz = np.stack([x + 500_000.0, y + 5_400_000.0, z + 200.0], axis=1)
        coloured = rng.random(n) < 0.6
        camera = np.where(coloured, (side > 0).astype(np.uint8), 255).astype(np.uint8)
        frame = np.where(coloured, (t * 10).astype(np.int32), -1).astype(np.int32)
        rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
        intensity = rng.uniform(0, 4000, n).astype(np.float32)
        yield xyz, rgb, _START_UTC + t, intensity, scan.astype(np.uint32), coloured, camera, frame
