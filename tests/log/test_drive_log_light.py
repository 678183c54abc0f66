"""A long log's index read without the scans' returns: its times and no more."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acq.camera import calibfile
from acq.cloud.job import prepare
from acq.cloud.report import Report
from acq.log.drive_log import read_log
from acq.sim.drive_log import DriveTruth


def test_an_index_without_returns_keeps_every_time_and_drops_the_points(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    """colorize's index of a log too long to read whole held every scan's ranges and
    intensities (8 bytes a point: 1.2 GB an hour of a UTM-30LX) that only the chunks
    use, reading their own."""
    truth, calib = short_drive
    full = read_log(truth.files)
    light = read_log(truth.files, returns=False)
    assert full.ranges.shape == (full.n_scans, full.steps) and full.steps > 1000
    assert light.ranges.shape == light.intensities.shape == (full.n_scans, 0)
    assert light.steps == full.steps
    for name in ("scan_ns", "scan_ticks", "scan_recv_ns", "clock"):
        assert np.array_equal(getattr(light, name), getattr(full, name)), name
    assert (light.angle_min, light.angle_increment, light.time_increment) == (
        full.angle_min, full.angle_increment, full.time_increment)  # fmt: skip
    assert light.between(full.scan_ns[2], full.scan_ns[5]).n_scans == 3
    _, index = prepare(truth.files, calibfile.load(calib), Report(output="x.ply"))
    assert index.ranges.size == 0 and index.steps == full.steps
