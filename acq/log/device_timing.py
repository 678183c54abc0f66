"""What a log's timing records say of each device's clock (:class:`DeviceSync`), of how
its GNSS fixes were stamped (:class:`GnssStamping`), and the lines ``acq info`` prints for
them and for the host clock's time base. Times ns unless ``_s``/``_ms``."""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from acq.log.timebase import TimeBase
from acq.time.clocksync import fit_log_drift
from acq.time.host_clock_summary import HostClockSummary
from acq.time.utc import host_ns_from_utc

__all__ = [
    "GNSS_TIMING",
    "DeviceSync",
    "DeviceTiming",
    "GnssStamping",
    "device_sync",
    "drift_text",
    "field_of",
    "formatted",
    "gnss_fix_timing",
    "gnss_stamping",
    "gnss_stamping_lines",
    "host_clock_lines",
    "latency_line",
]


@dataclass(frozen=True)
class DeviceSync:
    """Clock-sync quality of one device, from its ``/acq/timing/<device>`` records.

    ``epochs`` counts distinct estimator epochs (a reset or re-sync starts a new one);
    ``drift_ppm`` is the last estimate; ``offset_spread_ms`` is max - min of the
    device-to-host offset over the log; ``uncertainty_s_*`` the estimator's own
    uncertainty, seconds; ``residual_ms_*`` receive time minus mapped stamp
    (``recv_ns - stamp_ns``), milliseconds. ``drift_fit_ppm`` and its 95 % interval
    ``drift_ci_ppm`` come from the whole log's last clock epoch
    (:func:`acq.time.clocksync.fit_log_drift`; the interval counts the device clock's
    resolution). ``latency_*``: what the recorder took off the stamps at the end, how
    it got it, and its bounds where measured (the ``clock`` metadata). ``None`` where
    the log has no such values.
    """

    name: str
    records: int
    epochs: int
    drift_ppm: float | None
    offset_spread_ms: float | None
    uncertainty_s_median: float | None
    uncertainty_s_max: float | None
    residual_ms_p50: float | None
    residual_ms_p95: float | None
    residual_ms_max: float | None
    drift_fit_ppm: float | None = None
    drift_ci_ppm: tuple[float, float] | None = None
    latency_s: float | None = None  # subtracted from the device's stamps, s
    latency_source: str | None = None  # how it was obtained (configured, auto: ...)
    latency_bounds_s: tuple[float, float] | None = None


@dataclass(frozen=True)
class GnssStamping:
    """How a log's GNSS fixes were stamped, from ``/acq/timing/gnss``: ``stamped`` counts
    the fixes per source (``fix``: their own UTC fix time through the host's UTC clock;
    ``receipt``: their receipt times, as logs before the choice existed);
    ``receipt_minus_fix_ms_*``: each fix's receipt minus its UTC fix time on the host
    clock (through the log's ``/acq/clock`` pairs), ms, median and 5th/95th percentiles
    (the spread is their difference); it holds the receiver's delay and the host
    clock's error to UTC. None where the log has no clock pairs."""

    fixes: int
    stamped: dict[str, int]
    receipt_minus_fix_ms_median: float | None
    receipt_minus_fix_ms_p5: float | None
    receipt_minus_fix_ms_p95: float | None


def field_of(message: Any, name: str) -> Any:
    """``message.name``, or None when this version of the schema has no such field."""
    descriptor = getattr(message, "DESCRIPTOR", None)
    if descriptor is None or name not in descriptor.fields_by_name:
        return None
    return getattr(message, name)


def formatted(value: float | None, fmt: str) -> str:
    """``value`` in ``fmt``, "-" for none (None or NaN)."""
    return "-" if value is None or math.isnan(value) else format(value, fmt)


