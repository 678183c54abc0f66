"""The vehicle's buses of a recorded log, served back: the CAN frames of ``/vehicle/can``
on a python-can bus and the NMEA sentences of ``/gnss/raw`` on TCP, each at its recorded
receive time on the session's :class:`acq.sim.replay_devices.ReplayClock` (the scanners'
and cameras' clock), so that a recorder pointed at a replay records the odometry and the
fixes again along with the scans and frames.

- :class:`ReplayCanBus` sends the frames (identifier, flags and data as received) on
  ``udp_multicast`` with a TTL of 0 by default (:func:`acq.sim.can_vehicle.multicast_can`:
  it stays on this host, and reaches a recorder in another process). A CAN bus has no
  client to ask for data: it sends once another device's client has started the clock.
- :class:`NmeaReplayDevice` is a ``SimDevice`` (serve it with
  :class:`acq.sim.transport.TcpDeviceServer`): the recorded sentences byte for byte, each
  ended with CR LF, from when a client connects; a client connecting first starts the
  session's clock.

The sentences keep their recorded UTC fix times: the replay's configuration stamps the
fixes from their receipt (``gnss.time: receipt``), as the replay's host clock is not the
recording's.

Times are the host's ``time.monotonic()`` seconds.
"""

from __future__ import annotations

import struct
import threading
import time
from typing import Any

from acq.sim.can_vehicle import DBC_PATH, multicast_can
from acq.sim.replay_devices import ReplayStream

__all__ = ["NmeaReplayDevice", "ReplayCanBus", "pack_can", "vehicle_entries"]

_HEAD = struct.Struct("<IB")  # arbitration id, flags
_EXTENDED, _REMOTE, _ERROR, _FD = 1, 2, 4, 8


def pack_can(frame: Any) -> bytes:
    """One recorded ``acq.CanFrame`` (decoded) as the bytes a :class:`ReplayStream` holds:
    its identifier, flags and data."""
    flags = (
        _EXTENDED * bool(frame.is_extended)
        | _REMOTE * bool(frame.is_remote)
        | _ERROR * bool(frame.is_error)
        | _FD * bool(frame.is_fd)
    )
    return _HEAD.pack(int(frame.arbitration_id), flags) + bytes(frame.data)


def _message(packed: bytes) -> Any:
    import can

    arbitration_id, flags = _HEAD.unpack_from(packed)
    return can.Message(
        arbitration_id=arbitration_id,
        is_extended_id=bool(flags & _EXTENDED),
        is_remote_frame=bool(flags & _REMOTE),
        is_error_frame=bool(flags & _ERROR),
        is_fd=bool(flags & _FD),
        data=packed[_HEAD.size :],
    )


class ReplayCanBus:
    """Sends a log's CAN frames on python-can ``interface`` ``channel`` (default: a fresh
    ``udp_multicast`` group on this host) at their recorded times, from the moment the
    session's clock starts. :attr:`url` is ``interface:channel``, :attr:`options` the
    bus's keyword arguments a client needs too."""

    def __init__(
        self,
        stream: ReplayStream,
        interface: str = "udp_multicast",
        channel: str | None = None,
        options: dict[str, Any] | None = None,
    ) -> None:
        if channel is None:
            channel, found = multicast_can()
            options = {**found, **(options or {})}
        self.stream = stream
        self.interface = interface
        self.channel = channel
        self.options = dict(options or {})
        self.errors = 0  # frames the bus refused
        self._bus: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return f"{self.interface}:{self.channel}"

    def start(self) -> ReplayCanBus:
        import can

        self._bus = can.Bus(interface=self.interface, channel=self.channel, **self.options)
        self._thread = threading.Thread(target=self._run, name="replay-can", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        import can

        stream = self.stream
        while not stream.clock.wait_started(0.1):
            if self._stop.is_set():
                return
        stream.begin(time.monotonic())
        while not self._stop.is_set():
            due = stream.due()
            if due is None:  # the end of the log
                return
            wait = due - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            for packed in stream.take(time.monotonic()):
                try:
                    self._bus.send(_message(packed))
                except can.CanError:
                    self.errors += 1  # a full transmit queue: lost, as on a car

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()


class NmeaReplayDevice:
    """A GNSS receiver replaying recorded sentences (a ``SimDevice``): streamed while a
    client is connected, what it sends ignored."""

    def __init__(self, stream: ReplayStream) -> None:
        self.stream = stream

    def handle(self, data: bytes, now: float) -> bytes:
        return b""  # configuration commands are not replayed

    def poll(self, now: float) -> bytes:
        if not self.stream.active:
            self.stream.begin(now)
        # the log holds each sentence without its line end
        return b"".join(line.rstrip(b"\r\n") + b"\r\n" for line in self.stream.take(now))

    def next_due(self, now: float) -> float | None:
        return self.stream.due()

    def on_disconnect(self) -> None:
        self.stream.stop()

    def reboot(self, now: float) -> None:
        pass

    def corrupt_next(self) -> None:
        pass


def vehicle_entries(
    recorded: dict[str, Any], can: ReplayCanBus | None, gnss_url: str | None
) -> dict[str, Any]:
    """The ``can`` and ``gnss`` sections of a replay's configuration (YAML data): those of
    the ``recorded`` configuration (the DBC and its signals; the receiver's options)
    pointed at the replayed bus and receiver, the fixes stamped from their receipt. A log
    without a recorded ``can`` section is decoded with the simulator's DBC."""
    out: dict[str, Any] = {}
    if can is not None:
        entry = dict(recorded.get("can") or {"dbc": str(DBC_PATH)})
        entry.pop("bitrate", None)  # a real bus's
        entry.update(interface=can.interface, channel=can.channel, options=dict(can.options))
        out["can"] = entry
    if gnss_url is not None:
        entry = dict(recorded.get("gnss") or {})
        entry.update(url=gnss_url, time="receipt")
        out["gnss"] = entry
    return out
