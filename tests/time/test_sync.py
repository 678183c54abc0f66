"""Per-point scan times, frame times, and the pairing of laser points with frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.records import Scan
from acq.time.clocksync import DeviceClock
from acq.time.sync import (
    Gap,
    Pairing,
    frame_stamp_ns,
    frames_used,
    pair_frames,
    point_times_ns,
    scan_start_ns,
    stamp_scan,
)

MS = 1_000_000  # ns
T0 = 1_000_000_000_000  # ns, an arbitrary host time
PERIOD = 40 * MS  # 25 Hz


def make_scan(n: int = 5, time_increment: float = 0.001, **kw: object) -> Scan:
    args: dict = dict(
        ranges=np.ones(n),
        intensities=[],
        angle_min=-math.pi / 2,
        angle_increment=math.pi / max(n - 1, 1),
        time_increment=time_increment,
        scan_period=0.025,
        recv_ns=T0 + 30 * MS,
    )
    args.update(kw)
    return Scan(**args)


# --- laser scans ---------------------------------------------------------------------


def test_point_times_are_exact_int64() -> None:
    scan = make_scan(n=4, time_increment=0.001 / 3, start_ns=T0)
    times = point_times_ns(scan)
    assert times.dtype == np.int64
    assert times.tolist() == [T0, T0 + 333_333, T0 + 666_667, T0 + 1_000_000]


def test_point_times_of_a_utm_scan() -> None:
    # UTM-30LX: 1440 steps per 25 ms turn, 1081 points
    inc = 0.025 / 1440
    scan = make_scan(n=1081, time_increment=inc, start_ns=T0)
    times = point_times_ns(scan)
    assert times.tolist() == [T0 + round(i * inc * 1e9) for i in range(1081)]
    assert times[-1] - times[0] == 18_750_000  # 1080 steps of 17.36 µs


def test_point_times_of_many_scans_at_once_are_each_scans() -> None:
    inc = 0.025 / 1440
    starts = T0 + np.array([0, 25_000_123, 50_000_456])
    scan_idx, step = np.nonzero(np.ones((3, 1081), dtype=bool))
    times = point_times_ns(starts[scan_idx], inc, step)
    for k, start in enumerate(starts):
        scan = make_scan(n=1081, time_increment=inc, start_ns=int(start))
        assert times[scan_idx == k].tolist() == point_times_ns(scan).tolist()


def test_point_times_need_a_clock() -> None:
    with pytest.raises(ValueError, match="apply a clock first"):
        point_times_ns(make_scan())


def test_scan_start_adds_offset_and_subtracts_latency() -> None:
    assert scan_start_ns(T0, 0.0) == T0
    assert scan_start_ns(T0, -0.009375, 0.002) == T0 - 9_375_000 - 2_000_000
    assert scan_start_ns(T0, 0.0005, latency_s=0.0001) == T0 + 400_000


def test_stamp_scan_maps_the_first_tick_through_the_clock() -> None:
    clock = DeviceClock(tick_hz=1000, wrap_bits=24)
    host_at_tick0 = 7_000_000_000  # host ns of device tick 0
    latency = 2 * MS  # constant transport latency, invisible to the clock
    for tick in range(5000, 5250, 25):  # a scan every 25 ms
        clock.update(tick, host_at_tick0 + tick * MS + latency)
    updates = clock.updates
    tick = 5250
    offset_s, latency_s = -0.009375, 0.002
    scan = make_scan(device_ticks=(tick,), sequence=42)
    stamped = stamp_scan(scan, clock, offset_s, latency_s)
    expected = clock.to_host_ns(tick) + round(offset_s * 1e9) - round(latency_s * 1e9)
    assert stamped.start_ns == expected
    # and the truth, to within the estimator's 1-tick quantisation
    assert abs(stamped.start_ns - (host_at_tick0 + tick * MS - 9_375_000)) <= MS
    assert clock.updates == updates  # queried, not fed
    assert scan.start_ns is None  # a new record
    assert stamped.sequence == 42 and stamped.device_ticks == (tick,)
    np.testing.assert_array_equal(stamped.ranges, scan.ranges)


def test_stamp_scan_needs_ticks() -> None:
    clock = DeviceClock(tick_hz=1000, wrap_bits=24)
    clock.update(0, T0)
    with pytest.raises(ValueError, match="no device ticks"):
        stamp_scan(make_scan(), clock, 0.0)


# --- frames --------------------------------------------------------------------------


def test_frame_times_are_mid_exposure() -> None:
    # received at T0, read out 5 ms after a 20 ms exposure ended
    assert frame_stamp_ns(T0, 0.02, 0.005) == T0 - 5 * MS - 10 * MS
    assert frame_stamp_ns(T0, 0.0, 0.0) == T0


# --- pairing -------------------------------------------------------------------------


def regular_frames(n: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns, sequence numbers) of n frames at 25 Hz."""
    seq = np.arange(100, 100 + n)
    return T0 + (seq - 100) * PERIOD, seq


