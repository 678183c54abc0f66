"""Rotations: quaternions (w, x, y, z), rotation vectors, Euler angles, one module."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.geometry.rotations import (
    euler_from_matrices,
    matrices_from_euler,
    matrix_from_quat,
    matrix_from_rotvec,
    nearest_rotation,
    quat_from_matrix,
    rotation_angle,
    rotation_between,
    rotation_from_euler,
    rotation_to_euler,
    rotvec_from_matrix,
    skew,
)


def hamilton(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The quaternion product p q, (w, x, y, z)."""
    pw, pv, qw, qv = p[0], p[1:], q[0], q[1:]
    return np.r_[pw * qw - pv @ qv, pw * qv + qw * pv + np.cross(pv, qv)]


def elementary(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) @ Ry(pitch) @ Rx(roll), built from the three turns."""
    c, s = math.cos, math.sin
    Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-math.pi, math.pi), min_size=3, max_size=3))
def test_quaternion_round_trip(rpy: list[float]) -> None:
    R = rotation_from_euler(*rpy)
    q = quat_from_matrix(R[None])
    np.testing.assert_allclose(np.linalg.norm(q), 1.0, atol=1e-12)
    np.testing.assert_allclose(matrix_from_quat(q)[0], R, atol=1e-12)


def test_quaternion_round_trips_including_half_turns() -> None:
    rng = np.random.default_rng(2)
    rotations = [rotation_from_euler(*rng.uniform(-np.pi, np.pi, 3)) for _ in range(200)]
    rotations += [np.diag(d) for d in ([1, -1, -1], [-1, 1, -1], [-1, -1, 1], [1, 1, 1])]
    v = np.array([0.3, -1.2, 2.0])
    for R in rotations:
        q = quat_from_matrix(R)
        assert math.isclose(float(np.linalg.norm(q)), 1.0, abs_tol=1e-12) and q[0] >= 0
        np.testing.assert_allclose(matrix_from_quat(q), R, atol=1e-12)
        # scalar first: q (0, v) q* turns v as R does
        turned = hamilton(hamilton(q, np.r_[0.0, v]), q * [1, -1, -1, -1])
        np.testing.assert_allclose(turned, np.r_[0.0, R @ v], atol=1e-12)


def test_euler_angles_are_rz_ry_rx_and_round_trip() -> None:
    rng = np.random.default_rng(3)
    rpy = rng.uniform([-3, -1.5, -3], [3, 1.5, 3], (50, 3))
    R = matrices_from_euler(*rpy.T)
    back = np.column_stack(euler_from_matrices(R))
    for i in range(50):
        np.testing.assert_allclose(R[i], elementary(*rpy[i]), atol=1e-14)
        np.testing.assert_allclose(rotation_from_euler(*rpy[i]), R[i], atol=1e-14)
        np.testing.assert_allclose(rotation_to_euler(R[i]), rpy[i], atol=1e-12)
    np.testing.assert_allclose(back, rpy, atol=1e-12)
    for r in [(0.1, 0.2, 0.3), (-2.0, 1.2, 3.0), (0.0, -1.5, -0.7)]:
        np.testing.assert_allclose(rotation_to_euler(rotation_from_euler(*r)), r, atol=1e-12)
    # a half turn (quaternion w = 0) and the identity
    for M in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)):
        np.testing.assert_allclose(matrix_from_quat(quat_from_matrix(M[None]))[0], M)


def test_rotation_vectors() -> None:
    rng = np.random.default_rng(4)
    axes = rng.normal(size=(300, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.r_[rng.uniform(0, math.pi, 290), 0.0, 1e-10, 1e-7, 1e-3, math.pi - 1e-9,
                   math.pi - 1e-6, 0.5, 1.0, 2.0, 3.0]  # fmt: skip
    w = axes * angles[:, None]
    R = matrix_from_rotvec(w)
    half = angles / 2
    q = np.column_stack([np.cos(half), axes * np.sin(half)[:, None]])
    np.testing.assert_allclose(R, matrix_from_quat(q), atol=1e-14)
    np.testing.assert_allclose(matrix_from_rotvec(w[0]), R[0], atol=0)  # one vector
    back = rotvec_from_matrix(R)
    near_pi = angles > math.pi - 1e-5  # the axis' sign is then either
    np.testing.assert_allclose(back[~near_pi], w[~near_pi], atol=1e-12)
    np.testing.assert_allclose(matrix_from_rotvec(back), R, atol=1e-12)
    for i in range(len(w)):
        assert math.isclose(rotation_angle(R[i]), angles[i], abs_tol=1e-12)
    v = rng.normal(size=3)
    np.testing.assert_allclose(skew(w[5]) @ v, np.cross(w[5], v), atol=1e-15)


def test_rotation_between_turns_one_direction_onto_another() -> None:
    rng = np.random.default_rng(6)
    for a, b in rng.normal(size=(50, 2, 3)):
        R = rotation_between(a, b)
        np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
        np.testing.assert_allclose(R @ np.cross(a, b), np.cross(a, b), atol=1e-12)  # the axis
    np.testing.assert_allclose(rotation_between([0, 0, 2.0], [0, 0, 1.0]), np.eye(3))


def test_nearest_rotation_removes_noise_and_reflections() -> None:
    rng = np.random.default_rng(3)
    R = rotation_from_euler(0.3, -1.2, 2.0)
    noisy = R + rng.normal(0.0, 1e-4, (3, 3))
    Q = nearest_rotation(noisy)
    np.testing.assert_allclose(Q @ Q.T, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(Q) - 1.0) < 1e-12
    assert rotation_angle(Q @ R.T) < 5e-4
    np.testing.assert_allclose(nearest_rotation(R), R, atol=1e-12)
    # a reflection's nearest rotation flips its weakest axis, never keeps det = -1
    F = np.diag([1.0, 2.0, -0.5])
    np.testing.assert_allclose(nearest_rotation(F), np.diag([1.0, 1.0, 1.0]), atol=1e-12)
