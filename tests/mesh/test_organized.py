"""Facets from the scan grid (acq.mesh.organized): the rules on surfaces a simulated
pushbroom scanner sweeps (plain arrays: each point the exact hit of its beam on planes)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from acq.errors import InputValueError
from acq.mesh import FacetRules, grid_facets
from tests.mesh.pushbroom import HEIGHT_M, beams, sweep


def cells(tri: np.ndarray, scan: np.ndarray, step: np.ndarray) -> np.ndarray:
    """(F,2) the grid cell (lowest scan, lowest step) of each triangle."""
    return np.stack([scan[tri].min(axis=1), step[tri].min(axis=1)], axis=1)


def normals(tri: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    p = xyz[tri]
    out: np.ndarray = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return out


def test_a_flat_wall_gives_two_triangles_per_cell() -> None:
    scan, step, xyz, origin = sweep(12, beams(-20.0, 20.0))
    n_k = beams(-20.0, 20.0).size
    tri = grid_facets(scan, step, xyz, origin)
    assert tri.dtype == np.int64 and tri.shape == (2 * 11 * (n_k - 1), 3)
    # each cell twice, each triangle once
    _, per_cell = np.unique(cells(tri, scan, step), axis=0, return_counts=True)
    assert per_cell.size == 11 * (n_k - 1) and (per_cell == 2).all()
    assert np.unique(np.sort(tri, axis=1), axis=0).shape[0] == tri.shape[0]
    # the vertices of a triangle are grid neighbours
    assert (np.ptp(scan[tri], axis=1) == 1).all() and (np.ptp(step[tri], axis=1) == 1).all()


def test_scan_numbers_need_not_start_at_zero_and_input_order_does_not_matter() -> None:
    scan, step, xyz, origin = sweep(6, beams(-10.0, 10.0))
    tri = grid_facets(scan, step, xyz, origin)
    order = np.random.default_rng(1).permutation(scan.size)
    shuffled = grid_facets(scan[order] + 1000, step[order] - 7, xyz[order], origin[order])
    as_set = {tuple(sorted(t)) for t in tri.tolist()}
    assert {tuple(sorted(order[t])) for t in shuffled.tolist()} == as_set


@pytest.mark.parametrize("block_points", [1, 40, 100])
def test_blocks_of_scans_give_the_same_triangles(block_points: int) -> None:
    """A wall with holes, some where a block ends: meshed in blocks of whole scans
    (one scan at a time, or a few), each with the next scan."""
    scan, step, xyz, origin = sweep(9, beams(-5.0, 5.0))
    holes = ((scan == 3) & (step == 4)) | ((scan == 4) & (step == 0)) | ((scan == 6) & (step > 30))
    scan, step, xyz, origin = scan[~holes], step[~holes], xyz[~holes], origin[~holes]
    whole = grid_facets(scan, step, xyz, origin)
    # an interior hole costs 4 triangles, one at the edge 2, a scan's last 10 returns
    # 2 x (9 cells x 2 + 1)
    assert whole.shape[0] == 2 * 8 * 40 - 4 - 2 - 2 * 19
    blocks = grid_facets(scan, step, xyz, origin, block_points=block_points)
    assert sorted(map(tuple, blocks.tolist())) == sorted(map(tuple, whole.tolist()))


def test_a_missing_return_removes_exactly_its_adjacent_triangles() -> None:
    scan, step, xyz, origin = sweep(8, beams(-10.0, 10.0))
    full = grid_facets(scan, step, xyz, origin)
    gone = np.flatnonzero((scan == 4) & (step == 30))[0]
    keep = np.arange(scan.size) != gone
    tri = np.flatnonzero(keep)[grid_facets(scan[keep], step[keep], xyz[keep], origin[keep])]
    # the four cells around it keep one triangle each, the one without it
    around = {(3, 29), (3, 30), (4, 29), (4, 30)}
    got = {tuple(c) for c in cells(tri, scan, step).tolist()}
    assert around <= got
    for c in around:
        mine = tri[(cells(tri, scan, step) == c).all(axis=1)]
        assert mine.shape[0] == 1 and gone not in mine

    # everything else is as before
    def far(t: np.ndarray) -> list[list[int]]:
        keep = [tuple(c) not in around for c in cells(t, scan, step).tolist()]
        return sorted(sorted(x) for x in t[keep].tolist())

    assert far(tri) == far(full)
    assert full.shape[0] - tri.shape[0] == 4


def test_no_facet_across_a_depth_step_along_the_track() -> None:
    """A building's end 4 m in front of the next one: the two walls are meshed, the gap
    between consecutive scans is not."""
    near = sweep(10, beams(-20.0, 20.0), plane_d=-5.0)
    far = sweep(10, beams(-20.0, 20.0), plane_d=-9.0)
    pick = [near[0] < 5, far[0] >= 5]
    scan, step, xyz, origin = (np.concatenate([a[m] for a, m in zip(arrs, pick, strict=True)])
                               for arrs in zip(near, far, strict=True))  # fmt: skip
    tri = grid_facets(scan, step, xyz, origin)
    on_near = xyz[:, 1] < 7.0
    assert (on_near[tri].all(axis=1) | ~on_near[tri].any(axis=1)).all()
    n_k = beams(-20.0, 20.0).size
    assert tri.shape[0] == 2 * (n_k - 1) * (4 + 4)  # each wall's own cells, whole


def test_a_small_depth_step_far_away_is_refused_by_the_grazing_angle() -> None:
    """Within a scan: the lower beams hit a wall at 20 m, the upper ones a wall at 21 m.
    The step (1 m) is shorter than the length bound at that range (0.5 + 0.05 * 20), so
    only the angle to the viewing ray refuses it."""
    b = beams(-3.0, 3.0)
    near = sweep(4, b, plane_d=-20.0)
    far = sweep(4, b, plane_d=-21.0)
    pick = [near[1] < b.size // 2, far[1] >= b.size // 2]
    scan, step, xyz, origin = (np.concatenate([a[m] for a, m in zip(arrs, pick, strict=True)])
                               for arrs in zip(near, far, strict=True))  # fmt: skip
    on_near = xyz[:, 1] < 20.5
    tri = grid_facets(scan, step, xyz, origin)
    assert tri.shape[0] > 0 and (on_near[tri].all(axis=1) | ~on_near[tri].any(axis=1)).all()
    bridged = grid_facets(scan, step, xyz, origin, FacetRules(max_grazing_deg=0.0))
    assert (on_near[bridged].any(axis=1) & ~on_near[bridged].all(axis=1)).sum() == 2 * 3


@pytest.mark.parametrize(("incidence_deg", "meshed"), [(9.0, False), (16.0, True)])
def test_a_surface_seen_at_grazing_incidence_is_not_meshed(
    incidence_deg: float, meshed: bool
) -> None:
    """A plane tilted so the (near horizontal) beams meet it at ``incidence_deg``; the
    length bound is lifted so only the angle decides."""
    phi = math.radians(90.0 - incidence_deg)
    n = (0.0, -math.cos(phi), -math.sin(phi))
    through = (0.0, 5.0, HEIGHT_M)  # the plane passes 5 m to the left of the scanner
    d = float(np.dot(n, through))
    scan, step, xyz, origin = sweep(5, beams(-0.5, 0.5, 0.1), n, d)
    assert scan.size == 5 * 11
    tri = grid_facets(scan, step, xyz, origin, FacetRules(edge_a_m=100.0))
    assert tri.shape[0] == (2 * 4 * 10 if meshed else 0)


def test_each_end_is_judged_from_its_own_sensor_origin() -> None:
    """An edge between two scans is perpendicular to the first point's ray, but runs
    along the second point's ray when that point was measured from a position on the
    edge's line: refused (a shared origin would have accepted it)."""
    scan, step, xyz, origin = sweep(2, beams(-1.0, 1.0))
    tri = grid_facets(scan, step, xyz, origin)
    assert tri.shape[0] == 2 * (beams(-1.0, 1.0).size - 1)
    moved = origin.copy()
    second = scan == 1
    moved[second] = xyz[second] + np.array([3.0, 0.0, 0.0])  # looking back along -x
    assert grid_facets(scan, step, xyz, moved).shape[0] == 0


