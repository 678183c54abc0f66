"""Which frame textures each facet (:func:`select_views`): mvs-texturing's view selection
(a data term per candidate view, a Potts term between neighbouring facets) on a moving
fisheye rig.

- *Candidates*: for each camera, the frames the colouring used in the tile (decoded, of
  the model's size, within the trajectory) nearest in time to the facet, ``window``
  either side, within the colouring's ``max_dt_s`` plus that many frame periods.
- *Excluded*: a candidate where a corner of the facet is off the sensor or hidden by
  nearer laser points in that frame: the colouring's occlusion test
  (:mod:`acq.camera.occlusion`, a depth buffer of the laser points scanned within
  ``context_s`` of the frame, the colouring's cell and margins), each corner where the
  rig stood at the frame's time.
- *Data cost* of a candidate: -ln(the facet's area in the frame, px²) (the resolution on
  the surface: it falls with distance, with obliqueness and with the fisheye's
  compression off its axis) + ``per_s`` x |facet time - frame time| s + ``per_rad2`` x
  theta² (theta: the facet's centre's angle from the optical axis, rad).
- *Potts term*: ``smooth`` for each neighbour (a facet across an edge) in another view
  (mvs-texturing's model; it solves it with graph cuts). From each facet's cheapest
  candidate: iterated conditional modes (the facets in time order), then region moves
  (a connected region of one view takes a neighbouring region's view where the energy
  falls: no single facet can shift a straight boundary between two bands of frames,
  each facet on it having two neighbours of its own view), then one more ICM pass. On
  the 60 s drive 12.6 % of the edges between facets then join two views (ICM alone:
  20.8 %; no Potts term: 25.4 %).

A facet that no candidate sees whole keeps the view most of its vertices were coloured
from (:func:`acq.mesh.texture.facet_views`). Metres, host ns, pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from acq.camera import projection
from acq.camera.occlusion import MAX_SPLAT_CELLS, occlusion_depths, visible
from acq.cloud.job import Job
from acq.cloud.views import camera_poses
from acq.geometry.transforms import Rigid
from acq.mesh.texture import facet_views
from acq.time.sync import on_laser_clock

__all__ = ["Occluders", "ViewWeights", "candidate_costs", "neighbours", "potts", "select_views"]

REGION_ROUNDS = 2  # of :func:`potts` region moves (more change under 0.1 % of the edges)
_FALLBACK_COST = 1e6  # the vertices' own view where no candidate sees the facet whole


@dataclass(frozen=True)
class ViewWeights:
    """The weights of :func:`select_views` (module docstring): ``window`` frames either
    side of each camera's nearest; ``context_s``: the laser points scanned within this of
    a frame may hide facets in it (a point between the camera and a facet was scanned
    between the two: the facets weighed in a frame were scanned within ``window`` + 1/2
    frame periods of it, and the simulated rig's cameras sit 0.25 m from the laser, 45 ms
    at 20 km/h; 0.25 s gives the same views on the 60 s drive, the colouring's own
    context is 0.4 s); ``per_s``: cost per second between facet and frame; ``per_rad2``: per
    rad² off the optical axis; ``smooth``: per neighbour in another view; ``passes`` of
    iterated conditional modes."""

    window: int = 1
    context_s: float = 0.15
    per_s: float = 5.0
    per_rad2: float = 0.5
    smooth: float = 1.0
    passes: int = 2


@dataclass(frozen=True)
class Occluders:
    """Laser points that may hide a facet: ``xyz`` (N,3) m in the facets' frame,
    ``time_ns`` (N,) nondecreasing (laser clock), ``size_m`` (N,) each one's share of
    surface (:func:`acq.cloud.views.point_size`)."""

    xyz: np.ndarray
    time_ns: np.ndarray
    size_m: np.ndarray


def neighbours(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pairs (a, b) of facets that share an edge (each pair once)."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    facet = np.tile(np.arange(faces.shape[0]), 3)
    key = edges[:, 0] * (int(faces.max(initial=0)) + 1) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    same = np.flatnonzero(key[order][1:] == key[order][:-1])
    return facet[order][same], facet[order][same + 1]


@numba.njit(cache=True, nogil=True)
def _icm(order, start, nbr, keys, cost, smooth, passes, chosen):  # type: ignore[no-untyped-def]
    """Iterated conditional modes in place on ``chosen`` (F,), facets visited in ``order``,
    each one's neighbours ``nbr[start[f]:start[f + 1]]``."""
    for _ in range(passes):
        for f in order:
            best, best_e = chosen[f], np.inf
            for j in range(keys.shape[1]):
                k = keys[f, j]
                if k < 0 or not np.isfinite(cost[f, j]):
                    continue
                e = cost[f, j]
                for q in range(start[f], start[f + 1]):
                    if chosen[nbr[q]] != k:
                        e += smooth
                if e < best_e:
                    best, best_e = k, e
            chosen[f] = best


