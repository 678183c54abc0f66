"""Image-circle detection (paper §3.3.2): the four estimators against simulated truth,
the known pitfalls (black level, vignetting, glare, truncation, non-square pixels), and
the real truncated fisheye images against their checkerboard reference."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from acq.calib import circle_fit, image_circle
from acq.calib.circle_fit import ImageCircle
from acq.calib.image_circle import CircleResult, ImageCircleError
from acq.errors import InputError
from acq.sim.fisheye_images import CircleTruth, corner_arc_images, fisheye_image

REFERENCE_PP = (384.8, 240.0)  # ../shared/data/README.md, fisheye/

Detected = tuple[np.ndarray, CircleTruth, CircleResult]


def centre_error(c: ImageCircle, t: CircleTruth) -> float:
    return math.hypot(c.cx - t.cx, c.cy - t.cy)


@pytest.fixture(scope="module")
def whole() -> Detected:
    """Whole circle, vignetted rim (0.25), 3 px soft edge, black 12 DN with 2 DN noise."""
    img, truth = fisheye_image(
        cx=391.3, cy=289.6, radius=271.4, edge_width=3.0, rim=0.25, black=12.0, noise=2.0
    )
    return img, truth, image_circle.detect([img])


@pytest.fixture(scope="module")
def truncated() -> Detected:
    """Cut at top and bottom (radius 326 px on 582 rows), like the real images."""
    img, truth = fisheye_image(cx=388.7, cy=292.4, radius=326.3, edge_width=2.5, seed=1, t=4.0)
    return img, truth, image_circle.detect([img])


def test_subpixel_meets_its_accuracy_on_a_vignetted_noisy_soft_rim(whole: Detected) -> None:
    _, truth, res = whole
    sub = res.estimates["subpixel"].circle
    assert res.circle == sub
    assert centre_error(sub, truth) < 0.2
    assert abs(sub.radius - truth.radius) < 0.3
    assert res.truncated == ()
    assert res.rays["inliers"] > 300


def test_each_estimator_within_its_own_bound(whole: Detected) -> None:
    """The paper's three are coarser: Canny pixels fitted by least squares, a whole-pixel
    Hough, and a barycentre whose threshold meets the faded rim somewhere in the soft
    edge."""
    _, truth, res = whole
    bounds = {"canny_fit": (0.3, 0.4), "hough": (2.5, 2.5), "barycentre": (3.0, 4.0)}
    for name, (dc, dr) in bounds.items():
        c = res.estimates[name].circle
        assert centre_error(c, truth) < dc, name
        assert abs(c.radius - truth.radius) < dr, name
    assert set(res.estimates) == set(image_circle.ESTIMATORS)
    d = res.to_dict()
    assert d["spread"]["centre_px"] == pytest.approx(res.spread_centre_px, abs=1e-3)
    assert set(d["estimators"]) == set(image_circle.ESTIMATORS)


def test_black_level_and_noise_are_measured_not_assumed(whole: Detected) -> None:
    _, truth, res = whole
    assert res.black_level == pytest.approx(truth.black, abs=0.6)
    assert res.noise == pytest.approx(truth.noise, rel=0.35)
    assert res.threshold > truth.black + 2 * truth.noise


def test_truncated_circle_fits_and_barycentre_is_flagged_biased(truncated: Detected) -> None:
    _, truth, res = truncated
    assert truth.truncated
    assert res.truncated == ("top", "bottom")
    sub = res.estimates["subpixel"].circle
    assert centre_error(sub, truth) < 0.2
    assert abs(sub.radius - truth.radius) < 0.3
    bary = res.estimates["barycentre"]
    assert bary.notes and "truncated" in bary.notes[0]
    # the bias is real: the cut-off caps make the disc's area too small
    assert bary.circle.radius < truth.radius - 3.0
    assert any("barycentre is biased" in w for w in res.warnings)
    # no rim point on the sensor edges
    pts = res.edges.points
    assert np.all((pts[:, 1] > 5) & (pts[:, 1] < truth.height - 6))


def test_saturated_glare_blooming_past_the_rim_is_not_taken_for_the_rim() -> None:
    """The blob's outer fall is bright inside and dark outside like a rim, but past the
    circle: no fitted rim point lies there."""
    img, truth = fisheye_image(glare_deg=20.0, glare_radius=16.0, seed=2, t=6.0)
    res = image_circle.detect([img])
    pts = res.edges.points[res.edges.inlier]
    ang = np.degrees(np.arctan2(pts[:, 1] - truth.cy, pts[:, 0] - truth.cx))
    dist = np.hypot(pts[:, 0] - truth.cx, pts[:, 1] - truth.cy)
    assert np.all(np.abs(dist[np.abs(ang - 20.0) < 6.0] - truth.radius) < 1.0)
    sub = res.circle
    assert centre_error(sub, truth) < 0.2
    assert abs(sub.radius - truth.radius) < 0.3
    # the bloom pulls the threshold estimators outwards there, not the sub-pixel fit
    assert centre_error(res.estimates["barycentre"].circle, truth) > centre_error(sub, truth)


def test_gradient_edge_does_not_move_with_vignetting_unlike_a_threshold() -> None:
    """Same scene, rim brightness 0.6 then 0.12: the sub-pixel radius stays put, the
    barycentre's (a fixed threshold above black) moves inwards."""
    radii = {}
    for rim in (0.6, 0.12):
        img, truth = fisheye_image(rim=rim, edge_width=4.0, noise=1.0, seed=3, t=3.0)
        res = image_circle.detect([img])
        radii[rim] = (res.circle.radius, res.estimates["barycentre"].circle.radius)
    assert abs(radii[0.6][0] - radii[0.12][0]) < 0.15
    assert abs(radii[0.6][0] - truth.radius) < 0.3
    assert radii[0.6][1] - radii[0.12][1] > 0.5


