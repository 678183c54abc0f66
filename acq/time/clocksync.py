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
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

__all__ = [
    "DeviceClock",
    "DriftFit",
    "TurnFit",
    "Unwrapper",
    "fit_drift",
    "fit_log_drift",
    "latency_bounds",
    "retime_offline",
]


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


class TurnFit:
    """Turn numbers of a periodic stream (a scanner's stamps), online.

    A scanner stamps each turn: the true stamp of turn k is ``phase + k * period``, and
    the device reports it floored to whole ticks. Counting the turns (from the tick
    steps, so dropped scans are fine) gives a device-time proxy with no quantisation at
    all: any fixed affine function of the turn number. The least-squares line through
    (k, tick + 1/2) over the last ``window`` turns supplies that function (and maps a
    tick back to its turn). A stamp more than one tick off the line means the stream is
    not (or no longer) periodic: the count restarts from it as a new ``run``.
    """

    def __init__(self, window: int = 4800, min_turns: int = 20) -> None:
        self.window = window
        self.min_turns = min_turns
        self.run = 0
        self._turns: deque[tuple[int, float]] = deque()  # (k, tick + 1/2 - base)
        self._base = 0.0
        self._k0 = 0  # the turn the sums are relative to
        self._sums = [0.0] * 5  # n, Σk, Σv, Σk², Σkv (k relative to _k0)
        self._line: tuple[float, float] | None = None  # v = a + b (k - k0)

    @property
    def ready(self) -> bool:
        return self._line is not None

    def reset(self) -> None:
        self._turns.clear()
        self._sums = [0.0] * 5
        self._line = None
        self.run += 1

    def _resum(self) -> None:
        self._k0 = self._turns[0][0]
        ks = [float(k - self._k0) for k, _ in self._turns]
        vs = [v for _, v in self._turns]
        self._sums = [float(len(ks)), sum(ks), sum(vs), sum(k * k for k in ks),
                      sum(k * v for k, v in zip(ks, vs, strict=True))]  # fmt: skip

    def _add_sums(self, k: int, v: float, sign: float) -> None:
        kr = k - self._k0
        s = self._sums
        s[0] += sign
        s[1] += sign * kr
        s[2] += sign * v
        s[3] += sign * kr * kr
        s[4] += sign * kr * v

    def add(self, tick: int) -> int:
        """Add the next stamp (an unwrapped tick, in arrival order); its turn number."""
        turns = self._turns
        if not turns:
            self._base = float(tick)
            turns.append((0, 0.5))
            self._resum()
            return 0
        v = tick - self._base + 0.5
        k_last, v_last = turns[-1]
        if self._line is not None:
            period = self._line[1]
        elif len(turns) > 1:
            period = (v_last - turns[0][1]) / (k_last - turns[0][0])
        else:
            period = v - v_last
        steps = round((v - v_last) / period) if period > 0 else 0
        if steps < 1 or (self._line is not None and abs(self._at(k_last + steps) - v) > 1.0):
            self.reset()  # not the next turn of the same periodic stream
            return self.add(tick)
        k = k_last + steps
        turns.append((k, v))
        self._add_sums(k, v, 1.0)
        while len(turns) > self.window:
            k_old, v_old = turns.popleft()
            self._add_sums(k_old, v_old, -1.0)
        if k - self._k0 > 4 * self.window:  # keep the sums well conditioned
            self._resum()
        n, sk, sv, skk, skv = self._sums
        if n >= self.min_turns:
            b = (n * skv - sk * sv) / (n * skk - sk * sk)
            first = self._line is None
            self._line = ((sv - b * sk) / n, b)
            if first and any(abs(self._at(kk) - vv) > 1.0 for kk, vv in turns):
                self.reset()  # the first turns do not lie on a line: not periodic
                return self.add(tick)
        return k

    def _at(self, k: int) -> float:
        assert self._line is not None
        a, b = self._line
        return a + b * (k - self._k0)

    def ticks_at(self, k: int) -> float:
        """The device time of turn ``k`` on the current line, in (fractional) ticks."""
        return self._base + self._at(k)

    def turn_of(self, tick: int) -> int | None:
        """The turn whose stamp is this unwrapped tick, or None if no turn's is.

        A stamp's tick lies within half a tick of its turn on the line (plus the fit's
        error); a quarter tick more is allowed.
        """
        if self._line is None:
            return None
        v = tick + 0.5 - self._base
        a, b = self._line
        k = self._k0 + round((v - a) / b)
        return k if abs(self._at(k) - v) <= 0.75 else None


