"""Cameras through OpenCV's ``VideoCapture``, and MJPEG-over-HTTP read natively.

Sources: a camera index (``"0"``), a V4L2 node (``/dev/videoN``), an RTSP or HTTP URL, a
video file or image-sequence pattern, or a GStreamer pipeline (any text with ``!``).

``http://`` and ``https://`` sources are read here, not by OpenCV: the
``multipart/x-mixed-replace`` stream is parsed (:mod:`acq.drivers.mjpeg`) so every JPEG is
kept byte for byte as the camera sent it (``Frame.jpeg``) and never decoded; its size
comes from its SOF header, and a JPEG whose markers are broken is counted in
``corrupt`` and skipped. A camera that sends more parts that are not JPEG (empty, broken)
than frames, beyond a small allowance, has its connection dropped with a
:class:`ProtocolError` (the link reconnects with backoff): the parts of one read are
parsed only until then, so a flood costs bounded work. Other sources give decoded BGR
images (``Frame.image``); a V4L2 camera asked for ``MJPG`` hands its JPEG buffers through
undecoded.

Time: on V4L2, ``CAP_PROP_POS_MSEC`` is the kernel's buffer timestamp on the monotonic
clock (``time_source="kernel"``); elsewhere the host time at which the frame's last byte
arrived (``time_source="receipt"``): over HTTP on Linux, the kernel's receive time of its
bytes, so a busy host that reads them late does not make them late. Either way
``latency_s`` (the nominal delay from the middle of the exposure to that instant) is
subtracted, so ``stamp_ns`` is the middle of the exposure. Sequence numbers are the
driver's own: a gap of more than 1.75 frame periods since the previous frame advances
them by the frames that may have been lost, which are counted in ``drops``; first, for
up to half a period, the frames held up behind it are waited for: those that arrive
bunched up were late, not lost, and keep their numbers.
"""

from __future__ import annotations

import base64
import select
import socket
import ssl
import struct
import sys
import time
from collections import deque
from typing import Any
from urllib.parse import unquote, urlsplit

import cv2
import numpy as np

from acq.drivers.camera import Camera, FrameFormat, FrameTimeout
from acq.drivers.errors import ConnectionLost, DeviceError, DriverError, ProtocolError
from acq.drivers.mjpeg import (
    MAX_HEAD,
    MultipartReader,
    boundary_of,
    jpeg_size,
    parse_response_head,
)
from acq.records import DeviceInfo, Frame

__all__ = ["OpenCVCamera", "fourcc_text"]

_RECV = 256 * 1024  # bytes per recv
_MAX_BATCH = 8 * 1024 * 1024  # bytes read back-to-back before parts are handed out
_KERNEL_WINDOW_NS = 10_000_000_000  # a kernel time this far from receipt is not monotonic
# the kernel's receive timestamps on a TCP socket (Linux: SO_TIMESTAMPNS, which the socket
# module does not name; its SCM_ message carries a struct timespec)
_SO_TIMESTAMPNS = 35
_TIMESTAMP_SPACE = socket.CMSG_SPACE(16)
_KERNEL_AGE_NS = 5_000_000_000  # a receive time older than this is a realtime clock step
# parts that are not JPEG (or stretches that are not multipart) a connection may send
# beyond one per good frame before it is dropped: a corrupt frame now and then is
# skipped, a flood is not read on
_JUNK_ALLOWANCE = 16


def fourcc_text(code: float) -> str:
    """A FOURCC as OpenCV reports it (a float holding 4 bytes) -> ``"MJPG"``; "" for 0."""
    n = int(code)
    if n <= 0:
        return ""
    text = "".join(chr((n >> (8 * i)) & 0xFF) for i in range(4))
    return text.strip("\0 ") if text.isprintable() else f"0x{n:08x}"


