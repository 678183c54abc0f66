"""chrony's tracking read through chronyc: parsed from its CSV line, and asked of a
real chronyd (``-x``: it never sets the clock) following a reference the test feeds."""

from __future__ import annotations

from pathlib import Path

import pytest

from acq.time.absent import Absent
from acq.time.chrony import ChronyTracking, parse_tracking, read_chrony_tracking
from tests.time.chronyd import Chronyd

LINE = (
    "54455354,TEST,1,1796194607.257643873,-0.000000012,-0.005000000,0.005000000,"
    "-12.345,0.001,0.002,0.000000001,0.000002345,1.0,Normal"
)


def test_a_tracking_line_is_parsed_field_by_field() -> None:
    t = parse_tracking(LINE)
    assert t.reference_id == 0x54455354 and t.reference_name == "TEST" and t.stratum == 1
    assert t.last_offset_s == -0.005 and t.system_offset_s == -1.2e-8
    assert t.frequency_ppm == -12.345 and t.root_dispersion_s == 2.345e-6
    assert t.leap_status == "Normal" and t.synchronised


def test_not_synchronised_and_a_short_line() -> None:
    line = "00000000,,0,0.0,0.0,0.0,0.0,0.000,0.000,0.000,1.0,1.0,0.0,Not synchronised"
    assert not parse_tracking(line).synchronised
    with pytest.raises(ValueError, match="fields"):
        parse_tracking("506 Cannot talk to daemon")


def test_no_chronyd_on_the_socket_is_absent_not_an_error(tmp_path: Path) -> None:
    got = read_chrony_tracking(str(tmp_path / "none.sock"))
    assert isinstance(got, Absent) and got.why


def test_a_real_chronyd_5_ms_behind_its_reference(tmp_path: Path) -> None:
    chronyd = Chronyd(tmp_path / "chrony", offset_s=0.005)
    try:
        t = chronyd.synchronised()
    finally:
        chronyd.close()
    assert isinstance(t, ChronyTracking)
    assert t.reference_name == "TEST" and t.stratum == 1 and t.leap_status == "Normal"
    assert t.last_offset_s == pytest.approx(-0.005, abs=1e-5)
