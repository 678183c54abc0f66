"""Offline re-timing of a recorded log's scan and frame stamps (``acq colorize``).

The recorder stamps online: a scan by its device tick through the one-way clock
estimate of that moment (:class:`acq.time.clocksync.DeviceClock`), a frame by its receipt
minus the camera's configured latency. Offline, the whole log is known:

- scans (:func:`retime_scans`): every tick mapped with
  :func:`acq.time.clocksync.retime_offline` (both sides of each stamp; below the tick's
  quantisation for a scanner's regular turns). The recorder's constant part (the stamp's
  angular offset and the transport latency it subtracted) is kept: it is the median of
  online stamp minus offline host time of the tick, which the online estimate gets right
  once settled;
- frames (:func:`retime_frames`): a camera exposes on a regular grid, and its receipt
  times scatter above it by the transport's jitter (milliseconds for MJPEG over HTTP).
  Per run of frames without a gap longer than ``max_gap_s``, each frame is put on the
  grid slot nearest its stamp and the slots are fitted with one line by least squares
  (outliers beyond ``clip_ms`` left out, then snapped): the jitter averages out while
  the configured mean latency stays the reference. A run that is not grid-like (fewer
  than ``min_share`` of its frames near the line, two frames in one slot, residuals
  above ``max_residual_ms``: a camera that changed its rate) keeps its stamps, and the
  report says so.

Times are host monotonic ns (int64).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acq.time.clocksync import retime_offline

__all__ = ["FrameRetiming", "ScanRetiming", "retime_frames", "retime_scans"]


@dataclass(frozen=True)
class ScanRetiming:
    """New ``scan_ns`` and how far they moved: ``shift_rms_ms`` / ``shift_max_ms`` (new
    minus recorded), ``retimed`` scans that had ticks, ``note`` when nothing was done."""

    scan_ns: np.ndarray
    retimed: int
    shift_rms_ms: float
    shift_max_ms: float
    note: str = ""


@dataclass(frozen=True)
class FrameRetiming:
    """New ``frame_ns``: ``period_s`` of the fitted grid (median over runs), ``runs``
    fitted, ``kept`` frames left as recorded (runs too short or not grid-like, and
    outliers), ``residual_rms_ms`` of the fitted stamps about their grid (the jitter
    removed), ``shift_max_ms`` the largest change."""

    frame_ns: np.ndarray
    period_s: float
    runs: int
    kept: int
    residual_rms_ms: float
    shift_max_ms: float
    note: str = ""


def retime_scans(
    scan_ns: np.ndarray,
    ticks: np.ndarray,
    recv_ns: np.ndarray,
    tick_hz: float,
    wrap_bits: int,
) -> ScanRetiming:
    """Offline stamps of scans with their recorded ``scan_ns``, raw device ``ticks``
    (-1 unknown) and receipt times (see the module docstring)."""
    scan_ns = np.asarray(scan_ns, dtype=np.int64)
    ticks = np.asarray(ticks, dtype=np.int64)
    recv = np.asarray(recv_ns, dtype=np.int64)
    ok = (ticks >= 0) & (recv > 0)
    if ok.sum() < 10:
        return ScanRetiming(scan_ns.copy(), 0, 0.0, 0.0, "too few scans with device ticks")
    host = retime_offline(ticks[ok], recv[ok], tick_hz, wrap_bits)
    constant = np.median(scan_ns[ok] - host)
    out = scan_ns.copy()
    out[ok] = np.rint(host + constant).astype(np.int64)
    shift = (out[ok] - scan_ns[ok]) * 1e-6
    return ScanRetiming(
        out, int(ok.sum()), float(np.sqrt(np.mean(shift**2))), float(np.abs(shift).max())
    )


def _fit_run(t: np.ndarray, period: float, clip_ns: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid times (float ns) of one run of stamps ``t`` (float ns, sorted) and the mask
    of those within ``clip_ns`` of the grid. The grid is grown from the run's start
    (25 frames, then doubling) so that a rough ``period`` cannot slip a slot far out."""
    coef = np.array([period, t[0]])
    n = min(t.size, 25)
    while True:
        for _ in range(3):
            slot = np.rint((t[:n] - coef[1]) / coef[0])
            keep = np.abs(t[:n] - np.polyval(coef, slot)) <= clip_ns
            if keep.sum() >= 3 and np.unique(slot[keep]).size >= 2:
                coef = np.polyfit(slot[keep], t[:n][keep], 1)
        if n == t.size:
            break
        n = min(t.size, 2 * n)
    # frames come late, rarely early, and in order: going backwards, a frame whose slot
    # is not before the next frame's takes the slot before it (the one it was late for)
    slot = np.rint((t - coef[1]) / coef[0])
    for i in range(t.size - 2, -1, -1):
        if slot[i] >= slot[i + 1]:
            slot[i] = slot[i + 1] - 1
    keep = np.abs(t - np.polyval(coef, slot)) <= clip_ns
    return np.polyval(coef, slot), keep


def retime_frames(
    frame_ns: np.ndarray,
    *,
    max_gap_s: float = 1.0,
    clip_ms: float = 12.0,
    min_frames: int = 25,
    min_share: float = 0.9,
    max_residual_ms: float = 6.0,
) -> FrameRetiming:
    """Frame stamps on the camera's fitted grid (see the module docstring)."""
    t = np.asarray(frame_ns, dtype=np.int64)
    out = t.copy()
    if t.size < min_frames:
        return FrameRetiming(out, float("nan"), 0, int(t.size), 0.0, 0.0, "too few frames")
    order = np.argsort(t, kind="stable")
    ts = t[order].astype(np.float64)
    steps = np.diff(ts)
    if not (steps > 0).any():
        return FrameRetiming(out, float("nan"), 0, int(t.size), 0.0, 0.0, "one stamp only")
    gaps = np.flatnonzero(steps > max_gap_s * 1e9) + 1
    period = float(np.median(steps[steps > 0]))  # a frame read twice has no period
    periods, resid, runs, kept = [], [], 0, 0
    fitted = ts.copy()
    for run in np.split(np.arange(ts.size), gaps):
        if run.size < min_frames:
            kept += run.size
            continue
        grid, keep = _fit_run(ts[run], period, clip_ms * 1e6)
        r = (ts[run] - grid)[keep]
        if keep.mean() < min_share or np.sqrt(np.mean(r**2)) > max_residual_ms * 1e6:
            kept += run.size
            continue
        fitted[run] = grid  # outliers snapped to their slot too: a late frame is late
        runs += 1
        periods.append(float(np.median(np.diff(grid))))
        resid.append(r)
    out[order] = np.rint(fitted).astype(np.int64)
    note = "" if runs else "no run of frames on a regular grid: stamps kept"
    r_all = np.concatenate(resid) if resid else np.zeros(0)
    return FrameRetiming(
        out,
        float(np.median(periods)) * 1e-9 if periods else float("nan"),
        runs,
        kept,
        float(np.sqrt(np.mean(r_all**2))) * 1e-6 if r_all.size else 0.0,
        float(np.abs(out - t).max()) * 1e-6,
        note,
    )
