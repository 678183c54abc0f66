"""The time base's verdict over a log's host clock readings: unsynchronised readings,
steps of the clock (and a slew that is none), the kernel's state changing, chrony's
leap status, offsets from chrony, PTP and GNSS beyond 1 ms."""

from __future__ import annotations

from dataclasses import replace

import pytest

from acq.time.absent import Absent
from acq.time.chrony import parse_tracking
from acq.time.host_clock import GnssTime, HostClock
from acq.time.host_clock_summary import HostClockTally, summarise_host_clock
from acq.time.kernel_clock import KernelClock
from acq.time.ptp import PtpTime

S = 1_000_000_000
UTC = 1_796_194_600 * S
CHRONY = parse_tracking(
    "C0A80001,ntp.example,2,1796194600.0,0.0000012,0.0000034,0.0000021,"
    "-12.345,0.001,0.002,0.004,0.0012,64.0,Normal"
)
KERNEL = KernelClock(True, "ok", 0.012, 0.001, 2e-6, -3.5, True, False, 37)


def readings(n: int = 5, **parts: object) -> list[HostClock]:
    """``n`` readings a second apart of a synchronised host; ``parts`` replace sources."""
    base = HostClock(UTC, 100 * S, KERNEL, CHRONY, Absent("ptp4l not running"),
                     Absent("no PPS source"))  # fmt: skip
    out = [replace(base, realtime_ns=UTC + i * S, monotonic_ns=(100 + i) * S) for i in range(n)]
    return [replace(r, **parts) for r in out]  # type: ignore[arg-type]


def test_a_synchronised_steady_clock_is_trusted() -> None:
    s = summarise_host_clock(readings())
    assert s.records == 5 and s.unsynchronised == 0 and s.steps == [] and s.warnings == []
    assert s.sources == ["chrony ntp.example (stratum 2)", "kernel synchronised"]
    assert s.chrony_offset_ms_median == pytest.approx(0.0034) and s.utc_trusted


def test_an_unsynchronised_clock_and_no_readings_are_not_trusted() -> None:
    unsync = replace(KERNEL, synchronised=False, state="unsynchronised")
    none = parse_tracking("00000000,,0,0,0,0,0,0,0,0,1,1,0,Not synchronised")
    s = summarise_host_clock(readings(4, kernel=unsync, chrony=none))
    assert s.unsynchronised == 4 and not s.utc_trusted
    assert s.warnings == ["host clock unsynchronised in 4 of 4 readings: its UTC may be off"]
    empty = HostClockTally().summary()
    assert not empty.utc_trusted and "no time base records" in empty.warnings[0]


def test_a_step_is_found_and_a_slew_is_not() -> None:
    rs = readings(6)
    rs[3:] = [replace(r, realtime_ns=r.realtime_ns + 40_000_000) for r in rs[3:]]  # +40 ms
    rs[5] = replace(rs[5], realtime_ns=rs[5].realtime_ns + 400_000)  # 0.4 ms in 1 s: a slew
    s = summarise_host_clock(reversed(rs))  # any order: sorted by monotonic time
    assert s.steps == [(3.0, 0.04)]
    assert s.warnings == ["host clock stepped 1 times (+40.000 ms at 3.0 s)"]


def test_state_changes_leap_and_offsets_beyond_1_ms_are_warned() -> None:
    rs = readings(4, gnss=GnssTime(-0.0015, 0.05, 0.02))
    rs[2] = replace(rs[2], kernel=replace(KERNEL, state="leap second insert"),
                    chrony=replace(CHRONY, leap_status="Insert second", last_offset_s=-0.002),
                    ptp=PtpTime(0.003, True, "001122.fffe.334455"))  # fmt: skip
    s = summarise_host_clock(rs)
    assert s.kernel_states == ["ok", "leap second insert", "ok"]
    assert s.gnss_records == 4 and s.gnss_ms_median == -1.5 and s.gnss_ms_spread == 0.0
    assert s.warnings == [
        "the kernel's clock state changed: ok -> leap second insert -> ok",
        "chrony's leap status: Insert second",
        "host clock up to 2.000 ms off chrony's reference (limit 1 ms)",
        "PTP clock up to 3.000 ms off its grandmaster (limit 1 ms)",
        "host clock -1.500 ms off GNSS time (median; limit 1 ms)",
    ]
    tally = HostClockTally()
    for r in rs:
        tally.add(r)
    meta = tally.metadata()
    assert meta["utc_trusted"] == "no" and meta["records"] == "4"
    assert meta["warnings"] == "; ".join(s.warnings)
