"""A simulated fisheye camera, and the MJPEG-over-HTTP server that streams it.

:class:`SimCamera` is the camera: frame ``k``'s exposure starts when the camera's own
frame clock (offset and drift from the host's) says so; the frame is rendered from the
synthetic street at the true middle of its exposure, JPEG-encoded, and becomes available
``exposure/2 + latency + jitter`` after that middle (jitter random per frame, seeded).
The truth log keeps, per sequence number, the true middle of the exposure (host
monotonic s), when the frame became available and was sent, and a hash of the bytes
sent. ``next_frame()`` / ``frames()`` give the frames in process (for the recorder and
replay); :class:`MjpegServer` serves them over real HTTP on 127.0.0.1.

The stream carries the JPEG bytes and nothing else: no sequence number, no timestamp.
A client learns only the bytes and when they arrived.

:class:`MjpegServerProcess` runs camera and server in a child process, so a client's
timing is not disturbed by the renderer holding the GIL in its own process.

Times are the host's ``time.monotonic()`` seconds.
"""

from __future__ import annotations

import contextlib
import hashlib
import select
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any
from urllib.parse import urlsplit

import cv2
import numpy as np

from acq.sim import sensors
from acq.sim.world import Rig, Street, Trajectory, default_rig

__all__ = [
    "FrameTruth",
    "MjpegServer",
    "MjpegServerProcess",
    "SimCamera",
    "SimFrame",
    "jpeg_digest",
    "serve_camera",
]

DEFAULT_LISTEN = "http://127.0.0.1:8080/stream.mjpg"


def jpeg_digest(data: bytes) -> str:
    """The hash the truth log keeps of a frame's bytes (BLAKE2b-128, hex)."""
    return hashlib.blake2b(data, digest_size=16).hexdigest()


@dataclass
class FrameTruth:
    """What happened to one frame. ``status``: ``pending`` (made, not yet served),
    ``sent``, ``corrupt`` (sent broken), ``skipped`` (not sent, on demand), ``stalled``
    (not sent during a stall), ``unsent`` (no client connected), ``late`` (the server
    fell more than ``late_s`` behind and dropped it)."""

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
        t_origin: float | None = None,
        truth_limit: int = 1_000_000,
    ) -> None:
        if fps <= 0 or exposure_s < 0 or exposure_s > 1.0 / fps:
            raise ValueError(f"need fps > 0 and 0 <= exposure_s <= 1/fps, got {fps}, {exposure_s}")
        if jitter not in ("exponential", "uniform"):
            raise ValueError(f"jitter must be exponential or uniform, not {jitter!r}")
        self.street = street if street is not None else Street.generate(seed=seed, length_m=1000.0)
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
        self._truth: dict[int, FrameTruth] = {}
        self._lock = threading.Lock()
        # Power-up: compile or load the ray caster now, not in the middle of a stream.
        sensors.render_frame(self.street, self.trajectory, self.rig, 0.0)

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
        loop = max(self.street.length_m, 1.0) / self.trajectory.speed
        return sensors.render_frame(
            self.street, self.trajectory, self.rig, (t - self.t_origin) % loop
        )

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
        jpeg = self.encode(self.render(t_mid)) if render else b""
        truth = FrameTruth(k, t_mid, t_available, self.exposure_s)
        if jpeg:
            truth.digest, truth.size = jpeg_digest(jpeg), len(jpeg)
        with self._lock:
            self._truth[k] = truth
            while len(self._truth) > self.truth_limit:
                del self._truth[next(iter(self._truth))]
        return SimFrame(k, jpeg, t_mid, t_available, self.exposure_s)

    def skip_until(self, t: float) -> int:
        """Consume, unrendered (status ``unsent``), every frame available before ``t``;
        returns how many."""
        n = 0
        while self.exposure_start(self._next) + self.exposure_s + self.latency_s < t:
            self.record(self.next_frame(render=False).sequence, status="unsent")
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


