"""The V4L2 driver against a fake kernel device at the ioctl layer.

No kernel video device exists on the test machine (no /dev/video*, and vivid cannot be
loaded in a container), so :class:`FakeSystem` plays the kernel's side of every ioctl
the driver makes, on the real ctypes structures of :mod:`acq.drivers.v4l2_abi`: format
negotiation (nearest size, refused sizes), frame intervals, controls with ranges, the
mmap buffer queue (QBUF/DQBUF, EAGAIN when nothing is done), sequence numbers with
injected gaps, timestamps with their clock and source flags, and ENODEV after an
"unplug". The struct sizes and ioctl numbers are checked against the values of the
kernel headers on x86_64 (printed by a C program including ``<linux/videodev2.h>``).
"""

from __future__ import annotations

import collections
import ctypes
import errno
import os
import platform
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import pytest

from acq.drivers import v4l2_abi as abi
from acq.drivers.camera import FrameTimeout, camera_class
from acq.drivers.camera_v4l2 import V4L2Camera, jpeg_has_dht
from acq.drivers.errors import ConnectionLost, DeviceError
from acq.drivers.reconnect import Backoff, CameraLink, LinkEvent
from acq.drivers.v4l2_system import OsV4L2

PAGE = 4096
SOE = abi.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | abi.V4L2_BUF_FLAG_TSTAMP_SRC_SOE
EOF = abi.V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | abi.V4L2_BUF_FLAG_TSTAMP_SRC_EOF


def _oserror(code: int) -> OSError:
    return OSError(code, os.strerror(code))


@dataclass
class Control:
    minimum: int
    maximum: int
    value: int
    step: int = 1
    type: int = abi.V4L2_CTRL_TYPE_INTEGER
    name: str = ""


def uvc_controls() -> dict[int, Control]:
    """Controls of a typical UVC camera (ranges as uvcvideo reports them)."""
    return {
        abi.V4L2_CID_EXPOSURE_AUTO: Control(0, 3, abi.V4L2_EXPOSURE_APERTURE_PRIORITY, 1,
                                            abi.V4L2_CTRL_TYPE_MENU, "Auto Exposure"),
        abi.V4L2_CID_EXPOSURE_ABSOLUTE: Control(1, 5000, 156, 1, name="Exposure Time, Absolute"),
        abi.V4L2_CID_EXPOSURE_AUTO_PRIORITY: Control(0, 1, 1, 1, abi.V4L2_CTRL_TYPE_BOOLEAN),
        abi.V4L2_CID_GAIN: Control(0, 100, 32, name="Gain"),
        abi.V4L2_CID_AUTO_WHITE_BALANCE: Control(0, 1, 1, 1, abi.V4L2_CTRL_TYPE_BOOLEAN),
        abi.V4L2_CID_WHITE_BALANCE_TEMPERATURE: Control(2800, 6500, 4600, 10, name="WB Temp"),
    }  # fmt: skip


