"""What a view of a running recorder shows: one :class:`Snapshot` of its state, whatever
it was read from (the log being written, :mod:`acq.monitor.log_source`; its live server,
:mod:`acq.monitor.live_source`), built from the recorder's ``acq.Status``
(:func:`device_views`), and the problems it shows (:func:`problems`)."""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, Protocol

from acq.log.schemas import ColouringStatus

__all__ = ["DeviceView", "Snapshot", "Source", "device_views", "problems"]

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
    ``write_rate_bps``: bytes per second written (None: not known yet); ``colouring``:
    the live colourer's figures (None: the recorder colours nothing live); ``notes``:
    what the source could not tell."""

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
    colouring: ColouringStatus | None = None
    notes: list[str] = field(default_factory=list)


class Source(Protocol):
    """Where snapshots come from: each call the state as of now; :meth:`close` when done."""

    def snapshot(self) -> Snapshot: ...

    def close(self) -> None: ...


def device_views(status: Any, age_s: float, required: Collection[str] = ()) -> list[DeviceView]:
    """The devices of a decoded ``acq.Status`` as of ``age_s`` seconds after it was
    written; a device is required when the status says so or it is in ``required``."""
    return [
        DeviceView(
            name=d.name,
            kind=d.kind,
            # the status's own flag; an older log's has none
            required=getattr(d, "required", False) or d.name in required,
            connected=d.connected,
            rate_hz=d.rate_hz,
            received=d.received,
            dropped=d.dropped,
            disconnects=d.disconnects,
            gap_s=d.gap_s + age_s,
            last_event=d.last_event,
            clock_offset_ms=d.clock_offset_ns * 1e-6,
            clock_drift_ppm=d.clock_drift_ppm,
            clock_uncertainty_s=d.clock_uncertainty_s,
        )
        for d in status.devices
    ]


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
