"""acq.sim.mesh_views: renders of a mesh and a cloud against the ray-cast truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from acq.camera.camera_models import Pinhole
from acq.mesh.render import View, look_at
from acq.sim.mesh_views import compare, likeness, street_views, truth_image
from acq.sim.world import Street, Trajectory, solid_quad

BGR = (40, 160, 220)  # the quad's colour as the simulator holds it
RGB = np.array(BGR[::-1], np.uint8)


def test_likeness_counts_street_pixels_covered_and_within_tolerance() -> None:
    truth = np.full((10, 10, 3), 100, np.uint8)
    render = truth.copy()
    covered = np.ones((10, 10), bool)
    covered[:2] = False  # 20 px not covered
    render[2:4, :, 1] = 130  # 20 px off by 30 in one channel
    render[4, :, 0] = 124  # 10 px off by exactly 24: within
    street = np.ones((10, 10), bool)
    lk = likeness(render, covered, truth, street)
    assert lk.street == 100 and lk.covered == pytest.approx(0.8)
    assert lk.within == pytest.approx(60 / 80)
    mse = (20 * 30**2 + 10 * 24**2) / (80 * 3)
    assert lk.psnr_db == pytest.approx(10 * math.log10(255**2 / mse))
    street[:, 5:] = False  # only the left half is street
    assert likeness(render, covered, truth, street).covered == pytest.approx(0.8)
    same = likeness(truth, covered, truth, street)
    assert same.within == 1.0 and same.psnr_db == math.inf
    none = likeness(render, np.zeros_like(covered), truth, street)
    assert none.covered == 0.0 and math.isnan(none.within)


def _quad_scene() -> tuple[Street, View, np.ndarray]:
    """A 4 x 3 m plain quad standing 6 m ahead of a camera on an empty street."""
    street = Street(length_m=50.0)
    corners = np.array([[10.0, 4.0, 0.5], [14.0, 4.0, 0.5], [10.0, 4.0, 3.5], [14.0, 4.0, 3.5]])
    o, u, v = corners[0], corners[1] - corners[0], corners[2] - corners[0]
    street.add(solid_quad(tuple(o), tuple(u), tuple(v), BGR))  # type: ignore[arg-type]
    eye = np.array([12.0, -2.0, 2.0])
    view = View(Pinhole(160, 120, 100.0, 100.0, 79.5, 59.5), look_at(eye, [12.0, 4.0, 2.0]))
    return street, view, corners


def test_a_mesh_and_a_cloud_of_the_true_surface_agree_with_the_truth() -> None:
    street, view, corners = _quad_scene()
    truth, seen = truth_image(street, view)
    quad = np.zeros(seen.shape, bool)
    uv = view.pixels(corners)[:, :2]
    quad[math.ceil(uv[:, 1].min()) : math.floor(uv[:, 1].max()) + 1,
         math.ceil(uv[:, 0].min()) : math.floor(uv[:, 0].max()) + 1] = True  # fmt: skip
    assert np.abs(truth[quad].astype(int) - RGB).max() <= 1
    assert seen[quad].all() and seen[-1].all()  # the quad and the ground
    assert not seen[0, 0] and not seen[0, -1]  # the sky beside the quad
    faces = np.array([[0, 1, 3], [0, 3, 2]])
    a, b = np.meshgrid(np.linspace(0, 1, 81), np.linspace(0, 1, 61))
    points = (
        corners[0]
        + a.reshape(-1, 1) * (corners[1] - corners[0])
        + b.reshape(-1, 1) * (corners[2] - corners[0])
    )
    cloud = (points, np.tile(RGB, (points.shape[0], 1)))
    r = compare(street, {"v": view}, (corners, faces, np.tile(RGB, (4, 1))), cloud, 0.05)
    mesh, splatted = r.per_view[0]
    assert mesh.covered == pytest.approx(quad.sum() / seen.sum(), abs=0.01)
    assert mesh.within == 1.0 and mesh.psnr_db > 40
    # the squares of the rim's points spill up to a pixel over the ground below the quad
    assert splatted.within > 0.95
    assert splatted.covered == pytest.approx(quad.sum() / seen.sum(), abs=0.02)
    assert r.mesh == mesh  # one view: the pooled figures are its own
    wrong = compare(street, {"v": view}, (corners, faces, np.tile(RGB // 2, (4, 1))), cloud, 0.05)
    assert wrong.mesh.within == 0.0 and wrong.mesh.psnr_db < 20
    assert len(r.images) == 1 and r.images[0][1][quad].tolist() == [RGB.tolist()] * quad.sum()


def test_street_views_look_at_both_sides_and_obliquely_ahead() -> None:
    traj = Trajectory(curve_amplitude=0.0, vibration_rad=0.0)
    views = street_views(traj, [1.0, 2.0, 3.0])
    assert list(views) == ["left", "right", "oblique"]
    _, p = traj.poses(np.array([1.0, 2.0, 3.0]))
    for (name, view), pk in zip(views.items(), p, strict=True):
        eye = view.world_to_camera.inverse().translation
        axis = view.world_to_camera.rotation[2]  # the optical axis in the world
        assert eye[:2] == pytest.approx(pk[:2] - ([5.0, 0.0] if name == "oblique" else 0.0))
        if name == "oblique":
            assert eye[2] == pytest.approx(5.0) and axis[0] > 0.5 and axis[2] < -0.2
        else:
            assert eye[2] == pytest.approx(1.5)
            assert axis == pytest.approx([0.0, 1.0 if name == "left" else -1.0, 0.0], abs=1e-9)
    with pytest.raises(ValueError, match="three"):
        street_views(traj, [1.0, 2.0])
