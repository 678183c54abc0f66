"""The MJPEG-over-HTTP server that streams a simulated camera (:mod:`acq.sim.camera_device`).

:class:`MjpegServer` serves a :class:`SimCamera`'s frames over real HTTP on 127.0.0.1,
each when it becomes available, with faults on demand (stalls, dropped connections,
corrupt or skipped frames, a flood of parts that are not JPEG); :func:`serve_camera`
starts a camera and its server from a URL. The stream carries the JPEG bytes and nothing
else: no sequence number, no timestamp. A client learns only the bytes and when they
arrived.

:class:`acq.sim.mjpeg_process.MjpegServerProcess` runs camera and server in a child
process, so a client's timing is not disturbed by the renderer holding the GIL in its own
process.

Times are the host's ``time.monotonic()`` seconds.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import threading
import time
from typing import Any
from urllib.parse import urlsplit

from acq.sim.camera_device import SimCamera, SimFrame, jpeg_digest
from acq.sim.world import Rig, default_rig

__all__ = ["MjpegServer", "rig_camera", "serve_camera", "sim_camera"]

DEFAULT_LISTEN = "http://127.0.0.1:8080/stream.mjpg"


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
        self._flood_until = 0.0
        self._flood_s: float | None = None  # a flood asked for, not yet begun (s)
        self._flood_part = b""
        self._drop = False
        self._corrupt = 0
        self._skip = 0
        self.connections = 0  # clients served since start
        self.frames_sent = 0
        self._flood_sent = 0

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

    def flood(self, seconds: float, body: bytes = b"") -> None:
        """For ``seconds``, send every client parts holding ``body`` (empty by default: no
        JPEG) back to back, as fast as the sockets take them, instead of frames (frames
        meanwhile are lost: ``flooded``). New connections are flooded too."""
        head = f"--{self.boundary}\r\nContent-Type: image/jpeg\r\n"
        if self.content_length:
            head += f"Content-Length: {len(body)}\r\n"
        part = head.encode("ascii") + b"\r\n" + body + b"\r\n"
        with self._lock:
            self._flood_part = part * max(1, 65536 // len(part))  # one send's worth
            # timed from the server's first flood send: a server thread held up (rendering
            # on a loaded machine) would otherwise miss a short flood whole
            self._flood_until = math.inf
            self._flood_s = seconds
        self._wake()

    def flooded_bytes(self) -> int:
        """Bytes of flood parts sent so far (to all clients)."""
        return self._flood_sent

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
        render_s = 0.0  # how long the last frame took to make, s
        while not self._stop.is_set():
            if frame is None:
                with self._lock:
                    watched = bool(self._clients or self._requests)
                # a frame too late to send once made (the server held up, or rendering
                # slower than real time) is not made: made at its limit, every frame
                # would be late, none sent. Never one not yet due (a render the process
                # was stopped in seems long)
                t0 = time.monotonic()
                late = min(t0 + render_s - self.late_s, t0)
                cam.skip_until(late - 4 * cam.jitter_s, "late")
                frame = cam.next_frame(render=watched)
                if watched:
                    render_s = time.monotonic() - t0
            self._service(frame.t_available)
            if self._stop.is_set():
                return
            if time.monotonic() >= frame.t_available:
                self._deliver(frame)
                frame = None

    def _service(self, until: float) -> None:
        """Accept connections, read requests, forget clients that hung up, and send the
        flood if one is on, until ``until`` (monotonic s)."""
        while not self._stop.is_set():
            self._apply_drop()
            now = time.monotonic()
            with self._lock:
                clients = list(self._clients)
                if self._flood_s is not None:
                    self._flood_until, self._flood_s = now + self._flood_s, None
                flood = self._flood_part if now < self._flood_until else b""
            # behind (rendering slower than real time: a loaded host), one pass without
            # waiting still serves requests and the flood, which would otherwise starve
            left = max(0.0, until - now)
            watch = [self._listener, self._wake_r, *self._requests, *clients]
            ready, _, _ = select.select(watch, [], [], 0 if flood and clients else left)
            for sock in ready:
                if sock is self._wake_r:
                    with contextlib.suppress(OSError):
                        self._wake_r.recv(4096)
                elif sock is self._listener:
                    self._accept()
                elif sock in self._requests:
                    self._read_request(sock)
                else:
                    self._read_client(sock)
            now = time.monotonic()
            for sock, (_, since) in list(self._requests.items()):
                if now - since > 5.0:
                    self._requests.pop(sock)
                    sock.close()
            if flood:
                self._send_flood(flood)
            if left <= 0:
                return

    def _read_client(self, sock: socket.socket) -> None:
        """A client sends nothing after its request: readable means it hung up (a camera
        that notices frees the client's slot at once, not at the next frame)."""
        try:
            data = sock.recv(4096)
        except (BlockingIOError, InterruptedError, TimeoutError):
            return
        except OSError:
            data = b""
        if not data:
            self._forget(sock)

    def _forget(self, sock: socket.socket) -> None:
        with self._lock:
            if sock in self._clients:
                self._clients.remove(sock)
        with contextlib.suppress(OSError):
            sock.close()

    def _send_flood(self, data: bytes) -> None:
        with self._lock:
            clients = list(self._clients)
        for sock in clients:
            try:
                sock.sendall(data)
                self._flood_sent += len(data)
            except OSError:
                self._forget(sock)

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
            flooded = now < self._flood_until
            skip = corrupt = False
            if clients and frame.jpeg and not stalled and not flooded:
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
        if flooded:
            cam.record(frame.sequence, status="flooded")
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
                self._forget(sock)
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


def rig_camera(name: str) -> Rig:
    """The simulated rig holding only the camera ``name``: ``camera`` (the one-camera
    rig's), or ``left`` or ``right`` of the two-camera rig; ValueError for another."""
    try:
        return default_rig().only(name) if name == "camera" else default_rig(cameras=2).only(name)
    except KeyError as e:
        raise ValueError(f"camera {name!r}: {e.args[0]}") from None


def sim_camera(camera: str | None = None, **options: Any) -> SimCamera:
    """A :class:`SimCamera` of ``options`` (its keywords); with ``camera``, one of the
    simulated rig's cameras (:func:`rig_camera`), its latency and exposure by default
    those of the rig's camera."""
    if camera is not None:
        rig = rig_camera(camera)
        options.setdefault("latency_s", rig.cameras[0].latency_s)
        options.setdefault("exposure_s", rig.cameras[0].exposure)
        options["rig"] = rig
    return SimCamera(**options)


def serve_camera(listen: str | None = None, *, start: bool = True, **options: Any) -> MjpegServer:
    """Start a simulated camera serving MJPEG at ``listen`` (``http://HOST:PORT/PATH``,
    default ``http://127.0.0.1:8080/stream.mjpg``; port 0 picks a free one).

    ``options``: :func:`sim_camera`'s (``camera``, a rig camera's name, and
    :class:`SimCamera` keywords), and the server's ``boundary``, ``content_length``,
    ``max_clients``, ``late_s``. ``start`` False: the server listens but serves
    nothing until :meth:`MjpegServer.start`. Raises ValueError on a bad URL or camera
    name.
    """
    parts = urlsplit(listen or DEFAULT_LISTEN)
    if parts.scheme != "http" or not parts.hostname:
        raise ValueError(f"--listen must be http://HOST:PORT/PATH, got {listen!r}")
    try:
        port = parts.port if parts.port is not None else 80
    except ValueError as e:
        raise ValueError(f"--listen {listen!r}: {e}") from None
    camera_options, server_options = _split_options(options)
    camera = sim_camera(**camera_options)
    server = MjpegServer(camera, parts.hostname, port, parts.path or "/", **server_options)
    return server.start() if start else server
