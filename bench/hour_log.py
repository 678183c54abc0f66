"""A long drive synthesised from a short acq log: copy after copy of it, each shifted in
time, so that the result reads as one continuous drive (``acq info``, ``acq colorize``,
``acq replay``), for measuring what grows with a drive's length (memory, time).

``python bench/hour_log.py SRC.mcap OUT.mcap --minutes 60`` writes OUT (one file; with
``--split``, OUT is a new folder holding a session of files rolled as the source's
recorder rolled them: its configuration's ``output.split_minutes`` and
``split_megabytes``, by default 10 minutes or 2048 MB) and prints one JSON line: copies,
messages, bytes, wall and CPU seconds, peak memory. :func:`write_hour_log` does the same
for other benches.

How a copy is made (copy ``k``, times shifted by ``k * period_ns``):

- The copies tile a window of the source, ``[t0, t0 + period)`` by the messages' stamps
  (``publish_time``), in which every channel at over 2 Hz records; ``t0`` lies half a
  scan between two scans (a scanner's stamps come from its clock: no scan falls in two
  copies or in none). The first copy keeps the source's start before the window (the
  latched calibration and transforms, the first status); the last copy ends where the
  length asked ends. ``period`` is whole periods of the scanner, in whole ms (its
  ticks shift by whole ticks: it goes on at its pace across a junction), as near as can
  be to whole periods of the 1 Hz status and clock pairs; every other channel's interval
  across a junction is within two of its periods (never a gap to ``acq info``).
- Every time is shifted: MCAP ``log_time`` and ``publish_time``, every protobuf
  ``Timestamp`` (Foxglove stamps, ``acq.*`` timestamps), the host times of the ``acq.*``
  messages (``recv_ns``, ``stamp_ns``, the ``acq.Clock`` and ``acq.TimeBase`` pairs,
  a CAN interface's ``wall_ns``, chrony's and PPS's UTC seconds, ``uptime_s``), a GNSS
  fix's UTC time (``utc``, ``utc_s`` and its µs ticks), the device ticks (``device_ticks``
  modulo the device's counter width, ``unwrapped_tick``) and the scanner's tick inside a
  SCIP telegram (``/<scanner>/raw``; a replay of the long log serves a scanner clock that
  runs on). A CoLa (SICK) telegram's own time field is left as recorded.
- Counters go on: sequence numbers, received and dropped counts (``acq.Timing``,
  ``acq.RawTelegram``, each device of ``acq.Status``, PPS sequences) grow by what the
  window adds to them, so a copy's frames are no replay of the first one's.
- The vehicle's odometry is speeds and yaw rates: dead reckoned, the path goes on from
  where the last copy left it, and a coloured cloud grows along it.
- Metadata are written once, from the source's last records; the ``clock`` record's
  realtime/monotonic pair is moved to the new end, the ``time_base`` record summarises
  the readings written. The writer is the recorder's (:class:`acq.log.LogWriter`: zstd,
  8 MiB chunks, a new session name), fed message by message: nothing is held but the
  source (a short log, at most :data:`MAX_SOURCE_BYTES`).
"""

from __future__ import annotations

import argparse
import errno
import json
import math
import os
import resource
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.reader import make_reader

from acq.atomic_write import discard, temporary_beside
from acq.errors import InputError
from acq.log import LogError, LogReader, LogWriter, read_metadata
from acq.log.acq_proto import TimeBaseMsg, TimingMsg
from acq.log.reader import quiet
from acq.log.schemas import Schema, host_clock_of, message_class
from acq.log.stamp_shift import shift_stamps
from acq.log.timebase import TimeBase
from acq.record.config import OutputConfig
from acq.time.host_clock_summary import HostClockTally

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script or loaded by path
from shifted_copy import CounterKey, Shifter, Ticks, counter_steps, device_ticks

__all__ = ["HourLogError", "write_hour_log"]

_FAST_HZ = 2.0  # channels faster than this must record over the whole window
MAX_SOURCE_BYTES = 1 << 30  # the source is held in memory: a short log


class HourLogError(InputError):
    """A source that cannot be repeated, or an output that cannot be written."""


@dataclass(frozen=True)
class _Source:
    """The source log held in memory: per message (topic, log ns, publish ns, bytes), host
    monotonic ns, in file order; and what the copies need to know of it."""

    messages: list[tuple[str, int, int, bytes]]
    schemas: dict[str, Schema]  # by topic
    channel_metadata: dict[str, dict[str, str]]
    metadata: dict[str, dict[str, str]]
    time_base: TimeBase
    profile: str


