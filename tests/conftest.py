"""Shared fixtures: paths to the real device data in ../shared/data/.

Tests that drive simulated devices, recorders and clocks in real time (frame rates,
stall timeouts, kills at a moment) are marked ``realtime`` in their own modules
(``pytestmark``) or functions: CPU load from other tests makes them miss deadlines that
a real rig would meet, so `make test` runs them alone, then the rest on both cores
(pytest-xdist). The tests mirror the package: tests/<subpackage>/.
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"


@pytest.fixture
def shared_dir() -> Path:
    """../shared/ beside the checkout; tests that need it skip with a reason when absent."""
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent: the real captures and ARCHITECTURE.md are not here")
    return SHARED
