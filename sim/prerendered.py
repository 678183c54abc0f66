"""Simulated devices that serve pre-rendered data, for throughput benchmarks.

Rendering the street costs about 0.6 ms per scan and 21 ms per camera frame, so the live
simulators cannot run at many times the nominal rates. Here the data is rendered once
(``n`` scans or frames of the drive, at the nominal spacing) and then cycled; the wire
protocols and their timing are the real simulators' (:class:`acq.sim.scip_device.ScipDevice`
on :class:`acq.sim.transport.TcpDeviceServer`, :class:`acq.sim.mjpeg_server.MjpegServer`).

- :class:`PrerenderedScanSource`: a ``StreetSource`` stand-in for ``ScipDevice``.
- :class:`PrerenderedCamera`: a ``SimCamera`` whose frames are ``n`` JPEGs encoded once.
- :class:`CountingScipDevice`: a ``ScipDevice`` that lists the ticks of every streamed scan.
- ``python -m acq.sim.prerendered scanner|camera ...``: one of them in its own process; it
  prints ``{"url": ...}`` and then answers JSON commands on stdin, one per line:
  ``"stats"`` (what it sent so far, and its CPU seconds), ``"close"``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from acq.sim.camera_device import FrameTruth, SimCamera, SimFrame, jpeg_digest
from acq.sim.device_clock import SimClock
from acq.sim.mjpeg_server import MjpegServer
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import ScannerModel, model
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer

__all__ = [
    "CountingScipDevice",
    "PrerenderedCamera",
    "PrerenderedScanSource",
    "enlarged",
    "sped_up",
]

NOMINAL_FPS = 25.0


def sped_up(m: ScannerModel, factor: float) -> ScannerModel:
    """``m`` turning ``factor`` times faster (scan rate, SCIP rpm)."""
    return replace(m, scan_hz=m.scan_hz * factor)


class PrerenderedScanSource:
    """``n`` scans of the street rendered once (at the nominal model's spacing), then
    returned in turn by :meth:`scan` whatever ``t0``."""

    def __init__(self, m: ScannerModel, n: int = 80, seed: int = 0) -> None:
        self.model = m
        live = StreetSource(m, seed=seed)
        t = live.t_origin + 1.0
        self._scans = [live.scan(t + i * m.scan_period) for i in range(n)]
        self._next = 0

    def scan(self, t0: float) -> tuple[np.ndarray, np.ndarray]:
        ranges, intensities = self._scans[self._next % len(self._scans)]
        self._next += 1
        return ranges, intensities


class CountingScipDevice(ScipDevice):
    """A ``ScipDevice`` that keeps the device tick of every streamed scan in ``streamed``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.streamed: list[int] = []

    def _scan_telegram(
        self, echo: bytes, op: str, start: int, end: int, cluster: int, k: int, status: bytes
    ) -> bytes:
        telegram = super()._scan_telegram(echo, op, start, end, cluster, k, status)
        if status == b"99":
            self.streamed.append(self.sent[-1].timestamp)
        return telegram


def enlarged(image: np.ndarray, size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """``image`` (H,W,3 uint8) resized to ``size`` (width, height px) with Gaussian noise
    of 10 grey levels (sd) added, so that its JPEG is as large as a real sensor's of that size
    (a smooth upscale alone compresses to a fraction of it)."""
    big = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR).astype(np.int16)
    big += np.asarray(rng.normal(0.0, 10.0, size=big.shape)).astype(np.int16)
    out: np.ndarray = np.clip(big, 0, 255).astype(np.uint8)
    return out


class PrerenderedCamera(SimCamera):
    """A ``SimCamera`` at any ``fps`` whose frames cycle through ``n`` JPEGs rendered once,
    ``1/25`` s of the drive apart. Timing and the truth log are ``SimCamera``'s.
    ``size`` (width, height px): the views enlarged to it (:func:`enlarged`), e.g. a
    5 MP sensor's 2592x1944."""

    def __init__(self, *, n: int = 50, size: tuple[int, int] | None = None, **options: Any) -> None:
        super().__init__(**options)
        t = self.t_origin + 1.0
        rng = np.random.default_rng(options.get("seed", 0))
        views = (self.render(t + i / NOMINAL_FPS) for i in range(n))
        self._jpegs = [
            self.encode(view if size is None else enlarged(view, size, rng)) for view in views
        ]
        self._digests = [jpeg_digest(j) for j in self._jpegs]

    def next_frame(self, render: bool = True) -> SimFrame:
        k = self._next
        self._next += 1
        t_mid = self.exposure_start(k) + self.exposure_s / 2
        t_available = t_mid + self.exposure_s / 2 + self.latency_s + self._jitter()
        jpeg = self._jpegs[k % len(self._jpegs)] if render else b""
        truth = FrameTruth(k, t_mid, t_available, self.exposure_s)
        if jpeg:
            truth.digest, truth.size = self._digests[k % len(self._digests)], len(jpeg)
        with self._lock:
            self._truth[k] = truth
            while len(self._truth) > self.truth_limit:
                del self._truth[next(iter(self._truth))]
        return SimFrame(k, jpeg, t_mid, t_available, self.exposure_s)


# --- in a process of its own ---------------------------------------------------------------


def _serve_scanner(args: argparse.Namespace) -> tuple[Any, Any]:
    m = sped_up(model(args.model), args.speed)
    clock = SimClock(tick_hz=m.clock_hz, wrap_bits=m.clock_bits, epoch=time.monotonic())
    device = CountingScipDevice(m, source=PrerenderedScanSource(m, seed=args.seed), clock=clock)
    server = TcpDeviceServer(device, args.host, args.port).start()

    def stats() -> dict[str, Any]:
        return {
            "scan_hz": m.scan_hz,
            "sent": len(device.streamed),
            "ticks": list(device.streamed),
            "connections": server.connections,
        }

    return server, stats


def _serve_camera(args: argparse.Namespace) -> tuple[Any, Any]:
    # jitter and exposure scale with the frame period, as they would on a faster camera
    scale = NOMINAL_FPS / args.fps
    camera = PrerenderedCamera(
        n=args.frames,
        fps=args.fps,
        exposure_s=0.004 * min(scale, 1.0),
        jitter_s=0.003 * min(scale, 1.0),
        seed=args.seed,
        size=args.size,
    )
    server = MjpegServer(camera, args.host, args.port).start()

    def stats() -> dict[str, Any]:
        truth = camera.truth()
        sent = [t for t in truth if t.status == "sent" and t.t_sent is not None]
        return {
            "fps": args.fps,
            "sent": len(sent),
            "frames": [(t.sequence, t.digest, t.t_sent) for t in sent],
            "late": sum(t.status == "late" for t in truth),
            "max_send_delay_s": max(
                (t.t_sent - t.t_available for t in sent if t.t_sent is not None), default=0.0
            ),
            "connections": server.connections,
        }

    return server, stats


def _size(text: str) -> tuple[int, int]:
    """``WxH`` -> (W, H) px, for ``--size``."""
    w, sep, h = text.lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit() and 0 < int(w) <= 16384 and 0 < int(h) <= 16384):
        raise argparse.ArgumentTypeError(f"expected WxH in px (e.g. 2592x1944), not {text!r}")
    return int(w), int(h)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m acq.sim.prerendered", description=__doc__)
    sub = p.add_subparsers(dest="device", required=True)
    s = sub.add_parser("scanner", help="a SCIP scanner, sped up, pre-rendered scans, on TCP")
    s.add_argument("--model", default="utm-30lx")
    s.add_argument("--speed", type=float, default=1.0, help="times the model's scan rate")
    c = sub.add_parser("camera", help="an MJPEG-over-HTTP camera of pre-rendered JPEGs")
    c.add_argument("--fps", type=float, default=NOMINAL_FPS)
    c.add_argument("--frames", type=int, default=50, help="distinct JPEGs to cycle")
    c.add_argument(
        "--size", type=_size, default=None, metavar="WxH",
        help="enlarge the views to W x H px, with noise (e.g. 2592x1944, a 5 MP sensor)",
    )  # fmt: skip
    for q in (s, c):
        q.add_argument("--host", default="127.0.0.1")
        q.add_argument("--port", type=int, default=0, help="0: a free one")
        q.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    server, stats = (_serve_scanner if args.device == "scanner" else _serve_camera)(args)
    print(json.dumps({"url": server.url}), flush=True)
    try:
        for line in sys.stdin:
            command = json.loads(line)
            if command == "close":
                break
            if command == "stats":
                value = {**stats(), "cpu_s": time.process_time()}
            else:
                value = None
            print(json.dumps({"value": value}), flush=True)
    finally:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
