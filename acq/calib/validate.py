"""Calibration validation on a coloured two-depth pattern (``acq calibrate validate``,
paper §4.2, Table 4).

The pattern: two planar sets at different depths in front of the still rig, a front set
coloured red/green and a back set (wall) coloured blue/yellow (:data:`DEFAULT_COLOURS`,
RGB; what ``sim/validation_log.py`` paints). As in the paper, a laser point's set comes
from the geometry alone and its colour from the image:

1. sets (:func:`find_sets`): on the per-beam median scan, among the points in the
   camera's view, the two largest parallel lines (RANSAC, inliers within ``tol_m``);
   the nearer is the front set, the farther the back; back points count only within
   the front set's extent along the line (+25 % at each end). Back points the camera
   cannot see (:func:`occluded`: the camera-to-point segment crosses the front set,
   assuming the pattern's edges are perpendicular to the scan plane, as bars or panels
   crossing the laser line are) are left out;
2. every scan's points on a set go into the camera (``camera_to_laser`` inverted, the
   model) and the frame nearest in time (within ``max_dt_s``); the pixel's colour class is
   the nearest (RGB) of the pattern colours and of :data:`NEUTRALS` (non-pattern greys);
   a point is right when that class is one of its set's colours;
3. its pixel error: 0 when right, else the distance (px) from its pixel to the nearest
   pixel of its set's colours, binned 0/1/2/3/>3 px (Table 4);
4. the edge error (:func:`edge_errors`): at each end of a front run (a depth edge), the
   laser's edge (half a beam beyond the last front point) is projected, and the image's
   edge is found along the projected line (sub-pixel, where the colour turns from the
   front set's); signed error = image edge minus laser edge (px, positive outward).
   ``sigma`` is the standard deviation of a normal fit (mean, std) to those errors.

Units: metres, pixels; times host ns unless ``_s``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from acq.calib.plots import draw_legend
from acq.camera.calibfile import CameraCalib
from acq.errors import AcqError
from acq.log import drive_log
from acq.provenance import write_image

__all__ = [
    "BACK",
    "DEFAULT_COLOURS",
    "FRONT",
    "NEUTRALS",
    "NoPatternError",
    "Sets",
    "ValidationResult",
    "classify",
    "edge_errors",
    "find_sets",
    "occluded",
    "palette_of",
    "validate",
]

DEFAULT_COLOURS: dict[str, tuple[int, int, int]] = {
    "red": (200, 40, 40),
    "green": (40, 170, 60),
    "blue": (40, 70, 200),
    "yellow": (230, 210, 40),
}
"""The pattern's colours, RGB."""
FRONT = ("red", "green")
BACK = ("blue", "yellow")
NEUTRALS: dict[str, tuple[int, int, int]] = {
    "black": (0, 0, 0),
    "dark": (90, 90, 90),
    "light": (170, 170, 170),
    "white": (255, 255, 255),
}
"""Non-pattern colour classes (RGB): a pixel nearest one of these is on no set."""
BINS = ("0", "1", "2", "3", ">3")


class NoPatternError(AcqError, ValueError):
    """The recording does not show the validation pattern (a runtime failure: exit 1)."""


# --- geometry: the two sets -------------------------------------------------------------


@dataclass(frozen=True)
class Sets:
    """Per beam of the median scan: ``label`` (n,) 0 none, 1 front, 2 back (only those
    evaluated: visible and within the window); ``occluded`` (n,) back points hidden from
    the camera; ``median`` (n,) ranges (m); ``edges`` (E,2) int (beam of a front run's
    end, +1 or -1: the side the edge is on)."""

    label: np.ndarray
    occluded: np.ndarray
    median: np.ndarray
    edges: np.ndarray


