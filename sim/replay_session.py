"""A recorded session read for a replay (:mod:`acq.sim.replay`): its devices, each with
its records' receive times and the means to read their bytes when they are due
(:mod:`acq.sim.replay_records`), its description (driver, ``device.<name>`` metadata),
the recorded configuration and calibration; and the checks that a scanner's records
can be served (one SCIP scan command, one CoLa encoding). One pass over the files; the
records' bytes are not kept.

:class:`ReplayError` (an InputError) for a missing or unreadable log, nothing to replay
or an unknown driver, with one line naming the file.
"""

from __future__ import annotations

import json
import logging
from array import array
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.records import Channel, Schema

from acq.drivers.cola_codec import STX4, unframe
from acq.drivers.errors import ProtocolError
from acq.drivers.registry import DriverImportError, UnknownDriver
from acq.drivers.scanner import SCANNERS
from acq.drivers.scip_codec import parse_scan_echo
from acq.errors import InputValueError
from acq.log import LogError, LogReader, read_metadata
from acq.record import config as configfile
from acq.record.config import CameraConfig, Config, ScannerConfig
from acq.sim.replay_records import LogRecords, Records
from acq.sim.replay_vehicle import pack_can

__all__ = [
    "COLA",
    "SCIP",
    "DeviceLog",
    "ReplayError",
    "Session",
    "load_session",
    "scanner_wire",
]

log = logging.getLogger("acq.sim.replay")

SCIP, COLA = "SCIP", "CoLa"  # the wire protocols a replay serves (a driver's ``wire``)
_RAW_SUFFIX = "/raw"
_IMAGE_SUFFIX = "/image/compressed"
# the vehicle's buses: topic -> (schema, device, kind), as the recorder writes them
_VEHICLE_TOPICS = {
    "/vehicle/can": ("acq.CanFrame", "vehicle", "can"),
    "/gnss/raw": ("acq.RawTelegram", "gnss", "gnss"),
}


class ReplayError(InputValueError):
    """A log that cannot be replayed; ``str(e)`` is one line naming the file."""


@dataclass
class DeviceLog:
    """What a session recorded of one device: its records (times in receive order, bytes
    read when asked: telegrams and sentences as received, JPEGs as sent, CAN frames packed
    by pack_can) and its description."""

    name: str
    kind: str  # scanner | camera | can | gnss
    driver: str  # the recorded driver (hokuyo, sick, opencv, v4l2)
    file: Path  # the first file holding its records
    records: Records
    # a scanner's telegrams: their distinct first lines (a few) and whether CoLa-B framed
    echoes: set[bytes] = field(default_factory=set)
    binary: set[bool] = field(default_factory=set)
    metadata: dict[str, Any] = field(default_factory=dict)  # device.<name>, JSON decoded

    @property
    def times_ns(self) -> np.ndarray:
        """Receive times, host monotonic ns (int64, ascending)."""
        return self.records.times_ns

    @property
    def duration_s(self) -> float:
        t = self.times_ns
        return int(t[-1] - t[0]) * 1e-9 if len(t) else 0.0

    @property
    def rate_hz(self) -> float:
        return (len(self.times_ns) - 1) / self.duration_s if self.duration_s > 0 else 0.0


@dataclass
class Session:
    """The files of one recording, read: devices (scanners first), recorded config."""

    files: tuple[Path, ...]
    devices: dict[str, DeviceLog]
    config: Config | None  # the recorded configuration (metadata ``config``), if readable
    calibration_yaml: str | None  # the recorded calibration (metadata ``calibration``)

    @property
    def start_ns(self) -> int:
        return min(int(d.times_ns[0]) for d in self.devices.values())

    @property
    def end_ns(self) -> int:
        return max(int(d.times_ns[-1]) for d in self.devices.values())

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9


def _recorded_config(meta: dict[str, dict[str, str]], path: Path) -> Config | None:
    text = meta.get("config", {}).get("yaml")
    if not text:
        return None
    try:
        return configfile.parse(yaml.safe_load(text), f"{path}: metadata config")
    except (configfile.ConfigError, yaml.YAMLError) as e:
        log.warning(
            "%s: the recorded configuration is unusable (%s); using the device metadata", path, e
        )
        return None


