"""The synthetic street, its ray caster and the simulated camera and scanner."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from acq.sim import raycast
from acq.sim.sensors import (
    camera_to_world,
    render_frame,
    render_frame_truth,
    render_scan,
    true_pixels,
)
from acq.sim.world import (
    Box,
    Material,
    Street,
    Trajectory,
    checkerboard_quad,
    default_rig,
)


@pytest.fixture(scope="module")
def street() -> Street:
    return Street.generate(seed=1, length_m=120.0)


@pytest.fixture(scope="module")
def rig():  # type: ignore[no-untyped-def]
    return dataclasses.replace(default_rig(), range_noise=0.0)


def _brute_force(street: Street, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference nearest hit (distance, material) by testing every object, numpy."""
    n = o.shape[0]
    best = np.full(n, np.inf)
    mat = np.zeros(n, np.uint8)
    with np.errstate(divide="ignore", invalid="ignore"):
        tg = np.where(d[:, 2] < 0, -o[:, 2] / d[:, 2], np.inf)
    best = tg.copy()
    mat[np.isfinite(tg)] = Material.ROAD
    B = np.array([[b.xmin, b.xmax, b.ymin, b.ymax, b.zmin, b.zmax] for b in street.boxes])
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (B[None, :, 0::2] - o[:, None, :]) / d[:, None, :]
        t1 = (B[None, :, 1::2] - o[:, None, :]) / d[:, None, :]
    tn = np.nanmax(np.minimum(t0, t1), axis=2)
    tf = np.nanmin(np.maximum(t0, t1), axis=2)
    hit = (tn <= tf) & (tn > 0)
    tb = np.where(hit, tn, np.inf)
    j = np.argmin(tb, axis=1)
    tbm = tb[np.arange(n), j]
    closer = tbm < best
    best[closer] = tbm[closer]
    mat[closer] = np.array([b.material for b in street.boxes])[j[closer]]
    for c in street.cylinders:
        ex, ey = o[:, 0] - c.x, o[:, 1] - c.y
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        hb = ex * d[:, 0] + ey * d[:, 1]
        disc = hb**2 - a * (ex**2 + ey**2 - c.radius**2)
        with np.errstate(invalid="ignore"):
            t = (-hb - np.sqrt(disc)) / a
        z = o[:, 2] + d[:, 2] * t
        ok = (disc >= 0) & (t > 0) & (z >= c.zmin) & (z <= c.zmax) & (t < best)
        best[ok] = t[ok]
        mat[ok] = c.material
    return best, mat


def test_slice_caster_matches_brute_force(street: Street) -> None:
    rng = np.random.default_rng(5)
    n = 4000
    o = np.stack(
        [rng.uniform(0, 120, n), rng.uniform(-2.0, 2.0, n), rng.uniform(0.3, 3.0, n)], axis=1
    )
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = raycast.cast(street, o, d)
    want, want_mat = _brute_force(street, o, d)
    assert np.array_equal(np.isinf(got.distance), np.isinf(want))
    fin = np.isfinite(want)
    np.testing.assert_allclose(got.distance[fin], want[fin], rtol=0, atol=1e-9)
    assert np.mean(got.material[fin] == want_mat[fin]) > 0.999
    assert np.all(got.material[~fin] == Material.SKY)
    # the street has something of everything
    assert {Material.FACADE, Material.CAR_BODY, Material.SIDEWALK, Material.ROAD} <= set(
        got.material.tolist()
    )


def test_trajectory_moves_at_20_kmh() -> None:
    tr = Trajectory()
    a, b = tr.pose(2.0), tr.pose(3.0)
    np.testing.assert_allclose(b.translation - a.translation, [20 / 3.6, 0, 0], atol=1e-12)
    np.testing.assert_allclose(a.rotation, np.eye(3), atol=1e-15)
    curvy = Trajectory(curve_amplitude=0.8, vibration_rad=0.005, seed=3)
    R, t = curvy.poses(np.array([0.5, 4.25]))
    p = curvy.pose(4.25)
    np.testing.assert_allclose(R[1], p.rotation, atol=1e-15)
    np.testing.assert_allclose(t[1], p.translation, atol=1e-15)
    assert np.ptp(curvy.poses(np.linspace(0, 20, 50))[1][:, 1]) > 1.0


