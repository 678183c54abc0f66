"""The synthetic street as flat arrays for the ray caster's kernels (:mod:`acq.sim.raycast`).

The street is 2.5-D: boxes are axis-aligned and cylinders vertical, so the scene is cut
along x into slices at every object's x extent, each slice listing the objects it crosses
and the top of the tallest. :func:`pack` builds the arrays once per street (and version).
Distances are metres.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from acq.sim.world import N_PARAMS, Box, Cylinder, Quad, Street

__all__ = ["PackedScene", "pack"]


class PackedScene(NamedTuple):
    """A street as flat arrays for the compiled kernels (see :func:`pack`).

    Objects are split into groups (left of the centre line, right of it, across it), each
    with its own bounding box and its own x slices, so a ray looking left never marches
    through the right side's slices.
    """

    slice_x: np.ndarray  # (sum(S_g + 1),) float64 slice boundaries along x per group, m
    slice_offset: np.ndarray  # (sum(S_g) + 1,) int32 CSR offsets into slice_items
    slice_items: np.ndarray  # (M,) int32 object ids: box i, or n_boxes + cylinder j
    slice_zmax: np.ndarray  # (sum(S_g),) float64 top of the tallest object in the slice, m
    groups: np.ndarray  # (G,3) int64 first boundary in slice_x, S_g, first slice
    group_box: np.ndarray  # (G,6) float64 xmin, xmax, ymin, ymax, zmin, zmax of the group
    boxes: np.ndarray  # (B,6) float64 xmin, xmax, ymin, ymax, zmin, zmax
    box_material: np.ndarray  # (B,) int32
    box_params: np.ndarray  # (B,P) float64
    cylinders: np.ndarray  # (C,5) float64 x, y, radius, zmin, zmax
    cyl_material: np.ndarray  # (C,) int32
    cyl_params: np.ndarray  # (C,P) float64
    quads: np.ndarray  # (Q,12) float64 origin, u/|u|², v/|v|², unit normal
    quad_material: np.ndarray  # (Q,) int32
    quad_params: np.ndarray  # (Q,P) float64
    ground: np.ndarray  # (2,) road half width, lane edge line offset, m


# id(street) -> (a weak reference to it, its version, its packed scene); the reference
# tells a live street from a new one that got a dead one's id
_PACK_CACHE: dict[int, tuple[weakref.ref[Street], int, PackedScene]] = {}


def _slices(
    ids: np.ndarray, x_lo: np.ndarray, x_hi: np.ndarray, z_hi: np.ndarray
) -> tuple[np.ndarray, list[list[int]], np.ndarray]:
    """Slice boundaries, per-slice object lists and per-slice top for objects ``ids``."""
    edges = np.unique(np.concatenate([x_lo[ids], x_hi[ids]]))
    n = edges.size - 1
    lists: list[list[int]] = [[] for _ in range(n)]
    zmax = np.full(n, -np.inf)
    for i in ids:
        s0 = int(np.searchsorted(edges, x_lo[i]))
        s1 = int(np.searchsorted(edges, x_hi[i]))
        for s in range(s0, s1):
            lists[s].append(int(i))
        zmax[s0:s1] = np.maximum(zmax[s0:s1], z_hi[i])
    return edges, lists, zmax


def pack(street: Street) -> PackedScene:
    """The street's objects as flat arrays with the x slices built; cached per street."""
    key = id(street)
    hit = _PACK_CACHE.get(key)
    if hit is not None and hit[0]() is street and hit[1] == street.version:
        return hit[2]
    nb_, nc = len(street.boxes), len(street.cylinders)
    boxes = np.array(
        [[b.xmin, b.xmax, b.ymin, b.ymax, b.zmin, b.zmax] for b in street.boxes], float
    ).reshape(nb_, 6)
    cyl = np.array([[c.x, c.y, c.radius, c.zmin, c.zmax] for c in street.cylinders], float).reshape(
        nc, 5
    )
    # every object's bounding box, boxes first then cylinders
    aabb = np.concatenate(
        [
            boxes,
            np.stack(
                [
                    cyl[:, 0] - cyl[:, 2],
                    cyl[:, 0] + cyl[:, 2],
                    cyl[:, 1] - cyl[:, 2],
                    cyl[:, 1] + cyl[:, 2],
                    cyl[:, 3],
                    cyl[:, 4],
                ],
                axis=1,
            ),
        ]
    )
    side = np.where(aabb[:, 2] >= 0.0, 0, np.where(aabb[:, 3] <= 0.0, 1, 2))
    sx: list[np.ndarray] = []
    zmax: list[np.ndarray] = []
    lists: list[list[int]] = []
    groups, group_box = [], []
    for g in range(3):
        ids = np.flatnonzero(side == g)
        if ids.size == 0:
            continue
        edges, lst, zm = _slices(ids, aabb[:, 0], aabb[:, 1], aabb[:, 5])
        groups.append([sum(e.size for e in sx), edges.size - 1, len(lists)])
        sub = aabb[ids]
        group_box.append(
            [
                sub[:, 0].min(),
                sub[:, 1].max(),
                sub[:, 2].min(),
                sub[:, 3].max(),
                sub[:, 4].min(),
                sub[:, 5].max(),
            ]
        )
        sx.append(edges)
        zmax.append(zm)
        lists.extend(lst)
    offsets = np.zeros(len(lists) + 1, np.int32)
    offsets[1:] = np.cumsum([len(lst) for lst in lists])
    items = np.array([i for lst in lists for i in lst], np.int32)

    quads = np.zeros((len(street.quads), 12))
    for q, quad in enumerate(street.quads):
        u, v = np.asarray(quad.u, float), np.asarray(quad.v, float)
        n = np.cross(u, v)
        quads[q] = np.concatenate([quad.origin, u / (u @ u), v / (v @ v), n / np.linalg.norm(n)])

    def params(objs: Sequence[Box | Cylinder | Quad]) -> np.ndarray:
        return np.array([o.params for o in objs], float).reshape(len(objs), N_PARAMS)

    def mats(objs: Sequence[Box | Cylinder | Quad]) -> np.ndarray:
        return np.array([int(o.material) for o in objs], np.int32)

    packed = PackedScene(
        slice_x=np.concatenate(sx) if sx else np.zeros(0),
        slice_offset=offsets,
        slice_items=items,
        slice_zmax=np.concatenate(zmax) if zmax else np.zeros(0),
        groups=np.array(groups, np.int64).reshape(-1, 3),
        group_box=np.array(group_box, float).reshape(-1, 6),
        boxes=boxes,
        box_material=mats(street.boxes),
        box_params=params(street.boxes),
        cylinders=cyl,
        cyl_material=mats(street.cylinders),
        cyl_params=params(street.cylinders),
        quads=quads,
        quad_material=mats(street.quads),
        quad_params=params(street.quads),
        ground=np.array([street.road_half_width, street.lane_edge], float),
    )
    for k in [k for k, v in _PACK_CACHE.items() if v[0]() is None]:
        del _PACK_CACHE[k]  # streets that are gone
    _PACK_CACHE[key] = (weakref.ref(street), street.version, packed)
    return packed
