"""``acq info`` on a log's GNSS fixes: how they were stamped (``acq.Timing.stamp_source``,
empty in logs from before the choice: receipt) and their receipt minus their UTC fix
time through the log's ``/acq/clock`` pairs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from acq.log import format_info, info, schemas
from acq.log.timebase import MONOTONIC
from acq.log.writer import LogWriter

T0 = 1_000_000_000_000  # host monotonic ns of the first fix
UTC0_S = 1_700_000_000  # UTC s at T0 by the host clock
MS = 1_000_000
S = 1_000_000_000


def write(directory: Path, delays_ms: list[float], sources: list[str], clock: bool) -> Path:
    """A log of 10 Hz GNSS timing records, each received ``delays_ms`` after its fix
    time; with ``clock``, (monotonic, realtime) pairs every second, the wall clock
    slewing 100 ppm, else none (and log times in host monotonic: no UTC at all)."""
    writer = LogWriter(directory, prefix="gnss", time_base=None if clock else MONOTONIC)
    writer.add_channel("/acq/timing/gnss", schemas.SCHEMAS["acq.Timing"])
    writer.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    if clock:
        for second in range(3):
            mono = T0 + second * S
            real = UTC0_S * S + second * (S + 100_000)
            writer.write(
                "/acq/clock", schemas.clock(realtime_ns=real, monotonic_ns=mono), mono, mono
            )
    for k, (delay, source) in enumerate(zip(delays_ms, sources, strict=True)):
        fix_mono = T0 + round(k * 100 * MS / (1 + 1e-4))  # UTC in 0.1 s steps, slewed
        recv = fix_mono + round(delay * MS)
        tick = UTC0_S * 10**6 + k * 100_000  # UTC µs
        msg = schemas.timing(recv_ns=recv, stamp_ns=fix_mono, device_ticks=(tick,),
                             unwrapped_tick=tick, stamp_source=source)  # fmt: skip
        writer.write("/acq/timing/gnss", msg, recv, fix_mono)
    writer.close()
    return writer.files[0]


def test_receipt_minus_fix_time_and_the_stamping_per_log(tmp_path: Path) -> None:
    delays = [40.0 + (k * 7) % 13 for k in range(20)]
    sources = [""] * 8 + ["fix"] * 12  # an older recorder's records say nothing: receipt
    i = info(write(tmp_path, delays, sources, clock=True))
    g = i.gnss_stamping
    assert g is not None and g.fixes == 20 and g.stamped == {"receipt": 8, "fix": 12}
    assert g.receipt_minus_fix_ms_median == pytest.approx(np.median(delays), abs=1e-3)
    assert g.receipt_minus_fix_ms_p5 == pytest.approx(np.percentile(delays, 5), abs=1e-3)
    assert g.receipt_minus_fix_ms_p95 == pytest.approx(np.percentile(delays, 95), abs=1e-3)
    lines = format_info(i).splitlines()
    assert "  gnss time 20 fixes: 12 from their UTC fix time, 8 from their receipt" in lines
    p5, p50, p95 = np.percentile(delays, [5, 50, 95])
    assert (
        f"  gnss time receipt - fix time (host UTC clock): median {p50:.2f} ms,"
        f" spread {p95 - p5:.2f} ms (p5 {p5:.2f}, p95 {p95:.2f})"
    ) in lines


def test_without_clock_pairs_only_the_stamping_is_told(tmp_path: Path) -> None:
    path = write(tmp_path, [45.0] * 5, ["receipt"] * 5, clock=False)
    i = info(path)
    assert i.gnss_stamping is not None and i.gnss_stamping.receipt_minus_fix_ms_median is None
    text = format_info(i)
    assert "gnss time 5 fixes: 5 from their receipt" in text and "fix time (host" not in text
    assert json.loads(format_info(i, json=True))[0]["gnss_stamping"]["stamped"] == {"receipt": 5}


def test_a_log_without_fixes_says_nothing_of_gnss_time(tmp_path: Path) -> None:
    writer = LogWriter(tmp_path, prefix="none")
    writer.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    writer.write("/acq/clock", schemas.clock(realtime_ns=UTC0_S * S, monotonic_ns=T0), T0, T0)
    writer.close()
    i = info(writer.files[0])
    assert i.gnss_stamping is None and "gnss time" not in format_info(i)
