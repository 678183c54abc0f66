"""The facets of the scan grid (:func:`acq.mesh.grid_facets`, default rules) against the
truth of the simulated drive.

Data: ``acq.sim.drive_log.write_drive_log`` — ``--seconds`` (60) of the synthetic street at
20 km/h, one fisheye. Meshed twice: the noise-free hit points of the truth, each with the
laser's true origin at its own time; and the points as ``acq colorize --frame world``
places them from the log (:func:`acq.cloud.chunks.place`: re-timed scans, odometry poses,
motion compensated, 1 cm range noise), each with the laser's origin from the same poses.

Which surface a return lies on is read from the truth's geometry: the street's object
(a box, a pole, a quad of the validation pattern, or the ground) whose surface holds its
noise-free hit. Two objects touch when their boxes, grown by 2 cm, meet (a building and
the sidewalk, two buildings side by side, a car's cabin and body; not a car body and the
road: it stands 0.2 m up on wheels the street does not model).

One JSON line:

- ``continuous``: the returns on a continuous surface — one of its grid cells has its four
  corners on the same object with every side under 0.5 m — and the share of them in at
  least one facet (target >= 95 %), for the truth and the placed points;
- ``facets_across_discontinuity``: facets with vertices on two objects that do not touch
  (a building's edge to the row behind, a car body to the road under it), and of those
  ``..._depth_step_over_0_5_m`` the ones whose two ends' ranges differ by more than 0.5 m
  (target 0: a step of a few decimetres between consecutive profiles, 0.14 m apart, looks
  like a surface at 20-30 degrees to the ray, which no local rule can tell apart); for
  information, facets joining two touching objects (a corner);
- ``seconds_per_million``: :func:`grid_facets`'s time per million points (median of 5
  runs, and the best: the machine is shared, ``load_average`` says how busy it was), and
  its peak memory per million points (``tracemalloc``, numpy's buffers included).

Run as a script: ``python bench/mesh_facets.py [--seconds S] [--work DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

from acq.mesh import FacetRules, grid_facets
from acq.sim.world import Street

CLOSE_M = 0.5  # grid neighbours nearer than this on one object: a continuous surface
ON_SURFACE_M = 5e-3  # the truth's points are float32 (0.03 mm at 400 m)
TOUCH_M = 0.02
DEEP_M = 0.5  # a depth step: ranges of a facet's ends on objects apart differ by more


def object_boxes(street: Street) -> np.ndarray:
    """(O,6) the bounds (xmin, xmax, ymin, ymax, zmin, zmax) m of the street's objects:
    0 the ground, then boxes, cylinders, quads."""
    big = 1e9
    rows = [(-big, big, -big, big, 0.0, 0.0)]
    rows += [(b.xmin, b.xmax, b.ymin, b.ymax, b.zmin, b.zmax) for b in street.boxes]
    rows += [
        (c.x - c.radius, c.x + c.radius, c.y - c.radius, c.y + c.radius, c.zmin, c.zmax)
        for c in street.cylinders
    ]
    for q in street.quads:
        corners = np.array(q.origin) + np.array([[0, 0], [1, 0], [0, 1], [1, 1]]) @ np.array(
            [q.u, q.v]
        )
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        rows.append((lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
    return np.array(rows, dtype=np.float64)


def object_ids(street: Street, P: np.ndarray) -> np.ndarray:
    """(N,) the object (index into :func:`object_boxes`) whose surface holds each point
    of ``P`` (N,3) m; -1 for none (NaN, or on no surface)."""
    ids = np.full(P.shape[0], -1, dtype=np.int64)
    finite = np.isfinite(P).all(axis=1)
    ids[finite & (np.abs(P[:, 2]) < ON_SURFACE_M)] = 0
    order = np.argsort(np.where(finite, P[:, 0], np.inf))
    xs = P[order, 0]
    tol = ON_SURFACE_M
    nb, nc = len(street.boxes), len(street.cylinders)

    def span(x0: float, x1: float) -> np.ndarray:
        i0, i1 = np.searchsorted(xs, [x0 - tol, x1 + tol])
        return order[i0:i1]

    for i, b in enumerate(street.boxes):
        j = span(b.xmin, b.xmax)
        p = P[j]
        inside = (
            (p[:, 1] >= b.ymin - tol) & (p[:, 1] <= b.ymax + tol)
            & (p[:, 2] >= b.zmin - tol) & (p[:, 2] <= b.zmax + tol)
        )  # fmt: skip
        ids[j[inside]] = 1 + i
    for i, c in enumerate(street.cylinders):
        j = span(c.x - c.radius, c.x + c.radius)
        p = P[j]
        r = np.hypot(p[:, 0] - c.x, p[:, 1] - c.y)
        on = (np.abs(r - c.radius) < tol) & (p[:, 2] >= c.zmin - tol) & (p[:, 2] <= c.zmax + tol)
        ids[j[on]] = 1 + nb + i
    for i, q in enumerate(street.quads):
        o, u, v = (np.array(a, np.float64) for a in (q.origin, q.u, q.v))
        lo, hi = sorted((o[0], o[0] + u[0] + v[0]))
        j = span(min(lo, o[0] + u[0], o[0] + v[0]), max(hi, o[0] + u[0], o[0] + v[0]))
        n = np.cross(u, v)
        n /= np.linalg.norm(n)
        d = P[j] - o
        ab = np.linalg.lstsq(np.stack([u, v], axis=1), d.T, rcond=None)[0].T
        on = (np.abs(d @ n) < tol) & (ab >= -1e-3).all(axis=1) & (ab <= 1 + 1e-3).all(axis=1)
        ids[j[on]] = 1 + nb + nc + i
    return ids


def touching(boxes: np.ndarray) -> np.ndarray:
    """(O,O) whether objects' bounds, grown by TOUCH_M, meet."""
    lo, hi = boxes[:, 0::2] - TOUCH_M, boxes[:, 1::2] + TOUCH_M
    meet: np.ndarray = (
        (lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :])
    ).all(axis=2)
    return meet