@dataclass
class DeviceTiming:
    """Running totals over one device's ``/acq/timing/<device>`` records."""

    records: int = 0
    epochs: set[int] = field(default_factory=set)
    drift_ppm: float | None = None
    offsets: list[int] = field(default_factory=list)
    uncertainties: list[float] = field(default_factory=list)
    residuals: list[int] = field(default_factory=list)
    dropped: int | None = None
    # the last epoch's (unwrapped tick, receipt ns)
    epoch: int | None = None
    ticks: array[int] = field(default_factory=lambda: array("q"))
    recv: array[int] = field(default_factory=lambda: array("q"))

    def add(self, msg: Any) -> None:
        """One ``acq.Timing`` record more."""
        t = self
        t.records += 1
        epoch = field_of(msg, "epoch")
        if epoch is not None:
            t.epochs.add(int(epoch))
        drift = field_of(msg, "drift_ppm")
        if drift is not None and math.isfinite(drift):
            t.drift_ppm = float(drift)
        offset = field_of(msg, "offset_ns")
        if offset is not None:
            t.offsets.append(int(offset))
        uncertainty = field_of(msg, "uncertainty_s")
        if uncertainty is not None and math.isfinite(uncertainty):  # NaN: no estimate yet
            t.uncertainties.append(float(uncertainty))
        recv, stamp = field_of(msg, "recv_ns"), field_of(msg, "stamp_ns")
        if recv and stamp:
            t.residuals.append(int(recv) - int(stamp))
        tick = field_of(msg, "unwrapped_tick")
        if recv and tick is not None and epoch is not None:
            if epoch != t.epoch:
                t.epoch, t.ticks, t.recv = int(epoch), array("q"), array("q")
            t.ticks.append(int(tick))
            t.recv.append(int(recv))
        dropped = field_of(msg, "dropped")
        if dropped is not None:
            t.dropped = int(dropped)


def device_sync(name: str, t: DeviceTiming, clock: dict[str, str]) -> DeviceSync:
    """``t``'s summary; ``clock`` the recorder's ``clock`` metadata."""
    res = np.asarray(t.residuals, dtype=np.float64) / 1e6
    unc = np.asarray(t.uncertainties, dtype=np.float64)
    fit = None
    hz = _float(clock.get(f"{name}.tick_hz"))
    lo, hi, *_ = [_float(b) for b in clock.get(f"{name}.latency_bounds_s", "").split()] + [None] * 2
    if hz is not None and hz > 0 and len(t.ticks) >= 3 and np.ptp(t.ticks) > 0:
        fit = fit_log_drift(t.ticks, t.recv, hz)
    return DeviceSync(
        name=name,
        records=t.records,
        epochs=len(t.epochs),
        drift_ppm=t.drift_ppm,
        offset_spread_ms=(max(t.offsets) - min(t.offsets)) / 1e6 if t.offsets else None,
        uncertainty_s_median=float(np.median(unc)) if unc.size else None,
        uncertainty_s_max=float(unc.max()) if unc.size else None,
        residual_ms_p50=float(np.percentile(res, 50)) if res.size else None,
        residual_ms_p95=float(np.percentile(res, 95)) if res.size else None,
        residual_ms_max=float(res.max()) if res.size else None,
        drift_fit_ppm=fit.drift_ppm if fit is not None else None,
        drift_ci_ppm=fit.drift_ci_ppm if fit is not None else None,
        latency_s=_float(clock.get(f"{name}.latency_s")),
        latency_source=clock.get(f"{name}.latency_source"),
        latency_bounds_s=(lo, hi) if lo is not None and hi is not None else None,
    )


GNSS_TIMING = "/acq/timing/gnss"  # the GNSS section's fixes (unwrapped_tick: UTC µs)


def gnss_fix_timing(msg: Any) -> tuple[int, int, str]:
    """(receipt ns, UTC µs, stamp source) of one GNSS fix's timing record."""
    source = field_of(msg, "stamp_source") or "receipt"
    return int(msg.recv_ns), int(msg.unwrapped_tick), str(source)


