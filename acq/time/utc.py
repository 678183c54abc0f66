"""Host monotonic time to UTC through the log's (monotonic, realtime) clock pairs."""

from __future__ import annotations

import numpy as np


def utc_seconds(time_ns: np.ndarray, clock: np.ndarray) -> np.ndarray:
    """Host monotonic ns -> UTC seconds (float64) with the log's (monotonic, realtime)
    pairs, the offset interpolated between pairs (held at the ends); NaN without pairs."""
    t = np.asarray(time_ns, dtype=np.int64)
    if clock.size == 0:
        return np.full(t.shape, np.nan)
    mono = clock[:, 0]
    offset = clock[:, 1] - mono
    base = int(offset[0])
    order = np.argsort(mono, kind="stable")
    rel = np.interp(t.astype(np.float64), mono[order].astype(np.float64), (offset - base)[order])
    # whole seconds and the rest apart, so float64 keeps the nanoseconds' microseconds
    total = t + base + np.rint(rel).astype(np.int64)
    return (total // 10**9).astype(np.float64) + (total % 10**9).astype(np.float64) * 1e-9