def load_session(paths: Sequence[str | Path]) -> Session:
    """Read the files of one session (in the given order): every device's records and
    description, the recorded configuration and calibration. Raises :class:`ReplayError`."""
    files = tuple(Path(p) for p in paths)
    if not files:
        raise ReplayError("no log given")
    try:
        readers = [LogReader(p) for p in files]  # missing or not MCAP: at once
    except LogError as e:
        raise ReplayError(str(e)) from None
    found: dict[str, _Found] = {}
    config: Config | None = None
    calibration: str | None = None
    described: dict[str, dict[str, str]] = {}
    for path, reader in zip(files, readers, strict=True):
        meta = read_metadata(path)
        if config is None:
            config = _recorded_config(meta, path)
        if calibration is None:
            calibration = meta.get("calibration", {}).get("yaml")
        for name, values in meta.items():
            if name.startswith("device."):
                described.setdefault(name[len("device.") :], values)
        try:
            _read_records(reader, found)
        except LogError as e:
            raise ReplayError(str(e)) from None
    devices = {name: f.device(files) for name, f in found.items()}
    if not devices:
        where = ", ".join(str(p) for p in files)
        raise ReplayError(
            f"{where}: no raw scanner telegrams, camera images, CAN frames or NMEA sentences "
            "to replay"
        )
    for dev in devices.values():
        _describe(dev, described.get(dev.name, {}), config)
    ordered = sorted(devices.values(), key=lambda d: (d.kind != "scanner", _order(d, config)))
    return Session(files, {d.name: d for d in ordered}, config, calibration)


def _device_of(schema: Schema | None, channel: Channel) -> tuple[str, str] | None:
    """(device, kind) whose records the channel holds, or None: not replayed."""
    topic, name = channel.topic, schema.name if schema is not None else ""
    if topic in _VEHICLE_TOPICS:
        schema_name, device, kind = _VEHICLE_TOPICS[topic]
        return (device, kind) if name == schema_name else None
    if name == "acq.RawTelegram" and topic.endswith(_RAW_SUFFIX):
        return topic[1 : -len(_RAW_SUFFIX)], "scanner"
    if name == "foxglove.CompressedImage" and topic.endswith(_IMAGE_SUFFIX):
        return topic[1 : -len(_IMAGE_SUFFIX)], "camera"
    return None


ECHOES_KEPT = 4  # distinct first lines of a scanner's telegrams kept, for the check
_ECHO_BYTES = 64  # a SCIP echo is shorter


def _payload(kind: str, decoded: Any) -> bytes:
    """What a replay serves of a decoded record (see :class:`DeviceLog`)."""
    return pack_can(decoded) if kind == "can" else bytes(decoded.data)


@dataclass
class _Found:
    """One device's records as the first pass finds them: times per file, in file order."""

    name: str
    kind: str
    file: Path
    times: dict[Path, array[int]] = field(default_factory=dict)
    echoes: set[bytes] = field(default_factory=set)
    binary: set[bool] = field(default_factory=set)

    def device(self, files: Sequence[Path]) -> DeviceLog:
        name, kind = self.name, self.kind
        parts = [(p, np.frombuffer(self.times[p], np.int64)) for p in files if p in self.times]
        records = LogRecords(
            name, parts, lambda s, c: _device_of(s, c) == (name, kind),
            lambda decoded: _payload(kind, decoded),
        )  # fmt: skip
        return DeviceLog(name, kind, "", self.file, records, self.echoes, self.binary)


