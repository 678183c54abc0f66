"""A camera delivering frames far above its configured fps: the recorder warns (naming
it, the configured and the measured rate, repeated with a backoff), counts the time in
/acq/status, and `acq info` warns. The camera is the simulated MJPEG server on 127.0.0.1
flooding tiny valid JPEGs back to back (thousands a second)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from acq.log import format_info, info
from acq.record.config import parse
from acq.record.device_loop import DeviceState
from acq.record.recorder import Recorder
from sim.mjpeg_server import serve_camera
from tests.sim_rig import read_log

FPS = 10.0  # configured


def _fast_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and "records/s for" in r.getMessage()
    ]


@pytest.mark.realtime
def test_a_flooding_camera_is_warned_about_counted_and_reported(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ok, jpeg = cv2.imencode(".jpg", np.full((8, 8, 3), 100, np.uint8))
    assert ok
    with serve_camera("http://127.0.0.1:0/stream.mjpg") as server:
        server.flood(60.0, jpeg.tobytes())
        config = parse({
            "version": 1,
            "cameras": [{"name": "camera", "driver": "opencv", "source": server.url, "fps": FPS}],
            "output": {"dir": str(tmp_path)},
        })  # fmt: skip
        with caplog.at_level(logging.WARNING):
            recorder = Recorder(config, duration_s=5.0)
            assert recorder.run() == 0
    state = recorder.devices["camera"]
    assert state.received > 10 * FPS * 5.0  # far faster than configured, all recorded
    # warned after 2 s of it (the next only 5 s later); on a busy machine the server,
    # a thread of this process, may stall the stream a second, and the watch starts again
    warnings = _fast_warnings(caplog)
    assert 1 <= len(warnings) <= 2, warnings
    warning = warnings[0]
    assert warning.startswith("camera: ") and "configured 10/s" in warning
    assert float(warning.split()[1]) > 1.5 * FPS  # the measured rate
    [path] = sorted(tmp_path.glob("*.mcap"))
    last: Any = read_log(path)["/acq/status"][-1][2]
    [status] = [d for d in last.devices if d.name == "camera"]
    assert status.fast_s > 1.0
    [fast] = info(path).fast
    assert fast.name == "camera" and fast.configured_hz == FPS and fast.rate_hz > 10 * FPS
    assert "warning: camera recorded" in format_info(info(path))


def test_the_rate_watch_waits_warns_with_a_backoff_and_forgets(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Records counted at chosen host times (no device: the watch's arithmetic)."""
    state = DeviceState("camera", "camera", expected_hz=10.0)
    t_ns = 0

    def run(seconds: float, hz: float) -> None:
        nonlocal t_ns
        end = t_ns + round(seconds * 1e9)
        while t_ns < end:
            t_ns += round(1e9 / hz)
            state.count(t_ns)
            state.watch_rate(t_ns)

    def fast_for_s() -> list[int]:  # "camera: 100 records/s for 2 s, ..."
        return [int(w.split(" for ")[1].split()[0]) for w in _fast_warnings(caplog)]

    with caplog.at_level(logging.WARNING):
        run(10.0, 14.0)  # 1.4 times: not too fast
        assert fast_for_s() == [] and state.fast_s == 0.0
        run(20.0, 100.0)  # 10 times: warned after 2 s, then 5 and 10 s later
        assert fast_for_s() == [2, 7, 17]
        assert _fast_warnings(caplog)[0].startswith(
            "camera: 100 records/s for 2 s, configured 10/s"
        )
        assert state.fast_s == pytest.approx(20.0, abs=0.5)
        run(5.0, 10.0)  # back to its rate: the watch starts afresh
        run(3.0, 100.0)
        assert fast_for_s() == [2, 7, 17, 2]
