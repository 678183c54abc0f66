"""The simulated rig of `acq demo` and `acq sim rig`: a Hokuyo UTM-30LX (SCIP 2.0, its
own drifting millisecond clock), two 185-degree fisheyes looking left and right (the
cameras of ``default_rig(cameras=2)``, each serving MJPEG over HTTP from its own process
so its rendering and JPEG encoding take neither the recorder's GIL nor the other's), the
car (CAN frames on a python-can bus) and optionally a GNSS receiver (NMEA), all driving
down the synthetic street from one shared instant; the recorder's configuration for it
(:func:`rig_config`), the rig's true calibration and poses.

Two ways to link the devices: in process (the demo: the scanner and the receiver on
pseudo-terminals, the car on a ``virtual`` bus, which only this process sees), or on
loopback for a recorder in another process (``acq sim rig``: the scanner and the
receiver on TCP, the car on ``udp_multicast`` with a TTL of 0, which stays on this host).

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
from acq.sim.can_vehicle import DBC_PATH, SimVehicle, multicast_can
from acq.sim.device_clock import SimClock
from acq.sim.mjpeg_process import MjpegServerProcess
from acq.sim.nmea_device import NmeaDevice, NmeaPtyServer
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import DeviceServer, PtyDeviceServer, TcpDeviceServer
from acq.sim.world import Rig, default_rig

__all__ = [
    "CAMERAS",
    "CAMERA_SIM",
    "CAN_INTERFACE",
    "GNSS_LATENCY_S",
    "SCANNER_DRIFT_PPM",
    "SCANNER_MODEL",
    "SimRig",
    "camera_latency_s",
    "camera_sim",
    "demo_rig",
    "rig_config",
    "true_calibration",
]

# The simulated cameras' options in common (JSON for their processes): s, frames/s.
CAMERA_SIM: dict[str, Any] = {
    "fps": 25.0,
    "jitter_s": 0.003,  # mean of the random part of the latency (exponential, clipped at 4x)
    "jpeg_quality": 90,
    "street_seed": 0,  # the street the scanner scans
}
# Each camera's own frame clock: frame 0's exposure starts this long after the drive
# starts (s). Half a frame apart: two free-running cameras, their frames at other
# instants (and the recorder receiving one camera's frame at a time).
CLOCK_PHASE_S = {"left": 0.0, "right": 0.02}
SCANNER_MODEL = "utm-30lx"
SCANNER_DRIFT_PPM = 30.0  # the simulated scanner's clock runs fast by this much
CAN_INTERFACE = "virtual"  # python-can's in-process bus: the car and the recorder share it
GNSS_LATENCY_S = 0.040  # the simulated receiver's sentences: this long after the fix, s


def demo_rig() -> Rig:
    """The demo's rig (the truth): the laser and two fisheyes, ``left`` and ``right``."""
    return default_rig(cameras=2)


CAMERAS: tuple[str, ...] = demo_rig().camera_names


def camera_sim(name: str) -> dict[str, Any]:
    """The options of the demo's camera ``name`` for :class:`MjpegServerProcess`: the
    common ones, the rig camera's latency (end of exposure -> frame available) and
    exposure, its own jitter seed and clock phase."""
    cam = demo_rig().camera(name)
    return {
        **CAMERA_SIM,
        "camera": name,
        "latency_s": cam.latency_s,
        "exposure_s": cam.exposure,
        "seed": CAMERAS.index(name),
        "clock_offset_s": CLOCK_PHASE_S.get(name, 0.0),
    }


def camera_latency_s(name: str) -> float:
    """What the driver of camera ``name`` subtracts from receipt to get the middle of the
    exposure: the sim's latency, half its exposure and the mean of its clipped
    exponential jitter."""
    sim = camera_sim(name)
    jitter = float(sim["jitter_s"]) * (1.0 - math.exp(-4.0))
    return float(sim["latency_s"]) + float(sim["exposure_s"]) / 2 + jitter