class DeviceClock:
    """Host time of device ticks, from (tick, host receive ns) pairs in arrival order.

    The last ``window_s`` of device time are kept as the earliest arrival in each
    ``bucket_s`` of device time (the rest lie above the lower envelope anyway), so an
    update costs the same at any rate. The drift estimate is bounded by
    ``max_drift_ppm``. With ``periodic`` (the default), stamps that come once a turn are
    placed by their turn number (:class:`TurnFit`), which carries no tick quantisation;
    other stamps get the middle of their tick. ``drift_ppm`` and ``uncertainty_s`` (how
    far the envelope's vertices stray from the chosen line) describe the current
    estimate; ``epoch`` counts device clock restarts, each of which starts afresh.
    """

    def __init__(
        self,
        tick_hz: float,
        wrap_bits: int = 32,
        window_s: float = 120.0,
        bucket_s: float = 0.5,
        max_drift_ppm: float = 500.0,
        periodic: bool = True,
    ) -> None:
        self.tick_hz = tick_hz
        self.unwrapper = Unwrapper(tick_hz, wrap_bits)
        self.turns = TurnFit() if periodic else None
        self.window_s = window_s
        self.bucket_s = bucket_s
        self.max_drift = max_drift_ppm * 1e-6
        # earliest arrival per bucket: (bucket index, unwrapped tick, turn, run, host s)
        self._buckets: deque[tuple[int, int, int | None, int, float]] = deque()
        self._u0: int | None = None  # unwrapped tick of the origin
        self._y0_ns: int = 0  # host ns of the origin
        self._line: tuple[float, float] | None = None  # (a, b): host = a + b device, rel.
        self._epoch = 0
        self.uncertainty_s = math.inf
        self.updates = 0

    @property
    def epoch(self) -> int:
        return self.unwrapper.epoch

    def _reset(self) -> None:
        self._buckets.clear()
        self._u0 = None
        self._line = None
        self.uncertainty_s = math.inf
        if self.turns is not None:
            self.turns.reset()

    def _device_s(self, u: int, k: int | None, run: int) -> float:
        """Device seconds since the origin of a stamp (its turn's, where it has one)."""
        assert self._u0 is not None
        turns = self.turns
        if turns is not None and k is not None and run == turns.run and turns.ready:
            return (turns.ticks_at(k) - self._u0) / self.tick_hz
        return (u + 0.5 - self._u0) / self.tick_hz

    def update(self, tick: int, recv_ns: int) -> None:
        """Add one observation: the device stamped ``tick`` and the host got it at ``recv_ns``."""
        u = self.unwrapper.unwrap(tick, recv_ns)
        if self.unwrapper.epoch != self._epoch:
            self._epoch = self.unwrapper.epoch
            self._reset()
        k = self.turns.add(u) if self.turns is not None else None
        run = self.turns.run if self.turns is not None else 0
        if self._u0 is None:
            self._u0, self._y0_ns = u, recv_ns
        y = (recv_ns - self._y0_ns) * 1e-9
        self.updates += 1
        key = math.floor((u - self._u0) / self.tick_hz / self.bucket_s)
        buckets = self._buckets
        if buckets and buckets[-1][0] >= key:
            last = buckets[-1]
            if last[0] > key:
                return
            delay = y - self._device_s(u, k, run)
            if delay >= last[4] - self._device_s(last[1], last[2], last[3]):
                return  # later in its bucket than the earliest arrival: no news
            buckets[-1] = (key, u, k, run, y)
        else:
            buckets.append((key, u, k, run, y))
            horizon = (u - self._u0) / self.tick_hz - self.window_s
            while (buckets[0][1] - self._u0) / self.tick_hz < horizon:
                buckets.popleft()
        bx = np.array([self._device_s(b[1], b[2], b[3]) for b in buckets])
        by = np.array([b[4] for b in buckets])
        hull = _lower_hull(bx, by)
        self._line = _support_line(bx, by, hull, float(bx.mean()), self.max_drift)
        a, b = self._line
        self.uncertainty_s = float(np.max(np.abs(by[hull] - (a + b * bx[hull]))))

    @property
    def drift_ppm(self) -> float:
        return (self._line[1] - 1.0) * 1e6 if self._line else 0.0

    def to_host_ns(self, tick: int, *, stamp: bool = True) -> int:
        """Best current estimate of the host time (ns) at which the device read ``tick``.

        ``stamp=False`` for a tick that is not one of the stream's stamps (a clock
        query's answer): it then gets the middle of its tick, never a turn's time.
        """
        if self._line is None or self._u0 is None:
            raise ValueError("no observation yet")
        u = self.unwrapper.nearest(tick)
        turns = self.turns
        k = turns.turn_of(u) if turns is not None and stamp else None
        x = self._device_s(u, k, turns.run if turns is not None else 0)
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


