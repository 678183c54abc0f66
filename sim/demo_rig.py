"""The simulated rig of `acq demo`: a Hokuyo UTM-30LX (SCIP 2.0 on a pseudo-terminal, its
own drifting millisecond clock), the 185-degree fisheye (MJPEG over HTTP, in its own
process so its JPEG encoding does not take the recorder's GIL) and the car (CAN frames
on a python-can ``virtual`` bus), all driving down the synthetic street from one shared
instant; the rig's true calibration and poses.

Times host monotonic (s unless ``_ns``).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from acq.camera.calibfile import Calibration, CameraCalib
from acq.motion.trajectory import Trajectory
from acq.sim.can_vehicle import SimVehicle
from acq.sim.device_clock import SimClock
from acq.sim.mjpeg_server import MjpegServerProcess
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import PtyDeviceServer
from acq.sim.world import default_rig

__all__ = [
    "CAMERA_SIM",
    "CAN_INTERFACE",
    "SCANNER_DRIFT_PPM",
    "SCANNER_MODEL",
    "SimRig",
    "camera_latency_s",
    "true_calibration",
]

# The simulated camera's options (JSON for its process): s, frames/s.
CAMERA_SIM: dict[str, Any] = {
    "fps": 25.0,
    "exposure_s": 0.004,
    "latency_s": 0.020,  # end of exposure -> frame available
    "jitter_s": 0.003,  # mean of the random part (exponential, clipped at 4x)
    "jpeg_quality": 90,
    "seed": 0,
}
SCANNER_MODEL = "utm-30lx"
SCANNER_DRIFT_PPM = 30.0  # the simulated scanner's clock runs fast by this much
CAN_INTERFACE = "virtual"  # python-can's in-process bus: the car and the recorder share it


def camera_latency_s(sim: dict[str, Any] = CAMERA_SIM) -> float:
    """What the camera driver subtracts from receipt to get the middle of the exposure:
    the sim's latency, half its exposure and the mean of its clipped exponential jitter."""
    jitter = float(sim["jitter_s"]) * (1.0 - math.exp(-4.0))
    return float(sim["latency_s"]) + float(sim["exposure_s"]) / 2 + jitter


class SimRig:
    """The simulated scanner (in process, on a pty), camera (own process) and car (in
    process, on a python-can ``virtual`` bus named ``can_channel``) sharing ``t_origin``
    (host monotonic s): the same place on the street at the same time."""

    def __init__(self, t_origin: float) -> None:

        self.t_origin = t_origin
        self.camera: Any = None
        self.server: Any = None
        self.car: Any = None
        # a virtual bus is one process's: a name of its own (two demos, the test suite)
        self.can_channel = f"acq-demo-{os.getpid()}-{time.monotonic_ns()}"
        self._tmp: str | None = None  # holds the pty's link
        model = MODELS[SCANNER_MODEL]
        # the camera process starts (and loads its renderer) while the scanner is built
        started: dict[str, Any] = {}

        def start_camera() -> None:
            try:
                started["camera"] = MjpegServerProcess(**CAMERA_SIM, t_origin=t_origin)
            except Exception as e:  # raised in the caller below
                started["error"] = e

        thread = threading.Thread(target=start_camera, name="sim-camera-start", daemon=True)
        thread.start()
        try:
            try:
                self.source = StreetSource(model, seed=0, t_origin=t_origin)
                clock = SimClock(
                    tick_hz=model.clock_hz,
                    wrap_bits=model.clock_bits,
                    drift_ppm=SCANNER_DRIFT_PPM,
                    offset_ticks=1234567.0,
                )
                self.scanner = ScipDevice(model, source=self.source, clock=clock)
                self._tmp = tempfile.mkdtemp(prefix="acq-demo-")
                link = Path(self._tmp) / "ttyACM-sim"
                self.server = PtyDeviceServer(self.scanner, link=link).start()
                # the car: the scanner's trajectory, looping with the street
                self.car = SimVehicle(
                    CAN_INTERFACE,
                    self.can_channel,
                    trajectory=self.source.trajectory,
                    t_origin=t_origin,
                    loop_s=self.loop_s,
                ).start()
            finally:
                thread.join()
                self.camera = started.get("camera")
            if "error" in started:
                raise RuntimeError(f"the simulated camera did not start: {started['error']}")
        except BaseException:
            self.close()
            raise

    @property
    def loop_s(self) -> float:
        """The drive's period, s: it loops over the street."""
        return max(self.source.street.length_m, 1.0) / self.source.trajectory.speed

    def trajectory(self, start_ns: int, end_ns: int, rate_hz: float = 1000.0) -> Trajectory:
        """The car's true poses from ``start_ns`` to ``end_ns`` (host ns; none before
        ``t_origin``) every 1/``rate_hz`` s: what the demo places its points with."""
        origin_ns = round(self.t_origin * 1e9)
        step = round(1e9 / rate_hz)
        t_ns = np.arange(max(start_ns, origin_ns), end_ns + step, step, dtype=np.int64)
        R, p = self.source.trajectory.poses(((t_ns - origin_ns) * 1e-9) % self.loop_s)
        return Trajectory(t_ns, R, p)

    def close(self) -> None:
        if self.car is not None:
            self.car.close()
            self.car = None
        if self.server is not None:
            self.server.close()
            self.server = None
        if self.camera is not None:
            self.camera.close()
            self.camera = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


def true_calibration() -> Calibration:
    """The simulated rig's true calibration (the lens as kannala_brandt)."""

    rig = default_rig()
    return Calibration(
        laser="laser",
        cameras={"camera": CameraCalib(rig.lens, rig.camera_to_laser, method="simulator truth")},
        laser_to_vehicle=rig.laser_to_vehicle,
    )