def continuous_returns(ids: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(S,N) whether each return of the grid (``ids`` (S,N), ``P`` (S,N,3)) is on a
    continuous surface (module docstring)."""
    S, N = ids.shape
    corners = [(slice(0, S - 1), slice(0, N - 1)), (slice(0, S - 1), slice(1, N)),
               (slice(1, S), slice(0, N - 1)), (slice(1, S), slice(1, N))]  # fmt: skip
    a = corners[0]
    same = ids[a] >= 0
    for c in corners[1:]:
        same &= ids[c] == ids[a]
    for c0, c1 in ((0, 1), (0, 2), (1, 3), (2, 3)):
        gap = np.linalg.norm(P[corners[c0]] - P[corners[c1]], axis=2)
        with np.errstate(invalid="ignore"):
            same &= gap < CLOSE_M
    out = np.zeros((S, N), dtype=bool)
    for c in corners:
        out[c] |= same
    return out


def judge(
    scan: np.ndarray, step: np.ndarray, xyz: np.ndarray, origin: np.ndarray,
    ids: np.ndarray, cont: np.ndarray, meet: np.ndarray, repeats: int = 5,
    rules: FacetRules | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Mesh the points (``ids``, ``cont`` (S,N) of the truth's grid) and judge the facets."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        tri = grid_facets(scan, step, xyz, origin, rules or FacetRules())
        times.append(time.perf_counter() - t0)
    tracemalloc.start()  # numpy reports its buffers to tracemalloc
    grid_facets(scan, step, xyz, origin, rules or FacetRules())
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    in_facet = np.zeros(scan.size, dtype=bool)
    in_facet[tri.ravel()] = True
    on_cont = cont[scan, step]
    obj = ids[scan, step][tri]  # (F,3)
    r = np.linalg.norm(xyz - origin, axis=1)[tri]  # (F,3) each vertex's range
    unknown = (obj < 0).any(axis=1)
    across = np.zeros(tri.shape[0], dtype=bool)
    deep = np.zeros(tri.shape[0], dtype=bool)
    corner = np.zeros(tri.shape[0], dtype=bool)
    for i in range(3):
        x, y = obj[:, i], obj[:, (i + 1) % 3]
        ok = (x >= 0) & (y >= 0) & (x != y)
        apart = np.zeros_like(ok)
        apart[ok] = ~meet[x[ok], y[ok]]
        across |= apart
        deep |= apart & (np.abs(r[:, i] - r[:, (i + 1) % 3]) > DEEP_M)
        corner |= ok & ~apart
    return {
        "points": int(scan.size),
        "facets": int(tri.shape[0]),
        "continuous_returns": int(on_cont.sum()),
        "continuous_in_facet": round(float(in_facet[on_cont].mean()), 4),
        "all_returns_in_facet": round(float(in_facet.mean()), 4),
        "facets_across_discontinuity": int(across.sum()),
        "facets_across_depth_step_over_0_5_m": int(deep.sum()),
        "facets_joining_touching_objects": int((corner & ~across).sum()),
        "facets_on_unidentified_points": int(unknown.sum()),
        "seconds_per_million": round(float(np.median(times)) / (scan.size / 1e6), 3),
        "seconds_per_million_best": round(min(times) / (scan.size / 1e6), 3),
        "peak_mb_per_million": round(peak / 2**20 / (scan.size / 1e6)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument(
        "--work", type=Path, default=None, help="folder for the drive (default: a temporary one)"
    )
    args = ap.parse_args()
    from acq.cloud import chunks
    from acq.cloud.colorize import Report, prepare
    from acq.cloud.job import remap
    from acq.sim.drive_log import write_drive_log

    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        truth = write_drive_log(work, args.seconds)
        P = truth.points.astype(np.float64)  # (S,N,3)
        S, N = P.shape[:2]
        ids = object_ids(truth.street, P.reshape(-1, 3)).reshape(S, N)
        hit = np.isfinite(P).all(axis=2)
        cont = continuous_returns(ids, P)
        meet = touching(object_boxes(truth.street))

        s, k = np.nonzero(hit)
        origins = origins_of(truth, s, k)
        row: dict[str, Any] = {"bench": "mesh_facets", "seconds": args.seconds,
                               "rules": vars(FacetRules())}  # fmt: skip
        row["hits_unidentified"] = int((hit & (ids < 0)).sum())
        row["load_average"] = round(os.getloadavg()[0], 2)
        row["truth"] = judge(s, k, P[s, k], origins, ids, cont, meet)

        job, whole = prepare(truth.files, truth.calibration, Report(output="x"), jpegs=True)
        scan_ns = remap(job.scan_old, job.scan_new, whole.scan_ns)
        keep = np.ones(scan_ns.size, dtype=bool)
        placed = chunks.place(whole, scan_ns, keep, job.trajectory, job.laser_to_vehicle)
        laser_at = job.laser_to_vehicle.apply(np.zeros((placed.time_ns.size, 3)))
        origin = job.trajectory.transform(placed.time_ns, laser_at)
        ok = placed.inside & hit[placed.scan, placed.step]
        ps, pk = placed.scan[ok], placed.step[ok]
        true_r = np.linalg.norm(P[ps, pk] - origins_of(truth, ps, pk), axis=1)  # noise-free
        row["placed_range_vs_truth_m"] = round(float(np.median(np.abs(placed.r[ok] - true_r))), 4)
        row["placed"] = judge(ps, pk, placed.P_world[ok], origin[ok], ids, cont, meet)
    print(json.dumps(row))


def origins_of(truth: Any, s: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N,3) the laser's true position when return (s, k) was measured, m."""
    from acq.sim.sensors import laser_to_world

    return laser_to_world(truth.trajectory, truth.rig, truth.point_t_s()[s, k])[1]


if __name__ == "__main__":
    main()
