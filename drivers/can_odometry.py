"""Vehicle odometry (wheel speeds, yaw rate) from the CAN bus, decoded with a DBC file.

The bus is opened with python-can (``can.Bus(interface=..., channel=...)``: socketcan
on the vehicle, ``virtual`` or ``udp_multicast`` in tests); the DBC is read with
cantools, whose scale and offset give physical values and whose unit strings (km/h,
m/s, mph; deg/s, rad/s) give SI ones. :class:`CanOdometry` is the I/O side (one bus,
one thread): ``read_frame()`` returns every frame of the bus as a stamped
:class:`acq.records.CanFrame`; :class:`OdometryDecoder` (sans-I/O) turns a frame into
an :class:`acq.records.Odometry`, ``None`` for a frame it does not use (another id, an
error or remote frame), or raises :class:`CanDecodeError` for a frame of a used id
whose bytes do not decode (a wrong length): never another exception.

**Combining messages.** Wheel speeds and yaw rate usually come in different messages,
sampled at different instants (here ``WHEEL_SPEEDS`` and ``YAW_RATE``, both 50 Hz).
Each decoded message gives one Odometry at that message's time, holding what the
message carries and NaN for the rest. Holding the other message's last value instead
would date it up to one period (20 ms) late; an integrator gets each quantity at the
instants it was measured and interpolates it at any other (:mod:`acq.log.vehicle_log`
does that for complete rows).

**Time stamps.** socketcan stamps each frame in the kernel at receipt on the *wall*
clock (``CLOCK_REALTIME``; python-can's ``msg.timestamp``, seconds since the epoch).
Each frame is mapped to the host monotonic clock with the offset ``time.time_ns() -
time.monotonic_ns()`` sampled right after that frame is read. Both the kernel stamp
and that sample read the same wall clock, microseconds to milliseconds apart, so an
NTP *step* shifts both alike and cancels, unless it falls inside that window; a fixed
offset sampled once would be off by every step since. NTP *slewing* (at most 500 ppm)
changes the result by under 1 µs per ms spent in the socket buffer. A stamp that maps
after the frame's receipt (a step back inside the window) or more than
:data:`MAX_STAMP_AGE_S` before it (a step forward, an interface without wall-clock
stamps) is not used: the frame gets its receive time, and ``bad_stamps`` counts it.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from acq.drivers.errors import ConnectionLost, ProtocolError, ReadTimeout
from acq.errors import InputValueError
from acq.records import CanFrame, DeviceInfo, Odometry

__all__ = [
    "DEFAULT_WHEEL_SPEEDS",
    "DEFAULT_YAW_RATE",
    "MAX_STAMP_AGE_S",
    "CanDecodeError",
    "CanOdometry",
    "DbcError",
    "OdometryDecoder",
    "map_stamp",
]

DEFAULT_WHEEL_SPEEDS = tuple(f"WHEEL_SPEEDS.WHEEL_SPEED_{w}" for w in ("FL", "FR", "RL", "RR"))
DEFAULT_YAW_RATE = "YAW_RATE.YAW_RATE"
MAX_STAMP_AGE_S = 2.0  # an interface stamp older than this at receipt is not trusted
_FUTURE_TOLERANCE_NS = 1_000_000  # a stamp this much after receipt is clock-read noise

# unit string (lower case, as DBCs write it) -> factor to SI
_SPEED_UNITS = {
    "m/s": 1.0,
    "mps": 1.0,
    "km/h": 1 / 3.6,
    "kmh": 1 / 3.6,
    "kph": 1 / 3.6,
    "kmph": 1 / 3.6,
    "mph": 0.44704,
}
_RATE_UNITS = {
    "rad/s": 1.0,
    "deg/s": math.pi / 180,
    "°/s": math.pi / 180,
    "degree/s": math.pi / 180,
    "degrees/s": math.pi / 180,
    "dps": math.pi / 180,
}


class DbcError(InputValueError):
    """A DBC that cannot serve the configuration: unreadable, or a message, signal or
    unit the configuration needs that it lacks. The message names the file."""


class CanDecodeError(ProtocolError):
    """A frame of a message odometry uses whose bytes do not decode (wrong length...)."""

    def __init__(self, message: str, arbitration_id: int) -> None:
        super().__init__(message)
        self.arbitration_id = arbitration_id


def map_stamp(wall_ns: int, recv_ns: int, offset_ns: int) -> tuple[int, bool]:
    """(monotonic ns, usable) of an interface's wall-clock stamp ``wall_ns``, with
    ``offset_ns`` = wall minus monotonic sampled at receipt (``recv_ns``).

    Unusable (0, a stamp after receipt or more than :data:`MAX_STAMP_AGE_S` before it):
    ``(recv_ns, False)``.
    """
    if wall_ns <= 0:
        return recv_ns, False
    stamp = wall_ns - offset_ns
    age = recv_ns - stamp
    if age < -_FUTURE_TOLERANCE_NS or age > MAX_STAMP_AGE_S * 1e9:
        return recv_ns, False
    return min(stamp, recv_ns), True


@dataclass(frozen=True)
class _Signal:
    """One configured DBC signal: where it is and its factor to SI."""

    message: str
    signal: str
    frame_id: int
    to_si: float
    minimum: float | None  # physical range of valid values (DBC units), None: any
    maximum: float | None
    half_step: float  # half the signal's scale, slack for the range check


def _load_dbc(path: Path) -> Any:
    import cantools

    try:  # not strict: makers' DBCs often have overlapping or oversized signals
        return cantools.database.load_file(str(path), strict=False)
    except FileNotFoundError:
        raise DbcError(f"{path}: no such DBC file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DbcError(f"{path}: cannot read: {e}") from None
    except Exception as e:  # cantools' parsers raise their own errors on bad syntax
        raise DbcError(f"{path}: not a DBC cantools can read: {e}") from None


class OdometryDecoder:
    """CAN frames -> :class:`Odometry` with the signals named ``MESSAGE.SIGNAL``.

    ``db`` is a cantools database. ``speed`` names a vehicle speed signal; without it
    the speed is the mean of the finite wheel speeds. Raises :class:`DbcError` when a
    message, signal or unit is missing (``source`` names the DBC in its text).
    """

    def __init__(
        self,
        db: Any,
        *,
        wheel_speeds: Sequence[str] = DEFAULT_WHEEL_SPEEDS,
        yaw_rate: str = DEFAULT_YAW_RATE,
        speed: str | None = None,
        source: str = "DBC",
    ) -> None:
        if len(wheel_speeds) != 4:
            raise ValueError(f"expected 4 wheel speed signals, got {len(wheel_speeds)}")
        self.db = db
        self.source = source
        self.wheels = tuple(self._signal(n, _SPEED_UNITS, "a speed") for n in wheel_speeds)
        self.yaw = self._signal(yaw_rate, _RATE_UNITS, "an angular rate")
        self.speed = None if speed is None else self._signal(speed, _SPEED_UNITS, "a speed")
        used = [*self.wheels, self.yaw] + ([self.speed] if self.speed else [])
        self._messages = {s.frame_id: db.get_message_by_name(s.message) for s in used}
        # frame id -> (role, wheel index, signal); role: wheel | yaw | speed
        self._by_id: dict[int, list[tuple[str, int, _Signal]]] = {}
        roles = [("wheel", i, s) for i, s in enumerate(self.wheels)] + [("yaw", 0, self.yaw)]
        if self.speed is not None:
            roles.append(("speed", 0, self.speed))
        for role, index, sig in roles:
            self._by_id.setdefault(sig.frame_id, []).append((role, index, sig))

    @classmethod
    def from_file(cls, path: str | os.PathLike[str], **signals: Any) -> OdometryDecoder:
        """A decoder for the DBC at ``path``; ``signals`` as for the constructor."""
        path = Path(path)
        return cls(_load_dbc(path), source=str(path), **signals)

    def _signal(self, name: str, units: Mapping[str, float], kind: str) -> _Signal:
        message_name, _, signal_name = name.partition(".")
        try:
            message = self.db.get_message_by_name(message_name)
        except KeyError:
            raise DbcError(f"{self.source}: no message {message_name!r} (for {name})") from None
        try:
            signal = message.get_signal_by_name(signal_name)
        except KeyError:
            raise DbcError(
                f"{self.source}: message {message_name} has no signal {signal_name!r}"
            ) from None
        unit = (signal.unit or "").strip().lower()
        if unit not in units:
            raise DbcError(
                f"{self.source}: {name} has unit {signal.unit!r}; expected {kind} in one of "
                + ", ".join(units)
            )
        return _Signal(
            message=message_name,
            signal=signal_name,
            frame_id=int(message.frame_id),
            to_si=units[unit],
            minimum=None if signal.minimum is None else float(signal.minimum),
            maximum=None if signal.maximum is None else float(signal.maximum),
            half_step=abs(float(signal.scale)) / 2,
        )

    @property
    def frame_ids(self) -> frozenset[int]:
        """The identifiers of the messages odometry is decoded from."""
        return frozenset(self._by_id)

    def decode(self, frame: CanFrame) -> Odometry | None:
        """The odometry ``frame`` carries; None for a frame not used (another id, an
        error or remote frame). Raises :class:`CanDecodeError` for bytes that do not
        decode as the DBC's message of that id."""
        if frame.is_error or frame.is_remote:
            return None
        roles = self._by_id.get(frame.arbitration_id)
        if roles is None:
            return None
        message = self._messages[frame.arbitration_id]
        if bool(message.is_extended_frame) != frame.is_extended:
            return None  # the same number in the other identifier space: another message
        values = self._decode_message(message, frame)
        wheels = [math.nan] * 4
        yaw = speed = math.nan
        has_wheels = False
        for role, index, sig in roles:
            value = self._physical(values, sig)
            if role == "wheel":
                wheels[index] = value
                has_wheels = True
            elif role == "yaw":
                yaw = value
            else:
                speed = value
        if self.speed is None and has_wheels:
            finite = [w for w in wheels if math.isfinite(w)]
            speed = math.fsum(finite) / len(finite) if finite else math.nan
        return Odometry(
            recv_ns=frame.recv_ns,
            stamp_ns=frame.stamp_ns,
            speed=speed,
            yaw_rate=yaw,
            wheel_speeds=tuple(wheels) if has_wheels else (),
            arbitration_id=frame.arbitration_id,
        )

    def _decode_message(self, message: Any, frame: CanFrame) -> Mapping[str, Any]:
        from cantools.database.errors import DecodeError

        if len(frame.data) != message.length:
            raise CanDecodeError(
                f"{message.name} (0x{frame.arbitration_id:X}): {len(frame.data)} data bytes, "
                f"the DBC says {message.length}",
                frame.arbitration_id,
            )
        try:
            decoded = message.decode(
                frame.data, decode_choices=False, scaling=True, allow_truncated=False
            )
        except (DecodeError, ValueError, KeyError, IndexError) as e:
            raise CanDecodeError(
                f"{message.name} (0x{frame.arbitration_id:X}): {e}", frame.arbitration_id
            ) from None
        if not isinstance(decoded, Mapping):
            raise CanDecodeError(f"{message.name}: not a plain message", frame.arbitration_id)
        return decoded

    @staticmethod
    def _physical(values: Mapping[str, Any], sig: _Signal) -> float:
        """The signal in SI units; NaN when absent (multiplexed out) or out of its range."""
        raw = values.get(sig.signal)
        if not isinstance(raw, int | float):
            return math.nan
        value = float(raw)
        if sig.minimum is not None and value < sig.minimum - sig.half_step:
            return math.nan
        if sig.maximum is not None and value > sig.maximum + sig.half_step:
            return math.nan
        return value * sig.to_si


