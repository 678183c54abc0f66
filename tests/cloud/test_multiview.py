"""Choosing among cameras (acq.cloud.multiview)."""

from __future__ import annotations

import math

import numpy as np

from acq.camera.camera_models import KannalaBrandt, Pinhole
from acq.cloud.multiview import choose, half_aperture
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
