"""PTP's time status from pmc's answer, and kernel PPS sources from sysfs (a folder laid
out as /sys/class/pps); absent sources are absent, with why."""

from __future__ import annotations

from pathlib import Path

import pytest

from acq.time.absent import Absent
from acq.time.pps import PpsSource, parse_edge, read_pps
from acq.time.ptp import PtpTime, parse_time_status, read_ptp_time

PMC_ANSWER = """\
sending: GET TIME_STATUS_NP
\t001122.fffe.334455-0 seq 0 RESPONSE MANAGEMENT TIME_STATUS_NP
\t\tmaster_offset              -1234
\t\tingress_time               1796194600123456789
\t\tcumulativeScaledRateOffset +0.000000000
\t\tscaledLastGmPhaseChange    0
\t\tgmTimeBaseIndicator        0
\t\tlastGmPhaseChange          0x0000'0000000000000000.0000
\t\tgmPresent                  true
\t\tgmIdentity                 aabbcc.fffe.ddeeff
"""


def test_pmc_time_status_is_parsed() -> None:
    assert parse_time_status(PMC_ANSWER) == PtpTime(-1.234e-6, True, "aabbcc.fffe.ddeeff")
    with pytest.raises(ValueError, match="no TIME_STATUS_NP"):
        parse_time_status("sending: GET TIME_STATUS_NP\n")


def test_no_ptp4l_is_absent(tmp_path: Path) -> None:
    got = read_ptp_time(tmp_path / "ptp4l")
    assert isinstance(got, Absent) and got.why in ("ptp4l not running",
                                                   "pmc (linuxptp) not installed")  # fmt: skip


def test_a_pps_source_from_sysfs(tmp_path: Path) -> None:
    assert read_pps(tmp_path) == Absent("no PPS source")
    (tmp_path / "pps1").mkdir()
    (tmp_path / "pps1" / "assert").write_text("1796194600.000012000#42\n")
    (tmp_path / "pps1" / "clear").write_text("0.000000000#0\n")
    got = read_pps(tmp_path)
    assert isinstance(got, PpsSource) and got.name == "pps1" and got.assert_sequence == 42
    assert got.assert_error_s == pytest.approx(12e-6, abs=1e-7) and got.clear_s == 0
    assert parse_edge("12.5#3") == (12.000000005, 3)


def test_hostile_pmc_and_pps_values_are_refused() -> None:
    huge = PMC_ANSWER.replace("-1234", "9" * 400)  # a float cannot hold it
    with pytest.raises(ValueError, match="no TIME_STATUS_NP"):
        parse_time_status(huge)
    with pytest.raises(ValueError, match="no TIME_STATUS_NP"):
        parse_time_status(PMC_ANSWER.replace("aabbcc.fffe.ddeeff", "a" * 5_000_000))
    for edge in ("12.5#-1", f"12.5#{2**64}"):
        with pytest.raises(ValueError, match="not a PPS edge"):
            parse_edge(edge)
