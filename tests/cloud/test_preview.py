"""The preview's splatting: each pixel shows the nearest point whose block covers it."""

from __future__ import annotations

import numpy as np

from acq.cloud.preview import _BG, _splat


def test_the_nearest_block_wins_each_pixel() -> None:
    rng = np.random.default_rng(4)
    n, shape, width = 400, (30, 50), 3
    col, row = rng.integers(-3, 53, n), rng.integers(-3, 33, n)
    depth = rng.integers(0, 20, n).astype(float)  # ties: the earlier point wins
    colour = rng.integers(0, 255, (n, 3), dtype=np.uint8)
    heights = rng.integers(1, 6, n)
    expect = np.empty((*shape, 3), np.uint8)
    expect[:] = _BG
    for i in np.argsort(depth, kind="stable")[::-1]:  # farthest first, the nearest last
        top = row[i] - heights[i] // 2
        for r in range(max(top, 0), min(top + heights[i], shape[0])):
            for c in range(max(col[i], 0), min(col[i] + width, shape[1])):
                expect[r, c] = colour[i]
    np.testing.assert_array_equal(_splat(shape, col, row, depth, colour, width, heights), expect)
