"""The preview: its z-buffer and block heights, both sides of the street, and which
camera coloured what."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from acq.cloud.points import Cloud
from acq.cloud.preview import (
    _BG,
    UNCOLOURED_RGB,
    _block_heights,
    _palette,
    _zbuffer,
    preview_image,
    preview_panels,
)

RED, BLUE, GREEN = (200, 30, 30), (30, 30, 200), (40, 180, 40)  # RGB


def test_the_nearest_block_wins_each_pixel_among_the_selected() -> None:
    rng = np.random.default_rng(4)
    n, (h, w), width, res = 400, (30, 50), 3, 0.1
    u = rng.uniform(-0.3, 5.3, n)
    v = rng.uniform(-0.3, 3.3, n)
    depth = rng.integers(0, 20, n).astype(float)  # ties: the earlier point wins
    depth[::37] = np.nan  # never drawn
    sel = rng.uniform(-1, 1, n)
    heights = rng.integers(1, 6, n).astype(np.int32)
    covering: dict[tuple[int, int], list[tuple[float, int]]] = {}
    for i in range(n):
        if not (-0.5 < sel[i] < 0.8) or math.isnan(depth[i]):
            continue
        c0 = math.floor(u[i] / res)
        top = math.floor((3.0 - v[i]) / res) - heights[i] // 2
        for r in range(max(top, 0), min(top + heights[i], h)):
            for c in range(max(c0, 0), min(c0 + width, w)):
                covering.setdefault((r, c), []).append((-depth[i], i))
    expect = np.full((h, w), -1)
    for (r, c), points in covering.items():
        expect[r, c] = min(points)[1]  # the nearest, then the earliest
    got = _zbuffer(h, w, u, 0.0, v, 3.0, res, width, heights, depth, -1.0, sel, -0.5, 0.8)
    assert (got >= 0).sum() > 200
    np.testing.assert_array_equal(got, expect)


def test_a_block_is_a_pixel_taller_than_its_scans_spacing_but_not_an_edge() -> None:
    v = np.array([0.0, 0.25, 0.5, 3.0, 3.25, 5.0, 6.0])
    scan = np.array([0, 0, 0, 0, 0, 0, 1], np.uint32)
    step = np.array([0, 1, 2, 3, 4, 9, 0], np.uint32)
    # 0.25 apart: 2 px; beside the 2.5 m jump: at most twice 0.25; no neighbour: 1 px
    heights = _block_heights(v, scan, step, 0.25, 20)
    np.testing.assert_array_equal(heights, [2, 2, 3, 3, 2, 1, 1])
    assert _block_heights(v, scan, step, 0.01, 20)[2] == 20  # at most ``most``


def _street(cameras: int) -> Cloud:
    """40 m of a street 10 m wide: per scan (every 0.2 m) a wall 6 m high at y = +5
    (red, camera 0), the ground (green, camera 0 on the left, camera 1 on the right)
    and a wall at y = -5 (blue, camera 1, its top metre not coloured); with one camera,
    what camera 1 would colour is not coloured."""
    h = np.linspace(6.0, 0.0, 30)
    g = np.linspace(4.9, -4.9, 50)
    y = np.concatenate([np.full(30, 5.0), g, np.full(30, -5.0)])
    z = np.concatenate([h, np.zeros(50), h[::-1]])
    rgb = np.array([RED] * 30 + [GREEN] * 50 + [BLUE] * 30, np.uint8)
    cam = np.array([0] * 30 + [0 if v > 0 else 1 for v in g] + [1] * 30, np.uint8)
    cam[-5:] = 255
    if cameras == 1:
        cam[cam == 1] = 255
    xs = np.arange(0.0, 40.0, 0.2)
    s, p = xs.size, y.size
    xyz = np.stack([np.repeat(xs, p), np.tile(y, s), np.tile(z, s)], axis=1)
    camera = np.tile(cam, s)
    coloured = camera != 255
    return Cloud(
        xyz=xyz,
        rgb=np.where(coloured[:, None], np.tile(rgb, (s, 1)), 0).astype(np.uint8),
        coloured=coloured,
        time_ns=np.arange(s * p, dtype=np.int64),
        scan=np.repeat(np.arange(s, dtype=np.uint32), p),
        step=np.tile(np.arange(p, dtype=np.uint32), s),
        intensity=np.ones(s * p, np.float32),
        dt_s=np.zeros(s * p, np.float32),
        scan_origin=np.stack([xs, np.zeros(s), np.ones(s)], axis=1),
        view_axis=np.array([0.0, 1.0, 0.0]),
        clock=np.zeros((0, 2), np.int64),
        camera=camera,
        camera_names=("left", "right")[:cameras],
    )


def _colours(img: np.ndarray) -> set[tuple[int, ...]]:
    """The BGR colours in ``img`` but the background."""
    return {tuple(int(c) for c in px) for px in img.reshape(-1, 3)} - {_BG}


def _bgr(rgb: tuple[int, int, int]) -> tuple[int, ...]:
    return rgb[::-1]


def test_each_side_of_the_street_shows_its_own_facade_and_camera() -> None:
    cloud = _street(cameras=2)
    p = preview_panels(cloud, metres_per_px=0.1)
    assert _colours(p.left) == {_bgr(RED), _bgr(GREEN)}
    assert _colours(p.right) == {_bgr(BLUE), _bgr(GREEN), UNCOLOURED_RGB}
    assert p.strips is not None and p.top_camera is not None
    assert _colours(p.strips[0]) == {_palette(0)}
    assert _colours(p.strips[1]) == {_palette(1)}
    # from above, left of the track up: the left camera's half above the right one's
    rows = [_colours(row[None]) for row in p.top_camera]
    drawn = [i for i, c in enumerate(rows) if c]
    half = (drawn[0] + drawn[-1]) / 2
    assert all(rows[i] == {_palette(0)} for i in drawn if i < half - 1)
    assert all(rows[i] <= {_palette(1), UNCOLOURED_RGB} for i in drawn if i > half + 1)
    shares = dict(p.cameras)
    assert list(shares) == ["left", "right", "none"]
    for k, name in enumerate(["left", "right"]):
        assert math.isclose(shares[name], float(np.mean(cloud.camera == k)))
    assert math.isclose(shares["none"], 5 / 110)


def test_with_one_camera_both_sides_are_drawn_the_far_one_grey() -> None:
    cloud = _street(cameras=1)
    p = preview_panels(cloud, metres_per_px=0.1)
    assert _colours(p.left) == {_bgr(RED), _bgr(GREEN)}
    assert _colours(p.right) == {UNCOLOURED_RGB}
    assert p.strips is None and p.top_camera is None
    assert [name for name, _ in p.cameras] == ["left", "none"]
    one = preview_image(cloud, metres_per_px=0.1)
    two = preview_image(_street(cameras=2), metres_per_px=0.1)
    panels = p.left.shape[0] + p.right.shape[0] + p.top.shape[0]
    assert one.shape[1:] == (p.left.shape[1], 3)
    bands = one.shape[0] - panels  # 4 captions, 34 px and 22 more a wrapped line
    assert bands >= 4 * 34 and (bands - 4 * 34) % 22 == 0
    # two cameras: a strip under each side, a legend, the view from above by camera (and
    # the longer captions' lines)
    more = two.shape[0] - one.shape[0] - 2 * 6 - math.ceil(p.top.shape[0] / 4)
    assert more >= 34 and (more - 34) % 22 == 0


def test_a_single_point_and_unplaced_points_are_drawn_without_warnings() -> None:
    cloud = _street(cameras=2)
    per_point = ("xyz", "rgb", "coloured", "time_ns", "scan", "step", "intensity", "dt_s")
    one = replace(cloud, **{k: getattr(cloud, k)[:1] for k in (*per_point, "camera")},
                  scan_origin=cloud.scan_origin[:1])  # fmt: skip
    nan = np.where(np.arange(cloud.size)[:, None] % 3 == 0, np.nan, cloud.xyz)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _colours(preview_image(one)) > {_bgr(RED)}
        img = preview_panels(replace(cloud, xyz=nan), metres_per_px=0.1)
    assert _colours(img.left) == {_bgr(RED), _bgr(GREEN)}
