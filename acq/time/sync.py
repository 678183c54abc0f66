"""Per-point times of laser scans, frame times, and pairing of laser points with frames.

All times are integer nanoseconds on the host monotonic clock unless a name ends in
``_s`` (seconds, float). A scan's point ``i`` was measured at
``start_ns + i * time_increment``; ``start_ns`` is the host time of point 0, found from
the device stamp (mapped by :class:`acq.time.clocksync.DeviceClock`), the device's offset
from its stamp to point 0, and the constant transport latency that one-way timing cannot
see. A frame's time is the middle of its exposure.

:func:`pair_frames` finds, for every laser point, the frames just before and after it
and the nearer of the two, after removing duplicated and out-of-order frames, and says
which points lie where frames are missing (a gap), so that nothing pairs a point across
a gap, or with a repeated frame, without saying so.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass, field
from typing import overload

import numpy as np
import numpy.typing as npt

from acq.records import Scan
from acq.time.clocksync import DeviceClock

__all__ = [
    "Gap",
    "Pairing",
    "frame_stamp_ns",
    "frames_used",
    "on_laser_clock",
    "pair_frames",
    "point_times_ns",
    "scan_start_ns",
    "stamp_scan",
]


# --- laser scans ---------------------------------------------------------------------


def scan_start_ns(stamp_host_ns: int, stamp_offset_s: float, latency_s: float = 0.0) -> int:
    """Host ns of a scan's point 0.

    ``stamp_host_ns`` is the host time of the device's stamp (``DeviceClock.to_host_ns``
    of the scan's tick); ``stamp_offset_s`` the time from that stamp to point 0, seconds
    (SICK stamps the first point: 0; a Hokuyo stamps a fixed step of the turn, so
    point 0 at step ``start`` is ``(start - stamp_step) * scan_period / ares`` s after it,
    negative when it comes before). ``latency_s`` is the constant transport latency,
    seconds: the one-way estimate includes it, so it is subtracted.
    """
    return int(stamp_host_ns) + round(stamp_offset_s * 1e9) - round(latency_s * 1e9)


@overload
def point_times_ns(scan: Scan, /) -> np.ndarray: ...


@overload
def point_times_ns(
    start_ns: int | npt.ArrayLike | None, time_increment_s: float, step: npt.ArrayLike, /
) -> np.ndarray: ...


def point_times_ns(
    start: Scan | int | npt.ArrayLike | None,
    time_increment_s: float | None = None,
    step: npt.ArrayLike | None = None,
    /,
) -> np.ndarray:
    """int64 host ns of every point of a ``scan``, or of points ``step`` (int, any shape)
    of scans whose point 0 was measured at ``start_ns`` (broadcast against ``step``),
    ``time_increment_s`` s apart: ``start_ns + round(step * time_increment_s * 1e9)``."""
    if isinstance(start, Scan):
        scan = start
        start, time_increment_s, step = scan.start_ns, scan.time_increment, np.arange(scan.size)
    if start is None:
        raise ValueError("start_ns is None: apply a clock first (stamp_scan or scan_start_ns)")
    if time_increment_s is None or step is None:
        raise TypeError("point_times_ns(scan) or point_times_ns(start_ns, time_increment_s, step)")
    offsets = np.rint(np.asarray(step) * (time_increment_s * 1e9)).astype(np.int64)
    return np.asarray(start, dtype=np.int64) + offsets


def stamp_scan(
    scan: Scan, clock: DeviceClock, stamp_offset_s: float, latency_s: float = 0.0
) -> Scan:
    """``scan`` with ``start_ns`` from its first device tick through ``clock``.

    The clock is only queried (``to_host_ns``), never updated: the caller feeds it.
    ``stamp_offset_s`` and ``latency_s`` are seconds, as in :func:`scan_start_ns`.
    """
    if not scan.device_ticks:
        raise ValueError("the scan has no device ticks: nothing to map to host time")
    host = clock.to_host_ns(scan.device_ticks[0])
    return dataclasses.replace(scan, start_ns=scan_start_ns(host, stamp_offset_s, latency_s))


# --- camera frames -------------------------------------------------------------------


def frame_stamp_ns(recv_ns: int, exposure_s: float, latency_s: float) -> int:
    """Host ns of the middle of exposure of a frame received (or stamped at the end of
    its exposure) at ``recv_ns``: ``recv_ns - latency_s - exposure_s / 2``.

    Assumes the frame is read out right after its exposure ends, so ``latency_s``
    (seconds) covers readout and transport up to ``recv_ns``; ``exposure_s`` in seconds
    (0 where unknown). For a source that stamps the end of exposure, ``latency_s`` is 0.
    """
    return int(recv_ns) - round(latency_s * 1e9) - round(exposure_s * 0.5e9)


def on_laser_clock(frame_ns: npt.ArrayLike, time_offset_ns: npt.ArrayLike) -> np.ndarray:
    """int64 times on the laser's clock of frames stamped ``frame_ns`` by a camera whose
    clock is ``time_offset_ns`` ahead of the laser's (calib.yaml's ``time_offset_s``:
    camera time minus laser time): ``frame_ns - time_offset_ns``, broadcast (several
    candidate offsets against one frame, as :mod:`acq.calib.time_offset` tries)."""
    return np.asarray(frame_ns, dtype=np.int64) - np.asarray(time_offset_ns, dtype=np.int64)


# --- pairing -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Gap:
    """Missing frames between two consecutive usable frames stamped ``start_ns``, ``end_ns``."""

    start_ns: int
    end_ns: int
    missing_frames: int


def _empty_index() -> np.ndarray:
    return np.empty(0, dtype=np.int64)


@dataclass(frozen=True, slots=True)
class Pairing:
    """Frames around each laser point; see :func:`pair_frames`.

    Per point (arrays of the points' length, read-only): ``before``, ``after`` and
    ``nearest`` index the caller's frame arrays (-1: none); ``dt_s`` is the point time
    minus the nearest frame's time, seconds (NaN without frames); ``weight`` the
    interpolation weight of ``after`` in [0, 1]; ``in_gap`` whether the pairing crosses
    or borders missing frames. Per stream: ``gaps`` between usable frames in time
    order, ``duplicates`` and ``out_of_order`` the frames excluded (caller's indices,
    ascending), ``period_s`` the frame period used (NaN when unknown), ``n_frames`` the
    number of frames given.
    """

    before: np.ndarray
    after: np.ndarray
    nearest: np.ndarray
    dt_s: np.ndarray
    weight: np.ndarray
    in_gap: np.ndarray
    gaps: list[Gap] = field(default_factory=list)
    duplicates: np.ndarray = field(default_factory=_empty_index)
    out_of_order: np.ndarray = field(default_factory=_empty_index)
    period_s: float = math.nan
    n_frames: int = 0

    def __post_init__(self) -> None:
        for name in ("before", "after", "nearest", "dt_s", "weight", "in_gap"):
            getattr(self, name).flags.writeable = False
        self.duplicates.flags.writeable = False
        self.out_of_order.flags.writeable = False


def _int_array(values: npt.ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.size == 0:
        return np.empty(0, dtype=np.int64)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must hold integers (ns or counts), got {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def _longest_nondecreasing(values: np.ndarray) -> np.ndarray:
    """Boolean mask of a longest non-decreasing subsequence of ``values`` (O(n log n))."""
    keep = np.ones(values.size, dtype=bool)
    if values.size < 2 or bool(np.all(np.diff(values) >= 0)):
        return keep  # the usual case, without a Python loop
    tails: list[int] = []  # smallest tail value of a run of each length
    tail_at: list[int] = []  # its position
    prev = [-1] * values.size
    for i, v in enumerate(values.tolist()):
        j = bisect.bisect_right(tails, v)
        if j:
            prev[i] = tail_at[j - 1]
        if j == len(tails):
            tails.append(v)
            tail_at.append(i)
        else:
            tails[j] = v
            tail_at[j] = i
    keep[:] = False
    i = tail_at[-1]
    while i >= 0:
        keep[i] = True
        i = prev[i]
    return keep


def _usable_frames(
    frame_ns: np.ndarray, frame_seq: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Caller indices of (usable frames in time order, frames repeating a sequence
    number, frames repeating a usable frame's stamp, out-of-order frames)."""
    seq_dups = _empty_index()
    out_of_order = _empty_index()
    if frame_seq is None:
        order = np.argsort(frame_ns, kind="stable")
    else:
        order = np.argsort(frame_seq, kind="stable")  # ties keep the caller's order
        seq = frame_seq[order]
        first = np.ones(order.size, dtype=bool)
        first[1:] = seq[1:] != seq[:-1]
        seq_dups = order[~first]
        order = order[first]
        in_run = _longest_nondecreasing(frame_ns[order])
        out_of_order = order[~in_run]
        order = order[in_run]
    stamps = frame_ns[order]
    first = np.ones(order.size, dtype=bool)
    first[1:] = stamps[1:] != stamps[:-1]
    return (
        order[first].astype(np.int64),
        seq_dups.astype(np.int64),
        order[~first].astype(np.int64),
        np.sort(out_of_order).astype(np.int64),
    )


def pair_frames(
    point_ns: npt.ArrayLike,
    frame_ns: npt.ArrayLike,
    frame_seq: npt.ArrayLike | None = None,
    *,
    period_s: float | None = None,
    max_gap_factor: float = 1.5,
) -> Pairing:
    """The frames around each laser point time.

    ``point_ns`` (N,) and ``frame_ns`` (M,) are integer host ns (frames at the middle of
    exposure), in any order; ``frame_seq`` (M,) the source's frame counters, one
    monotonic count for the whole stream (unwrapped, re-based by the caller after a
    source restart). Every returned index refers to the caller's frame arrays.

    Frames excluded first, never paired:

    - ``duplicates``: a sequence number seen before (a replay after a reconnect), or
      a stamp equal to a usable frame's with a lower sequence number (or, without
      ``frame_seq``, equal to an earlier frame's in the caller's order). The first
      occurrence is kept.
    - ``out_of_order`` (only with ``frame_seq``): frames whose stamps go backwards
      relative to their sequence numbers (a clock step). The longest run of frames
      whose stamps increase with the sequence is kept, so one wild stamp costs one
      frame; the rest are excluded rather than re-sorted into a wrong pairing.

    With the remaining frames sorted by time, for each point at time ``p``:

    - ``before``: the last frame with stamp <= p; ``after``: the first with stamp > p
      (-1 where there is none); ``nearest``: the nearer of the two (``before`` on a
      tie), -1 only without frames.
    - ``dt_s = (p - stamp[nearest]) * 1e-9`` seconds, NaN without frames.
    - ``weight = (p - stamp[before]) / (stamp[after] - stamp[before])`` between two
      frames, 0 with only ``before``, 1 with only ``after``, 0 without frames.

    The period ``T = period_s`` defaults to the median interval between consecutive
    usable frames, per sequence step when ``frame_seq`` is given (robust to drops).
    Two consecutive usable frames bound a gap when their sequence numbers differ by
    more than one or their stamps by more than ``max_gap_factor * T``; each gap is a
    :class:`Gap` whose ``missing_frames`` is the sequence difference minus one (an
    out-of-order frame counts as missing, a frame that repeated a stamp does not), or,
    where the sequence shows no hole or is not given, ``round(interval / T) - 1`` (at
    least 1). A point is ``in_gap`` when

    - it lies strictly between two frames that bound a gap (a point exactly at a
      frame's stamp is paired with that frame and is not in a gap), or
    - it lies before the first or after the last frame by more than
      ``max_gap_factor * T / 2`` (farther than any point of a normal interval is
      from its nearest frame), or
    - there is no frame, or fewer than two frames and no ``period_s`` (no period known).

    Fully vectorised over the points (``np.searchsorted``).
    """
    if not max_gap_factor >= 1.0:
        raise ValueError(f"max_gap_factor must be >= 1, got {max_gap_factor}")
    if period_s is not None and not period_s > 0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    p = _int_array(point_ns, "point_ns")
    f_ns = _int_array(frame_ns, "frame_ns")
    seq = None if frame_seq is None else _int_array(frame_seq, "frame_seq")
    if seq is not None and seq.size != f_ns.size:
        raise ValueError(f"frame_seq has {seq.size} values for {f_ns.size} frame stamps")

    usable, seq_dups, stamp_dups, out_of_order = _usable_frames(f_ns, seq)
    duplicates = np.sort(np.concatenate([seq_dups, stamp_dups]))
    t = f_ns[usable]
    k = int(t.size)
    n = int(p.size)

    # the period, ns
    dt_frames = np.diff(t)
    dseq = None
    if seq is not None:
        # sequence steps between usable frames, not counting frames that repeated a
        # usable frame's stamp (they were there, only twice)
        used_seq = seq[usable]
        dup_seq = np.sort(seq[stamp_dups])
        dseq = np.diff(used_seq) - np.diff(np.searchsorted(dup_seq, used_seq))
    if period_s is not None:
        period_ns = period_s * 1e9
    elif k >= 2:
        steps = dt_frames / dseq if dseq is not None else dt_frames
        period_ns = float(np.median(steps))
    else:
        period_ns = math.nan
    limit_ns = max_gap_factor * period_ns  # NaN when unknown: every comparison False

    # gaps between consecutive usable frames
    is_gap = dt_frames > limit_ns
    if dseq is not None:
        is_gap |= dseq > 1
    gaps: list[Gap] = []
    for j in np.flatnonzero(is_gap).tolist():
        by_time = round(float(dt_frames[j]) / period_ns) - 1 if period_ns > 0 else 1
        missing = int(dseq[j]) - 1 if dseq is not None and dseq[j] > 1 else max(by_time, 1)
        gaps.append(Gap(int(t[j]), int(t[j + 1]), missing))

    if k == 0:
        none = np.full(n, -1, dtype=np.int64)
        return Pairing(
            before=none,
            after=none.copy(),
            nearest=none.copy(),
            dt_s=np.full(n, np.nan),
            weight=np.zeros(n),
            in_gap=np.ones(n, dtype=bool),
            gaps=gaps,
            duplicates=duplicates,
            out_of_order=out_of_order,
            period_s=period_ns * 1e-9,
            n_frames=int(f_ns.size),
        )

    # pos in 0..k: the point lies after frame pos - 1 and before frame pos (time order).
    # Two int64 scratch buffers are reused: fresh 10M-element arrays cost page faults.
    pos = np.searchsorted(t, p, side="right")
    idx_pad = np.concatenate([[-1], usable, [-1]]).astype(np.int64)
    before = idx_pad.take(pos)
    after = idx_pad[1:].take(pos)
    # the nearer frame: after when p is past the interval's midpoint (ties go to before);
    # the floor of the midpoint is exact for integer p, and the ends always pick their frame
    big = np.iinfo(np.int64).max
    mid = np.concatenate([[-big - 1], t[:-1] + (t[1:] - t[:-1]) // 2, [big]])
    s1 = mid.take(pos)
    use_after = p > s1
    near_pos = np.add(pos, use_after, out=s1)  # 1..k: frame near_pos - 1 in time order
    nearest = idx_pad.take(near_pos)
    t_pad = np.concatenate([[t[0]], t, [t[-1]]])
    s2 = t_pad.take(near_pos)
    dt_s = np.subtract(p, s2, out=s2) * 1e-9

    # weight of after; the ends' spans of -1 clip to 1 before the first frame, 0 after
    d_before = np.subtract(p, t_pad.take(pos, out=s1, mode="clip"), out=s1)
    span = np.concatenate([[-1], np.diff(t), [-1]])
    weight = d_before / span.take(pos, out=s2, mode="clip")
    np.clip(weight, 0.0, 1.0, out=weight)

    if math.isnan(limit_ns):
        in_gap = np.ones(n, dtype=bool)
    else:
        gap_at = np.zeros(k + 1, dtype=bool)
        gap_at[1:k] = is_gap
        in_gap = gap_at[pos]
        in_gap &= d_before != 0  # exactly at a frame: paired with it
        half = limit_ns / 2
        in_gap |= p < t[0] - half
        in_gap |= p > t[-1] + half

    return Pairing(
        before=before,
        after=after,
        nearest=nearest,
        dt_s=dt_s,
        weight=weight,
        in_gap=in_gap,
        gaps=gaps,
        duplicates=duplicates,
        out_of_order=out_of_order,
        period_s=period_ns * 1e-9,
        n_frames=int(f_ns.size),
    )


def frames_used(pairing: Pairing) -> np.ndarray:
    """Ascending int64 indices of the frames some point has as ``nearest`` (decode each once)."""
    used = np.zeros(pairing.n_frames, dtype=bool)
    nearest = pairing.nearest
    used[nearest[nearest >= 0]] = True
    return np.flatnonzero(used).astype(np.int64)
