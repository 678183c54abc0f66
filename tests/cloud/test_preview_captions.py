"""The preview's captions: each one readable whole, wrapped before the scale bar at its
right rather than struck through by it."""

from __future__ import annotations

import numpy as np

from acq.cloud.preview import _TEXT, preview_image
from tests.cloud.test_preview import _street


def _bars(img: np.ndarray, length: int) -> list[tuple[int, int, int]]:
    """(row, first, last column) of each horizontal run of the text colour ``length``
    px long (+-2): the 10 m scale bars."""
    found = []
    for y, row in enumerate(np.all(img == np.array(_TEXT, np.uint8), axis=2)):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
        for x0, x1 in zip(edges[::2], edges[1::2], strict=True):
            if abs((x1 - x0) - length) <= 2:
                found.append((y, int(x0), int(x1)))
    return found


def test_no_caption_runs_into_its_scale_bar() -> None:
    res = 0.04  # 40 m of street: 1000 px wide, the 10 m bar 250 px
    img = preview_image(_street(cameras=2), metres_per_px=res)
    assert img.shape[1] > 900
    bars = _bars(img, round(10 / res))
    rows = sorted({y for y, _, _ in bars})
    assert len({y // 10 for y in rows}) == 3, rows  # left, right and top views (2 px thick)
    lit = np.any(img > 120, axis=2)  # text and bar pixels on the dark caption strips
    for y, x0, x1 in bars:
        around = lit[y - 14 : y + 10, x0 - 10 : x1 + 3].copy()  # the label "10 m" after it
        around[12:17] = False  # the bar itself (this row, the one beside it, antialiasing)
        assert not around.any(), (y, x0, x1)
