"""A simulated fisheye camera: frames rendered from the synthetic street on its own clock.

:class:`SimCamera` is the camera: frame ``k``'s exposure starts when the camera's own
frame clock (offset and drift from the host's) says so; the frame is rendered from the
synthetic street at the true middle of its exposure, JPEG-encoded, and becomes available
``exposure/2 + latency + jitter`` after that middle (jitter random per frame, seeded).
The truth log keeps, per sequence number, the true middle of the exposure (host
monotonic s), when the frame became available and was sent, and a hash of the bytes
sent. ``next_frame()`` / ``frames()`` give the frames in process (for the recorder and
replay); :mod:`acq.sim.mjpeg_server` serves them over real HTTP on 127.0.0.1.

Times are the host's ``time.monotonic()`` seconds.
"""

from __future__ import annotations

import hashlib
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from acq.sim import sensors
from acq.sim.world import Rig, Street, Trajectory, default_rig

__all__ = ["FrameTruth", "SimCamera", "SimFrame", "jpeg_digest"]


def jpeg_digest(data: bytes) -> str:
    """The hash the truth log keeps of a frame's bytes (BLAKE2b-128, hex)."""
    return hashlib.blake2b(data, digest_size=16).hexdigest()


@dataclass
class FrameTruth:
    """What happened to one frame. ``status``: ``pending`` (made, not yet served),
    ``sent``, ``corrupt`` (sent broken), ``skipped`` (not sent, on demand), ``stalled``
    (not sent during a stall), ``flooded`` (not sent during a flood of parts that are
    not JPEG), ``unsent`` (no client connected), ``late`` (the server fell more than
    ``late_s`` behind and dropped it)."""

    sequence: int
    t_mid: float  # s, true middle of the exposure (host monotonic)
    t_available: float  # s, when the camera had it ready to send
    exposure_s: float
    digest: str = ""  # jpeg_digest of the bytes sent ("" when not rendered)
    size: int = 0  # bytes sent
    t_sent: float | None = None  # s, when the bytes were in every client's socket
    clients: int = 0  # how many clients it was sent to
    status: str = "pending"


@dataclass(frozen=True)
class SimFrame:
    """One frame as the camera produced it (``jpeg`` empty when not rendered)."""

    sequence: int
    jpeg: bytes
    t_mid: float  # s, true middle of the exposure
    t_available: float  # s
    exposure_s: float


