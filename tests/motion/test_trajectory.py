"""The vehicle's trajectory: SE(3) interpolation, dead reckoning, GNSS fusion, trajectory
files, the UTC <-> host clock mapping and GPS time."""

from __future__ import annotations

import calendar
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq import motion as tj
from acq.geometry.geodesy import WorldFrame
from acq.geometry.rotations import (
    euler_from_matrices,
    matrices_from_euler,
    matrix_from_quat,
    matrix_from_rotvec,
    quat_from_matrix,
    rotation_from_euler,
)
from acq.geometry.transforms import Rigid
from acq.motion import fusion
from acq.motion.ins import TrajectoryFileError
from acq.motion.odometry import Hold
from acq.motion.trajectory import OutOfSpanError, Trajectory
from acq.time import gpstime
from acq.time.utc import host_ns_from_utc, utc_seconds

T0 = 5_000_000_000_000  # ns, an arbitrary host time
S = 1_000_000_000  # ns per second


def ns(t_s: np.ndarray | float) -> np.ndarray:
    return T0 + np.rint(np.asarray(t_s, dtype=np.float64) * 1e9).astype(np.int64)


def angle_between(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(N,) rotation angle of A^T B, rad (|A - B|_F = 2 sqrt(2) sin(angle / 2))."""
    d = np.linalg.norm(np.asarray(A) - np.asarray(B), axis=(-2, -1))
    return 2 * np.arcsin(np.clip(d / (2 * math.sqrt(2)), 0, 1))


# --- interpolation -----------------------------------------------------------------------


def spinning(n: int = 40, seed: int = 0) -> tuple[Trajectory, Rigid, np.ndarray, np.ndarray]:
    """Constant angular velocity about a tilted axis (0.8 rad/s), constant velocity,
    sampled at irregular times."""
    rng = np.random.default_rng(seed)
    ts = np.cumsum(rng.uniform(0.005, 0.05, n))
    R0 = Rigid(rotation_from_euler(0.3, -0.2, 1.0), [10.0, -3.0, 1.0])
    omega = np.array([0.2, -0.3, 0.7])
    vel = np.array([5.0, 1.0, -0.2])
    traj = Trajectory(
        ns(ts),
        R0.rotation @ matrix_from_rotvec(ts[:, None] * omega),
        R0.translation + ts[:, None] * vel,
    )
    return traj, R0, omega, vel


def test_slerp_is_exact_for_a_constant_rate_turn() -> None:
    traj, R0, omega, vel = spinning()
    rng = np.random.default_rng(1)
    t_q = rng.integers(traj.start_ns, traj.end_ns + 1, 5000)
    R, p = traj.pose_at(t_q)
    ts = (t_q - T0) * 1e-9
    assert angle_between(R, R0.rotation @ matrix_from_rotvec(ts[:, None] * omega)).max() < 1e-9
    np.testing.assert_allclose(p, R0.translation + ts[:, None] * vel, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def test_interpolates_the_simulated_drive_to_well_under_a_millimetre() -> None:
    from acq.sim.world import Trajectory as SimTrajectory

    sim = SimTrajectory(curve_amplitude=2.0, curve_wavelength=60.0, vibration_rad=0.01, seed=4)
    ts = np.arange(0.0, 20.0, 0.01)  # 100 Hz
    traj = Trajectory(ns(ts), *sim.poses(ts))
    rng = np.random.default_rng(2)
    t_q = np.sort(rng.integers(traj.start_ns, traj.end_ns, 200_000))
    R, p = traj.pose_at(t_q)
    R_true, p_true = sim.poses((t_q - T0) * 1e-9)
    pos_err = np.linalg.norm(p - p_true, axis=1).max()
    rot_err = angle_between(R, R_true).max()
    print(f"100 Hz at 20 km/h: position error {pos_err * 1e6:.2f} µm, rotation {rot_err:.2e} rad")
    assert pos_err < 1e-5  # m; the chord of the lateral sine
    assert rot_err < 1e-4  # rad; 1-3 Hz body vibration of 0.01 rad


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 30), st.integers(0, 10_000))
def test_pose_at_the_sample_times_returns_the_samples(n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    t = T0 + np.cumsum(rng.integers(1, 10**9, n))
    R = matrices_from_euler(*rng.uniform(-3, 3, (3, n)))
    p = rng.normal(0, 1e3, (n, 3))
    traj = Trajectory(t, R, p)
    R2, p2 = traj.pose_at(t)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_array_equal(p2, p)
    # and between samples the rotation is on the short arc between its neighbours
    mid = t[:-1] + np.diff(t) // 2
    Rm, _ = traj.pose_at(mid)
    # at the fraction of the interval mid is at (not exactly a half for a short odd one)
    part = angle_between(R[:-1], R[1:]) * (mid - t[:-1]) / np.diff(t)
    np.testing.assert_allclose(angle_between(R[:-1], Rm), part, atol=2e-6)


def test_out_of_span_raises_and_covers_flags() -> None:
    traj, *_ = spinning()
    t = np.array([traj.start_ns - 1, traj.start_ns, traj.end_ns, traj.end_ns + S // 10])
    np.testing.assert_array_equal(traj.covers(t), [False, True, True, False])
    with pytest.raises(OutOfSpanError, match=r"2 of 4 times have no pose.*before the start"):
        traj.pose_at(t)
    with pytest.raises(OutOfSpanError, match=r"0\.100 s after the end"):
        traj.pose_at(t[2:])
    with pytest.raises(TypeError, match="integer host ns"):
        traj.pose_at(np.array([1.5]))
    # a short margin extrapolates the end intervals' motion (constant rate: exactly)
    _, R0, omega, vel = spinning()
    wide = Trajectory(traj.t_ns, traj.rotation, traj.translation, margin_s=0.2)
    assert wide.covers(t).all()
    assert not wide.covers(np.array([traj.end_ns + S // 4]))[0]
    R, p = wide.pose_at(t[[0, 3]])
    ts = (t[[0, 3]] - T0) * 1e-9
    assert angle_between(R, R0.rotation @ matrix_from_rotvec(ts[:, None] * omega)).max() < 1e-9
    np.testing.assert_allclose(p, R0.translation + ts[:, None] * vel, atol=1e-9)
    with pytest.raises(ValueError, match="margin_s"):
        Trajectory(traj.t_ns, traj.rotation, traj.translation, margin_s=1.0)


def test_shapes_and_bad_input() -> None:
    traj, *_ = spinning()
    R, p = traj.pose_at(traj.start_ns)
    assert R.shape == (3, 3) and p.shape == (3,)
    R, p = traj(np.full((4, 5), traj.start_ns))
    assert R.shape == (4, 5, 3, 3) and p.shape == (4, 5, 3)
    assert len(traj.resample(traj.t_ns[::2])) == (len(traj) + 1) // 2
    with pytest.raises(ValueError, match="increase strictly"):
        Trajectory(np.array([T0, T0]), np.stack([np.eye(3)] * 2), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="at least 2"):
        Trajectory(np.array([T0]), np.eye(3)[None], np.zeros((1, 3)))
    with pytest.raises(ValueError, match="proper rotations"):
        Trajectory(np.array([T0, T0 + 1]), np.stack([np.eye(3), -np.eye(3)]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="unknown frame"):
        Trajectory(traj.t_ns, traj.rotation, traj.translation, frame="EPSG:nonsense")


def test_laser_poses_compose_after_interpolation() -> None:
    traj, *_ = spinning()
    ltv = Rigid(rotation_from_euler(0.0, 0.3, math.pi / 2), [1.2, -0.4, 1.9])
    t = np.linspace(traj.start_ns, traj.end_ns, 101).astype(np.int64)
    R, p = traj.pose_at(t)
    RL, pL = tj.laser_poses(traj, t, ltv)
    P = np.array([3.0, -2.0, 0.5])
    np.testing.assert_allclose(RL @ P + pL, R @ ltv.apply(P) + p, atol=1e-12)
    RL2, pL2 = traj.with_lever_arm(ltv)(t)
    np.testing.assert_array_equal(RL2, RL)
    np.testing.assert_array_equal(pL2, pL)


# --- dead reckoning --------------------------------------------------------------------


def arcs(ts: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Reference dead reckoning, one sample at a time: (N,3) x, y, heading with the
    closed-form arc of constant v, w over each interval (forward hold)."""
    out = np.zeros((ts.size, 3))
    x = y = psi = 0.0
    for i in range(1, ts.size):
        dt = ts[i] - ts[i - 1]
        if abs(w[i - 1]) > 1e-12:
            r = v[i - 1] / w[i - 1]
            x += r * (math.sin(psi + w[i - 1] * dt) - math.sin(psi))
            y += r * (math.cos(psi) - math.cos(psi + w[i - 1] * dt))
        else:
            x += v[i - 1] * dt * math.cos(psi)
            y += v[i - 1] * dt * math.sin(psi)
        psi += w[i - 1] * dt
        out[i] = x, y, psi
    return out


def test_dead_reckoning_of_a_circle_is_exact() -> None:
    rng = np.random.default_rng(5)
    ts = np.concatenate([[0.0], np.cumsum(rng.uniform(0.005, 0.1, 600))])  # irregular
    v, w = 5.0, 0.4  # radius 12.5 m
    traj = tj.from_odometry(ns(ts), np.full(ts.size, v), np.full(ts.size, w))
    R, p = traj.pose_at(traj.t_ns)
    tt = (traj.t_ns - T0) * 1e-9
    r = v / w
    np.testing.assert_allclose(p[:, 0], r * np.sin(w * tt), atol=1e-9)
    np.testing.assert_allclose(p[:, 1], r * (1 - np.cos(w * tt)), atol=1e-9)
    np.testing.assert_allclose(np.arctan2(R[:, 1, 0], R[:, 0, 0]), np.angle(np.exp(1j * w * tt)))
    # the vehicle origin 1.5 m ahead of the rear axle runs on a wider circle
    ahead = tj.from_odometry(ns(ts), np.full(ts.size, v), np.full(ts.size, w), rear_axle_x_m=-1.5)
    _, pa = ahead.pose_at(ahead.t_ns)
    centre = [-1.5, r]  # of the axle's circle; the axle starts 1.5 m behind the origin
    np.testing.assert_allclose(np.hypot(*(pa[:, :2] - centre).T), math.hypot(r, 1.5), atol=1e-9)
    np.testing.assert_allclose(pa[0], 0.0, atol=1e-12)


def test_dead_reckoning_of_an_s_curve_with_a_start_pose() -> None:
    rng = np.random.default_rng(6)
    ts = np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 0.03, 1500))])
    v = 4.0 + 3.0 * (ts > 10) + rng.normal(0, 0.2, ts.size)  # piecewise constant inputs
    w = np.where(ts < 12, 0.3, -0.3) * (ts > 3) + rng.normal(0, 0.01, ts.size)
    start = Rigid(rotation_from_euler(0.0, 0.0, 2.0), [100.0, 50.0, 7.0])
    traj = tj.from_odometry(ns(ts), v, w, hold="forward", start=start)
    ref = arcs(ts, v, w)
    R, p = traj.pose_at(traj.t_ns)
    np.testing.assert_allclose(p, start.apply(np.c_[ref[:, :2], np.zeros(ts.size)]), atol=1e-8)
    np.testing.assert_allclose(
        np.arctan2(R[:, 1, 0], R[:, 0, 0]), np.angle(np.exp(1j * (ref[:, 2] + 2.0))), atol=1e-10
    )
    # irregular resampling of the same piecewise-constant inputs: the same path
    extra = np.sort(np.concatenate([ts, rng.uniform(0, ts[-1], 3000)]))
    k = np.searchsorted(ts, extra, side="right") - 1
    again = tj.from_odometry(ns(extra), v[k], w[k], hold="forward", start=start)
    _, p2 = again.pose_at(traj.t_ns)
    np.testing.assert_allclose(p2, p, atol=1e-6)  # ns rounding of the inserted times


