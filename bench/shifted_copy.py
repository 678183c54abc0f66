"""One message of an acq log moved into a later copy of the log (:mod:`hour_log`): its
times, its device's ticks and its counters, schema by schema.

Copy ``k`` of a message is the source message with ``k * period_ns`` on every time it
holds (every protobuf ``Timestamp``; ``recv_ns``, ``stamp_ns``, the ``acq.Clock`` and
``acq.TimeBase`` pairs, a CAN interface's ``wall_ns``, chrony's and PPS's UTC seconds,
``uptime_s``, a GNSS fix's ``utc`` and ``utc_s``), as many ticks on its device's clock
(``device_ticks`` modulo the counter's width, ``unwrapped_tick``, and the 24-bit ms
stamp inside a SCIP telegram), the UTC time (and date) of a GNSS receiver's NMEA
sentence (``/gnss/raw``, to the field's decimals), and ``k`` times what one copy adds
to each counter (sequence numbers, received and dropped counts, PPS sequences). A CoLa
(SICK) telegram's own time field keeps its recorded time.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from acq.drivers.nmea import checksum as nmea_checksum
from acq.drivers.registry import REGISTRIES, DriverImportError, UnknownDriver
from acq.drivers.scip_codec import SCAN_COMMANDS, checksum, decode_int, encode
from acq.log.schemas import message_class
from acq.log.stamp_shift import shift_stamps
from acq.record.adapters import GNSS_TICK_HZ

__all__ = [
    "CounterKey",
    "Shifter",
    "Ticks",
    "counter_steps",
    "counters",
    "device_ticks",
    "fix_utc",
    "nmea_with_time",
    "scip_with_tick",
]

_GNSS_TICK_BITS = 62  # as the recorder's GNSS clock (acq.record.adapters)
# the fields holding host or UTC ns, by schema (Timestamps are found by their type)
_NS_FIELDS = {
    "acq.Timing": ("recv_ns", "stamp_ns"),
    "acq.RawTelegram": ("recv_ns",),
    "acq.Clock": ("realtime_ns", "monotonic_ns"),
    "acq.Odometry": ("recv_ns",),
    "acq.CanFrame": ("recv_ns", "wall_ns"),
    "acq.TimeBase": ("realtime_ns", "monotonic_ns"),
}
_COUNTERS = {"acq.Timing": ("sequence", "received", "dropped"), "acq.RawTelegram": ("sequence",)}
_STATUS_COUNTERS = (
    "received", "dropped", "corrupt", "disconnects", "protocol_errors", "odd_size"
)  # fmt: skip

CounterKey = tuple[str, ...]
# the field holding the UTC time of day, by NMEA sentence kind (its last three letters)
_NMEA_TIME_FIELD = {"GGA": 1, "RMC": 1, "GST": 1, "GNS": 1, "ZDA": 1, "GBS": 1, "GLL": 5}
_NMEA_TIME = re.compile(r"(\d\d)(\d\d)(\d\d)(\.\d{1,6})?")


@dataclass(frozen=True)
class Ticks:
    """A device's clock counter: its rate (Hz) and width (bits)."""

    hz: float
    bits: int


# --- counters ----------------------------------------------------------------------------


def counters(schema: str, msg: Any) -> dict[CounterKey, int]:
    """The counters a message holds, by key (field, or device and field)."""
    if schema in _COUNTERS:
        return {(f,): int(getattr(msg, f)) for f in _COUNTERS[schema]}
    if schema == "acq.Status":
        return {(d.name, f): int(getattr(d, f)) for d in msg.devices for f in _STATUS_COUNTERS}
    if schema == "acq.TimeBase" and msg.HasField("pps"):
        return {("pps", f): int(getattr(msg.pps, f)) for f in ("assert_sequence", "clear_sequence")}
    return {}


def _add_counters(schema: str, msg: Any, steps: dict[CounterKey, int], k: int) -> None:
    if not steps or k == 0:
        return
    if schema in _COUNTERS:
        for f in _COUNTERS[schema]:
            setattr(msg, f, getattr(msg, f) + k * steps.get((f,), 0))
    elif schema == "acq.Status":
        for d in msg.devices:
            for f in _STATUS_COUNTERS:
                setattr(d, f, getattr(d, f) + k * steps.get((d.name, f), 0))
    elif schema == "acq.TimeBase" and msg.HasField("pps"):
        for f in ("assert_sequence", "clear_sequence"):
            setattr(msg.pps, f, getattr(msg.pps, f) + k * steps.get(("pps", f), 0))


