"""The recorder against hostile and absent devices, over real transports on 127.0.0.1: a
camera whose MJPEG part header is hostile (a superscript digit in its length), a camera
URL with nothing listening (a password in it and in its query), and a good simulated
UTM-30LX that must record on through both; required devices; the credentials of device
URLs kept out of the log lines and the MCAP file."""

from __future__ import annotations

import logging
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from acq.cli.main import main
from acq.record import config as configfile
from acq.record.recorder import EXIT_FAILURE, Recorder
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from tests.sim_rig import read_log

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]
SECRET = "S3CRET"
QUERY = f"?cmd=GetMJStream&usr=admin&pwd={SECRET}"  # a Foscam's credentials
JPEG = cv2.imencode(".jpg", np.full((48, 64, 3), 128, np.uint8))[1].tobytes()


class HostileCamera:
    """An MJPEG-over-HTTP camera that, on every connection, sends one good frame, then a
    part whose ``Content-Length`` holds a superscript digit (``4\\xb2``: ``str.isdigit``
    accepts it, ``int`` does not), then nothing."""

    def __init__(self) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.streams = 0  # connections that asked for the stream
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        self.server.settimeout(0.1)
        while not self._stop.is_set():
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            conn.settimeout(3.0)
            request = b""
            try:
                while b"\r\n\r\n" not in request:
                    data = conn.recv(4096)
                    if not data:
                        return  # a reachability probe
                    request += data
                self.streams += 1
                conn.sendall(b"HTTP/1.1 200 OK\r\n"
                             b"Content-Type: multipart/x-mixed-replace; boundary=frame\r\n\r\n"
                             b"--frame\r\nContent-Type: image/jpeg\r\n"
                             b"Content-Length: %d\r\n\r\n%b\r\n" % (len(JPEG), JPEG))  # fmt: skip
                time.sleep(0.1)  # the good frame is read alone, the bad part after it
                conn.sendall(b"--frame\r\nContent-Type: image/jpeg\r\n"
                             b"Content-Length: 4\xb2\r\n\r\nabcd\r\n")  # fmt: skip
                while conn.recv(4096):  # until the client gives up
                    pass
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self.server.close()


def closed_port() -> int:
    """A port on 127.0.0.1 with nothing listening."""
    with socket.create_server(("127.0.0.1", 0)) as s:
        return int(s.getsockname()[1])


@pytest.fixture
def hostile() -> Iterator[HostileCamera]:
    cam = HostileCamera()
    try:
        yield cam
    finally:
        cam.close()


def write_config(tmp_path: Path, scanner_url: str, cameras: list[dict[str, object]]) -> Path:
    data = {
        "version": 1,
        "scanners": [{"name": "laser", "driver": "hokuyo", "url": scanner_url}],
        "cameras": cameras,
        "output": {"dir": str(tmp_path / "logs")},
    }
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def dead_camera(**extra: object) -> dict[str, object]:
    url = f"http://admin:{SECRET}@127.0.0.1:{closed_port()}/stream.mjpg{QUERY}"
    return {"name": "dead", "driver": "opencv", "source": url, "fps": 25, **extra}


def _stamp(line: str) -> float:
    """The time of a terminal log line (``2024-05-01 12:00:00,123 LEVEL ...``), s."""
    return datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()