@dataclass
class FakeDevice:
    """The kernel side of one capture node."""

    formats: dict[str, list[tuple[int, int]]]  # FOURCC -> frame sizes, in ENUM_FMT order
    rates: tuple[float, ...] = (30.0, 15.0)
    controls: dict[int, Control] = field(default_factory=uvc_controls)
    card: str = "USB 2.0 Camera: HD 720P"
    caps: int = abi.V4L2_CAP_VIDEO_CAPTURE | abi.V4L2_CAP_STREAMING
    max_buffers: int = 8
    free_running: bool = False  # a frame is ready whenever the driver waits for one
    gone: bool = False
    streaming: bool = False
    pixelformat: int = 0
    width: int = 0
    height: int = 0
    fps: float = 30.0
    memory: list[bytearray] = field(default_factory=list)
    queued: collections.deque[int] = field(default_factory=collections.deque)
    done: collections.deque[tuple[int, int, int, int, int]] = field(
        default_factory=collections.deque
    )  # (index, bytesused, flags, timestamp ns, sequence)
    sequence: int = 0
    calls: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        first = next(iter(self.formats))
        self.pixelformat = abi.fourcc(first)
        self.width, self.height = self.formats[first][0]

    # --- what a test does to the "camera" --------------------------------------------
    def emit(
        self,
        payload: bytes,
        *,
        sequence: int | None = None,
        ts_ns: int | None = None,
        flags: int = SOE,
        error: bool = False,
    ) -> bool:
        """The sensor delivers a frame into the next queued buffer (False: none queued)."""
        seq = self.sequence if sequence is None else sequence
        self.sequence = seq + 1
        if not self.streaming or not self.queued:
            return False
        index = self.queued.popleft()
        mem = self.memory[index]
        mem[: len(payload)] = payload
        if error:
            flags |= abi.V4L2_BUF_FLAG_ERROR
        stamp = time.monotonic_ns() if ts_ns is None else ts_ns
        self.done.append((index, len(payload), flags, stamp, seq))
        return True

    def unplug(self) -> None:
        self.gone = True

    # --- the kernel side -------------------------------------------------------------
    def _sizeimage(self) -> int:
        if self.pixelformat == abi.PIX_FMT_YUYV:
            return self.width * self.height * 2
        return max(PAGE, self.width * self.height)  # a generous MJPEG buffer

    def _fill_pix(self, f: abi.v4l2_format) -> None:
        pix = f.fmt.pix
        pix.width, pix.height, pix.pixelformat = self.width, self.height, self.pixelformat
        pix.field = abi.V4L2_FIELD_NONE
        pix.bytesperline = self.width * 2 if self.pixelformat == abi.PIX_FMT_YUYV else 0
        pix.sizeimage = self._sizeimage()

    def ioctl(self, request: int, arg: Any) -> None:
        self.calls.append(abi.IOCTL_NAMES.get(request, hex(request)))
        if self.gone:
            raise _oserror(errno.ENODEV)
        if request == abi.VIDIOC_QUERYCAP:
            arg.driver, arg.card = b"uvcvideo", self.card.encode()
            arg.bus_info = b"usb-0000:00:14.0-2"
            arg.version = (6 << 16) | (1 << 8) | 0
            arg.capabilities = self.caps | abi.V4L2_CAP_DEVICE_CAPS
            arg.device_caps = self.caps
        elif request == abi.VIDIOC_ENUM_FMT:
            names = list(self.formats)
            if arg.type != abi.V4L2_BUF_TYPE_VIDEO_CAPTURE or arg.index >= len(names):
                raise _oserror(errno.EINVAL)
            arg.pixelformat = abi.fourcc(names[arg.index])
            arg.description = names[arg.index].encode()
        elif request == abi.VIDIOC_G_FMT:
            self._fill_pix(arg)
        elif request == abi.VIDIOC_S_FMT:
            if self.memory:
                raise _oserror(errno.EBUSY)
            name = abi.fourcc_str(arg.fmt.pix.pixelformat)
            if name not in self.formats:
                name = next(iter(self.formats))
            want = (arg.fmt.pix.width, arg.fmt.pix.height)
            w, h = min(
                self.formats[name],
                key=lambda s: abs(s[0] - want[0]) + abs(s[1] - want[1]),
            )
            self.pixelformat, self.width, self.height = abi.fourcc(name), w, h
            self._fill_pix(arg)
        elif request in (abi.VIDIOC_G_PARM, abi.VIDIOC_S_PARM):
            cap = arg.parm.capture
            if request == abi.VIDIOC_S_PARM and cap.timeperframe.numerator:
                wanted = cap.timeperframe.denominator / cap.timeperframe.numerator
                self.fps = min(self.rates, key=lambda r: abs(r - wanted))
            cap.capability = abi.V4L2_CAP_TIMEPERFRAME
            cap.timeperframe.numerator, cap.timeperframe.denominator = 1, int(self.fps)
        elif request == abi.VIDIOC_QUERYCTRL:
            c = self.controls.get(arg.id)
            if c is None:
                raise _oserror(errno.EINVAL)
            arg.type, arg.name = c.type, c.name.encode()
            arg.minimum, arg.maximum, arg.step = c.minimum, c.maximum, c.step
            arg.default_value = c.value
        elif request == abi.VIDIOC_G_CTRL:
            c = self.controls.get(arg.id)
            if c is None:
                raise _oserror(errno.EINVAL)
            arg.value = c.value
        elif request == abi.VIDIOC_S_CTRL:
            c = self.controls.get(arg.id)
            if c is None:
                raise _oserror(errno.EINVAL)
            auto = self.controls.get(abi.V4L2_CID_EXPOSURE_AUTO)
            if (
                arg.id == abi.V4L2_CID_EXPOSURE_ABSOLUTE
                and auto is not None
                and auto.value != abi.V4L2_EXPOSURE_MANUAL
            ):
                raise _oserror(errno.EACCES)  # inactive while the camera exposes itself
            value = min(max(arg.value, c.minimum), c.maximum)
            c.value = c.minimum + (value - c.minimum) // c.step * c.step
        elif request == abi.VIDIOC_REQBUFS:
            if self.streaming:
                raise _oserror(errno.EBUSY)
            assert arg.memory == abi.V4L2_MEMORY_MMAP
            arg.count = min(arg.count, self.max_buffers)
            self.memory = [bytearray(self._sizeimage()) for _ in range(arg.count)]
            self.queued.clear()
            self.done.clear()
        elif request == abi.VIDIOC_QUERYBUF:
            if arg.index >= len(self.memory):
                raise _oserror(errno.EINVAL)
            arg.length = len(self.memory[arg.index])
            arg.m.offset = arg.index * 256 * PAGE
        elif request == abi.VIDIOC_QBUF:
            busy = {d[0] for d in self.done}
            if arg.index >= len(self.memory) or arg.index in self.queued or arg.index in busy:
                raise _oserror(errno.EINVAL)
            self.queued.append(arg.index)
        elif request == abi.VIDIOC_DQBUF:
            if not self.done:
                raise _oserror(errno.EAGAIN)
            index, used, flags, stamp, seq = self.done.popleft()
            arg.index, arg.bytesused, arg.flags, arg.sequence = index, used, flags, seq
            arg.field = abi.V4L2_FIELD_NONE
            arg.timestamp.tv_sec, rest = divmod(stamp, 1_000_000_000)
            arg.timestamp.tv_usec = rest // 1000
            arg.length = len(self.memory[index])
        elif request == abi.VIDIOC_STREAMON:
            assert isinstance(arg, ctypes.c_int) and arg.value == abi.V4L2_BUF_TYPE_VIDEO_CAPTURE
            self.streaming = True
        elif request == abi.VIDIOC_STREAMOFF:
            self.streaming = False
            self.queued.clear()
            self.done.clear()
        else:
            raise _oserror(errno.ENOTTY)


