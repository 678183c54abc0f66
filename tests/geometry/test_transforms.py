"""Rigid transforms: composition, inverse, refusal of non-rotations."""

from __future__ import annotations

import numpy as np
import pytest

from acq.geometry.rotations import rotation_from_euler
from acq.geometry.transforms import Rigid


def test_inverse_and_composition() -> None:
    rng = np.random.default_rng(0)
    a = Rigid(rotation_from_euler(0.3, -0.2, 1.1), [1.0, -2.0, 0.5])
    b = Rigid(rotation_from_euler(-1.0, 0.4, -2.5), [0.1, 0.2, -0.3])
    P = rng.normal(size=(50, 3))
    np.testing.assert_allclose((a @ b).apply(P), a.apply(b.apply(P)), atol=1e-12)
    np.testing.assert_allclose(a.inverse().apply(a.apply(P)), P, atol=1e-12)
    np.testing.assert_allclose((a @ a.inverse()).matrix(), np.eye(4), atol=1e-12)


def test_reflection_and_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="proper rotation"):
        Rigid(np.diag([1.0, 1.0, -1.0]), np.zeros(3))
    with pytest.raises(ValueError, match="proper rotation"):
        Rigid(np.eye(3) * 1.01, np.zeros(3))
    with pytest.raises(ValueError, match="3 values"):
        Rigid(np.eye(3), np.zeros(2))


def test_many_points_go_through_the_compiled_loop_with_the_same_result() -> None:
    from acq.geometry.rigid_kernels import apply_rigid

    rng = np.random.default_rng(3)
    T = Rigid(rotation_from_euler(0.3, -0.2, 1.1), np.array([1.0, -2.0, 0.5]))
    P = rng.normal(0.0, 10.0, (60_000, 3))
    expected = P @ T.rotation.T + T.translation
    np.testing.assert_allclose(T.apply(P), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(apply_rigid(P[::2], T.rotation, T.translation), expected[::2],
                               rtol=0, atol=1e-12)  # fmt: skip