def counter_steps(
    messages: Iterable[tuple[str, str, bytes, bool]],
) -> dict[str, dict[CounterKey, int]]:
    """Per topic and counter, what one copy adds, from the source's ``messages`` (topic,
    schema name, bytes, whether in the copied window): the window's last value minus its
    first, plus the usual step between two messages of the whole source (1 for a
    sequence, 0 for no drops; a 1 Hz status once per window has but that)."""
    values: dict[str, dict[CounterKey, list[tuple[int, bool]]]] = {}
    for topic, schema, data, inside in messages:
        if schema not in _COUNTERS and schema not in ("acq.Status", "acq.TimeBase"):
            continue
        for key, v in counters(schema, message_class(schema).FromString(data)).items():
            values.setdefault(topic, {}).setdefault(key, []).append((v, inside))
    steps: dict[str, dict[CounterKey, int]] = {}
    for topic, by_key in values.items():
        for key, series in by_key.items():
            every = [v for v, _inside in series]
            window = [v for v, inside in series if inside]
            usual = round(float(np.median(np.diff(every)))) if len(every) > 1 else 0
            span = window[-1] - window[0] if window else 0
            steps.setdefault(topic, {})[key] = max(span + usual, 0)
    return steps


# --- device ticks ------------------------------------------------------------------------


def device_ticks(
    metadata: Mapping[str, Mapping[str, str]], schemas: Mapping[str, str]
) -> dict[str, Ticks]:
    """The clock counter of every device of a log (``schemas``: topic -> schema name)
    with timing records or raw telegrams: a scanner's from its driver class, the GNSS
    receiver's (UTC µs) as the recorder keeps it, another's from the ``clock`` metadata."""
    named = {t.removeprefix("/acq/timing/") for t, s in schemas.items() if s == "acq.Timing"}
    named |= {t[1:].removesuffix("/raw") for t in schemas if t.endswith("/raw")}
    out: dict[str, Ticks] = {}
    clock = metadata.get("clock", {})
    for name in sorted(named):
        driver = metadata.get(f"device.{name}", {}).get("driver")
        if name == "gnss":
            out[name] = Ticks(GNSS_TICK_HZ, _GNSS_TICK_BITS)
            continue
        cls: Any = None
        if driver:
            try:
                cls = REGISTRIES["scanner"].get(driver)
            except (UnknownDriver, DriverImportError):
                cls = None
        if cls is not None:
            out[name] = Ticks(float(cls.tick_hz), int(cls.tick_bits))
        elif f"{name}.tick_hz" in clock:
            out[name] = Ticks(float(clock[f"{name}.tick_hz"]), 64)
    return out


def scip_with_tick(data: bytes, add: int) -> bytes | None:
    """A SCIP scan telegram with ``add`` ms on its 24-bit timestamp; None if ``data`` is
    no SCIP scan telegram (echo, status, timestamp line)."""
    parts = data.split(b"\n", 3)
    if len(parts) < 4 or parts[0][:2].decode("ascii", "replace") not in SCAN_COMMANDS:
        return None
    ts = parts[2]
    if len(ts) != 5 or ts[4] != checksum(ts[:4]):
        return None
    tick = (decode_int(ts[:4]) + add) % (1 << 24)
    new = encode([tick], 4)
    return b"\n".join((parts[0], parts[1], new + bytes([checksum(new)]), parts[3]))


# --- one message -------------------------------------------------------------------------


