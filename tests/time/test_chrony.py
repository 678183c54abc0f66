"""chrony's tracking read through chronyc: parsed from its CSV line, and asked of a
real chronyd (``-x``: it never sets the clock) following a reference the test feeds."""

from __future__ import annotations

import os
import time
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


TAIL = "1796194607.25,0,0,0,0,0,0,0,0,1.0,Normal"


@pytest.mark.parametrize(
    ("line", "named"),
    [
        (f"FFFFFFFFFFFFFFFFFFFF,TEST,1,{TAIL}", "reference ID 'FFFFFFFFFFFFFFFFFFFF' is not in"),
        (f"54455354,TEST,-1,{TAIL}", "stratum '-1' is not in 0..0xff"),
        (f"54455354,{'x' * 5_000_000},1,{TAIL}", "reference name of 5000000 characters"),
        (f"54455354,TEST,1,{'9' * 5_000_000},0,0,0,0,0,0,0,0,1.0,Normal", "ref time '9999"),
        (f"54455354,TEST,1,{TAIL[:-7]},{'N' * 5_000_000}", "leap status of 5000000"),
    ],
    ids=["reference-id", "stratum", "name", "number", "leap-status"],
)
def test_a_field_no_tracking_report_can_hold_is_refused_by_name(line: str, named: str) -> None:
    with pytest.raises(ValueError, match="chronyc tracking: ") as e:
        parse_tracking(line)
    assert named in str(e.value) and len(str(e.value)) < 200


def test_a_chronyc_that_prints_without_end_is_absent_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``chronyc`` on PATH (a script: the test's stand-in for chrony's client) that
    prints ``yes`` without end: killed after 64 kB, not read for its whole timeout."""
    (tmp_path / "chronyc").write_text("#!/bin/sh\nexec yes 54455354\n")
    (tmp_path / "chronyc").chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}:{os.environ['PATH']}")
    t0 = time.monotonic()
    got = read_chrony_tracking(timeout_s=5.0)
    assert got == Absent("chronyc printed more than 65536 bytes, not an answer")
    assert time.monotonic() - t0 < 2.0


def test_an_absent_reason_is_bounded() -> None:
    why = Absent("chronyd not answering (" + "x" * 5_000_000 + ")").why
    assert len(why) <= 200 and why.endswith("…")
