"""A simulated rig for the recorder, replay and demo tests: a UTM-30LX speaking SCIP on
TCP (in this process), the fisheye camera serving MJPEG over HTTP (in its own process, a
still scene: it keeps its rate on a busy machine) and, if asked, the car on a python-can
``virtual`` bus and a GNSS receiver on TCP (in this process), with a recorder
configuration pointing at them."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import yaml

from acq.log.reader import LogReader
from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.can_vehicle import DBC_PATH, SimVehicle
from acq.sim.mjpeg_process import MjpegServerProcess
from acq.sim.nmea_device import NmeaDevice
from acq.sim.replay import Replay
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer


class Rig:
    """A simulated rig: a UTM-30LX on TCP and fisheye cameras over HTTP, each in its own
    process (default one, ``camera``; ``self.camera`` is the first, None without any);
    with ``vehicle``, the car (:attr:`car`, a ``virtual`` bus: a recorder in this process)
    and a GNSS receiver (:attr:`receiver`, 10 Hz on TCP)."""

    def __init__(self, cameras: tuple[str, ...] = ("camera",), vehicle: bool = False) -> None:
        self.scanner = ScipDevice(MODELS["utm-30lx"])
        self.scanner_server = TcpDeviceServer(self.scanner).start()
        self.cameras = {
            name: MjpegServerProcess(seed=k, still=True) for k, name in enumerate(cameras)
        }
        self.camera = next(iter(self.cameras.values()), None)
        self.car: SimVehicle | None = None
        self.receiver: NmeaDevice | None = None
        self.gnss_server: TcpDeviceServer | None = None
        if vehicle:
            self.car = SimVehicle(channel=f"acq-test-{id(self)}").start()
            self.receiver = NmeaDevice()
            self.gnss_server = TcpDeviceServer(self.receiver).start()

    def config(
        self, tmp_path: Path, latency: float | str = "auto", **output: object
    ) -> configfile.Config:
        data = {
            "version": 1,
            "scanners": [
                {"name": "laser", "driver": "hokuyo", "url": self.scanner_server.url,
                 "options": {"intensity": True}, "latency_s": latency},
            ],
            "cameras": [
                {"name": name, "driver": "opencv", "source": camera.url, "fps": 25,
                 "latency_s": 0.022}
                for name, camera in self.cameras.items()
            ],
            "output": {"dir": str(tmp_path / "logs"), **output},
        }  # fmt: skip
        if self.car is not None and self.gnss_server is not None:
            data["can"] = {
                "interface": "virtual",
                "channel": self.car.channel,
                "dbc": str(DBC_PATH),
            }
            data["gnss"] = {"url": self.gnss_server.url, "time": "receipt"}  # fmt: skip
        path = tmp_path / "rig.yaml"
        path.write_text(yaml.safe_dump(data))
        return configfile.load(path)

    def calibration(self, tmp_path: Path) -> Path:
        """The simulated rig's true calibration, for its cameras, as ``calib.yaml``."""
        from acq.camera import calibfile
        from acq.camera.calibfile import Calibration, CameraCalib
        from acq.sim.world import default_rig

        truth = default_rig()
        lens = CameraCalib(truth.lens, truth.camera_to_laser, method="truth")
        calib = Calibration(
            laser="laser",
            cameras=dict.fromkeys(self.cameras, lens),
            laser_to_vehicle=truth.laser_to_vehicle,
        )
        path = tmp_path / "calib.yaml"
        calibfile.save(calib, path)
        return path

    def warm_up(self) -> Rig:
        """Read a few frames and scans, so no test pays for the simulators' first frames."""
        from acq.drivers.camera_opencv import OpenCVCamera
        from acq.drivers.scip import ScipScanner

        for camera in self.cameras.values():
            with OpenCVCamera(camera.url, timeout=30.0) as cam:
                cam.connect()
                cam.start()
                for _ in range(3):
                    cam.read_frame()
        scanner = ScipScanner(self.scanner_server.url, timeout=5.0)
        try:
            scanner.connect()
            scanner.start()
            for _ in range(3):
                scanner.read_scan()
        finally:
            scanner.close()
        return self

    def close(self) -> None:
        self.scanner_server.close()
        if self.car is not None:
            self.car.close()
        if self.gnss_server is not None:
            self.gnss_server.close()
        for camera in self.cameras.values():
            camera.close()


def warm_rig(cameras: tuple[str, ...] = ("camera",)) -> Iterator[Rig]:
    """A warmed-up :class:`Rig`, closed after use: the body of a module's rig fixture."""
    r = Rig(cameras)
    try:
        yield r.warm_up()
    finally:
        r.close()


def read_log(path: Path) -> dict[str, list[tuple[int, int, object]]]:
    """topic -> [(log_time, publish_time, decoded message)], all host monotonic ns, as
    acq's reader gives them (the file's UTC times less the session's offset)."""
    out: dict[str, list[tuple[int, int, object]]] = {}
    reader = LogReader(path)
    for schema, channel, message in reader.messages():
        decoded = reader.decode(schema, channel, message)
        out.setdefault(channel.topic, []).append((message.log_time, message.publish_time, decoded))
    return out


def record_replay(replay: Replay, cfg: configfile.Config, timeout_s: float) -> None:
    """Record ``replay`` with a recorder of ``cfg`` (in a thread) until it has been served
    to its end, within ``timeout_s``; asserts the recorder exits 0 and the replay saw no
    error."""
    recorder = Recorder(cfg)
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(recorder.run()))
    thread.start()
    try:
        assert replay.wait(timeout=timeout_s), "the replay did not play to its end"
    finally:
        recorder.stop()
        thread.join(10)
    assert codes == [0]
    assert not replay.errors
