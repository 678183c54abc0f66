"""What a view of a running recorder shows: one :class:`Snapshot` of its state, whatever
it was read from (the log being written, :mod:`acq.monitor.log_source`; a live server
later), and the problems it shows (:func:`problems`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

__all__ = ["DeviceView", "Snapshot", "Source", "problems"]

STALE_S = 5.0  # a device silent longer than this is down, s


@dataclass(frozen=True)
class DeviceView:
    """One device as the recorder last reported it. ``gap_s``: seconds since its last
    record, as of the snapshot (the recorder's figure plus the age of its report while
    it runs); ``clock_uncertainty_s``: the clock sync's uncertainty (NaN: none yet);
    ``clock_offset_ms``: host minus device clock, ms."""

    name: str
    kind: str
    required: bool
    connected: bool
    rate_hz: float
    received: int
    dropped: int
    disconnects: int
    gap_s: float
    last_event: str
    clock_offset_ms: float
    clock_drift_ppm: float
    clock_uncertainty_s: float


@dataclass(frozen=True)
class Snapshot:
    """A recorder's state. ``writing``: it is running (False: the state is the last it
    wrote); ``closed``: its log was finished (False when not writing: it stopped without
    finishing it, killed); ``status_age_s``: how old its newest report is, s (None:
    it has reported nothing yet); ``disk_minutes_left``: minutes until the disk reaches
    the recorder's reserve at the current write rate (inf: nothing is being written);
    ``write_rate_bps``: bytes per second written (None: not known yet); ``notes``: what
    the source could not tell."""

    source: str
    file: str | None
    file_bytes: int | None
    writing: bool
    closed: bool
    status_age_s: float | None
    uptime_s: float | None
    devices: list[DeviceView] = field(default_factory=list)
    time_base: str = ""
    disk_free_bytes: int | None = None
    disk_minutes_left: float = math.inf
    write_rate_bps: float | None = None
    notes: list[str] = field(default_factory=list)


class Source(Protocol):
    """Where snapshots come from: each call the state as of now."""

    def snapshot(self) -> Snapshot: ...


def problems(snap: Snapshot, stale_s: float = STALE_S) -> list[str]:
    """One line per problem: a device silent longer than ``stale_s``, a required device
    disconnected, a running recorder that has not reported for ``stale_s``. Empty: all
    is well."""
    out = []
    if snap.writing and (snap.status_age_s is None or snap.status_age_s > stale_s):
        age = "nothing yet" if snap.status_age_s is None else f"{snap.status_age_s:.1f} s ago"
        out.append(f"the recorder's last status: {age} (more than {stale_s:g} s)")
    for d in snap.devices:
        if d.gap_s > stale_s:
            how = "" if d.connected else ", disconnected"
            event = f" ({d.last_event})" if d.last_event else ""
            out.append(f"{d.name}: no record for {d.gap_s:.1f} s{how}{event}")
        elif d.required and not d.connected:
            out.append(f"{d.name}: required, disconnected ({d.last_event or 'no answer'})")
    return out
