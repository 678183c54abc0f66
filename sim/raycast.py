"""A compiled ray caster for the synthetic street (numba).

The street comes packed into x slices (:mod:`acq.sim.packed_scene`). Inside a slice each
box fills the slice's whole x range, so a box test is a 2-D rectangle test in (y, z) on
the ray's stretch inside the slice. A ray marches slice by slice from its origin and
stops at the first slice that holds a hit; the ground plane z = 0 and an escape bound
(above the tallest object, beyond the outermost one) cap the march; free quads are
tested against every ray.

Textures are procedural and evaluated at the hit point, with a flat shade per face (no
lighting that varies across a face), so a surface point has one colour whichever ray hits
it. Colours are BGR uint8; distances are metres along unit directions.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numba as nb
import numpy as np

from acq.sim.packed_scene import pack
from acq.sim.world import Material, Street

__all__ = ["NO_RAY", "CastResult", "cast"]

NO_RAY = 255  # material of output positions no ray was cast for

# fastmath without "nnan"/"ninf": misses are +inf and must stay so
_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}
# The kernels allocate nothing, so they run without numba's reference counting
# (``_nrt=False``): passing a dozen arrays to an inlined helper otherwise costs two atomic
# operations per array per ray, more than the tracing itself. Helpers are inlined at the
# numba IR level (``inline="always"``). (A private option, which numba's stubs omit.)
_NO_NRT: dict[str, Any] = {"_nrt": False}

_SKY = int(Material.SKY)
_ROAD = int(Material.ROAD)
_SIDEWALK = int(Material.SIDEWALK)
_FACADE = int(Material.FACADE)
_CAR_BODY = int(Material.CAR_BODY)
_CAR_CABIN = int(Material.CAR_CABIN)
_POLE = int(Material.POLE)
_CHECKER = int(Material.CHECKER)

# hit kinds
_K_NONE, _K_GROUND, _K_BOX, _K_CYL, _K_QUAD = 0, 1, 2, 3, 4
# faces: the outward normal of the face that was hit
_F_NX, _F_PX, _F_NY, _F_PY, _F_NZ, _F_PZ, _F_SIDE = 0, 1, 2, 3, 4, 5, 6
_SHADE = np.array([0.78, 0.72, 0.86, 0.93, 0.6, 1.0, 1.0])


class CastResult(NamedTuple):
    """Per ray: distance (m, +inf for sky), BGR colour, material id (``Material``)."""

    distance: np.ndarray  # (N,) float64
    colour: np.ndarray  # (N,3) uint8 BGR
    material: np.ndarray  # (N,) uint8


# --- the kernels ------------------------------------------------------------------------


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", inline="always", **_NO_NRT)
def _slab(o, d, lo, hi, t0, t1):  # type: ignore[no-untyped-def]
    """Clip [t0, t1] to where o + t d lies in [lo, hi] (empty: t0 > t1)."""
    if d != 0.0:
        a = (lo - o) / d
        b = (hi - o) / d
        if a > b:
            a, b = b, a
        return max(t0, a), min(t1, b)
    if lo <= o <= hi:
        return t0, t1
    return 1.0, 0.0


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", inline="always", **_NO_NRT)
def _march(  # type: ignore[no-untyped-def]
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    idy,
    idz,
    g,
    best,
    kind,
    idx,
    face,
    slice_x,
    slice_offset,
    slice_items,
    slice_zmax,
    groups,
    group_box,
    boxes,
    cylinders,
):
    """Walk group g's slices along the ray; returns the updated (best, kind, idx, face)."""
    gb = group_box
    t0, t1 = _slab(ox, dx, gb[g, 0], gb[g, 1], 0.0, best)
    t0, t1 = _slab(oy, dy, gb[g, 2], gb[g, 3], t0, t1)
    t0, t1 = _slab(oz, dz, gb[g, 4], gb[g, 5], t0, t1)
    if t0 > t1:
        return best, kind, idx, face
    base = groups[g, 0]
    n_slices = groups[g, 1]
    first = groups[g, 2]
    sx = slice_x
    s_off = slice_offset
    s_items = slice_items
    s_zmax = slice_zmax
    bb = boxes
    cyl = cylinders
    n_boxes = bb.shape[0]
    x0 = ox + dx * t0
    # the slice holding x0 (moving -x, a point on a boundary belongs to the slice below)
    lo = 0
    hi = n_slices
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        xm = sx[base + mid]
        if xm < x0 or (xm == x0 and dx >= 0.0):
            lo = mid
        else:
            hi = mid
    s = lo
    step = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
    t_enter = t0
    limit = t1
    while t_enter <= limit:
        if step > 0:
            t_exit = (sx[base + s + 1] - ox) / dx
        elif step < 0:
            t_exit = (sx[base + s] - ox) / dx
        else:
            t_exit = math.inf
        t_hi = min(t_exit, limit, best)
        gs = first + s
        if min(oz + dz * t_enter, oz + dz * t_hi) <= s_zmax[gs]:
            for k in range(s_off[gs], s_off[gs + 1]):
                it = s_items[k]
                if it < n_boxes:
                    # 2-D slab test in (y, z) on [t_enter, t_hi]
                    ty0 = (bb[it, 2] - oy) * idy
                    ty1 = (bb[it, 3] - oy) * idy
                    tz0 = (bb[it, 4] - oz) * idz
                    tz1 = (bb[it, 5] - oz) * idz
                    tny = min(ty0, ty1)
                    tnz = min(tz0, tz1)
                    tf = min(max(ty0, ty1), max(tz0, tz1))
                    tn = max(tny, tnz)
                    if tf < t_enter or tn > tf:
                        continue
                    if tn < t_enter:
                        if t_enter < best:
                            best = t_enter
                            kind = _K_BOX
                            idx = it
                            face = _F_NX if step > 0 else _F_PX
                    elif tn < best and tn <= t_hi:
                        best = tn
                        kind = _K_BOX
                        idx = it
                        if tny > tnz:
                            face = _F_NY if dy > 0.0 else _F_PY
                        else:
                            face = _F_NZ if dz > 0.0 else _F_PZ
                        t_hi = tn
                else:
                    c = it - n_boxes
                    ex = ox - cyl[c, 0]
                    ey = oy - cyl[c, 1]
                    r = cyl[c, 2]
                    a = dx * dx + dy * dy
                    hb = ex * dx + ey * dy
                    cc = ex * ex + ey * ey - r * r
                    if a > 0.0:
                        disc = hb * hb - a * cc
                        if disc >= 0.0:
                            t = (-hb - math.sqrt(disc)) / a
                            if t_enter <= t <= t_hi and t < best:
                                z = oz + dz * t
                                if cyl[c, 3] <= z <= cyl[c, 4]:
                                    best = t
                                    kind = _K_CYL
                                    idx = c
                                    face = _F_SIDE
                                    t_hi = t
                    if dz < 0.0:  # the top cap
                        t = (cyl[c, 4] - oz) * idz
                        if t_enter <= t <= t_hi and t < best:
                            hx = ex + dx * t
                            hy = ey + dy * t
                            if hx * hx + hy * hy <= r * r:
                                best = t
                                kind = _K_CYL
                                idx = c
                                face = _F_PZ
                                t_hi = t
        if best <= t_exit or step == 0:
            break
        t_enter = t_exit
        s += step
        if s < 0 or s >= n_slices:
            break
    return best, kind, idx, face


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", inline="always", **_NO_NRT)
def _trace(  # type: ignore[no-untyped-def]
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    slice_x,
    slice_offset,
    slice_items,
    slice_zmax,
    groups,
    group_box,
    boxes,
    cylinders,
    quads,
):
    """Nearest hit of one ray: (t m, kind, object index, face)."""
    best = math.inf
    kind = _K_NONE
    idx = -1
    face = -1
    if dz < 0.0:
        best = -oz / dz
        kind = _K_GROUND
        face = _F_PZ
    # free quads, brute force (a handful at most)
    qd = quads
    for q in range(qd.shape[0]):
        den = qd[q, 9] * dx + qd[q, 10] * dy + qd[q, 11] * dz
        if den == 0.0:
            continue
        px = qd[q, 0] - ox
        py = qd[q, 1] - oy
        pz = qd[q, 2] - oz
        t = (qd[q, 9] * px + qd[q, 10] * py + qd[q, 11] * pz) / den
        if t <= 0.0 or t >= best:
            continue
        hx = dx * t - px
        hy = dy * t - py
        hz = dz * t - pz
        a = hx * qd[q, 3] + hy * qd[q, 4] + hz * qd[q, 5]
        b = hx * qd[q, 6] + hy * qd[q, 7] + hz * qd[q, 8]
        if 0.0 <= a <= 1.0 and 0.0 <= b <= 1.0:
            best = t
            kind = _K_QUAD
            idx = q
            face = 7
    idy = 1.0 / dy if dy != 0.0 else 1e300
    idz = 1.0 / dz if dz != 0.0 else 1e300
    for g in range(groups.shape[0]):
        best, kind, idx, face = _march(
            ox,
            oy,
            oz,
            dx,
            dy,
            dz,
            idy,
            idz,
            g,
            best,
            kind,
            idx,
            face,
            slice_x,
            slice_offset,
            slice_items,
            slice_zmax,
            groups,
            group_box,
            boxes,
            cylinders,
        )
    return best, kind, idx, face


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", inline="always", **_NO_NRT)
def _hash(ix, iy):  # type: ignore[no-untyped-def]
    h = (ix * 73856093) ^ (iy * 19349663)
    h = (h ^ (h >> 13)) * 1274126177
    return (h >> 7) & 3


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", inline="always", **_NO_NRT)
def _facade(P, i, u, z, is_front):  # type: ignore[no-untyped-def]
    """Facade texture at (u along the wall, z) m: 0 wall, 1 frame, 2 glass, 3 band."""
    floor_h = P[i, 10]
    if not is_front or floor_h <= 0.0 or P[i, 9] <= 0.0:
        return 0
    ground_h = P[i, 15]
    # a darker string course above the ground floor
    if ground_h - 0.25 <= z < ground_h:
        return 3
    pitch = P[i, 9]
    wx = P[i, 11]
    wz = P[i, 12]
    fr = 0.08
    uu = u - P[i, 14]
    cell = uu - pitch * math.floor(uu / pitch)
    if z < ground_h:
        # shop windows and doors: wider, from 0.4 m up
        w2 = min(pitch - 0.4, 2.0 * wx)
        if cell < w2 and 0.4 <= z < ground_h - 0.6:
            if cell < fr or cell >= w2 - fr or z < 0.4 + fr or z >= ground_h - 0.6 - fr:
                return 1
            return 2
        return 0
    zz = z - ground_h
    fz = zz - floor_h * math.floor(zz / floor_h)
    sill = P[i, 13]
    if cell < wx and sill <= fz < sill + wz:
        if cell < fr or cell >= wx - fr or fz < sill + fr or fz >= sill + wz - fr:
            return 1
        # a mullion in the middle
        if abs(cell - 0.5 * wx) < 0.03:
            return 1
        return 2
    return 0


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", inline="always", **_NO_NRT)
def _shade(  # type: ignore[no-untyped-def]
    ox,
    oy,
    oz,
    dx,
    dy,
    dz,
    t,
    kind,
    idx,
    face,
    boxes,
    box_material,
    box_params,
    cyl_material,
    cyl_params,
    quads,
    quad_material,
    quad_params,
    ground,
):
    """BGR colour and material id of a traced ray."""
    if kind == _K_NONE:
        # sky: horizon haze to zenith blue
        e = max(0.0, min(1.0, dz))
        e = math.sqrt(e)
        return (
            235.0 + (200.0 - 235.0) * e,
            225.0 + (150.0 - 225.0) * e,
            210.0 + (95.0 - 210.0) * e,
            _SKY,
        )
    hx = ox + dx * t
    hy = oy + dy * t
    hz = oz + dz * t
    shade = _SHADE[face] if face < 7 else 1.0
    if kind == _K_GROUND:
        glob = ground
        ay = abs(hy)
        if ay < glob[0]:
            # markings: dashed centre line, solid lane edges
            if ay < 0.06 and hx - 6.0 * math.floor(hx / 6.0) < 3.0:
                return 230.0, 230.0, 230.0, _ROAD
            if abs(ay - glob[1]) < 0.075:
                return 225.0, 225.0, 225.0, _ROAD
            g = 72.0 + 3.0 * _hash(math.floor(hx * 10.0), math.floor(hy * 10.0))
            return g, g + 1.0, g + 3.0, _ROAD
        g = 105.0 + 6.0 * _hash(math.floor(hx * 2.0), math.floor(hy * 2.0))
        return g - 10.0, g, g + 5.0, _ROAD
    if kind == _K_BOX:
        mat = box_material[idx]
        p = box_params
        bb = boxes
        if mat == _FACADE:
            if face == _F_PZ:
                return 62.0, 60.0, 66.0, _FACADE
            is_front = face == _F_NY or face == _F_PY
            k = _facade(p, idx, hx - bb[idx, 0], hz, is_front)
            o = 3 * k if k < 3 else 0
            s = shade if k != 3 else shade * 0.7
            return p[idx, o] * s, p[idx, o + 1] * s, p[idx, o + 2] * s, _FACADE
        if mat == _SIDEWALK:
            if face == _F_PZ:
                size = p[idx, 9]
                gw = p[idx, 10]
                fu = hx / size
                fv = hy / size
                iu = math.floor(fu)
                iv = math.floor(fv)
                if (fu - iu) * size < gw or (fv - iv) * size < gw:
                    return p[idx, 6], p[idx, 7], p[idx, 8], _SIDEWALK
                o = 3 * ((int(iu) + int(iv)) & 1)
                return p[idx, o], p[idx, o + 1], p[idx, o + 2], _SIDEWALK
            return p[idx, 11] * shade, p[idx, 12] * shade, p[idx, 13] * shade, _SIDEWALK
        if mat == _CAR_BODY:
            return p[idx, 0] * shade, p[idx, 1] * shade, p[idx, 2] * shade, _CAR_BODY
        if mat == _CAR_CABIN:
            if face == _F_PZ:
                return p[idx, 0], p[idx, 1], p[idx, 2], _CAR_CABIN
            pw = p[idx, 6]
            if face == _F_NY or face == _F_PY:
                u = min(hx - bb[idx, 0], bb[idx, 1] - hx)
            else:
                u = min(hy - bb[idx, 2], bb[idx, 3] - hy)
            if u < pw:
                return p[idx, 0] * shade, p[idx, 1] * shade, p[idx, 2] * shade, _CAR_CABIN
            return p[idx, 3], p[idx, 4], p[idx, 5], _CAR_CABIN
        if mat == _CHECKER:
            return 128.0, 128.0, 128.0, _CHECKER
        return p[idx, 0] * shade, p[idx, 1] * shade, p[idx, 2] * shade, mat
    if kind == _K_CYL:
        mat = cyl_material[idx]
        p = cyl_params
        if mat == _POLE and p[idx, 6] > 0.0:
            o = 3 * (math.floor(hz / p[idx, 6]) & 1)
            return p[idx, o], p[idx, o + 1], p[idx, o + 2], _POLE
        return p[idx, 0], p[idx, 1], p[idx, 2], mat
    # quad
    qd = quads
    mat = quad_material[idx]
    p = quad_params
    if mat == _CHECKER:
        rx = hx - qd[idx, 0]
        ry = hy - qd[idx, 1]
        rz = hz - qd[idx, 2]
        a = rx * qd[idx, 3] + ry * qd[idx, 4] + rz * qd[idx, 5]
        b = rx * qd[idx, 6] + ry * qd[idx, 7] + rz * qd[idx, 8]
        i = min(int(a * p[idx, 0]), int(p[idx, 0]) - 1)
        j = min(int(b * p[idx, 1]), int(p[idx, 1]) - 1)
        o = 2 + 3 * ((i + j) & 1)
        return p[idx, o], p[idx, o + 1], p[idx, o + 2], _CHECKER
    return p[idx, 0], p[idx, 1], p[idx, 2], mat


