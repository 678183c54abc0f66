"""What ``acq info`` tells about logs: per channel counts, rates and gaps, per device
drops, disconnects and clock-sync quality, frames of an unexpected size, whether the file
was closed, the host clock's time base (``/acq/timebase``), as tables or JSON.

All times are integer nanoseconds of the host clock (MCAP ``log_time``) unless a name
says otherwise (``_s`` seconds, ``_ms`` milliseconds, ``_hz`` hertz).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, Message, Metadata, Schema

from acq import json_text
from acq.log import schemas
from acq.log.device_timing import (
    GNSS_TIMING,
    DeviceSync,
    DeviceTiming,
    GnssStamping,
    device_sync,
    drift_text,
    field_of,
    formatted,
    gnss_fix_timing,
    gnss_stamping,
    gnss_stamping_lines,
    host_clock_lines,
    latency_line,
)
from acq.log.fast_devices import FastDevice, fast_cameras
from acq.log.reader import LogReader, quiet
from acq.log.silent_devices import DeviceRecords, SilentDevice, silent_devices, why_silent
from acq.log.timebase import MONOTONIC, TimeBase
from acq.time.host_clock import HostClock
from acq.time.host_clock_summary import HostClockSummary, summarise_host_clock
from acq.time.utc import utc_ns

__all__ = [
    "ChannelInfo",
    "DeviceSync",
    "GnssStamping",
    "LogInfo",
    "format_info",
    "gaps",
    "info",
    "info_many",
]

_SLOW_PERIOD_S = 0.5  # topics at 2 Hz or slower (status, clock): gap = period + 0.5 s

# --- results ------------------------------------------------------------------------


@dataclass(frozen=True)
class ChannelInfo:
    """One topic of a log.

    ``rate_hz`` is ``(count - 1) / (last_ns - first_ns)``; ``max_gap_s`` the longest
    interval between consecutive messages, seconds; ``gaps`` the intervals
    ``(start_ns, end_ns)`` longer than 3x the median period, or, for topics at 2 Hz or
    slower (1 Hz status and clock), longer than the median period + 0.5 s (one missed
    beat). ``bytes`` is the sum of the message payloads. ``undecodable``: its messages
    that cannot be decoded (a garbled schema or payload), which every command skips.
    """

    topic: str
    schema: str
    count: int
    first_ns: int
    last_ns: int
    rate_hz: float
    max_gap_s: float
    gaps: list[tuple[int, int]]
    bytes: int
    undecodable: int = 0


@dataclass(frozen=True)
class LogInfo:
    """Summary of one log file, or (``len(files) > 1``) of a session of split files.

    ``closed`` is True when the footer and the summary are present and valid.
    ``bytes_read`` is where reading stopped (the end of the last good record; the file
    size when closed). ``readable_until_ns`` is the latest ``log_time`` read.
    Times are host monotonic ns, as the reader gives them. ``start_realtime_ns`` is UTC
    ns of ``start_ns``: as the file has it for a UTC log (``time_base``), else from the
    ``/acq/clock`` pairs.
    ``drops`` and ``disconnects`` come from the last ``/acq/status`` (the counters of
    ``/acq/timing`` for devices it does not list). ``problem`` says, in one line, what is
    wrong with the file (not closed, corrupt chunks), or is None. ``odd_size``: per
    camera, the frames of another size than expected, recorded and flagged (from the last
    ``/acq/status``; an older log's status has no such count: none listed).
    ``host_clock``: the ``/acq/timebase`` readings summarised, None in a log without.
    ``writing``: a file of it was being written by a live recorder when read.
    ``silent``: the devices of the last ``/acq/status`` (every configured one) that
    recorded nothing, or stopped well before the end (:mod:`acq.log.silent_devices`).
    ``fast``: the cameras that recorded far faster than configured
    (:mod:`acq.log.fast_devices`).
    """

    path: Path
    files: tuple[Path, ...]
    closed: bool
    bytes_read: int
    bytes_total: int
    readable_until_ns: int | None
    messages: int
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    start_realtime_ns: int | None
    channels: list[ChannelInfo]
    devices: list[DeviceSync]
    drops: dict[str, int]
    disconnects: dict[str, int]
    metadata: dict[str, dict[str, str]]
    attachments: int
    problem: str | None
    odd_size: dict[str, int] = field(default_factory=dict)
    time_base: TimeBase = MONOTONIC
    gnss_stamping: GnssStamping | None = None  # None: no GNSS fixes
    host_clock: HostClockSummary | None = None
    writing: bool = False
    silent: list[SilentDevice] = field(default_factory=list)
    fast: list[FastDevice] = field(default_factory=list)


# --- summarising --------------------------------------------------------------------


def gaps(times: list[int]) -> tuple[float, list[tuple[int, int]]]:
    """(max interval s, gaps) of sorted times, ns; gaps as in :class:`ChannelInfo` (the
    rule ``acq info`` applies to a topic's log times)."""
    if len(times) < 2:
        return 0.0, []
    t = np.asarray(times, dtype=np.int64)
    d = np.diff(t)
    # the pace: the median interval, ignoring those far below the mean (records logged
    # in bursts, as several CAN messages sent together, would otherwise set it)
    positive = d[d > max((t[-1] - t[0]) / (len(t) - 1) / 10, 0)]
    if positive.size == 0:
        return 0.0, []
    period = float(np.median(positive))
    if period >= _SLOW_PERIOD_S * 1e9:
        threshold = period + _SLOW_PERIOD_S * 1e9
    else:
        threshold = 3.0 * period
    idx = np.flatnonzero(d > threshold)
    gaps = [(int(t[i]), int(t[i + 1])) for i in idx]
    return float(d.max()) / 1e9, gaps


@dataclass
class _Acc:
    """Running totals over the messages of one file or of a session."""

    times: dict[str, list[int]] = field(default_factory=dict)
    schemas: dict[str, str] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)
    timing: dict[str, DeviceTiming] = field(default_factory=dict)
    status: Any = None
    status_ns: int = 0  # log time of the last status
    clock: list[tuple[int, int]] = field(default_factory=list)  # (monotonic, realtime) ns
    host_clock: list[HostClock] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: int = 0
    gnss: list[tuple[int, int, str]] = field(default_factory=list)  # recv ns, UTC µs, source
    undecodable: dict[str, int] = field(default_factory=dict)  # by topic

    def add_undecodable(self, counts: dict[str, int]) -> None:
        """A pass's messages that did not decode, by topic."""
        for topic, n in counts.items():
            self.undecodable[topic] = self.undecodable.get(topic, 0) + n

    def add(self, schema: Schema | None, channel: Channel, message: Message, decoded: Any) -> None:
        topic = channel.topic
        self.times.setdefault(topic, []).append(message.log_time)
        self.schemas.setdefault(topic, schema.name if schema is not None else "")
        self.sizes[topic] = self.sizes.get(topic, 0) + len(message.data)
        if decoded is None:
            return
        if topic.startswith("/acq/timing/"):
            self.timing.setdefault(topic.removeprefix("/acq/timing/"), DeviceTiming()).add(decoded)
            if topic == GNSS_TIMING:
                self.gnss.append(gnss_fix_timing(decoded))
        elif topic == "/acq/status":
            self.status, self.status_ns = decoded, message.log_time
        elif topic == "/acq/clock":
            realtime, monotonic = (
                field_of(decoded, "realtime_ns"),
                field_of(decoded, "monotonic_ns"),
            )
            if realtime and monotonic:
                self.clock.append((int(monotonic), int(realtime)))
        elif topic == "/acq/timebase" and field_of(decoded, "absent") is not None:
            self.host_clock.append(schemas.host_clock_of(decoded))

    def add_metadata(self, record: Metadata) -> None:
        self.metadata[record.name] = dict(record.metadata)  # the last of a name wins

    def channels(self) -> list[ChannelInfo]:
        out = []
        for topic in sorted(self.times):
            times = sorted(self.times[topic])
            span = times[-1] - times[0]
            max_gap_s, found = gaps(times)
            out.append(
                ChannelInfo(
                    topic=topic,
                    schema=self.schemas[topic],
                    count=len(times),
                    first_ns=times[0],
                    last_ns=times[-1],
                    rate_hz=(len(times) - 1) / (span / 1e9) if span > 0 else 0.0,
                    max_gap_s=max_gap_s,
                    gaps=found,
                    bytes=self.sizes[topic],
                    undecodable=self.undecodable.get(topic, 0),
                )
            )
        return out

    def odd_size(self) -> dict[str, int]:
        """Per device of the last status: its frames of an unexpected size, when any."""
        out: dict[str, int] = {}
        status_devices = field_of(self.status, "devices") if self.status is not None else None
        for dev in status_devices or []:
            name, n = field_of(dev, "name"), field_of(dev, "odd_size")
            if name and n:
                out[str(name)] = int(n)
        return out

    def silent(self, end_ns: int | None) -> list[SilentDevice]:
        """The devices of the last status that recorded nothing or stopped early."""
        status_devices = field_of(self.status, "devices") if self.status is not None else None
        if end_ns is None or not status_devices:
            return []
        records = []
        for dev in status_devices:
            name, received = field_of(dev, "name"), field_of(dev, "received")
            if not name or received is None:
                continue  # a status from before these fields
            gap_s = float(field_of(dev, "gap_s") or 0.0)
            records.append(
                DeviceRecords(
                    name=str(name),
                    kind=str(field_of(dev, "kind") or "device"),
                    received=int(received),
                    last_ns=self.status_ns - round(gap_s * 1e9) if received else None,
                    why=why_silent(
                        bool(field_of(dev, "connected")), str(field_of(dev, "last_event") or "")
                    ),
                )
            )
        return silent_devices(records, end_ns)

    def devices(self) -> tuple[list[DeviceSync], dict[str, int], dict[str, int]]:
        drops: dict[str, int] = {}
        disconnects: dict[str, int] = {}
        listed: list[str] = []
        status_devices = field_of(self.status, "devices") if self.status is not None else None
        for dev in status_devices or []:
            name = str(field_of(dev, "name") or "")
            if not name:
                continue
            listed.append(name)
            dropped, disc = field_of(dev, "dropped"), field_of(dev, "disconnects")
            if dropped is not None:
                drops[name] = int(dropped)
            if disc is not None:
                disconnects[name] = int(disc)
        for name, t in self.timing.items():
            if name not in drops and t.dropped is not None:
                drops[name] = t.dropped
        clock = self.metadata.get("clock", {})
        names = listed + [n for n in sorted(self.timing) if n not in listed]
        devices = [device_sync(n, self.timing.get(n, DeviceTiming()), clock) for n in names]
        return devices, drops, disconnects


def _decode_topic(topic: str) -> bool:
    return topic in ("/acq/status", "/acq/clock", "/acq/timebase") or topic.startswith(
        "/acq/timing/"
    )


def _result(
    acc: _Acc,
    path: Path,
    files: tuple[Path, ...],
    closed: bool,
    bytes_read: int,
    bytes_total: int,
    problem: str | None,
    time_base: TimeBase,
) -> LogInfo:
    channels = acc.channels()
    devices, drops, disconnects = acc.devices()
    start = min((c.first_ns for c in channels), default=None)
    end = max((c.last_ns for c in channels), default=None)
    if start is None:
        start_utc = None
    elif time_base.utc:
        start_utc = time_base.to_log(start)
    elif acc.clock:
        start_utc = int(utc_ns(start, acc.clock))
    else:
        start_utc = None
    return LogInfo(
        path=path,
        files=files,
        closed=closed,
        bytes_read=bytes_read,
        bytes_total=bytes_total,
        readable_until_ns=end,
        messages=sum(c.count for c in channels),
        start_ns=start,
        end_ns=end,
        duration_s=(end - start) / 1e9 if start is not None and end is not None else 0.0,
        start_realtime_ns=start_utc,
        channels=channels,
        devices=devices,
        drops=drops,
        disconnects=disconnects,
        metadata=acc.metadata,
        attachments=acc.attachments,
        problem=problem,
        odd_size=acc.odd_size(),
        time_base=time_base,
        gnss_stamping=gnss_stamping(acc.gnss, acc.clock, time_base),
        host_clock=summarise_host_clock(acc.host_clock) if acc.host_clock else None,
        silent=acc.silent(end),
        fast=fast_cameras(((c.topic, c.rate_hz) for c in channels), acc.metadata),
    )


def info(path: str | os.PathLike[str]) -> LogInfo:
    """Summary of one log; reads everything before a cut when the file was not closed."""
    return info_many([path])[0]


def info_many(paths: Iterable[str | os.PathLike[str]]) -> list[LogInfo]:
    """One :class:`LogInfo` per file, in the given order, and, for more than one file
    (the split files of a session), a last one for the whole session: its ``files`` lists
    them, its ``path`` is their common directory, its channels and gaps span them all.
    Raises :class:`acq.log.reader.LogError` for a file that is missing or not MCAP."""
    files = [Path(p) for p in paths]
    readers = [LogReader(p) for p in files]  # every LogError before any long read
    session = _Acc()
    out: list[LogInfo] = []
    for reader in readers:
        acc = _Acc()
        with quiet():  # the damage is in the summary's problem
            for schema, channel, message in reader.messages():
                # every message is decoded, to count those that do not decode
                decoded = reader.decode(schema, channel, message)
                if not _decode_topic(channel.topic):
                    decoded = None
                acc.add(schema, channel, message, decoded)
                session.add(schema, channel, message, decoded)
        acc.add_undecodable(reader.undecodable)
        session.add_undecodable(reader.undecodable)
        for record in reader.metadata:
            acc.add_metadata(record)
            session.add_metadata(record)
        acc.attachments += reader.attachments
        session.attachments += reader.attachments
        one = _result(
            acc,
            reader.path,
            (reader.path,),
            reader.closed,
            reader.bytes_read,
            reader.size,
            reader.problem(),
            reader.time_base,
        )
        out.append(dataclasses.replace(one, writing=reader.writing))
    if len(out) > 1:
        problems = [f"{i.path.name}: {i.problem}" for i in out if i.problem]
        out.append(
            _result(
                session,
                Path(os.path.commonpath([p.resolve() for p in files])),
                tuple(files),
                all(i.closed for i in out),
                sum(i.bytes_read for i in out),
                sum(i.bytes_total for i in out),
                " | ".join(problems) or None,
                readers[-1].time_base,
            )
        )
        out[-1] = dataclasses.replace(out[-1], writing=any(i.writing for i in out[:-1]))
    return out


# --- output -------------------------------------------------------------------------


def _bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GiB"


def _utc(ns: int) -> str:
    return datetime.fromtimestamp(ns / 1e9, tz=UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def _meta_item(key: str, value: str) -> str:
    short = value.strip()
    if len(short) <= 32 and "\n" not in short:
        return f"{key}={short}"
    return f"{key} ({len(value.encode())} B)"


def _format_one(i: LogInfo) -> list[str]:
    title = str(i.path) if len(i.files) == 1 else f"session {i.path} ({len(i.files)} files)"
    state = "closed" if i.closed else "BEING WRITTEN" if i.writing else "NOT CLOSED"
    lines = [f"{title}: {state}"]
    if i.problem:
        lines.append(f"  warning: {i.problem}")
    bag = i.metadata.get("acq", {}).get("source") == "rosbag2"  # acq.log.rosbag_source
    if i.start_ns is not None and i.end_ns is not None:
        where = f"monotonic {i.start_ns / 1e9:.3f} s .. {i.end_ns / 1e9:.3f} s, "
        if bag:  # its stamps are UTC: no host monotonic clock to name
            where = ""
        if i.start_realtime_ns is not None:
            where += f"from {_utc(i.start_realtime_ns)}"
        lines.append(f"  span      {i.duration_s:.3f} s ({where.removesuffix(', ')})")
    if bag:
        clock = "a ROS 2 bag (rosbag2): its stamps taken as UTC; ROS topics read as acq's"
    elif i.time_base.utc:
        clock = (
            f"UTC (host monotonic + {i.time_base.utc_offset_ns / 1e9:.6f} s, fixed at the"
            " session start); acq.* messages host monotonic"
        )
    else:
        clock = "host monotonic (a log from before acq's UTC logs); UTC from /acq/clock"
    lines.append(f"  clock     {clock}")
    lines.extend(host_clock_lines(i.host_clock))
    lines.append(
        f"  messages  {i.messages} in {len(i.channels)} channels, attachments {i.attachments};"
        f" read {_bytes(i.bytes_read)} of {_bytes(i.bytes_total)}"
    )
    for name, data in i.metadata.items():
        keys = ", ".join(_meta_item(k, v) for k, v in data.items())
        lines.append(f"  metadata  {name}: {keys}")
    if i.channels:
        width = max(24, *(len(c.topic) for c in i.channels))
        swidth = max(12, *(len(c.schema) for c in i.channels))
        lines.append(
            f"  {'topic':<{width}}  {'schema':<{swidth}}  {'count':>7}  {'rate Hz':>8}"
            f"  {'max gap s':>9}  {'gaps':>4}  {'size':>10}"
        )
        for c in i.channels:
            lines.append(
                f"  {c.topic:<{width}}  {c.schema:<{swidth}}  {c.count:>7}  {c.rate_hz:>8.2f}"
                f"  {c.max_gap_s:>9.3f}  {len(c.gaps):>4}  {_bytes(c.bytes):>10}"
            )
        start = i.start_ns or 0
        for c in i.channels:
            if c.gaps:
                shown = ", ".join(
                    f"{(a - start) / 1e9:.3f}..{(b - start) / 1e9:.3f} s" for a, b in c.gaps[:5]
                )
                more = f" and {len(c.gaps) - 5} more" if len(c.gaps) > 5 else ""
                lines.append(f"  gaps on {c.topic} (s from start): {shown}{more}")
        bad = [f"{c.topic} {c.undecodable} of {c.count}" for c in i.channels if c.undecodable]
        if bad:
            lines.append(
                "  warning: messages that cannot be decoded (a garbled schema or payload;"
                f" every command skips them): {', '.join(bad)}"
            )
    names = [d.name for d in i.devices] + sorted(
        (set(i.drops) | set(i.disconnects)) - {d.name for d in i.devices}
    )
    if names:
        by_name = {d.name: d for d in i.devices}
        lines.append(
            f"  {'device':<12}  {'drops':>6}  {'disconn':>7}  {'timing':>7}  {'epochs':>6}"
            f"  {'drift ppm (95 %)':>20}  {'offset spread ms':>16}  {'uncert. s med/max':>19}"
            f"  {'recv-stamp ms p50/p95/max':>25}"
        )
        for name in names:
            d = by_name.get(name)
            drops = str(i.drops.get(name, "-"))
            disc = str(i.disconnects.get(name, "-"))
            if d is None:
                lines.append(f"  {name:<12}  {drops:>6}  {disc:>7}")
                continue
            unc = (
                f"{formatted(d.uncertainty_s_median, '.2e')}"
                f"/{formatted(d.uncertainty_s_max, '.2e')}"
            )
            res = (
                f"{formatted(d.residual_ms_p50, '.2f')}/{formatted(d.residual_ms_p95, '.2f')}"
                f"/{formatted(d.residual_ms_max, '.2f')}"
            )
            lines.append(
                f"  {name:<12}  {drops:>6}  {disc:>7}  {d.records:>7}  {d.epochs:>6}"
                f"  {drift_text(d):>20}  {formatted(d.offset_spread_ms, '.3f'):>16}"
                f"  {unc:>19}  {res:>25}"
            )
        lines.extend(latency_line(d) for d in i.devices if d.latency_s is not None)
    if i.gnss_stamping is not None:
        lines.extend(gnss_stamping_lines(i.gnss_stamping))
    if i.odd_size:
        counts = ", ".join(f"{name} {n}" for name, n in i.odd_size.items())
        lines.append(f"  warning: frames of an unexpected size (recorded, flagged): {counts}")
    lines.extend(f"  warning: {s.line()}" for s in i.silent)
    lines.extend(f"  warning: {f.line()}" for f in i.fast)
    return lines


def _jsonable(i: LogInfo) -> dict[str, Any]:
    d = dataclasses.asdict(i)
    d["path"] = str(i.path)
    d["files"] = [str(p) for p in i.files]
    for c in d["channels"]:
        c["gaps"] = [list(g) for g in c["gaps"]]
    return d


def format_info(infos: LogInfo | Iterable[LogInfo], *, json: bool = False) -> str:
    """Human-readable tables (channels, devices, the "not closed" warning) or, with
    ``json=True``, a JSON list with one object per :class:`LogInfo`."""
    items = [infos] if isinstance(infos, LogInfo) else list(infos)
    if json:
        return json_text.dumps([_jsonable(i) for i in items], what="acq info --json")
    blocks = ["\n".join(_format_one(i)) for i in items]
    return "\n\n".join(blocks)
