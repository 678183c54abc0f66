"""GNSS fixes checked against each other and against the speed a vehicle can have
(:func:`screen_fixes`): a fix that jumps, or lies off the track its neighbours draw, is
rejected whatever accuracy the receiver claims for it. Positions m, times host ns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acq.motion.gnss import GnssTrack, local_quadratic

__all__ = ["MAX_SPEED_MPS", "Screened", "screen_fixes"]

MAX_SPEED_MPS = 70.0
"""The fastest a road vehicle is taken to move, m/s (252 km/h)."""


@dataclass(frozen=True)
class Screened:
    """The fixes kept (``track``), the indices of the rejected ones in the track given
    (``rejected``, increasing), and the fixes' scatter around their track (``scatter_m``,
    a robust 1-sigma per axis, m)."""

    track: GnssTrack
    rejected: np.ndarray
    scatter_m: float

    @property
    def note(self) -> str | None:
        """One line for the user when fixes were rejected, else None."""
        n = int(self.rejected.size)
        if not n:
            return None
        total = len(self.track) + n
        return (
            f"GNSS: {n} of {total} fixes rejected as outliers (off the track the other fixes "
            f"draw, or reached faster than {MAX_SPEED_MPS:.0f} m/s)"
        )


def screen_fixes(
    track: GnssTrack,
    *,
    max_speed_mps: float = MAX_SPEED_MPS,
    smooth_s: float = 2.0,
    min_error_m: float = 0.5,
    k_sigma: float = 6.0,
) -> Screened:
    """Reject outlying fixes of ``track``, in two steps.

    1. Speed: the track is cut where two successive fixes lie farther apart than
       ``max_speed_mps`` allows (plus the scatter); the longest piece is kept, and each
       other piece, longest first, when it is reachable from the kept fixes around it.
    2. Fit: a quadratic in time over ``smooth_s`` around each fix, all fixes weighted
       alike (the receiver's claimed accuracy is not trusted here), repeatedly; the
       worst fix of its window is rejected while it lies farther from the fit than
       ``k_sigma`` times the fixes' scatter and ``min_error_m``.

    The scatter is measured on the fixes (second differences, median based), not taken
    from the receiver."""
    t, P = track.t_ns, track.xyz
    K = t.size
    keep = np.ones(K, dtype=bool)
    scatter = _scatter(P)
    if K < 3:
        return Screened(track, np.zeros(0, dtype=np.int64), scatter)
    slack = max(min_error_m, k_sigma * scatter)
    keep &= _speed_consistent(t, P, max_speed_mps, slack)
    ts = (t - t[0]) * 1e-9
    half = smooth_s / 2
    span = max(float(ts[-1] - ts[0]), 1e-9)
    window = max(3, round(K / span * smooth_s) | 1)  # fixes in a window, odd
    for _ in range(K):
        idx = np.flatnonzero(keep)
        if idx.size < 4:
            break
        fit, _ = local_quadratic(ts[idx], P[idx], np.ones(idx.size), half)
        r = np.linalg.norm(P[idx] - fit, axis=1)
        worst = _sliding_max(r, window)
        bad = (r > slack) & (r >= worst)
        if not bad.any():
            break
        keep[idx[bad]] = False
    rejected = np.flatnonzero(~keep)
    if keep.sum() == K:
        return Screened(track, rejected, scatter)
    kept = GnssTrack(t[keep], P[keep], track.sigma_m[keep], track.frame, track.origin)
    return Screened(kept, rejected, scatter)


def _scatter(P: np.ndarray) -> float:
    """The fixes' noise, m (1-sigma per axis): white noise of sigma gives second
    differences of sigma * sqrt(6); the median keeps outliers and turns out."""
    if len(P) < 3:
        return 0.0
    d2 = np.abs(np.diff(P, n=2, axis=0)).ravel()
    return float(1.4826 * np.median(d2) / np.sqrt(6.0))


def _speed_consistent(t: np.ndarray, P: np.ndarray, vmax: float, slack: float) -> np.ndarray:
    """Which fixes belong to pieces of the track reachable from each other at ``vmax``
    m/s (plus ``slack`` m); see :func:`screen_fixes`, step 1."""

    def reachable(a: int, b: int) -> bool:
        gap = abs(float(t[b] - t[a])) * 1e-9
        return bool(np.linalg.norm(P[b] - P[a]) <= vmax * gap + slack)

    step = np.linalg.norm(np.diff(P, axis=0), axis=1)
    cuts = np.flatnonzero(step > vmax * np.diff(t) * 1e-9 + slack) + 1
    pieces = np.split(np.arange(t.size), cuts)
    keep = np.zeros(t.size, dtype=bool)
    for piece in sorted(pieces, key=len, reverse=True):
        before = np.flatnonzero(keep[: piece[0]])
        after = np.flatnonzero(keep[piece[-1] + 1 :]) + piece[-1] + 1
        if (not before.size or reachable(int(before[-1]), int(piece[0]))) and (
            not after.size or reachable(int(piece[-1]), int(after[0]))
        ):
            keep[piece] = True
    return keep


def _sliding_max(r: np.ndarray, window: int) -> np.ndarray:
    """The largest of ``r`` within ``window``//2 samples of each, edges included."""
    h = window // 2
    padded = np.pad(r, h, mode="constant", constant_values=-np.inf)
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * h + 1)
    return np.asarray(windows.max(axis=1), dtype=np.float64)
