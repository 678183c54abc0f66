"""The compiled projection core against the float64 camera models."""

from __future__ import annotations

import math

import numpy as np
import pytest

from acq.camera import projection
from acq.camera.camera_models import CameraModel, Equidistant, KannalaBrandt, Pinhole
from acq.geometry.rotations import rotation_from_euler
from acq.geometry.transforms import Rigid

KB = KannalaBrandt(780, 582, 169.0, 169.6, 390.2, 291.1, (0.007, -0.0012, 0.0003, -0.00004))
EQ = Equidistant.from_f(169.3, 390.2, 291.1, 780, 582, 185.0)
PH = Pinhole(1280, 960, 900.0, 905.0, 640.5, 478.2, (-0.28, 0.09, 0.0012, -0.0007, -0.012))
# A camera looking along the laser's -y with a lever arm: not the identity, on purpose.
EXTR = Rigid(rotation_from_euler(1.55, 0.02, -0.03), [0.35, -0.12, -0.2])
MODELS = [KB, EQ, PH]
IDS = ["kannala_brandt", "equidistant", "pinhole"]


def street_points(n: int, seed: int = 0) -> np.ndarray:
    """Laser-frame points at street distances, in and around the camera's view."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(1.0, 30.0, n)
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True) * d[:, None]


def reference(P: np.ndarray, model: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    return model.project(EXTR.inverse().apply(P.astype(np.float64)))


@pytest.mark.parametrize("model", MODELS, ids=IDS)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_matches_float64_reference_to_1e3_px(model: CameraModel, dtype: type) -> None:
    P = street_points(200_000).astype(dtype)
    uv, valid = projection.project(P, model, EXTR)
    uv_ref, valid_ref = reference(P, model)
    both = valid & valid_ref
    assert both.sum() > 20_000
    assert np.abs(uv[both] - uv_ref[both]).max() < 1e-3
    # Validity can only differ for points within a hair of the image border or fov.
    differ = valid != valid_ref
    assert differ.sum() <= 2


def test_eq2_direction_camera_axis_lands_on_principal_point() -> None:
    # P_laser = R @ P_camera + t: the camera's axis point at 5 m, seen from the laser.
    axis_point = EXTR.apply(np.array([[0.0, 0.0, 5.0]]))
    uv, valid = projection.project(axis_point, EQ, EXTR)
    assert valid[0]
    np.testing.assert_allclose(uv[0], [EQ.cx, EQ.cy], atol=1e-4)


def test_non_finite_points_are_invalid() -> None:
    P = np.array([[np.inf, 0, 0], [np.nan, 1, 1], [-np.inf, 2, 0], [0.0, 0.0, 0.0]])
    P = np.vstack([P, EXTR.apply(np.array([[0.5, 0.2, 5.0]]))])
    for model in MODELS:
        _, valid = projection.project(P, model, EXTR)
        assert valid.tolist() == [False, False, False, False, True]


def test_past_90_degrees_projects_onto_the_image() -> None:
    theta = np.radians(np.linspace(88.0, 92.4, 20))
    Pc = 6.0 * np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    uv, valid = projection.project(EXTR.apply(Pc), EQ, EXTR)
    assert valid.all()
    assert np.all(np.diff(uv[:, 0]) > 0)
    np.testing.assert_allclose(uv[:, 0] - EQ.cx, EQ.f * theta, atol=1e-3)


@pytest.mark.parametrize("model", [KB, PH], ids=["kannala_brandt", "pinhole"])
def test_colorize_nearest_and_bilinear(model: CameraModel) -> None:
    rng = np.random.default_rng(5)
    image = rng.integers(0, 256, (model.height, model.width, 3), dtype=np.uint8)
    P = street_points(50_000, seed=1)
    uv_ref, valid_ref = reference(P, model)
    colours, valid = projection.colorize(P, model, EXTR, image)
    # Nearest: exactly the pixel the float64 reference rounds to, away from pixel borders.
    safe = valid & valid_ref & (np.abs(uv_ref - np.round(uv_ref)) < 0.49).all(axis=1)
    iu, iv = np.round(uv_ref[safe]).astype(int).T
    np.testing.assert_array_equal(colours[safe], image[iv, iu])
    # Bilinear against a float64 numpy interpolation, within rounding.
    colours_b, valid_b = projection.colorize(P, model, EXTR, image, bilinear=True)
    np.testing.assert_array_equal(valid_b, valid)
    inner = valid & (uv_ref[:, 0] > 1) & (uv_ref[:, 0] < model.width - 2)
    inner &= (uv_ref[:, 1] > 1) & (uv_ref[:, 1] < model.height - 2)
    u, v = uv_ref[inner].T
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = (u - u0)[:, None], (v - v0)[:, None]
    img = image.astype(np.float64)
    expect = (1 - b) * ((1 - a) * img[v0, u0] + a * img[v0, u0 + 1]) + b * (
        (1 - a) * img[v0 + 1, u0] + a * img[v0 + 1, u0 + 1]
    )
    assert np.abs(colours_b[inner] - expect).max() <= 1.0


@pytest.mark.parametrize("model", [KB, PH], ids=["kannala_brandt", "pinhole"])
def test_colour_into_is_colorize_on_the_rows_it_is_given_far_from_the_origin(
    model: CameraModel,
) -> None:
    rng = np.random.default_rng(6)
    image = rng.integers(0, 256, (model.height, model.width, 3), dtype=np.uint8)
    P = street_points(20_000, seed=2)
    colours, valid = projection.colorize(P, model, EXTR, image, bilinear=True)
    uv_ref, _ = projection.project(P, model, EXTR)
    # the same scene 200 km from the origin: float32 alone would be off by centimetres
    far = np.array([2.0e5, -1.5e5, 30.0])
    idx = np.flatnonzero(rng.random(P.shape[0]) < 0.5)
    out = np.full((P.shape[0], 3), 7, dtype=np.uint8)
    seen = np.zeros(P.shape[0], dtype=bool)
    uv = np.full((P.shape[0], 2), np.nan, dtype=np.float32)
    pose = (EXTR.rotation, EXTR.translation + far)
    projection.colour_into(P + far, idx, model, pose, image, out, seen, uv)
    assert not seen[np.setdiff1d(np.arange(P.shape[0]), idx)].any()
    np.testing.assert_array_equal(seen[idx], valid[idx])
    both = idx[valid[idx]]
    assert np.abs(out[both].astype(int) - colours[both]).max() <= 1
    assert np.abs(uv[both] - uv_ref[both]).max() < 2e-3
    assert (out[~seen] == 7).all()


@pytest.mark.parametrize("bilinear", [True, False], ids=["bilinear", "nearest"])
@pytest.mark.parametrize("model", [KB, PH], ids=["kannala_brandt", "pinhole"])
def test_colour_into_reads_only_the_pixels_pixels_read_marks(
    model: CameraModel, bilinear: bool
) -> None:
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (model.height, model.width, 3), dtype=np.uint8)
    P = street_points(20_000, seed=3) + np.array([2.0e5, -1.5e5, 30.0])
    pose = (EXTR.rotation, EXTR.translation + np.array([2.0e5, -1.5e5, 30.0]))
    idx = np.flatnonzero(rng.random(P.shape[0]) < 0.3)
    rows = np.zeros(model.height, dtype=bool)
    cols = np.array([model.width, 0], dtype=np.int64)
    projection.pixels_read(P, idx, model, pose, rows, cols)
    assert 0 < rows.sum() < model.height and 0 <= cols[0] < cols[1] <= model.width
    # every pixel not marked changed: the colours must not
    scrambled = 255 - image
    scrambled[rows, cols[0] : cols[1]] = image[rows, cols[0] : cols[1]]
    got = []
    for img in (image, scrambled):
        out = np.zeros((P.shape[0], 3), dtype=np.uint8)
        seen = np.zeros(P.shape[0], dtype=bool)
        projection.colour_into(P, idx, model, pose, img, out, seen, bilinear=bilinear)
        got.append(out)
    assert seen.sum() > 300
    np.testing.assert_array_equal(got[0], got[1])


def test_colorize_grey_image_and_keeps_out_for_invalid_points() -> None:
    grey = np.full((EQ.height, EQ.width), 77, dtype=np.uint8)
    P = np.vstack([EXTR.apply(np.array([[0.0, 0.0, 4.0]])), [[np.inf, 0, 0]]])
    out = np.full((2, 1), 9, dtype=np.uint8)
    colours, valid = projection.colorize(P, EQ, EXTR, grey, out=out)
    assert colours is out
    assert valid.tolist() == [True, False]
    assert colours[:, 0].tolist() == [77, 9]


def test_colorize_refuses_an_image_of_another_size() -> None:
    with pytest.raises(ValueError, match="image is 100x50, the camera model 780x582"):
        projection.colorize(np.zeros((1, 3)), EQ, EXTR, np.zeros((50, 100, 3), np.uint8))
    with pytest.raises(ValueError, match="image is 100x50, the camera model 780x582"):
        projection.colour_into(
            np.zeros((1, 3)), np.zeros(1, np.int64), KB, (np.eye(3), np.zeros(3)),
            np.zeros((50, 100, 3), np.uint8), np.zeros((1, 3), np.uint8), np.zeros(1, bool),
        )  # fmt: skip


def test_atan_kernel_is_accurate_over_the_whole_range() -> None:
    # theta = atan2(rho, z) over [0, pi]: the custom float32 arctangent behind the kernels.
    th = np.linspace(0.0, math.pi - 1e-3, 100_001)  # pi itself has no azimuth
    Pc = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=1) * 3.0
    wide = KannalaBrandt(4000, 4000, 500.0, 500.0, 2000.0, 2000.0, fov_deg=359.0)
    uv, _ = projection.project(Pc, wide, Rigid.identity())
    assert np.abs((uv[:, 0] - 2000.0) / 500.0 - th).max() < 2e-6