class MjpegServer:
    """Serves a :class:`SimCamera` as ``multipart/x-mixed-replace`` over HTTP/1.0.

    Several clients at a time (up to ``max_clients``): each receives every frame sent
    after it connected. Other paths get 404, other methods 405. ``content_length``
    False leaves ``Content-Length`` out of the parts (the reader must find the
    boundary). Frames are sent when they become available, in real time, by one thread;
    rendering happens only while a client is connected (other frames are ``unsent``).
    A frame more than ``late_s`` late is dropped (``late``) instead of sent.
    """

    def __init__(
        self,
        camera: SimCamera,
        host: str = "127.0.0.1",
        port: int = 0,
        path: str = "/stream.mjpg",
        *,
        boundary: str = "acqframe",
        content_length: bool = True,
        max_clients: int = 8,
        late_s: float = 0.5,
    ) -> None:
        self.camera = camera
        self.path = path
        self.boundary = boundary
        self.content_length = content_length
        self.max_clients = max_clients
        self.late_s = late_s
        self._listener = socket.create_server((host, port))
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._clients: list[socket.socket] = []
        self._requests: dict[socket.socket, tuple[bytes, float]] = {}
        self._stall_until = 0.0
        self._drop = False
        self._corrupt = 0
        self._skip = 0
        self.connections = 0  # clients served since start
        self.frames_sent = 0

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}{self.path}"

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    # --- faults -----------------------------------------------------------------------

    def stall(self, seconds: float) -> None:
        """Send nothing for ``seconds`` (frames meanwhile are lost: ``stalled``); the
        connections stay open."""
        with self._lock:
            self._stall_until = time.monotonic() + seconds

    def drop_connection(self) -> None:
        """Close every client's connection now (the camera keeps running)."""
        with self._lock:
            self._drop = True
        self._wake()

    def corrupt_next(self) -> None:
        """Send the next frame truncated to half its length (a JPEG with no EOI)."""
        with self._lock:
            self._corrupt += 1

    def skip_next(self) -> None:
        """Do not send the next frame (its sequence number is consumed)."""
        with self._lock:
            self._skip += 1

    # --- life cycle -------------------------------------------------------------------

    def start(self) -> MjpegServer:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="MjpegServer", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for sock in [*self._clients, *self._requests]:
            with contextlib.suppress(OSError):
                sock.close()
        self._clients.clear()
        self._requests.clear()
        for sock in (self._listener, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                sock.close()

    def __enter__(self) -> MjpegServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")

    # --- the server thread ------------------------------------------------------------

    def _run(self) -> None:
        cam = self.camera
        cam.skip_until(time.monotonic())
        frame: SimFrame | None = None
        while not self._stop.is_set():
            if frame is None:
                with self._lock:
                    watched = bool(self._clients or self._requests)
                frame = cam.next_frame(render=watched)
            self._service(frame.t_available)
            if self._stop.is_set():
                return
            if time.monotonic() >= frame.t_available:
                self._deliver(frame)
                frame = None

    def _service(self, until: float) -> None:
        """Accept connections and read requests until ``until`` (monotonic s)."""
        while not self._stop.is_set():
            self._apply_drop()
            left = until - time.monotonic()
            if left <= 0:
                return
            watch = [self._listener, self._wake_r, *self._requests]
            ready, _, _ = select.select(watch, [], [], left)
            for sock in ready:
                if sock is self._wake_r:
                    with contextlib.suppress(OSError):
                        self._wake_r.recv(4096)
                elif sock is self._listener:
                    self._accept()
                else:
                    self._read_request(sock)
            now = time.monotonic()
            for sock, (_, since) in list(self._requests.items()):
                if now - since > 5.0:
                    self._requests.pop(sock)
                    sock.close()

    def _apply_drop(self) -> None:
        with self._lock:
            drop, self._drop = self._drop, False
            clients = self._clients if drop else []
            if drop:
                self._clients = []
        for sock in clients:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def _accept(self) -> None:
        try:
            sock, _ = self._listener.accept()
        except (BlockingIOError, OSError):
            return
        sock.setblocking(False)
        self._requests[sock] = (b"", time.monotonic())

    def _read_request(self, sock: socket.socket) -> None:
        buf, since = self._requests[sock]
        try:
            data = sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._requests.pop(sock)
            sock.close()
            return
        buf += data
        if b"\r\n\r\n" not in buf and b"\n\n" not in buf:
            if len(buf) > 16384:
                self._requests.pop(sock)
                sock.close()
            else:
                self._requests[sock] = (buf, since)
            return
        self._requests.pop(sock)
        words = buf.split(b"\r\n", 1)[0].split(b"\n", 1)[0].split()
        method = words[0] if words else b""
        target = words[1].decode("latin-1").split("?", 1)[0] if len(words) > 1 else ""
        sock.setblocking(True)
        sock.settimeout(2.0)
        try:
            if method != b"GET":
                sock.sendall(_response(405, "Method Not Allowed"))
            elif target != self.path:
                sock.sendall(_response(404, "Not Found"))
            elif self.clients >= self.max_clients:
                sock.sendall(_response(503, "Service Unavailable"))
            else:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.sendall(
                    b"HTTP/1.0 200 OK\r\n"
                    b"Server: acq-sim-camera\r\n"
                    b"Connection: close\r\n"
                    b"Cache-Control: no-cache, no-store\r\n"
                    b"Pragma: no-cache\r\n"
                    b"Content-Type: multipart/x-mixed-replace; boundary="
                    + self.boundary.encode("ascii")
                    + b"\r\n\r\n"
                )
                with self._lock:
                    self._clients.append(sock)
                self.connections += 1
                return
        except OSError:
            pass
        with contextlib.suppress(OSError):
            sock.close()

    def _deliver(self, frame: SimFrame) -> None:
        cam = self.camera
        now = time.monotonic()
        with self._lock:
            clients = list(self._clients)
            stalled = now < self._stall_until
            skip = corrupt = False
            if clients and frame.jpeg and not stalled:
                if self._skip:
                    self._skip -= 1
                    skip = True
                elif self._corrupt:
                    self._corrupt -= 1
                    corrupt = True
        if not clients or not frame.jpeg:
            cam.record(frame.sequence, status="unsent")
            return
        if stalled:
            cam.record(frame.sequence, status="stalled")
            return
        if skip:
            cam.record(frame.sequence, status="skipped")
            return
        if now - frame.t_available > self.late_s:
            cam.record(frame.sequence, status="late")
            return
        body = frame.jpeg[: len(frame.jpeg) // 2] if corrupt else frame.jpeg
        head = f"--{self.boundary}\r\nContent-Type: image/jpeg\r\n"
        if self.content_length:
            head += f"Content-Length: {len(body)}\r\n"
        data = head.encode("ascii") + b"\r\n" + body + b"\r\n"
        status = "corrupt" if corrupt else "sent"
        # what goes out is logged before it goes: a client may read it before send returns
        cam.record(frame.sequence, status=status, digest=jpeg_digest(body), size=len(body))
        sent = 0
        for sock in clients:
            try:
                sock.sendall(data)
                sent += 1
            except OSError:
                with self._lock:
                    if sock in self._clients:
                        self._clients.remove(sock)
                with contextlib.suppress(OSError):
                    sock.close()
        self.frames_sent += 1
        cam.record(frame.sequence, t_sent=time.monotonic(), clients=sent)


def _response(code: int, reason: str) -> bytes:
    body = f"{code} {reason}\n".encode("ascii")
    return (
        f"HTTP/1.0 {code} {reason}\r\nContent-Type: text/plain\r\n"
        f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n"
    ).encode("ascii") + body


_SERVER_OPTIONS = ("boundary", "content_length", "max_clients", "late_s")


def _split_options(options: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    server = {k: options[k] for k in _SERVER_OPTIONS if k in options}
    camera = {k: v for k, v in options.items() if k not in _SERVER_OPTIONS}
    return camera, server


def serve_camera(listen: str | None = None, **options: Any) -> MjpegServer:
    """Start a simulated camera serving MJPEG at ``listen`` (``http://HOST:PORT/PATH``,
    default ``http://127.0.0.1:8080/stream.mjpg``; port 0 picks a free one).

    ``options``: :class:`SimCamera` keywords, and the server's ``boundary``,
    ``content_length``, ``max_clients``, ``late_s``. Raises ValueError on a bad URL.
    """
    parts = urlsplit(listen or DEFAULT_LISTEN)
    if parts.scheme != "http" or not parts.hostname:
        raise ValueError(f"--listen must be http://HOST:PORT/PATH, got {listen!r}")
    try:
        port = parts.port if parts.port is not None else 80
    except ValueError as e:
        raise ValueError(f"--listen {listen!r}: {e}") from None
    camera_options, server_options = _split_options(options)
    camera = SimCamera(**camera_options)
    server = MjpegServer(camera, parts.hostname, port, parts.path or "/", **server_options)
    return server.start()


# --- in a child process -------------------------------------------------------------------


def _child_main() -> None:
    """``python -m acq.sim.camera_device --child``: JSON commands on stdin, replies on stdout."""
    import json
    import sys

    spec = json.loads(sys.stdin.readline())
    try:
        server = serve_camera(spec["listen"], **spec["options"])
    except Exception as e:  # reported to the parent, which raises it
        print(json.dumps({"error": repr(e)}), flush=True)
        return
    print(json.dumps({"url": server.url}), flush=True)
    with server:
        for line in sys.stdin:
            command, *args = json.loads(line)
            if command == "close":
                break
            if command == "truth":
                value: Any = [asdict(t) for t in server.camera.truth()]
            elif command == "cpu":
                value = time.process_time()
            elif command in ("stall", "drop_connection", "corrupt_next", "skip_next"):
                value = getattr(server, command)(*args)
            else:
                value = None
            print(json.dumps({"value": value}), flush=True)


class MjpegServerProcess:
    """:func:`serve_camera` in a child process: the same faults, ``truth()`` fetched over
    a pipe. ``options`` must be JSON values (no Street or Rig objects). The default
    ``listen`` picks a free port on 127.0.0.1."""

    def __init__(self, listen: str | None = "http://127.0.0.1:0/stream.mjpg", **options: Any):
        import json
        import subprocess
        import sys

        self._proc = subprocess.Popen(
            [sys.executable, "-m", "acq.sim.camera_device", "--child"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self._json = json
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.write(json.dumps({"listen": listen, "options": options}) + "\n")
        self._proc.stdin.flush()
        ready, _, _ = select.select([self._proc.stdout], [], [], 60)
        reply = json.loads(self._proc.stdout.readline() or "{}") if ready else {}
        if "url" not in reply:
            self._proc.kill()
            self._proc.wait(5)
            raise RuntimeError(f"the simulated camera process failed: {reply.get('error')}")
        self.url: str = reply["url"]

    def _call(self, *command: Any) -> Any:
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._proc.stdin.write(self._json.dumps(command) + "\n")
        self._proc.stdin.flush()
        return self._json.loads(self._proc.stdout.readline())["value"]

    def stall(self, seconds: float) -> None:
        self._call("stall", seconds)

    def drop_connection(self) -> None:
        self._call("drop_connection")

    def corrupt_next(self) -> None:
        self._call("corrupt_next")

    def skip_next(self) -> None:
        self._call("skip_next")

    def truth(self) -> list[FrameTruth]:
        return [FrameTruth(**t) for t in self._call("truth")]

    def cpu_seconds(self) -> float:
        """The server process's CPU time so far (s)."""
        return float(self._call("cpu"))

    def close(self) -> None:
        if self._proc.poll() is None:
            assert self._proc.stdin is not None
            with contextlib.suppress(OSError, ValueError):
                self._proc.stdin.write(self._json.dumps(["close"]) + "\n")
                self._proc.stdin.close()
            try:
                self._proc.wait(5)
            except Exception:
                self._proc.kill()
                self._proc.wait(5)
        if self._proc.stdout is not None:
            self._proc.stdout.close()

    def __enter__(self) -> MjpegServerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["--child"]:
        _child_main()