def test_an_edge_longer_than_its_bound_is_refused() -> None:
    """Beams 2 degrees apart on a wall 5 m away: 0.175 m between neighbours in a scan."""
    scan, step, xyz, origin = sweep(3, beams(-4.0, 4.0, 2.0))
    cells_2x4 = 2 * 2 * 4
    assert (
        grid_facets(scan, step, xyz, origin, FacetRules(edge_a_m=0.18, edge_b=0.0)).shape[0]
        == cells_2x4
    )
    assert grid_facets(scan, step, xyz, origin, FacetRules(edge_a_m=0.17, edge_b=0.0)).shape == (
        0,
        3,
    )
    # range counts: 0.1 + 0.016 * 5 m > 0.175 m, 0.1 + 0.014 * 5 m < 0.175 m
    assert (
        grid_facets(scan, step, xyz, origin, FacetRules(edge_a_m=0.10, edge_b=0.016)).shape[0]
        == cells_2x4
    )
    assert grid_facets(scan, step, xyz, origin, FacetRules(edge_a_m=0.10, edge_b=0.014)).shape == (
        0,
        3,
    )


def test_the_length_bound_allows_the_sensors_travel_between_scans() -> None:
    """At 100 km/h (0.7 m between scans) a wall is meshed whole with the default rules;
    points placed 0.5 m further apart than the sensor moved (beyond 0.05 + 0.05 * 5 m)
    are not."""
    scan, step, xyz, origin = sweep(4, beams(-4.0, 4.0), advance_m=0.7)
    assert grid_facets(scan, step, xyz, origin).shape[0] == 2 * 3 * 32
    stretched = xyz.copy()
    stretched[:, 0] = scan * 1.2  # the points 1.2 m apart, the sensor 0.7 m
    assert grid_facets(scan, step, stretched, origin).shape == (0, 3)


