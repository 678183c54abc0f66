"""A simulated car publishing its true motion as CAN frames on a python-can bus.

The car drives a :class:`acq.sim.world.Trajectory` from ``t_origin`` (host monotonic s; by
default when it is made, like the other simulated devices), looping every ``loop_s``
when given. Its ECUs send, in real time from one thread, the frames of
``sim/vehicle.dbc``:

- ``WHEEL_SPEEDS`` (0x1A0, 50 Hz): the four wheel speeds, 0.01 km/h, each the speed of
  the vehicle's reference point ± yaw rate × track / 2 (left slower in a left turn;
  front wheels as the rear ones: no steering geometry);
- ``YAW_RATE`` (0x1B0, 50 Hz, ``yaw_delay_s`` after the wheel speeds): yaw rate
  (0.01 deg/s, positive to the left), lateral and longitudinal acceleration, a counter;
- ``STEERING`` (0x025, 100 Hz): the steering-wheel angle of a bicycle model, a counter.

Speed and yaw rate are the trajectory's, by central differences of its poses (so any
trajectory works). Frames go out on a fixed schedule from ``t_origin``; each carries
the motion at the moment it is sent less ``latency_s`` (an ECU's sampling delay);
:attr:`SimVehicle.truth` gives, per frame, the true values and the instant they hold
for (a copy: the car's thread goes on sending while a test reads it). Faults:
:meth:`SimVehicle.send_raw` puts any frame on the bus (a wrong length, an unknown id).
"""

from __future__ import annotations

import dataclasses
import heapq
import math
import random
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from acq.sim.world import Trajectory

__all__ = ["DBC_PATH", "SentFrame", "SimVehicle", "multicast_can", "true_motion"]

DBC_PATH = Path(str(resources.files("acq.sim").joinpath("vehicle.dbc")))
WHEEL_SPEEDS_ID = 0x1A0
YAW_RATE_ID = 0x1B0
STEERING_ID = 0x025
_H = 1e-3  # s, step of the central differences


def multicast_can() -> tuple[str, dict[str, Any]]:
    """A python-can ``udp_multicast`` channel (an IPv4 group) and its bus options for one
    simulated or replayed car: a port free now and a TTL of 0, so that its frames stay on this host
    and two rigs on one machine do not hear each other."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    group = f"239.74.163.{random.randrange(1, 255)}"
    return group, {"port": port, "hop_limit": 0}


def true_motion(trajectory: Trajectory, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed over ground (m/s) and yaw rate (rad/s, counter-clockwise) of the vehicle's
    reference point at times ``ts`` (s of the drive), by central differences."""
    ts = np.atleast_1d(np.asarray(ts, dtype=np.float64))
    R0, p0 = trajectory.poses(ts - _H)
    R1, p1 = trajectory.poses(ts + _H)
    speed = np.hypot(*(p1 - p0)[:, :2].T) / (2 * _H)
    yaw0 = np.arctan2(R0[:, 1, 0], R0[:, 0, 0])
    yaw1 = np.arctan2(R1[:, 1, 0], R1[:, 0, 0])
    dyaw = (yaw1 - yaw0 + math.pi) % (2 * math.pi) - math.pi
    return speed, dyaw / (2 * _H)


@dataclass(frozen=True)
class SentFrame:
    """One frame the car sent and the truth it encodes (SI units)."""

    t_sent: float  # host monotonic s, just before bus.send
    t_true: float  # host monotonic s the values hold for (t_sent - latency_s)
    arbitration_id: int
    data: bytes
    speed: float  # m/s
    yaw_rate: float  # rad/s
    wheel_speeds: tuple[float, float, float, float]  # m/s FL, FR, RL, RR
    t_returned: float = 0.0  # host monotonic s, once bus.send returned (a busy host: later)