@nb.njit(cache=True, fastmath=_FM, error_model="numpy", **_NO_NRT)
def _kernel(origins, dirs, R, index, sc, dist, colour, material):  # type: ignore[no-untyped-def]
    """Trace rays ``R @ dirs[i]`` from ``origins[i]`` (or the single origin ``origins[0]``)
    and write distance, colour and material at position ``index[i]`` of the outputs."""
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    (sx, so, si, sz, gr, gb, bb, bm, bp, cyl, cm, cp, qd, qm, qp, gd) = sc
    one_origin = origins.shape[0] == 1
    ox, oy, oz = origins[0, 0], origins[0, 1], origins[0, 2]
    for i in range(dirs.shape[0]):
        if not one_origin:
            ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        ux, uy, uz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        dx = r00 * ux + r01 * uy + r02 * uz
        dy = r10 * ux + r11 * uy + r12 * uz
        dz = r20 * ux + r21 * uy + r22 * uz
        t, kind, idx, face = _trace(ox, oy, oz, dx, dy, dz, sx, so, si, sz, gr, gb, bb, cyl, qd)
        b, g, r, m = _shade(
            ox, oy, oz, dx, dy, dz, t, kind, idx, face, bb, bm, bp, cm, cp, qd, qm, qp, gd
        )
        p = index[i]
        dist[p] = t
        colour[p, 0] = np.uint8(min(255.0, b + 0.5))
        colour[p, 1] = np.uint8(min(255.0, g + 0.5))
        colour[p, 2] = np.uint8(min(255.0, r + 0.5))
        material[p] = m


