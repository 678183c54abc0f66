"""Colour balance (acq.cloud.balance) on synthetic samples: known gains per camera and
frame are recovered from points seen twice, up to the rig's reference."""

from __future__ import annotations

import numpy as np

from acq.cloud.balance import _solve, estimate_gains
from acq.cloud.views import Coloured, Pairs


def _camera(
    rng: np.random.Generator, albedo: np.ndarray, gains: np.ndarray, seen_by_other: np.ndarray
) -> Coloured:
    """One camera's samples of points of ``albedo`` (N,3) through per-frame ``gains`` (F,3):
    each point in a random frame, and every point again in a frame 1 and 5 away."""
    n, f = albedo.shape[0], gains.shape[0]
    frame = rng.integers(0, f, n)

    def look(frames: np.ndarray, points: np.ndarray) -> np.ndarray:
        v = albedo[points] * gains[frames] + rng.normal(0.0, 1.0, (points.size, 3))
        return np.clip(np.rint(v), 0, 255).astype(np.uint8)

    points = np.concatenate([np.arange(n), np.arange(n)])
    other = np.concatenate([frame + 1, frame - 5])
    ok = (other >= 0) & (other < f)
    points, other = points[ok], other[ok]
    coloured = np.ones(n, bool) if seen_by_other is None else seen_by_other
    nan = np.full(n, np.nan, np.float32)
    return Coloured(
        rgb=look(frame, np.arange(n)), coloured=coloured, frame=np.where(coloured, frame, -1),
        dt_s=nan, theta=nan, hidden=np.zeros(n, bool), frames_used=f, frames_failed=0,
        depth=nan, pairs=Pairs(points, other, look(other, points), np.ones(points.size, bool)),
    )  # fmt: skip


def test_gains_of_two_cameras_and_their_frames_are_recovered() -> None:
    rng = np.random.default_rng(1)
    n, f = 20_000, 60
    albedo = rng.uniform(60, 200, (n, 3))
    t = np.arange(f)
    left = np.stack([np.full(f, 0.95), np.ones(f), np.full(f, 1.05)], axis=1)
    left[20:35] *= 1.1  # an exposure step up and back
    right = np.stack([np.full(f, 1 / 0.95), np.ones(f), np.full(f, 1 / 1.05)], axis=1)
    right *= (1 - 0.15 * np.exp(-(((t - 40) / 6.0) ** 2)))[:, None]  # a cloud
    both = rng.random(n) < 0.2  # what both cameras see
    cams = [_camera(rng, albedo, left, None), _camera(rng, albedo, right, both)]
    gains = estimate_gains(cams, [f, f])
    assert 0.9 * both.sum() < gains.cross <= both.sum()  # usable samples seen by both
    est = [np.exp(g) for g in gains.log_gain]
    # relative to the reference, each camera's frames are its true gains to within 1 %
    ref = np.exp(np.mean([np.median(np.log(left), 0), np.median(np.log(right), 0)], axis=0))
    for got, true in zip(est, (left, right), strict=True):
        np.testing.assert_allclose(got, true / ref, rtol=0.01)
    # the reference: the mean of each camera's median frame is gain 1
    assert np.allclose(np.exp(np.mean([np.median(g, 0) for g in gains.log_gain], 0)), 1.0)
    # applying them brings both cameras to the same colour
    a = gains.apply(0, cams[0].rgb, cams[0].frame)[both].astype(float)
    b = gains.apply(1, cams[1].rgb, cams[1].frame)[both].astype(float)
    assert np.median(np.abs(a - b)) <= 1.0
    raw = np.abs(cams[0].rgb[both].astype(float) - cams[1].rgb[both])
    assert np.median(raw) >= 5.0  # before: the cameras' white balances apart


def test_clipped_and_dark_samples_are_not_used() -> None:
    rng = np.random.default_rng(2)
    n, f = 5_000, 10
    albedo = np.full((n, 3), 250.0)  # white walls: clipped in any brighter frame
    gains = np.ones((f, 3))
    gains[5:] = 1.2
    cam = _camera(rng, albedo, gains, None)
    out = estimate_gains([cam], [f])
    assert out.pairs == 0  # every sample at 250 or clipped at 255: nothing to go on
    np.testing.assert_allclose(out.log_gain[0], 0.0, atol=1e-9)


def test_the_solve_gives_the_bytes_of_conjugate_gradients_in_numpy() -> None:
    # the compiled iterations sum in numpy's order (bincount, sum over axis 0): the same
    # gains to the last bit as the numpy loop they replace, written out here
    rng = np.random.default_rng(5)
    n = 300
    a, b = rng.integers(0, n, 4000), rng.integers(0, n, 4000)
    w = rng.uniform(1.0, 100.0, 4000)
    diag = np.arange(n)
    rows = np.concatenate([a, b, a, b, diag])  # repeated entries add up
    cols = np.concatenate([a, b, b, a, diag])
    vals = np.concatenate([w, w, -w, -w, np.full(n, 1e-3)])
    rhs = rng.normal(0.0, 1.0, (n, 3))

    def times(x: np.ndarray) -> np.ndarray:
        return np.stack(
            [np.bincount(rows, weights=vals * x[cols, k], minlength=n) for k in range(3)], axis=1
        )

    d = np.bincount(rows[rows == cols], weights=vals[rows == cols], minlength=n)
    x, r = np.zeros_like(rhs), rhs.copy()
    z = r / d[:, None]
    p, rz = z.copy(), np.sum(r * z, axis=0)
    stop = 1e-20 * np.maximum(np.sum(rhs * rhs, axis=0), 1e-30)
    for _ in range(4 * n):
        if np.all(np.sum(r * r, axis=0) <= stop):
            break
        q = times(p)
        alpha = rz / np.maximum(np.sum(p * q, axis=0), 1e-300)
        x += alpha * p
        r -= alpha * q
        z = r / d[:, None]
        rz_new = np.sum(r * z, axis=0)
        p = z + (rz_new / np.maximum(rz, 1e-300)) * p
        rz = rz_new
    got = _solve(rows, cols, vals, rhs)
    assert np.array_equal(got, x)
    np.testing.assert_allclose(times(got), rhs, atol=1e-6)  # and it solves the system