class OpenCVCamera(Camera):
    """One capture through OpenCV, or an MJPEG-over-HTTP stream read natively.

    ``verify``: how a JPEG is checked before it is passed on: ``"markers"`` (SOI, a
    header that parses, EOI; no decoding, a few µs) or ``"decode"`` (a full
    ``cv2.imdecode``, about 1.5 ms for 780x582). ``native_http``: False hands HTTP URLs
    to OpenCV's FFmpeg backend instead (decoded images, no byte-exact JPEG).
    """

    driver = "opencv"

    def __init__(
        self,
        source: str,
        *,
        verify: str = "markers",
        native_http: bool = True,
        **options: Any,
    ) -> None:
        super().__init__(source, **options)
        if verify not in ("markers", "decode"):
            raise ValueError(f"verify must be 'markers' or 'decode', not {verify!r}")
        self.verify = verify
        self.native_http = native_http
        self._sock: socket.socket | None = None
        self._reader: MultipartReader | None = None
        # (JPEG or None for a broken frame, width, height, receipt host ns)
        self._parts: deque[tuple[bytes | None, int, int, int]] = deque()
        self._credit = _JUNK_ALLOWANCE  # junk the connection may still send
        self._junk_parts = self._good_parts = 0  # on this connection
        self._closed_why = "not connected"
        self._error: DriverError | None = None  # raised once the frames before it are read
        self._cap: cv2.VideoCapture | None = None
        self._kernel_time = False
        self._kernel_receipt = False  # the socket gives the kernel's receive times
        self._passthrough = False
        self._pending: Frame | None = None  # the frame read while connecting
        self._sequence = -1
        self._last_ns: int | None = None  # receipt of the previous batch with a frame
        self._suspect = 0  # frames a long gap says may be lost, until the next ones show

    # --- common ------------------------------------------------------------------------

    @property
    def is_http(self) -> bool:
        return self.native_http and self.source.lower().startswith(("http://", "https://"))

    def _period_ns(self) -> int:
        fps = self.format.fps if self.format is not None and self.format.fps > 0 else self.fps
        return int(1e9 / fps) if fps > 0 else 0

    def _missing(self, recv_ns: int, count: int) -> int:
        """Frames the time since the previous batch says were lost before ``count`` frames
        completed at ``recv_ns``: a lost frame leaves a gap of two periods, give or take
        the jitter; a frame merely late (the sender or this host busy) rarely by as much
        as 3/4 period."""
        period = self._period_ns()
        if self._last_ns is None or period <= 0:
            return 0
        gap = (recv_ns - self._last_ns) / period
        return max(0, round(gap) - count) if gap > 1.75 else 0

    def _advance(self, recv_ns: int, count: int = 1) -> int:
        """Sequence number of the first of ``count`` frames completed at ``recv_ns``;
        the frames a time gap says were lost are added to ``drops``."""
        missing = self._missing(recv_ns, count)
        period = self._period_ns()
        if not missing and self._last_ns is not None and period > 0:
            if (recv_ns - self._last_ns) / period < 0.5 and self._suspect > 0:
                # frames arriving in a bunch after a long gap were late, not lost: a
                # busy host or network delays them; a lost frame is never made up for
                self._suspect -= 1
                self.drops -= 1
        self._last_ns = recv_ns
        self.drops += missing
        self._suspect = missing if missing else self._suspect
        self._sequence += 1 + missing
        return self._sequence

    def connect(self) -> DeviceInfo:
        self.close()
        self._sequence, self._last_ns, self._suspect = -1, None, 0
        info = self._connect_http() if self.is_http else self._connect_capture()
        self.info = info
        return info

    def start(self) -> None:
        """Nothing to do: the stream flows from ``connect()`` (whose first frame is read
        first, even if the camera's connection has been dropped since)."""
        if self._sock is None and self._cap is None and self._pending is None:
            raise ConnectionLost(f"{self.source}: {self._closed_why}")

    def stop(self) -> None:
        """Nothing to do: an HTTP stream or a capture is stopped by ``close()``."""

    def read_frame(self) -> Frame:
        if self._pending is not None:
            frame, self._pending = self._pending, None
            return frame
        if self._sock is not None or self._parts or self._error is not None:
            return self._read_http(time.monotonic() + self.timeout)
        if self._cap is not None:
            return self._read_capture()
        raise ConnectionLost(f"{self.source}: {self._closed_why}")

    def close(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
            self._sock = None
        if self._cap is not None:
            self._cap.release()
            self._cap = None
        self._reader = None
        self._parts.clear()
        self._pending = None
        self._closed_why = "not connected"
        self._error = None

    def _requested(self) -> str:
        size = f"{self.width or '?'}x{self.height or '?'}"
        return f"{size}@{self.fps:g} {self.fourcc or 'any'}"

    # --- MJPEG over HTTP ---------------------------------------------------------------

    def _connect_http(self) -> DeviceInfo:
        url = urlsplit(self.source)
        host = url.hostname or "localhost"
        port = url.port or (443 if url.scheme == "https" else 80)
        deadline = time.monotonic() + self.timeout
        try:
            sock = socket.create_connection((host, port), timeout=self.timeout)
            if url.scheme == "https":
                sock = ssl.create_default_context().wrap_socket(sock, server_hostname=host)
        except OSError as e:
            raise ConnectionLost(f"{self.source}: cannot connect: {e}") from e
        self._sock = sock
        self._credit, self._junk_parts, self._good_parts = _JUNK_ALLOWANCE, 0, 0
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self._kernel_receipt = _kernel_receipt_on(sock)
        path = url.path or "/"
        if url.query:
            path += "?" + url.query
        lines = [
            f"GET {path} HTTP/1.1",
            f"Host: {url.netloc.rpartition('@')[2]}",
            "User-Agent: acq",
            "Accept: multipart/x-mixed-replace, image/jpeg",
            "Connection: close",
        ]
        if url.username is not None:
            cred = f"{unquote(url.username)}:{unquote(url.password or '')}".encode()
            lines.append("Authorization: Basic " + base64.b64encode(cred).decode("ascii"))
        try:
            sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1"))
        except OSError as e:
            raise ConnectionLost(f"{self.source}: request failed: {e}") from e
        head, rest = self._read_head(deadline)
        status, reason, headers = parse_response_head(head)
        if status != 200:
            raise DeviceError(f"{self.source}: HTTP {status} {reason}".rstrip(), str(status))
        ctype = headers.get("content-type", "")
        if not ctype.lower().startswith("multipart/"):
            raise DeviceError(
                f"{self.source}: Content-Type {ctype!r} is not an MJPEG stream "
                "(multipart/x-mixed-replace)"
            )
        self._reader = MultipartReader(boundary_of(ctype))
        self._feed(rest, time.monotonic_ns())
        self.format = FrameFormat(0, 0, self.fps, "MJPG")
        first = self._read_http(deadline)
        self._pending = first
        self.format = FrameFormat(first.width, first.height, self.fps, "MJPG")
        return DeviceInfo(
            name=self.name,
            driver=self.driver,
            vendor=headers.get("server", ""),
            model="MJPEG over HTTP",
            extra={
                "source": self.source,
                "backend": "http-mjpeg",
                "content_type": ctype,
                "requested": self._requested(),
                "applied": f"{first.width}x{first.height}@{self.fps:g} MJPG",
                "fps_source": "configured",
                "time_source": "receipt",
            },
        )

    def _recv(self, deadline: float) -> tuple[bytes, int]:
        """Bytes from the socket by ``deadline`` (monotonic s) and their receipt host ns;
        past it, only bytes that have already arrived."""
        sock = self._sock
        if sock is None:
            raise ConnectionLost(f"{self.source}: {self._closed_why}")
        left = deadline - time.monotonic()
        kernel_ns: int | None = None
        try:
            # past the deadline, what has already arrived is still read (timeout 0): a
            # host that held this thread up is not a camera gone quiet
            sock.settimeout(max(left, 0.0))
            if self._kernel_receipt:
                data, ancillary, _, _ = sock.recvmsg(_RECV, _TIMESTAMP_SPACE)
                kernel_ns = _kernel_time(ancillary)
            else:
                data = sock.recv(_RECV)
        except (TimeoutError, BlockingIOError, ssl.SSLWantReadError):
            raise FrameTimeout(f"{self.source}: no frame within {self.timeout:g} s") from None
        except OSError as e:
            raise ConnectionLost(f"{self.source}: {e}") from e
        recv_ns = time.monotonic_ns()
        if not data:
            raise ConnectionLost(f"{self.source}: the camera closed the stream")
        if kernel_ns is not None:
            # the kernel's receipt (realtime clock) on the monotonic clock: how long ago
            # it was, taken from now; a step of the realtime clock between the two (an
            # age out of bounds) falls back to now
            age = time.time_ns() - kernel_ns
            if 0 <= age < _KERNEL_AGE_NS:
                recv_ns -= age
        return data, recv_ns

    def _read_head(self, deadline: float) -> tuple[bytes, bytes]:
        buf = b""
        while True:
            end = buf.find(b"\r\n\r\n")
            if end >= 0:
                return buf[:end], buf[end + 4 :]
            if len(buf) > MAX_HEAD:
                raise ProtocolError(f"{self.source}: HTTP response head over {MAX_HEAD} bytes")
            data, _ = self._recv(deadline)
            buf += data

    def _feed(self, data: bytes, recv_ns: int) -> None:
        """Parse what arrived: JPEG parts are queued with their receipt time, a part that
        begins like one but does not parse as a placeholder (its frame number is used).
        Every part that is not a JPEG, and every multipart error, spends the junk
        allowance (:meth:`_junk`); a multipart error is raised once the frames before it
        are read, and the parser starts again at the next delimiter."""
        reader = self._reader
        if reader is None:
            return
        reader.push(data)
        while True:
            try:
                part = reader.next_part()
            except ProtocolError as e:
                self._reader = MultipartReader(reader.boundary)
                self._error = ProtocolError(f"{self.source}: {e}")
                self._junk(str(e))
                return
            if part is None:
                return
            body = part.body
            try:
                width, height = jpeg_size(body)
            except ProtocolError as e:
                self.corrupt += 1
                if body.startswith(b"\xff\xd8"):  # a frame, broken
                    self._parts.append((None, 0, 0, recv_ns))
                if not self._junk(f"a {len(body)}-byte part: {e}"):
                    return
                continue
            self._good_parts += 1
            self._credit = min(_JUNK_ALLOWANCE, self._credit + 1)
            self._parts.append((body, width, height, recv_ns))

    def _junk(self, what: str) -> bool:
        """One part that is not a JPEG (or bytes that are not multipart); False when that
        was beyond the allowance: the connection is closed, a ProtocolError saying why
        raised once the frames before it are read."""
        self._junk_parts += 1
        self._credit -= 1
        if self._credit >= 0:
            return True
        why = (
            f"dropped the connection: {self._junk_parts} parts were not JPEG, "
            f"{self._good_parts} were (the last bad one: {what})"
        )
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
            self._sock = None
        self._reader = None
        self._closed_why = why
        self._error = ProtocolError(f"{self.source}: {why}")
        return False

    def _fill(self, deadline: float) -> None:
        """Read until at least one part is complete (or an error is pending), then
        whatever else is already waiting (a backlog), so the parts of one burst are timed
        as one batch."""
        batch = 0
        while True:
            data, recv_ns = self._recv(deadline)
            self._feed(data, recv_ns)
            batch += len(data)
            sock = self._sock
            if self._error is not None or sock is None:
                return
            if self._parts:
                if batch >= _MAX_BATCH:
                    return
                ready, _, _ = select.select([sock], [], [], 0)
                if not ready and not (isinstance(sock, ssl.SSLSocket) and sock.pending()):
                    return
            elif self._reader is not None and self._reader.finished:
                raise ConnectionLost(f"{self.source}: the camera ended the stream")

    def _settle(self, deadline: float) -> None:
        """After a gap in time that says frames were lost, wait up to half a period past
        the last arrival for more: frames a busy host or network held up arrive bunched
        right behind, and join the batch as late, not lost. A real loss costs the frame
        after it half a period of latency."""
        half = self._period_ns() / 2e9
        while self._sock is not None and self._error is None:
            last_ns = self._parts[-1][3]
            if not self._missing(last_ns, len(self._parts)):
                return
            try:
                data, recv_ns = self._recv(min(deadline, last_ns * 1e-9 + half))
            except FrameTimeout:
                return
            except DriverError as e:  # raised once the frames already here are read
                self._error = e
                return
            self._feed(data, recv_ns)

    def _read_http(self, deadline: float) -> Frame:
        while True:
            if not self._parts:
                if self._error is not None:
                    error, self._error = self._error, None
                    raise error
                self._fill(deadline)
                if not self._parts:
                    continue  # an error is pending
                self._settle(deadline)
                # sequence numbers for the whole batch: frames that arrive together
                # explain the time since the previous batch
                first = self._advance(self._parts[-1][3], len(self._parts))
                self._sequence = first - 1
            body, width, height, recv_ns = self._parts.popleft()
            self._sequence += 1
            sequence = self._sequence
            if body is None:
                continue
            if self.verify == "decode":
                img = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
                if img is None:
                    self.corrupt += 1
                    self._junk("a JPEG that does not decode")
                    continue
            self.frames += 1
            return Frame(
                recv_ns=recv_ns,
                stamp_ns=recv_ns - round(self.latency_s * 1e9),
                sequence=sequence,
                width=width,
                height=height,
                jpeg=body,
                time_source="receipt",
            )

    # --- VideoCapture ------------------------------------------------------------------

    def _open_args(self) -> tuple[str | int, int]:
        src = self.source
        if src.isdigit():
            return int(src), cv2.CAP_V4L2
        if src.startswith("/dev/video"):
            return src, cv2.CAP_V4L2
        if "!" in src:
            return src, cv2.CAP_GSTREAMER
        if "://" in src:
            return src, cv2.CAP_FFMPEG
        return src, cv2.CAP_ANY

    def _connect_capture(self) -> DeviceInfo:
        src, api = self._open_args()
        ms = max(1, round(self.timeout * 1000))
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
        cap = cv2.VideoCapture(src, api, params if api == cv2.CAP_FFMPEG else [])
        if not cap.isOpened():
            cap.release()
            raise DeviceError(f"{self.source}: VideoCapture cannot open it")
        self._cap = cap
        backend = cap.getBackendName()
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc[:4].ljust(4)))
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps and backend == "V4L2":
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        fourcc = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        self._kernel_time = backend == "V4L2"
        # a V4L2 camera sending MJPG: hand its JPEG buffers on undecoded
        self._passthrough = backend == "V4L2" and fourcc == "MJPG"
        if self._passthrough:
            self._passthrough = bool(cap.set(cv2.CAP_PROP_CONVERT_RGB, 0))
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        fps_source = "device"
        if not (0 < fps < 1000) or backend == "CV_IMAGES":
            fps, fps_source = self.fps, "configured"
        self.format = FrameFormat(width, height, fps, fourcc)
        if width <= 0 or height <= 0:
            first = self._read_capture()
            self._pending = first
            width, height = first.width, first.height
            self.format = FrameFormat(width, height, fps, fourcc)
        return DeviceInfo(
            name=self.name,
            driver=self.driver,
            model=backend,
            extra={
                "source": self.source,
                "backend": backend,
                "requested": self._requested(),
                "applied": f"{width}x{height}@{fps:g} {fourcc or '?'}",
                "fps_source": fps_source,
                "time_source": "kernel" if self._kernel_time else "receipt",
                "passthrough": str(self._passthrough).lower(),
            },
        )

    def _read_capture(self) -> Frame:
        cap = self._cap
        assert cap is not None
        t0 = time.monotonic()
        ok = cap.grab()
        recv_ns = time.monotonic_ns()
        if not ok:
            if time.monotonic() - t0 >= self.timeout:
                raise FrameTimeout(f"{self.source}: no frame within {self.timeout:g} s")
            raise ConnectionLost(f"{self.source}: the capture ended (end of stream or unplugged)")
        ok, data = cap.retrieve()
        if not ok or data is None:
            self.corrupt += 1
            raise ProtocolError(f"{self.source}: a frame was grabbed but cannot be retrieved")
        time_ns, source = recv_ns, "receipt"
        if self._kernel_time:
            kernel_ns = round(cap.get(cv2.CAP_PROP_POS_MSEC) * 1e6)
            if 0 <= recv_ns - kernel_ns < _KERNEL_WINDOW_NS:
                time_ns, source = kernel_ns, "kernel"
        sequence = self._advance(time_ns)
        stamp_ns = time_ns - round(self.latency_s * 1e9)
        if self._passthrough and data.ndim <= 2 and (data.ndim == 1 or data.shape[0] == 1):
            jpeg = data.tobytes()
            try:
                width, height = jpeg_size(jpeg)
            except ProtocolError:
                self.corrupt += 1
                raise
            self.frames += 1
            return Frame(recv_ns, stamp_ns, sequence, width, height, jpeg=jpeg, time_source=source)
        image = data
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        elif image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        height, width = image.shape[:2]
        self.frames += 1
        return Frame(recv_ns, stamp_ns, sequence, width, height, image=image, time_source=source)


def _kernel_receipt_on(sock: socket.socket) -> bool:
    """Ask the kernel to stamp what ``sock`` receives (a plain TCP socket on Linux): a
    frame's receipt is then when its bytes arrived, not when a busy host got round to
    reading them. False where it cannot."""
    if sys.platform != "linux" or isinstance(sock, ssl.SSLSocket):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def _kernel_time(ancillary: list[tuple[int, int, bytes]]) -> int | None:
    """The kernel's receive time (realtime ns) in a recvmsg's ancillary data, if any."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= 16:
            sec, nsec = struct.unpack("qq", data[:16])
            return int(sec) * 1_000_000_000 + int(nsec)
    return None