def test_rig_geometry(rig) -> None:  # type: ignore[no-untyped-def]
    cam = rig.camera_to_vehicle()
    # the optical axis looks left, image x forward, image y down (within the small tilt)
    assert cam.rotation[:, 2] @ [0, 1, 0] > math.cos(math.radians(3))
    assert cam.rotation[:, 0] @ [1, 0, 0] > math.cos(math.radians(3))
    assert cam.rotation[:, 1] @ [0, 0, -1] > math.cos(math.radians(3))
    # the laser: angle 0 straight up, +90 degrees to the vehicle's right
    L = rig.laser_to_vehicle.rotation
    np.testing.assert_allclose(L @ [1, 0, 0], [0, 0, 1])
    np.testing.assert_allclose(L @ [0, 1, 0], [0, -1, 0])
    # the camera sits in front of the scan plane, not in it
    assert 0.3 <= cam.translation[0] - rig.laser_to_vehicle.translation[0] <= 0.5
    assert abs(rig.time_increment * 1440 - rig.scan_period) < 1e-15
    assert rig.n_steps == 1081 and math.isclose(math.degrees(rig.angles[-1]), 135.0)


def test_lens_truth_follows_table_3() -> None:
    lens = default_rig().lens
    assert any(lens.k)
    for deg, bound in [(53.75, 1), (67.75, 2), (77.5, 3), (85.375, 4)]:
        th = np.linspace(0, math.radians(deg), 200)
        diff = lens.fx * np.abs(lens.distort_theta(th) - th)
        assert diff.max() < bound
        assert diff.max() > bound - 1  # and not a negligible distortion either
    assert not any(default_rig(exact_equidistant=True).lens.k)


def test_laser_straight_up_is_no_echo(street: Street, rig) -> None:  # type: ignore[no-untyped-def]
    scan = render_scan(street, Trajectory(), rig, 3.0, np.random.default_rng(0))
    up = np.argmin(np.abs(scan.angles))
    assert scan.angles[up] == 0.0
    assert np.isposinf(scan.ranges[up]) and np.isposinf(scan.true_ranges[up])
    assert np.all(np.isnan(scan.points[up]))
    assert scan.material[up] == Material.SKY