def _socketcan_up(url: str) -> bool:
    """Cheap check that a socketcan interface is up (sysfs operstate)."""
    interface, _, channel = url.partition("://")
    if interface != "socketcan":
        return True  # no cheap check: rely on the backoff
    try:
        state = Path(f"/sys/class/net/{channel}/operstate").read_text().strip()
    except OSError:
        return False
    return state in ("up", "unknown")


class CanOdometry:
    """One python-can bus and a DBC: raw frames and the odometry they carry.

    ``interface``/``channel``/``bitrate`` (None: as the interface is set up) and
    ``bus_options`` go to ``can.Bus``; ``dbc`` is the DBC's path; ``wheel_speeds``,
    ``yaw_rate`` and ``speed`` name its signals as ``MESSAGE.SIGNAL``. ``timeout`` (s) is
    how long ``read_frame`` waits for a frame before raising :class:`ReadTimeout`.
    Counters: ``frames`` read, ``bad_stamps`` (stamps not used, see the module doc).
    """

    driver: ClassVar[str] = "python-can"
    reachable = staticmethod(_socketcan_up)

    def __init__(
        self,
        interface: str,
        channel: str,
        dbc: str | os.PathLike[str],
        *,
        bitrate: int | None = None,
        wheel_speeds: Sequence[str] = DEFAULT_WHEEL_SPEEDS,
        yaw_rate: str = DEFAULT_YAW_RATE,
        speed: str | None = None,
        name: str = "vehicle",
        timeout: float = 1.0,
        bus_options: Mapping[str, Any] | None = None,
    ) -> None:
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.name = name
        self.timeout = timeout
        self.bus_options = dict(bus_options or {})
        self.dbc = Path(dbc)
        self.decoder = OdometryDecoder.from_file(
            self.dbc, wheel_speeds=wheel_speeds, yaw_rate=yaw_rate, speed=speed
        )
        self.info: DeviceInfo | None = None
        self.frames = 0
        self.bad_stamps = 0
        self._bus: Any = None

    @property
    def url(self) -> str:
        """``interface://channel``, for logs and reachability checks."""
        return f"{self.interface}://{self.channel}"

    def connect(self) -> DeviceInfo:
        """Open the bus; raises ConnectionLost when the interface cannot be opened."""
        import can

        self.close()
        kwargs: dict[str, Any] = dict(self.bus_options)
        if self.bitrate is not None:
            kwargs["bitrate"] = self.bitrate
        try:
            self._bus = can.Bus(interface=self.interface, channel=self.channel, **kwargs)
        except (can.CanError, OSError, ValueError) as e:
            raise ConnectionLost(f"{self.url}: cannot open: {e}") from e
        ids = ", ".join(f"0x{i:X}" for i in sorted(self.decoder.frame_ids))
        self.info = DeviceInfo(
            name=self.name,
            driver=self.driver,
            vendor=self.interface,
            model=str(getattr(self._bus, "channel_info", "") or self.channel),
            extra={
                "interface": self.interface,
                "channel": self.channel,
                "bitrate": str(self.bitrate or ""),
                "dbc": str(self.dbc),
                "odometry_ids": ids,
                "wheel_speeds": " ".join(f"{s.message}.{s.signal}" for s in self.decoder.wheels),
                "yaw_rate": f"{self.decoder.yaw.message}.{self.decoder.yaw.signal}",
            },
        )
        return self.info

    def start(self) -> None:
        """Nothing to start: a bus streams once open."""
        if self._bus is None:
            raise RuntimeError("connect() first")

    def read_frame(self) -> CanFrame:
        """The next frame of the bus (any id), stamped; raises ReadTimeout, ConnectionLost."""
        import can

        if self._bus is None:
            raise ConnectionLost("not connected")
        try:
            msg = self._bus.recv(self.timeout)
        except (can.CanError, OSError, ValueError) as e:
            raise ConnectionLost(f"{self.url}: {e}") from e
        recv_ns = time.monotonic_ns()
        offset_ns = time.time_ns() - recv_ns  # wall minus monotonic, right now
        if msg is None:
            raise ReadTimeout(f"{self.url}: no CAN frame within {self.timeout} s")
        wall_ns = round(float(msg.timestamp) * 1e9) if msg.timestamp else 0
        stamp_ns, ok = map_stamp(wall_ns, recv_ns, offset_ns)
        if not ok:
            self.bad_stamps += 1
        self.frames += 1
        return CanFrame(
            recv_ns=recv_ns,
            stamp_ns=stamp_ns,
            wall_ns=wall_ns,
            arbitration_id=int(msg.arbitration_id),
            data=bytes(msg.data),
            is_extended=bool(msg.is_extended_id),
            is_remote=bool(msg.is_remote_frame),
            is_error=bool(msg.is_error_frame),
            is_fd=bool(msg.is_fd),
            channel=str(msg.channel) if msg.channel is not None else self.channel,
        )

    def decode(self, frame: CanFrame) -> Odometry | None:
        """See :meth:`OdometryDecoder.decode`."""
        return self.decoder.decode(frame)

    def read_odometry(self) -> Odometry:
        """The next odometry record (other frames skipped); raises CanDecodeError for a
        bad frame of a used id, and as :meth:`read_frame`."""
        while True:
            odometry = self.decoder.decode(self.read_frame())
            if odometry is not None:
                return odometry

    def odometry(self, count: int) -> Iterator[Odometry]:
        """``count`` odometry records (for probes and tests)."""
        for _ in range(count):
            yield self.read_odometry()

    def stop(self) -> None:
        """Nothing to stop (the bus stays open)."""

    def close(self) -> None:
        """Shut the bus down; safe to call twice and after a failure."""
        bus, self._bus = self._bus, None
        if bus is None:
            return
        try:
            bus.shutdown()
        except Exception:  # interfaces raise anything on a dead bus
            pass

    def __enter__(self) -> CanOdometry:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
