"""acq.mesh.render: triangles and points drawn into a virtual pinhole, on plain arrays."""

from __future__ import annotations

import numpy as np
import pytest

from acq.camera.camera_models import Pinhole
from acq.geometry.transforms import Rigid
from acq.mesh.render import View, look_at, rasterise, render_mesh, render_textured, splat

RGB = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)


def view(size: int = 64, f: float = 100.0, cx: float = 0.0, cy: float = 0.0) -> View:
    """Identity pose: the camera at the world origin looking along +z."""
    return View(Pinhole(size, size, f, f, cx, cy), Rigid.identity())


def at_pixels(v: View, uv: np.ndarray, z: np.ndarray) -> np.ndarray:
    """World points (identity pose) seen at pixels ``uv`` (N,2) at depths ``z`` (N,)."""
    c = v.camera
    return np.stack([(uv[:, 0] - c.cx) * z / c.fx, (uv[:, 1] - c.cy) * z / c.fy, z], axis=1)


def test_a_triangle_covers_exactly_the_pixel_centres_inside_it() -> None:
    v = view()
    uv = np.array([[9.5, 9.5], [50.7, 9.5], [9.5, 50.7]])
    xyz = at_pixels(v, uv, np.full(3, 2.0))
    img, mask = render_mesh(v, xyz, np.array([[0, 1, 2]]), RGB)
    y, x = np.mgrid[0:64, 0:64]
    expected = (x >= 10) & (y >= 10) & (x + y <= 60)
    assert np.array_equal(mask, expected)
    assert (img[~mask] == 0).all()
    # either winding draws the same pixels
    _, mask2 = render_mesh(v, xyz, np.array([[0, 2, 1]]), RGB)
    assert np.array_equal(mask2, expected)


def test_colours_are_interpolated_across_a_facet_facing_the_camera() -> None:
    v = view()
    uv = np.array([[9.5, 9.5], [50.7, 9.5], [9.5, 50.7]])
    img, mask = render_mesh(v, at_pixels(v, uv, np.full(3, 3.0)), np.array([[0, 1, 2]]), RGB)
    for x, y in [(10, 10), (30, 12), (12, 40), (25, 25)]:
        # screen barycentrics of the pixel centre (a facet at one depth: affine)
        A = np.array([[uv[0, 0], uv[1, 0], uv[2, 0]], [uv[0, 1], uv[1, 1], uv[2, 1]], [1, 1, 1]])
        w = np.linalg.solve(A, [x, y, 1.0])
        assert mask[y, x]
        assert np.abs(img[y, x].astype(float) - w @ RGB.astype(float)).max() <= 1.0


def test_interpolation_is_perspective_correct_on_a_slanted_facet() -> None:
    """The 3-D centroid of a facet spanning depths 1 to 5 m gets the mean of its corners'
    colours, not what screen-space weights would give there."""
    A, B, C = np.array([-0.3, -0.3, 1.0]), np.array([2.0, -1.0, 5.0]), np.array([-1.0, 2.0, 5.0])
    g = (A + B + C) / 3
    u, w = 100.0 * g[0] / g[2], 100.0 * g[1] / g[2]
    v = view(cx=32.0 - u, cy=32.0 - w)  # the centroid exactly at pixel (32, 32)
    img, mask = render_mesh(v, np.stack([A, B, C]), np.array([[0, 1, 2]]), RGB)
    assert mask[32, 32]
    assert np.abs(img[32, 32].astype(float) - 255 / 3).max() <= 1.0
    uv = v.pixels(np.stack([A, B, C]))[:, :2]
    M = np.vstack([uv.T, np.ones(3)])
    affine = np.linalg.solve(M, [32.0, 32.0, 1.0]) @ RGB.astype(float)
    assert np.abs(affine - 255 / 3).max() > 20  # the test tells the two apart


@pytest.mark.parametrize("near_first", [True, False])
def test_a_nearer_facet_hides_a_farther_one_whatever_the_order(near_first: bool) -> None:
    v = view()
    uv = np.array([[0.5, 0.5], [63.2, 0.5], [0.5, 63.2]])
    far = at_pixels(v, uv, np.full(3, 5.0))
    near = at_pixels(v, uv + 10.0, np.full(3, 2.0))
    xyz = np.vstack([far, near])
    faces = np.array([[3, 4, 5], [0, 1, 2]]) if near_first else np.array([[0, 1, 2], [3, 4, 5]])
    rgb = np.array([[200, 0, 0]] * 3 + [[0, 0, 200]] * 3, np.uint8)
    img, mask = render_mesh(v, xyz, faces, rgb)
    r = rasterise(v, xyz, faces)
    assert (img[20, 20] == [0, 0, 200]).all() and r.depth[20, 20] == pytest.approx(2.0)
    assert (img[5, 5] == [200, 0, 0]).all() and r.depth[5, 5] == pytest.approx(5.0)
    assert mask[5, 5] and not mask[63, 63]