def test_ranges_to_a_known_facade(rig) -> None:  # type: ignore[no-untyped-def]
    """One long facade at y = 6 m, nothing else: ranges follow from the geometry."""
    wall = Street(length_m=100.0)
    wall.add(Box(-100.0, 200.0, 6.0, 16.0, 0.0, 20.0, Material.SOLID, (200, 200, 200)))
    tr = Trajectory(y0=0.0)
    scan = render_scan(wall, tr, rig, 1.0, np.random.default_rng(0))
    h = rig.laser_to_vehicle.translation[2]
    # laser direction in the vehicle: (0, -sin a, cos a) (left is negative angles)
    a = scan.angles
    left, up = -np.sin(a), np.cos(a)
    with np.errstate(divide="ignore"):
        t_wall = np.where(left > 0, 6.0 / left, np.inf)
        t_wall = np.where(h + up * t_wall <= 20.0, t_wall, np.inf)
        t_ground = np.where(up < 0, -h / up, np.inf)
    want = np.minimum(t_wall, t_ground)
    np.testing.assert_allclose(scan.true_ranges, want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(scan.true_ranges[np.argmin(np.abs(a + np.pi / 2))], 6.0)
    # max range: the ground far away to the right is beyond 30 m only if the scan says so
    echo = want <= rig.max_range
    assert np.all(np.isposinf(scan.ranges[~echo]))
    # noise: 10 mm, seeded
    noisy_rig = dataclasses.replace(rig, range_noise=0.01)
    s1 = render_scan(wall, tr, noisy_rig, 1.0, np.random.default_rng(7))
    s2 = render_scan(wall, tr, noisy_rig, 1.0, np.random.default_rng(7))
    assert np.array_equal(s1.ranges, s2.ranges)
    err = s1.ranges[echo] - s1.true_ranges[echo]
    assert 0.007 < np.std(err) < 0.013
    assert s1.ranges.dtype == np.float32


def test_scan_points_lie_on_surfaces(street: Street, rig) -> None:  # type: ignore[no-untyped-def]
    tr = Trajectory()
    scan = render_scan(street, tr, rig, 5.0, np.random.default_rng(0))
    np.testing.assert_allclose(scan.times[1] - scan.times[0], 0.025 / 1440)
    echo = np.isfinite(scan.ranges)
    assert echo.sum() > 500
    road = scan.material == Material.ROAD
    assert road.sum() > 20
    np.testing.assert_allclose(scan.points[road, 2], 0.0, atol=1e-9)
    # every box hit lies on the surface of some box
    B = np.array([[b.xmin, b.xmax, b.ymin, b.ymax, b.zmin, b.zmax] for b in street.boxes])
    boxed = echo & np.isin(scan.material, [Material.FACADE, Material.SIDEWALK, Material.CAR_BODY])
    P = scan.points[boxed]
    inside = np.all((P[:, None, :] >= B[None, :, 0::2] - 1e-9), axis=2) & np.all(
        (P[:, None, :] <= B[None, :, 1::2] + 1e-9), axis=2
    )
    on_face = np.any(
        np.isclose(P[:, None, :], B[None, :, 0::2], atol=1e-9)
        | np.isclose(P[:, None, :], B[None, :, 1::2], atol=1e-9),
        axis=2,
    )
    assert np.all(np.any(inside & on_face, axis=1))
    # each step is cast from the laser at its own time: the origin moves 20 km/h
    dx = scan.origins[-1, 0] - scan.origins[0, 0]
    np.testing.assert_allclose(dx, 20 / 3.6 * (scan.times[-1] - scan.times[0]), rtol=1e-9)
    # true points are origin + range * direction
    np.testing.assert_allclose(
        np.linalg.norm(scan.points[echo] - scan.origins[echo], axis=1), scan.true_ranges[echo]
    )


def test_frame_image_circle(street: Street, rig) -> None:  # type: ignore[no-untyped-def]
    img = render_frame(street, Trajectory(), rig, 4.0)
    lens = rig.lens
    assert img.shape == (582, 780, 3) and img.dtype == np.uint8
    for v, u in [(0, 0), (0, 779), (581, 0), (581, 779), (291, 5), (291, 775)]:
        assert not img[v, u].any()
    r_max = lens.fx * lens.distort_theta(np.array([lens.theta_max]))[0]
    v, u = np.mgrid[0:582, 0:780]
    r = np.hypot(u - lens.cx, v - lens.cy)
    lit = img.any(axis=2)
    assert np.all(lit[r < r_max - 1.0])
    assert not np.any(lit[r > r_max + 1.0])
    # a varied scene, not a flat fill
    assert len(np.unique(img[r < r_max].reshape(-1, 3), axis=0)) > 50


def test_colour_at_true_pixel_matches_laser_hit(street: Street, rig) -> None:  # type: ignore[no-untyped-def]
    tr = Trajectory()
    t_frame = 6.0
    truth = render_frame_truth(street, tr, rig, t_frame)
    img = truth.image
    checked = 0
    matches = []
    for k in range(4):
        scan = render_scan(street, tr, rig, t_frame - 0.05 + 0.025 * k, np.random.default_rng(k))
        echo = np.isfinite(scan.ranges)
        uv, valid = true_pixels(scan.points, tr, rig, t_frame)
        ok = echo & valid
        u = np.rint(uv[ok, 0]).astype(int)
        v = np.rint(uv[ok, 1]).astype(int)
        inner = (u > 0) & (u < 779) & (v > 0) & (v < 581)
        u, v = u[inner], v[inner]
        colours = scan.colours[ok][inner]
        pts = scan.points[ok][inner]
        # seen by the camera (not occluded): the pixel's depth reaches the point
        cam = camera_to_world(tr, rig, t_frame)
        dist = np.linalg.norm(pts - cam.translation, axis=1)
        seen = np.abs(truth.depth[v, u] - dist) < 0.05 * dist
        # away from texture edges: a uniform 3x3 neighbourhood
        nb = np.stack([img[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
        uniform = np.all(nb == nb[:, :1], axis=(1, 2))
        sel = seen & uniform
        same = np.all(img[v[sel], u[sel]] == colours[sel], axis=1)
        assert same.mean() > 0.98, f"{(~same).sum()} of {sel.sum()} differ"
        checked += sel.sum()
        # at texture edges (asphalt grain, window frames) a pixel may show a neighbour's
        # colour, but seldom
        matches.append(np.all(img[v[seen], u[seen]] == colours[seen], axis=1))
    assert checked > 200
    assert np.concatenate(matches).mean() > 0.85


def test_true_pixel_ray_reaches_the_laser_point(street: Street, rig) -> None:  # type: ignore[no-untyped-def]
    """Unprojecting the true pixel and casting from the camera lands on the scan point."""
    tr = Trajectory(curve_amplitude=0.5, vibration_rad=0.004, seed=2)
    t_frame = 7.0
    scan = render_scan(street, tr, rig, t_frame + 0.01, np.random.default_rng(0))
    uv, valid = true_pixels(scan.points, tr, rig, t_frame)
    ok = np.isfinite(scan.ranges) & valid
    assert ok.sum() > 300
    cam = camera_to_world(tr, rig, t_frame)
    rays = rig.lens.unproject(uv[ok])
    hit = raycast.cast(street, cam.translation, rays, cam.rotation)
    dist = np.linalg.norm(scan.points[ok] - cam.translation, axis=1)
    seen = hit.distance > dist - 1e-3  # the rest is hidden from the camera
    assert seen.mean() > 0.5
    np.testing.assert_allclose(hit.distance[seen], dist[seen], rtol=0, atol=1e-6)
    assert np.array_equal(hit.material[seen], scan.material[ok][seen])


def test_checkerboard_quad_renders_where_projected(rig) -> None:  # type: ignore[no-untyped-def]
    """A board 3 m left of the camera: its square centres land on the right colours."""
    tr = Trajectory()
    t = 2.0
    cam = camera_to_world(tr, rig, t)
    c = cam.translation
    board = Street(length_m=50.0)
    cols, rows, sq = 7, 5, 0.1
    origin = (c[0] - 0.35, c[1] + 3.0, c[2] - 0.25)
    board.add(checkerboard_quad(origin, (1, 0, 0), (0, 0, 1), cols, rows, sq))
    img = render_frame(board, tr, rig, t)
    i, j = np.meshgrid(np.arange(cols), np.arange(rows), indexing="ij")
    centres = np.stack(
        [
            origin[0] + (i.ravel() + 0.5) * sq,
            np.full(i.size, origin[1]),
            origin[2] + (j.ravel() + 0.5) * sq,
        ],
        axis=1,
    )
    uv, valid = true_pixels(centres, tr, rig, t)
    assert valid.all()
    px = img[np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]
    dark = ((i + j) % 2 == 0).ravel()
    assert np.all(px[dark] == 20) and np.all(px[~dark] == 235)


def test_deterministic_for_a_seed(rig) -> None:  # type: ignore[no-untyped-def]
    a, b = Street.generate(seed=9, length_m=80.0), Street.generate(seed=9, length_m=80.0)
    assert a.boxes == b.boxes and a.cylinders == b.cylinders
    assert Street.generate(seed=10, length_m=80.0).boxes != a.boxes
    tr = Trajectory()
    assert np.array_equal(render_frame(a, tr, rig, 1.5), render_frame(b, tr, rig, 1.5))
    noisy = dataclasses.replace(rig, range_noise=0.01)
    s1 = render_scan(a, tr, noisy, 1.5, np.random.default_rng(3))
    s2 = render_scan(b, tr, noisy, 1.5, np.random.default_rng(3))
    assert np.array_equal(s1.ranges, s2.ranges)
    assert np.array_equal(s1.colours, s2.colours)


def test_street_layout_follows_table_1(street: Street) -> None:
    facades = [b for b in street.boxes if b.material == Material.FACADE and abs(b.ymin) < 20]
    near = np.array([b.ymin if b.ymin > 0 else -b.ymax for b in facades])
    assert np.all((near >= 5.0) & (near <= 10.0))
    heights = np.array([b.zmax for b in facades])
    assert np.all((heights >= 10.0) & (heights <= 30.0))
    widths = np.array([b.xmax - b.xmin for b in facades])
    assert np.median(widths) > 8.0
    assert street.cylinders and any(b.material == Material.CAR_BODY for b in street.boxes)


def test_a_new_street_with_a_dead_streets_id_is_packed_afresh() -> None:
    # CPython reuses the id of a freed object: a cache keyed by id alone would hand a new
    # street the old one's scene
    import gc

    from acq.sim import packed_scene, world

    old = world.Street.generate(seed=1)
    stale = packed_scene.pack(old)
    key = id(old)
    del old
    gc.collect()
    new = world.Street.generate(seed=2)
    # whether or not CPython gave it the same id, a cache entry under its id whose street
    # is gone must not be used
    entry = packed_scene._PACK_CACHE.get(key)
    assert entry is None or entry[0]() is None
    if entry is not None:
        packed_scene._PACK_CACHE[id(new)] = entry
    packed = packed_scene.pack(new)
    assert packed is not stale
    assert len(packed.boxes) == len(new.boxes) and len(packed.cylinders) == len(new.cylinders)