def cast(
    street: Street,
    origins: np.ndarray,
    dirs: np.ndarray,
    rotation: np.ndarray | None = None,
    index: np.ndarray | None = None,
    size: int | None = None,
) -> CastResult:
    """Cast rays from world origins (N,3) or one origin (3,) m along unit directions (N,3).

    With ``rotation`` (3,3) the directions are rotated into the world first (camera-frame
    rays of a pinned camera). With ``index`` (N,) the results land at those positions of
    outputs of length ``size``; the rest is distance NaN, black, material ``NO_RAY``.
    """
    # writeable C arrays always, so the kernel compiles for one signature only
    origins = np.require(np.reshape(origins, (-1, 3)), np.float64, ["C", "W"])
    dirs = np.require(np.reshape(dirs, (-1, 3)), np.float64, ["C", "W"])
    n = dirs.shape[0]
    if origins.shape[0] not in (1, n):
        raise ValueError(f"{origins.shape[0]} origins for {n} directions")
    R = np.eye(3) if rotation is None else np.array(rotation, dtype=np.float64, order="C")
    if index is None:
        index = np.arange(n)
        size = n
    elif size is None:
        raise ValueError("index needs size")
    dist = np.full(size, np.nan)
    colour = np.zeros((size, 3), np.uint8)
    material = np.full(size, NO_RAY, np.uint8)
    index = np.require(index, np.int64, ["C", "W"])
    _kernel(origins, dirs, R, index, pack(street), dist, colour, material)
    return CastResult(dist, colour, material)
