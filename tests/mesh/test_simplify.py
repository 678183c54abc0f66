"""acq mesh --simplify: near-coplanar facets merged within a tolerance (acq.mesh.simplify
on grids of known shape, checked by the distance of every original vertex to the result),
and on the short simulated drive through the command."""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from acq.mesh.simplify import simplify, surface_distance
from tests.mesh.test_mesh_cli import Drive, _mesh, _ply

NOISE_M = 0.002  # a laser's range noise on the grids, m


def _grid(nx: int, ny: int, height: object = None, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(xyz, faces) of a grid of nx x ny vertices 0.1 m apart in x and y, z = ``height``
    (a function of x, y; default 0) plus NOISE_M of noise, two facets a cell."""
    x, y = np.meshgrid(np.arange(nx) * 0.1, np.arange(ny) * 0.1, indexing="ij")
    z = height(x, y) if callable(height) else np.zeros_like(x)
    z = z + NOISE_M * np.random.default_rng(seed).standard_normal(x.shape)
    xyz = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    i = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel()
    return xyz, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _colours(xyz: np.ndarray) -> np.ndarray:
    """Red where x < 2 m, blue beyond."""
    return np.where((xyz[:, 0] < 2.0)[:, None], [[200, 0, 0]], [[0, 0, 200]]).astype(np.uint8)


def test_a_flat_grid_collapses_to_few_facets_within_the_tolerance() -> None:
    xyz, faces = _grid(40, 40)
    s_xyz, s_rgb, s_faces = simplify(xyz, _colours(xyz), faces, 0.02)
    assert s_faces.shape[0] < 0.3 * faces.shape[0], s_faces.shape
    assert s_faces.dtype == np.int64 and s_rgb.dtype == np.uint8
    assert np.unique(s_faces).size == s_xyz.shape[0]  # no vertex without a facet
    d = surface_distance(xyz, s_xyz, s_faces)
    assert d.max() <= 0.02, d.max()
    # a finer tolerance keeps more facets and holds closer
    f_xyz, _, f_faces = simplify(xyz, _colours(xyz), faces, 0.003)
    assert s_faces.shape[0] < f_faces.shape[0] < faces.shape[0]
    assert surface_distance(xyz, f_xyz, f_faces).max() <= 0.003


def test_a_step_is_kept_and_the_border_does_not_move() -> None:
    # a kerb: 0.15 m up from y = 2 m on
    xyz, faces = _grid(40, 40, lambda x, y: np.where(y >= 2.0, 0.15, 0.0))
    s_xyz, _, s_faces = simplify(xyz, _colours(xyz), faces, 0.02)
    assert s_faces.shape[0] < 0.3 * faces.shape[0]
    assert surface_distance(xyz, s_xyz, s_faces).max() <= 0.02  # the edge's vertices too
    # the step's two edges are still there: vertices at the kerb's foot and top
    foot = (np.abs(s_xyz[:, 1] - 1.9) < 0.01) & (np.abs(s_xyz[:, 2]) < 0.01)
    top = (np.abs(s_xyz[:, 1] - 2.0) < 0.01) & (np.abs(s_xyz[:, 2] - 0.15) < 0.01)
    assert foot.sum() >= 2 and top.sum() >= 2
    # every vertex of the open border kept exactly: a neighbouring tile meets it
    x, y = xyz[:, 0], xyz[:, 1]
    rim = (x == x.min()) | (x == x.max()) | (y == y.min()) | (y == y.max())
    kept = {p.tobytes() for p in s_xyz}
    assert all(p.tobytes() in kept for p in xyz[rim])


def test_colours_are_carried_from_the_nearest_original_vertex() -> None:
    xyz, faces = _grid(40, 30)
    rgb = _colours(xyz)
    s_xyz, s_rgb, _ = simplify(xyz, rgb, faces, 0.02)
    # away from the colour edge (within half a cell either side's colour may be nearest)
    clear = np.abs(s_xyz[:, 0] - 2.0) > 0.05
    assert np.array_equal(s_rgb[clear, 0] == 200, s_xyz[clear, 0] < 2.0)
    assert {tuple(c) for c in s_rgb} == {(200, 0, 0), (0, 0, 200)}


def test_far_from_the_origin_the_tolerance_holds() -> None:
    """Projected coordinates (UTM: 10^5-10^6 m) lose nothing to the quadrics."""
    xyz, faces = _grid(30, 30)
    far = xyz + np.array([431_000.0, 4_582_000.0, 120.0])
    s_xyz, _, s_faces = simplify(far, _colours(xyz), faces, 0.02)
    assert s_faces.shape[0] < 0.35 * faces.shape[0]
    assert surface_distance(far, s_xyz, s_faces).max() <= 0.02


def test_surface_distance_is_exact() -> None:
    """Against trimesh's closest point on every facet, for points near and off a mesh
    whose facets are of very different sizes."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    xyz, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    xyz[xyz[:, 2] > 0.5] *= 1.5  # large facets beside small ones
    pts = np.random.default_rng(1).uniform(-1.2, 1.2, (300, 3))
    tri = xyz[faces]
    truth = np.array([np.linalg.norm(trimesh.triangles.closest_point(
        tri, np.broadcast_to(p, (len(tri), 3))) - p, axis=1).min() for p in pts])  # fmt: skip
    assert np.allclose(surface_distance(pts, xyz, faces), truth, atol=1e-12)
    fast = surface_distance(pts, xyz, faces, exact_over_m=0.2)
    big = truth > 0.2
    assert big.any() and np.allclose(fast[big], truth[big], atol=1e-12)
    assert (fast >= truth - 1e-12).all()  # the others: an upper bound


def test_the_command_merges_facets_and_tiles_still_meet(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    whole, simple = tmp_path / "w.ply", tmp_path / "s.ply"
    assert _mesh(short_drive, whole) == 0
    capsys.readouterr()
    assert _mesh(short_drive, simple, "--simplify", "0.02") == 0
    said = capsys.readouterr().out
    xyz, rgb, faces = _ply(whole)
    s_xyz, s_rgb, s_faces = _ply(simple)
    assert f"simplified from {faces.shape[0]:,} facets" in said
    assert f"{s_faces.shape[0]:,} facets on {s_xyz.shape[0]:,} vertices" in said
    assert s_faces.shape[0] < 0.9 * faces.shape[0]
    assert b"near-coplanar facets merged within 0.02 m" in simple.read_bytes()[:2000]
    # "about": the planes of the facets merged into a vertex are within 0.02 m of it
    assert surface_distance(xyz, s_xyz, s_faces, exact_over_m=0.01).max() <= 0.03
    # each vertex's colour is its own where it did not move, else the nearest vertex's
    at = {p.tobytes(): k for k, p in enumerate(xyz)}
    same = [k for k, p in enumerate(s_xyz) if p.tobytes() in at]
    assert len(same) > 0.2 * s_xyz.shape[0]  # the border, edges and steps
    assert np.array_equal(s_rgb[same], rgb[[at[s_xyz[k].tobytes()] for k in same]])
    some = s_xyz[:: max(1, s_xyz.shape[0] // 40)]
    near = [int(np.argmin(np.linalg.norm(xyz - p, axis=1))) for p in some]
    assert np.array_equal(s_rgb[:: max(1, s_xyz.shape[0] // 40)], rgb[near])
    # in tiles: the profile two tiles share is in both, unmoved
    assert _mesh(short_drive, tmp_path / "t.ply", "--simplify", "0.02", "--tile-m", "3") == 0
    tiles = [_ply(p)[0] for p in sorted(tmp_path.glob("t_*.ply"))]
    assert len(tiles) == 4
    for a, b in itertools.pairwise(tiles):
        shared = {p.tobytes() for p in a} & {p.tobytes() for p in b}
        assert len(shared) > 50  # a profile's returns on the street and facades


@pytest.mark.parametrize("value", ["nan", "-0.02", "0", "inf", "5", "two"])
def test_bad_simplify_values_are_one_line_and_exit_2(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str
) -> None:
    assert _mesh(short_drive, tmp_path / "m.glb", "--simplify", value) == 2
    err = capsys.readouterr().err
    assert "--simplify: expected metres in (0, 0.5]" in err and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


def test_simplify_with_texture_is_refused(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _mesh(short_drive, tmp_path / "m.glb", "--simplify", "0.02", "--texture") == 2
    err = capsys.readouterr().err
    assert "--simplify: not with --texture" in err and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


def test_two_threads_simplifying_at_once_give_what_each_gives_alone() -> None:
    """pyfqmr holds its mesh in global state: tiles simplified on two writer threads
    must not take each other's mesh."""
    from concurrent.futures import ThreadPoolExecutor

    meshes = []
    for k in range(6):
        xyz, faces = _grid(40 + 7 * k, 30, seed=k)
        meshes.append((xyz, _colours(xyz), faces))
    alone = [simplify(*m, 0.01) for m in meshes]
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # the threads take turns between pyfqmr's calls
    try:
        with ThreadPoolExecutor(2) as pool:
            together = list(pool.map(lambda m: simplify(*m, 0.01), meshes * 3))
    finally:
        sys.setswitchinterval(switch)
    for got, want in zip(together, alone * 3, strict=True):
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