@dataclass
class Shifter:
    """Moves messages into copy ``k`` (``__call__``): ``schemas`` topic -> schema name,
    ``ticks`` by device, ``steps`` of the counters by topic (:func:`counter_steps`),
    ``period_ns`` between two copies (ValueError unless it is whole ticks of every
    device). ``untouched_telegrams`` counts the raw telegrams whose own time field was
    left as recorded (not SCIP)."""

    schemas: Mapping[str, str]
    ticks: Mapping[str, Ticks]
    steps: Mapping[str, dict[CounterKey, int]]
    period_ns: int
    untouched_telegrams: int = 0

    def __post_init__(self) -> None:
        for name, ticks in self.ticks.items():
            per_copy = self.period_ns * ticks.hz / 1e9
            if abs(per_copy - round(per_copy)) > 1e-6:
                raise ValueError(f"{name}: {self.period_ns} ns is not a whole number of its ticks")

    def __call__(self, topic: str, data: bytes, k: int) -> bytes:
        if k == 0:
            return data
        schema = self.schemas[topic]
        msg = message_class(schema).FromString(data)
        delta = k * self.period_ns
        shift_stamps(msg, delta)
        for f in _NS_FIELDS.get(schema, ()):
            if getattr(msg, f):
                setattr(msg, f, getattr(msg, f) + delta)
        _add_counters(schema, msg, self.steps.get(topic, {}), k)
        if schema == "acq.Status":
            msg.uptime_s += delta * 1e-9
        elif schema == "acq.TimeBase":
            self._time_base(msg, delta)
        elif schema == "foxglove.LocationFix":
            fix_utc(msg, delta)
        elif schema == "acq.RawTelegram" and msg.data.startswith(b"$"):
            msg.data = nmea_with_time(msg.data, delta)
        elif schema in ("acq.Timing", "acq.RawTelegram"):
            self._ticks(topic, schema, msg, delta)
        out: bytes = msg.SerializeToString()
        return out

    def _ticks(self, topic: str, schema: str, msg: Any, delta: int) -> None:
        device = (
            topic.removeprefix("/acq/timing/")
            if schema == "acq.Timing"
            else msg.device or topic[1:].removesuffix("/raw")
        )
        ticks = self.ticks.get(device)
        if ticks is None or not msg.device_ticks:
            return
        add = round(delta * ticks.hz / 1e9)
        wrap = 1 << ticks.bits
        msg.device_ticks[:] = [(t + add) % wrap for t in msg.device_ticks]
        if schema == "acq.Timing" and msg.unwrapped_tick:
            msg.unwrapped_tick += add
        elif schema == "acq.RawTelegram":
            data = scip_with_tick(msg.data, add) if ticks.hz == 1000.0 else None
            if data is None:
                self.untouched_telegrams += 1
            else:
                msg.data = data

    @staticmethod
    def _time_base(msg: Any, delta: int) -> None:
        ds = delta * 1e-9
        if msg.HasField("chrony") and msg.chrony.ref_time_s:
            msg.chrony.ref_time_s += ds
        if msg.HasField("pps"):
            for f in ("assert_s", "clear_s"):
                if getattr(msg.pps, f):
                    setattr(msg.pps, f, getattr(msg.pps, f) + ds)


def nmea_with_time(data: bytes, delta_ns: int) -> bytes:
    """An NMEA sentence with its UTC time of day (and RMC's or ZDA's date) ``delta_ns``
    later, to the field's own decimals, its checksum made anew; a sentence without a time
    (VTG, GSA), or that is not one, as it is."""
    line = data.rstrip(b"\r\n")
    if len(line) < 4 or line[-3:-2] != b"*":
        return data
    fields = line[1:-3].decode("ascii", "replace").split(",")
    at = _NMEA_TIME_FIELD.get(fields[0][-3:])
    if at is None or len(fields) <= at:
        return data
    when = _NMEA_TIME.fullmatch(fields[at])
    kind = fields[0][-3:]
    date = dt.date(2000, 1, 1)  # a sentence without a date: only its time of day moves
    try:
        if kind == "RMC" and len(fields) > 9 and fields[9]:
            date = dt.datetime.strptime(fields[9], "%d%m%y").date()
        elif kind == "ZDA" and len(fields) > 4 and all(fields[2:5]):
            date = dt.date(int(fields[4]), int(fields[3]), int(fields[2]))
    except ValueError:
        return data
    if when is None:
        return data
    decimals = len(when[4] or ".") - 1  # when[4]: the point and the fraction
    seconds = int(when[1]) * 3600 + int(when[2]) * 60 + int(when[3]) + float(when[4] or 0)
    step = 10 ** (6 - decimals)  # the field's resolution, µs
    moved = round((seconds * 1e6 + delta_ns / 1e3) / step) * step
    new = dt.datetime.combine(date, dt.time()) + dt.timedelta(microseconds=moved)
    fields[at] = new.strftime("%H%M%S")
    if decimals:
        fields[at] += f".{new.microsecond // step:0{decimals}d}"
    if kind == "RMC" and len(fields) > 9 and fields[9]:
        fields[9] = new.strftime("%d%m%y")
    elif kind == "ZDA" and len(fields) > 4 and all(fields[2:5]):
        fields[2:5] = [f"{new.day:02d}", f"{new.month:02d}", f"{new.year:04d}"]
    body = ",".join(fields).encode("ascii")
    return b"$" + body + b"*%02X" % nmea_checksum(body) + data[len(line) :]


def fix_utc(msg: Any, delta: int) -> None:
    """A LocationFix's ``utc_s`` and ``utc`` metadata moved by ``delta`` ns."""
    items = {kv.key: kv for kv in msg.metadata}
    if "utc_s" not in items:
        return
    try:
        utc_s = float(items["utc_s"].value) + delta * 1e-9
    except ValueError:
        return
    items["utc_s"].value = f"{utc_s:.3f}"
    if "utc" in items and items["utc"].value:
        text = dt.datetime.fromtimestamp(utc_s, dt.UTC).isoformat(timespec="milliseconds")
        items["utc"].value = text.replace("+00:00", "Z")
