"""A simulated device clock: its own offset, drift, tick rate and counter width."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["SimClock"]


@dataclass
class SimClock:
    """Device ticks as a function of true time ``t`` (s, the host's monotonic clock).

    ``ticks(t) = floor((t - epoch) * (1 + drift_ppm·1e-6) * tick_hz + offset_ticks)``
    modulo ``2**wrap_bits``. A reboot restarts the counter at 0 (a new epoch).
    """

    tick_hz: float = 1000.0
    wrap_bits: int = 24
    drift_ppm: float = 0.0
    offset_ticks: float = 0.0
    epoch: float = 0.0  # true time at which the counter read offset_ticks
    reboots: int = field(default=0)

    def ticks(self, t: float) -> int:
        raw = (t - self.epoch) * (1.0 + self.drift_ppm * 1e-6) * self.tick_hz + self.offset_ticks
        return int(raw // 1) % (1 << self.wrap_bits)

    def reboot(self, t: float) -> None:
        """The device restarts at true time t: the counter starts again from 0."""
        self.epoch = t
        self.offset_ticks = 0.0
        self.reboots += 1
