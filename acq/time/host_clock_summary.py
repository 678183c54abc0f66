"""How far a log's UTC can be trusted, from its host clock readings
(:class:`acq.time.host_clock.HostClock`, one a second): whether something kept the
host clock synchronised, whether it stepped (UTC minus monotonic jumping between
readings by more than a slew can explain, chrony's leap status, the kernel's clock
state changing), chrony's and PTP's offsets, and the host clock against GNSS time.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from acq.time.chrony import ChronyTracking
from acq.time.host_clock import GnssTime, HostClock
from acq.time.kernel_clock import KernelClock
from acq.time.pps import PpsSource
from acq.time.ptp import PtpTime

__all__ = [
    "OFFSET_LIMIT_S", "STEP_S", "HostClockSummary", "HostClockTally", "summarise_host_clock",
    "utc_doubt",
]  # fmt: skip

OFFSET_LIMIT_S = 1e-3  # a host clock further than this from its reference or GNSS: warned
STEP_S = 1e-3  # UTC minus monotonic changing by more than this (and a slew's 500 ppm): a step
SLEW_MAX = 500e-6  # the most the kernel slews the clock, s/s


@dataclass(frozen=True)
class HostClockSummary:
    """A log's host clock readings summarised. ``records`` how many, ``unsynchronised``
    how many found nothing disciplining the clock; ``sources`` what disciplined it;
    ``steps`` the clock's jumps (``when, size s``, seconds after the first reading);
    ``kernel_states`` the kernel's clock states seen, in order; ``leap_statuses``
    chrony's; ``chrony_offset_ms_median``/``_max`` the host clock minus chrony's
    reference (last offset), median and largest magnitude; ``ptp_offset_ms_max`` the
    same of PTP; ``gnss_ms_median`` and ``gnss_ms_spread`` the host clock minus GNSS
    time (median, p95 - p5, of ``gnss_records``); ``warnings`` one line each; ``None``
    where the log has no such readings."""

    records: int
    unsynchronised: int
    sources: list[str]
    steps: list[tuple[float, float]]
    kernel_states: list[str]
    leap_statuses: list[str]
    chrony_offset_ms_median: float | None
    chrony_offset_ms_max: float | None
    ptp_offset_ms_max: float | None
    gnss_records: int
    gnss_ms_median: float | None
    gnss_ms_spread: float | None
    warnings: list[str] = field(default_factory=list)

    @property
    def utc_trusted(self) -> bool:
        """The log has readings and none of them is a reason to doubt its UTC."""
        return self.records > 0 and not self.warnings


def _source(r: HostClock) -> list[str]:
    out = []
    if isinstance(r.chrony, ChronyTracking) and r.chrony.synchronised:
        out.append(f"chrony {r.chrony.reference_name or f'{r.chrony.reference_id:08X}'} "
                   f"(stratum {r.chrony.stratum})")  # fmt: skip
    if isinstance(r.ptp, PtpTime) and r.ptp.gm_present:
        out.append(f"PTP grandmaster {r.ptp.gm_identity}")
    if isinstance(r.pps, PpsSource):
        out.append(f"PPS {r.pps.name}")
    if isinstance(r.kernel, KernelClock) and r.kernel.synchronised:
        out.append("kernel synchronised" + (" (PPS)" if r.kernel.pps else ""))
    return out


def _ms_stats(values: Iterable[float]) -> tuple[float | None, float | None]:
    """(median, largest magnitude) in ms of values in s."""
    a = np.asarray(values, dtype=np.float64) * 1e3
    if not a.size:
        return None, None
    return float(np.median(a)), float(np.max(np.abs(a)))


class HostClockTally:
    """The running summary of readings added in the order they were taken (the
    recorder's, updated once a second); :meth:`summary` at any time."""

    def __init__(self) -> None:
        self.records = 0
        self.unsynchronised = 0
        self.sources: dict[str, None] = {}
        self.steps: list[tuple[float, float]] = []
        self.kernel_states: list[str] = []
        self.leaps: list[str] = []
        self.chrony = array("d")
        self.ptp = array("d")
        self.gnss = array("d")
        self._first_ns: int | None = None
        self._last: HostClock | None = None

    def add(self, r: HostClock) -> None:
        """One more reading, taken after the last one added."""
        self.records += 1
        self.unsynchronised += not r.synchronised
        self.sources.update(dict.fromkeys(_source(r)))
        if self._first_ns is None:
            self._first_ns = r.monotonic_ns
        prev = self._last
        if prev is not None:
            dt = (r.monotonic_ns - prev.monotonic_ns) * 1e-9
            jump = (
                (r.realtime_ns - r.monotonic_ns) - (prev.realtime_ns - prev.monotonic_ns)
            ) * 1e-9
            if abs(jump) > STEP_S + SLEW_MAX * dt:
                self.steps.append(((r.monotonic_ns - self._first_ns) * 1e-9, jump))
        self._last = r
        if isinstance(r.kernel, KernelClock) and (
            not self.kernel_states or self.kernel_states[-1] != r.kernel.state
        ):
            self.kernel_states.append(r.kernel.state)
        if isinstance(r.chrony, ChronyTracking):
            if not self.leaps or self.leaps[-1] != r.chrony.leap_status:
                self.leaps.append(r.chrony.leap_status)
            if r.chrony.synchronised:
                self.chrony.append(r.chrony.last_offset_s)
        if isinstance(r.ptp, PtpTime) and r.ptp.gm_present:
            self.ptp.append(r.ptp.master_offset_s)
        if isinstance(r.gnss, GnssTime) and math.isfinite(r.gnss.host_minus_gnss_s):
            self.gnss.append(r.gnss.host_minus_gnss_s)

    def summary(self) -> HostClockSummary:
        """The readings so far, summarised, with their warnings."""
        chrony_median, chrony_max = _ms_stats(self.chrony)
        _, ptp_max = _ms_stats(self.ptp)
        g = np.asarray(self.gnss) * 1e3
        gnss_median = float(np.median(g)) if g.size else None
        gnss_spread = float(np.percentile(g, 95) - np.percentile(g, 5)) if g.size else None
        warnings = []
        if not self.records:
            warnings.append("no time base records: whether the host clock was synchronised "
                            "is unknown")  # fmt: skip
        elif self.unsynchronised:
            warnings.append(f"host clock unsynchronised in {self.unsynchronised} of "
                            f"{self.records} readings: its UTC may be off")  # fmt: skip
        if self.steps:
            shown = ", ".join(f"{d * 1e3:+.3f} ms at {t:.1f} s" for t, d in self.steps[:5])
            warnings.append(f"host clock stepped {len(self.steps)} times ({shown})")
        if len(self.kernel_states) > 1:
            warnings.append(f"the kernel's clock state changed: {' -> '.join(self.kernel_states)}")
        odd_leaps = [s for s in self.leaps if s not in ("Normal", "Not synchronised")]
        if odd_leaps:
            warnings.append(f"chrony's leap status: {', '.join(odd_leaps)}")
        limit_ms = OFFSET_LIMIT_S * 1e3
        if chrony_max is not None and chrony_max > limit_ms:
            warnings.append(f"host clock up to {chrony_max:.3f} ms off chrony's reference "
                            f"(limit {limit_ms:g} ms)")  # fmt: skip
        if ptp_max is not None and ptp_max > limit_ms:
            warnings.append(f"PTP clock up to {ptp_max:.3f} ms off its grandmaster "
                            f"(limit {limit_ms:g} ms)")  # fmt: skip
        if gnss_median is not None and abs(gnss_median) > limit_ms:
            warnings.append(f"host clock {gnss_median:+.3f} ms off GNSS time (median; limit "
                            f"{limit_ms:g} ms)")  # fmt: skip
        return HostClockSummary(
            records=self.records,
            unsynchronised=self.unsynchronised,
            sources=list(self.sources),
            steps=list(self.steps),
            kernel_states=list(self.kernel_states),
            leap_statuses=list(self.leaps),
            chrony_offset_ms_median=chrony_median,
            chrony_offset_ms_max=chrony_max,
            ptp_offset_ms_max=ptp_max,
            gnss_records=int(g.size),
            gnss_ms_median=gnss_median,
            gnss_ms_spread=gnss_spread,
            warnings=warnings,
        )

    def metadata(self) -> dict[str, str]:
        """The summary as the log's ``time_base`` metadata: ``utc_trusted`` (yes/no),
        ``records``, ``sources`` and ``warnings`` (joined with "; ")."""
        s = self.summary()
        return {
            "utc_trusted": "yes" if s.utc_trusted else "no",
            "records": str(s.records),
            "sources": ", ".join(s.sources),
            "warnings": "; ".join(s.warnings),
        }


def summarise_host_clock(readings: Iterable[HostClock]) -> HostClockSummary:
    """The summary of ``readings`` (any order: sorted by their monotonic time)."""
    tally = HostClockTally()
    for r in sorted(readings, key=lambda r: r.monotonic_ns):
        tally.add(r)
    return tally.summary()


def utc_doubt(metadata: Mapping[str, Mapping[str, str]]) -> str | None:
    """Why a log's UTC cannot be trusted, from its ``time_base`` metadata
    (:meth:`HostClockTally.metadata`); None when it can."""
    time_base = metadata.get("time_base")
    if time_base is None:
        return "the log has no time base: whether the host clock was synchronised is unknown"
    if time_base.get("utc_trusted") == "yes":
        return None
    return time_base.get("warnings") or "the log's time base does not vouch for it"
