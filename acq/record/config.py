"""The recorder's YAML configuration (see ARCHITECTURE.md, "the configuration file").

:func:`load` reads and validates a file; every problem is a :class:`ConfigError` whose
text is one line naming the file, the key path and what was expected, e.g.
``rig.yaml: cameras[0].fsp: unknown key; did you mean fps?``. Driver ``options`` are
checked against the keyword parameters of the driver class the ``driver:`` key selects;
driver names are those of the driver registry (:mod:`acq.drivers.registry`: ours and any
installed through its entry points), and what a scanner's ``url``, ``protocol`` and
``latency_s`` accept is what its driver class declares. A device's address (a scanner's
``url``, a camera's ``source``) is checked against what its driver opens
(:mod:`acq.record.device_addresses`). Every number is bounded (finite; rates, sizes and
times positive where they must be, and below a sane maximum), driver options named as
ours too (:data:`acq.record.driver_options.OPTION_BOUNDS`).

Relative paths in a file (``calibration``, ``output.dir``, ``can.dbc``) are relative to
the folder of that file, not to the working directory; ``~`` is the user's home.
:func:`load` returns them absolute, :func:`parse` leaves them as written. Times are in
seconds, rates in frames per second, sizes in megabytes (10**6 bytes).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    BaseModel,
    BeforeValidator,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from acq import yamlcheck
from acq.drivers.registry import REGISTRIES, DriverImportError
from acq.errors import InputValueError
from acq.record.device_addresses import camera_source, serial_url, tcp_url
from acq.record.driver_options import MAX_BAUD, check_options, driver_class, expected_one_of
from acq.yamlcheck import did_you_mean, fail, show

__all__ = [
    "DEFAULT",
    "GNSS",
    "VEHICLE",
    "CameraConfig",
    "CanConfig",
    "Config",
    "ConfigError",
    "GnssConfig",
    "OutputConfig",
    "ScannerConfig",
    "dump",
    "load",
    "optional_devices",
    "parse",
    "required_devices",
    "shipped",
]

VERSION = 1
DEFAULT = "sim.yaml"
"""The configuration ``acq record`` uses without ``-c``: the simulated rig."""
_NAME = re.compile(r"[A-Za-z0-9_]+")
_PREFIX = re.compile(r"[A-Za-z0-9_.-]+")
MAX_LATENCY_S = 10.0
"""The largest constant transport latency, s."""
MAX_SIDE_PX = 65535
"""The largest requested image width or height, px (JPEG's limit)."""
MAX_MEGABYTES = 1e9
"""The largest file size or disk reserve, MB (a petabyte)."""


VEHICLE = "vehicle"  # the CAN bus's device name: topics /vehicle/odometry, /vehicle/can
GNSS = "gnss"  # the GNSS receiver's: /gnss/fix, /gnss/raw, /acq/timing/gnss


class ConfigError(InputValueError):
    """A configuration that cannot be used; ``str(e)`` is one line: file, key path, problem."""


def _not_empty_path(value: Any) -> Any:
    if value == "":
        raise fail("expected a path, got ''")
    if isinstance(value, str) and not value.isprintable():
        raise fail(f"expected a path, got {value!r} (it holds a control character)")
    return value


def _none_is_empty(cls: type[BaseModel], value: Any, info: ValidationInfo) -> Any:
    """A section left empty (``cameras:`` with every entry commented out) is its default."""
    if value is None and info.field_name is not None:
        return cls.model_fields[info.field_name].get_default(call_default_factory=True)
    return value


# Paths are written as strings in YAML, so they are validated in lax mode.
_Path = Annotated[Path, Field(strict=False), BeforeValidator(_not_empty_path)]


class _Model(BaseModel):
    model_config = yamlcheck.STRICT


def _driver_name(kind: str) -> Any:
    """A validator of the ``driver`` key of a device of ``kind``."""

    def check(cls: type[BaseModel], v: Any) -> str:
        if not isinstance(v, str) or v not in REGISTRIES[kind].entries:
            expected_one_of(REGISTRIES[kind].names(), v)
        driver_class(kind, v)
        return v

    return classmethod(check)


def _scanner(info: ValidationInfo) -> Any:
    """The driver class of the scanner being validated; None when its driver is invalid."""
    driver = info.data.get("driver")
    return None if driver is None else driver_class("scanner", driver)


def _scanners() -> list[tuple[str, Any]]:
    """(name, class) of every scanner driver that can be imported, for messages."""
    found = []
    for name in REGISTRIES["scanner"].names():
        try:
            found.append((name, REGISTRIES["scanner"].get(name)))
        except DriverImportError:
            continue  # reported where a configuration uses it
    return found


class ScannerConfig(_Model):
    """One laser scanner: topics ``/<name>/scan`` and ``/<name>/raw``."""

    name: str
    driver: str  # a scanner driver of the registry: hokuyo, sick, ...
    url: str  # hokuyo: a pyserial URL (tcp:// becomes socket://); sick: tcp://host:port
    protocol: str | None = Field(default=None, validate_default=True)  # sick: cola-b | cola-a
    # from the stamp to receipt, s; auto (the default where the driver can measure it):
    # its latency_probe; else 0
    latency_s: float | Literal["auto"] = Field(default=None, validate_default=True)
    options: dict[str, Any] = {}  # keyword arguments of the driver class
    # true: without a record within 10 s of the start the recorder stops (exit 1);
    # unset: without one by the end the exit status is 1; false: optional, a warning
    required: bool | None = None

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return _check_name(v)

    _driver = field_validator("driver", mode="plain")(_driver_name("scanner"))
    _empty = field_validator("options", mode="before")(_none_is_empty)

    @field_validator("url")
    @classmethod
    def _url(cls, v: str, info: ValidationInfo) -> str:
        scanner = _scanner(info)
        if scanner is not None and scanner.url_kind == "serial":
            return serial_url(v)
        if scanner is not None and scanner.url_kind == "tcp":
            return tcp_url(v, info.data["driver"])
        return v

    @field_validator("protocol", mode="plain")
    @classmethod
    def _protocol(cls, v: Any, info: ValidationInfo) -> str | None:
        scanner = _scanner(info)
        if scanner is None:
            return v if v is None or isinstance(v, str) else expected_one_of(["a string"], v)
        choices = scanner.protocols
        if v is None:
            return choices[0] if choices else None
        if not choices:
            others = [d for d, c in _scanners() if c.protocols]
            speaks = f" (a {scanner.driver or info.data['driver']} speaks {scanner.wire})"
            raise fail(
                f"only for driver {' or '.join(others)}{speaks if scanner.wire else ''}; remove it"
            )
        if isinstance(v, str) and v in choices:
            return v
        expected_one_of(list(choices), v)

    @field_validator("latency_s", mode="plain")
    @classmethod
    def _latency(cls, v: Any, info: ValidationInfo) -> float | str:
        if v is None:  # not given: auto where the driver measures it
            scanner = _scanner(info)
            return "auto" if scanner is None or scanner.latency_probe else 0.0
        if v == "auto" and isinstance(v, str):
            scanner = _scanner(info)
            if scanner is not None and not scanner.latency_probe:
                probing = [(d, c.latency_probe) for d, c in _scanners() if c.latency_probe]
                raise fail(
                    f"auto is measured with {' or '.join(p for _, p in probing)}, for driver "
                    f"{', '.join(d for d, _ in probing)} only; expected a number of seconds "
                    f"0..{MAX_LATENCY_S:g}"
                )
            return v
        return _seconds(v, f"a number of seconds 0..{MAX_LATENCY_S:g} or auto")

    @field_validator("options")
    @classmethod
    def _options(cls, v: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        driver = info.data.get("driver")
        return v if driver is None else check_options("scanner", driver, v, cls)


class CameraConfig(_Model):
    """One camera: topics ``/<name>/image/compressed`` and ``/<name>/calibration``."""

    name: str
    driver: str  # a camera driver of the registry: opencv, v4l2, ...
    source: str  # an index, /dev/videoN, a URL or a pipeline (CAMERA_SOURCES)
    fps: float = Field(default=25.0, ge=0.01, le=1000)  # requested frame rate, 1/s
    width: int | None = Field(default=None, gt=0, le=MAX_SIDE_PX)  # requested size, px
    height: int | None = Field(default=None, gt=0, le=MAX_SIDE_PX)
    fourcc: str | None = None  # requested pixel format, e.g. MJPG
    # middle of exposure to receipt, s, where unknown
    latency_s: float = Field(default=0.0, ge=0, le=MAX_LATENCY_S)
    options: dict[str, Any] = {}  # keyword arguments of the driver class
    required: bool | None = None  # as a scanner's

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        return _check_name(v)

    _driver = field_validator("driver", mode="plain")(_driver_name("camera"))
    _empty = field_validator("options", mode="before")(_none_is_empty)

    @field_validator("source", mode="before")
    @classmethod
    def _source(cls, v: Any) -> Any:
        if isinstance(v, int) and not isinstance(v, bool):
            return str(v)  # a camera index, written as a number
        if v == "":
            raise fail("expected an index, a device, a URL or a pipeline, got ''")
        return v

    @field_validator("source")
    @classmethod
    def _opens(cls, v: str, info: ValidationInfo) -> str:
        driver = info.data.get("driver")
        return v if driver is None else camera_source(driver, v)

    @field_validator("fourcc")
    @classmethod
    def _fourcc(cls, v: str | None) -> str | None:
        if v is not None and not (len(v) == 4 and v.isascii() and v.isprintable()):
            raise fail(f"expected 4 characters such as MJPG or YUYV, got {v!r}")
        return v

    @field_validator("options")
    @classmethod
    def _options(cls, v: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        driver = info.data.get("driver")
        return v if driver is None else check_options("camera", driver, v, cls)


class OutputConfig(_Model):
    """Where and how logs are written."""

    dir: _Path = Path("./logs")
    prefix: str = "acq"  # file names start with it
    split_minutes: float = Field(default=10.0, ge=0.01, le=1e6)  # a new file after this long, min
    split_megabytes: float = Field(default=2048.0, ge=1, le=MAX_MEGABYTES)  # ... or this large, MB
    reserve_megabytes: float = Field(default=512.0, ge=0, le=MAX_MEGABYTES)  # disk kept free, MB

    @field_validator("prefix")
    @classmethod
    def _prefix(cls, v: str) -> str:
        if not _PREFIX.fullmatch(v):
            raise fail(
                f"expected letters, digits, '.', '-' or '_' (it starts file names), got {v!r}"
            )
        return v


class CanConfig(_Model):
    """Vehicle CAN bus through python-can, decoded with a DBC file: topics
    ``/vehicle/odometry`` and ``/vehicle/can`` (every frame, raw).

    Signals are named ``MESSAGE.SIGNAL`` as in the DBC, whose scale, offset and unit
    (km/h, m/s, mph; deg/s, rad/s) give SI values. The defaults are those of
    ``sim/vehicle.dbc``. ``speed`` names a vehicle speed signal; without one the speed
    is the mean of the four wheel speeds. ``options`` are further keyword arguments of
    ``can.Bus`` (e.g. ``fd: true``, ``data_bitrate``, ``port`` of udp_multicast).
    """

    driver: str = "python-can"  # a CAN driver of the registry
    interface: str = Field(min_length=1)  # python-can interface: socketcan, pcan...
    channel: str = Field(min_length=1)  # e.g. can0
    dbc: _Path
    bitrate: int | None = Field(default=None, gt=0, le=MAX_BAUD)  # bit/s; None: as set up
    wheel_speeds: list[str] = [
        f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR")
    ]  # front left, front right, rear left, rear right
    yaw_rate: str = "YAW_RATE.YAW_RATE"  # positive counter-clockwise (left turn)
    speed: str | None = None  # a vehicle speed signal; None: mean of the wheel speeds
    options: dict[str, Any] = {}  # keyword arguments of can.Bus
    required: bool | None = None  # as a scanner's

    _driver = field_validator("driver", mode="plain")(_driver_name("can"))
    _empty = field_validator("options", mode="before")(_none_is_empty)

    @field_validator("interface")
    @classmethod
    def _interface(cls, v: str) -> str:
        try:
            from can.interfaces import VALID_INTERFACES
        except Exception:  # python-can missing or broken here: the recorder will say
            return v
        if v not in VALID_INTERFACES:
            hint = did_you_mean(v, sorted(VALID_INTERFACES))
            raise fail(
                f"unknown python-can interface {v!r}{hint}"
                if hint
                else f"unknown python-can interface {v!r}; expected one of "
                + ", ".join(sorted(VALID_INTERFACES))
            )
        return v

    @field_validator("wheel_speeds")
    @classmethod
    def _wheels(cls, v: list[str]) -> list[str]:
        if len(v) != 4:
            raise fail(
                f"expected 4 signals (front left, front right, rear left, rear right), got {len(v)}"
            )
        for i, name in enumerate(v):
            _signal_name(name, i)
        return v

    @field_validator("yaw_rate", "speed")
    @classmethod
    def _signal(cls, v: str | None) -> str | None:
        return v if v is None else _signal_name(v)


class GnssConfig(_Model):
    """A GNSS receiver sending NMEA 0183 over a pyserial URL: topics ``/gnss/fix`` and
    ``/gnss/raw``.

    ``time`` says what stamps a fix: ``fix``, its own UTC fix time mapped to host time
    through the host's UTC clock (right when that clock is disciplined to UTC: chrony,
    PTP, a PPS); ``receipt``, the fix time mapped like a device clock through the
    sentences' receipt times, less ``latency_s``; ``auto`` (default), ``fix`` while the
    kernel says the host clock is synchronised, else ``receipt``. ``latency_s`` is the
    constant delay, s, from the fix instant to the receipt of the epoch's last sentence
    at its shortest (the receiver's computation and the line), which receipt times
    cannot see; fixes stamped from their UTC time do not need it and it is not
    subtracted from them."""

    driver: str = "nmea"  # a GNSS driver of the registry
    url: str
    baudrate: int = Field(default=9600, gt=0, le=MAX_BAUD)
    time: Literal["auto", "fix", "receipt"] = "auto"
    latency_s: float = Field(default=0.0, ge=0, le=MAX_LATENCY_S)
    required: bool | None = None  # as a scanner's

    _driver = field_validator("driver", mode="plain")(_driver_name("gnss"))

    @field_validator("url")
    @classmethod
    def _url(cls, v: str) -> str:
        return serial_url(v)


class Config(_Model):
    """A whole configuration file; ``source`` is the file it was read from (set by load)."""

    version: Literal[1]
    scanners: list[ScannerConfig] = []
    cameras: list[CameraConfig] = []
    calibration: _Path | None = None
    output: OutputConfig = OutputConfig()
    can: CanConfig | None = None
    gnss: GnssConfig | None = None
    source: Path | None = Field(default=None, exclude=True)

    _empty = field_validator("scanners", "cameras", "output", mode="before")(_none_is_empty)

    @field_validator("version", mode="plain")
    @classmethod
    def _version(cls, v: Any) -> int:
        if type(v) is not int or v != VERSION:
            raise fail(f"expected {VERSION} (the version this acq reads), got {show(v)}")
        return v

    @model_validator(mode="after")
    def _devices(self) -> Config:
        seen: dict[str, str] = {}
        groups: list[tuple[str, Sequence[ScannerConfig | CameraConfig]]] = [
            ("scanners", self.scanners),
            ("cameras", self.cameras),
        ]
        for kind, devices in groups:
            for i, device in enumerate(devices):
                if device.name in seen:
                    raise fail(
                        f"{device.name!r} is already the name of {seen[device.name]}; "
                        "device names must be unique",
                        kind,
                        i,
                        "name",
                    )
                seen[device.name] = f"{kind}[{i}]"
        if not seen:
            raise fail("no device; expected at least one scanner or camera", "scanners")
        for section, name in (("can", "vehicle"), ("gnss", "gnss")):
            if getattr(self, section) is not None and name in seen:
                where = seen[name].replace("[", " ").rstrip("]").split()
                raise fail(
                    f"{name!r} names the {section} section's topics (/{name}/...); "
                    "rename this device",
                    where[0],
                    int(where[1]),
                    "name",
                )
        return self

    def devices(self) -> list[str]:
        """The names of all devices, scanners first."""
        return [s.name for s in self.scanners] + [c.name for c in self.cameras]


# --- field checks ------------------------------------------------------------------------


def _check_name(v: str) -> str:
    if not _NAME.fullmatch(v):
        raise fail(f"expected letters, digits or '_' (it names topics), got {v!r}")
    return v


def _signal_name(v: str, *subpath: str | int) -> str:
    """A DBC signal as ``MESSAGE.SIGNAL``."""
    message, dot, signal = v.partition(".")
    if not (dot and _NAME.fullmatch(message) and _NAME.fullmatch(signal)):
        raise fail(f"expected MESSAGE.SIGNAL as named in the DBC, got {v!r}", *subpath)
    return v


def _seconds(v: Any, expected: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise fail(f"expected {expected}, got {show(v)}")
    if not (math.isfinite(v) and 0 <= v <= MAX_LATENCY_S):
        raise fail(f"expected {expected}, got {show(v)}")
    return float(v)


# --- errors ------------------------------------------------------------------------------


def _error(source: str, path: str, message: str) -> ConfigError:
    return ConfigError(yamlcheck.line(source, path, message))


# --- reading and writing -----------------------------------------------------------------


def parse(data: Any, source: str = "<config>") -> Config:
    """A :class:`Config` from an already-parsed YAML tree; paths stay as written.

    ``source`` names the file in error messages.
    """
    if data is None:
        raise _error(source, "", "empty file; expected a mapping with version: 1 and devices")
    if not isinstance(data, Mapping):
        raise _error(
            source,
            "",
            f"expected a mapping with version: 1 and devices, got {show(data)}",
        )
    if "source" in data:
        keys = [k for k in Config.model_fields if k != "source"]
        raise _error(source, "source", "unknown key" + did_you_mean("source", keys))
    try:
        return Config.model_validate(dict(data))
    except ValidationError as e:
        raise ConfigError(yamlcheck.message(e, source, Config)) from None


def _absolute(path: Path, base: Path) -> Path:
    return Path(os.path.normpath(base / path.expanduser()))


def shipped(name: str = DEFAULT) -> Path:
    """The path of a configuration shipped with acq (the repository's ``config/NAME``,
    package data ``acq.config``)."""
    return Path(str(resources.files("acq.config").joinpath(name)))


def load(path: str | Path) -> Config:
    """Read and validate a configuration file; relative paths become absolute, relative
    to the file's folder."""
    path = Path(path)
    data = yamlcheck.read(path, ConfigError)
    config = parse(data, str(path))
    base = path.parent.absolute()
    output = config.output.model_copy(update={"dir": _absolute(config.output.dir, base)})
    update: dict[str, Any] = {"output": output, "source": path.absolute()}
    if config.calibration is not None:
        update["calibration"] = _absolute(config.calibration, base)
    if config.can is not None:
        update["can"] = config.can.model_copy(update={"dbc": _absolute(config.can.dbc, base)})
    return config.model_copy(update=update)


def _plain(value: Any) -> Any:
    """Model-dump values as YAML's safe dumper writes them."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def dump(config: Config) -> str:
    """The YAML text of a configuration (``parse(yaml.safe_load(dump(c)))`` equals ``c``)."""
    data = _plain(config.model_dump(exclude_none=True))
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True)


def _requirements(config: Config) -> list[tuple[str, bool | None]]:
    """Each device's name and its ``required`` (None: unset)."""
    out = [(s.name, s.required) for s in config.scanners]
    out += [(c.name, c.required) for c in config.cameras]
    if config.can is not None:
        out.append((VEHICLE, config.can.required))
    if config.gnss is not None:
        out.append((GNSS, config.gnss.required))
    return out


def required_devices(config: Config) -> list[str]:
    """The names of the devices the configuration marks ``required: true``."""
    return [name for name, required in _requirements(config) if required]


def optional_devices(config: Config) -> list[str]:
    """The names of the devices the configuration marks ``required: false``: one that
    records nothing is a warning, not a failure."""
    return [name for name, required in _requirements(config) if required is False]
