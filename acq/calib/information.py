"""How well a laser swath and camera images agree: the information measure of the
targetless checks (:mod:`acq.calib.time_offset` along time, :mod:`acq.calib.pose_search`
over the camera's pose).

Two terms, each the mutual information (nats) of a laser feature and an image feature
sampled where the points project: the points' return strengths against the image's grey
levels (Pandey et al., AAAI 2012: no model of how the laser's infrared reflectance maps
to grey is needed, which differs per material), and the laser's depth edges (the near
side of a range jump between neighbouring beams, or of a missing return: a pole, a
kerb, a roof line against the sky) against the image's gradient magnitude (Napier,
Corke and Newman, ICRA 2013, aligned the swath with image gradients). On the simulated
street the second term stays near 0.001 nats with no peak at the true pose (its
textured facades have gradients everywhere; under 1 % of the points are depth edges),
against 0.74 nats for the first, so :mod:`acq.calib.pose_check` weighs it 0 by default.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

__all__ = [
    "DEPTH_JUMP_M",
    "bins_of_bytes",
    "depth_edges",
    "image_features",
    "information",
    "joint_counts",
    "mutual_information",
    "quantile_bins",
    "quantile_edges",
]

DEPTH_JUMP_M = 0.25
"""A range jump between neighbouring beams of at least this much (m) is a depth edge."""


def mutual_information(a_bins: np.ndarray, b_bins: np.ndarray, bins: int) -> float:
    """Mutual information (nats) of two integer samples in [0, bins)."""
    joint = np.bincount(a_bins * bins + b_bins, minlength=bins * bins)
    return information(joint.reshape(bins, bins))


def information(joint: np.ndarray) -> float:
    """Mutual information (nats) of two integer samples from their joint counts
    ``joint`` (bins_a, bins_b)."""
    p = joint.astype(np.float64) / max(int(joint.sum()), 1)
    pa, pb = p.sum(axis=1), p.sum(axis=0)
    nz = p > 0
    return float(np.sum(p[nz] * np.log(p[nz] / np.outer(pa, pb)[nz])))


def quantile_bins(x: np.ndarray, bins: int, edges: np.ndarray | None = None) -> np.ndarray:
    """``x`` as integers in [0, bins): by its own quantiles, or by ``edges`` (bins - 1,
    sorted) so that samples binned alike compare."""
    if edges is None:
        edges = quantile_edges(x, bins)
    return np.searchsorted(edges, x).astype(np.int64)


def quantile_edges(x: np.ndarray, bins: int) -> np.ndarray:
    """(bins - 1,) float64: the edges that cut ``x`` into ``bins`` equal parts."""
    edges: np.ndarray = np.quantile(x, np.linspace(0.0, 1.0, bins + 1)[1:-1])
    return edges.astype(np.float64)


def joint_counts(
    a_bins: np.ndarray, x: np.ndarray, edges: np.ndarray, mask: np.ndarray, joint: np.ndarray
) -> None:
    """Add to ``joint`` (bins, bins) the counts of ``a_bins`` (N,) against ``x`` (N,)
    binned by ``edges`` (:func:`quantile_bins`) over the samples ``mask`` (N,): without
    a copy of the masked samples or of their bins."""
    _joint_counts(a_bins, x, np.asarray(edges, dtype=np.float64), mask, joint)


@numba.njit(cache=True, nogil=True)
def _joint_counts(a_bins, x, edges, mask, joint):  # type: ignore[no-untyped-def]
    # a value's bin: how many edges lie below it (NaN: every one, as np.searchsorted
    # has it), counted without branches: 3 times faster than a binary search's
    # unpredictable ones over a few dozen edges
    ne = edges.size
    for i in range(x.size):
        if mask[i]:
            v = np.float64(x[i])
            k = ne
            if v == v:
                k = 0
                for j in range(ne):
                    k += edges[j] < v
            joint[a_bins[i], k] += 1


def depth_edges(
    scan: np.ndarray, step: np.ndarray, r: np.ndarray, jump_m: float = DEPTH_JUMP_M
) -> np.ndarray:
    """(N,) bool: the points (``scan``, ``step`` indices, range ``r`` m; in time order,
    so each scan's beams in order) nearer by ``jump_m`` than a neighbouring beam of
    their scan, or next to a beam without a return (the edge of an object against the
    sky)."""
    edge = np.zeros(r.size, dtype=bool)
    if r.size < 2:
        return edge
    neighbours = (scan[1:] == scan[:-1]) & (step[1:] - step[:-1] == 1)
    gap = (scan[1:] == scan[:-1]) & (step[1:] - step[:-1] > 1)
    dr = r[1:] - r[:-1]
    edge[:-1] |= (neighbours & (dr >= jump_m)) | gap  # this one nearer than the next
    edge[1:] |= (neighbours & (-dr >= jump_m)) | gap
    return edge


def image_features(bgr: np.ndarray, blur_px: float, gradient: bool = True) -> np.ndarray:
    """(H,W,2) uint8: the image's grey levels and gradient magnitude, after a Gaussian
    blur of ``blur_px`` px (the sampled values then change smoothly with the pose); the
    gradient from a blur of twice that, 255 at eight times its mean. Without
    ``gradient``: (H,W,1), the grey levels."""
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    smooth = cv2.GaussianBlur(grey, (0, 0), blur_px) if blur_px > 0 else grey
    if not gradient:
        return smooth[..., None]
    g = cv2.GaussianBlur(grey, (0, 0), max(2 * blur_px, 1.0))
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1)
    mag = cv2.add(np.abs(gx), np.abs(gy))  # the L1 norm: no square root per pixel
    scale = 255.0 / max(8.0 * float(cv2.mean(mag)[0]), 1e-6)
    grad = cv2.convertScaleAbs(mag, alpha=scale)
    return np.dstack([smooth, grad])


def bins_of_bytes(sample: np.ndarray, bins: int) -> np.ndarray:
    """(256,) int64: the bin in [0, bins) of each byte value, by the quantiles of
    ``sample`` (uint8): a lookup that bins a sample of bytes at once."""
    return quantile_bins(np.arange(256), bins, quantile_edges(sample, bins))
