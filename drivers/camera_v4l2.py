"""Direct V4L2 capture (driver ``v4l2``): mmap buffers, kernel timestamps, manual controls.

The camera is opened non-blocking (``/dev/videoN``, a ``/dev/v4l/by-id/...`` link or a
bare index), its formats enumerated, and MJPEG preferred (YUYV the fallback); the
applied size and rate are read back. Four mmap buffers circulate through QBUF/DQBUF,
``poll`` waiting at most ``timeout`` seconds for the next one.

**Timing.** Each buffer carries the kernel's timestamp; with
``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC`` it is CLOCK_MONOTONIC, the clock of
``time.monotonic_ns()``, so no mapping is needed (``time_source="kernel"``). Its source
flag says what it marks: the start of exposure (SOE, what ``uvcvideo`` reports) gives
``mid = t + exposure / 2``; the end of frame (EOF) gives ``mid = t - exposure / 2`` (the
sensor readout time is not known and ignored: an EOF stamp is late by about the readout,
a few ms to one frame period on a rolling-shutter sensor). The exposure is the value
read back from ``V4L2_CID_EXPOSURE_ABSOLUTE`` (100 µs units), re-read once a second
while the camera exposes automatically; where it cannot be read, ``latency_s`` stands for
the nominal offset between the middle of the exposure and the timestamp (half the
nominal exposure). Buffers without a monotonic timestamp fall back to receipt time less
``latency_s`` (``time_source="receipt"``). Gaps in the buffers' ``sequence`` are
counted in ``drops``.

**Pixels.** MJPEG is passed on byte for byte (``Frame.jpeg`` holds the buffer's
``bytesused`` bytes). Many UVC cameras omit the Huffman tables (no DHT segment; decoders
use the standard ones from JPEG Annex K): that is noted in ``info.extra["jpeg_dht"]``
and the bytes are still kept as sent. YUYV is converted to BGR (``Frame.image``), and
JPEG-encoded into ``Frame.jpeg`` only with ``encode_jpeg=True``.

The operating-system calls go through a :class:`acq.drivers.v4l2_system.V4L2System`
(default :class:`~acq.drivers.v4l2_system.OsV4L2`: ``os``, ``fcntl.ioctl``, ``mmap``,
``select.poll``) so tests can put a fake kernel device behind the real ctypes structures.
The rest stays whole: one driver class whose negotiation, controls and capture share the
open device's state (descriptor, format, buffers, exposure).
"""

from __future__ import annotations

import ctypes
import errno
import logging
import os
import time
from collections.abc import Sequence
from fractions import Fraction
from typing import Any

import cv2
import numpy as np

from acq.drivers import v4l2_abi as abi
from acq.drivers.camera import Camera, FrameFormat, FrameTimeout
from acq.drivers.errors import ConnectionLost, DeviceError
from acq.drivers.v4l2_system import Buffer, OsV4L2, V4L2System
from acq.records import DeviceInfo, Frame

__all__ = ["ControlInfo", "V4L2Camera", "jpeg_has_dht"]

log = logging.getLogger(__name__)

# errno values meaning the device is gone (unplugged, USB reset, driver unbound)
_GONE = {errno.ENODEV, errno.EIO, errno.ENXIO, errno.ENOENT, errno.ESHUTDOWN, errno.EPIPE}

_PREFERRED = ("MJPG", "JPEG", "YUYV")
_SUPPORTED = {abi.PIX_FMT_MJPEG, abi.PIX_FMT_JPEG, abi.PIX_FMT_YUYV}


class ControlInfo:
    """A control's range as the device reports it (VIDIOC_QUERYCTRL)."""

    def __init__(self, q: abi.v4l2_queryctrl) -> None:
        self.id = int(q.id)
        self.name = q.name.decode("utf-8", "replace")
        self.type = int(q.type)
        self.minimum = int(q.minimum)
        self.maximum = int(q.maximum)
        self.step = max(1, int(q.step))
        self.default = int(q.default_value)
        self.flags = int(q.flags)

    def clamp(self, value: int) -> int:
        """``value`` within [minimum, maximum], on the step grid."""
        value = min(max(value, self.minimum), self.maximum)
        return self.minimum + round((value - self.minimum) / self.step) * self.step