def test_a_failing_device_is_contained_and_credentials_stay_out(
    scanner: TcpDeviceServer, hostile: HostileCamera, tmp_path: Path
) -> None:
    cameras = [
        {"name": "hostile", "driver": "opencv", "fps": 5,
         "source": f"http://admin:{SECRET}@127.0.0.1:{hostile.port}/stream.mjpg{QUERY}"},
        dead_camera(required=False),  # optional: the recording exits 0 without it
    ]  # fmt: skip
    cfg = write_config(tmp_path, scanner.url, cameras)
    duration = 5.0

    def pull_the_laser() -> None:  # a required device that goes away later
        time.sleep(duration - 1.0)
        scanner.reboot(2.0)

    threading.Thread(target=pull_the_laser, daemon=True).start()
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg), "--duration", str(duration),
         "--require", "laser", "-v"],
        cwd=ROOT, capture_output=True, timeout=60,
    )  # fmt: skip
    took = time.monotonic() - t0
    err = done.stderr.decode(errors="replace")
    assert done.returncode == 0, err
    assert took > duration  # it recorded to the end
    assert "required: laser" in err

    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(path)
    # the good scanner recorded throughout, while the camera kept failing
    scans = np.array([t for t, _, _ in log["/laser/scan"]]) * 1e-9
    assert len(scans) > 100 and scans[-1] - scans[0] > duration - 3.0
    assert hostile.streams >= 2  # the camera was reopened after its failure
    status = [m for _, _, m in log["/acq/status"]]
    bad = [next(d for d in s.devices if d.name == "hostile") for s in status]
    # its bad part a protocol error, its silence after it a stall: counted and reported
    assert bad[-1].disconnects >= 1 and bad[-1].protocol_errors >= 1, bad[-1]
    assert any("Content-Length" in d.last_event for d in bad), [d.last_event for d in bad]
    dead = next(d for d in status[-1].devices if d.name == "dead")
    assert not dead.connected and dead.received == 0 and dead.gap_s > 4.0
    assert "connect_failed" in dead.last_event and "refused" in dead.last_event

    lines = err.splitlines()
    assert any(" WARNING " in x and "hostile" in x and "Content-Length" in x for x in lines)
    start = next(_stamp(x) for x in lines if "INFO acq.record: recording " in x)
    warning = next(x for x in lines if " WARNING " in x and "dead:" in x)
    assert "refused" in warning and "not connected" in warning
    after = _stamp(warning) - start
    assert after < 5.0
    print(f"the first warning of the dead camera came {after:.2f} s after the start")

    # no password anywhere: log lines, the file's bytes, its metadata and messages
    assert SECRET not in err
    assert "http://***@127.0.0.1" in err
    assert SECRET.encode() not in path.read_bytes()
    with path.open("rb") as f:
        reader = make_reader(f)
        metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
        messages = [m.data for _, _, m in reader.iter_messages()]
    assert SECRET not in repr(metadata)
    assert not any(SECRET.encode() in data for data in messages)
    described = dict(metadata)["device.hostile"]["info"]
    at = f"http://***@127.0.0.1:{hostile.port}/stream.mjpg?cmd=GetMJStream&usr=admin&pwd=***"
    assert at in described
    assert "pwd=***" in dict(metadata)["config"]["yaml"]


