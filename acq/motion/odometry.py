"""Wheel odometry: the vehicle's speed and yaw rate from its wheel speeds, and planar dead
reckoning of them into a :class:`acq.motion.trajectory.Trajectory` in the ``"odometry"``
frame (:func:`from_odometry`). Times are host monotonic ns (int64); speeds m/s, yaw rates
rad/s counter-clockwise."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import numpy.typing as npt

from acq.geometry.rotations import matrices_from_euler
from acq.geometry.transforms import Rigid
from acq.motion.trajectory import Trajectory

__all__ = [
    "Hold",
    "dead_reckon",
    "from_odometry",
    "integrate",
    "odometry_arrays",
    "speed_from_wheels",
    "yaw_rate_from_wheels",
]

Hold = Literal["forward", "mean"]

_WHEELS = {"front": (0, 1), "rear": (2, 3), "all": (0, 1, 2, 3)}


def speed_from_wheels(
    wheel_speeds: npt.ArrayLike, which: Literal["rear", "front", "all"] = "rear"
) -> np.ndarray:
    """(N,) vehicle speed, m/s, from (N,4) wheel speeds (m/s) ordered front-left,
    front-right, rear-left, rear-right: the mean of the ``which`` wheels. The rear
    wheels' mean is the speed of the rear axle's centre, where a car's velocity points
    along x (no sideslip: :func:`from_odometry`'s ``rear_axle_x_m``); the front wheels
    run wider in a bend (by 1/cos of the steering angle)."""
    w = np.asarray(wheel_speeds, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 4:
        raise ValueError(f"wheel_speeds must be (N,4) FL, FR, RL, RR, got shape {w.shape}")
    if which not in _WHEELS:
        raise ValueError(f"which must be one of {', '.join(_WHEELS)}, got {which!r}")
    speed: npt.NDArray[np.float64] = w[:, list(_WHEELS[which])].mean(axis=1)
    return speed


def yaw_rate_from_wheels(
    wheel_speeds: npt.ArrayLike, track_m: float, which: Literal["rear", "front"] = "rear"
) -> np.ndarray:
    """(N,) yaw rate, rad/s counter-clockwise, from the ``which`` axle's wheel speeds
    ((N,4) m/s, FL FR RL RR) and its track width (m): ``(right - left) / track``. Wheel
    slip and tyre radius differences bias it; a gyro's yaw rate is better."""
    w = np.asarray(wheel_speeds, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != 4:
        raise ValueError(f"wheel_speeds must be (N,4) FL, FR, RL, RR, got shape {w.shape}")
    if which not in ("rear", "front") or not track_m > 0:
        raise ValueError("which must be 'rear' or 'front' and track_m > 0")
    left, right = _WHEELS[which]
    return (w[:, right] - w[:, left]) / track_m


def dead_reckon(
    dt_s: np.ndarray, speed: np.ndarray, yaw_rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planar dead reckoning over intervals ``dt_s`` (M,) s with constant ``speed`` (m/s)
    and ``yaw_rate`` (rad/s) in each: exact arcs (``chord = v dt sinc(w dt / 2)`` at the
    mid heading). Returns x, y (m) and heading (rad) (M+1,) from (0, 0, 0)."""
    dpsi = yaw_rate * dt_s
    psi = np.concatenate([[0.0], np.cumsum(dpsi)])
    chord = speed * dt_s * np.sinc(dpsi / (2 * math.pi))
    mid = psi[:-1] + 0.5 * dpsi
    x = np.concatenate([[0.0], np.cumsum(chord * np.cos(mid))])
    y = np.concatenate([[0.0], np.cumsum(chord * np.sin(mid))])
    return x, y, psi


def odometry_arrays(
    t_ns: npt.ArrayLike, speed_mps: npt.ArrayLike, yaw_rate_rps: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(t_ns)
    if t.dtype.kind not in "iu":
        raise TypeError(f"t_ns must be integer host ns, got {t.dtype}")
    t = t.astype(np.int64).reshape(-1)
    v = np.asarray(speed_mps, dtype=np.float64).reshape(-1)
    w = np.asarray(yaw_rate_rps, dtype=np.float64).reshape(-1)
    if not (t.size == v.size == w.size):
        raise ValueError(f"t_ns, speed, yaw_rate lengths differ: {t.size}, {v.size}, {w.size}")
    if t.size < 2:
        raise ValueError(f"odometry needs at least 2 samples, got {t.size}")
    if not (np.isfinite(v).all() and np.isfinite(w).all()):
        i = int(np.argmin(np.isfinite(v) & np.isfinite(w)))
        raise ValueError(f"odometry sample {i} is not finite (speed {v[i]}, yaw rate {w[i]})")
    dt = np.diff(t)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise ValueError(f"odometry times must increase strictly: sample {i + 1} is not after {i}")
    return t, v, w


def integrate(
    t: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    hold: Hold,
    max_gap_s: float,
    on_gap: str,
    step_s: float | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Host ns of the output samples and the rear axle's x, y (m), heading (rad) there."""
    if hold not in ("forward", "mean"):
        raise ValueError(f"hold must be 'forward' or 'mean', got {hold!r}")
    if on_gap not in ("raise", "flag"):
        raise ValueError(f"on_gap must be 'raise' or 'flag', got {on_gap!r}")
    dt_ns = np.diff(t)
    gap = dt_ns > max_gap_s * 1e9
    if gap.any() and on_gap == "raise":
        i = int(np.argmax(gap))
        raise ValueError(
            f"odometry gap of {dt_ns[i] * 1e-9:.3f} s after sample {i} "
            f"({(t[i] - t[0]) * 1e-9:.3f} s in; max_gap_s {max_gap_s} s): "
            "dead reckoning across it is a guess (on_gap='flag' bridges and flags it)"
        )
    if hold == "forward":
        vi, wi = v[:-1], w[:-1]
    else:
        vi, wi = 0.5 * (v[:-1] + v[1:]), 0.5 * (w[:-1] + w[1:])
    t_out = t
    if step_s is not None:
        if not step_s > 0:
            raise ValueError("step_s must be > 0")
        n_sub = np.where(gap, 1, np.ceil(dt_ns / (step_s * 1e9))).astype(np.int64)
        n_sub = np.maximum(n_sub, 1)
        k = np.arange(int(n_sub.sum())) - np.repeat(np.cumsum(n_sub) - n_sub, n_sub)
        sub = (np.repeat(dt_ns, n_sub) * k) // np.repeat(n_sub, n_sub)
        t_out = np.append(np.repeat(t[:-1], n_sub) + sub, t[-1])
        vi, wi = np.repeat(vi, n_sub), np.repeat(wi, n_sub)
    x, y, psi = dead_reckon(np.diff(t_out) * 1e-9, vi, wi)
    return t_out, x, y, psi


def from_odometry(
    t_ns: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    *,
    start: Rigid | None = None,
    hold: Hold = "mean",
    max_gap_s: float = 0.5,
    on_gap: Literal["raise", "flag"] = "raise",
    step_s: float | None = None,
    rear_axle_x_m: float = 0.0,
) -> Trajectory:
    """Planar dead reckoning of speed (m/s, of the rear axle's centre, along the
    vehicle's x) and yaw rate (rad/s, counter-clockwise) sampled at host ns ``t_ns``.

    Each interval is integrated exactly as an arc with constant inputs: ``hold``
    "forward" takes a sample's values until the next sample (exact for piecewise-constant
    inputs), "mean" the mean of the interval's two ends (second order for smooth
    inputs). Irregular sampling is fine. An interval longer than ``max_gap_s`` raises
    ValueError (``on_gap="raise"``) or is bridged with the held inputs and flagged: the
    trajectory has no pose inside it, and the poses after it carry the guess's error
    (``"flag"``). ``step_s`` adds arc-exact samples so that no other interval is longer.
    ``rear_axle_x_m``: the vehicle-frame x of the rear axle's centre (the one point of a
    car that moves along x without sideslip); the pose is the vehicle origin's. The first
    pose is ``start`` (frame "odometry", identity by default); roll and pitch stay
    ``start``'s.
    """
    t, v, w = odometry_arrays(t_ns, speed_mps, yaw_rate_rps)
    t_out, x, y, psi = integrate(t, v, w, hold, max_gap_s, on_gap, step_s)
    if rear_axle_x_m:  # origin = axle - Rz(psi) (rear_axle_x_m, 0), and (0, 0) at start
        x = x - rear_axle_x_m * (np.cos(psi) - 1.0)
        y = y - rear_axle_x_m * np.sin(psi)
    start = Rigid.identity() if start is None else start
    R = start.rotation @ matrices_from_euler(0.0, 0.0, psi)
    p = np.stack([x, y, np.zeros_like(x)], axis=1) @ start.rotation.T + start.translation
    return Trajectory(t_out, R, p, "odometry", max_gap_s=max_gap_s)