def test_regular_frames_pair_exactly() -> None:
    f, seq = regular_frames()
    p = np.array([T0 + 10 * MS, T0 + 30 * MS, T0 + 20 * MS, f[3], f[3] + 1, f[9] - 1])
    r = pair_frames(p, f, seq)
    assert r.before.tolist() == [0, 0, 0, 3, 3, 8]
    assert r.after.tolist() == [1, 1, 1, 4, 4, 9]
    assert r.nearest.tolist() == [0, 1, 0, 3, 3, 9]  # a tie goes to before
    np.testing.assert_array_equal(r.dt_s, np.array([10 * MS, -10 * MS, 20 * MS, 0, 1, -1]) * 1e-9)
    assert r.weight.tolist() == [0.25, 0.75, 0.5, 0.0, 1 / PERIOD, (PERIOD - 1) / PERIOD]
    assert not r.in_gap.any()
    assert r.gaps == [] and r.duplicates.size == 0 and r.out_of_order.size == 0
    assert r.period_s == pytest.approx(0.04, abs=1e-12)
    assert r.n_frames == 10
    assert r.before.dtype == np.int64 and r.dt_s.dtype == np.float64
    assert not r.before.flags.writeable
    assert frames_used(r).tolist() == [0, 1, 3, 9]


@pytest.mark.parametrize("with_seq", [True, False], ids=["seq", "time"])
def test_a_dropped_frame_is_a_gap(with_seq: bool) -> None:
    f, seq = regular_frames()
    keep = seq != 105
    f, seq = f[keep], seq[keep]  # input index 5 is now frame 106
    p = T0 + np.arange(0, 9 * PERIOD, MS)
    r = pair_frames(p, f, seq if with_seq else None)
    assert r.gaps == [Gap(int(f[4]), int(f[5]), 1)]
    inside = (p > f[4]) & (p < f[5])
    np.testing.assert_array_equal(r.in_gap, inside)
    assert not r.in_gap[p == f[4]].any()  # exactly at a frame: paired with it
    # still paired, across the gap, with the frames around it
    assert set(r.before[inside].tolist()) == {4} and set(r.after[inside].tolist()) == {5}
    assert r.period_s == pytest.approx(0.04, abs=1e-12)


def test_missing_frames_are_counted_from_the_sequence() -> None:
    f, seq = regular_frames(20)
    keep = (seq < 105) | (seq > 108)
    r = pair_frames([T0], f[keep], seq[keep])
    assert r.gaps == [Gap(int(f[4]), int(f[9]), 4)]
    # without sequence numbers: from the time span and the median period
    r = pair_frames([T0], f[keep])
    assert r.gaps == [Gap(int(f[4]), int(f[9]), 4)]


def test_period_is_per_sequence_step_despite_many_drops() -> None:
    f, seq = regular_frames(20)
    r = pair_frames([T0 + 60 * MS], f[::2], seq[::2])  # every other frame dropped
    assert r.period_s == pytest.approx(0.04, abs=1e-12)
    assert len(r.gaps) == 9 and all(g.missing_frames == 1 for g in r.gaps)
    assert r.in_gap.tolist() == [True]


def test_a_gap_the_sequence_does_not_show_is_found_in_time() -> None:
    f, seq = regular_frames()
    f = f.copy()
    f[6:] += 2 * PERIOD  # two frames lost, the driver's own counter did not notice
    r = pair_frames([f[5] + MS], f, seq)
    assert r.gaps == [Gap(int(f[5]), int(f[6]), 2)]
    assert r.in_gap.tolist() == [True]