@numba.njit(cache=True, nogil=True)
def _components(n, a, b, chosen):  # type: ignore[no-untyped-def]
    """(F,) int64: the connected regions of one label (union-find over the edges a-b)."""
    parent = np.arange(n)
    for e in range(a.size):
        if chosen[a[e]] != chosen[b[e]]:
            continue
        x, y = a[e], b[e]
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        while parent[y] != y:
            parent[y] = parent[parent[y]]
            y = parent[y]
        if x != y:
            parent[max(x, y)] = min(x, y)
    for f in range(n):
        r = f
        while parent[r] != r:
            r = parent[r]
        parent[f] = r
    return parent


@numba.njit(cache=True, nogil=True)
def _move_gains(keys, cost, chosen, start, facets, pair_region, pair_label, pair_edges, smooth):  # type: ignore[no-untyped-def]
    """For each (region, label) pair: ``smooth`` x its edges to that label minus the data
    costs the region's facets (``facets[start[r]:start[r + 1]]``) would add taking it."""
    gain = np.empty(pair_region.size)
    for p in range(pair_region.size):
        r, label = pair_region[p], pair_label[p]
        d = 0.0 if chosen[facets[start[r]]] >= 0 else np.inf  # a region without a view stays
        for i in range(start[r], start[r + 1]):
            f = facets[i]
            now, then = np.inf, np.inf
            for j in range(keys.shape[1]):
                if keys[f, j] == label:
                    then = min(then, cost[f, j])
                if keys[f, j] == chosen[f]:
                    now = min(now, cost[f, j])
            d += then - now
            if not np.isfinite(d):
                break
        gain[p] = smooth * pair_edges[p] - d if np.isfinite(d) else -np.inf
    return gain


