"""Fixtures of the recorder's tests: a simulated UTM-30LX speaking SCIP on TCP; a
simulated rig (the scanner and a fisheye camera)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from tests.sim_rig import Rig


@pytest.fixture(scope="module")
def scanner() -> Iterator[TcpDeviceServer]:
    """A simulated UTM-30LX on 127.0.0.1 (in this process), one per test module."""
    server = TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start()
    try:
        yield server
    finally:
        server.close()


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    """The simulated rig of :mod:`tests.sim_rig` (a UTM-30LX, one camera), warmed up."""
    r = Rig()
    try:
        yield r.warm_up()
    finally:
        r.close()
