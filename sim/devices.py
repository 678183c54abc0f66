"""Which simulated device speaks for which scanner model, and serving one on a transport."""

from __future__ import annotations

import time
from urllib.parse import urlsplit

from acq.sim.cola_device import ColaDevice
from acq.sim.device_clock import SimClock
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import ScannerModel, model
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import DeviceServer, PtyDeviceServer, SimDevice, TcpDeviceServer

__all__ = ["make_scanner", "parse_listen", "serve_scanner"]


def make_scanner(
    name: str,
    *,
    seed: int = 0,
    drift_ppm: float = 0.0,
    offset_ticks: float = 0.0,
    protocol: str = "cola-b",
) -> tuple[ScannerModel, SimDevice]:
    """The model and a simulated device for it, with its own clock.

    ``protocol`` (cola-a | cola-b) applies to SICK models, which power up in it.
    """
    m = model(name)
    clock = SimClock(
        tick_hz=m.clock_hz,
        wrap_bits=m.clock_bits,
        drift_ppm=drift_ppm,
        offset_ticks=offset_ticks,
        epoch=time.monotonic(),  # powered up now: its clock counts from here
    )
    source = StreetSource(m, seed=seed)
    if m.vendor == "hokuyo":
        return m, ScipDevice(m, source=source, clock=clock)

    return m, ColaDevice(m, source=source, clock=clock, protocol=protocol)


def parse_listen(listen: str) -> tuple[str, int]:
    """(host, port) of a ``tcp://HOST:PORT`` (or ``HOST:PORT``) listen address."""
    parts = urlsplit(listen if "://" in listen else f"tcp://{listen}")
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("tcp", "socket") or port is None:
        raise ValueError(f"--listen {listen!r}: expected tcp://HOST:PORT")
    return parts.hostname or "127.0.0.1", port


def serve_scanner(device: SimDevice, listen: str | None, pty: bool = False) -> DeviceServer:
    """Start serving ``device`` on ``listen`` (tcp://host:port) or on a pty."""
    if pty:
        return PtyDeviceServer(device).start()
    if listen is None:
        return TcpDeviceServer(device).start()
    host, port = parse_listen(listen)
    return TcpDeviceServer(device, host, port).start()