def _support_line(
    xs: np.ndarray, ys: np.ndarray, hull: list[int], at_x: float, max_drift: float
) -> tuple[float, float]:
    """(a, b) of the line y = a + b x along the hull edge under ``at_x``.

    The slope is clamped to 1 ± ``max_drift``; the line then goes through the lower of
    the edge's two vertices, so it stays below both. A one-point hull gives slope 1.
    """
    if len(hull) == 1:
        return float(ys[hull[0]] - xs[hull[0]]), 1.0
    j = 0
    while j < len(hull) - 2 and xs[hull[j + 1]] < at_x:
        j += 1
    i1, i2 = hull[j], hull[j + 1]
    b = float((ys[i2] - ys[i1]) / (xs[i2] - xs[i1]))
    b = min(max(b, 1.0 - max_drift), 1.0 + max_drift)
    a = float(min(ys[i1] - b * xs[i1], ys[i2] - b * xs[i2]))
    return a, b


def _turn_times(u: np.ndarray) -> np.ndarray:
    """Device time of each stamp in (fractional) ticks, from its turn where periodic.

    The offline counterpart of :class:`TurnFit`: the turns are counted in one pass, and
    each run of turns gets one least-squares line through (k, tick + 1/2) over the
    whole run (both sides of every stamp). A run that strays more than a tick from its
    line (a motor whose speed wandered) keeps the middle of its ticks.
    """
    fit = TurnFit(window=max(u.size, 1))
    ks = np.empty(u.size, dtype=np.float64)
    runs = np.empty(u.size, dtype=np.int64)
    for i, t in enumerate(u.tolist()):
        ks[i] = fit.add(int(t))
        runs[i] = fit.run
    out = u + 0.5
    for run in np.unique(runs):
        sel = runs == run
        if sel.sum() < fit.min_turns:
            continue
        coef = np.polyfit(ks[sel], out[sel], 1)
        line = np.polyval(coef, ks[sel])
        if np.max(np.abs(line - out[sel])) <= 1.0:
            out[sel] = line
    return out


