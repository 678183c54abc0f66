"""CPU cost of the camera capture path at 780x582, 25 Hz: one JSON line per result.

(a) ``mjpeg_passthrough``: the OpenCV driver reading the simulated camera's MJPEG stream
    over HTTP on 127.0.0.1 (the camera in another process); CPU time of the reading
    thread (``time.thread_time()``) per frame, bytes kept as sent, markers checked.
(b) ``jpeg_encode``: frames that arrive raw and must be JPEG-encoded (``cv2.imencode``
    at quality 90); process CPU time (``time.process_time()``, all of OpenCV's threads).
(c) ``jpeg_check_markers`` / ``jpeg_check_decode``: the two ``verify`` options' cost.

``share_of_core_25hz`` is CPU seconds per second at 25 frames/s (1.0 = one core).
Targets: under 0.02 for passthrough, under 0.10 with encoding.
Run as a script: ``python bench/camera.py [--seconds S]``.
"""

from __future__ import annotations

import argparse
import json
import time

import cv2
import numpy as np

from acq.drivers.camera_opencv import OpenCVCamera
from acq.drivers.mjpeg import jpeg_size
from acq.sim.camera_device import SimCamera
from acq.sim.mjpeg_process import MjpegServerProcess
from acq.sim.world import Street

FPS = 25.0


def _line(bench: str, cpu_per_frame_s: float, frames: int, **extra: object) -> None:
    print(
        json.dumps(
            {
                "bench": bench,
                "width": 780,
                "height": 582,
                "frames": frames,
                "cpu_ms_per_frame": round(cpu_per_frame_s * 1e3, 4),
                "share_of_core_25hz": round(cpu_per_frame_s * FPS, 5),
                **extra,
            }
        ),
        flush=True,
    )


def passthrough(seconds: float) -> None:
    with MjpegServerProcess(seed=1) as srv:
        cam = OpenCVCamera(srv.url, fps=FPS, timeout=2.0)
        cam.connect()
        for _ in range(10):  # warm up
            cam.read_frame()
        server_cpu0 = srv.cpu_seconds()
        cpu0, wall0 = time.thread_time(), time.monotonic()
        n, size = 0, 0
        while time.monotonic() - wall0 < seconds:
            size += len(cam.read_frame().jpeg)
            n += 1
        cpu = time.thread_time() - cpu0
        server_cpu = srv.cpu_seconds() - server_cpu0
        cam.close()
    _line(
        "mjpeg_passthrough",
        cpu / n,
        n,
        mean_jpeg_bytes=round(size / n),
        drops=cam.drops,
        corrupt=cam.corrupt,
        sim_server_cpu_ms_per_frame=round(server_cpu / n * 1e3, 3),
        target_share=0.02,
    )


def _cpu_per_call(fn: object, calls: int) -> float:
    assert callable(fn)
    fn()
    t0 = time.process_time()
    for _ in range(calls):
        fn()
    return (time.process_time() - t0) / calls


def encode_and_checks() -> None:
    cam = SimCamera(Street.generate(seed=0, length_m=200.0))
    image = cam.render(cam.t_origin + 5.0)
    params = [cv2.IMWRITE_JPEG_QUALITY, 90]
    calls = 100
    _line(
        "jpeg_encode",
        _cpu_per_call(lambda: cv2.imencode(".jpg", image, params), calls),
        calls,
        quality=90,
        opencv_threads=cv2.getNumThreads(),
        target_share=0.10,
    )
    data = cv2.imencode(".jpg", image, params)[1].tobytes()
    _line("jpeg_check_markers", _cpu_per_call(lambda: jpeg_size(data), 2000), 2000)
    buf = np.frombuffer(data, np.uint8)
    _line(
        "jpeg_check_decode",
        _cpu_per_call(lambda: cv2.imdecode(buf, cv2.IMREAD_UNCHANGED), calls),
        calls,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="passthrough run length")
    args = parser.parse_args()
    passthrough(args.seconds)
    encode_and_checks()


if __name__ == "__main__":
    main()
