"""The search over a camera's pose relative to the laser and its time offset that best
aligns a drive's swath with the camera's frames (:mod:`acq.calib.information`).

Seven parameters, each a change from the calibration given: a small rotation about the
LASER x, y, z axes (rad; ``R = exp([w]x) R_0``, as calib.yaml's std has it, turning the
camera about its own centre), a translation along them (m) and a time offset (s, camera
minus laser time). Every frame's points, placed in the world at their own time, go into
the laser frame as the rig stood at the frame's time and through the camera's model; the
score is the information measure of what they sample there.

First coordinate ascent (:func:`search`: each parameter in turn on a grid of seven
steps around the current best, a least-squares parabola through the grid's top, rounds
with the steps halved; :mod:`acq.calib.pose_check` runs it on every other point, see
:meth:`Swath.every`), which finds the top's neighbourhood but crawls along the valleys
where a rotation and a translation move the image alike; then Newton steps on a
quadratic fitted to the score around the estimate (:func:`newton`), which walk along
them. The swath is cut in blocks of consecutive frames (:meth:`Swath.part`); each
block's estimate is the Newton step from the whole's with the block's own gradient
(:func:`gradient`) and the whole's Hessian (the measure is a mean over the points, so
its curvature does not depend on how many); their spread is the whole's standard error.

Candidates are scored in batches (:meth:`Scorer.many`: a search line's seven, a fit's
57): frame by frame, so that each frame's image is read from memory once a batch.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, replace

import numba
import numpy as np

from acq.calib.information import information
from acq.camera.camera_models import CameraModel
from acq.camera.projection import kernel_args, project_block
from acq.geometry.rotations import matrix_from_rotvec
from acq.geometry.transforms import PoseFn, Rigid, world_to_laser
from acq.time import sync

__all__ = [
    "FIT_STEPS",
    "PARAMS",
    "START_STEPS",
    "Many",
    "Scorer",
    "Swath",
    "concave",
    "gradient",
    "newton",
    "quadratic_fit",
    "search",
    "shifted",
]

PARAMS = ("rx", "ry", "rz", "tx", "ty", "tz", "dt")
"""The parameters: rotation about the laser's axes (rad), translation (m), time (s)."""

START_STEPS = np.array([np.radians(0.4)] * 3 + [0.02] * 3 + [0.002])
"""The first round's step per parameter; a line reaches three steps either side."""

FIT_STEPS = np.array([np.radians(0.2)] * 3 + [0.01] * 3 + [0.002])
"""The quadratic fit's steps per parameter (:func:`quadratic_fit`)."""


def shifted(c2l: Rigid, x: np.ndarray) -> Rigid:
    """``camera_to_laser`` changed by the parameters ``x`` (7,) (module docstring)."""
    return Rigid(matrix_from_rotvec(x[:3]) @ c2l.rotation, c2l.translation + x[3:6])


