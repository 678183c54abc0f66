"""Offline re-timing of scan and frame stamps (acq/retime.py)."""

from __future__ import annotations

import numpy as np

from acq.time.retime import retime_frames, retime_scans


def _camera(seed: int, n: int = 1500, period: float = 0.04, drift_ppm: float = 40.0):
    """True mid-exposure times (ns) and stamps = receipt - the configured mean latency:
    exponential jitter (mean 3 ms), 1 % of frames 20-60 ms late, those behind a late one
    queued after it (one stream: no frame overtakes another, 1 ms each), 2 % dropped."""
    rng = np.random.default_rng(seed)
    true = 5e9 + np.arange(n) * period * (1 + drift_ppm * 1e-6) * 1e9
    jitter = rng.exponential(3e6, n)
    late = rng.random(n) < 0.01
    jitter[late] += rng.uniform(20e6, 60e6, late.sum())
    recv = true + jitter
    for k in range(1, n):
        recv[k] = max(recv[k], recv[k - 1] + 1e6)
    stamps = recv - 3e6
    keep = rng.random(n) > 0.02
    return true[keep], np.rint(stamps[keep]).astype(np.int64)


def test_frames_back_on_their_grid() -> None:
    for seed in range(5):
        true, stamps = _camera(seed)
        r = retime_frames(stamps)
        before = np.sqrt(np.mean((stamps - true) ** 2)) * 1e-6
        err = np.abs(r.frame_ns - true) * 1e-6
        assert r.runs == 1 and r.kept == 0
        assert abs(r.period_s - 0.04 * (1 + 40e-6)) < 6e-7  # 3 sigma of the slope
        # a frame late by more than a period next to a dropped one may take its slot
        assert before > 3.0 and np.mean(err > 1.0) < 0.005 and np.median(err) < 0.3


def test_frames_not_on_a_grid_are_kept() -> None:
    rng = np.random.default_rng(0)
    stamps = np.cumsum(rng.uniform(0.02, 0.08, 300) * 1e9).astype(np.int64)
    r = retime_frames(stamps)
    assert np.array_equal(r.frame_ns, stamps) and r.runs == 0 and r.note


def test_a_gap_splits_the_runs_and_short_runs_stay() -> None:
    _, a = _camera(1, n=200)
    _, b = _camera(2, n=10)
    stamps = np.concatenate([a, b + a[-1] + 5_000_000_000 - b[0]])
    r = retime_frames(stamps)
    assert r.runs == 1 and r.kept == b.size
    assert np.array_equal(r.frame_ns[a.size :], stamps[a.size :])


def test_scans_offline_beats_online_and_keeps_the_constant() -> None:
    rng = np.random.default_rng(3)
    n, period = 2400, 0.025
    true = 1e9 + np.arange(n) * period * 1e9  # host time of each scan's stamp
    ticks = (np.floor((true - 1e9) * 1e-6 * (1 + 30e-6)) + 7000).astype(np.int64) % 2**24
    recv = np.rint(true + 1e6 + rng.exponential(2e6, n)).astype(np.int64)
    constant = -12_500_000  # the stamp's angular offset minus the latency
    online = np.rint(true + constant + rng.normal(0, 0.3e6, n)).astype(np.int64)
    r = retime_scans(online, ticks, recv, 1000.0, 24)
    err = (r.scan_ns - (true + constant)) * 1e-6
    assert r.retimed == n
    assert np.sqrt(np.mean(err**2)) < 0.1 and abs(np.median(err)) < 0.05


def test_scans_without_ticks_are_kept() -> None:
    stamps = np.arange(5, dtype=np.int64) * 25_000_000
    r = retime_scans(stamps, np.full(5, -1), stamps, 1000.0, 24)
    assert np.array_equal(r.scan_ns, stamps) and r.retimed == 0 and r.note