def test_facets_behind_or_too_near_the_camera_are_not_drawn() -> None:
    v = view()
    uv = np.array([[9.5, 9.5], [50.7, 9.5], [9.5, 50.7]])
    behind = at_pixels(v, uv, np.full(3, -2.0))
    straddling = at_pixels(v, uv, np.array([2.0, 2.0, 0.01]))
    _, mask = render_mesh(v, np.vstack([behind, straddling]), np.array([[0, 1, 2], [3, 4, 5]]),
                          np.vstack([RGB, RGB]))  # fmt: skip
    assert not mask.any()


def test_splat_draws_squares_sized_by_distance_nearest_first() -> None:
    v = view()
    xyz = at_pixels(v, np.array([[20.0, 20.0], [21.0, 21.0], [50.0, 50.0]]),
                    np.array([4.0, 2.0, 400.0]))  # fmt: skip
    rgb = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90]], np.uint8)
    img, mask = splat(v, xyz, rgb, size_m=0.2)
    # 0.2 m at 4 m with f = 100 px: 5 px wide; at 2 m: 10 px (centres within 5 px)
    y, x = np.mgrid[0:64, 0:64]
    near = (np.abs(x - 21) <= 5) & (np.abs(y - 21) <= 5)
    far = (np.abs(x - 20) <= 2) & (np.abs(y - 20) <= 2) & ~near
    assert (img[near] == [40, 50, 60]).all()
    assert (img[far] == [10, 20, 30]).all()
    # at 400 m it would be 0.05 px: one pixel at least
    assert mask[50, 50] and (img[50, 50] == [70, 80, 90]).all()
    assert mask.sum() == near.sum() + far.sum() + 1
    with pytest.raises(ValueError, match="size"):
        splat(v, xyz, rgb, size_m=0.0)


def test_look_at_and_rays_agree_with_the_projection() -> None:
    eye, target = np.array([3.0, 1.0, 1.5]), np.array([3.0, 9.0, 2.0])
    v = View(Pinhole(40, 30, 30.0, 30.0, 19.5, 14.5), look_at(eye, target))
    u, w, z = v.pixels(target[None])[0]
    assert (u, w) == (pytest.approx(19.5), pytest.approx(14.5)) and z > 0
    assert v.pixels((target + np.array([0, 0, 1.0]))[None])[0, 1] < 14.5  # up is up in the image
    assert (
        v.pixels((target + np.array([1.0, 0, 0]))[None])[0, 0] > 19.5
    )  # east on the right looking north
    origin, d = v.rays()
    assert np.allclose(origin, eye)
    back = v.pixels(origin + 5.0 * d)
    y, x = np.mgrid[0:30, 0:40]
    assert np.allclose(back[:, 0], x.ravel()) and np.allclose(back[:, 1], y.ravel())
    with pytest.raises(ValueError, match="along"):
        look_at(eye, eye + np.array([0, 0, 2.0]))


def test_a_corner_just_past_the_near_plane_far_off_screen_is_clamped() -> None:
    """A corner 6 cm ahead and far to the side projects 1e20 px away: the facet's part in
    the image is still drawn (no integer overflow, no loop over its whole extent)."""
    v = view()
    xyz = np.array([[-0.3, -0.31, 2.0], [1e17, 0.0, 0.06], [-0.3, 0.31, 2.0]])  # rows 0-15
    _, mask = render_mesh(v, xyz, np.array([[0, 1, 2]]), RGB)
    uv = v.pixels(xyz)[:, :2]
    y, x = np.mgrid[0:64, 0:64].astype(float)

    def edge(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])

    e = [edge(uv[0], uv[1]), edge(uv[1], uv[2]), edge(uv[2], uv[0])]
    inside = np.all([s >= 0 for s in e], axis=0) | np.all([s <= 0 for s in e], axis=0)
    assert inside.sum() == 16 * 64 and np.array_equal(mask, inside)


def test_a_textured_quad_shows_its_texels_where_they_lie_upright() -> None:
    """A 4 x 4 texel image on a quad spanning pixels 10..50 (edges) facing the camera:
    each texel's centre falls on a pixel centre, which shows that texel exactly; the
    texture's first row (v = 1 at the top, v up) is at the top of the picture."""
    v = view()
    texels = np.arange(48, dtype=np.uint8).reshape(4, 4, 3) * 5  # 16 distinct colours
    edges = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 50.0], [10.0, 50.0]])  # px, screen
    xyz = at_pixels(v, edges, np.full(4, 3.0))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    corner_uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]], np.float32)
    img, mask = render_textured(v, xyz, faces, corner_uv[faces], texels)
    for row in range(4):
        for col in range(4):
            y, x = 15 + 10 * row, 15 + 10 * col  # the centre of texel (row, col)
            assert mask[y, x] and (img[y, x] == texels[row, col]).all(), (row, col)
    assert not mask[5, 5] and (img[~mask] == 0).all()
    # between two texels' centres: their mean (bilinear)
    mixed = (texels[0, 0].astype(float) + texels[0, 1]) / 2
    assert np.abs(img[15, 20] - mixed).max() <= 1.0
    # the same quad upside down in the texture shows the last row on top
    flipped, _ = render_textured(v, xyz, faces, (corner_uv * [1, -1] + [0, 1])[faces], texels)
    assert (flipped[15, 15] == texels[3, 0]).all()
