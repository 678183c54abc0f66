"""Shared fixtures: paths to the real device data in ../shared/data/.

Tests that drive simulated devices, recorders and clocks in real time (frame rates,
stall timeouts, kills at a moment) are marked ``realtime`` in their own modules
(``pytestmark``) or functions: CPU load from other tests makes them miss deadlines that
a real rig would meet, so `make test` runs them alone, then the rest on both cores
(pytest-xdist). The tests mirror the package: tests/<subpackage>/.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

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


def once_per_run(
    tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], dict[str, Any]]
) -> tuple[Path, dict[str, Any]]:
    """``make(folder)`` run once in a whole test run, however many xdist workers ask (a
    module fixture runs once per worker that runs its tests): the first to ask makes the
    folder ``name`` and its JSON result under a lock, the others wait and read them."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the workers' temporary folders share this parent
    folder, done = root / name, root / f"{name}.json"
    with (root / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)  # a failed attempt's
            folder.mkdir()
            done.write_text(json.dumps(make(folder)))
        result: dict[str, Any] = json.loads(done.read_text())
    return folder, result