def retime_offline(
    ticks: npt.ArrayLike,
    recv_ns: npt.ArrayLike,
    tick_hz: float,
    wrap_bits: int,
    *,
    window_s: float = 120.0,
    bucket_s: float = 0.5,
    max_drift_ppm: float = 500.0,
    periodic: bool = True,
) -> np.ndarray:
    """Host ns of every stamp of a whole log, using past and future samples alike.

    Per device-clock epoch: unwrap the ticks; refine periodic stamps below the tick
    from the turns on both sides; keep the earliest arrival per ``bucket_s`` of device
    time; then for each bucket take the lower convex hull of the ``window_s`` centred
    on it (shifted to stay inside the log at its ends, so the first and last minutes
    are not fitted on a few points) and the hull edge under that window's centre, as
    :class:`DeviceClock` does online but looking both ways. Returns float64 ns in the
    input's order.
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
        x = (_turn_times(u[sel]) if periodic else u[sel] + 0.5) / tick_hz
        x0, y0 = x[0], recv[sel[0]]
        x = x - x0
        y = (recv[sel] - y0) * 1e-9
        bx, by = _earliest_per_bucket(x, y, bucket_s)
        b = np.floor(x / bucket_s).astype(np.int64)
        est = np.empty(sel.size)
        first, last = float(bx[0]), float(bx[-1])
        whole = last - first <= window_s
        for bucket in np.unique(b):
            centre = (bucket + 0.5) * bucket_s
            lo = first if whole else min(max(centre - window_s / 2, first), last - window_s)
            near = np.flatnonzero((bx >= lo) & (bx <= lo + window_s))
            hx, hy = bx[near], by[near]
            at = float(hx.mean()) if whole else lo + window_s / 2
            a, slope = _support_line(hx, hy, _lower_hull(hx, hy), at, max_drift)
            members = b == bucket
            est[members] = a + slope * x[members]
        out[sel] = y0 + est * 1e9
    return out


def _earliest_per_bucket(
    x: np.ndarray, y: np.ndarray, bucket_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the earliest arrival (least y - x) in each ``bucket_s`` of x, sorted."""
    b = np.floor(x / bucket_s).astype(np.int64)
    order = np.lexsort((y - x, b))
    first = np.ones(order.size, dtype=bool)
    first[1:] = b[order][1:] != b[order][:-1]
    keep = order[first]
    return x[keep], y[keep]


@dataclass(frozen=True)
class DriftFit:
    """A device clock's rate against the host's over one stretch of (device, host) times.

    ``drift_ppm`` is (d host / d device - 1) · 1e6, from the lower envelope of the delays;
    ``drift_ci_ppm`` its confidence interval; ``offset_s`` host minus device seconds on
    the envelope line at the first sample; the residuals are the delays above the line
    (seconds): what one-way timing sees of the transport jitter.
    """

    drift_ppm: float
    drift_ci_ppm: tuple[float, float]
    offset_s: float
    residual_median_s: float
    residual_p95_s: float
    residual_max_s: float
    n: int


def _envelope_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    return _support_line(x, y, _lower_hull(x, y), float(x.mean()), 0.5)


def fit_drift(
    device_s: npt.ArrayLike,
    host_s: npt.ArrayLike,
    *,
    confidence: float = 0.95,
    reps: int = 400,
    seed: int = 0,
    tick_s: float = 0.0,
) -> DriftFit:
    """Drift and offset of a device clock from (device s, host receive s) pairs.

    The line is the lower-envelope edge under the mean device time (as
    :class:`DeviceClock`). Its slope is an extreme-value estimate (it rests on the few
    least-delayed samples), so the interval comes from subsampling rather than from a
    Gaussian formula: the slope is recomputed on ``reps`` random halves of the samples
    and their spread is scaled to the full set at the rate 1/n of such estimates.
    ``tick_s``, the device clock's resolution, widens the interval by what the device
    times cannot show: one tick over their span (a 1 ms clock: 100 ppm over 10 s).
    """
    x = np.asarray(device_s, dtype=np.float64)
    y = np.asarray(host_s, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"device_s and host_s must be 1-D of one length: {x.shape}, {y.shape}")
    if x.size < 3:
        raise ValueError(f"fit_drift needs at least 3 samples, got {x.size}")
    order = np.argsort(x, kind="stable")
    x0, y0 = x[order[0]], y[order[0]]
    x, y = x[order] - x0, y[order] - y0
    a, b = _envelope_slope(x, y)
    resid = y - (a + b * x)
    n = x.size
    m = n // 2
    rng = np.random.default_rng(seed)
    dev = np.empty(reps)
    for r in range(reps):
        idx = np.sort(rng.choice(n, m, replace=False))
        dev[r] = _envelope_slope(x[idx], y[idx])[1] - b
    tail = (1.0 - confidence) / 2
    q_lo, q_hi = np.quantile(dev, [tail, 1.0 - tail]) * (m / n)
    if tick_s > 0:
        unseen = tick_s / max(float(x[-1]), tick_s)  # the span's first and last ticks
        q_lo, q_hi = q_lo - unseen, q_hi + unseen
    return DriftFit(
        drift_ppm=(b - 1.0) * 1e6,
        drift_ci_ppm=(float(b - q_hi - 1.0) * 1e6, float(b - q_lo - 1.0) * 1e6),
        offset_s=float(y0 - x0 + a),
        residual_median_s=float(np.median(resid)),
        residual_p95_s=float(np.quantile(resid, 0.95)),
        residual_max_s=float(resid.max()),
        n=int(n),
    )


