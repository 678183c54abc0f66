"""A camera's hiccups through the recorder's camera path, on a loaded machine: one JSON
line per result.

The simulated fisheye serves MJPEG over HTTP from its own process
(:class:`acq.sim.mjpeg_process.MjpegServerProcess`); the recorder's camera path reads it
(:class:`acq.record.adapters.CameraAdapter` in :func:`acq.record.device_loop.run_device`,
the OpenCV driver through its :class:`acq.drivers.reconnect.CameraLink`), with two busy
loops (``python -c 'while 1: pass'``) beside it on this machine's cores.

(a) ``camera_stall``: the camera sends nothing for a few frame periods (its connection
    stays open); ``closed`` counts the trials in which the recorder closed the stream
    (it must not: the frames resume on it), ``gap_s`` the longest time between two frames.
(b) ``camera_outage``: the connection really goes: ``drop`` (the camera closes every
    connection and keeps running) and ``restart`` (the camera's process killed, a new one
    started on the same port ``down_s`` later); ``back_s`` is the time from the source
    being back (the drop; the new process serving) to the first frame recorded
    (target: under 0.5 s); ``freeze``: the camera's process stopped (SIGSTOP) for
    ``down_s``, its connection open, then resumed: from the resumption.
``--live``: the camera renders each frame when due instead of first (a frame costs it
20-40 ms of a core, more beside the busy loops: it falls behind).

Run as a script: ``python bench/camera_hiccup.py [--trials N] [--no-load] [--live]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import os
import socket
import statistics
import subprocess
import sys
import threading
import time
from typing import Any

from acq.record.adapters import CameraAdapter
from acq.record.config import CameraConfig
from acq.record.device_loop import Outbox, run_device
from acq.sim.mjpeg_process import MjpegServerProcess

FPS = 25.0
# the camera renders its frames first (a frame costs 20-40 ms of a core, and more beside
# the busy loops), then sends them in real time as a real camera would: the figures are
# the recorder's, not the renderer's falling behind
PRERENDER_S = 60.0
RESTART_PRERENDER_S = 3.0
FREEZE_S = 2.0  # the camera's process stopped this long (longer than CAMERA_STALL_S)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class CameraPath:
    """The recorder's camera path on its own thread; the receipt times it delivers."""

    def __init__(self, url: str) -> None:
        cfg = CameraConfig(name="camera", driver="opencv", source=url, fps=FPS, latency_s=0.022)
        self.adapter = CameraAdapter(cfg)
        self.outbox = Outbox(1000)
        self.stop = threading.Event()
        self.recv: list[int] = []
        self._threads = [
            threading.Thread(
                target=run_device, args=(self.adapter, self.outbox, self.stop), daemon=True
            ),
            threading.Thread(target=self._drain, daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _drain(self) -> None:
        while not self.stop.is_set():
            item = self.outbox.get(0.05)
            if item is not None:
                self.recv.append(item.payload.frame.recv_ns)  # type: ignore[attr-defined]

    @property
    def disconnects(self) -> int:
        return self.adapter.state.disconnects

    def wait_frames(self, n: int, timeout: float = 20.0) -> None:
        target = len(self.recv) + n
        deadline = time.monotonic() + timeout
        while len(self.recv) < target and time.monotonic() < deadline:
            time.sleep(0.01)
        if len(self.recv) < target:
            raise RuntimeError(f"no {n} frames within {timeout} s")

    def first_after(self, t_ns: int, timeout: float = 10.0) -> int | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            after = [t for t in self.recv[-50:] if t > t_ns]
            if after:
                return after[0]
            time.sleep(0.005)
        return None

    def close(self) -> None:
        self.stop.set()
        for t in self._threads:
            t.join(5.0)


def _line(bench: str, **fields: Any) -> None:
    load_1min = round(os.getloadavg()[0], 1)
    print(json.dumps({"bench": bench, **fields, "load_1min": load_1min}), flush=True)


def stalls(path: CameraPath, server: MjpegServerProcess, trials: int, load: int) -> None:
    for periods in (3, 5, 8):
        stall_s = periods / FPS
        closed, gaps = 0, []
        for _ in range(trials):
            path.wait_frames(10)
            before, start = path.disconnects, len(path.recv)
            server.stall(stall_s)
            path.wait_frames(10)
            closed += path.disconnects > before
            recv = path.recv[start - 1 :]
            gaps.append(max(b - a for a, b in itertools.pairwise(recv)) * 1e-9)
        _line("camera_stall", busy_loops=load, stall_periods=periods, stall_s=stall_s,
              trials=trials, closed=closed, gap_s_max=round(max(gaps), 3),
              gap_s_median=round(statistics.median(gaps), 3))  # fmt: skip


def drops(path: CameraPath, server: MjpegServerProcess, trials: int, load: int) -> None:
    backs = []
    for _ in range(trials):
        path.wait_frames(10)
        t0 = time.monotonic_ns()
        server.drop_connection()
        first = path.first_after(t0 + 1)
        backs.append(math.inf if first is None else (first - t0) * 1e-9)
    _summary("drop", backs, load, down_s=0.0)


def freezes(path: CameraPath, server: MjpegServerProcess, trials: int, load: int) -> None:
    backs = []
    for _ in range(trials):
        path.wait_frames(10)
        server.freeze()  # SIGSTOP: the connection stays open, nothing is sent
        time.sleep(FREEZE_S)
        t0 = time.monotonic_ns()
        server.thaw()
        first = path.first_after(t0)
        backs.append(math.inf if first is None else (first - t0) * 1e-9)
    _summary("freeze", backs, load, down_s=FREEZE_S)


def _summary(kind: str, backs: list[float], load: int, **extra: Any) -> None:
    _line("camera_outage", kind=kind, busy_loops=load, trials=len(backs), **extra,
          back_s=[round(b, 3) for b in backs], back_s_max=round(max(backs), 3),
          under_0_5_s=sum(b < 0.5 for b in backs))  # fmt: skip


def _serve(url: str, prerender_s: float) -> MjpegServerProcess:
    """A camera serving at ``url``: pre-rendered, it listens at once and serves from
    ``start()``; live, it serves when it answers."""
    server = MjpegServerProcess(url, prerender_s=prerender_s)
    if prerender_s:
        server.start(time.monotonic())
    return server


def restarts(trials: int, load: int, down_s: float, prerender_s: float) -> None:
    port = _free_port()
    url = f"http://127.0.0.1:{port}/stream.mjpg"
    server = _serve(url, prerender_s)
    path = CameraPath(url)
    backs = []
    try:
        for _ in range(trials):
            path.wait_frames(10)
            server.kill()  # its connections are closed by the kernel
            server.close()
            time.sleep(down_s)
            server = _serve(url, prerender_s)
            t0 = time.monotonic_ns()  # the source is back (a little earlier when live)
            first = path.first_after(t0)
            backs.append(math.inf if first is None else (first - t0) * 1e-9)
    finally:
        path.close()
        server.close()
    _summary("restart", backs, load, down_s=down_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--no-load", action="store_true", help="without the two busy loops")
    parser.add_argument(
        "--live", action="store_true", help="the camera renders each frame when due (no pre-render)"
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)d %(message)s")
    load = 0 if args.no_load else 2
    prerender = (0.0, 0.0) if args.live else (PRERENDER_S, RESTART_PRERENDER_S)
    server = MjpegServerProcess(prerender_s=prerender[0])
    busy = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(load)]
    try:
        with server:
            if prerender[0]:
                server.start(time.monotonic())
            path = CameraPath(server.url)
            try:
                path.wait_frames(25)
                t0, before = time.monotonic(), path.disconnects
                path.wait_frames(int(5 * FPS))
                _line("camera_steady", busy_loops=load, seconds=round(time.monotonic() - t0, 2),
                      closed=path.disconnects - before)  # fmt: skip
                stalls(path, server, args.trials, load)
                drops(path, server, args.trials, load)
                freezes(path, server, args.trials, load)
            finally:
                path.close()
        for down_s in (0.3, 3.0):
            restarts(args.trials, load, down_s, prerender[1])
    finally:
        for p in busy:
            p.kill()
            p.wait()


if __name__ == "__main__":
    main()