class SimRig:
    """The simulated scanner (in process), cameras (``cameras``, by name, each in its own
    process), car (in process, on python-can ``can_interface`` ``can_channel``) and, with
    ``gnss``, GNSS receiver (in process, :attr:`receiver`) sharing ``t_origin`` (host
    monotonic s): the same place on the street at the same time.

    ``loopback`` False: the scanner and the receiver on pseudo-terminals and the car on a
    ``virtual`` bus, for a recorder in this process; True: the scanner and the receiver on
    TCP on 127.0.0.1 and the car on ``udp_multicast`` (:func:`multicast_can`), for a
    recorder in any process of this host. :attr:`urls` says where each device is.

    Each camera first renders the frames of the drive's first ``prerender_s`` seconds
    (the two cameras at once, a core each; later frames are rendered when due); the
    drive starts, ``t_origin``, when all have, so that the cameras send every frame on
    time however busy the machine is while recording."""

    def __init__(
        self, prerender_s: float = 0.0, *, loopback: bool = False, gnss: bool = False
    ) -> None:

        self.t_origin = math.nan
        self.cameras: dict[str, MjpegServerProcess] = {}
        self.server: Any = None
        self.gnss_server: DeviceServer | None = None
        self.receiver: NmeaDevice | None = None
        self.car: Any = None
        self.can_options: dict[str, Any] = {}
        if loopback:
            self.can_interface = "udp_multicast"
            self.can_channel, self.can_options = multicast_can()
        else:
            # a virtual bus is one process's: a name of its own (two demos, the test suite)
            self.can_interface = CAN_INTERFACE
            self.can_channel = f"acq-demo-{os.getpid()}-{time.monotonic_ns()}"
        self._tmp: str | None = None  # holds the ptys' links
        model = MODELS[SCANNER_MODEL]
        # the camera processes start (load their renderer, render their first frames)
        # while the scanner is built
        started: dict[str, Any] = {}

        def start_camera(name: str) -> None:
            try:
                started[name] = MjpegServerProcess(**camera_sim(name), prerender_s=prerender_s)
            except Exception as e:  # raised in the caller below
                started.setdefault("error", e)

        threads = [
            threading.Thread(target=start_camera, args=(name,), name=f"sim-{name}-start")
            for name in CAMERAS
        ]
        for thread in threads:
            thread.start()
        try:
            try:
                self.source = StreetSource(model, rig=demo_rig(), seed=0)
                clock = SimClock(
                    tick_hz=model.clock_hz,
                    wrap_bits=model.clock_bits,
                    drift_ppm=SCANNER_DRIFT_PPM,
                    offset_ticks=1234567.0,
                )
                self.scanner = ScipDevice(model, source=self.source, clock=clock)
                self._tmp = tempfile.mkdtemp(prefix="acq-demo-")
                if loopback:
                    self.server = TcpDeviceServer(self.scanner).start()
                else:
                    link = Path(self._tmp) / "ttyACM-sim"
                    self.server = PtyDeviceServer(self.scanner, link=link).start()
            finally:
                for thread in threads:
                    thread.join()
                self.cameras = {name: started[name] for name in CAMERAS if name in started}
            if "error" in started:
                raise RuntimeError(f"a simulated camera did not start: {started['error']}")
            self.t_origin = self.source.t_origin = time.monotonic()
            for camera in self.cameras.values():
                camera.start(self.t_origin)
            # the car and the receiver: the scanner's trajectory, looping with the street
            self.car = SimVehicle(
                self.can_interface,
                self.can_channel,
                trajectory=self.source.trajectory,
                t_origin=self.t_origin,
                loop_s=self.loop_s,
                bus_options=self.can_options,
            ).start()
            if gnss:
                self.receiver = NmeaDevice(
                    self.source.trajectory,
                    latency_s=GNSS_LATENCY_S,
                    sentences=("RMC", "VTG", "GGA", "GST", "GSA"),
                    t_origin=self.t_origin,
                    loop_s=self.loop_s,
                )
                if loopback:
                    self.gnss_server = TcpDeviceServer(self.receiver).start()
                else:
                    link = Path(self._tmp) / "ttyUSB-gnss"
                    self.gnss_server = NmeaPtyServer(self.receiver, link=link).start()
        except BaseException:
            self.close()
            raise

    @property
    def urls(self) -> dict[str, str]:
        """Where each device is: ``laser``, every camera, ``vehicle`` (the CAN bus as
        ``interface:channel``) and ``gnss`` (when there is a receiver)."""
        urls = {"laser": str(self.server.url)}
        urls.update({name: camera.url for name, camera in self.cameras.items()})
        urls["vehicle"] = f"{self.can_interface}:{self.can_channel}"
        if self.gnss_server is not None:
            urls["gnss"] = self.gnss_server.url
        return urls

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
        if self.gnss_server is not None:
            self.gnss_server.close()
            self.gnss_server = None
        if self.server is not None:
            self.server.close()
            self.server = None
        for camera in self.cameras.values():
            camera.close()
        self.cameras = {}
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None


def rig_config(rig: SimRig, calibration: Path, output: dict[str, Any]) -> dict[str, Any]:
    """The recorder's configuration (as YAML data) for ``rig``: the scanner, every camera
    through the OpenCV driver on its own URL (its latency what the driver subtracts from
    receipt, :func:`camera_latency_s`), the car's CAN bus, the receiver (stamped from
    receipt less its latency: a simulated fix's UTC is the host's own clock, which need
    not be disciplined), the ``calibration`` file and the ``output`` section."""
    data: dict[str, Any] = {
        "version": 1,
        "scanners": [
            {
                "name": "laser",
                "driver": "hokuyo",
                "url": rig.server.url,
                "latency_s": "auto",
                "options": {"intensity": True},
            }
        ],
        "cameras": [
            {
                "name": name,
                "driver": "opencv",
                "source": camera.url,
                "fps": CAMERA_SIM["fps"],
                "latency_s": round(camera_latency_s(name), 6),
            }
            for name, camera in rig.cameras.items()
        ],
        "can": {  # the signals are the config's defaults, those of sim/vehicle.dbc
            "interface": rig.can_interface,
            "channel": rig.can_channel,
            "dbc": str(DBC_PATH.resolve()),
            **({"options": dict(rig.can_options)} if rig.can_options else {}),
        },
    }
    if rig.gnss_server is not None:
        data["gnss"] = {"url": rig.gnss_server.url, "time": "receipt", "latency_s": GNSS_LATENCY_S}
    data["calibration"] = str(calibration)
    data["output"] = dict(output)
    return data


def true_calibration(rig: Rig | None = None) -> Calibration:
    """The true calibration of ``rig`` (default the demo's): every camera's lens
    (kannala_brandt) and ``camera_to_laser``, and the laser on the vehicle."""

    rig = rig if rig is not None else demo_rig()
    return Calibration(
        laser="laser",
        cameras={
            c.name: CameraCalib(c.lens, c.camera_to_laser, method="simulator truth")
            for c in rig.cameras
        },
        laser_to_vehicle=rig.laser_to_vehicle,
    )