def fit_log_drift(
    ticks: npt.ArrayLike, recv_ns: npt.ArrayLike, tick_hz: float, *, buckets: int = 1000
) -> DriftFit:
    """:func:`fit_drift` over one device-clock epoch of a log: unwrapped ``ticks`` and
    their host receive ns (arrays of one length), periodic stamps placed by their turn;
    first the earliest arrival in each of at most ``buckets`` stretches of device time
    (at least 0.5 s each), so that a log of hours costs what one of minutes does; the
    interval widened by the samples' median delay above the line, over the span."""
    u = np.asarray(ticks, dtype=np.float64)
    x = _turn_times(u) / tick_hz
    y = np.asarray(recv_ns, dtype=np.int64)
    x0, y0 = float(x.min()), int(y.min())
    xs, ys = x - x0, (y - y0) * 1e-9
    bucket_s = max(0.5, float(xs.max()) / buckets)
    bx, by = _earliest_per_bucket(xs, ys, bucket_s)
    if bx.size < 3:  # under a second and a half: every sample
        bx, by = xs, ys
    fit = fit_drift(bx, by, reps=200, tick_s=1.0 / tick_hz)
    # the floor's own wander, which no subsample of it sees: a host busier over one part
    # of a short log lifts the floor there, which looks like drift; taken to be as much
    # as the samples' median delay above the line, over the span (0.3 ms over 3 s:
    # 100 ppm; over an hour, nothing)
    above = ys - (fit.offset_s + (1.0 + fit.drift_ppm * 1e-6) * xs)
    wander = float(np.median(above)) / max(float(bx.max()), 1e-9) * 1e6
    lo, hi = fit.drift_ci_ppm
    return replace(fit, offset_s=fit.offset_s + y0 * 1e-9 - x0,
                   drift_ci_ppm=(lo - wander, hi + wander))  # fmt: skip


def latency_bounds(
    round_trips: Iterable[tuple[int, int, int]],
    clock: DeviceClock,
    quantisation_ticks: float = 1.0,
) -> tuple[float, float]:
    """Lower and upper bound (s) of the constant latency in ``clock``'s stamp times.

    One-way timing maps a stamp to its true host time plus a constant latency it cannot
    see. A time query (SCIP ``TM1``) sent at host ns ``sent`` and answered by ``recv``
    with ``tick`` shows that the device read ``tick`` between the two: the clock's
    estimate for that tick minus ``recv`` and minus ``sent`` bound the latency from
    below and above, widened by ``quantisation_ticks`` for where in its tick (and in
    the tick of the scan stamps) the reading fell. Round trips from either side of the
    stream intersect. Raises ValueError if they do not (the clock is not that device's,
    or its device clock restarted in between).
    """
    lo, hi = -math.inf, math.inf
    q = quantisation_ticks / clock.tick_hz
    for sent, tick, recv in round_trips:
        est = clock.to_host_ns(tick, stamp=False)
        lo = max(lo, (est - recv) * 1e-9 - q)
        hi = min(hi, (est - sent) * 1e-9 + q)
    if lo == -math.inf:
        raise ValueError("no round trip given")
    if lo > hi:
        raise ValueError(f"round trips disagree with the clock: latency in [{lo}, {hi}] s")
    return lo, hi
