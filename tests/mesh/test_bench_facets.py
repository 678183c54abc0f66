"""What bench/mesh_facets.py judges, on a small street: which object holds each point,
which objects touch, which returns are on a continuous surface, and that a facet across
a depth step is counted."""

from __future__ import annotations

import numpy as np

from acq.mesh import FacetRules
from acq.sim.world import Box, Cylinder, Material, Quad, Street
from tests.bench_scripts import load
from tests.mesh.pushbroom import beams, sweep

bench = load("mesh_facets")


def street() -> Street:
    s = Street()
    s.add(
        Box(0.0, 10.0, 5.0, 8.0, 0.0, 10.0, Material.FACADE),  # a building on the ground
        Box(10.0, 20.0, 8.0, 12.0, 0.0, 10.0, Material.FACADE),  # its neighbour, set back
        Box(-5.0, 20.0, 25.0, 30.0, 0.0, 20.0, Material.FACADE),  # the row behind
        Box(2.0, 6.0, 2.0, 3.8, 0.2, 1.0, Material.CAR_BODY),  # on wheels
        Cylinder(12.0, 4.0, 0.1, 0.0, 5.0, Material.POLE),
        Quad((3.0, 4.9, 0.5), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), Material.CHECKER),
    )
    return s


def test_each_point_is_given_the_object_whose_surface_holds_it() -> None:
    P = np.array(
        [
            [1.0, 5.0, 3.0],  # building 1's front
            [15.0, 8.0, 3.0],  # building 2's front
            [10.0, 6.0, 3.0],  # building 1's end (x = 10), where building 2 does not hide it
            [0.0, 25.0, 15.0],  # the row behind
            [4.0, 2.0, 0.5],  # the car's side
            [12.0, 3.9, 1.0],  # the pole
            [3.5, 4.9, 1.0],  # the quad
            [30.0, -3.0, 0.0],  # the ground
            [1.0, 1.0, 1.0],  # in the air
            [np.nan, 0.0, 0.0],
        ]
    )
    ids = bench.object_ids(street(), P)
    assert ids.tolist() == [1, 2, 1, 3, 4, 5, 6, 0, -1, -1]


def test_touching_objects() -> None:
    meet = bench.touching(bench.object_boxes(street()))
    assert meet[1, 2] and meet[0, 1] and meet[0, 5] and meet[4, 4]
    assert not meet[1, 3] and not meet[0, 4] and not meet[4, 1]  # the car floats 0.2 m up


def test_continuous_returns_need_a_cell_on_one_object_with_close_corners() -> None:
    ids = np.zeros((3, 4), dtype=np.int64)
    P = np.zeros((3, 4, 3))
    P[..., 0] = np.arange(3)[:, None] * 0.1
    P[..., 2] = np.arange(4)[None, :] * 0.1
    ids[0, 3] = 7  # another object at one corner
    P[2, 0] = (5.0, 0.0, 0.0)  # far from its neighbours
    cont = bench.continuous_returns(ids, P)
    assert cont.tolist() == [
        [True, True, True, False],
        [True, True, True, True],
        [False, True, True, True],
    ]


def test_a_facet_across_a_depth_step_is_counted() -> None:
    """Two walls 4 m apart met between consecutive scans: with the default rules no facet
    crosses; with the rules switched off the crossing facets are counted, each with a
    depth step over 0.5 m."""
    near = sweep(6, beams(-10.0, 10.0), plane_d=-5.0)
    far = sweep(6, beams(-10.0, 10.0), plane_d=-9.0)
    pick = [near[0] < 3, far[0] >= 3]
    scan, step, xyz, origin = (
        np.concatenate([a[m] for a, m in zip(arrs, pick, strict=True)])
        for arrs in zip(near, far, strict=True)
    )
    ids = np.zeros((6, int(step.max()) + 1), dtype=np.int64)
    ids[3:] = 1
    cont = np.ones(ids.shape, dtype=bool)
    apart = np.array([[True, False], [False, True]])
    good = bench.judge(scan, step, xyz, origin, ids, cont, apart, repeats=1)
    assert good["facets_across_discontinuity"] == 0
    assert good["continuous_in_facet"] == 1.0 and good["seconds_per_million"] > 0
    loose = FacetRules(max_grazing_deg=0.0, edge_a_m=100.0)
    bad = bench.judge(scan, step, xyz, origin, ids, cont, apart, repeats=1, rules=loose)
    assert bad["facets_across_discontinuity"] == 2 * 80
    assert bad["facets_across_depth_step_over_0_5_m"] == 2 * 80
    assert bad["facets_joining_touching_objects"] == 0
