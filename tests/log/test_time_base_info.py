"""``acq info``'s time base: readings of a real chronyd (``-x``, never setting the
clock) following a reference the test controls, recorded on ``/acq/timebase`` as the
recorder does, summarised with no warning when chrony is synchronised with ~0 offset and
with one when it reports the host 5 ms off; a log without readings says so."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from acq.cli.main import main
from acq.log import schemas
from acq.log.summary import format_info, info
from acq.log.writer import LogWriter
from acq.time.host_clock import read_host_clock
from tests.time.chronyd import Chronyd

READINGS = 3


def _record(folder: Path, offset_s: float) -> Path:
    """A log of a few time base readings taken while chronyd follows a reference
    ``offset_s`` ahead of the host clock."""
    chronyd = Chronyd(folder / "chrony", offset_s)
    writer = LogWriter(folder, prefix="timebase")
    writer.add_channel("/acq/timebase", schemas.SCHEMAS["acq.TimeBase"])
    try:
        chronyd.synchronised()
        for _ in range(READINGS):
            reading = read_host_clock(chronyd.command)
            writer.write(
                "/acq/timebase",
                schemas.time_base_record(reading),
                reading.monotonic_ns,
                reading.monotonic_ns,
            )
            time.sleep(0.05)
    finally:
        chronyd.close()
        writer.close()
    return writer.files[0]


def _time_base_lines(path: Path) -> list[str]:
    return [line for line in format_info(info(path)).splitlines() if "time base" in line]


def test_chrony_synchronised_at_no_offset_is_no_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _record(tmp_path, 0.0)
    summary = info(path).host_clock
    assert summary is not None and summary.records == READINGS
    assert summary.unsynchronised == 0, "chrony's synchronised reference counts"
    assert "chrony TEST (stratum 1)" in summary.sources
    assert summary.chrony_offset_ms_max is not None and summary.chrony_offset_ms_max < 0.01
    assert summary.warnings == [] and summary.utc_trusted
    lines = _time_base_lines(path)
    assert not [line for line in lines if "warning" in line], lines
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"time base {READINGS} readings, {READINGS} synchronised" in out


def test_chrony_reporting_a_5_ms_offset_is_a_warning(tmp_path: Path) -> None:
    summary = info(path := _record(tmp_path, 0.005)).host_clock
    assert summary is not None and summary.chrony_offset_ms_median == pytest.approx(-5.0, abs=0.01)
    assert not summary.utc_trusted
    warnings = [line for line in _time_base_lines(path) if "warning" in line]
    assert warnings == [
        "  warning: time base: host clock up to 5.000 ms off chrony's reference (limit 1 ms)"
    ]


def test_a_log_without_readings_says_its_utc_is_unverified(tmp_path: Path) -> None:
    writer = LogWriter(tmp_path, prefix="none")
    writer.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    writer.write("/acq/clock", schemas.clock(realtime_ns=1, monotonic_ns=1), 1, 1)
    writer.close()
    assert info(writer.files[0]).host_clock is None
    assert _time_base_lines(writer.files[0]) == [
        "  time base not recorded (no /acq/timebase): the host clock's UTC is unverified"
    ]
