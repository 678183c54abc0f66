"""The host clock's poller outlives a failure of its sources' readers."""

from __future__ import annotations

import time

import pytest

from acq.time import host_clock
from acq.time.host_clock import HostClockPoller


def test_a_reader_that_raises_is_warned_about_and_polling_goes_on(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """An unforeseen exception in a source's reader (stood in for by a patched reader:
    the real ones return Absent on every failure we know of) used to end the thread, and
    the time base stopped without a word."""
    real = host_clock.read_pps
    calls = {"n": 0}

    def flaky() -> object:
        calls["n"] += 1
        if calls["n"] <= 2:
            raise RuntimeError("unforeseen")
        return real()

    monkeypatch.setattr(host_clock, "read_pps", flaky)
    poller = HostClockPoller(period_s=0.05)
    poller.start()
    try:
        deadline = time.monotonic() + 10.0
        reading = None
        while reading is None and time.monotonic() < deadline:
            time.sleep(0.05)
            reading = poller.take()
    finally:
        poller.stop()
    assert reading is not None and calls["n"] >= 3
    warnings = [r.getMessage() for r in caplog.records if r.name == "acq.time.host_clock"]
    assert warnings[0].startswith("reading the host clock's sources failed (RuntimeError")
    assert warnings[1] == "the host clock's sources are read again"
    assert len(warnings) == 2