def test_ellipse_for_non_square_pixels() -> None:
    img, truth = fisheye_image(radius=262.0, aspect=1.07, seed=1, t=9.0)
    res = image_circle.detect([img], ellipse=True)
    c = res.circle
    assert centre_error(c, truth) < 0.2
    assert abs(c.rx - truth.a) < 0.3 and abs(c.ry - truth.b) < 0.3
    assert res.to_dict()["ry"] == pytest.approx(c.ry, abs=1e-3)
    # a circle cannot fit it: its rim points disagree by a pixel or more
    circ = image_circle.detect([img]).estimates["subpixel"]
    assert circ.rms_px > 3 * res.estimates["subpixel"].rms_px


def test_several_images_are_pooled() -> None:
    imgs, truth = [], None
    for seed, t in ((0, 2.0), (1, 7.0), (2, 12.0)):
        img, truth = fisheye_image(cx=385.4, cy=296.8, radius=268.2, seed=seed, t=t)
        imgs.append(img)
    assert truth is not None
    res = image_circle.detect(imgs)
    assert len(res.per_image) == 3
    assert set(res.edges.image.tolist()) == {0, 1, 2}
    assert centre_error(res.circle, truth) < 0.1
    assert abs(res.circle.radius - truth.radius) < 0.2
    assert res.estimates["subpixel"].n_points > max(e["subpixel"].n_points for e in res.per_image)


def test_fits_recover_exact_points_and_ransac_drops_outliers() -> None:
    rng = np.random.default_rng(5)
    phi = rng.uniform(0.3, 2.6, 200)  # an arc, as on a truncated circle
    c = ImageCircle(300.5, 250.25, 280.0, 290.0)
    pts = np.stack([c.cx + c.rx * np.cos(phi), c.cy + c.ry * np.sin(phi)], axis=1)
    fit = circle_fit.fit_conic(pts, ellipse=True)
    assert np.allclose([fit.cx, fit.cy, fit.rx, fit.ry], [c.cx, c.cy, c.rx, c.ry], atol=1e-6)
    circle = ImageCircle(300.5, 250.25, 280.0, 280.0)
    pts = np.stack([circle.cx + 280 * np.cos(phi), circle.cy + 280 * np.sin(phi)], axis=1)
    pts += rng.normal(0, 0.1, pts.shape)
    bad = rng.random(len(pts)) < 0.3
    pts[bad] -= rng.uniform(5, 30, (int(bad.sum()), 1)) * (pts[bad] - (300.5, 250.25)) / 280
    inl = circle_fit.ransac_fit(pts, 1.0)
    assert np.array_equal(inl, ~bad)
    refined, res, sigma = circle_fit.refine_fit(pts[inl], circle_fit.fit_conic(pts[inl]))
    # within 4 of its own standard errors (an arc fixes the centre less than a circle)
    assert abs(refined.cx - 300.5) < 4 * sigma[0] and abs(refined.cy - 250.25) < 4 * sigma[1]
    assert abs(refined.rx - 280.0) < 4 * sigma[2]
    assert np.std(res) == pytest.approx(0.1, rel=0.3) and all(s < 0.1 for s in sigma)
    assert np.allclose(refined.residuals(pts[inl]), res)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ImageCircleError, match=r"^image 1: no image circle found: .*black"):
        image_circle.detect([np.full((120, 160), 7, np.uint8)])
    a = np.zeros((100, 100), np.uint8)
    with pytest.raises(ImageCircleError, match=r"^b\.png: 100x90 px, a\.png 100x100"):
        image_circle.detect([a, np.zeros((90, 100), np.uint8)], names=["a.png", "b.png"])
    with pytest.raises(ImageCircleError, match="no images"):
        image_circle.detect([])


