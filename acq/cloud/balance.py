"""Colour balance across cameras and frames (``acq colorize``, default; ``--no-balance``).

Each camera's exposure and white balance change over a drive (auto-exposure steps, a
cloud passing), and two cameras never agree: the same wall comes out brighter in one
frame than in the next, and warmer in one camera than in the other. A point sampled in
two frames (of one camera, or of two cameras) gives the ratio of their gains, channel by
channel. The gains are estimated per chunk, as natural logarithms per camera and frame
and channel, by weighted least squares on the medians of those ratios (one equation per
pair of frames that share points, weighted by how many), with a weak pull between a
camera's consecutive frames (so frames that share no points follow their neighbours),
and divided out of every colour.

What stays free is one gain per channel for the whole rig: absolute colour cannot be
seen from the images. It is fixed so that the mean over the cameras of each camera's
median frame has gain 1: the colours are those of the rig's typical exposure and its
cameras' mean white balance.

Colours are RGB uint8; samples darker than ``MIN_LEVEL`` or brighter than ``MAX_LEVEL``
in any channel (noise, clipping) are not used.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from acq.cloud.views import Coloured

__all__ = ["MAX_LEVEL", "MIN_LEVEL", "Gains", "estimate_gains"]

MIN_LEVEL = 40
MAX_LEVEL = 243
_SMOOTH = 1.0  # weight of the pull between consecutive frames of a camera
_RIDGE = 1e-3  # keeps the system regular where nothing ties a camera to the others
_MAX_WEIGHT = 100  # a pair of frames counts as at most this many points


@dataclass(frozen=True)
class Gains:
    """Per camera, ``log_gain`` (F,3) float64: the natural log of each frame's RGB gain
    against the rig's reference; ``pairs`` the point pairs they were estimated from,
    ``cross`` of them between two cameras, ``by_camera`` those involving each camera."""

    log_gain: list[np.ndarray]
    pairs: int
    cross: int
    by_camera: tuple[int, ...] = ()

    def scales(self, camera: int) -> np.ndarray:
        """What a colour of each frame of ``camera`` is multiplied by: (F,3) float32."""
        scales: np.ndarray = np.exp(-self.log_gain[camera]).astype(np.float32)
        return scales

    def apply(self, camera: int, rgb: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """``rgb`` (N,3) uint8 of points coloured from ``frame`` (N,) (-1: left as
        they are) of ``camera``, with its gains divided out."""
        out = rgb.copy()
        sel = np.flatnonzero(frame >= 0)
        if self.log_gain[camera].size == 0 or sel.size == 0:
            return out
        scale = self.scales(camera)[frame[sel]]
        out[sel] = np.clip(rgb[sel] * scale + 0.5, 0, 255).astype(np.uint8)
        return out


def _usable(*colours: np.ndarray) -> np.ndarray:
    ok = np.ones(colours[0].shape[0], dtype=bool)
    for c in colours:
        ok &= np.all((c >= MIN_LEVEL) & (c <= MAX_LEVEL), axis=1)
    return ok


def estimate_gains(cameras: Sequence[Coloured], n_frames: Sequence[int]) -> Gains:
    """The gains of each camera's ``n_frames`` frames from the points of ``cameras``
    (one :class:`acq.cloud.views.Coloured` per camera, over the same points, with their
    :class:`acq.cloud.views.Pairs`)."""
    offsets = np.concatenate([[0], np.cumsum(n_frames)]).astype(np.int64)
    n = int(offsets[-1])
    a_parts, b_parts, d_parts = [], [], []
    cross = 0
    for c, col in enumerate(cameras):
        p = col.pairs
        if p.point.size:
            ok = p.ok & col.coloured[p.point]
            va, vb = col.rgb[p.point[ok]], p.rgb[ok]
            use = _usable(va, vb)
            a_parts.append(offsets[c] + col.frame[p.point[ok]][use])
            b_parts.append(offsets[c] + p.frame[ok][use])
            d_parts.append(np.log(vb[use].astype(np.float64)) - np.log(va[use].astype(np.float64)))
        for c2 in range(c + 1, len(cameras)):
            other = cameras[c2]
            both = np.flatnonzero(col.coloured & other.coloured)
            va, vb = col.rgb[both], other.rgb[both]
            use = _usable(va, vb)
            both = both[use]
            cross += int(both.size)
            a_parts.append(offsets[c] + col.frame[both])
            b_parts.append(offsets[c2] + other.frame[both])
            d_parts.append(np.log(vb[use].astype(np.float64)) - np.log(va[use].astype(np.float64)))
    if n == 0:
        return Gains([np.zeros((0, 3)) for _ in cameras], 0, 0, (0,) * len(cameras))
    a = np.concatenate(a_parts) if a_parts else np.zeros(0, np.int64)
    b = np.concatenate(b_parts) if b_parts else np.zeros(0, np.int64)
    d = np.concatenate(d_parts) if d_parts else np.zeros((0, 3))
    keep = a != b
    a, b, d = a[keep], b[keep], d[keep]
    swap = a > b
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    d = np.where(swap[:, None], -d, d)
    rows, cols, vals = [], [], []
    rhs = np.zeros((n, 3))
    if a.size:
        ga, gb, weight, median = _medians(a, b, d, n)
        rows += [ga, gb, ga, gb]
        cols += [ga, gb, gb, ga]
        vals += [weight, weight, -weight, -weight]
        np.add.at(rhs, gb, weight[:, None] * median)
        np.add.at(rhs, ga, -weight[:, None] * median)
    for c in range(len(cameras)):
        i = np.arange(offsets[c], offsets[c + 1] - 1)
        w = np.full(i.size, _SMOOTH)
        rows += [i, i + 1, i, i + 1]
        cols += [i, i + 1, i + 1, i]
        vals += [w, w, -w, -w]
    diag = np.arange(n)
    rows.append(diag)
    cols.append(diag)
    vals.append(np.full(n, _RIDGE))
    g = _solve(np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), rhs)
    seen = np.zeros(n, dtype=bool)
    seen[a] = seen[b] = True
    refs = [
        np.median(g[lo:hi][seen[lo:hi]], axis=0)
        for lo, hi in itertools.pairwise(offsets)
        if seen[lo:hi].any()
    ]
    if refs:
        g -= np.mean(refs, axis=0)
    cam_a = np.searchsorted(offsets, a, side="right") - 1
    cam_b = np.searchsorted(offsets, b, side="right") - 1
    by_camera = tuple(
        int(np.count_nonzero((cam_a == c) | (cam_b == c))) for c in range(len(cameras))
    )
    return Gains(
        [g[lo:hi] for lo, hi in itertools.pairwise(offsets)], int(a.size), cross, by_camera
    )


def _solve(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x (n,3) with M @ x = ``rhs`` for the symmetric positive definite M given by its
    entries (``rows``, ``cols``, ``vals``; repeated entries add up): conjugate gradients
    with a diagonal preconditioner, to 1e-10 of the right-hand side."""
    x: np.ndarray = _cg(
        np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64),
        np.asarray(vals, dtype=np.float64), np.ascontiguousarray(rhs, dtype=np.float64),
    )  # fmt: skip
    return x


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _cg(rows, cols, vals, rhs):  # type: ignore[no-untyped-def]
    """:func:`_solve`'s iterations, each sum taken in the order numpy's ``bincount`` and
    ``sum(axis=0)`` take it (the same bytes, without their temporaries)."""
    n = rhs.shape[0]
    diag = np.zeros(n)
    for e in range(rows.size):
        if rows[e] == cols[e]:
            diag[rows[e]] += vals[e]
    x = np.zeros((n, 3))
    r = np.empty((n, 3))
    z = np.empty((n, 3))
    p = np.empty((n, 3))
    q = np.empty((n, 3))
    sums = np.zeros((6, 3))  # r.z, the stop, r.r, p.q, the new r.z, alpha
    for i in range(n):
        for k in range(3):
            r[i, k] = rhs[i, k]
            z[i, k] = r[i, k] / diag[i]
            p[i, k] = z[i, k]
            sums[0, k] += r[i, k] * z[i, k]
            sums[1, k] += rhs[i, k] * rhs[i, k]
    for k in range(3):
        sums[1, k] = 1e-20 * max(sums[1, k], 1e-30)
    for _ in range(4 * n):
        for k in range(3):
            sums[2, k] = 0.0
        for i in range(n):
            for k in range(3):
                sums[2, k] += r[i, k] * r[i, k]
        if sums[2, 0] <= sums[1, 0] and sums[2, 1] <= sums[1, 1] and sums[2, 2] <= sums[1, 2]:
            break
        for i in range(n):
            for k in range(3):
                q[i, k] = 0.0
        for e in range(rows.size):  # q = M @ p
            i, j, v = rows[e], cols[e], vals[e]
            for k in range(3):
                q[i, k] += v * p[j, k]
        for k in range(3):
            sums[3, k] = sums[4, k] = 0.0
        for i in range(n):
            for k in range(3):
                sums[3, k] += p[i, k] * q[i, k]
        for k in range(3):
            sums[5, k] = sums[0, k] / max(sums[3, k], 1e-300)
        for i in range(n):
            for k in range(3):
                x[i, k] += sums[5, k] * p[i, k]
                r[i, k] -= sums[5, k] * q[i, k]
                z[i, k] = r[i, k] / diag[i]
                sums[4, k] += r[i, k] * z[i, k]
        for i in range(n):
            for k in range(3):
                p[i, k] = z[i, k] + sums[4, k] / max(sums[0, k], 1e-300) * p[i, k]
        for k in range(3):
            sums[0, k] = sums[4, k]
    return x


def _medians(
    a: np.ndarray, b: np.ndarray, d: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pair of frames (a < b): (a, b, weight, median of ``d`` (K,3) per channel)."""
    key = a * n + b
    order = np.argsort(key, kind="stable")
    key_s = key[order]
    starts = np.flatnonzero(np.r_[True, key_s[1:] != key_s[:-1]])
    counts = np.diff(np.r_[starts, key_s.size])
    median = np.empty((starts.size, 3))
    # sorted by pair, then by value: one sort of (pair, value quantised to 1e-5) integers
    q = np.clip(np.rint(d[order] * 1e5), -(2**22), 2**22 - 1).astype(np.int64) + 2**22
    lo = starts + (counts - 1) // 2
    hi = starts + counts // 2
    for ch in range(3):
        both = np.sort((key_s << 23) | q[:, ch])
        vals = ((both & (2**23 - 1)) - 2**22) * 1e-5
        median[:, ch] = 0.5 * (vals[lo] + vals[hi])
    first = key_s[starts]
    return first // n, first % n, np.minimum(counts, _MAX_WEIGHT).astype(np.float64), median
