"""Wheel odometry fused with GNSS fixes (:func:`fuse`): a drift-correcting, piecewise
rigid alignment of the dead-reckoned track to the fixes, with the odometry's speed scale
and yaw-rate bias calibrated. Times are host monotonic ns (int64) unless a name ends in
``_s``."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from acq.geometry.rotations import matrices_from_euler
from acq.motion.gnss import GnssTrack
from acq.motion.odometry import Hold, from_odometry, integrate, odometry_arrays
from acq.motion.trajectory import Trajectory

__all__ = ["Fusion", "fuse"]


@dataclass(frozen=True, eq=False)
class Fusion:
    """The result of :func:`fuse`: the ``trajectory`` (in the GNSS frame), the odometry's
    estimated ``speed_scale`` and ``yaw_rate_bias_rps`` (subtracted), ``used`` (K,) the
    fixes that entered the fit (inside the odometry's span, not rejected), the
    horizontal ``residual_rms_m`` of the used fixes, and ``outages``: (start, end) host
    ns of the spans longer than ``window_s``/4 without a used fix (the odometry's ends
    included), bridged by calibrated odometry alone."""

    trajectory: Trajectory
    speed_scale: float
    yaw_rate_bias_rps: float
    used: np.ndarray
    residual_rms_m: float
    outages: list[tuple[int, int]]


def _procrustes_2d(
    src: np.ndarray, dst: np.ndarray, w: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted rigid 2D fit ``dst ~ c_dst + Rz(theta) (src - c_src)``: theta, c_src, c_dst."""
    ws = w / w.sum()
    cs, cd = ws @ src, ws @ dst
    a, b = src - cs, dst - cd
    cross = ws @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    dot = ws @ (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    return math.atan2(cross, dot), cs, cd


def _rot2(theta: np.ndarray | float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _window_weights(
    t: npt.NDArray[np.float64], knots: npt.NDArray[np.float64], half_s: float
) -> npt.NDArray[np.float64]:
    """(J, K) triangular weights of fix times ``t`` (s) around knot times (s)."""
    return np.clip(1.0 - np.abs(t[None, :] - knots[:, None]) / half_s, 0.0, None)


def fuse(
    t_ns: npt.ArrayLike,
    speed_mps: npt.ArrayLike,
    yaw_rate_rps: npt.ArrayLike,
    gnss: GnssTrack,
    *,
    antenna_m: npt.ArrayLike = (0.0, 0.0, 0.0),
    window_s: float = 40.0,
    calibrate: bool = True,
    min_fixes: int = 5,
    heading_prior_rad: float = 0.05,
    reject: float = 4.0,
    hold: Hold = "mean",
    max_gap_s: float = 0.5,
    on_gap: Literal["raise", "flag"] = "raise",
    step_s: float | None = None,
) -> Fusion:
    """Odometry (as :func:`from_odometry`, ``rear_axle_x_m`` 0) fitted to GNSS fixes: a
    drift-correcting, piecewise rigid alignment weighted by each fix's ``sigma_m``.

    1. Calibration (``calibrate``): one speed scale and one yaw-rate bias for the whole
       drive, with the heading and offset that best align the dead-reckoned antenna
       track (``antenna_m``: the antenna in the vehicle frame, m) to the fixes, by
       weighted Gauss-Newton, the bias started from the trend of per-window headings.
       Without it, the heading and offset alone.
    2. Windows: knots every ``window_s``/2; at each, the fixes within ``window_s``/2 of
       it (triangular weights, so every fix counts in two windows, its weights summing
       to 1) give a small rigid correction: a turn about the window's
       centroid (with a prior of ``heading_prior_rad``, so that a window too short or
       straight to fix it leaves it near zero) and a horizontal and vertical offset.
       Between knots the corrected positions and headings blend linearly; a knot whose
       window has fewer than ``min_fixes`` fixes is skipped (an outage: odometry bridges
       it). Fixes off by more than ``reject`` robust sigmas are dropped and all refitted.

    The result is sampled at the odometry's times, in the GNSS frame. Limits (it is not
    an INS): roll and pitch stay zero (on a 5 % grade a point 20 m away is ~1 m too high
    or low); heights are the windows' mean GNSS heights; the speed scale and bias are
    constant over the drive; within a window the odometry's own errors remain; a fix's
    time must be right (latency x speed is a position error); the fixes' errors are
    taken as independent, which multipath and atmospheric errors are not.
    """
    t, v, w = odometry_arrays(t_ns, speed_mps, yaw_rate_rps)
    if not window_s > 0 or min_fixes < 2:
        raise ValueError("window_s must be > 0 and min_fixes >= 2")
    ant = np.asarray(antenna_m, dtype=np.float64).reshape(3)
    base = from_odometry(t, v, w, hold=hold, max_gap_s=max_gap_s, on_gap=on_gap, step_s=step_s)
    inside = base.covers(gnss.t_ns)
    if int(inside.sum()) < min_fixes:
        raise ValueError(
            f"only {int(inside.sum())} GNSS fixes fall inside the odometry's span "
            f"(need {min_fixes}): are both on the same host clock?"
        )
    tk, zk, sk = gnss.t_ns[inside], gnss.xyz[inside], gnss.sigma_m[inside]
    wk = 1.0 / sk**2
    ts = (tk - t[0]) * 1e-9
    span_s = (t[-1] - t[0]) * 1e-9
    knots = np.linspace(0.0, span_s, max(1, math.ceil(span_s / (window_s / 2))) + 1)
    W = _window_weights(ts, knots, window_s / 2)

    def antenna_xy(scale: float, bias: float) -> np.ndarray:
        """The antenna's dead-reckoned x, y at the fix times (odometry frame)."""
        t_out, x, y, psi = integrate(t, v * scale, w - bias, hold, max_gap_s, on_gap, step_s)
        x, y, psi = (np.interp(tk, t_out, a) for a in (x, y, psi))
        c, s = np.cos(psi), np.sin(psi)
        return np.column_stack([x + c * ant[0] - s * ant[1], y + s * ant[0] + c * ant[1]])

    scale, bias = 1.0, 0.0
    active = np.ones(tk.size, dtype=bool)
    if calibrate:
        bias = _initial_bias(antenna_xy(1.0, 0.0), zk[:, :2], wk, ts, W)
    for rnd in range(3):  # fit, drop outliers, fit again
        wa = wk * active
        if calibrate:
            scale, bias = _calibrate(antenna_xy, zk[:, :2], wa, W, scale, bias)
        a_xy = antenna_xy(scale, bias)
        theta0, cs, cd = _procrustes_2d(a_xy, zk[:, :2], wa)
        dz0 = float(wa @ (zk[:, 2] - ant[2]) / wa.sum())
        align = _Knot(theta0, cs, np.array([*(cd - cs), dz0]))  # p -> cd + R (p - cs)
        a1 = align.apply(np.column_stack([a_xy, np.full(tk.size, ant[2])]))
        fits = _knot_fits(a1, zk, wa, W, min_fixes, heading_prior_rad)
        fused = _blend(fits, knots, ts, a1)
        r = np.hypot(*(fused[:, :2] - zk[:, :2]).T) / sk
        robust = float(np.median(r[active])) / 1.1774  # Rayleigh: median = 1.1774 sigma
        keep = r <= reject * max(robust, 1.0)
        if rnd == 2 or (keep == active).all():
            break
        active = keep

    traj = from_odometry(
        t, v * scale, w - bias, hold=hold, max_gap_s=max_gap_s, on_gap=on_gap, step_s=step_s
    )
    t_s = (traj.t_ns - t[0]) * 1e-9
    p = _blend(fits, knots, t_s, align.apply(traj.translation))
    R = matrices_from_euler(0.0, 0.0, theta0 + _blend_theta(fits, knots, t_s)) @ traj.rotation
    out = Trajectory(traj.t_ns, R, p, gnss.frame, gnss.origin, max_gap_s=traj.max_gap_s)
    used = np.zeros(len(gnss), dtype=bool)
    used[np.flatnonzero(inside)[active]] = True
    res = np.hypot(*(fused[active, :2] - zk[active, :2]).T)
    edges = np.concatenate([[t[0]], tk[active], [t[-1]]])
    long = np.flatnonzero(np.diff(edges) > window_s / 4 * 1e9)
    outages = [(int(edges[i]), int(edges[i + 1])) for i in long]
    return Fusion(out, scale, bias, used, float(np.sqrt(np.mean(res**2))), outages)


def _initial_bias(
    a: np.ndarray, z: np.ndarray, w: np.ndarray, ts: np.ndarray, W: np.ndarray
) -> float:
    """A yaw-rate bias guess (rad/s) from the trend of per-window headings: a bias b
    turns the dead-reckoned track by b t, so the windows' corrections go as -b t."""
    th, tc, wt = [], [], []
    for row in W:
        ww = row * w
        sel = ww > 0
        if sel.sum() < 3 or np.ptp(a[sel], axis=0).max() < 5.0:
            continue  # heading unobservable: too few fixes, or standing still
        theta, _, _ = _procrustes_2d(a[sel], z[sel], ww[sel])
        th.append(theta)
        tc.append(float(ww @ ts / ww.sum()))
        wt.append(float(ww.sum()))
    if len(th) < 2:
        return 0.0
    slope = np.polyfit(np.array(tc), np.unwrap(np.array(th)), 1, w=np.sqrt(np.array(wt)))[0]
    return float(-slope)


def _calibrate(
    antenna_xy: Callable[[float, float], np.ndarray],
    z: np.ndarray,
    w: np.ndarray,
    W: np.ndarray,
    scale: float,
    bias: float,
) -> tuple[float, float]:
    """Gauss-Newton on (speed scale, yaw-rate bias), each window's best rigid 2D
    alignment of the trial track to its fixes solved inside (a variable projection):
    the scale shows in the windows' lengths, the bias in their curvature, so a slowly
    wandering bias does not bend the scale as one alignment of the whole drive would."""
    knot, fix = np.nonzero(W * (w > 0))
    pw = W[knot, fix] * w[fix]  # a fix counts in two windows, its weights summing to 1
    n_knots = W.shape[0]
    enough = np.bincount(knot, minlength=n_knots) >= 3
    sel = enough[knot]
    knot, fix, pw = knot[sel], fix[sel], pw[sel]
    sq = np.sqrt(pw)
    zc = z - z.mean(axis=0)  # Procrustes ignores shifts; large CRS numbers cancel badly
    Z = zc[fix]

    def wsum(x: np.ndarray) -> np.ndarray:
        return np.bincount(knot, weights=pw * x, minlength=n_knots)

    sw = np.maximum(wsum(np.ones(knot.size)), 1e-300)
    cd = np.column_stack([wsum(Z[:, 0]), wsum(Z[:, 1])]) / sw[:, None]

    def residual(s: float, b: float) -> np.ndarray:
        a = antenna_xy(s, b)
        A = (a - a.mean(axis=0))[fix]
        cs = np.column_stack([wsum(A[:, 0]), wsum(A[:, 1])]) / sw[:, None]
        cross = wsum(A[:, 0] * Z[:, 1] - A[:, 1] * Z[:, 0]) / sw - (
            cs[:, 0] * cd[:, 1] - cs[:, 1] * cd[:, 0]
        )
        dot = wsum(A[:, 0] * Z[:, 0] + A[:, 1] * Z[:, 1]) / sw - np.einsum("ij,ij->i", cs, cd)
        th = np.arctan2(cross, dot)[knot]
        c, si = np.cos(th), np.sin(th)
        d = A - cs[knot]
        rx = c * d[:, 0] - si * d[:, 1] + cd[knot, 0] - Z[:, 0]
        ry = si * d[:, 0] + c * d[:, 1] + cd[knot, 1] - Z[:, 1]
        return np.concatenate([rx * sq, ry * sq])

    r0 = residual(scale, bias)
    for _ in range(20):
        hs, hb = 1e-4, 1e-5
        J = np.column_stack(
            [
                (residual(scale + hs, bias) - residual(scale - hs, bias)) / (2 * hs),
                (residual(scale, bias + hb) - residual(scale, bias - hb)) / (2 * hb),
            ]
        )
        step = np.linalg.lstsq(J, -r0, rcond=None)[0]
        lam = 1.0
        while True:  # halve the step until the cost drops
            r1 = residual(scale + lam * step[0], bias + lam * step[1])
            if r1 @ r1 <= r0 @ r0 or lam < 1e-3:
                break
            lam /= 2
        if r1 @ r1 > r0 @ r0:
            break
        scale, bias, r0 = scale + lam * step[0], bias + lam * step[1], r1
        if abs(lam * step[0]) < 1e-9 and abs(lam * step[1]) < 1e-10:
            break
    if not 0.5 < scale < 2.0:
        raise ValueError(f"odometry speed scale {scale:.3f} against GNSS: wrong units or data?")
    return float(scale), float(bias)


@dataclass(frozen=True)
class _Knot:
    theta: float  # rad, turn about centre
    centre: np.ndarray  # (2,) m
    offset: np.ndarray  # (3,) m, added after the turn

    def apply(self, P: np.ndarray) -> np.ndarray:
        out = np.empty_like(P)
        out[:, :2] = (P[:, :2] - self.centre) @ _rot2(self.theta).T + self.centre + self.offset[:2]
        out[:, 2] = P[:, 2] + self.offset[2]
        return out


def _knot_fits(
    a: np.ndarray,
    z: np.ndarray,
    w: np.ndarray,
    W: np.ndarray,
    min_fixes: int,
    prior: float,
) -> list[_Knot | None]:
    """Per knot (row of ``W``): the turn (with a zero-mean prior of sd ``prior`` rad)
    about the window's weighted centroid and the offset taking the antenna points ``a``
    to the fixes ``z``; None where fewer than ``min_fixes`` fixes have weight."""
    out: list[_Knot | None] = []
    for row in W:
        ww = row * w
        sel = ww > 0
        if int(sel.sum()) < min_fixes:
            out.append(None)
            continue
        aa, zz, ws = a[sel], z[sel], ww[sel] / ww[sel].sum()
        c = ws @ aa[:, :2]
        d = aa[:, :2] - c
        wsum = float(ww[sel].sum())
        theta = 0.0
        for _ in range(3):  # Gauss-Newton, the turn linearised about theta
            rd = d @ _rot2(theta).T
            r = zz[:, :2] - c - rd
            r -= ws @ r  # the offset (uncorrelated with the turn about the centroid)
            g = np.column_stack([-rd[:, 1], rd[:, 0]])
            num = wsum * float(ws @ np.einsum("ij,ij->i", g, r)) - theta / prior**2
            den = wsum * float(ws @ np.einsum("ij,ij->i", g, g)) + 1.0 / prior**2
            theta += num / den
        off = ws @ (zz[:, :2] - c - d @ _rot2(theta).T)
        dz = float(ws @ (zz[:, 2] - aa[:, 2]))
        out.append(_Knot(theta, c, np.array([off[0], off[1], dz])))
    return out


def _valid(fits: list[_Knot | None], knots: np.ndarray) -> tuple[np.ndarray, list[_Knot]]:
    idx = [i for i, k in enumerate(fits) if k is not None]
    if not idx:
        raise ValueError("no window has enough GNSS fixes to align the odometry")
    return knots[idx], [fits[i] for i in idx]  # type: ignore[misc]


def _blend(fits: list[_Knot | None], knots: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Points ``P`` (N,3) at times ``t`` (s) through the two nearest knots' transforms,
    weighted linearly in time (held at the ends; outages bridged)."""
    times, valid = _valid(fits, knots)
    out = np.zeros_like(P)
    if len(valid) == 1:
        return valid[0].apply(P)
    j = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
    a = np.clip((t - times[j]) / (times[j + 1] - times[j]), 0.0, 1.0)
    for i, k in enumerate(valid):  # a loop over knots, not points
        wi = np.where(j == i, 1.0 - a, 0.0) + np.where(j + 1 == i, a, 0.0)
        sel = np.flatnonzero(wi > 0)
        if sel.size:
            out[sel] += wi[sel, None] * k.apply(P[sel])
    return out


def _blend_theta(
    fits: list[_Knot | None], knots: np.ndarray, t: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    times, valid = _valid(fits, knots)
    return np.interp(t, times, [k.theta for k in valid])
