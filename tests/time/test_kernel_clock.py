"""The kernel's clock status (adjtimex): read here for real, and decoded from a fake
libc for the states this host cannot be put in (setting them needs CAP_SYS_TIME and
would change the host's clock)."""

from __future__ import annotations

import ctypes
from typing import Any

import pytest

from acq.time import kernel_clock
from acq.time.kernel_clock import STA_NANO, STA_PLL, STA_UNSYNC, TIME_ERROR, read_kernel_clock


def test_this_hosts_clock_status_reads() -> None:
    status = read_kernel_clock()
    assert status is not None  # Linux
    assert status.state in kernel_clock.STATES.values()
    assert status.maxerror_s >= 0 and status.esterror_s >= 0


class _FakeLibc:
    """adjtimex filling ``struct timex`` as the kernel would, returning ``state``."""

    def __init__(self, state: int, **fields: int) -> None:
        self.state, self.fields = state, fields

    def adjtimex(self, ref: Any) -> int:
        tx = ctypes.cast(ref, ctypes.POINTER(kernel_clock._Timex)).contents
        assert tx.modes == 0  # read only: never changes the clock
        for name, value in self.fields.items():
            setattr(tx, name, value)
        return self.state


@pytest.mark.parametrize(
    ("state", "fields", "synchronised", "offset_s"),
    [
        (TIME_ERROR, {"status": STA_UNSYNC, "maxerror": 16_000_000}, False, 0.0),
        (0, {"status": STA_PLL | STA_NANO, "offset": 5_000_000, "freq": 12 * 65536}, True, 5e-3),
        (0, {"status": STA_PLL, "offset": -250}, True, -250e-6),  # µs without STA_NANO
        (0, {"status": STA_PLL | STA_UNSYNC}, False, 0.0),
    ],
)
def test_status_decoded(
    monkeypatch: pytest.MonkeyPatch,
    state: int,
    fields: dict[str, int],
    synchronised: bool,
    offset_s: float,
) -> None:
    monkeypatch.setattr(kernel_clock, "_libc", lambda: _FakeLibc(state, **fields))
    status = read_kernel_clock()
    assert status is not None
    assert status.synchronised is synchronised
    assert status.offset_s == pytest.approx(offset_s)
    if "freq" in fields:
        assert status.freq_ppm == pytest.approx(12.0)
    assert status.state == ("unsynchronised" if state == TIME_ERROR else "ok")