class SimCamera:
    """A free-running camera filming the street from the rig (see the module doc).

    ``fps`` is nominal: the camera's frame clock runs ``drift_ppm`` fast and its frame 0
    starts ``clock_offset_s`` after ``t_origin`` (power-up, by default now). ``latency_s``
    is the constant delay from the end of the exposure to availability, plus a random
    part per frame of mean about ``jitter_s`` (``jitter``: ``exponential``, clipped at
    4·jitter_s, or ``uniform`` on [0, 2·jitter_s]). The drive loops over the street.
    ``seed`` seeds the jitter and, unless ``street_seed`` is given, the street; the rig's
    first camera is the one filming (:meth:`acq.sim.world.Rig.only` picks another).
    ``still``: every frame is the street's first view with its time written in a corner,
    so a frame costs a JPEG encoding (about 1.5 ms) instead of a render (20-40 ms): for
    tests of the link and its timing, whose camera must keep its rate on a busy machine.
    """

    def __init__(
        self,
        street: Street | None = None,
        trajectory: Trajectory | None = None,
        rig: Rig | None = None,
        *,
        fps: float = 25.0,
        exposure_s: float = 0.004,
        clock_offset_s: float = 0.0,
        drift_ppm: float = 0.0,
        latency_s: float = 0.02,
        jitter_s: float = 0.003,
        jitter: str = "exponential",
        jpeg_quality: int = 90,
        seed: int = 0,
        street_seed: int | None = None,
        t_origin: float | None = None,
        truth_limit: int = 1_000_000,
        still: bool = False,
    ) -> None:
        if fps <= 0 or exposure_s < 0 or exposure_s > 1.0 / fps:
            raise ValueError(f"need fps > 0 and 0 <= exposure_s <= 1/fps, got {fps}, {exposure_s}")
        if jitter not in ("exponential", "uniform"):
            raise ValueError(f"jitter must be exponential or uniform, not {jitter!r}")
        if street is None:
            street = Street.generate(
                seed=seed if street_seed is None else street_seed, length_m=1000.0
            )
        self.street = street
        self.trajectory = trajectory if trajectory is not None else Trajectory()
        self.rig = rig if rig is not None else default_rig()
        self.fps = fps
        self.exposure_s = exposure_s
        self.clock_offset_s = clock_offset_s
        self.drift_ppm = drift_ppm
        self.latency_s = latency_s
        self.jitter_s = jitter_s
        self.jitter = jitter
        self.jpeg_quality = jpeg_quality
        self.t_origin = time.monotonic() if t_origin is None else t_origin
        self.truth_limit = truth_limit
        self._rng = np.random.default_rng(seed)
        self._next = 0
        self._prerendered: dict[int, bytes] = {}  # frame -> JPEG, see prerender
        self._truth: dict[int, FrameTruth] = {}
        self._lock = threading.Lock()
        # Power-up: compile or load the ray caster now, not in the middle of a stream.
        first = sensors.render_frame(self.street, self.trajectory, self.rig, 0.0)
        self._still = first if still else None

    @property
    def width(self) -> int:
        return int(self.rig.lens.width)

    @property
    def height(self) -> int:
        return int(self.rig.lens.height)

    def exposure_start(self, k: int) -> float:
        """True time (s) at which frame ``k``'s exposure starts, by the camera's clock."""
        return self.t_origin + self.clock_offset_s + k / (self.fps * (1.0 + self.drift_ppm * 1e-6))

    def _jitter(self) -> float:
        if self.jitter_s <= 0:
            return 0.0
        if self.jitter == "uniform":
            return float(self._rng.uniform(0.0, 2.0 * self.jitter_s))
        return float(min(self._rng.exponential(self.jitter_s), 4.0 * self.jitter_s))

    def render(self, t: float) -> np.ndarray:
        """(H,W,3) uint8 BGR view at true time t (s); the drive loops over the street."""
        return self._render_drive(t - self.t_origin)

    def _render_drive(self, t_drive: float) -> np.ndarray:
        """(H,W,3) uint8 BGR view ``t_drive`` s after the drive's start."""
        if self._still is not None:
            image = self._still.copy()
            cv2.putText(image, f"{t_drive:.3f}", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0,
                        (255, 255, 255), 2)  # fmt: skip
            return image
        loop = max(self.street.length_m, 1.0) / self.trajectory.speed
        return sensors.render_frame(self.street, self.trajectory, self.rig, t_drive % loop)

    def prerender(self, seconds: float) -> int:
        """Render and encode now the frames exposed in the first ``seconds`` of the drive
        (by the camera's clock, whatever ``t_origin`` is set to later), so that
        :meth:`next_frame` serves them without rendering: a camera that cannot render
        in real time on a busy machine still sends every frame on time. Frames after
        those are rendered when due. Returns how many were rendered."""
        n = max(0, math.ceil(seconds * self.fps * (1.0 + self.drift_ppm * 1e-6)))
        for k in range(self._next, n):
            t_drive = self.exposure_start(k) - self.t_origin + self.exposure_s / 2
            self._prerendered[k] = self.encode(self._render_drive(t_drive))
        return len(self._prerendered)

    def encode(self, image: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise RuntimeError("cv2.imencode failed")
        return buf.tobytes()

    def next_frame(self, render: bool = True) -> SimFrame:
        """The next frame in sequence, whatever the time (``render=False``: its timing
        only, ``jpeg`` empty, for frames nobody will see)."""
        k = self._next
        self._next += 1
        t_mid = self.exposure_start(k) + self.exposure_s / 2
        t_available = t_mid + self.exposure_s / 2 + self.latency_s + self._jitter()
        jpeg = self._prerendered.pop(k, b"")
        if not render:
            jpeg = b""
        elif not jpeg:
            jpeg = self.encode(self.render(t_mid))
        truth = FrameTruth(k, t_mid, t_available, self.exposure_s)
        if jpeg:
            truth.digest, truth.size = jpeg_digest(jpeg), len(jpeg)
        with self._lock:
            self._truth[k] = truth
            while len(self._truth) > self.truth_limit:
                del self._truth[next(iter(self._truth))]
        return SimFrame(k, jpeg, t_mid, t_available, self.exposure_s)

    def skip_until(self, t: float, status: str = "unsent") -> int:
        """Consume, unrendered (with ``status``), every frame whose exposure end plus the
        constant latency is before ``t`` (s); returns how many."""
        n = 0
        while self.exposure_start(self._next) + self.exposure_s + self.latency_s < t:
            self.record(self.next_frame(render=False).sequence, status=status)
            n += 1
        return n

    def frames(
        self, realtime: bool = True, stop: threading.Event | None = None
    ) -> Iterator[SimFrame]:
        """Frames in sequence; with ``realtime``, each when it becomes available (frames
        already past when the iterator starts are skipped)."""
        if realtime:
            self.skip_until(time.monotonic())
        while stop is None or not stop.is_set():
            frame = self.next_frame()
            if realtime:
                delay = frame.t_available - time.monotonic()
                if delay > 0:
                    if stop is not None:
                        if stop.wait(delay):
                            return
                    else:
                        time.sleep(delay)
            self.record(frame.sequence, status="sent", t_sent=time.monotonic())
            yield frame

    def record(self, sequence: int, **fields: Any) -> None:
        """Update the truth of one frame (status, t_sent, digest...)."""
        with self._lock:
            truth = self._truth.get(sequence)
            if truth is not None:
                for key, value in fields.items():
                    setattr(truth, key, value)

    def truth(self) -> list[FrameTruth]:
        """A copy of the truth log, in sequence order."""
        with self._lock:
            return [FrameTruth(**asdict(t)) for t in self._truth.values()]
