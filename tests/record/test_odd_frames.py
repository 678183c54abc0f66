"""A camera that sends a frame of another size: the recorder writes it, counts it in the
device's state and /acq/status, and logs it (1st, 2nd, 4th...); `acq info` shows the
count. The camera is a small MJPEG server on 127.0.0.1 sending frames of chosen sizes."""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import Equidistant
from acq.drivers.mjpeg import jpeg_size
from acq.log import info
from acq.record.adapters import CameraAdapter
from acq.record.config import Config, parse
from acq.record.device_loop import Outbox, run_device
from acq.record.recorder import Recorder
from tests.sim_rig import read_log

# a camera and a recorder in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

HEAD = b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n\r\n"


class SizedCamera:
    """MJPEG over HTTP on 127.0.0.1, 25 frames a second, frame ``i`` (from 0 on each
    connection) of ``size(i)`` (width, height) px."""

    def __init__(self, size: Callable[[int], tuple[int, int]]) -> None:
        self.size = size
        self._jpegs: dict[tuple[int, int], bytes] = {}
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.1)
        self.url = f"http://127.0.0.1:{self._listener.getsockname()[1]}/stream.mjpg"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _jpeg(self, size: tuple[int, int]) -> bytes:
        if size not in self._jpegs:
            w, h = size
            ok, buf = cv2.imencode(".jpg", np.full((h, w, 3), 100, np.uint8))
            assert ok
            self._jpegs[size] = buf.tobytes()
        return self._jpegs[size]

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                sock, _ = self._listener.accept()
            except TimeoutError:
                continue
            with sock, contextlib.suppress(OSError):
                request = b""
                while b"\r\n\r\n" not in request:
                    request += sock.recv(1024)
                sock.sendall(HEAD)
                i = 0
                while not self._stop.is_set():
                    body = self._jpeg(self.size(i))
                    head = f"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: {len(body)}"
                    sock.sendall(head.encode() + b"\r\n\r\n" + body + b"\r\n")
                    i += 1
                    self._stop.wait(0.04)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._listener.close()


def _config(url: str, tmp_path: Path) -> Config:
    return parse({
        "version": 1,
        "cameras": [{"name": "camera", "driver": "opencv", "source": url, "fps": 25}],
        "output": {"dir": str(tmp_path)},
    })  # fmt: skip


def _odd_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and "recorded, flagged" in r.getMessage()
    ]


def test_odd_sized_frames_are_recorded_counted_and_reported(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The calibration's size is expected, though the first frame is of another."""
    camera = SizedCamera(lambda i: (32, 24) if i in (0, 5) else (64, 48))
    model = Equidistant.from_f(20.0, 31.5, 23.5, 64, 48)
    calib = Calibration(cameras={"camera": CameraCalib(model)})
    try:
        with caplog.at_level(logging.WARNING):
            recorder = Recorder(_config(camera.url, tmp_path), duration_s=1.6, calibration=calib)
            assert recorder.run() == 0
    finally:
        camera.close()
    [path] = sorted(tmp_path.glob("*.mcap"))
    log = read_log(path)
    sizes = [jpeg_size(m.data) for _, _, m in log["/camera/image/compressed"]]
    assert len(sizes) == recorder.devices["camera"].received > 20  # every frame written
    assert sizes[:7] == [(32, 24), *[(64, 48)] * 4, (32, 24), (64, 48)]
    assert set(sizes[7:]) == {(64, 48)}
    last: Any = log["/acq/status"][-1][2]
    [status] = [d for d in last.devices if d.name == "camera"]
    assert status.odd_size == 2
    assert info(path).odd_size == {"camera": 2}
    assert _odd_warnings(caplog) == [
        f"camera: a 32x24 frame, not 64x48 as the calibration's camera model: recorded, "
        f"flagged ({n} so far)"
        for n in (1, 2)
    ]


def test_without_a_calibration_the_size_is_the_cameras_own(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    camera = SizedCamera(lambda i: (48, 32) if i in (3, 4, 5, 7) else (64, 48))
    adapter = CameraAdapter(_config(camera.url, tmp_path).cameras[0])
    outbox, stop = Outbox(64), threading.Event()
    reader = threading.Thread(target=run_device, args=(adapter, outbox, stop))
    try:
        with caplog.at_level(logging.WARNING):
            reader.start()
            deadline = time.monotonic() + 20
            while adapter.state.received < 10 and time.monotonic() < deadline:
                time.sleep(0.02)
            stop.set()
            reader.join(timeout=10)
    finally:
        stop.set()
        camera.close()
    assert not reader.is_alive()
    assert adapter.state.received >= 10 and adapter.state.odd_size == 4
    assert outbox.qsize() == adapter.state.received  # every frame goes to the writer
    assert _odd_warnings(caplog) == [
        f"camera: a 48x32 frame, not 64x48 as the camera's format: recorded, flagged ({n} so far)"
        for n in (1, 2, 4)
    ]