def test_the_shorter_diagonal_is_chosen() -> None:
    """Each scan's beams shifted by most of a beam against the previous scan's: the
    cell's short diagonal runs (s, k+1) -> (s+1, k)."""
    scan, step, xyz, origin = sweep(2, beams(-2.0, 2.0))
    xyz = xyz.copy()
    xyz[scan == 1, 2] += 0.8 * 5.0 * math.radians(0.25)
    tri = grid_facets(scan, step, xyz, origin)
    assert tri.shape[0] == 2 * 16
    has_ad = ((scan[tri] == 0) & (step[tri] == step[tri].min(axis=1, keepdims=True))).any(
        axis=1
    ) & ((scan[tri] == 1) & (step[tri] == step[tri].max(axis=1, keepdims=True))).any(axis=1)
    assert not has_ad.any()


@pytest.mark.parametrize(
    ("plane_n", "plane_d", "beams_deg"),
    [
        ((0.0, -1.0, 0.0), -5.0, beams(-20.0, 20.0)),  # a wall on the left
        ((0.0, 1.0, 0.0), -5.0, beams(160.0, 200.0)),  # a wall on the right
        ((0.0, 0.0, 1.0), 0.0, beams(-80.0, -30.0)),  # the road
    ],
)
def test_triangles_are_counter_clockwise_seen_from_the_sensor(
    plane_n: tuple[float, float, float], plane_d: float, beams_deg: np.ndarray
) -> None:
    scan, step, xyz, origin = sweep(4, beams_deg, plane_n, plane_d)
    tri = grid_facets(scan, step, xyz, origin)
    assert tri.shape[0] == 2 * 3 * (beams_deg.size - 1)
    towards = origin[tri[:, 0]] - xyz[tri].mean(axis=1)
    assert (np.einsum("ij,ij->i", normals(tri, xyz), towards) > 0).all()
    # consistently: every interior edge is walked once each way
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    assert np.unique(directed, axis=0).shape[0] == directed.shape[0]


def test_empty_and_one_scan_give_no_facets() -> None:
    none = grid_facets(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)))
    assert none.shape == (0, 3) and none.dtype == np.int64
    scan, step, xyz, origin = sweep(1, beams(-5.0, 5.0))
    assert grid_facets(scan, step, xyz, origin).shape == (0, 3)


def test_scans_not_consecutive_are_not_joined() -> None:
    scan, step, xyz, origin = sweep(2, beams(-5.0, 5.0))
    assert grid_facets(scan * 2, step, xyz, origin).shape == (0, 3)
    assert grid_facets(scan, step * 2, xyz, origin).shape == (0, 3)