def _photo(kind: str) -> np.ndarray:
    """A 640x480 image that is no fisheye's: nothing dark around a bright disc."""
    v, u = np.mgrid[0:480, 0:640]
    if kind == "uniform":
        return np.full((480, 640, 3), 128, np.uint8)
    if kind == "gradient":
        return np.repeat((u * 255 // 639).astype(np.uint8)[:, :, None], 3, axis=2)
    if kind == "checkerboard":
        return (((u // 40 + v // 40) % 2) * 255).astype(np.uint8)
    if kind == "rectangle":
        return np.where((abs(u - 320) < 200) & (abs(v - 240) < 150), 200, 0).astype(np.uint8)
    if kind == "line":
        return np.where(abs(u - v) < 3, 255, 0).astype(np.uint8)
    return np.full((1, 1), 200, np.uint8)  # 1x1


@pytest.mark.parametrize(
    ("kind", "why"),
    [
        ("uniform", "no dark surround: even the darkest part of its border is at 128 DN"),
        ("gradient", "too few rim edge pixels"),
        ("checkerboard", "do not outline a circle on the sensor"),
        ("rectangle", "do not outline a circle on the sensor"),
        ("line", "do not outline a circle on the sensor"),  # OpenCV failed on its circle
        ("1x1", "1x1 px is too small to hold one"),
    ],
)
def test_an_image_without_a_circle_is_named_with_why(kind: str, why: str) -> None:
    fisheye, _ = fisheye_image(640, 480, 320.0, 240.0, radius=220.0, seed=5)
    images, names = [fisheye, _photo(kind)], ["fisheye.png", f"{kind}.png"]
    if kind == "1x1":
        images, names = images[1:], names[1:]
    with pytest.raises(ImageCircleError) as e:
        image_circle.detect(images, names=names)
    assert str(e.value).startswith(f"{kind}.png: ")
    assert "no image circle found: " in str(e.value) and why in str(e.value)
    assert isinstance(e.value, InputError)


def real_images(shared_dir: Path) -> list[np.ndarray]:
    from acq.calib.fisheye_calib import read_images

    folder = shared_dir / "data" / "fisheye"
    paths = sorted(folder.glob("Fisheye2_*.jpg"))
    if not paths:
        pytest.skip(f"{folder} has no Fisheye2_*.jpg: the real fisheye images are not here")
    return read_images(paths)


def test_real_truncated_images_centre_near_reference_principal_point(shared_dir: Path) -> None:
    res = image_circle.detect(real_images(shared_dir))
    assert (res.width, res.height) == (748, 480)
    assert res.truncated == ("top", "bottom")
    c = res.circle
    assert math.hypot(c.cx - REFERENCE_PP[0], c.cy - REFERENCE_PP[1]) < 2.0
    assert 286.0 < c.radius < 294.0
    # every image alone lands within 2.5 px too (the rims are soft and vignetted); on each
    # the fits agree within 1.5 px, or the result says why the one off is not trusted
    centres = np.array([(e["subpixel"].circle.cx, e["subpixel"].circle.cy) for e in res.per_image])
    assert np.all(np.hypot(*(centres - REFERENCE_PP).T) < 2.5)
    for i, est in enumerate(res.per_image):
        sub = est["subpixel"].circle
        for k in ("canny_fit", "hough"):
            c = est[k].circle
            if max(centre_error_px(c, sub), abs(c.radius - sub.radius)) > 1.5:
                assert est[k].notes
                (why,) = [w for w in res.warnings if w.startswith(f"image {i + 1}: {k} is ")]
                assert est[k].notes[0] in why
    assert any("barycentre is biased" in w for w in res.warnings)
    assert not any("no reason found" in w for w in res.warnings)


def centre_error_px(a: ImageCircle, b: ImageCircle) -> float:
    return math.hypot(a.cx - b.cx, a.cy - b.cy)


@pytest.mark.parametrize(("width", "height", "seed"), [(780, 582, 0), (1032, 778, 1)])
def test_corner_arcs_beside_clipped_pixels_under_a_glare_halo(
    width: int, height: int, seed: int
) -> None:
    """A circle larger than the sensor, its rim only four corner arcs (under 25 % of it),
    clipped at 255 beside the rim, a wide halo outside, JPEG, a time stamp in a corner:
    two images of one camera together, centre within 2 px and radius within 3 px."""
    images, truth = corner_arc_images(np.random.default_rng(seed), 2, width, height)
    arcs, span = truth.visible_arcs()
    assert arcs >= 4 and span < 0.25
    res = image_circle.detect(images)
    assert res.truncated == ("left", "right", "top", "bottom")
    assert res.rays["clipped_inliers"] > 0.5 * res.rays["inliers"]  # clipped rims used
    for name in ("subpixel", "canny_fit", "hough"):
        c = res.estimates[name].circle
        assert centre_error(c, truth) < 2.0, name
        assert abs(c.radius - truth.radius) < 3.0, name


def test_a_circle_covering_the_whole_sensor_says_so() -> None:
    """Bright (clipped) and ordinary scenes reaching every edge: not "the image is black"."""
    bright, _ = fisheye_image(radius=700.0, rim=0.8, flare=600.0, gain=3.0)
    dim, _ = fisheye_image(radius=700.0, rim=0.8)
    for img in (bright, dim):
        with pytest.raises(ImageCircleError, match=r"no dark surround.*covers the whole sensor"):
            image_circle.detect([img])
