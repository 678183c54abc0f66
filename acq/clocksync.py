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

__all__ = ["DeviceClock", "Unwrapper"]


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