def _read_records(reader: LogReader, found: dict[str, _Found]) -> None:
    """The first pass: each device's record times, and what the checks look at."""
    path = reader.path
    for (device, kind), _channel, message, decoded in reader.decoded(_device_of):
        if decoded is None:  # a garbled record: counted, the reader warns once per channel
            continue
        dev = found.get(device)
        if dev is None:
            dev = found[device] = _Found(device, kind, path)
        elif dev.kind != kind:
            raise ReplayError(f"{path}: {device!r} has both {dev.kind} and {kind} records")
        dev.times.setdefault(path, array("q")).append(message.log_time)
        if kind == "scanner":
            data = decoded.data
            if len(dev.echoes) < ECHOES_KEPT:
                dev.echoes.add(bytes(data[:_ECHO_BYTES]).split(b"\n", 1)[0])
            dev.binary.add(data[:4] == STX4)


def _order(dev: DeviceLog, config: Config | None) -> int:
    names = config.devices() if config is not None else []
    return names.index(dev.name) if dev.name in names else len(names)


def _describe(dev: DeviceLog, values: dict[str, str], config: Config | None) -> None:
    """Fill in the device's driver and metadata; check that it can be replayed."""
    for key in ("info", "geometry", "params", "format"):
        if key in values:
            try:
                dev.metadata[key] = json.loads(values[key])
            except ValueError:
                raise ReplayError(
                    f"{dev.file}: metadata device.{dev.name}: {key} is not JSON"
                ) from None
    cfg = _device_config(config, dev.name)
    dev.driver = values.get("driver") or (str(cfg.driver) if cfg is not None else "")
    if dev.kind != "scanner":
        return
    wire = scanner_wire(dev.driver)
    if wire not in _CHECKS:
        got = repr(dev.driver) if dev.driver else "no recorded driver"
        served = [d for d in SCANNERS.names() if scanner_wire(d) in _CHECKS]
        raise ReplayError(
            f"{dev.file}: scanner {dev.name!r}: {got}; a replay serves "
            + " and ".join(served)
            + " scanners"
        )
    _CHECKS[wire](dev)


def scanner_wire(driver: str) -> str:
    """The wire protocol of a scanner driver of the registry ("" when there is none)."""
    try:
        return SCANNERS.get(driver).wire
    except (UnknownDriver, DriverImportError):
        return ""


def _check_scip(dev: DeviceLog) -> None:

    if "params" not in dev.metadata or "info" not in dev.metadata:
        raise ReplayError(
            f"{dev.file}: no device.{dev.name} metadata (the PP parameters and "
            "identity a Hokuyo replay answers with)"
        )
    echoes = set(dev.echoes)
    if len(echoes) > 1:
        shown = ", ".join(sorted(e.decode("ascii", "replace") for e in echoes))
        raise ReplayError(
            f"{dev.file}: {dev.name}: scans of different commands ({shown}); "
            "replay the files of each separately"
        )
    echo = echoes.pop()
    try:
        parsed = parse_scan_echo(echo)
    except ProtocolError as e:
        raise ReplayError(f"{dev.file}: {dev.name}: not a SCIP scan stream: {e}") from None
    if parsed.command[0] not in "MN":
        raise ReplayError(
            f"{dev.file}: {dev.name}: single scans ({parsed.command}) cannot be "
            "replayed as a stream"
        )


def _check_cola(dev: DeviceLog) -> None:

    if "geometry" not in dev.metadata:
        raise ReplayError(
            f"{dev.file}: no device.{dev.name} metadata (the scan geometry a "
            "SICK replay answers with)"
        )
    try:
        first = unframe(dev.records.head(1)[0])
    except ProtocolError as e:
        raise ReplayError(f"{dev.file}: {dev.name}: not a CoLa telegram: {e}") from None
    if first.name != "LMDscandata":
        raise ReplayError(
            f"{dev.file}: {dev.name}: not LMDscandata telegrams ({first.kind} {first.name})"
        )
    if len(dev.binary) > 1:
        raise ReplayError(
            f"{dev.file}: {dev.name}: both CoLa-A and CoLa-B telegrams; replay "
            "the files of each separately"
        )


_CHECKS = {SCIP: _check_scip, COLA: _check_cola}


def _device_config(config: Config | None, name: str) -> ScannerConfig | CameraConfig | None:
    if config is None:
        return None
    found = [d for d in config.scanners if d.name == name]
    return found[0] if found else next((c for c in config.cameras if c.name == name), None)
