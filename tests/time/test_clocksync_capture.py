"""bench/clocksync_capture.py's computation on the real LMS111 capture, for sanity: the
scans, the drift and its interval, the delays above the lower envelope."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from acq.time.clocksync import fit_drift
from tests import bench_scripts


def test_lms111_capture_clock(shared_dir: Path) -> None:
    bench = bench_scripts.load("clocksync_capture")
    path = shared_dir / "data" / "sick" / "20210302_lms111.pcapng.json"
    a = bench.scan_arrivals(path)
    assert a.ticks.size == 172 and a.counters.tolist() == list(range(4, 176))
    assert a.retransmissions == 6
    assert (np.diff(a.recv_s) > 0).all() and (np.diff(a.ticks) > 0).all()  # no wrap here
    fit = fit_drift(a.ticks * 1e-6, a.recv_s)
    lo, hi = fit.drift_ci_ppm
    assert fit.n == 172 and abs(fit.drift_ppm) < 1000
    assert lo <= fit.drift_ppm <= hi and hi - lo > 0
    assert 0 <= fit.residual_median_s <= fit.residual_p95_s <= fit.residual_max_s < 0.02
    # the delays above the envelope, computed from the line's drift and offset
    x0 = a.ticks.min() * 1e-6
    line = x0 + fit.offset_s + (1 + fit.drift_ppm * 1e-6) * (a.ticks * 1e-6 - x0)
    resid = a.recv_s - line
    assert resid.min() > -1e-9 and np.median(resid) == pytest.approx(fit.residual_median_s)
    groups = {f["figure"] + f.get("stamp", ""): f for f in bench.figures(a)}
    assert groups["scans"]["scans"] == 172 and groups["scans"]["lost"] == 0
    period = groups["scan_period"]
    assert period["device_ms"] == pytest.approx(20.11, abs=0.05)  # 49.7 Hz
    assert period["capture_ms"] == pytest.approx(period["device_ms"], rel=1e-3)
    retimed = groups["retime_offline"]
    assert retimed["recv_minus_retimed_min_ms"] > -1e-3  # nothing arrives before its stamp
    assert all(math.isfinite(v) for v in (retimed["median_ms"], retimed["p95_ms"]))
