"""Cameras that deliver frames far faster than configured (a misconfigured or faulty
camera, a stream of tiny frames): the warning lines of ``acq info``; the recorder warns
while it happens (:meth:`acq.record.device_loop.DeviceState.watch_rate`).

Rates are records per second.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

__all__ = ["FAST_FACTOR", "FastDevice", "fast_cameras"]

FAST_FACTOR = 1.5  # over this many times the configured rate: too fast


@dataclass(frozen=True)
class FastDevice:
    """A device whose recorded rate is over :data:`FAST_FACTOR` times its configured one."""

    name: str
    rate_hz: float  # recorded, over the whole recording
    configured_hz: float

    def line(self) -> str:
        times = self.rate_hz / self.configured_hz
        return (
            f"{self.name} recorded {self.rate_hz:.1f} frames/s, {times:.0f} times its"
            f" configured {self.configured_hz:g} fps (a misconfigured or faulty camera)"
        )


def _configured_fps(device: Mapping[str, str]) -> float:
    """The fps in a ``device.<name>`` metadata record's ``format``; 0 when none (unknown)."""
    try:
        fps = json.loads(device.get("format", "{}")).get("fps", 0.0)
    except (ValueError, AttributeError):
        return 0.0  # a garbled record: no rate to compare with
    return float(fps) if isinstance(fps, int | float) and fps > 0 else 0.0


def fast_cameras(
    rates_hz: Iterable[tuple[str, float]], metadata: Mapping[str, Mapping[str, str]]
) -> list[FastDevice]:
    """The cameras of ``metadata`` (``device.<name>`` records) whose image topic
    ``/<name>/image/compressed`` has a rate in ``rates_hz`` (topic, Hz) over
    :data:`FAST_FACTOR` times their configured fps."""
    rates = dict(rates_hz)
    out = []
    for key, device in metadata.items():
        name = key.removeprefix("device.")
        rate = rates.get(f"/{name}/image/compressed")
        fps = _configured_fps(device) if key.startswith("device.") else 0.0
        if rate is not None and fps > 0 and rate > FAST_FACTOR * fps:
            out.append(FastDevice(name, rate, fps))
    return out
