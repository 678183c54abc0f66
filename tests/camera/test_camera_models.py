"""Camera models against OpenCV and against themselves (round trips, validity)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.camera.camera_models import Equidistant, KannalaBrandt, Pinhole, from_dict

KB = KannalaBrandt(
    width=780, height=582, fx=169.0, fy=170.2, cx=390.2, cy=291.1,
    k=(0.007, -0.0012, 0.0003, -0.00004), fov_deg=185.0,
)  # fmt: skip
EQ = Equidistant.from_f(169.3, 390.2, 291.1, 780, 582, 185.0)
PH = Pinhole(
    width=1280, height=960, fx=900.0, fy=905.0, cx=640.5, cy=478.2,
    dist=(-0.28, 0.09, 0.0012, -0.0007, -0.012),
)  # fmt: skip


def rays_at(theta: np.ndarray, phi: np.ndarray, dist: float = 7.0) -> np.ndarray:
    """Camera-frame points at angle theta from the axis, azimuth phi, distance dist."""
    return dist * np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1
    )


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    # atan2 of cross and dot is accurate for tiny angles, unlike arccos.
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))


def test_kannala_brandt_equals_opencv_fisheye_below_85_degrees() -> None:
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.0, math.radians(85.0), 5000)
    phi = rng.uniform(-math.pi, math.pi, 5000)
    P = rays_at(theta, phi, 1.0) * rng.uniform(0.5, 40.0, (5000, 1))
    ours, _ = KB.project(P)
    K = np.array([[KB.fx, 0, KB.cx], [0, KB.fy, KB.cy], [0, 0, 1]])
    cv, _ = cv2.fisheye.projectPoints(
        P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.array(KB.k)
    )
    assert np.abs(ours - cv.reshape(-1, 2)).max() < 1e-6


def test_pinhole_equals_opencv() -> None:
    rng = np.random.default_rng(2)
    P = np.column_stack(
        [rng.uniform(-3, 3, 5000), rng.uniform(-2, 2, 5000), rng.uniform(2, 9, 5000)]
    )
    ours, _ = PH.project(P)
    K = np.array([[PH.fx, 0, PH.cx], [0, PH.fy, PH.cy], [0, 0, 1]])
    cv, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, np.array(PH.dist))
    assert np.abs(ours - cv.reshape(-1, 2)).max() < 1e-6


def test_radius_keeps_growing_past_90_degrees_where_opencv_mirrors() -> None:
    theta = np.radians(np.linspace(80.0, 92.5, 60))
    P = rays_at(theta, np.zeros_like(theta))
    uv, valid = EQ.project(P)
    r = np.hypot(uv[:, 0] - EQ.cx, uv[:, 1] - EQ.cy)
    assert valid.all()
    assert np.all(np.diff(r) > 0)
    np.testing.assert_allclose(r, EQ.f * theta, rtol=0, atol=1e-9)
    # OpenCV's fisheye uses atan(r) of x/z: a point at 92.5 degrees lands at 87.5.
    K = np.array([[EQ.fx, 0, EQ.cx], [0, EQ.fy, EQ.cy], [0, 0, 1]])
    cv, _ = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.zeros(4))
    r_cv = np.hypot(cv[:, 0, 0] - EQ.cx, cv[:, 0, 1] - EQ.cy)
    beyond = theta > math.pi / 2
    assert np.all(np.abs(r_cv[beyond] - r[beyond]) > 1.0)


@pytest.mark.parametrize("model", [KB, EQ, PH], ids=["kannala_brandt", "equidistant", "pinhole"])
def test_unproject_inverts_project_to_1e9_rad(model: KannalaBrandt | Pinhole) -> None:
    rng = np.random.default_rng(3)
    if isinstance(model, Pinhole):
        theta = rng.uniform(0.0, math.radians(30.0), 20000)
    else:
        theta = rng.uniform(0.0, model.theta_max, 20000)
    P = rays_at(theta, rng.uniform(-math.pi, math.pi, theta.size))
    uv, valid = model.project(P)
    rays = model.unproject(uv[valid])
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    assert angle_between(rays, P[valid]).max() < 1e-9
    assert valid.mean() > 0.5


@settings(max_examples=200, deadline=None)
@given(
    theta=st.floats(0.0, math.radians(92.5)),
    phi=st.floats(-math.pi, math.pi),
    dist=st.floats(0.05, 1000.0),
)
def test_round_trip_property(theta: float, phi: float, dist: float) -> None:
    P = rays_at(np.array([theta]), np.array([phi]), dist)
    uv, _ = KB.project(P)
    assert angle_between(KB.unproject(uv), P)[0] < 1e-9


def test_validity_behind_outside_fov_and_outside_image() -> None:
    P = np.array(
        [
            [0.0, 0.0, 5.0],  # on the axis: valid
            [0.0, 0.0, -5.0],  # straight behind
            rays_at(np.radians([93.0]), np.zeros(1))[0],  # just outside 185 degrees
            rays_at(np.radians([92.0]), np.zeros(1))[0],  # just inside, on the sensor (u < 780)
            [0.0, 0.0, 0.0],  # the centre of projection itself
        ]
    )
    _, valid = EQ.project(P)
    assert valid.tolist() == [True, False, False, True, False]
    # A truncated image circle (as in ../shared/data/fisheye): inside the fov, off the sensor.
    cut = Equidistant.from_f(209.0, 384.8, 240.0, 748, 480, 185.0)
    _, valid_cut = cut.project(rays_at(np.radians([92.0, 92.0]), np.array([0.0, math.pi / 2])))
    assert valid_cut.tolist() == [True, False]
    _, valid_ph = PH.project(np.array([[0.1, 0.1, 2.0], [0.1, 0.1, -2.0], [50.0, 0.0, 1.0]]))
    assert valid_ph.tolist() == [True, False, False]


def test_pinhole_point_past_the_distortion_fold_is_invalid() -> None:
    # 68 degrees off-axis: the radial polynomial has folded back, and OpenCV puts the
    # point inside the image, left of centre, though it lies far to the right.
    P = np.array([[2.5, 0.0, 1.0]])
    K = np.array([[PH.fx, 0, PH.cx], [0, PH.fy, PH.cy], [0, 0, 1]])
    cv, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, np.array(PH.dist))
    assert 0 < cv[0, 0, 0] < PH.cx
    uv, valid = PH.project(P)
    assert uv[0, 0] == pytest.approx(cv[0, 0, 0])
    assert not valid[0]


def test_equidistant_is_the_three_parameter_model() -> None:
    assert EQ.f == EQ.fx == EQ.fy
    with pytest.raises(ValueError, match="square pixels"):
        Equidistant(width=10, height=10, fx=1.0, fy=2.0, cx=5, cy=5)
    with pytest.raises(ValueError, match="no distortion"):
        Equidistant(width=10, height=10, fx=1.0, fy=1.0, cx=5, cy=5, k=(0.1, 0, 0, 0))


def test_lens_polynomial_that_folds_back_is_refused() -> None:
    with pytest.raises(ValueError, match="not increasing"):
        KannalaBrandt(width=10, height=10, fx=1.0, fy=1.0, cx=5, cy=5, k=(-0.5, 0, 0, 0))


@pytest.mark.parametrize("model", [KB, EQ, PH], ids=["kannala_brandt", "equidistant", "pinhole"])
def test_dict_round_trip(model: KannalaBrandt | Pinhole) -> None:
    again = from_dict(model.to_dict())
    assert again == model
    assert type(again) is type(model)