class FakeSystem:
    """The driver's :class:`V4L2System`, backed by fake devices by path."""

    def __init__(self, devices: dict[str, FakeDevice]) -> None:
        self.devices = devices
        self.fds: dict[int, FakeDevice] = {}
        self.next_fd = 3
        self.mapped: list[bytearray] = []

    def open(self, path: str) -> int:
        dev = self.devices.get(path)
        if dev is None or dev.gone:
            raise _oserror(errno.ENOENT)
        fd, self.next_fd = self.next_fd, self.next_fd + 1
        self.fds[fd] = dev
        return fd

    def close(self, fd: int) -> None:
        if self.fds.pop(fd, None) is None:
            raise _oserror(errno.EBADF)

    def ioctl(self, fd: int, request: int, arg: Any) -> None:
        self.fds[fd].ioctl(request, arg)

    def mmap(self, fd: int, length: int, offset: int) -> bytearray:
        dev = self.fds[fd]
        assert offset % PAGE == 0
        mem = dev.memory[offset // (256 * PAGE)]
        assert length == len(mem)
        self.mapped.append(mem)
        return mem

    def munmap(self, buffer: Any) -> None:
        self.mapped.remove(buffer)

    def wait_readable(self, fd: int, timeout: float) -> bool:
        dev = self.fds[fd]
        if dev.free_running and dev.streaming and not dev.done and not dev.gone:
            dev.emit(a_jpeg())
        return bool(dev.done) or dev.gone


MJPG_720 = {"MJPG": [(1280, 720), (640, 480)], "YUYV": [(640, 480), (320, 240)]}


def make(
    device: FakeDevice | None = None, path: str = "/dev/video0", **options: Any
) -> tuple[V4L2Camera, FakeDevice, FakeSystem]:
    dev = device if device is not None else FakeDevice(dict(MJPG_720))
    system = FakeSystem({path: dev})
    options.setdefault("timeout", 0.05)
    return V4L2Camera(path, system=system, **options), dev, system


def a_jpeg(w: int = 64, h: int = 48) -> bytes:
    img = np.zeros((h, w, 3), np.uint8)
    img[:, : w // 2] = (0, 128, 255)
    ok, enc = cv2.imencode(".jpg", img)
    assert ok
    return enc.tobytes()


def strip_dht(jpeg: bytes) -> bytes:
    """The JPEG without its DHT segments, as many UVC cameras send MJPEG."""
    out, i = bytearray(jpeg[:2]), 2
    while jpeg[i + 1] != 0xDA:
        n = int.from_bytes(jpeg[i + 2 : i + 4], "big")
        if jpeg[i + 1] != 0xC4:
            out += jpeg[i : i + 2 + n]
        i += 2 + n
    return bytes(out + jpeg[i:])


# --- the ABI ----------------------------------------------------------------------------


@pytest.mark.skipif(platform.machine() != "x86_64", reason="sizes are x86_64's")
def test_struct_sizes_match_the_kernel_abi() -> None:
    sizes = {
        abi.v4l2_capability: 104,
        abi.v4l2_fmtdesc: 64,
        abi.v4l2_pix_format: 48,
        abi.v4l2_format: 208,
        abi.v4l2_requestbuffers: 20,
        abi.v4l2_buffer: 88,
        abi.v4l2_streamparm: 204,
        abi.v4l2_control: 8,
        abi.v4l2_queryctrl: 68,
    }
    for struct, size in sizes.items():
        assert ctypes.sizeof(struct) == size, struct.__name__
    # offsets that the unions and the timeval decide
    assert abi.v4l2_format.fmt.offset == 8
    assert abi.v4l2_buffer.timestamp.offset == 24
    assert abi.v4l2_buffer.sequence.offset == 56
    assert abi.v4l2_buffer.m.offset == 64
    assert abi.v4l2_buffer.length.offset == 72
    assert abi.v4l2_streamparm.parm.offset == 4


@pytest.mark.skipif(platform.machine() != "x86_64", reason="numbers are x86_64's")
def test_ioctl_numbers_match_the_kernel() -> None:
    assert abi.VIDIOC_QUERYCAP == 0x80685600
    assert abi.VIDIOC_ENUM_FMT == 0xC0405602
    assert abi.VIDIOC_G_FMT == 0xC0D05604
    assert abi.VIDIOC_S_FMT == 0xC0D05605
    assert abi.VIDIOC_REQBUFS == 0xC0145608
    assert abi.VIDIOC_QUERYBUF == 0xC0585609
    assert abi.VIDIOC_QBUF == 0xC058560F
    assert abi.VIDIOC_DQBUF == 0xC0585611
    assert abi.VIDIOC_STREAMON == 0x40045612
    assert abi.VIDIOC_STREAMOFF == 0x40045613
    assert abi.VIDIOC_G_PARM == 0xC0CC5615
    assert abi.VIDIOC_S_PARM == 0xC0CC5616
    assert abi.VIDIOC_G_CTRL == 0xC008561B
    assert abi.VIDIOC_S_CTRL == 0xC008561C
    assert abi.VIDIOC_QUERYCTRL == 0xC0445624
    assert abi.USBDEVFS_RESET == 0x5514
    assert abi.V4L2_CID_EXPOSURE_ABSOLUTE == 0x9A0902
    assert abi.V4L2_CID_WHITE_BALANCE_TEMPERATURE == 0x98091A
    assert abi.PIX_FMT_MJPEG == 0x47504A4D and abi.fourcc_str(abi.PIX_FMT_YUYV) == "YUYV"


def test_registered_as_v4l2() -> None:
    assert camera_class("v4l2") is V4L2Camera


# --- negotiation -------------------------------------------------------------------------


def test_mjpeg_preferred_and_rate_read_back() -> None:
    cam, dev, _ = make(width=1280, height=720, fps=25)
    info = cam.connect()
    assert cam.format is not None
    assert (cam.format.fourcc, cam.format.width, cam.format.height) == ("MJPG", 1280, 720)
    assert cam.format.fps == 30.0  # the device offers 30 and 15: the nearest is applied
    assert info.driver == "v4l2" and info.model == "USB 2.0 Camera: HD 720P"
    assert info.firmware == "6.1.0"
    assert info.extra["formats"] == "MJPG,YUYV"
    assert info.extra["fps"] == "30" and info.extra["requested_fps"] == "25"
    assert "requested_size" not in info.extra
    assert info.extra["buffers"] == "4" and len(dev.memory) == 4
    cam.close()


def test_refused_size_reports_what_was_applied() -> None:
    cam, _, _ = make(width=1000, height=700)
    info = cam.connect()
    assert cam.format is not None and (cam.format.width, cam.format.height) == (1280, 720)
    assert info.extra["size"] == "1280x720" and info.extra["requested_size"] == "1000x700"
    cam.close()


def test_yuyv_fallback_and_explicit_fourcc() -> None:
    cam, _, _ = make(FakeDevice({"YUYV": [(320, 240)]}))
    cam.connect()
    assert cam.format is not None and cam.format.fourcc == "YUYV"
    cam.close()
    cam, _, _ = make(fourcc="YUYV", width=640, height=480)
    cam.connect()
    assert cam.format is not None and cam.format.fourcc == "YUYV"
    cam.close()
    cam, _, _ = make(FakeDevice({"YUYV": [(320, 240)]}), fourcc="MJPG")
    with pytest.raises(DeviceError, match="does not offer MJPG; it offers YUYV"):
        cam.connect()


def test_a_metadata_node_is_refused_clearly() -> None:
    dev = FakeDevice(dict(MJPG_720), caps=abi.V4L2_CAP_STREAMING)
    cam, _, system = make(dev, path="/dev/video1")
    with pytest.raises(DeviceError, match="not a video capture node"):
        cam.connect()
    assert not system.fds  # closed again


def test_an_index_means_dev_video() -> None:
    dev = FakeDevice(dict(MJPG_720))
    cam = V4L2Camera("2", system=FakeSystem({"/dev/video2": dev}))
    assert cam.connect().extra["path"] == "/dev/video2"
    cam.close()


# --- buffers, sequence, timestamps --------------------------------------------------------


def test_buffers_circulate_and_gaps_count_as_drops() -> None:
    cam, dev, system = make()
    cam.connect()
    cam.start()
    assert list(dev.queued) == [0, 1, 2, 3] and dev.streaming
    jpeg = a_jpeg()
    seqs = [0, 1, 2, 5, 6, 7, 8, 9, 20, 21]
    got = []
    for s in seqs:
        assert dev.emit(jpeg, sequence=s)
        got.append(cam.read_frame().sequence)
        assert len(dev.queued) == 4  # the buffer went straight back to the kernel
    assert got == seqs
    assert cam.frames == len(seqs) and cam.drops == 2 + 10
    cam.stop()
    assert not dev.streaming
    cam.start()  # again after a stop: every buffer queued afresh
    assert len(dev.queued) == 4
    cam.close()
    assert not system.mapped and not system.fds and dev.memory == []  # REQBUFS(0)
    cam.close()  # twice is fine


def test_soe_and_eof_timestamps_give_the_middle_of_exposure() -> None:
    cam, dev, _ = make(exposure_s=0.02)
    info = cam.connect()
    assert info.extra["exposure_s"] == "0.02"
    cam.start()
    t0 = (time.monotonic_ns() - 50_000_000) // 1000 * 1000  # timeval: µs
    dev.emit(a_jpeg(), ts_ns=t0, flags=SOE)
    f = cam.read_frame()
    assert f.time_source == "kernel" and f.exposure_s == pytest.approx(0.02)
    assert f.stamp_ns == t0 + 10_000_000  # start of exposure + exposure / 2
    assert f.recv_ns >= t0
    dev.emit(a_jpeg(), ts_ns=t0 + 40_000_000, flags=EOF)
    f = cam.read_frame()
    assert f.stamp_ns == t0 + 40_000_000 - 10_000_000  # end of frame - exposure / 2
    assert info.extra["timestamps"] == "monotonic, start of exposure"
    cam.close()


def test_unknown_exposure_uses_latency_and_copied_stamps_use_receipt() -> None:
    dev = FakeDevice(dict(MJPG_720), controls={})
    cam, _, _ = make(dev, latency_s=0.004)
    info = cam.connect()
    assert info.extra["exposure_mode"] == "unknown" and "exposure_s" not in info.extra
    cam.start()
    t0 = (time.monotonic_ns() - 30_000_000) // 1000 * 1000
    dev.emit(a_jpeg(), ts_ns=t0, flags=EOF)
    f = cam.read_frame()
    assert f.stamp_ns == t0 - 4_000_000 and f.exposure_s == 0.0 and f.time_source == "kernel"
    dev.emit(a_jpeg(), ts_ns=t0, flags=abi.V4L2_BUF_FLAG_TIMESTAMP_COPY)
    f = cam.read_frame()
    assert f.time_source == "receipt" and f.stamp_ns == f.recv_ns - 4_000_000
    cam.close()


def test_auto_exposure_is_read_back_from_the_camera() -> None:
    cam, dev, _ = make()  # camera in aperture priority, exposure 156 x 100 µs
    info = cam.connect()
    assert info.extra["exposure_mode"] == "auto"
    assert info.extra["exposure_s"] == "0.0156"
    cam.start()
    t0 = time.monotonic_ns() // 1000 * 1000
    dev.emit(a_jpeg(), ts_ns=t0)
    assert cam.read_frame().stamp_ns == t0 + 7_800_000
    cam.close()


# --- pixels --------------------------------------------------------------------------------


def test_mjpeg_passes_through_byte_identical_even_without_dht() -> None:
    cam, dev, _ = make()
    info = cam.connect()
    cam.start()
    uvc = strip_dht(a_jpeg())
    assert not jpeg_has_dht(uvc) and jpeg_has_dht(a_jpeg())
    dev.emit(uvc)
    f = cam.read_frame()
    assert f.jpeg == uvc and f.image is None
    assert (f.width, f.height) == (640, 480) or (f.width, f.height) == (1280, 720)
    assert info.extra["jpeg_dht"].startswith("absent")
    cam.close()


def test_garbled_and_error_buffers_are_counted_and_skipped() -> None:
    cam, dev, _ = make()
    cam.connect()
    cam.start()
    dev.emit(b"\x00" * 100)  # no SOI
    dev.emit(a_jpeg()[:200])  # truncated: no EOI
    dev.emit(a_jpeg(), error=True)  # the driver flagged it
    good = a_jpeg()
    dev.emit(good)
    f = cam.read_frame()
    assert f.jpeg == good and f.sequence == 3
    assert cam.corrupt == 3 and cam.frames == 1 and cam.drops == 0
    cam.close()


def _yuyv(w: int, h: int) -> bytes:
    rng = np.random.default_rng(1)
    return rng.integers(16, 235, size=(h, w, 2), dtype=np.uint8).tobytes()


def test_yuyv_converted_and_encoded_on_request() -> None:
    dev = FakeDevice({"YUYV": [(320, 240)]})
    cam, _, _ = make(dev)
    cam.connect()
    cam.start()
    raw = _yuyv(320, 240)
    dev.emit(raw)
    f = cam.read_frame()
    expected = cv2.cvtColor(
        np.frombuffer(raw, np.uint8).reshape(240, 320, 2), cv2.COLOR_YUV2BGR_YUYV
    )
    assert f.image is not None and np.array_equal(f.image, expected) and f.jpeg == b""
    cam.close()

    cam, dev, _ = make(FakeDevice({"YUYV": [(320, 240)]}), encode_jpeg=True)
    cam.connect()
    cam.start()
    dev.emit(raw)
    f = cam.read_frame()
    assert f.jpeg.startswith(b"\xff\xd8") and f.image is not None
    decoded = cv2.imdecode(np.frombuffer(f.jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (240, 320, 3)
    cam.close()


# --- controls ------------------------------------------------------------------------------


def test_manual_controls_set_and_read_back() -> None:
    cam, dev, _ = make(exposure_s=0.0123, gain=40, white_balance_k=4507)
    info = cam.connect()
    c = dev.controls
    assert c[abi.V4L2_CID_EXPOSURE_AUTO].value == abi.V4L2_EXPOSURE_MANUAL
    assert c[abi.V4L2_CID_EXPOSURE_ABSOLUTE].value == 123
    assert c[abi.V4L2_CID_EXPOSURE_AUTO_PRIORITY].value == 0
    assert c[abi.V4L2_CID_AUTO_WHITE_BALANCE].value == 0
    assert c[abi.V4L2_CID_WHITE_BALANCE_TEMPERATURE].value == 4510  # on the 10 K grid
    assert info.extra["exposure_mode"] == "manual"
    assert info.extra["exposure_s"] == "0.0123"
    assert info.extra["gain"] == "40" and info.extra["white_balance_k"] == "4510"
    cam.close()


def test_out_of_range_values_report_what_the_camera_applied() -> None:
    cam, _, _ = make(exposure_s=1.0, gain=500)
    info = cam.connect()
    assert info.extra["exposure_s"] == "0.5" and info.extra["gain"] == "100"
    cam.close()


def test_a_missing_control_is_a_clear_error() -> None:
    dev = FakeDevice(dict(MJPG_720), controls={})
    cam, _, system = make(dev, gain=3)
    with pytest.raises(DeviceError, match="no gain control"):
        cam.connect()
    assert not system.fds


# --- failures ------------------------------------------------------------------------------


def test_unplug_is_connection_lost() -> None:
    cam, dev, system = make()
    cam.connect()
    cam.start()
    dev.emit(a_jpeg())
    cam.read_frame()
    dev.unplug()
    with pytest.raises(ConnectionLost, match="VIDIOC_DQBUF"):
        cam.read_frame()
    cam.close()
    cam.close()
    assert not system.fds and not system.mapped
    with pytest.raises(ConnectionLost):  # still gone: reconnecting fails the same way
        cam.connect()


def test_camera_link_rides_through_an_unplug() -> None:
    dev = FakeDevice(dict(MJPG_720), free_running=True)
    cam, _, system = make(dev)
    events: list[str] = []

    def on_event(e: LinkEvent) -> None:
        events.append(e.kind)
        if e.kind == "connect_failed" and events.count("connect_failed") == 2:
            dev.gone, dev.streaming, dev.memory = False, False, []  # plugged back in, afresh

    link = CameraLink(cam, backoff=Backoff(first=0.001, cap=0.002), on_event=on_event,
                      reachable=lambda url: False)  # fmt: skip
    got = []
    stop = threading.Event()
    timer = threading.Timer(5.0, stop.set)  # a failing test must not hang
    timer.start()
    for frame in link.frames(stop):
        got.append(frame.sequence)
        if len(got) == 3:
            dev.unplug()
        if len(got) == 6:
            stop.set()
    timer.cancel()
    assert events[:4] == ["connected", "disconnected", "connect_failed", "connect_failed"]
    assert events[4] == "connected" and link.disconnects == 1
    assert got == [0, 1, 2, 3, 4, 5]  # the fake's counter runs on, as a device's would
    assert not system.fds and not system.mapped


def test_nothing_ready_is_frame_timeout() -> None:
    cam, _, _ = make(timeout=0.02)
    cam.connect()
    cam.start()
    t = time.monotonic()
    with pytest.raises(FrameTimeout, match=r"no frame within 0\.02 s"):
        cam.read_frame()
    assert time.monotonic() - t < 1.0
    cam.close()


def test_read_before_start_is_connection_lost() -> None:
    cam, _, _ = make()
    with pytest.raises(ConnectionLost):
        cam.read_frame()


# --- the real OS layer, on what this machine has ------------------------------------------


def test_real_system_on_a_missing_node_and_on_a_non_video_file() -> None:
    missing = "/dev/video-acq-test-missing"
    with pytest.raises(ConnectionLost, match="No such file"):
        V4L2Camera(missing).connect()
    with pytest.raises(DeviceError, match="/dev/null"):  # VIDIOC_QUERYCAP: ENOTTY
        V4L2Camera("/dev/null").connect()


def test_real_system_mmap_and_poll(tmp_path: Any) -> None:
    system = OsV4L2()
    path = tmp_path / "buf"
    path.write_bytes(bytes(range(256)) * 32)
    fd = system.open(str(path))
    try:
        buf = system.mmap(fd, 4096, 4096)
        assert bytes(buf[:4]) == bytes([0, 1, 2, 3]) and len(buf) == 4096
        system.munmap(buf)
    finally:
        system.close(fd)
    r, w = os.pipe()
    try:
        assert not OsV4L2().wait_readable(r, 0.01)
        os.write(w, b"x")
        assert OsV4L2().wait_readable(r, 0.01)
    finally:
        os.close(r)
        os.close(w)
