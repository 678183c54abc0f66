"""Host monotonic time <-> UTC through the log's (monotonic, realtime) clock pairs."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["host_ns_from_utc", "utc_ns", "utc_seconds"]


def utc_ns(time_ns: npt.ArrayLike, clock: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """Host monotonic ns -> UTC ns (int64) with the log's (monotonic ns, realtime ns) pairs,
    the offset interpolated between pairs (held at the ends). Raises ValueError without
    pairs."""
    t = np.asarray(time_ns, dtype=np.int64)
    pairs = np.asarray(clock, dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] == 0:
        raise ValueError("no (monotonic, realtime) clock pairs: host time cannot be mapped to UTC")
    mono = pairs[:, 0]
    offset = pairs[:, 1] - mono
    base = int(offset[0])
    order = np.argsort(mono, kind="stable")
    rel: npt.NDArray[np.float64] = np.interp(
        t.astype(np.float64), mono[order].astype(np.float64), (offset - base)[order]
    )
    total: npt.NDArray[np.int64] = t + base + np.rint(rel).astype(np.int64)
    return total


def utc_seconds(time_ns: npt.ArrayLike, clock: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """Host monotonic ns -> UTC seconds (float64), as :func:`utc_ns`; NaN without pairs."""
    if clock.size == 0:
        return np.full(np.shape(time_ns), np.nan)
    total = utc_ns(time_ns, clock)
    # whole seconds and the rest apart, so float64 keeps the nanoseconds' microseconds
    return (total // 10**9).astype(np.float64) + (total % 10**9).astype(np.float64) * 1e-9


def host_ns_from_utc(utc_s: npt.ArrayLike, clock: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """UTC seconds (POSIX, float64) -> host monotonic ns (int64) with the log's (monotonic
    ns, realtime ns) pairs: the inverse of :func:`utc_seconds` (offset
    interpolated between pairs, held at the ends). Good to the float's resolution
    (~0.25 µs at present-day UTC seconds). Raises ValueError without pairs, or where the
    wall clock was stepped back so far that a UTC time names two host times."""
    u = np.asarray(utc_s, dtype=np.float64)
    pairs = np.asarray(clock, dtype=np.int64).reshape(-1, 2)
    if pairs.shape[0] == 0:
        raise ValueError("no (monotonic, realtime) clock pairs: UTC cannot be mapped to host time")
    if not np.isfinite(u).all():
        raise ValueError("UTC times must be finite")
    order = np.argsort(pairs[:, 0], kind="stable")
    mono = pairs[order, 0]
    off = pairs[order, 1] - mono
    u_pair = mono + off
    if (np.diff(u_pair) <= 0).any():
        i = int(np.argmax(np.diff(u_pair) <= 0))
        raise ValueError(
            f"the wall clock went back between clock pairs {i} and {i + 1}: UTC is ambiguous there"
        )
    sec = np.floor(u)
    u_ns = sec.astype(np.int64) * 10**9 + np.rint((u - sec) * 1e9).astype(np.int64)
    rel = (u_ns - u_pair[0]).astype(np.float64)
    m = mono[0] + np.rint(
        np.interp(rel, (u_pair - u_pair[0]).astype(np.float64), (mono - mono[0]).astype(np.float64))
    ).astype(np.int64)
    m = np.where(u_ns < u_pair[0], u_ns - off[0], m)
    host: npt.NDArray[np.int64] = np.where(u_ns > u_pair[-1], u_ns - off[-1], m)
    return host
