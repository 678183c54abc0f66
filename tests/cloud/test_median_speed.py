"""The rig's median speed that `acq colorize` sizes its frame search with: scans that share
a stamp (a re-timed scanner that sent two scans with one device tick) give no numpy
warning and the right speed."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from acq.cloud.job import _median_speed
from acq.motion.trajectory import Trajectory


def test_scans_sharing_a_stamp_give_the_speed_without_a_warning() -> None:
    t = np.arange(0, 11, dtype=np.int64) * 10**9  # 10 s at 5 m/s along x
    traj = Trajectory(t, np.repeat(np.eye(3)[None], t.size, axis=0),
                      np.stack([5.0 * t * 1e-9, 0 * t, 0 * t], axis=1))  # fmt: skip
    scans = np.arange(1, 9, dtype=np.int64) * 10**9
    scans = np.sort(np.concatenate([scans, scans[:3]]))  # three stamps twice
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _median_speed(traj, scans) == pytest.approx(5.0)
