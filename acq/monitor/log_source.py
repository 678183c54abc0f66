"""Snapshots of a recorder read from the log it writes: its ``/acq/status`` (1 Hz: per
device rate, drops, gap, clock sync, last event) and ``/acq/timebase``, the file's size
and growth, and the disk it is on. The newest file of the newest session is followed
across the recorder's file rolls, and only what each second adds is read
(:mod:`acq.log.tail`)."""

from __future__ import annotations

import math
import shutil
import time
from pathlib import Path
from typing import Any

import yaml

from acq.errors import InputValueError
from acq.log import writer_lock
from acq.log.inputs import session_stem
from acq.log.mcap_magic import LogError
from acq.log.schemas import colouring_of
from acq.log.tail import LogTail
from acq.monitor.snapshot import Snapshot, device_views

__all__ = ["LogSource", "newest_log", "time_base_line"]

TOPICS = ("/acq/status", "/acq/timebase")


def newest_log(path: Path) -> Path:
    """The log to follow for ``path``: a folder's newest ``.mcap`` file (by modification
    time), then the newest part of its session (by part number). InputValueError naming
    ``path`` when there is none."""
    if path.is_dir():
        found = []
        for p in path.glob("*.mcap"):
            try:
                if p.is_file() and not p.name.endswith(".repaired.mcap"):
                    found.append((p.stat().st_mtime_ns, p.name, p))
            except OSError:  # removed while we looked
                continue
        if not found:
            raise InputValueError(f"{path}: no .mcap log in this folder")
        path = max(found)[2]
    elif not path.exists():
        raise InputValueError(f"{path}: no such log or folder")
    stem = session_stem(path)
    if stem is None:
        return path
    parts = [p for p in path.parent.glob(f"{stem}_*.mcap") if session_stem(p) == stem]
    return max(parts, key=lambda p: (len(p.name), p.name), default=path)


class LogSource:
    """:class:`acq.monitor.snapshot.Source` over the log at ``path`` (a file or a folder:
    :func:`newest_log`, looked up again at each snapshot so a new file is followed)."""

    def __init__(self, path: Path) -> None:
        self.given = path
        newest_log(path)  # InputValueError now for a path without a log
        self._tail: LogTail | None = None
        self._status: Any = None
        self._time_base: Any = None
        self._required: set[str] = set()
        self._reserve_bytes = 0.0
        self._config_read = False
        self._notes: list[str] = []

    def snapshot(self) -> Snapshot:
        """The recorder's state as of now."""
        path = newest_log(self.given)
        if self._tail is None or self._tail.path != path:
            try:
                self._tail = LogTail(path, TOPICS)
            except LogError:
                if self._tail is None:
                    raise
                # a file the recorder has just created, its first bytes not yet there:
                # the previous part until the next snapshot
                path = self._tail.path
        for one in self._tail.poll():
            if one.decoded is None:
                continue
            if one.topic == "/acq/status":
                self._status = one.decoded
            else:
                self._time_base = one.decoded
        self._read_config()
        writing = writer_lock.being_written(path)
        try:
            size: int | None = path.stat().st_size
            free: int | None = shutil.disk_usage(path.parent).free
        except OSError:
            size = free = None
        status = self._status
        age = None
        if status is not None and writing:
            age = max(time.monotonic_ns() - _ns(status.timestamp), 0) * 1e-9
        devices = device_views(status, age or 0.0, self._required) if status else []
        rate = self._tail.write_rate() if writing else None
        minutes = math.inf
        if writing and rate and free is not None:
            minutes = max(free - self._reserve_bytes, 0.0) / rate / 60.0
        elif writing and status is not None:  # the recorder's own figure
            minutes = status.disk_minutes_left
        return Snapshot(
            source=f"log {path}",
            file=str(path),
            file_bytes=size,
            writing=writing,
            closed=self._tail.finished,
            status_age_s=age,
            uptime_s=status.uptime_s if status is not None else None,
            devices=devices,
            time_base=time_base_line(self._time_base),
            disk_free_bytes=free,
            disk_minutes_left=minutes,
            write_rate_bps=rate,
            colouring=colouring_of(status) if status is not None else None,
            notes=list(self._notes),
        )

    def close(self) -> None:
        """Nothing to release: the log is opened for each read."""

    def _read_config(self) -> None:
        """The required devices and the disk reserve, from the configuration the log
        holds (its ``config`` metadata record)."""
        assert self._tail is not None
        text = self._tail.metadata.get("config", {}).get("yaml")
        if text is None or self._config_read:
            return
        self._config_read = True
        from acq.record.config import OutputConfig, parse, required_devices

        self._reserve_bytes = OutputConfig().reserve_megabytes * 1e6
        try:
            config = parse(yaml.safe_load(text), "the log's config record")
        except Exception as e:  # an older or foreign configuration: nothing required
            self._notes = [f"required devices unknown: {str(e).splitlines()[0]}"]
            return
        self._required = set(required_devices(config))
        self._reserve_bytes = config.output.reserve_megabytes * 1e6


def _ns(stamp: Any) -> int:
    return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)


def time_base_line(reading: Any) -> str:
    """One line for an ``acq.TimeBase`` reading: whether the host clock is disciplined,
    and by what, with each source's figure ("" without a reading)."""
    if reading is None:
        return ""
    parts = []
    if reading.HasField("chrony"):
        c = reading.chrony
        parts.append(
            f"chrony {c.reference_name or '?'} stratum {c.stratum}, "
            f"offset {c.system_offset_s * 1e6:+.0f} µs"
        )
    if reading.HasField("ptp"):
        parts.append(f"PTP offset {reading.ptp.master_offset_s * 1e6:+.1f} µs")
    if reading.HasField("pps"):
        parts.append(f"PPS {reading.pps.name}")
    if reading.HasField("gnss"):
        parts.append(f"GNSS host-GNSS {reading.gnss.host_minus_gnss_s * 1e3:+.1f} ms")
    if reading.HasField("kernel"):
        k = reading.kernel
        parts.append(f"kernel {k.state or '?'}, est. error {k.esterror_s * 1e6:.0f} µs")
    head = "synchronised" if reading.synchronised else "NOT synchronised"
    return f"host clock {head}" + (f": {'; '.join(parts)}" if parts else "")