def test_mean_hold_is_second_order_for_smooth_inputs() -> None:
    def inputs(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return 6 + np.sin(ts / 3), 0.3 * np.sin(ts / 2)

    fine = np.arange(0, 30 + 1e-9, 1e-3)
    ref = tj.from_odometry(ns(fine), *inputs(fine))  # 1 kHz: ~2 µm from the limit

    def err(rate_hz: float, hold: Hold) -> float:
        ts = np.arange(0, 30 + 1e-9, 1 / rate_hz)
        traj = tj.from_odometry(ns(ts), *inputs(ts), hold=hold)
        return float(np.abs(traj.translation[-1] - ref.pose_at(traj.t_ns[-1])[1]).max())

    # 30 s, 190 m at 50 Hz: 0.85 mm with the mean, 64 mm holding each sample forward
    assert err(50, "mean") < 1e-3 and err(50, "forward") > 50 * err(50, "mean")
    assert 3.5 < err(25, "mean") / err(50, "mean") < 4.5  # second order
    assert 1.8 < err(25, "forward") / err(50, "forward") < 2.2  # first order


def test_odometry_gaps_raise_or_are_flagged() -> None:
    ts = np.concatenate([np.arange(0, 2, 0.02), np.arange(3.5, 5, 0.02)])  # 1.52 s gap
    v, w = np.full(ts.size, 5.0), np.full(ts.size, 0.1)
    with pytest.raises(ValueError, match=r"gap of 1\.520 s after sample 99 \(1\.980 s in"):
        tj.from_odometry(ns(ts), v, w)
    traj = tj.from_odometry(ns(ts), v, w, on_gap="flag", step_s=0.005)
    assert traj.gaps == [(int(ns(1.98)), int(ns(3.5)))]
    t = ns(np.array([1.0, 1.98, 2.5, 3.5, 4.0]))
    np.testing.assert_array_equal(traj.covers(t), [True, True, False, True, True])
    with pytest.raises(OutOfSpanError, match=r"in a gap of 1\.520 s at 1\.980 s"):
        traj.pose_at(t)
    # bridged with the held inputs: a circle throughout
    _, p = traj.pose_at(t[[0, 1, 3, 4]])
    tt = np.array([1.0, 1.98, 3.5, 4.0])
    np.testing.assert_allclose(p[:, 0], 50 * np.sin(0.1 * tt), atol=1e-9)
    # step_s: no interval but the gap longer than 5 ms
    d = np.diff(traj.t_ns)
    assert d.max() == ns(3.5) - ns(1.98) and np.sort(d)[-2] <= 5_000_000


def test_odometry_input_errors() -> None:
    t = ns(np.arange(5) * 0.01)
    with pytest.raises(ValueError, match="increase strictly: sample 3"):
        tj.from_odometry(t[[0, 1, 2, 2, 4]], np.ones(5), np.zeros(5))
    with pytest.raises(ValueError, match="sample 2 is not finite"):
        tj.from_odometry(t, [1, 1, np.nan, 1, 1], np.zeros(5))
    with pytest.raises(ValueError, match="lengths differ"):
        tj.from_odometry(t, np.ones(4), np.zeros(5))
    with pytest.raises(TypeError):
        tj.from_odometry(t * 1.0, np.ones(5), np.zeros(5))


def test_wheel_speeds() -> None:
    wheels = np.array([[10.0, 10.4, 9.9, 10.3], [5.0, 5.0, 5.0, 5.0]])  # FL FR RL RR
    np.testing.assert_allclose(tj.speed_from_wheels(wheels), [10.1, 5.0])
    np.testing.assert_allclose(tj.speed_from_wheels(wheels, "front"), [10.2, 5.0])
    np.testing.assert_allclose(tj.speed_from_wheels(wheels, "all"), [10.15, 5.0])
    np.testing.assert_allclose(tj.yaw_rate_from_wheels(wheels, 1.6), [0.25, 0.0])  # left turn
    with pytest.raises(ValueError, match="FL, FR, RL, RR"):
        tj.speed_from_wheels(np.ones((3, 2)))


# --- world frames and GNSS -----------------------------------------------------------


def test_world_frames() -> None:
    enu = WorldFrame("enu", (50.0, 8.0, 100.0))
    P = enu.from_geodetic([50.0, 50.001], [8.0, 8.0], [100.0, 100.0])
    np.testing.assert_allclose(P[0], 0.0, atol=1e-6)
    assert abs(P[1, 0]) < 1e-6 and 111.0 < P[1, 1] < 111.4  # 0.001° of latitude north
    Q = np.array([[1234.5, -987.6, 12.3], [-5000.0, 3000.0, -40.0]])
    lat, lon, h = enu.to_geodetic(Q)
    np.testing.assert_allclose(enu.from_geodetic(lat, lon, h), Q, atol=1e-6)
    np.testing.assert_allclose(
        enu.rotation_from_local_enu(50.0, 8.0, 100.0)[0], np.eye(3), atol=1e-15
    )
    # 10 km east the local north is tilted by dlon * sin(lat) about up
    Rl = enu.rotation_from_local_enu(lat[0], lon[0], h[0])[0]
    tilt = math.radians(lon[0] - 8.0) * math.sin(math.radians(50))
    assert abs(math.atan2(Rl[0, 1], Rl[1, 1]) + tilt) < 1e-6

    utm = WorldFrame("EPSG:25832", (400_000.0, 5_500_000.0, 0.0))
    P = utm.from_geodetic(50.0, 7.0, 120.0)  # 2° west of the zone's central meridian
    back = utm.to_geodetic(P)
    np.testing.assert_allclose([back[0][0], back[1][0], back[2][0]], [50.0, 7.0, 120.0])
    Rg = utm.rotation_from_local_enu(50.0, 7.0, 120.0)[0]
    # grid convergence: a parallel runs along the rotated east (a different difference)
    e = utm.from_geodetic(50.0, 7.00001, 120.0) - utm.from_geodetic(50.0, 6.99999, 120.0)
    np.testing.assert_allclose(Rg @ [1, 0, 0], e[0] / np.linalg.norm(e[0]), atol=1e-6)
    # west of the central meridian (9° E) true north lies east of grid north
    gamma = math.degrees(math.atan2(Rg[1, 0], Rg[0, 0]))
    assert -1.6 < gamma < -1.4  # ~ dlon sin(lat) = -2° * 0.766
    with pytest.raises(ValueError, match="not a projected CRS"):
        WorldFrame("EPSG:4326")
    with pytest.raises(ValueError, match="not tied to the Earth"):
        WorldFrame().from_geodetic(0, 0, 0)


def test_gnss_track_drops_bad_fixes() -> None:
    t = ns(np.array([0.0, 1.0, 1.0, 2.0, 3.0, 4.0]))
    lat = np.array([50.0, 50.0001, 50.0001, np.nan, 50.0003, 50.0004])
    track = tj.gnss_track(
        t, lat, np.full(6, 8.0), np.full(6, 100.0),
        hdop=[1.0, 2.0, 2.0, 1.0, np.nan, 1.0], quality=[1, 1, 1, 1, 1, 0], uere_m=1.5,
    )  # fmt: skip
    np.testing.assert_array_equal(track.t_ns, t[[0, 1, 4]])
    np.testing.assert_allclose(track.sigma_m, [1.5, 3.0, 1.5])
    np.testing.assert_allclose(track.xyz[0], 0.0, atol=1e-6)
    assert track.origin == (50.0, 8.0, 100.0)
    with pytest.raises(ValueError, match="no usable GNSS fix"):
        tj.gnss_track(t[:1], [50.0], [8.0], [100.0], quality=[0])


def test_gnss_from_fix_records() -> None:
    from acq.records import Fix

    clock = np.array([[T0, 1_700_000_000 * S]], dtype=np.int64)
    fixes = [
        Fix(recv_ns=T0 + i * S + 80_000_000, utc_s=1_700_000_000.0 + i,
            latitude=50.0 + i * 1e-4, longitude=8.0, altitude=100.0, quality=1, hdop=1.2)
        for i in range(4)
    ]  # fmt: skip
    by_utc = tj.gnss_from_fixes(fixes, utc_to_host_ns=lambda u: host_ns_from_utc(u, clock))
    np.testing.assert_array_equal(by_utc.t_ns, T0 + np.arange(4) * S)
    by_recv = tj.gnss_from_fixes(fixes)
    np.testing.assert_array_equal(by_recv.t_ns, T0 + np.arange(4) * S + 80_000_000)
    np.testing.assert_allclose(by_recv.sigma_m, 1.2)


def simulated_drive(seed: int = 1, T: float = 90.0):  # type: ignore[no-untyped-def]
    """Truth (piecewise-constant inputs at 1 kHz), biased noisy 50 Hz odometry, and 5 Hz
    GNSS fixes of an antenna (σ 0.8-3 m horizontally, outliers) in an ENU frame whose
    axes are turned 0.7 rad from the odometry's."""
    rng = np.random.default_rng(seed)

    def inputs(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return 6 + 2 * np.sin(2 * np.pi * ts / 40), 0.25 * np.sin(2 * np.pi * ts / 25) + 0.05

    fine = np.arange(0, T + 1e-9, 0.001)
    truth = tj.from_odometry(ns(fine), *inputs(fine), hold="forward")
    to = np.arange(0, T, 0.02) + rng.uniform(-0.002, 0.002, round(T / 0.02))
    to[0] = 0.0
    v, w = inputs(to)
    v = v * 1.02 + rng.normal(0, 0.05, to.size)  # 2 % speed scale error
    w = w + math.radians(0.3) + rng.normal(0, 0.01, to.size)  # 0.3 °/s gyro bias
    world = Rigid(rotation_from_euler(0, 0, 0.7), [120.0, -40.0, 3.0])
    antenna = np.array([0.5, 0.0, 1.8])
    tf = np.arange(0.1, T - 0.1, 0.2)
    Rt, pt = truth.pose_at(ns(tf))
    fixes = world.apply(pt + Rt @ antenna)
    hdop = rng.uniform(0.8, 2.0, tf.size)
    fixes += rng.normal(0, 1, fixes.shape) * np.c_[hdop, hdop, 1.5 * hdop]
    fixes[::37] += [15.0, -10.0, 0.0]  # multipath
    frame = WorldFrame("enu", (50.0, 8.0, 100.0))
    lat, lon, h = frame.to_geodetic(fixes)
    track = tj.gnss_track(ns(tf), lat, lon, h, origin=frame.origin, hdop=hdop)
    return truth, world, ns(to), v, w, track, antenna


def horizontal_errors(traj: Trajectory, truth: Trajectory, world: Rigid, t: np.ndarray):  # type: ignore[no-untyped-def]
    R, p = traj.pose_at(t)
    Rt, pt = truth.pose_at(t)
    Rw = world.rotation @ Rt
    dyaw = np.arctan2(R[:, 1, 0], R[:, 0, 0]) - np.arctan2(Rw[:, 1, 0], Rw[:, 0, 0])
    return np.linalg.norm((p - world.apply(pt))[:, :2], axis=1), np.angle(np.exp(1j * dyaw))


def test_fusion_beats_odometry_alone() -> None:
    truth, world, t, v, w, track, antenna = simulated_drive()
    fused = tj.fuse(t, v, w, track, antenna_m=antenna)
    assert fused.trajectory.frame == "enu" and fused.trajectory.origin == track.origin
    assert fused.speed_scale == pytest.approx(1 / 1.02, rel=3e-3)
    assert fused.yaw_rate_bias_rps == pytest.approx(math.radians(0.3), abs=5e-4)
    assert (~fused.used).sum() >= len(range(0, len(track), 37))  # the outliers went
    assert fused.outages == []
    te = t[10:-10:5]
    err, dyaw = horizontal_errors(fused.trajectory, truth, world, te)
    # odometry alone, even aligned to the truth by the best rigid transform
    odo = tj.from_odometry(t, v, w)
    _, po = odo.pose_at(te)
    _, pt = truth.pose_at(te)
    th, cs, cd = fusion._procrustes_2d(po[:, :2], world.apply(pt)[:, :2], np.ones(te.size))
    odo_err = np.linalg.norm(
        (po[:, :2] - cs) @ fusion._rot2(th).T + cd - world.apply(pt)[:, :2], axis=1
    )
    rms = float(np.sqrt(np.mean(err**2)))
    odo_rms = float(np.sqrt(np.mean(odo_err**2)))
    print(
        f"90 s: fused {rms:.2f} m rms ({err.max():.2f} max), heading "
        f"{math.degrees(np.sqrt(np.mean(dyaw**2))):.2f}° rms; odometry alone {odo_rms:.2f} m"
    )
    assert rms < 0.4 and err.max() < 1.0 and rms < odo_rms / 10
    assert np.abs(dyaw).max() < math.radians(1.0)
    # heights: the windows' mean GNSS height, the vehicle below its antenna
    _, pf = fused.trajectory.pose_at(te)
    _, pt = truth.pose_at(te)
    assert np.abs(pf[:, 2] - world.apply(pt)[:, 2]).max() < 0.6
    # without calibration the windows still beat odometry alone, less well
    plain = tj.fuse(t, v, w, track, antenna_m=antenna, calibrate=False)
    err2, _ = horizontal_errors(plain.trajectory, truth, world, te)
    assert rms < float(np.sqrt(np.mean(err2**2))) < odo_rms / 5


def test_fusion_bridges_a_gnss_outage() -> None:
    truth, world, t, v, w, track, antenna = simulated_drive(seed=2)
    keep = (track.t_ns < ns(40.0)) | (track.t_ns > ns(60.0))
    cut = tj.GnssTrack(track.t_ns[keep], track.xyz[keep], track.sigma_m[keep], "enu", track.origin)
    fused = tj.fuse(t, v, w, cut, antenna_m=antenna)
    assert len(fused.outages) == 1
    lo, hi = fused.outages[0]
    assert (lo, hi) == (ns(39.9), ns(60.1))  # the last fix before, the first after
    err, _ = horizontal_errors(fused.trajectory, truth, world, t[10:-10:5])
    assert float(np.sqrt(np.mean(err**2))) < 0.6  # calibrated odometry through 20 s
    with pytest.raises(ValueError, match="inside the odometry's span"):
        tj.fuse(t + 1000 * S, v, w, track)


def test_gnss_alone_heads_along_the_track() -> None:
    truth, world, _, _, _, track, _ = simulated_drive(seed=3)
    gnss = tj.from_gnss(track)
    te = np.arange(track.t_ns[0], track.t_ns[-1], S // 2)
    err, dyaw = horizontal_errors(gnss, truth, world, te)
    assert float(np.median(err)) < 3.0  # the raw fixes, noise and all
    assert float(np.median(np.abs(dyaw))) < 0.3  # noisy: 0.2 s between fixes


# --- clocks and GPS time -------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 20),
    st.integers(0, 10_000),
    st.floats(-2e-4, 2e-4),
)
def test_host_ns_from_utc_inverts_utc_seconds(n_pairs: int, seed: int, drift: float) -> None:
    rng = np.random.default_rng(seed)
    mono = T0 + np.cumsum(rng.integers(S // 2, 2 * S, n_pairs))
    offset = 1_700_000_000 * S + np.rint((mono - T0) * drift + rng.normal(0, 1e5, n_pairs)).astype(
        np.int64
    )  # NTP slews: 0.1 ms jitter, drift up to 200 ppm
    clock = np.stack([mono, mono + offset], axis=1)
    t = rng.integers(mono[0] - 5 * S, mono[-1] + 5 * S, 200)  # also beyond the pairs
    back = host_ns_from_utc(utc_seconds(t, clock), clock)
    assert np.abs(back - t).max() < 1000  # ns: float64 UTC seconds carry ~0.24 µs


def test_host_ns_from_utc_refuses_what_it_cannot_map() -> None:
    with pytest.raises(ValueError, match=r"no .* clock pairs"):
        host_ns_from_utc([1.7e9], np.zeros((0, 2), dtype=np.int64))
    stepped = np.array([[T0, 1_700_000_000 * S], [T0 + S, 1_700_000_000 * S - 3 * S]])
    with pytest.raises(ValueError, match="wall clock went back"):
        host_ns_from_utc([1.7e9], stepped)


def utc(y: int, mo: int, d: int, h: int = 0, mi: int = 0, s: int = 0) -> float:
    return float(calendar.timegm((y, mo, d, h, mi, s)))


def test_gps_time() -> None:
    assert gpstime.gps_minus_utc(utc(2016, 12, 31, 23, 59, 59)) == 17
    assert gpstime.gps_minus_utc(utc(2017, 1, 1)) == 18
    assert gpstime.gps_minus_utc(utc(1980, 1, 6)) == 0
    week, sow = gpstime.utc_to_gps_week_sow(utc(2024, 1, 1))  # a Monday
    assert (int(week), float(sow)) == (2295, 86400.0 + 18)
    assert gpstime.gps_week_sow_to_utc(2295, 86418.0) == utc(2024, 1, 1)
    np.testing.assert_allclose(
        gpstime.gps_adjusted_standard_time(utc(2024, 1, 1) + 0.25),
        1704067200 - 315964800 + 18 - 1e9 + 0.25,
    )
    assert gpstime.utc_from_adjusted_standard_time(388102418.0) == utc(2024, 1, 1)


@given(st.floats(utc(1980, 1, 6), utc(2035, 1, 1)))
def test_gps_time_round_trip(u: float) -> None:
    assert gpstime.gps_to_utc(gpstime.utc_to_gps(u)) == pytest.approx(u, abs=1e-6)
    w, s = gpstime.utc_to_gps_week_sow(u)
    assert 0 <= s < gpstime.SECONDS_PER_WEEK
    assert gpstime.gps_week_sow_to_utc(w, s) == pytest.approx(u, abs=1e-6)


# --- files ---------------------------------------------------------------------------

CLOCK = np.array([[T0, 1_714_550_400 * S], [T0 + 100 * S, 1_714_550_500 * S + 2_000_000]])


def to_host(u: np.ndarray) -> np.ndarray:
    return host_ns_from_utc(u, CLOCK)


def to_utc(t: np.ndarray) -> np.ndarray:
    return utc_seconds(t, CLOCK)


@pytest.mark.parametrize(
    "frame, origin",
    [
        ("enu", (50.0, 8.0, 100.0)),
        ("EPSG:25832", (400_000.0, 5_500_000.0, 0.0)),
        ("odometry", (0, 0, 0)),
    ],
)
def test_csv_round_trip(tmp_path: Path, frame: str, origin: tuple[float, float, float]) -> None:
    rng = np.random.default_rng(8)
    t = ns(np.cumsum(rng.uniform(0.005, 0.02, 500)))
    R = matrices_from_euler(*rng.uniform([-0.2, -0.2, -3], [0.2, 0.2, 3], (500, 3)).T)
    traj = Trajectory(t, R, rng.normal(0, 100, (500, 3)), frame, origin)
    path = tmp_path / "traj.csv"
    assert tj.to_csv(path, traj, host_to_utc=to_utc) == 500
    back = tj.from_csv(path, utc_to_host_ns=to_host)
    assert (back.frame, back.origin) == (traj.frame, traj.origin)
    assert np.abs(back.t_ns - t).max() < 1000  # ns
    np.testing.assert_allclose(back.translation, traj.translation, atol=1e-6)
    assert angle_between(back.rotation, R).max() < 1e-9
    if frame == "EPSG:25832":  # full grid coordinates in the file
        first = path.read_text().splitlines()[3].split(",")
        assert 399_000 < float(first[1]) < 401_000


def test_csv_times_positions_and_attitude_conventions(tmp_path: Path) -> None:
    frame = WorldFrame("enu", (50.0, 8.0, 100.0))
    P = np.array([[0.0, 0.0, 0.0], [100.0, 50.0, 1.0], [200.0, 80.0, 2.0]])
    lat, lon, h = frame.to_geodetic(P)
    rows = [
        "# an INS export, NED attitude",
        "gps_week,gps_sow,lat,lon,h,roll,pitch,heading,sdx",
    ]
    for i in range(3):
        rows.append(
            f"2314,{172818 + i * 0.5},{lat[i]:.12f},{lon[i]:.12f},{h[i]:.6f},2.0,5.0,90.0,0.01"
        )
    (tmp_path / "ned.csv").write_text("\n".join(rows) + "\n")
    traj = tj.from_csv(tmp_path / "ned.csv", utc_to_host_ns=to_host, origin=frame.origin)
    u0 = gpstime.gps_week_sow_to_utc(2314, 172818.0)
    np.testing.assert_array_equal(traj.t_ns, to_host(u0 + np.array([0.0, 0.5, 1.0])))
    np.testing.assert_allclose(traj.translation, P, atol=1e-6)
    # heading 90° (east) is yaw 0; NED pitch up is ENU pitch negative (the nose up)
    r, p, y = euler_from_matrices(traj.rotation[:1])
    np.testing.assert_allclose(np.degrees([r[0], p[0], y[0]]), [2.0, -5.0, 0.0], atol=1e-6)
    nose = traj.rotation[0] @ [1.0, 0.0, 0.0]
    assert nose[2] > 0 and nose[0] > 0.99
    left = traj.rotation[0] @ [0.0, 1.0, 0.0]
    assert left[2] > 0  # roll right side down lifts the left

    iso = "time,x,y,z,roll,pitch,yaw\n" + "".join(
        f"2024-05-01T08:00:0{i}.5Z,{i}.0,0,0,0,0,{30 * i}\n" for i in range(3)
    )
    (tmp_path / "iso.csv").write_text(iso)
    traj = tj.from_csv(tmp_path / "iso.csv", utc_to_host_ns=to_host, frame="EPSG:25832")
    np.testing.assert_array_equal(traj.t_ns, to_host(utc(2024, 5, 1, 8) + np.arange(3) + 0.5))
    np.testing.assert_allclose(euler_from_matrices(traj.rotation)[2], np.radians([0, 30, 60]))


HEADER = "time,x,y,z,roll,pitch,yaw\n"
ROW = "1,0,0,0,0,0,0\n"


@pytest.mark.parametrize(
    "text, where",
    [
        (HEADER + ROW + "2,0,abc,0,0,0,0\n", r":3: column 'y' \(column 3\): 'abc' is not a number"),
        (HEADER + ROW + "2,0,0\n", r":3: 3 fields, the header has 7"),
        ("# c\ntime,x,y,z,roll,pitch\n1,0,0,0,0,0\n", r":2: no attitude columns"),
        ("time,x,y,x,roll,pitch,yaw\n", r":1: repeated column 'x'"),
        (HEADER + ROW + "\n" + ROW, r":4: time 1.0 is not after"),
        (HEADER + ROW, r":1: 1 data rows"),
        (HEADER + "yesterday,0,0,0,0,0,0\n", r":2: column 'time' \(column 1\): 'yesterday' is not"),
        (HEADER + "1,0,0,nan,0,0,0\n", r":2: column 'z' \(column 4\): 'nan' is not finite"),
        ("", r": empty"),
    ],
)
def test_bad_csv_files_name_the_line_and_column(tmp_path: Path, text: str, where: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(TrajectoryFileError, match=r"bad\.csv" + where):
        tj.from_csv(path, utc_to_host_ns=to_host, frame="odometry")


def test_csv_frame_errors(tmp_path: Path) -> None:
    path = tmp_path / "xyz.csv"
    path.write_text("time,x,y,z,roll,pitch,yaw\n1,0,0,0,0,0,0\n2,1,0,0,0,0,0\n")
    with pytest.raises(TrajectoryFileError, match=r"xyz\.csv:1: x,y,z columns need a frame"):
        tj.from_csv(path, utc_to_host_ns=to_host)
    with pytest.raises(TrajectoryFileError, match="unknown frame"):
        tj.from_csv(path, utc_to_host_ns=to_host, frame="EPSG:999999")
    with pytest.raises(TrajectoryFileError, match=r"missing\.csv"):
        tj.from_csv(tmp_path / "missing.csv", utc_to_host_ns=to_host)
    with pytest.raises(TrajectoryFileError, match=r"xyz\.csv:1: x,y,z in 'enu' need its origin"):
        tj.from_csv(path, utc_to_host_ns=to_host, frame="enu")
    path.write_text("# frame: EPSG:25832\n# origin: 1, 2\n" + path.read_text())
    with pytest.raises(TrajectoryFileError, match=r"xyz\.csv:2: '# origin: 1, 2' is not 3"):
        tj.from_csv(path, utc_to_host_ns=to_host)
    with pytest.raises(TrajectoryFileError, match=r"xyz\.csv:1: the file's frame is 'EPSG:25832'"):
        tj.from_csv(path, utc_to_host_ns=to_host, frame="EPSG:32632")


def test_transform_is_pose_at_applied_to_the_points() -> None:
    rng = np.random.default_rng(5)
    n = 50
    t = T0 + np.cumsum(rng.integers(10**6, 10**8, n))
    traj = Trajectory(t, matrices_from_euler(*rng.uniform(-3, 3, (3, n))),
                      rng.normal(0, 100, (n, 3)))  # fmt: skip
    t_q = rng.integers(t[0], t[-1], 10_000)
    P = rng.normal(0, 20, (t_q.size, 3))
    R, p = traj.pose_at(t_q)
    np.testing.assert_allclose(traj.transform(t_q, P), np.einsum("nij,nj->ni", R, P) + p,
                               atol=1e-9)  # fmt: skip
    with pytest.raises(OutOfSpanError):
        traj.transform(np.array([t[0] - 10**9]), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="2 times but 1 points"):
        traj.transform(t[:2], np.zeros((1, 3)))


def test_the_compiled_kernels_turn_quaternions_into_matrices_as_the_geometry_module() -> None:
    """The numba kernels convert the slerped quaternion inline (a compiled twin of
    matrix_from_quat): at the samples and between them, the same rotations."""
    rng = np.random.default_rng(5)
    n = 30
    R = matrices_from_euler(*rng.uniform(-3, 3, (3, n)))
    t = T0 + np.cumsum(rng.integers(5, 20, n)) * 10**6
    traj = Trajectory(t, R, rng.normal(size=(n, 3)))
    got, _ = traj.pose_at(t)
    np.testing.assert_allclose(got, matrix_from_quat(quat_from_matrix(R)), rtol=0, atol=1e-15)
    a = rng.uniform(0.0, 1.0, n - 1)
    mid = t[:-1] + np.rint(a * np.diff(t)).astype(np.int64)
    a = (mid - t[:-1]) / np.diff(t)
    q0, perp, theta = traj._table[:, 0:4], traj._table[:, 4:8], traj._table[:, 8]  # slerp
    q = np.cos(a * theta)[:, None] * q0 + np.sin(a * theta)[:, None] * perp
    got, _ = traj.pose_at(mid)
    np.testing.assert_allclose(got, matrix_from_quat(q), rtol=0, atol=1e-15)