class SimVehicle:
    """A car on a python-can bus (``interface``, ``channel``, ``bus_options``).

    ``rate_hz`` is the rate of WHEEL_SPEEDS and YAW_RATE; ``track_m`` the distance
    between left and right wheels, ``wheelbase_m`` and ``steering_ratio`` those of the
    bicycle model behind the steering angle. Start with :meth:`start` (or ``with``).
    """

    def __init__(
        self,
        interface: str = "virtual",
        channel: str = "acq-sim-vehicle",
        *,
        trajectory: Trajectory | None = None,
        rate_hz: float = 50.0,
        yaw_delay_s: float = 0.010,
        steering_rate_hz: float = 100.0,
        latency_s: float = 0.0,
        track_m: float = 1.6,
        wheelbase_m: float = 2.7,
        steering_ratio: float = 15.0,
        t_origin: float | None = None,
        loop_s: float | None = None,
        truth_limit: int = 100_000,
        bus_options: dict[str, Any] | None = None,
    ) -> None:
        import cantools

        if rate_hz <= 0 or steering_rate_hz <= 0:
            raise ValueError("rates must be > 0")
        self.interface = interface
        self.channel = channel
        self.trajectory = trajectory if trajectory is not None else Trajectory()
        self.rate_hz = rate_hz
        self.yaw_delay_s = yaw_delay_s
        self.steering_rate_hz = steering_rate_hz
        self.latency_s = latency_s
        self.track_m = track_m
        self.wheelbase_m = wheelbase_m
        self.steering_ratio = steering_ratio
        self.t_origin = time.monotonic() if t_origin is None else t_origin
        self.loop_s = loop_s
        self.bus_options = dict(bus_options or {})
        db = cantools.database.load_file(str(DBC_PATH))
        assert isinstance(db, cantools.database.can.Database)
        self.db = db
        self._truth: deque[SentFrame] = deque(maxlen=truth_limit)
        self.sent = 0
        self._bus: Any = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._counters = {YAW_RATE_ID: 0, STEERING_ID: 0}

    # --- the truth -------------------------------------------------------------------

    @property
    def truth(self) -> list[SentFrame]:
        """The frames sent so far (the last ``truth_limit``), oldest first."""
        with self._lock:
            return list(self._truth)

    def drive_time(self, t: float) -> float:
        """Seconds of the drive at host monotonic time ``t``."""
        dt = t - self.t_origin
        return dt % self.loop_s if self.loop_s else dt

    def motion(self, t: float) -> tuple[float, float, float]:
        """(speed m/s, yaw rate rad/s, longitudinal acceleration m/s²) at host time t."""
        td = self.drive_time(t)
        speed, yaw = true_motion(self.trajectory, np.array([td - _H, td, td + _H]))
        accel = (speed[2] - speed[0]) / (2 * _H)
        return float(speed[1]), float(yaw[1]), float(accel)

    def wheel_speeds(self, speed: float, yaw_rate: float) -> tuple[float, float, float, float]:
        """True wheel speeds (m/s, magnitudes) FL, FR, RL, RR."""
        half = yaw_rate * self.track_m / 2
        left, right = abs(speed - half), abs(speed + half)
        return left, right, left, right

    # --- frames ----------------------------------------------------------------------

    def _frame(self, frame_id: int, t_true: float) -> tuple[bytes, SentFrame]:
        speed, yaw, accel = self.motion(t_true)
        wheels = self.wheel_speeds(speed, yaw)
        if frame_id == WHEEL_SPEEDS_ID:
            names = ("FL", "FR", "RL", "RR")
            values: dict[str, float] = {
                f"WHEEL_SPEED_{n}": min(w * 3.6, 655.33) for n, w in zip(names, wheels, strict=True)
            }
        elif frame_id == YAW_RATE_ID:
            values = {
                "YAW_RATE": math.degrees(yaw),
                "LAT_ACCEL": speed * yaw,
                "LONG_ACCEL": accel,
                "YAW_COUNTER": self._count(frame_id),
            }
        else:
            road = math.atan2(self.wheelbase_m * yaw, max(speed, 0.1))
            values = {
                "STEERING_ANGLE": math.degrees(road) * self.steering_ratio,
                "STEERING_RATE": 0.0,
                "STEERING_COUNTER": self._count(frame_id),
            }
        data = self.db.get_message_by_frame_id(frame_id).encode(values, strict=False)
        return bytes(data), SentFrame(0.0, t_true, frame_id, bytes(data), speed, yaw, wheels)

    def _count(self, frame_id: int) -> int:
        n = self._counters[frame_id]
        self._counters[frame_id] = (n + 1) % 16
        return n

    def send_raw(self, arbitration_id: int, data: bytes, *, is_extended: bool = False) -> None:
        """Put any frame on the bus now (a fault: a wrong length, an unknown id)."""
        import can

        msg = can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=is_extended)
        with self._lock:
            if self._bus is None:
                raise RuntimeError("start() first")
            self._bus.send(msg)

    # --- running ---------------------------------------------------------------------

    def start(self) -> SimVehicle:
        """Open the bus and start sending (a second call is a no-op)."""
        import can

        if self._thread is not None:
            return self
        self._bus = can.Bus(interface=self.interface, channel=self.channel, **self.bus_options)
        self._thread = threading.Thread(target=self._run, name="SimVehicle", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        import can

        period, steer = 1.0 / self.rate_hz, 1.0 / self.steering_rate_hz
        now = time.monotonic()
        # the schedules keep their phase from t_origin: (due, frame id, index)
        k0 = math.ceil((now - self.t_origin) / period)
        j0 = math.ceil((now - self.t_origin) / steer)
        events = [
            (self.t_origin + k0 * period, WHEEL_SPEEDS_ID, k0),
            (self.t_origin + k0 * period + self.yaw_delay_s, YAW_RATE_ID, k0),
            (self.t_origin + j0 * steer, STEERING_ID, j0),
        ]
        heapq.heapify(events)
        while not self._stop.is_set():
            due, frame_id, k = heapq.heappop(events)
            step = steer if frame_id == STEERING_ID else period
            offset = self.yaw_delay_s if frame_id == YAW_RATE_ID else 0.0
            heapq.heappush(events, (self.t_origin + (k + 1) * step + offset, frame_id, k + 1))
            wait = due - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                break
            # sampled now (a late thread sends late values, not stale ones), as an ECU
            data, truth = self._frame(frame_id, time.monotonic() - self.latency_s)
            msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False)
            with self._lock:
                if self._bus is None:
                    break
                t_sent = time.monotonic()
                try:
                    self._bus.send(msg)
                except can.CanError:
                    continue  # a full transmit queue: the frame is lost, as on a car
                self.sent += 1
                self._truth.append(
                    dataclasses.replace(truth, t_sent=t_sent, t_returned=time.monotonic())
                )

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        with self._lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    def __enter__(self) -> SimVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