@dataclass(frozen=True)
class Swath:
    """What the search scores, made once: ``P_world`` (N,3) m the points of every frame
    one after the other (a point may serve several frames), frame ``f``'s from
    ``starts[f]`` to ``starts[f + 1]``; ``frame_ns`` (F,) the frames' stamps (re-timed,
    no offset applied); their grey level and gradient ``features`` ((F,H,W,C) uint8,
    :func:`acq.calib.information.image_features`; C 1 without the gradient); per point
    its return strength's bin ``s_bins`` (N,) and whether it is a depth ``edge`` (N,);
    the bins of grey levels ``grey_lut`` and gradients ``grad_lut`` (F,256), per frame
    (a camera's exposure and white balance change from frame to frame; the laser's
    return strengths do not) and fixed (so that scores compare); ``edge_weight`` the
    depth-edge term's weight."""

    P_world: np.ndarray
    starts: np.ndarray
    frame_ns: np.ndarray
    features: np.ndarray
    s_bins: np.ndarray
    edge: np.ndarray
    grey_lut: np.ndarray
    grad_lut: np.ndarray
    bins: int
    edge_weight: float

    @property
    def frames(self) -> int:
        return int(self.frame_ns.size)

    @property
    def points(self) -> int:
        return int(self.P_world.shape[0])

    def part(self, lo: int, hi: int) -> Swath:
        """Frames ``lo`` to ``hi`` (excluded), their points, the same bins."""
        a, b = int(self.starts[lo]), int(self.starts[hi])
        return replace(
            self, P_world=self.P_world[a:b], starts=self.starts[lo : hi + 1] - a,
            frame_ns=self.frame_ns[lo:hi], features=self.features[lo:hi],
            grey_lut=self.grey_lut[lo:hi], grad_lut=self.grad_lut[lo:hi],
            s_bins=self.s_bins[a:b], edge=self.edge[a:b],
        )  # fmt: skip

    def every(self, k: int) -> Swath:
        """Every ``k``-th point of each frame, the same frames and bins."""
        keep = np.arange(self.points)
        keep = keep[(keep - np.repeat(self.starts[:-1], np.diff(self.starts))) % k == 0]
        starts = np.searchsorted(keep, self.starts)
        return replace(self, P_world=self.P_world[keep], starts=starts.astype(np.int64),
                       s_bins=self.s_bins[keep], edge=self.edge[keep])  # fmt: skip


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sample(images, f, u, v, c):  # type: ignore[no-untyped-def]
    """images[f] at (u, v) px, channel c: bilinear, clamped to the image, rounded."""
    _, h, w, _ = images.shape
    u = min(max(np.float32(u), np.float32(0.0)), np.float32(w - 1))
    v = min(max(np.float32(v), np.float32(0.0)), np.float32(h - 1))
    u0 = min(int(u), w - 2)
    v0 = min(int(v), h - 2)
    a = u - np.float32(u0)
    b = v - np.float32(v0)
    p00 = np.float32(images[f, v0, u0, c])
    p01 = np.float32(images[f, v0, u0 + 1, c])
    p10 = np.float32(images[f, v0 + 1, u0, c])
    p11 = np.float32(images[f, v0 + 1, u0 + 1, c])
    top = p00 + a * (p01 - p00)
    bot = p10 + a * (p11 - p10)
    return np.uint8(min(top + b * (bot - top) + np.float32(0.5), np.float32(255.0)))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _joints(  # type: ignore[no-untyped-def]
    images, starts, Pf, which, R, t, intr, pinhole, s_bins, grey_lut, edge, grad_lut, joint,
    out, seen,
):  # fmt: skip
    """The joint counts of each candidate pose ``k`` (a camera at ``R[k]``, ``t[k]``,
    :func:`acq.camera.projection.kernel_args`; the points at ``Pf[which[k]]``, flat
    (3N,) in the laser frame) of the points that project into the image:
    ``joint[k, 0]`` of their return strengths' bins ``s_bins`` and their frames' grey
    levels' bins (``grey_lut`` per frame, of channel 0 sampled there); with a second
    channel, ``joint[k, 1]`` of their depth ``edge`` (0/1) and their gradients' bins
    (``grad_lut``). Frame by frame, every candidate in turn: a frame's image is read
    from memory once for all of them and then stays in the core's cache. When ``out``
    (N,C) has rows, the points' samples go there too, and whether they project into
    the image into ``seen`` (N,) (one candidate: what its counts are of)."""
    _, h, w, nc = images.shape
    wf, hf = np.float32(w), np.float32(h)
    most = 0
    for f in range(starts.size - 1):
        most = max(most, starts[f + 1] - starts[f])
    uvf = np.empty(2 * most, dtype=np.float32)
    valid = np.empty(most, dtype=np.bool_)
    for f in range(starts.size - 1):
        a, b = starts[f], starts[f + 1]
        n = b - a
        for k in range(which.size):
            project_block(Pf[which[k], 3 * a : 3 * b], R[k], t[k], intr, pinhole, wf, hf,
                          uvf[: 2 * n], valid[:n])  # fmt: skip
            for i in range(n):
                if out.shape[0]:
                    seen[a + i] = valid[i]
                if not valid[i]:
                    continue
                u, v = uvf[2 * i], uvf[2 * i + 1]
                g = _sample(images, f, u, v, 0)
                joint[k, 0, s_bins[a + i], grey_lut[f, g]] += 1
                if nc > 1:
                    d = _sample(images, f, u, v, 1)
                    joint[k, 1, 1 if edge[a + i] else 0, grad_lut[f, d]] += 1
                if out.shape[0]:
                    out[a + i, 0] = g
                    if nc > 1:
                        out[a + i, 1] = d