def test_a_required_device_without_a_record_stops_the_recorder(
    scanner: TcpDeviceServer, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cfg = configfile.load(write_config(tmp_path, scanner.url, [dead_camera(required=True)]))
    t0 = time.monotonic()
    with caplog.at_level(logging.INFO, logger="acq.record"):
        code = Recorder(cfg, duration_s=20.0, required_within_s=1.0).run()
    took = time.monotonic() - t0
    assert code == EXIT_FAILURE
    assert took < 5.0
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1, errors
    assert re.search(r"required device without a record 1 s after the start: dead not "
                     r"connected \(connect_failed: .*refused", errors[0]), errors[0]  # fmt: skip
    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    assert read_log(path)["/laser/scan"]  # the file was closed, with what was recorded


def test_a_record_that_cannot_be_encoded_is_a_bad_record_of_its_device(
    scanner: TcpDeviceServer, tmp_path: Path
) -> None:
    cfg = configfile.load(write_config(tmp_path, scanner.url, []))
    recorder = Recorder(cfg, duration_s=1.0)
    laser = recorder.adapters[0]
    write, calls = laser.write, [0]

    def buggy_encoder(writer: Any, payload: Any) -> None:
        calls[0] += 1
        if calls[0] == 3:
            raise IndexError("index 1081 is out of bounds for axis 0 with size 1081")
        write(writer, payload)

    laser.write = buggy_encoder  # type: ignore[method-assign]
    assert recorder.run() == 0
    assert laser.state.protocol_errors == 1
    assert laser.state.last_event == (
        "protocol_error: IndexError: index 1081 is out of bounds for axis 0 with size 1081"
    )
    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    assert len(read_log(path)["/laser/scan"]) == calls[0] - 1 > 20


@pytest.fixture
def cli_logging() -> Iterator[None]:
    """`acq record` sets up the process's logging: put it back afterwards."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    try:
        yield
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)


def test_require_names_a_device_of_the_configuration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], cli_logging: None
) -> None:
    cfg = write_config(tmp_path, "socket://127.0.0.1:9", [])
    assert main(["record", "-c", str(cfg), "--require", "laser", "lidar"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]  # after the log lines
    assert last == (
        "acq record: --require: no device named 'lidar'; the configuration's devices: laser"
    )


def test_a_scanner_that_never_connected_fails_the_recording_and_is_named(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two scanners: ``laser`` never connects (nothing listens on its port), ``laser2``
    records for about a second and then goes away for good. The recorder exits 1, its
    closing lines name both (an error, a warning), and `acq info` on the file warns for
    both."""
    gone = TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start()
    data = {
        "version": 1,
        "scanners": [
            {"name": "laser", "driver": "hokuyo", "url": f"socket://127.0.0.1:{closed_port()}"},
            {"name": "laser2", "driver": "hokuyo", "url": gone.url, "latency_s": 0.0},
        ],
        "output": {"dir": str(tmp_path / "logs")},
    }
    recorder = Recorder(configfile.parse(data), duration_s=6.0)
    laser2 = recorder.devices["laser2"]

    def pull_laser2() -> None:  # once it has recorded
        deadline = time.monotonic() + 3.0
        while not laser2.received and time.monotonic() < deadline:
            time.sleep(0.02)
        gone.close()

    threading.Thread(target=pull_laser2, daemon=True).start()
    try:
        with caplog.at_level(logging.INFO, logger="acq.record"):
            code = recorder.run()
    finally:
        gone.close()
    assert code == EXIT_FAILURE
    closing = [(r.levelno, r.getMessage()) for r in caplog.records]
    errors = [m for level, m in closing if level == logging.ERROR]
    assert len(errors) == 1, errors
    assert errors[0].startswith("scanner laser recorded nothing: not connected (connect_failed")
    assert "refused" in errors[0] and "exit status 1" in errors[0]
    stopped = re.compile(r"scanner laser2 stopped recording \d+\.\d s before the end")
    assert any(level == logging.WARNING and stopped.match(m) for level, m in closing), closing
    assert any(m.startswith("stopped after ") and "laser 0, laser2 " in m for _, m in closing)

    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    assert main(["info", str(path)]) == 0
    warnings = [x.strip() for x in capsys.readouterr().out.splitlines() if "warning:" in x]
    assert any(x.startswith("warning: scanner laser recorded nothing: not connected")
               for x in warnings), warnings  # fmt: skip
    assert any(re.match(r"warning: scanner laser2 stopped recording \d+\.\d s before the end",
                        x) for x in warnings), warnings  # fmt: skip


def test_an_optional_device_that_recorded_nothing_is_a_warning(
    scanner: TcpDeviceServer, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """``required: false``: a camera that never connects is named, and the exit status is 0."""
    cfg = configfile.load(write_config(tmp_path, scanner.url, [dead_camera(required=False)]))
    with caplog.at_level(logging.INFO, logger="acq.record"):
        assert Recorder(cfg, duration_s=1.5).run() == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(
        m.startswith("camera dead recorded nothing: not connected") and "optional" in m
        for m in warnings
    ), warnings
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
