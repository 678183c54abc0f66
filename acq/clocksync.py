"""Device clocks mapped to the host clock from one-way timing.

A device stamps its telegrams with its own counter (Hokuyo: 24-bit ms; SICK: 32-bit
µs); the host sees each telegram some time after the device stamped it. Every delay is
>= the constant transport latency, so the points (device time, host receive time) lie on
or above the line ``host = offset + (1 + drift) * device + latency``: the estimator
follows the lower convex hull of the recent points (the approach of TICSync) and takes
the hull edge under the window's mean device time, which is the line below every point
that is closest to them all. Latency spikes and bursts lie above the hull and do not move
it. The constant latency itself cannot be seen by one-way timing: it is the device's
configured ``latency_s``.

:class:`Unwrapper` turns a wrapping counter into a monotonic one, using the host clock
to recover wraps missed during a disconnection, and detects a counter that restarted
(a reboot) as a new epoch.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["DeviceClock", "Unwrapper", "retime_offline"]


@dataclass
class Unwrapper:
    """Unwraps a ``wrap_bits``-bit counter at ``tick_hz`` with the help of host time.

    ``unwrap(tick, recv_ns)`` returns the unwrapped tick of the current epoch; a tick
    that no wrap count can reconcile with the host time elapsed since the previous one
    (more than ``tolerance_s`` plus ``max_drift`` of the elapsed time off) starts a new
    epoch: ``epoch`` increments and the count restarts from that tick.
    """

    tick_hz: float
    wrap_bits: int
    tolerance_s: float = 0.5
    max_drift: float = 1e-3
    epoch: int = 0
    _last: int | None = None  # unwrapped tick
    _last_ns: int = 0

    def unwrap(self, tick: int, recv_ns: int) -> int:
        modulus = 1 << self.wrap_bits
        tick %= modulus
        if self._last is None:
            self._last, self._last_ns = tick, recv_ns
            return tick
        elapsed = (recv_ns - self._last_ns) * 1e-9
        expected = self._last + elapsed * self.tick_hz
        candidate = tick + modulus * round((expected - tick) / modulus)
        allowed = (self.tolerance_s + self.max_drift * abs(elapsed)) * self.tick_hz
        if abs(candidate - expected) > allowed:
            self.epoch += 1  # the counter restarted: a reboot
            candidate = tick
        self._last, self._last_ns = candidate, recv_ns
        return candidate

    def nearest(self, tick: int) -> int:
        """The unwrapped value of ``tick`` nearest the last one seen (for queries)."""
        modulus = 1 << self.wrap_bits
        base = self._last if self._last is not None else 0
        tick %= modulus
        return tick + modulus * round((base - tick) / modulus)


class DeviceClock:
    """Host time of device ticks, from (tick, host receive ns) pairs in arrival order.

    The last ``window_s`` of device time are kept as the earliest arrival in each
    ``bucket_s`` of device time (the rest lie above the lower envelope anyway), so an
    update costs the same at any rate. The drift estimate is bounded by
    ``max_drift_ppm``. ``drift_ppm`` and ``uncertainty_s`` (how far the envelope's
    vertices stray from the chosen line) describe the current estimate; ``epoch``
    counts device clock restarts, each of which starts the estimate afresh.
    """

    def __init__(
        self,
        tick_hz: float,
        wrap_bits: int = 32,
        window_s: float = 120.0,
        bucket_s: float = 0.5,
        max_drift_ppm: float = 500.0,
    ) -> None:
        self.tick_hz = tick_hz
        self.unwrapper = Unwrapper(tick_hz, wrap_bits)
        self.window_s = window_s
        self.bucket_s = bucket_s
        self.max_drift = max_drift_ppm * 1e-6
        # (bucket index, device s, host s) of the earliest arrival per bucket, relative
        self._buckets: deque[tuple[int, float, float]] = deque()
        self._hull: list[tuple[float, float]] = []
        self._x0: float | None = None  # device s of the origin
        self._y0_ns: int = 0  # host ns of the origin
        self._line: tuple[float, float] | None = None  # (a, b): y = a + b x, relative
        self._epoch = 0
        self.uncertainty_s = math.inf
        self.updates = 0

    @property
    def epoch(self) -> int:
        return self.unwrapper.epoch

    def _reset(self) -> None:
        self._buckets.clear()
        self._hull = []
        self._x0 = None
        self._line = None
        self.uncertainty_s = math.inf

    def update(self, tick: int, recv_ns: int) -> None:
        """Add one observation: the device stamped ``tick`` and the host got it at ``recv_ns``."""
        unwrapped = self.unwrapper.unwrap(tick, recv_ns)
        if self.unwrapper.epoch != self._epoch:
            self._epoch = self.unwrapper.epoch
            self._reset()
        x_abs = unwrapped / self.tick_hz
        if self._x0 is None:
            self._x0, self._y0_ns = x_abs, recv_ns
        x = x_abs - self._x0
        y = (recv_ns - self._y0_ns) * 1e-9
        self.updates += 1
        k = math.floor(x / self.bucket_s)
        buckets = self._buckets
        if buckets and buckets[-1][0] >= k:
            if buckets[-1][0] > k or y - x >= buckets[-1][2] - buckets[-1][1]:
                return  # later in its bucket than the earliest arrival: no news
            buckets[-1] = (k, x, y)
        else:
            buckets.append((k, x, y))
            while buckets[0][1] < x - self.window_s:
                buckets.popleft()
        self._hull = []
        for _, bx, by in buckets:
            self._push(bx, by)
        self._fit()

    def _push(self, x: float, y: float) -> None:
        hull = self._hull
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            # keep only left turns (lower hull, x increasing)
            if (x2 - x1) * (y - y1) - (y2 - y1) * (x - x1) <= 0:
                hull.pop()
            else:
                break
        hull.append((x, y))

    def _fit(self) -> None:
        hull = self._hull
        if len(hull) == 1:
            x, y = hull[0]
            self._line = (y - x, 1.0)
            return
        mean_x = sum(b[1] for b in self._buckets) / len(self._buckets)
        # the hull edge over the mean device time
        i = 0
        while i < len(hull) - 2 and hull[i + 1][0] < mean_x:
            i += 1
        (x1, y1), (x2, y2) = hull[i], hull[i + 1]
        b = (y2 - y1) / (x2 - x1)
        b = min(max(b, 1.0 - self.max_drift), 1.0 + self.max_drift)
        # through the lower of the two vertices after clamping, so it stays below both
        a = min(y1 - b * x1, y2 - b * x2)
        self._line = (a, b)
        self.uncertainty_s = max(abs(y - (a + b * x)) for x, y in hull) if len(hull) > 2 else 0.0

    @property
    def drift_ppm(self) -> float:
        return (self._line[1] - 1.0) * 1e6 if self._line else 0.0

    def to_host_ns(self, tick: int) -> int:
        """Best current estimate of the host time (ns) at which the device read ``tick``."""
        if self._line is None or self._x0 is None:
            raise ValueError("no observation yet")
        x = self.unwrapper.nearest(tick) / self.tick_hz - self._x0
        a, b = self._line
        return self._y0_ns + round((a + b * x) * 1e9)


def _lower_hull(xs: np.ndarray, ys: np.ndarray) -> list[int]:
    """Indices of the lower convex hull of points sorted by x."""
    hull: list[int] = []
    for i in range(xs.size):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            if (xs[b] - xs[a]) * (ys[i] - ys[a]) - (ys[b] - ys[a]) * (xs[i] - xs[a]) <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    return hull


def _periodic_device_times(u: np.ndarray, tick_hz: float) -> np.ndarray | None:
    """Device seconds of a periodic stream's stamps, finer than its ticks.

    A scanner's stamps come once a turn: the true stamp of turn k is ``phase + k·period``
    and the device reports ``floor`` of it in ticks. A straight line through
    (k, tick + 1/2) recovers the stamps to far better than a tick when the period is not
    a whole number of ticks (it never is exactly). None when the stream is not periodic
    to within a tick.
    """
    if u.size < 20:
        return None
    steps = np.diff(u)
    period = float(np.median(steps))
    if period <= 0:
        return None
    # turn numbers, counting a gap of n periods as n turns
    turns = np.round(steps / period)
    if np.any(turns <= 0):
        return None
    k = np.concatenate([[0.0], np.cumsum(turns)])
    coef = np.polyfit(k, u + 0.5, 1)
    fit = np.polyval(coef, k)
    if np.max(np.abs(fit - (u + 0.5))) > 1.0:  # more than the quantisation: not periodic
        return None
    return fit / tick_hz


def retime_offline(
    ticks: npt.ArrayLike,
    recv_ns: npt.ArrayLike,
    tick_hz: float,
    wrap_bits: int,
    *,
    window_s: float = 120.0,
    bucket_s: float = 0.5,
    max_drift_ppm: float = 500.0,
) -> np.ndarray:
    """Host ns of every stamp of a whole log, using past and future samples alike.

    Per device-clock epoch: unwrap the ticks; for a periodic stream (a scanner's turns)
    replace each tick by the fitted stamp; then, for every ``bucket_s`` of device time,
    take the lower convex hull of the earliest arrivals within ``window_s`` centred on
    it and the hull edge under its centre, as :class:`DeviceClock` does online but
    looking both ways. Returns float64 ns (same order as the input).
    """
    ticks = np.asarray(ticks, dtype=np.int64)
    recv = np.asarray(recv_ns, dtype=np.int64)
    unwrapper = Unwrapper(tick_hz, wrap_bits)
    u = np.empty(ticks.size, dtype=np.float64)
    epochs = np.empty(ticks.size, dtype=np.int64)
    for i, (t, r) in enumerate(zip(ticks.tolist(), recv.tolist(), strict=True)):
        u[i] = unwrapper.unwrap(t, r)
        epochs[i] = unwrapper.epoch
    out = np.empty(ticks.size, dtype=np.float64)
    max_drift = max_drift_ppm * 1e-6
    for epoch in np.unique(epochs):
        sel = np.flatnonzero(epochs == epoch)
        dev = _periodic_device_times(u[sel], tick_hz)
        # the middle of a tick is the best guess of when within it the stamp was taken
        x = dev if dev is not None else (u[sel] + 0.5) / tick_hz
        x0, y0 = x[0], recv[sel[0]]
        x = x - x0
        y = (recv[sel] - y0) * 1e-9
        # earliest arrival (least y - x) in each bucket
        b = np.floor(x / bucket_s).astype(np.int64)
        order = np.lexsort((y - x, b))
        first = np.ones(order.size, dtype=bool)
        first[1:] = b[order][1:] != b[order][:-1]
        keep = order[first]
        bx, by = x[keep], y[keep]
        est = np.empty(sel.size)
        for bucket in np.unique(b):
            centre = (bucket + 0.5) * bucket_s
            near = np.flatnonzero(np.abs(bx - centre) <= window_s / 2)
            hx, hy = bx[near], by[near]
            hull = _lower_hull(hx, hy)
            members = b == bucket
            if len(hull) == 1:
                a, slope = hy[hull[0]] - hx[hull[0]], 1.0
            else:
                j = 0
                while j < len(hull) - 2 and hx[hull[j + 1]] < centre:
                    j += 1
                i1, i2 = hull[j], hull[j + 1]
                slope = (hy[i2] - hy[i1]) / (hx[i2] - hx[i1])
                slope = min(max(slope, 1.0 - max_drift), 1.0 + max_drift)
                a = min(hy[i1] - slope * hx[i1], hy[i2] - slope * hx[i2])
            est[members] = a + slope * x[members]
        out[sel] = y0 + est * 1e9
    return out