def test_a_duplicated_frame_is_never_used() -> None:
    f, seq = regular_frames()
    # frame 103 delivered again after a reconnect, stamped at its later receipt
    f = np.append(f, f[3] + 15 * MS)
    seq = np.append(seq, 103)
    p = T0 + np.arange(0, 9 * PERIOD, MS // 4)
    r = pair_frames(p, f, seq)
    assert r.duplicates.tolist() == [10]
    assert r.out_of_order.size == 0
    assert not np.isin(10, r.nearest) and not np.isin(10, r.before) and not np.isin(10, r.after)
    assert 10 not in frames_used(r).tolist()
    assert not r.in_gap.any()  # the duplicate leaves no hole


def test_the_same_stamp_twice_is_a_duplicate() -> None:
    f, _ = regular_frames(5)
    # the same buffer handed out twice, counted twice by a driver
    f2 = np.array([f[0], f[1], f[1], f[2], f[3], f[4]])
    r = pair_frames([f[1] + MS], f2, np.arange(6))
    assert r.duplicates.tolist() == [2]
    assert r.nearest.tolist() == [1]
    assert r.gaps == [] and not r.in_gap.any()  # the repeat is no dropped frame
    # also in a stream with a stamp going backwards: the repeat is no clock step
    f3 = np.append(f2, f[0] - MS)
    r = pair_frames([f[1] + MS], f3, np.arange(7))
    assert r.duplicates.tolist() == [2]
    assert r.out_of_order.tolist() == [6]
    # without sequence numbers, the first in the caller's order is kept
    r = pair_frames([f[1] + MS], f2[::-1])
    assert r.duplicates.tolist() == [4]
    assert r.nearest.tolist() == [3]


def test_unsorted_frames_are_indexed_in_the_callers_order() -> None:
    f, seq = regular_frames()
    perm = np.array([7, 2, 9, 0, 5, 1, 8, 3, 6, 4])
    p = T0 + np.array([10, 30, 200, 355]) * MS
    ref = pair_frames(p, f, seq)
    for s in (seq[perm], None):
        r = pair_frames(p, f[perm], s)
        np.testing.assert_array_equal(perm[r.before], ref.before)
        np.testing.assert_array_equal(perm[r.after], ref.after)
        np.testing.assert_array_equal(perm[r.nearest], ref.nearest)
        np.testing.assert_array_equal(r.weight, ref.weight)
        np.testing.assert_array_equal(r.dt_s, ref.dt_s)
    assert r.nearest.tolist() == [3, 5, 4, 2]  # frames 0, 1, 5, 9 at perm positions


def test_a_stamp_going_backwards_is_out_of_order() -> None:
    f, seq = regular_frames()
    f = f.copy()
    f[6] = f[3] + MS  # a clock step: frame 106 stamped before frame 104
    p = np.array([f[3] + 2 * MS, f[5] + 10 * MS])
    r = pair_frames(p, f, seq)
    assert r.out_of_order.tolist() == [6]
    assert r.duplicates.size == 0
    assert not np.isin(6, r.nearest) and not np.isin(6, r.after)
    assert r.nearest.tolist() == [3, 5]
    # the frame is lost to pairing: a gap, counted from the sequence
    assert r.gaps == [Gap(int(f[5]), int(f[7]), 1)]
    assert r.in_gap.tolist() == [False, True]


def test_one_wild_stamp_costs_one_frame() -> None:
    f, seq = regular_frames()
    f = f.copy()
    f[4] += 10_000_000_000  # 10 s ahead: everything after it would look backwards
    r = pair_frames(f[[2, 8]] + MS, f, seq)
    assert r.out_of_order.tolist() == [4]
    assert r.nearest.tolist() == [2, 8]
    assert r.gaps == [Gap(int(f[3]), int(f[5]), 1)]


def test_points_before_the_first_and_after_the_last_frame() -> None:
    f, seq = regular_frames()
    half = 30 * MS  # max_gap_factor * period / 2
    p = np.array([f[0] - 10 * MS, f[0] - half, f[0] - half - 1, f[9], f[9] + half, f[9] + half + 1])
    r = pair_frames(p, f, seq)
    assert r.before.tolist() == [-1, -1, -1, 9, 9, 9]
    assert r.after.tolist() == [0, 0, 0, -1, -1, -1]
    assert r.nearest.tolist() == [0, 0, 0, 9, 9, 9]
    assert r.weight.tolist() == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    np.testing.assert_array_equal(r.dt_s, (p - f[[0, 0, 0, 9, 9, 9]]) * 1e-9)
    assert r.dt_s[2] == -(half + 1) * 1e-9
    assert r.in_gap.tolist() == [False, False, True, False, False, True]


def test_no_frames_pairs_nothing() -> None:
    p = T0 + np.arange(5) * MS
    seqs: list[list[int] | None] = [None, []]
    for seq in seqs:
        r = pair_frames(p, np.array([], dtype=np.int64), seq)
        assert r.before.tolist() == [-1] * 5
        assert r.after.tolist() == [-1] * 5
        assert r.nearest.tolist() == [-1] * 5
        assert np.isnan(r.dt_s).all()
        assert r.in_gap.all()
        assert r.gaps == []
        assert math.isnan(r.period_s)
        assert frames_used(r).size == 0


def test_one_frame_needs_a_period() -> None:
    p = np.array([T0 - 5 * MS, T0, T0 + 25 * MS])
    r = pair_frames(p, [T0])
    assert r.nearest.tolist() == [0, 0, 0]
    assert r.in_gap.all()  # no period known: nothing vouches for the pairing
    r = pair_frames(p, [T0], period_s=0.04)
    assert r.in_gap.tolist() == [False, False, False]
    r = pair_frames(p, [T0], period_s=0.02)
    assert r.in_gap.tolist() == [False, False, True]


def test_no_points() -> None:
    f, seq = regular_frames()
    r = pair_frames(np.array([], dtype=np.int64), f, seq)
    assert r.nearest.size == 0 and r.weight.size == 0 and r.in_gap.size == 0


def test_bad_input_is_rejected() -> None:
    f, seq = regular_frames()
    with pytest.raises(ValueError, match="frame_seq"):
        pair_frames([T0], f, seq[:-1])
    with pytest.raises(TypeError, match="point_ns"):
        pair_frames(np.array([1.5e12]), f)
    with pytest.raises(ValueError, match="max_gap_factor"):
        pair_frames([T0], f, max_gap_factor=0.5)
    with pytest.raises(ValueError, match="period_s"):
        pair_frames([T0], f, period_s=0.0)


def test_ten_million_points() -> None:
    f, seq = regular_frames(2500)  # 100 s of frames
    rng = np.random.default_rng(1)
    p = np.sort(rng.integers(f[0] - PERIOD, f[-1] + PERIOD, 10_000_000))
    r = pair_frames(p, f, seq)
    sample = rng.integers(0, p.size, 1000)
    brute = np.abs(p[sample, None] - f[None, :]).argmin(axis=1)
    np.testing.assert_array_equal(r.nearest[sample], brute)


# --- properties ----------------------------------------------------------------------

times = st.integers(min_value=-(10**15), max_value=10**15)


def check_against_brute_force(p: np.ndarray, f: np.ndarray, r_kept: np.ndarray, r: Pairing) -> None:
    """r's before/after/nearest/dt_s/weight are right for points p among frames f[r_kept]."""
    kept = f[r_kept]
    for i, t in enumerate(p.tolist()):
        le, gt = kept[kept <= t], kept[kept > t]
        b, a, n = int(r.before[i]), int(r.after[i]), int(r.nearest[i])
        if le.size:
            assert b in r_kept and f[b] == le.max()
        else:
            assert b == -1
        if gt.size:
            assert a in r_kept and f[a] == gt.min()
        else:
            assert a == -1
        assert n in r_kept
        best = np.abs(kept - t).min()
        assert abs(t - int(f[n])) == best
        assert r.dt_s[i] == (t - int(f[n])) * 1e-9
        assert 0.0 <= r.weight[i] <= 1.0
        if b >= 0 and a >= 0:
            assert r.weight[i] == pytest.approx((t - int(f[b])) / (int(f[a]) - int(f[b])))
            assert n == (a if int(f[a]) - t < t - int(f[b]) else b)


@settings(max_examples=200, deadline=None)
@given(
    frames=st.lists(times, min_size=1, max_size=40).map(sorted),
    points=st.lists(times, max_size=60),
)
def test_nearest_is_nearest_among_sorted_frames(frames: list[int], points: list[int]) -> None:
    f, p = np.array(frames, dtype=np.int64), np.array(points, dtype=np.int64)
    r = pair_frames(p, f)
    kept = np.setdiff1d(np.arange(f.size), r.duplicates)
    assert np.unique(f[kept]).size == kept.size == np.unique(f).size
    check_against_brute_force(p, f, kept, r)


@settings(max_examples=200, deadline=None)
@given(
    frames=st.lists(st.tuples(st.integers(0, 50), times), min_size=1, max_size=40),
    points=st.lists(times, max_size=60),
)
def test_excluded_frames_are_never_paired(frames: list[tuple[int, int]], points: list[int]) -> None:
    seq = np.array([s for s, _ in frames], dtype=np.int64)
    f = np.array([t for _, t in frames], dtype=np.int64)
    p = np.array(points, dtype=np.int64)
    r = pair_frames(p, f, seq)
    excluded = np.concatenate([r.duplicates, r.out_of_order])
    assert np.unique(excluded).size == excluded.size  # reported once
    kept = np.setdiff1d(np.arange(f.size), excluded)
    # what is left increases strictly in both sequence and time: no frame twice
    by_seq = kept[np.argsort(seq[kept])]
    assert np.all(np.diff(seq[by_seq]) > 0) and np.all(np.diff(f[by_seq]) > 0)
    # a sequence number keeps its first occurrence, unless it is out of order or repeats
    # the stamp of a kept frame with a lower sequence number
    for s in np.unique(seq).tolist():
        first = int(np.flatnonzero(seq == s)[0])
        same_stamp = kept[(f[kept] == f[first]) & (seq[kept] < s)]
        assert first in kept or first in r.out_of_order or same_stamp.size == 1
    assert not np.isin(excluded, frames_used(r)).any()
    check_against_brute_force(p, f, kept, r)