def jpeg_has_dht(jpeg: bytes) -> bool:
    """True when the JPEG's header (before the scan data) holds a DHT (FF C4) segment."""
    i = 2
    n = len(jpeg)
    while i + 4 <= n and jpeg[i] == 0xFF:
        marker = jpeg[i + 1]
        if marker == 0xC4:
            return True
        if marker == 0xDA:  # start of scan: the header is over
            return False
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        i += 2 + int.from_bytes(jpeg[i + 2 : i + 4], "big")
    return False


def _device_path(source: str) -> str:
    return f"/dev/video{source}" if source.isdigit() else source


def _text(raw: bytes) -> str:
    return raw.decode("utf-8", "replace")


class V4L2Camera(Camera):
    """One V4L2 capture device, read through mmap buffers (see the module docstring).

    Options beyond :class:`acq.drivers.camera.Camera`'s: ``exposure_s`` (manual exposure,
    seconds; None leaves the camera's automatic exposure), ``gain`` (device units),
    ``white_balance_k`` (manual white balance, kelvin), ``buffers`` (mmap buffers to ask
    for, 4), ``encode_jpeg`` (YUYV frames also JPEG-encoded, at ``jpeg_quality``), and
    ``system`` (the :class:`V4L2System`; the real one by default).
    """

    driver = "v4l2"

    def __init__(
        self,
        source: str,
        *,
        exposure_s: float | None = None,
        gain: int | None = None,
        white_balance_k: int | None = None,
        buffers: int = 4,
        encode_jpeg: bool = False,
        jpeg_quality: int = 90,
        system: V4L2System | None = None,
        **options: Any,
    ) -> None:
        super().__init__(source, **options)
        self.exposure_s = exposure_s
        self.gain = gain
        self.white_balance_k = white_balance_k
        self.buffer_count = buffers
        self.encode_jpeg = encode_jpeg
        self.jpeg_quality = jpeg_quality
        self.system: V4L2System = system if system is not None else OsV4L2()
        self._fd: int | None = None
        self._buffers: list[Buffer] = []
        self._pixelformat = 0
        self._bytesperline = 0
        self._streaming = False
        self._last_sequence: int | None = None
        self._exposure_known: float | None = None  # s, read back from the device
        self._exposure_auto = False  # the camera chooses its exposure: re-read it
        self._exposure_read_ns = 0
        self._extra: dict[str, str] = {}
        self._dht_checked = False

    # --- low level ---------------------------------------------------------------------

    def _ioctl(self, request: int, arg: Any) -> None:
        """One ioctl on the open device; a vanished device raises ConnectionLost."""
        if self._fd is None:
            raise ConnectionLost(f"{self.source}: not open")
        try:
            self.system.ioctl(self._fd, request, arg)
        except OSError as e:
            name = abi.IOCTL_NAMES.get(request, hex(request))
            if e.errno in _GONE:
                raise ConnectionLost(f"{self.source}: {name}: {os.strerror(e.errno)}") from e
            raise

    def _try_ioctl(self, request: int, arg: Any) -> bool:
        """An ioctl whose refusal (EINVAL, ENOTTY, EACCES...) is an answer, not a failure."""
        try:
            self._ioctl(request, arg)
            return True
        except ConnectionLost:
            raise
        except OSError:
            return False

    def query_control(self, cid: int) -> ControlInfo | None:
        """The control's range, or None when the device has no such (enabled) control."""
        q = abi.v4l2_queryctrl(id=cid)
        if not self._try_ioctl(abi.VIDIOC_QUERYCTRL, q):
            return None
        if q.flags & abi.V4L2_CTRL_FLAG_DISABLED:
            return None
        return ControlInfo(q)

    def get_control(self, cid: int) -> int | None:
        """The control's current value, or None when it cannot be read."""
        c = abi.v4l2_control(id=cid)
        return int(c.value) if self._try_ioctl(abi.VIDIOC_G_CTRL, c) else None

    def set_control(self, cid: int, value: int, what: str) -> int:
        """Set a control (clamped to its range) and return the value read back.

        Raises DeviceError naming ``what`` when the device lacks or refuses the control."""
        info = self.query_control(cid)
        if info is None:
            raise DeviceError(f"{self.source}: the camera has no {what} control")
        if info.flags & abi.V4L2_CTRL_FLAG_READ_ONLY:
            raise DeviceError(f"{self.source}: {what} ({info.name}) is read-only")
        wanted = info.clamp(value) if info.type != abi.V4L2_CTRL_TYPE_MENU else value
        c = abi.v4l2_control(id=cid, value=wanted)
        try:
            self._ioctl(abi.VIDIOC_S_CTRL, c)
        except OSError as e:
            raise DeviceError(
                f"{self.source}: setting {what} ({info.name}) to {wanted} failed: "
                f"{os.strerror(e.errno or 0)}"
            ) from e
        read = self.get_control(cid)
        return wanted if read is None else read

    # --- connect -------------------------------------------------------------------------

    def connect(self) -> DeviceInfo:
        """Open, check it captures, negotiate format and rate, apply controls, map buffers."""
        self.close()
        path = _device_path(self.source)
        try:
            self._fd = self.system.open(path)
        except OSError as e:
            if e.errno in _GONE:
                raise ConnectionLost(f"{path}: {os.strerror(e.errno)}") from e
            raise DeviceError(f"{path}: cannot open: {os.strerror(e.errno or 0)}") from e
        self._extra = {"path": path}
        self._last_sequence = None
        self._dht_checked = False
        try:
            info = self._negotiate(path)
        except OSError as e:
            self.close()
            raise DeviceError(f"{path}: {e}") from e
        except BaseException:
            self.close()
            raise
        self.info = info
        return info

    def _negotiate(self, path: str) -> DeviceInfo:
        cap = abi.v4l2_capability()
        self._ioctl(abi.VIDIOC_QUERYCAP, cap)
        caps = cap.device_caps if cap.capabilities & abi.V4L2_CAP_DEVICE_CAPS else cap.capabilities
        card = _text(cap.card)
        if not caps & abi.V4L2_CAP_VIDEO_CAPTURE:
            raise DeviceError(
                f"{path} ({card}) is not a video capture node (a UVC camera's second node "
                "carries metadata; use the first, ...-video-index0)"
            )
        if not caps & abi.V4L2_CAP_STREAMING:
            raise DeviceError(f"{path} ({card}) cannot stream through buffers")
        formats = self._enum_formats()
        self._extra.update(
            driver=_text(cap.driver),
            bus_info=_text(cap.bus_info),
            formats=",".join(abi.fourcc_str(f) for f in formats),
        )
        pixelformat = self._choose_format(formats, path)
        self._set_format(pixelformat, path)
        fps = self._set_rate()
        assert self.format is not None
        self.format = FrameFormat(self.format.width, self.format.height, fps, self.format.fourcc)
        self._apply_controls()
        self._map_buffers()
        v = cap.version
        return DeviceInfo(
            name=self.name,
            driver=self.driver,
            vendor=_text(cap.driver),
            model=card,
            serial=_serial_from_path(self.source),
            firmware=f"{(v >> 16) & 0xFF}.{(v >> 8) & 0xFF}.{v & 0xFF}",
            extra=self._extra,
        )

    def _enum_formats(self) -> list[int]:
        found: list[int] = []
        for index in range(64):
            d = abi.v4l2_fmtdesc(index=index, type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
            if not self._try_ioctl(abi.VIDIOC_ENUM_FMT, d):
                break
            found.append(int(d.pixelformat))
        return found

    def _choose_format(self, formats: Sequence[int], path: str) -> int:
        names = [abi.fourcc_str(f) for f in formats]
        if self.fourcc:
            wanted = abi.fourcc(self.fourcc.upper().ljust(4)[:4])
            if wanted not in _SUPPORTED:
                raise DeviceError(f"fourcc {self.fourcc!r} is not one of MJPG, JPEG, YUYV")
            if wanted not in formats:
                raise DeviceError(
                    f"{path} does not offer {self.fourcc}; it offers {', '.join(names) or 'none'}"
                )
            return wanted
        for name in _PREFERRED:
            if abi.fourcc(name) in formats:
                return abi.fourcc(name)
        raise DeviceError(
            f"{path} offers {', '.join(names) or 'no formats'}; acq needs MJPG or YUYV"
        )

    def _set_format(self, pixelformat: int, path: str) -> None:
        current = abi.v4l2_format(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
        self._ioctl(abi.VIDIOC_G_FMT, current)
        f = abi.v4l2_format(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
        f.fmt.pix.width = self.width or current.fmt.pix.width
        f.fmt.pix.height = self.height or current.fmt.pix.height
        f.fmt.pix.pixelformat = pixelformat
        f.fmt.pix.field = abi.V4L2_FIELD_ANY
        self._ioctl(abi.VIDIOC_S_FMT, f)
        applied = abi.v4l2_format(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
        self._ioctl(abi.VIDIOC_G_FMT, applied)
        pix = applied.fmt.pix
        if pix.pixelformat not in _SUPPORTED:
            raise DeviceError(
                f"{path} applied {abi.fourcc_str(pix.pixelformat)} where "
                f"{abi.fourcc_str(pixelformat)} was asked"
            )
        if self.width and self.height and (pix.width, pix.height) != (self.width, self.height):
            self._extra["requested_size"] = f"{self.width}x{self.height}"
            log.warning(
                "%s: asked for %dx%d, the camera applied %dx%d",
                path,
                self.width,
                self.height,
                pix.width,
                pix.height,
            )
        self._pixelformat = int(pix.pixelformat)
        self._bytesperline = int(pix.bytesperline)
        fourcc = abi.fourcc_str(pix.pixelformat)
        self.format = FrameFormat(int(pix.width), int(pix.height), 0.0, fourcc)
        self._extra.update(fourcc=fourcc, size=f"{pix.width}x{pix.height}")

    def _set_rate(self) -> float:
        """Ask for ``fps`` where the device allows it; the rate read back (0: unknown)."""
        parm = abi.v4l2_streamparm(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
        if not self._try_ioctl(abi.VIDIOC_G_PARM, parm):
            return 0.0
        if self.fps > 0 and parm.parm.capture.capability & abi.V4L2_CAP_TIMEPERFRAME:
            rate = Fraction(self.fps).limit_denominator(1001)
            parm.parm.capture.timeperframe.numerator = rate.denominator
            parm.parm.capture.timeperframe.denominator = rate.numerator
            self._try_ioctl(abi.VIDIOC_S_PARM, parm)
            parm = abi.v4l2_streamparm(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
            self._try_ioctl(abi.VIDIOC_G_PARM, parm)
        tpf = parm.parm.capture.timeperframe
        fps = tpf.denominator / tpf.numerator if tpf.numerator else 0.0
        self._extra["fps"] = f"{fps:g}"
        if self.fps > 0 and fps > 0 and abs(fps - self.fps) > 0.01 * self.fps:
            self._extra["requested_fps"] = f"{self.fps:g}"
        return fps

    def _apply_controls(self) -> None:
        extra = self._extra
        if self.exposure_s is not None:
            mode = self.set_control(
                abi.V4L2_CID_EXPOSURE_AUTO, abi.V4L2_EXPOSURE_MANUAL, "manual exposure mode"
            )
            if mode != abi.V4L2_EXPOSURE_MANUAL:
                raise DeviceError(f"{self.source}: the camera stays in exposure mode {mode}")
            if self.query_control(abi.V4L2_CID_EXPOSURE_AUTO_PRIORITY) is not None:
                # 0: never lengthen the frame period to expose longer (keeps the rate)
                self._try_ioctl(
                    abi.VIDIOC_S_CTRL, abi.v4l2_control(id=abi.V4L2_CID_EXPOSURE_AUTO_PRIORITY)
                )
            units = max(1, round(self.exposure_s / abi.EXPOSURE_UNIT_S))
            got = self.set_control(abi.V4L2_CID_EXPOSURE_ABSOLUTE, units, "exposure time")
            extra["exposure_mode"] = "manual"
            self._exposure_known = got * abi.EXPOSURE_UNIT_S
            self._exposure_auto = False
        else:
            mode_read = self.get_control(abi.V4L2_CID_EXPOSURE_AUTO)
            self._exposure_auto = mode_read is not None and mode_read != abi.V4L2_EXPOSURE_MANUAL
            extra["exposure_mode"] = {
                None: "unknown",
                abi.V4L2_EXPOSURE_MANUAL: "manual (as set on the camera)",
            }.get(mode_read, "auto")
            self._read_exposure()
        if self._exposure_known is not None:
            extra["exposure_s"] = f"{self._exposure_known:.6g}"
        if self.gain is not None:
            extra["gain"] = str(self.set_control(abi.V4L2_CID_GAIN, self.gain, "gain"))
        if self.white_balance_k is not None:
            self.set_control(abi.V4L2_CID_AUTO_WHITE_BALANCE, 0, "automatic white balance")
            got = self.set_control(
                abi.V4L2_CID_WHITE_BALANCE_TEMPERATURE,
                self.white_balance_k,
                "white balance temperature",
            )
            extra["white_balance_k"] = str(got)

    def _read_exposure(self) -> None:
        """Re-read the exposure time (100 µs units) the camera is using now."""
        units = self.get_control(abi.V4L2_CID_EXPOSURE_ABSOLUTE)
        self._exposure_known = units * abi.EXPOSURE_UNIT_S if units and units > 0 else None
        self._exposure_read_ns = time.monotonic_ns()

    def _map_buffers(self) -> None:
        req = abi.v4l2_requestbuffers(
            count=self.buffer_count,
            type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE,
            memory=abi.V4L2_MEMORY_MMAP,
        )
        self._ioctl(abi.VIDIOC_REQBUFS, req)
        if req.count < 2:
            raise DeviceError(f"{self.source}: only {req.count} capture buffer(s) available")
        assert self._fd is not None
        for index in range(req.count):
            b = abi.v4l2_buffer(
                index=index, type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=abi.V4L2_MEMORY_MMAP
            )
            self._ioctl(abi.VIDIOC_QUERYBUF, b)
            self._buffers.append(self.system.mmap(self._fd, b.length, b.m.offset))
        self._extra["buffers"] = str(req.count)

    # --- streaming -----------------------------------------------------------------------

    def _queue(self, index: int) -> None:
        b = abi.v4l2_buffer(
            index=index, type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=abi.V4L2_MEMORY_MMAP
        )
        self._ioctl(abi.VIDIOC_QBUF, b)

    def start(self) -> None:
        """Queue every buffer and start streaming."""
        if self._fd is None:
            raise ConnectionLost(f"{self.source}: start() before connect()")
        if self._streaming:
            return
        for index in range(len(self._buffers)):
            self._queue(index)
        self._ioctl(abi.VIDIOC_STREAMON, ctypes.c_int(abi.V4L2_BUF_TYPE_VIDEO_CAPTURE))
        self._streaming = True
        self._last_sequence = None

    def stop(self) -> None:
        """Stop streaming (the kernel takes every buffer back); the device stays open."""
        if self._fd is None or not self._streaming:
            return
        self._streaming = False
        self._ioctl(abi.VIDIOC_STREAMOFF, ctypes.c_int(abi.V4L2_BUF_TYPE_VIDEO_CAPTURE))

    def close(self) -> None:
        """Stop, unmap, free the buffers and close; safe to call twice and after a failure."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        if self._streaming:
            self._streaming = False
            try:
                self.system.ioctl(
                    fd, abi.VIDIOC_STREAMOFF, ctypes.c_int(abi.V4L2_BUF_TYPE_VIDEO_CAPTURE)
                )
            except OSError:
                pass
        for buf in self._buffers:
            try:
                self.system.munmap(buf)
            except (OSError, BufferError):
                pass
        if self._buffers:
            self._buffers = []
            try:  # free the kernel's buffers
                self.system.ioctl(
                    fd,
                    abi.VIDIOC_REQBUFS,
                    abi.v4l2_requestbuffers(
                        count=0,
                        type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE,
                        memory=abi.V4L2_MEMORY_MMAP,
                    ),
                )
            except OSError:
                pass
        try:
            self.system.close(fd)
        except OSError:
            pass

    def _dequeue(self, deadline_ns: int) -> abi.v4l2_buffer:
        assert self._fd is not None
        while True:
            left = (deadline_ns - time.monotonic_ns()) * 1e-9
            if left <= 0 or not self.system.wait_readable(self._fd, left):
                raise FrameTimeout(f"{self.source}: no frame within {self.timeout:g} s")
            b = abi.v4l2_buffer(type=abi.V4L2_BUF_TYPE_VIDEO_CAPTURE, memory=abi.V4L2_MEMORY_MMAP)
            try:
                self._ioctl(abi.VIDIOC_DQBUF, b)
            except ConnectionLost:
                raise
            except OSError as e:
                if e.errno in (errno.EAGAIN, errno.EINTR):
                    continue
                raise DeviceError(
                    f"{self.source}: VIDIOC_DQBUF: {os.strerror(e.errno or 0)}"
                ) from e
            return b

    def read_frame(self) -> Frame:
        """The next good frame (at most ``timeout`` s); raises FrameTimeout, ConnectionLost."""
        if self._fd is None or not self._streaming:
            raise ConnectionLost(f"{self.source}: not streaming")
        deadline = time.monotonic_ns() + int(self.timeout * 1e9)
        while True:
            b = self._dequeue(deadline)
            recv_ns = time.monotonic_ns()
            index = int(b.index)
            try:
                if b.flags & abi.V4L2_BUF_FLAG_ERROR or b.bytesused == 0:
                    data = None
                else:
                    data = bytes(self._buffers[index][: b.bytesused])
            finally:
                self._queue(index)  # back to the kernel at once
            self._count_sequence(int(b.sequence))
            if data is None:
                self.corrupt += 1
                continue
            frame = self._frame(b, data, recv_ns)
            if frame is None:
                self.corrupt += 1
                continue
            self.frames += 1
            return frame

    def _count_sequence(self, sequence: int) -> None:
        last = self._last_sequence
        if last is not None:
            gap = (sequence - last - 1) & 0xFFFFFFFF
            if gap < 0x80000000:  # ignore a counter that went backwards (restart)
                self.drops += gap
        self._last_sequence = sequence

    def frame_time(self, b: abi.v4l2_buffer, recv_ns: int) -> tuple[int, float, str]:
        """(middle of exposure, host monotonic ns; exposure s or 0; time source)."""
        if (
            self._exposure_auto
            and recv_ns - self._exposure_read_ns > 1_000_000_000
            and self._fd is not None
        ):
            self._read_exposure()
        exposure = self._exposure_known
        half_ns = round((exposure / 2 if exposure else self.latency_s) * 1e9)
        ts = b.timestamp.tv_sec * 1_000_000_000 + b.timestamp.tv_usec * 1000
        kind = b.flags & abi.V4L2_BUF_FLAG_TIMESTAMP_MASK
        if kind != abi.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC or ts <= 0:
            return recv_ns - round(self.latency_s * 1e9), exposure or 0.0, "receipt"
        if b.flags & abi.V4L2_BUF_FLAG_TSTAMP_SRC_MASK == abi.V4L2_BUF_FLAG_TSTAMP_SRC_SOE:
            return ts + half_ns, exposure or 0.0, "kernel"
        return ts - half_ns, exposure or 0.0, "kernel"

    def _frame(self, b: abi.v4l2_buffer, data: bytes, recv_ns: int) -> Frame | None:
        assert self.format is not None
        w, h = self.format.width, self.format.height
        stamp_ns, exposure, source = self.frame_time(b, recv_ns)
        if not self._dht_checked:
            self._dht_checked = True
            self._extra["timestamps"] = _describe_flags(int(b.flags))
        if self._pixelformat in (abi.PIX_FMT_MJPEG, abi.PIX_FMT_JPEG):
            if not data.startswith(b"\xff\xd8") or data.rfind(b"\xff\xd9") < 2:
                return None  # truncated or garbled: no SOI or no EOI
            if "jpeg_dht" not in self._extra:
                self._extra["jpeg_dht"] = (
                    "present" if jpeg_has_dht(data) else "absent (standard tables implied)"
                )
            return Frame(recv_ns, stamp_ns, int(b.sequence), w, h, jpeg=data,
                         exposure_s=exposure, time_source=source)  # fmt: skip
        image = self._yuyv_to_bgr(data, w, h)
        if image is None:
            return None
        jpeg = b""
        if self.encode_jpeg:
            ok, enc = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            if not ok:
                return None
            jpeg = enc.tobytes()
        return Frame(recv_ns, stamp_ns, int(b.sequence), w, h, jpeg=jpeg, image=image,
                     exposure_s=exposure, time_source=source)  # fmt: skip

    def _yuyv_to_bgr(self, data: bytes, w: int, h: int) -> np.ndarray | None:
        stride = self._bytesperline or 2 * w
        if len(data) < stride * (h - 1) + 2 * w:
            return None  # short buffer
        rows = np.frombuffer(data, np.uint8, count=stride * h if len(data) >= stride * h else -1)
        if rows.size < stride * h:
            rows = np.concatenate([rows, np.zeros(stride * h - rows.size, np.uint8)])
        yuyv = rows.reshape(h, stride)[:, : 2 * w].reshape(h, w, 2)
        return cv2.cvtColor(np.ascontiguousarray(yuyv), cv2.COLOR_YUV2BGR_YUYV)


def _describe_flags(flags: int) -> str:
    clock = {
        abi.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC: "monotonic",
        abi.V4L2_BUF_FLAG_TIMESTAMP_COPY: "copy",
    }.get(flags & abi.V4L2_BUF_FLAG_TIMESTAMP_MASK, "unknown")
    src = (
        "start of exposure"
        if flags & abi.V4L2_BUF_FLAG_TSTAMP_SRC_MASK == abi.V4L2_BUF_FLAG_TSTAMP_SRC_SOE
        else "end of frame"
    )
    return f"{clock}, {src}"


def _serial_from_path(source: str) -> str:
    """The serial in a ``/dev/v4l/by-id/usb-Vendor_Model_SERIAL-video-index0`` name."""
    base = os.path.basename(source)
    if not base.startswith("usb-") or "-video-index" not in base:
        return ""
    parts = base[4:].rsplit("-video-index", 1)[0].split("_")
    return parts[-1] if len(parts) >= 3 else ""
