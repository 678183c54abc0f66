"""Choosing among cameras (acq.cloud.multiview)."""

from __future__ import annotations

import math

import numpy as np

from acq.camera.camera_models import KannalaBrandt, Pinhole
from acq.cloud.balance import Gains
from acq.cloud.multiview import choose, half_aperture, pick
from acq.cloud.views import Coloured

LENS = KannalaBrandt(width=780, height=582, fx=169.3, fy=169.3, cx=390.2, cy=291.1,
                     k=(0.0, 0.0, 0.0, 0.0), fov_deg=185.0)  # fmt: skip


def _view(coloured: list[bool], theta_deg: list[float], depth: list[float], dt: list[float]
          ) -> Coloured:  # fmt: skip
    n = len(coloured)
    c = np.array(coloured)
    return Coloured(
        rgb=np.zeros((n, 3), np.uint8), coloured=c, frame=np.where(c, 0, -1),
        dt_s=np.array(dt, np.float32), theta=np.radians(theta_deg).astype(np.float32),
        hidden=np.zeros(n, bool), frames_used=1, frames_failed=0,
        depth=np.array(depth, np.float32),
    )  # fmt: skip


def test_each_point_takes_the_camera_that_sees_it_best() -> None:
    a = _view([True, True, True, False], [10, 85, 30, 0], [5, 5, 5, 5], [0, 0, 0, 0])
    b = _view([True, True, True, False], [40, 20, 30, 0], [5, 5, 2.5, 5], [0, 0, 0, 0])
    rgb_a = np.full((4, 3), 10, np.uint8)
    rgb_b = np.full((4, 3), 200, np.uint8)
    got = choose([a, b], [rgb_a, rgb_b], [LENS, LENS], max_dt_s=0.1)
    # nearer the axis; away from the rim; the same angle but half the footprint; nobody
    assert got.camera.tolist() == [0, 1, 1, -1]
    assert got.coloured.tolist() == [True, True, True, False]
    assert got.rgb[:, 0].tolist() == [10, 200, 200, 0]
    # a frame far in time loses to one at the same angle and range
    far = _view([True], [20], [5], [0.09])
    near = _view([True], [20], [5], [0.0])
    assert choose([far, near], [rgb_a[:1], rgb_b[:1]], [LENS, LENS], 0.1).camera[0] == 1


def test_blend_weights_the_views_by_their_cost() -> None:
    a = _view([True, True], [20, 20], [5, 5], [0, 0])
    b = _view([True, False], [20, 0], [5, 5], [0, 0])
    rgb_a = np.array([[100, 100, 100], [100, 100, 100]], np.uint8)
    rgb_b = np.array([[200, 200, 200], [7, 7, 7]], np.uint8)
    got = choose([a, b], [rgb_a, rgb_b], [LENS, LENS], 0.1, blend=True)
    assert got.rgb[0].tolist() == [150, 150, 150]  # equal views: the mean
    assert got.rgb[1].tolist() == [100, 100, 100]  # only one sees it


def test_half_aperture_of_a_fisheye_and_a_pinhole() -> None:
    assert math.isclose(half_aperture(LENS), math.radians(92.5))
    pin = Pinhole(width=800, height=600, fx=400.0, fy=400.0, cx=400.0, cy=300.0)
    assert math.isclose(half_aperture(pin), math.atan(math.hypot(1.0, 0.75)))


def _random_view(rng: np.random.Generator, n: int, frames: int) -> Coloured:
    """A camera's colours of ``n`` points from ``frames`` frames: some points not seen,
    some hidden, some with a cost that is not finite, some at the other's very cost."""
    coloured = rng.random(n) < 0.7
    theta = rng.choice(np.radians([10.0, 30.0, 60.0, 90.0]), n).astype(np.float32)
    depth = rng.choice([2.0, 5.0, 0.0, np.inf], n, p=[0.45, 0.45, 0.05, 0.05]).astype(np.float32)
    return Coloured(
        rgb=rng.integers(0, 256, (n, 3)).astype(np.uint8)[:, ::-1],  # a view, as colouring gives
        coloured=coloured, frame=np.where(coloured, rng.integers(0, frames, n), -1),
        dt_s=rng.choice([0.0, 0.02], n).astype(np.float32), theta=theta,
        hidden=~coloured & (rng.random(n) < 0.5), frames_used=frames, frames_failed=0,
        depth=depth,
    )  # fmt: skip


def test_pick_gives_what_balancing_every_colour_then_choosing_gives() -> None:
    rng = np.random.default_rng(7)
    n, frames = 20_000, 12
    views = [_random_view(rng, n, frames) for _ in range(3)]
    gains = Gains([rng.normal(0.0, 0.3, (frames, 3)) for _ in views], 0, 0)
    for balanced in (True, False):
        rgbs = [gains.apply(c, v.rgb, v.frame) if balanced else v.rgb for c, v in enumerate(views)]
        want = choose(views, rgbs, [LENS] * 3, 0.1)
        scales = [gains.scales(c) if balanced else None for c in range(3)]
        got = pick(views, [LENS] * 3, 0.1, scales)
        assert np.array_equal(got.camera, want.camera)  # ties to the first camera, as argmin
        assert np.array_equal(got.rgb, want.rgb)  # the same bytes, rounding included
        assert np.array_equal(got.coloured, want.coloured)
        c = np.maximum(want.camera, 0)
        for name, fill in (("frame", -1), ("dt_s", np.nan), ("theta", np.nan)):
            field = np.stack([getattr(v, name) for v in views])[c, np.arange(n)]
            assert np.array_equal(getattr(got, name), np.where(want.coloured, field, fill),
                                  equal_nan=True), name  # fmt: skip
        hidden = np.any([v.hidden for v in views], axis=0) & ~want.coloured
        assert np.array_equal(got.hidden, hidden) and hidden.any()
    # a camera without frames' gains keeps its colours as taken
    empty = Gains([np.zeros((0, 3))] * 3, 0, 0)
    got = pick(views, [LENS] * 3, 0.1, [empty.scales(c) for c in range(3)])
    assert np.array_equal(got.rgb, choose(views, [v.rgb for v in views], [LENS] * 3, 0.1).rgb)
