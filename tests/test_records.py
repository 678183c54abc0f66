"""Records: frozen, validated, and the scan geometry helpers."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from acq.records import Frame, Scan


def make_scan(**kw: object) -> Scan:
    args: dict = dict(
        ranges=[1.0, 2.0, np.inf, -np.inf, np.nan],
        intensities=[10, 20, 0, 0, 0],
        angle_min=-math.pi / 2,
        angle_increment=math.pi / 4,
        time_increment=0.001,
        scan_period=0.025,
        recv_ns=123,
    )
    args.update(kw)
    return Scan(**args)


def test_scan_geometry() -> None:
    scan = make_scan()
    assert scan.ranges.dtype == np.float32
    np.testing.assert_allclose(scan.angles(), np.linspace(-math.pi / 2, math.pi / 2, 5))
    P = scan.points()
    np.testing.assert_allclose(P[0], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(P[1], [2 * math.cos(math.pi / 4), -2 * math.sin(math.pi / 4), 0])
    assert not np.isfinite(P[2:, :2]).any()


def test_scan_is_immutable() -> None:
    scan = make_scan()
    with pytest.raises(dataclasses.FrozenInstanceError):
        scan.recv_ns = 5  # type: ignore[misc]
    with pytest.raises(ValueError):
        scan.ranges[0] = 3.0


def test_scan_rejects_mismatched_intensities() -> None:
    with pytest.raises(ValueError, match="intensities has 2 values for 5 ranges"):
        make_scan(intensities=[1, 2])
    assert make_scan(intensities=[]).intensities.size == 0


def test_frame_needs_pixels_or_jpeg() -> None:
    with pytest.raises(ValueError, match="needs jpeg bytes or an image"):
        Frame(recv_ns=0, stamp_ns=0, sequence=0, width=4, height=3)
    with pytest.raises(ValueError, match="does not match"):
        Frame(0, 0, 0, 4, 3, image=np.zeros((4, 3, 3), np.uint8))
    assert Frame(0, 0, 0, 4, 3, jpeg=b"\xff\xd8").jpeg