@dataclass(frozen=True)
class _Plan:
    """Which source messages each copy takes (indexes into the source) and by how much
    each copy moves: ``period_ns`` of time, ``steps`` of every counter."""

    head: list[int]  # the first copy
    middle: list[int]  # the copies between
    tail: list[int]  # the last copy
    copies: int
    period_ns: int
    steps: dict[str, dict[CounterKey, int]]  # by topic

    def indexes(self, k: int) -> list[int]:
        if self.copies == 1:
            return sorted(set(self.head) | set(self.tail))
        return self.head if k == 0 else self.tail if k == self.copies - 1 else self.middle


def _read_source(src: Path) -> _Source:
    try:
        reader = LogReader(src, progress=False)
        if reader.size > MAX_SOURCE_BYTES:
            raise HourLogError(
                f"{src}: {reader.size / 1e9:.1f} GB: repeat a short log (at most "
                f"{MAX_SOURCE_BYTES / 1e9:.1f} GB, it is held in memory)"
            )
        messages = []
        schemas: dict[str, Schema] = {}
        channel_metadata: dict[str, dict[str, str]] = {}
        with quiet():  # the damage is said in one line below
            read = list(reader.messages())
            metadata = read_metadata(src)
        for schema, channel, message in read:
            topic = channel.topic
            if topic not in schemas:
                if schema is None:
                    raise HourLogError(f"{src}: channel {topic} has no schema")
                schemas[topic] = Schema(schema.name, schema.encoding, bytes(schema.data))
                channel_metadata[topic] = dict(channel.metadata)
            messages.append((topic, message.log_time, message.publish_time, bytes(message.data)))
    except LogError as e:
        raise HourLogError(str(e)) from None
    if not reader.closed:
        raise HourLogError(f"{src}: not a closed log ({reader.problem()}): repeat a whole one")
    if not messages:
        raise HourLogError(f"{src}: no messages to repeat")
    for topic, known in schemas.items():
        try:
            message_class(known.name)
        except KeyError:
            raise HourLogError(
                f"{src}: channel {topic} has schema {known.name!r}, not one of acq's: "
                "its times cannot be shifted"
            ) from None
    with src.open("rb") as f:  # the header's profile, to write the same
        profile = make_reader(f).get_header().profile
    return _Source(messages, schemas, channel_metadata, metadata, reader.time_base, profile)


def _median_period_ns(times: Sequence[int]) -> float:
    d = np.diff(np.asarray(times, dtype=np.int64))
    d = d[d > 0]
    return float(np.median(d)) if d.size else math.inf


