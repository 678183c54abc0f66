"""acq.sim.mesh_views: renders of a mesh and a cloud against the ray-cast truth."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from acq.camera.camera_models import Pinhole
from acq.mesh import files
from acq.mesh.render import View, look_at
from acq.mesh.texture import Atlas
from acq.sim.mesh_views import (
    compare,
    likeness,
    picture,
    read_mesh,
    read_textured_mesh,
    resolution_ceiling,
    street_views,
    truth_image,
)
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


def test_a_textured_glb_reads_back_upright_and_renders_as_the_truth(tmp_path: Path) -> None:
    """The quad written by acq.mesh.files as a textured glb whose atlas holds the quad's
    colour in its upper half and half of it in its lower half, the quad's corners on the
    upper half: read back, rendered, it matches the truth (v read upside down would show
    the lower half)."""
    street, view, corners = _quad_scene()
    image = np.zeros((32, 32, 3), np.uint8)  # halves on JPEG's 16-px blocks: no ringing
    image[:16], image[16:] = RGB, RGB // 2
    faces = np.array([[0, 1, 3], [0, 3, 2]])
    corner_uv = np.array([[0.1, 0.6], [0.9, 0.6], [0.1, 0.95], [0.9, 0.95]], np.float32)  # v up
    atlas = Atlas(image[..., ::-1].copy(), corner_uv[faces], np.ones(2, bool), np.arange(2))  # BGR
    glb = tmp_path / "quad.glb"
    files.write(glb, corners, np.zeros((4, 3), np.uint8), faces, texture=atlas)

    mesh = read_textured_mesh(glb)
    assert np.allclose(mesh.xyz[mesh.faces], corners[faces], atol=1e-5)
    assert np.allclose(mesh.uv, corner_uv[faces], atol=1e-6)
    assert np.abs(mesh.image[4].astype(int) - RGB).max() <= 6  # JPEG
    # glTF itself holds v down, from the image's top: 1 - v
    gltf = pygltflib.GLTF2.load(glb)
    acc = gltf.accessors[gltf.meshes[0].primitives[0].attributes.TEXCOORD_0]
    view_ = gltf.bufferViews[acc.bufferView]
    raw = gltf.binary_blob()[view_.byteOffset + (acc.byteOffset or 0) :][: acc.count * 8]
    stored = np.frombuffer(raw, np.float32).reshape(-1, 2)
    assert np.allclose(stored[:, 1], 1.0 - corner_uv[faces].reshape(-1, 2)[:, 1], atol=1e-6)

    plain = (corners, faces, np.tile(RGB, (4, 1)))
    cloud = (corners, np.tile(RGB, (4, 1)))
    r = compare(street, {"v": view}, plain, cloud, 0.05, textured=mesh)
    assert r.textured is not None and r.textured == r.textured_views[0][1]
    assert r.textured.within == 1.0 and r.textured.covered == pytest.approx(r.mesh.covered)
    quad = r.images[0][1].any(axis=2)  # the vertex-coloured quad's pixels
    assert np.abs(r.textured_views[0][0][quad].astype(int) - RGB).max() <= 6
    # the picture gets a panel more per view
    assert picture(r, "t").shape[1] == 4 * view.shape[1]
    assert picture(compare(street, {"v": view}, plain, cloud, 0.05), "t").shape[1] == 3 * 160
    with pytest.raises(ValueError, match="vertex colours"):
        read_mesh(glb)
    files.write(tmp_path / "plain.glb", *plain[:1], plain[2], faces)
    with pytest.raises(ValueError, match="texture"):
        read_textured_mesh(tmp_path / "plain.glb")


@pytest.mark.filterwarnings("error")
def test_an_atlas_over_pillows_89_megapixels_reads_without_a_warning(tmp_path: Path) -> None:
    """acq mesh writes atlases up to MAX_SIDE a side; Pillow would warn past 89 Mpx."""
    from PIL import Image

    side = 9600  # 92 Mpx, one colour: a small JPEG
    corners = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]])
    atlas = Atlas(np.full((side, side, 3), 90, np.uint8), np.zeros((1, 3, 2), np.float32),
                  np.ones(1, bool), np.zeros(1, np.int64))  # fmt: skip
    files.write(tmp_path / "big.glb", corners, np.zeros((3, 3), np.uint8), np.array([[0, 1, 2]]),
                texture=atlas)  # fmt: skip
    limit = Image.MAX_IMAGE_PIXELS
    mesh = read_textured_mesh(tmp_path / "big.glb")
    assert mesh.image.shape == (side, side, 3) and Image.MAX_IMAGE_PIXELS == limit


def test_the_resolution_ceiling_falls_as_the_street_is_seen_coarser() -> None:
    """At the view's own resolution the truth is its own ceiling; seen at half of it, the
    edges between colours blur (the generated street: facades, windows, poles)."""
    street = Street.generate(0, length_m=80.0, pattern_at=None)
    traj = Trajectory(speed=20 / 3.6, x0=0.0, y0=1.5, curve_amplitude=0.0)
    views = street_views(traj, [3.0, 4.0, 5.0], width=160, height=120)
    f = next(iter(views.values())).camera.fx
    own = resolution_ceiling(street, views, f)[1]
    assert own.within == 1.0 and own.covered == 1.0
    each, half = resolution_ceiling(street, views, f / 2)
    quarter = resolution_ceiling(street, views, f / 4)[1]
    assert 0.5 < quarter.within < half.within < 0.99
    assert quarter.psnr_db < half.psnr_db
    assert list(each) == list(views) and all(lk.within < 1.0 for lk in each.values())