def _region_moves(
    keys: np.ndarray, cost: np.ndarray, a: np.ndarray, b: np.ndarray, chosen: np.ndarray,
    smooth: float, rounds: int,
) -> np.ndarray:  # fmt: skip
    """``chosen`` after ``rounds`` of region moves: each connected region of one label
    takes the label of a neighbouring region where that lowers the energy (a straight
    boundary between two bands, which no single facet's move shifts); of two neighbouring
    regions that would move, the one that gains more."""
    n = chosen.size
    for _ in range(rounds):
        region = _components(n, a, b, chosen)
        cut = chosen[a] != chosen[b]
        # each region's edges to each label across its border
        ra = np.concatenate([region[a[cut]], region[b[cut]]])
        lab = np.concatenate([chosen[b[cut]], chosen[a[cut]]])
        other = np.concatenate([region[b[cut]], region[a[cut]]])
        if ra.size == 0:
            break
        labels, lab = np.unique(lab, return_inverse=True)
        pair, count = np.unique(ra * labels.size + lab, return_counts=True)
        pairs = np.stack([pair // labels.size, labels[pair % labels.size]])
        by_region = np.argsort(region, kind="stable")
        start = np.searchsorted(region[by_region], np.arange(n + 1))
        gain = _move_gains(keys, cost, chosen, start, by_region, pairs[0], pairs[1],
                           count.astype(np.float64), smooth)  # fmt: skip
        best = np.full(n, 0.0)
        np.maximum.at(best, pairs[0], gain)
        take = np.full(n, -1, dtype=np.int64)
        win = gain > 0
        take[pairs[0][win & (gain >= best[pairs[0]])]] = pairs[1][win & (gain >= best[pairs[0]])]
        # of two neighbouring regions that would both move, the one that gains more
        moving = take >= 0
        clash = moving[ra] & moving[other] & (best[ra] <= best[other])
        take[ra[clash]] = -1
        if not (take >= 0).any():
            break
        chosen = np.where(take[region] >= 0, take[region], chosen)
    return chosen


def potts(
    keys: np.ndarray, cost: np.ndarray, faces: np.ndarray, smooth: float, passes: int,
    time_ns: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """(F,) the label of each facet among its candidates ``keys`` (F,K) int64 (-1: no
    candidate) of data ``cost`` (F,K) (inf: excluded) minimising the data costs plus
    ``smooth`` for each pair of neighbouring facets (:func:`neighbours`) of other labels:
    the cheapest candidate, then ``passes`` of iterated conditional modes, each facet in
    turn in the order of ``time_ns`` (F,) (then of its vertices: whatever the facets'
    order), so that a label spreads along the track as far as it stays within
    ``smooth`` of the cheapest. -1 where no candidate is finite."""
    n = keys.shape[0]
    cost = np.where(keys >= 0, cost, np.inf)
    some = np.isfinite(cost).any(axis=1)
    chosen = np.where(some, keys[np.arange(n), np.argmin(cost, axis=1)], -1)
    if passes and smooth > 0 and n:
        a, b = neighbours(faces)
        f_all, g_all = np.concatenate([a, b]), np.concatenate([b, a])
        by_f = np.argsort(f_all, kind="stable")
        start = np.searchsorted(f_all[by_f], np.arange(n + 1))
        corners = np.sort(faces, axis=1).T[::-1]
        order = np.lexsort((*corners, *([] if time_ns is None else [time_ns])))
        _icm(order, start, g_all[by_f], keys, cost, float(smooth), passes, chosen)
        chosen = _region_moves(keys, cost, a, b, chosen, float(smooth), REGION_ROUNDS)
        _icm(order, start, g_all[by_f], keys, cost, float(smooth), 1, chosen)
    return chosen


@numba.njit(cache=True, nogil=True)
def _facet_costs(corner, uv, seen, P, dt_s, per_s, per_rad2, out):  # type: ignore[no-untyped-def]
    """out[i]: facet i's data cost in a frame (module docstring), inf unless its corners
    ``corner`` (F,3) are all ``seen``: pixels ``uv`` (V,2), camera-frame points ``P`` (V,3)."""
    for i in range(corner.shape[0]):
        a, b, c = corner[i, 0], corner[i, 1], corner[i, 2]
        out[i] = np.inf
        if not (seen[a] and seen[b] and seen[c]):
            continue
        e1u, e1v = uv[b, 0] - uv[a, 0], uv[b, 1] - uv[a, 1]
        e2u, e2v = uv[c, 0] - uv[a, 0], uv[c, 1] - uv[a, 1]
        area = 0.5 * abs(e1u * e2v - e1v * e2u)
        if area <= 0.0:
            continue
        x = P[a, 0] + P[b, 0] + P[c, 0]
        y = P[a, 1] + P[b, 1] + P[c, 1]
        theta = np.arctan2(np.hypot(x, y), P[a, 2] + P[b, 2] + P[c, 2])
        out[i] = -np.log(area) + per_s * dt_s[i] + per_rad2 * theta * theta


def candidate_costs(
    job: Job, xyz: np.ndarray, time_ns: np.ndarray, faces: np.ndarray, camera: np.ndarray,
    frame: np.ndarray, occluders: Occluders, weights: ViewWeights,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """((F,K) int64 view keys (camera << 32 | session frame, -1 none), (F,K) float64 data
    costs, inf where excluded) of the facets ``faces`` (F,3) on vertices ``xyz`` (V,3) m
    scanned at ``time_ns`` (V,) (laser clock) and coloured from ``camera`` (V,) /
    ``frame`` (V,) (the candidate frames are those): K = cameras x (2 window + 1)."""
    W = weights.window
    per_cam = 2 * W + 1
    n_f = faces.shape[0]
    keys = np.full((n_f, len(job.cameras) * per_cam), -1, dtype=np.int64)
    cost = np.full(keys.shape, np.inf)
    t_f = time_ns[faces].mean(axis=1)
    opts = job.options
    pose_at = job.trajectory.pose_at if job.trajectory is not None else None
    at_origin = Rigid.identity()  # the points are given in the camera's frame
    for c, cj in enumerate(job.cameras):
        used = np.unique(frame[(camera == c) & (frame >= 0)])
        if used.size == 0:
            continue
        t_frame = on_laser_clock(cj.frame_new[used], cj.time_offset_ns)
        period = float(np.median(np.diff(t_frame))) if used.size > 1 else 4e7
        max_dt = opts.max_dt_s * 1e9 + W * period
        r0 = np.clip(np.searchsorted(t_frame, t_f), 1, max(1, used.size - 1))
        if used.size > 1:  # the nearest of the two frames either side
            r0 -= t_f - t_frame[r0 - 1] < t_frame[r0] - t_f
        else:
            r0[:] = 0
        order = np.argsort(r0, kind="stable")
        context = np.array([-1, 1], dtype=np.int64) * round(weights.context_s * 1e9)
        r0_sorted = r0[order]
        Rs, ts = camera_poses(cj.cam, job.laser_to_vehicle, pose_at, t_frame)
        model = cj.cam.model
        f_px = 0.5 * (model.fx + model.fy)
        for r in range(used.size):
            lo, hi = np.searchsorted(r0_sorted, [r - W, r + W + 1])
            fs = order[lo:hi]
            fs = fs[np.abs(t_f[fs] - t_frame[r]) <= max_dt]
            if fs.size == 0:
                continue
            slot = c * per_cam + (r - r0[fs] + W)
            keys[fs, slot] = (c << 32) | int(used[r])
            # the facets' vertices: a run of scans (vertices and facets in time order)
            corner = faces[fs]
            v_lo = int(corner.min())
            P = (xyz[v_lo : int(corner.max()) + 1] - ts[r]) @ Rs[r]
            uv, ok = projection.project(P, model, at_origin)
            if not ok.any():
                continue
            # the depth buffer of the laser points scanned around the frame's time, over
            # the cells of the vertices' pixels (and as far as a point's splat reaches)
            cell = opts.cell_px
            lo_px = (np.floor(uv[ok].min(axis=0) / cell) - MAX_SPLAT_CELLS) * cell
            hi_px = (np.floor(uv[ok].max(axis=0) / cell) + MAX_SPLAT_CELLS + 1) * cell
            o_lo, o_hi = np.searchsorted(occluders.time_ns, t_frame[r] + context)
            P_o = (occluders.xyz[o_lo:o_hi] - ts[r]) @ Rs[r]
            uv_o, ok_o = projection.project(P_o, model, at_origin)
            ok_o &= ((uv_o >= lo_px) & (uv_o < hi_px)).all(axis=1)
            box = (int(hi_px[1] - lo_px[1]), int(hi_px[0] - lo_px[0]))
            zbuf = occlusion_depths(
                uv_o[ok_o] - lo_px, np.linalg.norm(P_o[ok_o], axis=1),
                occluders.size_m[o_lo:o_hi][ok_o], f_px, box, cell,
            )  # fmt: skip
            seen = ok & visible(zbuf, uv - lo_px, np.linalg.norm(P, axis=1), cell,
                                opts.margin_m, opts.margin_rel)  # fmt: skip
            got = np.empty(fs.size)
            _facet_costs(corner - v_lo, uv, seen, P, np.abs(t_f[fs] - t_frame[r]) * 1e-9,
                         weights.per_s, weights.per_rad2, got)  # fmt: skip
            cost[fs, slot] = got
    return keys, cost


def select_views(
    job: Job, xyz: np.ndarray, time_ns: np.ndarray, faces: np.ndarray, camera: np.ndarray,
    frame: np.ndarray, occluders: Occluders, weights: ViewWeights | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each facet's view: ((F,) camera index, (F,) session frame), -1 for none (module
    docstring); arguments as :func:`candidate_costs` takes them."""
    weights = weights or ViewWeights()
    keys, cost = candidate_costs(job, xyz, time_ns, faces, camera, frame, occluders, weights)
    # the vertices' own view, the last resort
    own_cam, own_frame = facet_views(camera, frame, faces)
    own = np.where(own_cam >= 0, (own_cam << 32) | np.maximum(own_frame, 0), -1)
    keys = np.concatenate([keys, own[:, None]], axis=1)
    cost = np.concatenate([cost, np.full((faces.shape[0], 1), _FALLBACK_COST)], axis=1)
    chosen = potts(keys, cost, faces, weights.smooth, weights.passes, time_ns[faces].mean(axis=1))
    return np.where(chosen >= 0, chosen >> 32, -1), np.where(chosen >= 0, chosen & 0xFFFFFFFF, -1)
