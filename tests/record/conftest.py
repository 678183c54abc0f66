"""Fixtures of the recorder's tests: a simulated UTM-30LX speaking SCIP on TCP."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer


@pytest.fixture(scope="module")
def scanner() -> Iterator[TcpDeviceServer]:
    """A simulated UTM-30LX on 127.0.0.1 (in this process), one per test module."""
    server = TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start()
    try:
        yield server
    finally:
        server.close()
