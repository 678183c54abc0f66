"""How the GNSS adapter stamps fixes (``gnss.time``), without a port: the simulated
receiver's sentences, with their receipt times, go straight into
:meth:`GnssAdapter.receive`.

The host clock's discipline is what :func:`acq.time.kernel_clock.read_kernel_clock`
says; the tests replace that function (the lowest layer, the kernel's ``adjtimex``
answer) with a chosen status, as no test can discipline the host's clock.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import pytest

from acq.record.adapters import GNSS_CLOCK_CHECK_S, GnssAdapter, _FixItem
from acq.record.config import GnssConfig
from acq.records import Sentence
from acq.sim.nmea_device import NmeaDevice
from acq.time import kernel_clock

LATENCY_S = 0.040  # the simulated receiver's constant delay (jitter on top)

SYNCHRONISED = kernel_clock.KernelClock(
    synchronised=True, state="ok", maxerror_s=0.0015, esterror_s=0.0001, offset_s=0.0,
    freq_ppm=1.2, pll=True, pps=False, tai_s=37,
)  # fmt: skip
UNSYNCHRONISED = dataclasses.replace(SYNCHRONISED, synchronised=False, state="unsynchronised")


class KernelAnswer:
    """Stands for the kernel's answer; ``status`` may change mid-test."""

    def __init__(self, status: kernel_clock.KernelClock | None) -> None:
        self.status = status
        self.calls = 0

    def __call__(self) -> kernel_clock.KernelClock | None:
        self.calls += 1
        return self.status


@pytest.fixture
def kernel(monkeypatch: pytest.MonkeyPatch) -> KernelAnswer:
    answer = KernelAnswer(UNSYNCHRONISED)
    monkeypatch.setattr(kernel_clock, "read_kernel_clock", answer)
    return answer


def adapter(**cfg: object) -> GnssAdapter:
    """An opened adapter (its receiver made, the port not opened)."""
    a = GnssAdapter(GnssConfig.model_validate({"url": "/dev/ttyUSB0", **cfg}))
    a.open(lambda event: None)
    return a


def feed(a: GnssAdapter, receiver: NmeaDevice, t0: float, seconds: float) -> list[_FixItem]:
    """The receiver's sentences from host time ``t0`` for ``seconds``, each received
    when it is due (40 ms after its fix instant plus jitter): the fixes they give."""
    out: list[_FixItem] = []
    now = t0
    while now < t0 + seconds:
        for line in receiver.poll(now).splitlines():
            for item in a.receive(Sentence(round(now * 1e9), line)):
                if isinstance(item, _FixItem):
                    out.append(item)
        due = receiver.next_due(now)
        assert due is not None
        now = max(due, now + 1e-6)
    return out


def truth_ns(receiver: NmeaDevice) -> dict[float, int]:
    """Fix time (UTC s, to the hundredth) -> the true fix instant, host ns."""
    return {round(t.utc_s, 2): round(t.t * 1e9) for t in receiver.truth}


def test_fix_time_stamps_the_fix_instant_without_latency(kernel: KernelAnswer) -> None:
    # the simulated receiver's UTC is the host's wall clock: a disciplined host's
    receiver = NmeaDevice(latency_s=LATENCY_S)
    a = adapter(time="fix", latency_s=LATENCY_S)
    fixes = feed(a, receiver, time.monotonic(), 2.0)
    truth = truth_ns(receiver)
    assert len(fixes) >= 18 and {f.source for f in fixes} == {"fix"}
    for f in fixes:
        # latency_s is not taken off; the wall clock may slew a little meanwhile
        assert f.stamp_ns - truth[round(f.fix.utc_s, 2)] == pytest.approx(0, abs=100_000)
        assert f.fix.recv_ns - f.stamp_ns > LATENCY_S * 1e9
    assert kernel.calls == 0  # forced: the kernel is not asked
    assert "not subtracted" in a.state.latency_source


def test_receipt_stamps_through_the_receipt_times_less_latency(kernel: KernelAnswer) -> None:
    kernel.status = SYNCHRONISED  # forced: whatever the kernel says
    receiver = NmeaDevice(latency_s=LATENCY_S, jitter_s=0.003)
    a = adapter(time="receipt", latency_s=LATENCY_S)
    fixes = feed(a, receiver, time.monotonic(), 2.0)
    truth = truth_ns(receiver)
    assert {f.source for f in fixes} == {"receipt"}
    errors_ms = [(f.stamp_ns - truth[round(f.fix.utc_s, 2)]) / 1e6 for f in fixes]
    # the earliest receipts set the mapping: the fix instant within the jitter's reach
    assert all(-1.0 < e < 13.0 for e in errors_ms), errors_ms
    assert sorted(errors_ms)[len(errors_ms) // 2] < 5.0, errors_ms


def test_auto_follows_the_kernels_word_on_the_host_clock(
    kernel: KernelAnswer, caplog: pytest.LogCaptureFixture
) -> None:
    receiver = NmeaDevice(latency_s=LATENCY_S)
    with caplog.at_level(logging.INFO, logger="acq.record"):
        a = adapter(latency_s=LATENCY_S)  # gnss.time auto, the default
        assert a.source == "receipt"
        assert "fixes stamped from their receipt, less latency_s 40.00 ms" in caplog.text
        assert "not synchronised (kernel: unsynchronised)" in caplog.text
        t0 = time.monotonic()
        before = feed(a, receiver, t0, 2.0)
        kernel.status = SYNCHRONISED  # chrony got there: seen at the next check
        after = feed(a, receiver, t0 + 2.0, GNSS_CLOCK_CHECK_S + 1.0)
    assert {f.source for f in before} == {"receipt"}
    sources = [f.source for f in after]
    switch = sources.index("fix")
    assert set(sources[:switch]) == {"receipt"} and set(sources[switch:]) == {"fix"}
    # asked at the open and again once 10 s of fixes had passed
    assert kernel.calls == 2
    at = (after[switch].fix.recv_ns - before[0].fix.recv_ns) / 1e9
    assert GNSS_CLOCK_CHECK_S - 0.2 <= at <= GNSS_CLOCK_CHECK_S + 0.2
    assert "from now on fixes stamped from their UTC fix time" in caplog.text
    assert "kernel maxerror 1.5 ms" in caplog.text
    assert a.state.last_event.startswith("time_source: fixes stamped from their UTC fix time")
    truth = truth_ns(receiver)
    for f in after[switch:]:
        assert abs(f.stamp_ns - truth[round(f.fix.utc_s, 2)]) < 100_000


def test_a_fix_time_far_from_its_receipt_is_stamped_from_receipt(
    kernel: KernelAnswer, caplog: pytest.LogCaptureFixture
) -> None:
    kernel.status = SYNCHRONISED
    # the receiver's UTC 2.5 s behind the host's: one of the two is wrong
    receiver = NmeaDevice(latency_s=LATENCY_S, utc_offset_s=time.time() - time.monotonic() - 2.5)
    with caplog.at_level(logging.INFO, logger="acq.record"):
        a = adapter()
        assert a.source == "fix"
        fixes = feed(a, receiver, time.monotonic(), 1.5)
    assert fixes and {f.source for f in fixes} == {"receipt"}
    warnings = [r for r in caplog.records if "after its UTC fix time" in r.getMessage()]
    assert len(warnings) == 1 and "a fix received 2.5" in warnings[0].getMessage()


def test_no_kernel_status_is_taken_for_an_undisciplined_clock(kernel: KernelAnswer) -> None:
    kernel.status = None  # not Linux
    a = adapter()
    assert a.source == "receipt"
    assert "status is unknown" in a.state.latency_source
