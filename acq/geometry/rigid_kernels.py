"""Compiled loops for rigid transforms of many points (numpy's ``P @ R.T`` on an (N,3)
array takes a slow path: about 20 times slower than one pass over the points).

Imported only for large inputs by :meth:`acq.geometry.transforms.Rigid.apply`, so that
code handling a few points (the recorder, calibration files) does not import numba.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["apply_rigid"]


@numba.njit(cache=True, nogil=True)
def _apply(P, R, t):  # type: ignore[no-untyped-def]
    out = np.empty_like(P)
    for i in range(P.shape[0]):
        x, y, z = P[i, 0], P[i, 1], P[i, 2]
        for k in range(3):
            out[i, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * z + t[k]
    return out


def apply_rigid(P: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``P @ R.T + t`` for points ``P`` (N,3) float64: (N,3) float64."""
    out: np.ndarray = _apply(
        np.ascontiguousarray(P, dtype=np.float64),
        np.ascontiguousarray(R, dtype=np.float64),
        np.ascontiguousarray(t, dtype=np.float64),
    )
    return out
