"""Every --json output is JSON under RFC 8259 (no NaN, no Infinity): acq.json_text, and
`acq info --json` on a real MCAP log whose chrony reading was NaN."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest

from acq import json_text
from acq.cli.main import main
from acq.log import schemas
from acq.log.writer import LogWriter
from acq.time.absent import Absent
from acq.time.chrony import ChronyTracking
from acq.time.host_clock import HostClock
from tests.strict_json import strict_json


def test_values_that_are_not_finite_are_null_and_named_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    value = {"a": float("nan"), "b": [1.0, np.float32("inf")], "c": np.arange(2), "d": (Path("x"),)}
    with caplog.at_level(logging.WARNING):
        text = json_text.dumps(value, what="acq x --json")
    assert strict_json(text) == {"a": None, "b": [1.0, None], "c": [0, 1], "d": ["x"]}
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith("acq x --json: 2 values not finite numbers (NaN or infinite)")
    assert line.endswith("$.a, $.b[1]")


def _chrony(offset_s: float) -> ChronyTracking:
    return ChronyTracking(
        reference_id=0x47505300, reference_name="GPS", stratum=1, ref_time_s=1.7e9,
        system_offset_s=offset_s, last_offset_s=offset_s, rms_offset_s=offset_s,
        frequency_ppm=0.0, residual_frequency_ppm=0.0, skew_ppm=0.0, root_delay_s=0.0,
        root_dispersion_s=0.0, update_interval_s=1.0, leap_status="Normal",
    )  # fmt: skip


def test_info_json_with_a_nan_chrony_reading_is_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    writer = LogWriter(tmp_path, prefix="nan")
    writer.add_channel("/acq/timebase", schemas.SCHEMAS["acq.TimeBase"])
    for k in range(3):
        t = 10**9 * (k + 1)
        reading = HostClock(
            realtime_ns=1_700_000_000 * 10**9 + t, monotonic_ns=t, kernel=Absent("test"),
            chrony=_chrony(math.nan), ptp=Absent("test"), pps=Absent("test"),
        )  # fmt: skip
        writer.write("/acq/timebase", schemas.time_base_record(reading), t, t)
    writer.close()
    with caplog.at_level(logging.WARNING):
        assert main(["info", "--json", str(writer.files[0])]) == 0
    (log_info,) = strict_json(capsys.readouterr().out)
    assert log_info["host_clock"]["records"] == 3
    assert log_info["host_clock"]["chrony_offset_ms_max"] is None
    (line,) = [r.getMessage() for r in caplog.records if "as JSON has no NaN" in r.getMessage()]
    assert "$[0].host_clock.chrony_offset_ms_max" in line