def _plan(source: _Source, minutes: float, ticks: dict[str, Ticks]) -> _Plan:
    """The window the copies repeat and how many copies make ``minutes`` of log time.

    A message belongs to the window by its stamp (``publish_time``): a scanner's come
    from its clock, steady where receipts are not, so with the window's ends half a scan
    between two scans no scan is in two copies, and none in none."""
    stamps: dict[str, list[int]] = {}
    for topic, _log, pub, _data in source.messages:
        stamps.setdefault(topic, []).append(pub)
    fast = {t: v for t, v in stamps.items() if _median_period_ns(v) < 1e9 / _FAST_HZ}
    if not fast:
        raise HourLogError("the source has no channel at over 2 Hz to repeat")
    shortest = min(_median_period_ns(v) for v in fast.values())
    t0: float = max(v[0] for v in fast.values())
    room: float = min(v[-1] for v in fast.values()) - t0 + shortest  # where the window may end
    scans = [t for t in fast if source.schemas[t].name == "foxglove.LaserScan"]
    pace = shortest
    if scans:  # the scanner's period, and the window's start half a scan after one
        v = stamps[scans[0]]
        pace = _scan_period_ns(source, scans[0][1:].removesuffix("/scan"), ticks) or (
            (v[-1] - v[0]) / (len(v) - 1)
        )
        later = (v[0] - t0 + pace / 2) % pace
        t0, room = t0 + later, room - later
    # whole periods of the scanner (its ticks run on at its pace), as near as can be to
    # whole periods of the slow channels (the 1 Hz status and clock pairs, where a beat
    # missed is half a period late); a faster channel's interval across a junction is
    # within two of its periods (cameras at their own rates cannot all fit whole)
    means = [(v[-1] - v[0]) / (len(v) - 1) for v in stamps.values() if len(v) >= 3]
    means = [p for p in means if p >= 1e9 / _FAST_HZ]
    most = math.floor(room / pace)
    periods, worst = most, math.inf
    for n in range(most, max(most // 2, 1) - 1, -1):
        off = max((abs(n * pace / p - round(n * pace / p)) for p in means if p <= n * pace),
                  default=0.0)  # fmt: skip
        if off < worst:
            periods, worst = n, off
        if off <= 0.05:  # within 5 % of a period of each: the longest such window
            break
    period_ns = round(periods * pace / 1e6) * 1_000_000
    if period_ns <= 0:
        raise HourLogError("the source's devices do not record at the same time: no window")
    for _ in range(100):  # a scan received late at the end, one early at the start: later
        middle = [i for i, m in enumerate(source.messages) if t0 <= m[2] < t0 + period_ns]
        if _steady(source, middle, period_ns):
            break
        t0 += pace
        if t0 + period_ns > min(v[-1] for v in fast.values()) + shortest:
            break
    else:
        middle = []
    if not middle or not _steady(source, middle, period_ns):
        raise HourLogError("no window whose copies keep every channel in time order")
    start = min(m[1] for m in source.messages)
    end = start + round(minutes * 60e9)
    # the last copy ends inside the window, where every channel records: here (source time)
    copies = max(math.ceil((end - t0) / period_ns), 1)
    cut = end - (copies - 1) * period_ns
    head, tail = [], []
    for i, (_topic, log_ns, pub, _data) in enumerate(source.messages):
        if pub < t0 + period_ns and (copies > 1 or log_ns <= cut):
            head.append(i)
        if t0 <= pub and log_ns <= cut:
            tail.append(i)
    inside = set(middle)
    steps = counter_steps(
        (topic, source.schemas[topic].name, data, i in inside)
        for i, (topic, _log, _pub, data) in enumerate(source.messages)
    )
    return _Plan(head, middle, tail, copies, period_ns, steps)


def _scan_period_ns(source: _Source, name: str, ticks: dict[str, Ticks]) -> float | None:
    """A scanner's period by its own clock (the median step of its ticks), ns; None
    without ticks."""
    clock = ticks.get(name)
    topic = f"/acq/timing/{name}"
    if clock is None or topic not in source.schemas:
        return None
    timing = [TimingMsg.FromString(m[3]) for m in source.messages if m[0] == topic]
    values = [t.unwrapped_tick or (t.device_ticks[0] if t.device_ticks else 0) for t in timing]
    steps = np.diff(np.asarray(values, dtype=np.int64))
    steps = steps[steps > 0]
    return float(np.median(steps)) / clock.hz * 1e9 if steps.size else None


def _steady(source: _Source, window: list[int], period_ns: int) -> bool:
    """Whether copies of ``window`` one after another keep each channel's log times
    increasing (the first message of a copy after the last of the one before)."""
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    for i in window:
        topic, log_ns, _pub, _data = source.messages[i]
        first.setdefault(topic, log_ns)
        last[topic] = log_ns
    return all(first[t] + period_ns > last[t] for t in first)


# --- the whole log -----------------------------------------------------------------------


def _metadata(
    source: _Source, plan: _Plan, shift: Callable[[str, bytes, int], bytes]
) -> dict[str, dict[str, str]]:
    """The source's last metadata records, the clock pair at the new end and the time
    base's readings counted."""
    meta = {name: dict(values) for name, values in source.metadata.items()}
    last = plan.copies - 1
    source_end = max(m[1] for m in source.messages)
    end_shift = max(source.messages[i][1] for i in plan.indexes(last)) - source_end
    end_shift += last * plan.period_ns  # the new end minus the source's
    clock = meta.get("clock")
    if clock is not None:
        for key in ("realtime_ns", "monotonic_ns"):
            if key in clock:
                clock[key] = str(int(clock[key]) + end_shift)
    if "time_base" in meta:  # its counts and warnings, of the readings written
        tally = HostClockTally()
        for k in range(plan.copies):
            for i in plan.indexes(k):
                topic, _log, _pub, data = source.messages[i]
                if topic == "/acq/timebase":
                    tally.add(host_clock_of(TimeBaseMsg.FromString(shift(topic, data, k))))
        meta["time_base"] = tally.metadata()
    return meta


def _groups(source: _Source, indexes: list[int]) -> Iterator[list[tuple[str, int, int, bytes]]]:
    """Consecutive messages of one log time together (a scan, its telegram and timing)."""
    group: list[tuple[str, int, int, bytes]] = []
    for i in indexes:
        m = source.messages[i]
        if group and m[1] != group[0][1]:
            yield group
            group = []
        group.append(m)
    if group:
        yield group


def _rolling(metadata: dict[str, dict[str, str]]) -> OutputConfig:
    """The recorder's file rolling (prefix, split) as the source's configuration set it,
    else the defaults."""
    try:
        section = yaml.safe_load(metadata.get("config", {}).get("yaml", "")) or {}
        return OutputConfig.model_validate(section.get("output") or {})
    except (yaml.YAMLError, AttributeError, ValueError):
        return OutputConfig()


def _check_out(out: Path, split: bool) -> None:
    if split:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise HourLogError(f"{out}: exists and is not an empty folder (--split writes one)")
    elif out.exists() or out.is_symlink():
        raise HourLogError(f"{out}: exists; a log is never overwritten")
    if not out.parent.is_dir():
        raise HourLogError(f"{out.parent}: no such folder")


def write_hour_log(
    src: str | os.PathLike[str],
    out: str | os.PathLike[str],
    minutes: float,
    *,
    split: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Any]:
    """Write ``minutes`` of drive to ``out`` from copies of the log ``src`` (see the module
    docstring); one file, or with ``split`` a new folder of files rolled as the recorder
    rolls them. ``progress(k, copies)`` after each copy. Returns what was written:
    ``copies``, ``period_s``, ``messages``, ``bytes``, ``files``, ``span_s``,
    ``untouched_telegrams``. Raises HourLogError (bad input), OSError (the disk); a
    failed write leaves nothing behind."""
    src, out = Path(src), Path(out)
    if not math.isfinite(minutes) or minutes <= 0:
        raise HourLogError(f"--minutes: {minutes} is not a positive number of minutes")
    _check_out(out, split)
    source = _read_source(src)
    names = {topic: schema.name for topic, schema in source.schemas.items()}
    ticks = device_ticks(source.metadata, names)
    plan = _plan(source, minutes, ticks)
    need = src.stat().st_size * plan.copies
    free = shutil.disk_usage(out.parent).free
    if need > free:
        raise OSError(
            errno.ENOSPC, f"about {need / 1e9:.1f} GB needed, {free / 1e9:.1f} GB free", str(out)
        )
    try:
        shifter = Shifter(names, ticks, plan.steps, plan.period_ns)
    except ValueError as e:
        raise HourLogError(str(e)) from None
    made_folder = not out.exists()  # the session folder (with --split), removed on failure
    folder = out if split else temporary_beside(out, "", folder=True)
    rolling = _rolling(source.metadata)
    writer: LogWriter | None = None
    done = False
    try:
        writer = LogWriter(
            folder,
            prefix=rolling.prefix,
            split_bytes=int(rolling.split_megabytes * 1e6) if split else 1 << 62,
            split_s=rolling.split_minutes * 60.0 if split else 1e12,
            metadata=_metadata(source, plan, shifter),
            profile=source.profile,
            time_base=source.time_base,
        )
        with writer:
            latched, span = _write_copies(writer, source, plan, shifter, progress)
        files = writer.files
        if not split:
            os.link(files[0], out)  # never onto an existing file
            files = [out]
        done = True
    finally:
        if not split:
            discard(folder)
        elif not done:  # nothing half written left behind
            for f in writer.files if writer is not None else []:
                f.unlink(missing_ok=True)
            if made_folder:
                shutil.rmtree(folder, ignore_errors=True)
    return {
        "copies": plan.copies,
        "period_s": plan.period_ns / 1e9,
        "messages": writer.messages + latched * len(files),  # latched: in every file
        "bytes": sum(f.stat().st_size for f in files),
        "files": [str(f) for f in files],
        "span_s": span * 1e-9,
        "untouched_telegrams": shifter.untouched_telegrams,
    }


def _write_copies(
    writer: LogWriter,
    source: _Source,
    plan: _Plan,
    shifter: Shifter,
    progress: Callable[[int, int], None] | None,
) -> tuple[int, int]:
    """The source's channels and every copy's messages to ``writer``, the latched ones
    (a channel's one message before the window: calibration, transforms) as the
    recorder latches them. Returns (the latched channels, the span written in ns)."""
    for topic, schema in source.schemas.items():
        writer.add_channel(topic, schema, source.channel_metadata[topic])
    latched = {
        t for t in source.schemas if sum(source.messages[i][0] == t for i in plan.head) == 1
        and all(source.messages[i][0] != t for i in plan.middle)
    }  # fmt: skip
    first, last = math.inf, -math.inf
    for k in range(plan.copies):
        indexes = plan.indexes(k)
        if k == 0:
            for i in indexes:
                topic, _log, pub, data = source.messages[i]
                if topic in latched:
                    first = min(first, pub)
                    writer.set_latched(topic, _restamped(source, topic, data, pub), pub)
            indexes = [i for i in indexes if source.messages[i][0] not in latched]
        delta = k * plan.period_ns
        for group in _groups(source, indexes):  # of one log time
            first = min(first, group[0][1] + delta)
            last = max(last, group[0][1] + delta)
            writer.write_group([
                (topic, shifter(topic, data, k), log_ns + delta, pub + delta)
                for topic, log_ns, pub, data in group
            ])  # fmt: skip
        if progress is not None:
            progress(k + 1, plan.copies)
    return len(latched), int(last - first)


def _restamped(source: _Source, topic: str, data: bytes, publish_ns: int) -> Callable[[int], bytes]:
    """A latched message for a file starting at log time ``start`` (ns): its stamps moved
    from its publish time there, as the recorder stamps each file's copy."""
    schema = source.schemas[topic].name
    to_log = source.time_base.to_log

    def encode_at(start: int) -> bytes:
        msg = message_class(schema).FromString(data)
        shift_stamps(msg, start - to_log(publish_ns))
        out: bytes = msg.SerializeToString()
        return out

    return encode_at


def _measure(src: Path, out: Path, minutes: float, split: bool) -> int:
    """Write the drive and print its JSON line; the exit status."""
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    try:
        result = write_hour_log(src, out, minutes, split=split)
    except HourLogError as e:
        print(f"hour_log: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"hour_log: {e.filename or out}: {e.strerror or e}", file=sys.stderr)
        return 3 if e.errno in (errno.ENOSPC, errno.EDQUOT) else 1
    line = {
        "bench": "hour_log",
        "src": str(src),
        "minutes": minutes,
        **result,
        "wall_s": round(time.perf_counter() - t_wall, 1),
        "cpu_s": round(time.process_time() - t_cpu, 1),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "loadavg": [round(x, 2) for x in os.getloadavg()],
    }
    print(json.dumps(line))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python bench/hour_log.py",
        description="Write a long drive made of time-shifted copies of a short acq log (one "
        "continuous drive to acq info, colorize and replay); print one JSON line: copies, "
        "messages, bytes, span, wall and CPU s, peak memory. Without SRC and OUT (make "
        "bench): a minute from the 2 s simulated drive, in a temporary folder removed after.",
    )
    parser.add_argument(
        "src", type=Path, nargs="?", help="a closed acq log (e.g. acq demo's demo.mcap)"
    )
    parser.add_argument("out", type=Path, nargs="?", help="the new log (never overwritten)")
    parser.add_argument(
        "--minutes", type=float, default=None, help="the drive's length, minutes (default 60)"
    )
    parser.add_argument(
        "--split",
        action="store_true",
        help="OUT is a new folder of files rolled as the source's recorder rolled them "
        "(its output.split_minutes and split_megabytes, by default 10 minutes or 2048 MB "
        "each), not one file",
    )
    args = parser.parse_args(argv)
    minutes = args.minutes if args.minutes is not None else 60.0 if args.src else 1.0
    if not math.isfinite(minutes) or not 0 < minutes <= 24 * 60:
        parser.error(f"--minutes: {minutes} is not within (0, 1440]")
    if (args.src is None) != (args.out is None):
        parser.error("give both SRC and OUT, or neither")
    # a stop ends the run through the writer's clean-up: no half log left behind
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
    if args.src is not None:
        return _measure(args.src, args.out, minutes, args.split)
    from acq.sim.drive_log import write_drive_log  # here: only the default needs it

    with tempfile.TemporaryDirectory(prefix="hour_log.") as tmp:
        src = write_drive_log(Path(tmp), 2.0).files[0]
        return _measure(src, Path(tmp) / "long.mcap", minutes, args.split)


if __name__ == "__main__":
    sys.exit(main())