def test_nan_points_are_in_no_facet_and_cost_only_their_own_triangles() -> None:
    scan, step, xyz, origin = sweep(6, beams(-5.0, 5.0))
    full = grid_facets(scan, step, xyz, origin).shape[0]
    xyz = xyz.copy()
    bad = np.flatnonzero((scan == 2) & (step == 20))[0]
    xyz[bad, 1] = np.nan
    origin = origin.copy()
    bad_origin = np.flatnonzero((scan == 4) & (step == 5))[0]
    origin[bad_origin, 0] = np.inf
    tri = grid_facets(scan, step, xyz, origin)
    assert bad not in tri and bad_origin not in tri
    assert tri.shape[0] == full - 2 * 4  # as missing returns (the previous test)


def test_mismatched_or_malformed_inputs_are_refused() -> None:
    scan, step, xyz, origin = sweep(3, beams(-1.0, 1.0))
    with pytest.raises(ValueError, match="one length"):
        grid_facets(scan[:-1], step, xyz, origin)
    with pytest.raises(ValueError, match="one length"):
        grid_facets(scan, step, xyz, origin[:-1])
    with pytest.raises(ValueError, match=r"xyz must have shape \(P, 3\)"):
        grid_facets(scan, step, xyz[:, :2], origin)
    with pytest.raises(ValueError, match="step must hold integers"):
        grid_facets(scan, step.astype(float), xyz, origin)
    with pytest.raises(ValueError, match=r"\(scan, step\) = \(1, 4\) is given more than once"):
        twice = np.flatnonzero((scan == 1) & (step == 4))
        grid_facets(
            np.append(scan, 1), np.append(step, 4), np.vstack([xyz, xyz[twice]]),
            np.vstack([origin, origin[twice]]),
        )  # fmt: skip
    with pytest.raises(InputValueError, match="max_grazing_deg"):
        FacetRules(max_grazing_deg=90.0)
    with pytest.raises(InputValueError, match="edge_a_m and edge_b"):
        FacetRules(edge_b=-0.1)


@st.composite
def random_grids(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Any grid: random scan and step numbers (unique pairs), points anywhere (some NaN,
    some coincident, some collinear), origins anywhere."""
    n_s = draw(st.integers(1, 6))
    n_k = draw(st.integers(1, 8))
    present = draw(hnp.arrays(bool, (n_s, n_k)))
    s, k = np.nonzero(present)
    s0 = draw(st.integers(-(2**40), 2**40))
    k0 = draw(st.integers(-1000, 1000))
    coord = st.one_of(
        st.floats(-10, 10, allow_nan=False),
        st.sampled_from([0.0, 1.0, float("nan")]),
    )
    xyz = draw(hnp.arrays(np.float64, (s.size, 3), elements=coord))
    origin = draw(hnp.arrays(np.float64, (s.size, 3), elements=st.sampled_from([0.0, 0.5, -3.0])))
    return s + s0, k + k0, xyz, origin


@settings(max_examples=300, deadline=None)
@given(
    random_grids(),
    st.floats(0.0, 80.0),
    st.floats(0.0, 5.0),
    st.floats(0.0, 1.0),
    st.integers(1, 30),
)
def test_any_grid_gives_valid_non_degenerate_triangles(
    grid: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    grazing: float,
    a: float,
    b: float,
    block: int,
) -> None:
    scan, step, xyz, origin = grid
    rules = FacetRules(max_grazing_deg=grazing, edge_a_m=a, edge_b=b)
    tri = grid_facets(scan, step, xyz, origin, rules)
    # in blocks of a few scans: the same triangles
    blocks = grid_facets(scan, step, xyz, origin, rules, block_points=block)
    assert sorted(map(tuple, blocks.tolist())) == sorted(map(tuple, tri.tolist()))
    assert tri.dtype == np.int64 and tri.ndim == 2 and tri.shape[1] == 3
    if tri.size == 0:
        return
    assert tri.min() >= 0 and tri.max() < scan.size
    assert np.isfinite(xyz[tri]).all()
    srt = np.sort(tri, axis=1)
    assert (srt[:, 0] < srt[:, 1]).all() and (srt[:, 1] < srt[:, 2]).all()
    assert np.unique(srt, axis=0).shape[0] == tri.shape[0]
    assert (np.ptp(scan[tri], axis=1) == 1).all() and (np.ptp(step[tri], axis=1) == 1).all()
    assert (np.linalg.norm(normals(tri, xyz), axis=1) > 0).all()
