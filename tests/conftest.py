"""Shared fixtures: paths to the real device data in ../shared/data/.

Tests that drive simulated devices, recorders and clocks in real time (frame rates,
stall timeouts, kills at a moment) are marked ``realtime`` in their own modules
(``pytestmark``) or functions: CPU load from other tests makes them miss deadlines that
a real rig would meet, so `make test` runs them alone, then the rest on both cores
(pytest-xdist). The tests mirror the package: tests/<subpackage>/.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from acq.sim.drive_log import DriveTruth


ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"


@pytest.fixture
def shared_dir() -> Path:
    """../shared/ beside the checkout; tests that need it skip with a reason when absent."""
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent: the real captures and ARCHITECTURE.md are not here")
    return SHARED


@pytest.fixture(scope="session")
def short_drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, Path]:
    """A 2 s simulated drive (sim/drive_log.py: one laser, one camera, CAN odometry) as a
    real MCAP log, and its calibration file; for tests that copy it and damage the copy."""
    from acq.camera import calibfile  # here: most tests need neither
    from acq.sim.drive_log import write_drive_log

    d = tmp_path_factory.mktemp("short_drive")
    truth = write_drive_log(d, 2.0, pattern_at=15.0)
    calib = d / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    return truth, calib