def _ransac_line(
    P: np.ndarray, cand: np.ndarray, tol_m: float, rng: np.random.Generator, tries: int = 300
) -> tuple[np.ndarray, float, np.ndarray]:
    """The line (unit normal n, offset c: n.p = c) with most inliers among ``P[cand]``."""
    best: tuple[np.ndarray, float, np.ndarray] = (np.zeros(2), 0.0, np.zeros(len(P), bool))
    idx = np.flatnonzero(cand)
    if idx.size < 2:
        return best
    for _ in range(tries):
        i, j = rng.choice(idx, 2, replace=False)
        d = P[j] - P[i]
        norm = float(np.hypot(*d))
        if norm < 1e-6:
            continue
        n = np.array([-d[1], d[0]]) / norm
        c = float(n @ P[i])
        inl = cand & (np.abs(P @ n - c) < tol_m)
        if inl.sum() > best[2].sum():
            best = (n, c, inl)
    n, c, inl = best
    if inl.sum() >= 2:  # refit on the inliers
        Q = P[inl]
        m = Q.mean(axis=0)
        _, _, Vt = np.linalg.svd(Q - m)
        n = Vt[1]
        c = float(n @ m)
        inl = cand & (np.abs(P @ n - c) < tol_m)
    return n, c, inl


def _cross(
    o: npt.NDArray[np.float64], a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (
        b[..., 0] - o[..., 0]
    )


def occluded(camera_xy: np.ndarray, points: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """(N,) whether the 2-D segment camera -> each of ``points`` (N,2) crosses one of
    ``segments`` (S,2,2) (all in the scan plane, m)."""
    if not len(points) or not len(segments):
        return np.zeros(len(points), bool)
    C = np.broadcast_to(camera_xy, points.shape)[:, None, :]
    P = points[:, None, :]
    A, B = segments[None, :, 0, :], segments[None, :, 1, :]
    d1, d2 = _cross(A, B, C), _cross(A, B, P)
    d3, d4 = _cross(C, P, A), _cross(C, P, B)
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    return np.asarray(hit.any(axis=1))


def find_sets(
    log: drive_log.DriveLog,
    camera: CameraCalib,
    *,
    tol_m: float = 0.04,
    occlusion_beams: float = 2.0,
    seed: int = 0,
) -> Sets:
    """The front and back sets on the median scan (module docstring, step 1); ValueError
    when there are not two parallel lines at different depths in the camera's view. The
    front set occludes ``occlusion_beams`` beam steps beyond its runs' ends (a margin for
    blur)."""
    r = np.where(np.isfinite(log.ranges), log.ranges, np.nan)
    with warnings.catch_warnings():  # beams with no return in any scan stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(r, axis=0) if log.n_scans > 1 else r[0]
    a = log.angle_min + log.angle_increment * np.arange(med.size)
    P = np.column_stack([np.nan_to_num(med * np.cos(a)), np.nan_to_num(med * np.sin(a))])
    # only points in the camera's view can be on a set: what lies behind it (a street's
    # far side, the vehicle) is left out, however large
    P3 = np.column_stack([P, np.zeros(len(P))])
    _, seen = camera.model.project(camera.camera_to_laser.inverse().apply(P3))
    ok = np.isfinite(med) & seen
    rng = np.random.default_rng(seed)
    n1, c1, in1 = _ransac_line(P, ok, tol_m, rng)
    c2, in2 = c1, np.zeros_like(in1)
    rest = ok & ~in1
    for _ in range(5):  # the largest line parallel to the first, not the same
        n, c, inl = _ransac_line(P, rest, tol_m, rng)
        if inl.sum() < 10:
            break
        if abs(float(n @ n1)) > math.cos(math.radians(5.0)) and abs(abs(c) - abs(c1)) > 3 * tol_m:
            c2, in2 = c, inl
            break
        rest &= ~inl
    if in1.sum() < 10 or in2.sum() < 10:
        raise NoPatternError("no pattern: not two parallel planar sets at different depths")
    front, back = (in1, in2) if abs(c1) < abs(c2) else (in2, in1)
    # the window along the line
    along = P @ np.array([-n1[1], n1[0]])
    lo, hi = along[front].min(), along[front].max()
    margin = 0.25 * (hi - lo)
    back &= (along >= lo - margin) & (along <= hi + margin)
    # front runs -> occluding segments, extended one beam beyond each end; edges
    seg: list[np.ndarray] = []
    edges: list[tuple[int, int]] = []
    padded = np.concatenate([[False], front, [False]]).astype(np.int8)
    starts = np.flatnonzero(np.diff(padded) == 1)
    ends = np.flatnonzero(np.diff(padded) == -1)
    step = abs(log.angle_increment)
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        if e - s < 2:
            continue
        ext = (occlusion_beams * med[s] * step, occlusion_beams * med[e - 1] * step)
        Q = P[s:e].copy()
        u0 = (Q[0] - Q[1]) / max(float(np.linalg.norm(Q[0] - Q[1])), 1e-9)
        u1 = (Q[-1] - Q[-2]) / max(float(np.linalg.norm(Q[-1] - Q[-2])), 1e-9)
        Q[0] += u0 * ext[0]
        Q[-1] += u1 * ext[1]
        seg.extend(np.stack([Q[:-1], Q[1:]], axis=1))
        for beam, side in ((s, -1), (e - 1, 1)):
            nb = beam + side
            if 0 <= nb < med.size and (not ok[nb] or med[nb] > med[beam] + 3 * tol_m):
                edges.append((beam, side))
    cam_xy = camera.camera_to_laser.translation[:2]
    occ = np.zeros(med.size, bool)
    bi = np.flatnonzero(back)
    occ[bi] = occluded(cam_xy, P[bi], np.array(seg).reshape(-1, 2, 2))
    label = np.zeros(med.size, np.int64)
    label[front] = 1
    label[back & ~occ] = 2
    return Sets(label, occ & back, med, np.array(edges, np.int64).reshape(-1, 2))


# --- colour -------------------------------------------------------------------------------


def palette_of(colours: dict[str, tuple[int, int, int]]) -> tuple[list[str], np.ndarray]:
    """(names, (K,3) BGR float32) of the pattern's ``colours`` (RGB) and the neutrals."""
    names = list(colours) + list(NEUTRALS)
    rgb = np.array([*colours.values(), *NEUTRALS.values()], np.float32)
    return names, rgb[:, ::-1].copy()  # BGR


def classify(bgr: np.ndarray, palette: np.ndarray) -> npt.NDArray[np.int64]:
    """(H,W) index of the nearest ``palette`` (K,3) BGR colour of each pixel."""
    img = bgr.astype(np.float32)
    d = [np.sum((img - c) ** 2, axis=2) for c in palette]
    nearest: np.ndarray = np.argmin(np.stack(d), axis=0)
    return nearest.astype(np.int64)


def _scores(samples: np.ndarray, palette: np.ndarray, mine: np.ndarray) -> np.ndarray:
    """(N,) distance to the nearest other colour minus to the nearest of ``mine`` (>0: mine)."""
    d = np.sqrt(((samples[:, None, :] - palette[None, :, :]) ** 2).sum(axis=2))
    return np.asarray(d[:, ~mine].min(axis=1) - d[:, mine].min(axis=1))


def edge_errors(
    bgr: np.ndarray,
    palette: np.ndarray,
    front: np.ndarray,
    edge_uv: np.ndarray,
    inner_uv: np.ndarray,
    reach_px: float = 6.0,
) -> np.ndarray:
    """Signed image-minus-laser edge errors (px, positive outward; NaN: no edge found).

    ``edge_uv`` (E,2) the projected laser edges, ``inner_uv`` (E,2) points inside the run
    giving the outward direction; ``front`` (K,) bool, the front set's palette entries."""
    out = np.full(len(edge_uv), np.nan)
    s = np.arange(-reach_px, reach_px + 1e-9, 0.1)
    img = bgr.astype(np.float32)
    for k, (e, i) in enumerate(zip(edge_uv, inner_uv, strict=True)):
        d = e - i
        norm = float(np.hypot(*d))
        if norm < 1e-6:
            continue
        pts = (e + s[:, None] * (d / norm)).astype(np.float32)
        samples = cv2.remap(
            img, pts[:, 0].reshape(1, -1), pts[:, 1].reshape(1, -1), cv2.INTER_LINEAR
        ).reshape(-1, 3)
        sc = _scores(samples, palette, front)
        flips = np.flatnonzero((sc[:-1] > 0) & (sc[1:] <= 0))
        if not flips.size:
            continue
        j = flips[np.argmin(np.abs(s[flips]))]
        f = sc[j] / (sc[j] - sc[j + 1])
        out[k] = s[j] + f * (s[j + 1] - s[j])
    return out


# --- the whole log ----------------------------------------------------------------------


@dataclass
class ValidationResult:
    """Points evaluated, right, per set (``front``/``back``: [points, right]), the
    pixel-error histogram (counts for 0/1/2/3/>3 px), the back beams left out as
    occluded, the edge errors' normal fit (``edge_mean_px``, ``sigma_px``, ``n_edges``)
    and ``frames``: per frame used [frame time s from the first scan, points, right]."""

    points: int = 0
    right: int = 0
    front: list[int] = field(default_factory=lambda: [0, 0])
    back: list[int] = field(default_factory=lambda: [0, 0])
    histogram: list[int] = field(default_factory=lambda: [0] * len(BINS))
    occluded_beams: int = 0
    edge_mean_px: float = math.nan
    sigma_px: float = math.nan
    n_edges: int = 0
    frames: list[list[float]] = field(default_factory=list)

    @property
    def share_right(self) -> float:
        return self.right / self.points if self.points else 0.0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["share_right"] = self.share_right
        d["histogram"] = dict(zip(BINS, self.histogram, strict=True))
        d["histogram_share"] = {
            b: (c / self.points if self.points else 0.0)
            for b, c in zip(BINS, self.histogram, strict=True)
        }
        for k in ("edge_mean_px", "sigma_px"):
            d[k] = None if math.isnan(d[k]) else d[k]
        return d


def _nearest(frame_ns: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
    """(N,) index of the frame nearest in time to each of ``t_ns`` (frames sorted)."""
    hi = np.clip(np.searchsorted(frame_ns, t_ns), 0, frame_ns.size - 1)
    lo = np.maximum(hi - 1, 0)
    return np.where(np.abs(frame_ns[lo] - t_ns) <= np.abs(frame_ns[hi] - t_ns), lo, hi)


def _decode(jpeg: bytes) -> np.ndarray | None:
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    return img if img is not None and img.ndim == 3 else None


def _colour(right: bool) -> tuple[int, int, int]:
    """An overlay point's colour (BGR): green on the right colour, red otherwise."""
    return (0, 255, 0) if right else (0, 0, 255)


def validate(
    log: drive_log.DriveLog,
    camera: CameraCalib,
    *,
    colours: dict[str, tuple[int, int, int]] | None = None,
    max_dt_s: float = 0.1,
    overlay: Path | None = None,
) -> ValidationResult:
    """Validate ``camera`` (intrinsics and camera_to_laser) on the pattern in ``log``
    (module docstring); ``overlay``: a PNG of the frame with most points (green right,
    red wrong). ValueError when the log has no frames or no pattern."""
    if not log.n_frames:
        raise ValueError("the log has no camera frames")
    colours = colours or DEFAULT_COLOURS
    names, palette = palette_of(colours)
    in_front = np.array([n in FRONT for n in names])
    in_back = np.array([n in BACK for n in names])
    sets = find_sets(log, camera)
    beams = np.flatnonzero(sets.label > 0)
    a = log.angle_min + log.angle_increment * np.arange(sets.median.size)
    T_inv = camera.camera_to_laser.inverse()
    model = camera.model
    frame_ns = log.frame_ns - round(camera.time_offset_s * 1e9)
    j = _nearest(frame_ns, log.scan_ns)
    near = np.abs(frame_ns[j] - log.scan_ns) <= max_dt_s * 1e9
    res = ValidationResult(occluded_beams=int(sets.occluded.sum()))
    # the laser's edges (median scan), projected once
    e_beam, e_side = sets.edges[:, 0], sets.edges[:, 1]
    r_e = sets.median[e_beam]
    ang_e = a[e_beam] + 0.5 * e_side * log.angle_increment
    ang_i = a[e_beam] - 2.0 * e_side * log.angle_increment
    E = np.column_stack([r_e * np.cos(ang_e), r_e * np.sin(ang_e), np.zeros_like(r_e)])
    inner = np.column_stack([r_e * np.cos(ang_i), r_e * np.sin(ang_i), np.zeros_like(r_e)])
    e_uv, e_ok = model.project(T_inv.apply(E))
    i_uv, i_ok = model.project(T_inv.apply(inner))
    e_ok &= i_ok
    errors: list[np.ndarray] = []
    best_n, best_img = 0, None
    best_uv, best_right = np.zeros((0, 2)), np.zeros(0, bool)
    t0 = int(log.scan_ns[0])
    for f in np.unique(j[near]).tolist():
        img = _decode(log.jpegs[f])
        if img is None:
            continue
        cls = classify(img, palette)
        fm, bm = in_front[cls], in_back[cls]
        dist = {
            1: cv2.distanceTransform((~fm).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE),
            2: cv2.distanceTransform((~bm).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE),
        }
        scans = np.flatnonzero(near & (j == f))
        r = log.ranges[np.ix_(scans, beams)].astype(np.float64)
        lab = np.broadcast_to(sets.label[beams], r.shape)
        ang = np.broadcast_to(a[beams], r.shape)
        keep = np.isfinite(r) & (np.abs(r - sets.median[beams]) < 0.1)
        r, lab, ang = r[keep], lab[keep], ang[keep]
        P = np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(r)])
        uv, ok = model.project(T_inv.apply(P))
        uv, lab = uv[ok], lab[ok]
        px = np.rint(uv).astype(np.int64)
        px[:, 0] = np.clip(px[:, 0], 0, img.shape[1] - 1)
        px[:, 1] = np.clip(px[:, 1], 0, img.shape[0] - 1)
        c = cls[px[:, 1], px[:, 0]]
        right = np.where(lab == 1, in_front[c], in_back[c])
        err = np.where(lab == 1, dist[1][px[:, 1], px[:, 0]], dist[2][px[:, 1], px[:, 0]]).astype(
            np.float64
        )
        err[right] = 0.0
        bins = np.minimum(np.rint(err), 4).astype(np.int64)
        res.histogram = (np.array(res.histogram) + np.bincount(bins, minlength=5)).tolist()
        res.points += int(right.size)
        res.right += int(right.sum())
        for s, which in ((1, res.front), (2, res.back)):
            which[0] += int((lab == s).sum())
            which[1] += int(right[lab == s].sum())
        res.frames.append([(int(log.frame_ns[f]) - t0) * 1e-9, int(right.size), int(right.sum())])
        if np.any(e_ok):
            errors.append(edge_errors(img, palette, in_front, e_uv[e_ok], i_uv[e_ok]))
        if right.size > best_n:
            best_n, best_img, best_uv, best_right = int(right.size), img, uv, right
    if errors:
        e = np.concatenate(errors)
        e = e[np.isfinite(e) & (np.abs(e) < 5.0)]
        res.n_edges = int(e.size)
        if e.size >= 2:
            res.edge_mean_px = float(e.mean())
            res.sigma_px = float(e.std(ddof=1))
    if overlay is not None and best_img is not None:
        draw = best_img.copy()
        for (u, v), good in zip(best_uv, best_right, strict=True):
            cv2.circle(draw, (round(float(u)), round(float(v))), 1, _colour(good), -1)
        share = 100 * float(np.mean(best_right)) if len(best_right) else 0.0
        draw_legend(draw, [
            (None, f"frame with the most pattern points: {len(best_right)}, {share:.1f} % right"),
            (_colour(True), "laser point on its set's colours (bars or panel)"),
            (_colour(False), "laser point on another colour"),
        ])  # fmt: skip
        overlay.parent.mkdir(parents=True, exist_ok=True)
        write_image(overlay, draw)
    return res