def gnss_stamping(
    fixes: list[tuple[int, int, str]], clock: list[tuple[int, int]], time_base: TimeBase
) -> GnssStamping | None:
    """The summary of a log's GNSS fix timing records; None without any."""
    if not fixes:
        return None
    stamped: dict[str, int] = {}
    for _, _, source in fixes:
        stamped[source] = stamped.get(source, 0) + 1
    pairs = clock or ([(0, time_base.utc_offset_ns)] if time_base.utc else [])
    if not pairs:
        return GnssStamping(len(fixes), stamped, None, None, None)
    recv = np.array([f[0] for f in fixes], dtype=np.int64)
    utc_us = np.array([f[1] for f in fixes], dtype=np.int64)
    # whole seconds apart so float64 keeps the microseconds
    utc_s = (utc_us // 10**6).astype(np.float64) + (utc_us % 10**6).astype(np.float64) * 1e-6
    try:
        delay_ms = (recv - host_ns_from_utc(utc_s, pairs)) / 1e6
    except ValueError:  # the wall clock went back: UTC names two host times
        return GnssStamping(len(fixes), stamped, None, None, None)
    p5, p50, p95 = (float(v) for v in np.percentile(delay_ms, [5, 50, 95]))
    return GnssStamping(len(fixes), stamped, p50, p5, p95)


def _float(text: str | None) -> float | None:
    """``text`` as a finite float, None if it is none."""
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def host_clock_lines(h: HostClockSummary | None) -> list[str]:
    """The time base's lines: what disciplined the host clock, its offsets and steps,
    and a warning line for each reason to doubt the log's UTC."""
    if h is None:
        return ["  time base not recorded (no /acq/timebase): the host clock's UTC is unverified"]
    synced = h.records - h.unsynchronised
    sources = ", ".join(h.sources) or "none"
    lines = [f"  time base {h.records} readings, {synced} synchronised; sources: {sources}"]
    parts = []
    if h.chrony_offset_ms_median is not None and h.chrony_offset_ms_max is not None:
        parts.append(f"host minus chrony's reference {h.chrony_offset_ms_median:+.3f} ms "
                     f"(median; largest {h.chrony_offset_ms_max:.3f} ms)")  # fmt: skip
    if h.ptp_offset_ms_max is not None:
        parts.append(f"PTP offset up to {h.ptp_offset_ms_max:.3f} ms")
    if h.gnss_ms_median is not None and h.gnss_ms_spread is not None:
        parts.append(f"host minus GNSS {h.gnss_ms_median:+.3f} ms (median of "
                     f"{h.gnss_records}; p5-p95 {h.gnss_ms_spread:.3f} ms)")  # fmt: skip
    if h.leap_statuses:
        parts.append(f"chrony leap {' -> '.join(h.leap_statuses)}")
    if h.kernel_states:
        parts.append(f"kernel clock {' -> '.join(h.kernel_states)}")
    parts.append(f"{len(h.steps)} steps")
    lines.append(f"  time base {'; '.join(parts)}")
    lines.extend(f"  warning: time base: {w}" for w in h.warnings)
    return lines


def latency_line(d: DeviceSync) -> str:
    """``d``'s latency, as the recorder took it off the stamps, and where it came from."""
    assert d.latency_s is not None
    how = d.latency_source or "how obtained not recorded"
    if d.latency_bounds_s is not None:
        lo, hi = d.latency_bounds_s
        how += f", bounds {lo * 1e3:.2f}-{hi * 1e3:.2f} ms"
    return f"  latency   {d.name}: {d.latency_s * 1e3:.2f} ms ({how})"


def gnss_stamping_lines(g: GnssStamping) -> list[str]:
    """How the fixes were stamped, and their receipt minus their fix time."""
    names = {"fix": "their UTC fix time", "receipt": "their receipt"}
    how = ", ".join(f"{n} from {names.get(k, k)}" for k, n in sorted(g.stamped.items()))
    lines = [f"  gnss time {g.fixes} fixes: {how}"]
    if g.receipt_minus_fix_ms_median is not None:
        lo, hi = g.receipt_minus_fix_ms_p5, g.receipt_minus_fix_ms_p95
        assert lo is not None and hi is not None
        lines.append(
            f"  gnss time receipt - fix time (host UTC clock): median"
            f" {g.receipt_minus_fix_ms_median:.2f} ms, spread {hi - lo:.2f} ms"
            f" (p5 {lo:.2f}, p95 {hi:.2f})"
        )
    return lines


def drift_text(d: DeviceSync) -> str:
    """The whole log's drift fit with its interval, else the recorder's last estimate."""
    if d.drift_fit_ppm is None or d.drift_ci_ppm is None:
        return formatted(d.drift_ppm, ".2f")
    lo, hi = d.drift_ci_ppm
    return f"{d.drift_fit_ppm:.1f} ({lo:.0f}..{hi:.0f})"