class Scorer:
    """The score of parameters on a swath, for a camera ``model`` at ``camera_to_laser``
    with CALIB's ``offset_s`` and the rig at ``pose_at``; the points in the laser frame
    kept for the last :data:`SLOTS` time offsets tried (only the time line moves them),
    in rows of one array made once (the search tries hundreds of candidates: a new
    array each time costs the kernel's zeroing of its pages)."""

    SLOTS = 9
    """The time offsets whose points are kept: a line of the search tries 7."""

    def __init__(
        self, swath: Swath, model: CameraModel, camera_to_laser: Rigid, offset_s: float,
        laser_to_vehicle: Rigid, pose_at: PoseFn,
    ) -> None:  # fmt: skip
        self.swath, self.model, self.c2l, self.offset_s = swath, model, camera_to_laser, offset_s
        self.v2l = laser_to_vehicle.inverse()
        self.pose_at = pose_at
        self.frame_of = np.repeat(np.arange(swath.frames), np.diff(swath.starts))
        self._laser = np.empty((self.SLOTS, 3 * swath.points))  # pages touched as used
        self._row: dict[float, int] = {}  # time offset (rounded) -> its row
        self.evaluations = 0

    def _rows(self, dts: list[float]) -> list[int]:
        """The rows of ``_laser`` holding the points at each time offset of ``dts``
        (at most :data:`SLOTS` different), made where missing."""
        keys = [round(dt, 7) for dt in dts]
        if len(set(keys)) > self.SLOTS:
            raise ValueError(f"{len(set(keys))} time offsets at once (at most {self.SLOTS})")
        for key, dt in zip(keys, dts, strict=True):
            if key in self._row:
                continue
            free = set(range(self.SLOTS)) - set(self._row.values())
            if free:
                row = min(free)
            else:  # the oldest offset not asked for now
                row = self._row.pop(next(k for k in self._row if k not in keys))
            self._place(row, dt)
            self._row[key] = row
        return [self._row[k] for k in keys]

    def _place(self, row: int, dt: float) -> None:
        """Row ``row`` of ``_laser``: the points in the laser frame at offset ``dt`` s."""
        t = sync.on_laser_clock(self.swath.frame_ns, round((self.offset_s + dt) * 1e9))
        R, tr = self.pose_at(t)
        P, out = self.swath.P_world, self._laser[row].reshape(-1, 3)
        for f, (a, b) in enumerate(itertools.pairwise(self.swath.starts.tolist())):
            out[a:b] = world_to_laser(P[a:b], R[f], tr[f], self.v2l)

    def samples(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The features (N,C) uint8 where the points project under ``x`` (7,) (0
        elsewhere), and which project into the image (N,): what the score counts."""
        sw = self.swath
        out = np.zeros((sw.points, sw.features.shape[3]), dtype=np.uint8)
        seen = np.zeros(sw.points, dtype=np.bool_)
        self._counts(np.asarray(x, dtype=np.float64)[None], out, seen)
        return out, seen

    def many(self, X: np.ndarray) -> np.ndarray:
        """The information measure (nats) under each row of parameters ``X`` (K,7): (K,)."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        self.evaluations += X.shape[0]
        none = np.zeros((0, 1), dtype=np.uint8)
        joint = self._counts(X, none, np.zeros(0, dtype=np.bool_))
        out = np.array([information(j[0]) for j in joint])
        if self.swath.edge_weight > 0:
            out += self.swath.edge_weight * np.array([information(j[1]) for j in joint])
        return out

    def _counts(self, X: np.ndarray, out: np.ndarray, seen: np.ndarray) -> np.ndarray:
        """The joint counts (K,2,bins,bins) under ``X`` (K,7) (:func:`_joints`)."""
        sw = self.swath
        which = np.array(self._rows([float(dt) for dt in X[:, 6]]), dtype=np.int64)
        R = np.empty((X.shape[0], 3, 3), dtype=np.float32)
        t = np.empty((X.shape[0], 3), dtype=np.float32)
        for k, x in enumerate(X):
            R[k], t[k], intr, pinhole = kernel_args(self.model, shifted(self.c2l, x))
        joint = np.zeros((X.shape[0], 2, sw.bins, sw.bins), dtype=np.int64)
        _joints(sw.features, sw.starts, self._laser, which, R, t, intr, pinhole, sw.s_bins,
                sw.grey_lut, sw.edge, sw.grad_lut, joint, out, seen)  # fmt: skip
        return joint

    def __call__(self, x: np.ndarray) -> float:
        """The information measure (nats) under parameters ``x`` (7,)."""
        return float(self.many(np.asarray(x)[None])[0])


Many = Callable[[np.ndarray], np.ndarray]
"""A score of candidates: parameters (K,n) -> the measure (K,)."""


def _line(score: Many, x: np.ndarray, i: int, step: float, half: int = 3) -> np.ndarray:
    """``x`` with parameter ``i`` at the top of the score along it: a grid of ``half``
    steps either side, a parabola through the grid when its best is inside (a least
    squares fit: the score is not smooth at the scale of a step), else the edge's best."""
    ks = np.arange(-half, half + 1)
    X = np.repeat(x[None], ks.size, axis=0)
    X[:, i] += ks * step
    ys = score(X)
    best = int(np.argmax(ys))
    out = x.copy()
    top = float(ks[best])
    if 0 < best < ks.size - 1:
        a, b, _ = np.polyfit(ks.astype(float), ys, 2)
        if a < 0:
            top = float(np.clip(-b / (2 * a), ks[0], ks[-1]))
    out[i] += top * step
    return out


def search(
    score: Many,
    x0: np.ndarray,
    steps: np.ndarray,
    rounds: int,
    free: np.ndarray | None = None,
) -> np.ndarray:
    """Coordinate ascent of ``score`` (:data:`Many`) from ``x0`` (7,) with ``steps`` (7,)
    halved each of ``rounds``; only the parameters ``free`` (7,) bool move (default
    all)."""
    x = x0.astype(np.float64).copy()
    free = np.ones(len(PARAMS), dtype=bool) if free is None else free
    s = steps.astype(np.float64).copy()
    for _ in range(rounds):
        for i in np.flatnonzero(free).tolist():
            x = _line(score, x, i, float(s[i]))
        s = s / 2
    return x


def _design(n: int) -> np.ndarray:
    """The quadratic fit's offsets (in steps): the centre, +-1 along each parameter,
    and (1, 1) and (1, -1) along each pair: 57 for 7 parameters."""
    rows = [np.zeros(n)]
    eye = np.eye(n)
    for i in range(n):
        rows += [eye[i], -eye[i]]
    for i in range(n):
        for j in range(i + 1, n):
            rows += [eye[i] + eye[j], eye[i] - eye[j]]
    return np.array(rows)


def quadratic_fit(score: Many, x: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The gradient (n,) and Hessian (n,n) of ``score`` (:data:`Many`) at ``x`` (n,) in units of the
    steps ``h`` (n,): a least-squares quadratic through the score at :func:`_design`'s
    offsets (the score is not smooth at the scale of a few points' pixels, so no
    finite differences of two values)."""
    n = x.size
    d = _design(n)
    y = score(x + d * h)
    iu, ju = np.triu_indices(n)
    A = np.hstack([np.ones((d.shape[0], 1)), d, d[:, iu] * d[:, ju]])
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    g = coef[1 : n + 1]
    H = np.zeros((n, n))
    H[iu, ju] = coef[n + 1 :]
    H = H + H.T  # the diagonal doubled: d2/dx2 of c x^2 is 2c
    return g, H


def concave(H: np.ndarray, floor: float = 0.02) -> np.ndarray:
    """``H`` with every eigenvalue at most ``-floor`` times the largest magnitude: a
    direction the fit sees flat or rising (noise over a shallow valley) gets a short,
    bounded step instead of none or an unbounded one."""
    lam, V = np.linalg.eigh(H)
    lam = np.minimum(lam, -floor * float(np.abs(lam).max()))
    out: np.ndarray = (V * lam) @ V.T
    return out


def newton(
    score: Many, x: np.ndarray, h: np.ndarray, iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Newton steps to the top of the score's fitted quadratic (:func:`quadratic_fit`,
    made :func:`concave`), each at most two steps ``h`` per parameter. The estimate
    and the last Hessian (in units of ``h``)."""
    H = np.zeros((x.size, x.size))
    for _ in range(iterations):
        g, H = quadratic_fit(score, x, h)
        H = concave(H)
        x = x + np.clip(-np.linalg.solve(H, g), -2.0, 2.0) * h
    return x, H


def gradient(score: Many, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The gradient (n,) of ``score`` (:data:`Many`) at ``x`` in units of ``h``: central
    differences."""
    eye = np.eye(x.size) * h
    y = score(np.concatenate([x + eye, x - eye]))
    out: np.ndarray = (y[: x.size] - y[x.size :]) / 2
    return out
