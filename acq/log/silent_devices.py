"""The devices of a recording that recorded nothing, or whose records stopped well before
its end: the warning lines of ``acq info`` and of the recorder's closing lines.

Times are host monotonic ns; ``_s`` names are seconds.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["STOPPED_EARLY_S", "DeviceRecords", "SilentDevice", "silent_devices", "why_silent"]

# a device whose last record came this long before the recording's end stopped early (as
# long as the recorder's first warning about a silent device: no device of a rig is
# quiet that long while it works)
STOPPED_EARLY_S = 4.0


@dataclass(frozen=True)
class DeviceRecords:
    """What a recording holds of one configured device."""

    name: str
    kind: str  # scanner | camera | can | gnss
    received: int  # records over the recording
    last_ns: int | None  # its last record, None without one
    why: str = ""  # what its link did last (the last connect error...), "" unknown


@dataclass(frozen=True)
class SilentDevice:
    """A device that recorded nothing (``stopped_before_end_s`` None) or stopped early."""

    name: str
    kind: str
    stopped_before_end_s: float | None
    why: str = ""

    @property
    def recorded_nothing(self) -> bool:
        return self.stopped_before_end_s is None

    def line(self) -> str:
        """One line naming the device, what is missing and why."""
        if self.stopped_before_end_s is None:
            text = f"{self.kind} {self.name} recorded nothing"
        else:
            text = (
                f"{self.kind} {self.name} stopped recording "
                f"{self.stopped_before_end_s:.1f} s before the end"
            )
        return f"{text}: {self.why}" if self.why else text


def why_silent(connected: bool, last_event: str) -> str:
    """Why a device gives no record: not connected and its last connect error, or what
    the connected device did last (``last_event``, "" when nothing happened yet)."""
    if not connected:
        return f"not connected ({last_event or 'no answer yet'})"
    return f"connected, but no record ({last_event})"


def silent_devices(
    devices: Iterable[DeviceRecords], end_ns: int, stopped_early_s: float = STOPPED_EARLY_S
) -> list[SilentDevice]:
    """The devices, in the given order, that recorded nothing, or whose last record came
    more than ``stopped_early_s`` before ``end_ns`` (the recording's end)."""
    out = []
    for d in devices:
        if d.received <= 0 or d.last_ns is None:
            out.append(SilentDevice(d.name, d.kind, None, d.why))
            continue
        before_end_s = (end_ns - d.last_ns) * 1e-9
        if before_end_s > stopped_early_s:
            out.append(SilentDevice(d.name, d.kind, before_end_s, d.why))
    return out
