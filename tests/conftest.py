"""Shared fixtures (paths to the real device data in ../shared/data/) and the
``realtime`` marker.

Tests in :data:`REALTIME_MODULES`, and tests marked ``realtime`` elsewhere, drive
simulated devices, recorders and clocks in real time (frame rates, stall timeouts,
kills at a moment): CPU load from other tests makes them miss deadlines that a real rig
would meet. `make test` runs them alone, then the
rest on both cores (pytest-xdist).
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"

REALTIME_MODULES = frozenset(
    {
        "test_camera_cli",
        "test_camera_opencv",
        "test_can_odometry",
        "test_cola_sim",
        "test_demo",
        "test_mcap_log",
        "test_nmea",
        "test_probe",
        "test_reconnect",
        "test_recorder",
        "test_recorder_vehicle",
        "test_replay",
        "test_scanner_faults",
        "test_scip",
        "test_sim_camera",
        "test_soak",
        "test_transport",
    }
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.stem in REALTIME_MODULES:
            item.add_marker(pytest.mark.realtime)


@pytest.fixture
def shared_dir() -> Path:
    """../shared/ beside the checkout; tests that need it skip with a reason when absent."""
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent: the real captures and ARCHITECTURE.md are not here")
    return SHARED
