"""The OpenCV camera driver against the simulated MJPEG camera over real HTTP on 127.0.0.1,
on a video file and an image sequence, and a fuzz of its multipart parser."""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq.drivers.camera import FrameTimeout, camera_for
from acq.drivers.camera_opencv import OpenCVCamera
from acq.drivers.errors import ConnectionLost, DeviceError
from acq.drivers.reconnect import Backoff, CameraLink
from acq.records import Frame
from acq.sim.camera_device import SimCamera, jpeg_digest
from acq.sim.mjpeg_process import MjpegServerProcess
from acq.sim.mjpeg_server import MjpegServer
from acq.sim.world import Street

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

EXPOSURE = 0.004
LATENCY = 0.02
JITTER = 0.003


@pytest.fixture(scope="module")
def street() -> Street:
    return Street.generate(seed=5, length_m=200.0)


@pytest.fixture(scope="module")
def server() -> Iterator[MjpegServerProcess]:
    """One simulated camera in its own process for the fault tests (its renderer would
    hold this process's GIL and delay the driver's receipt times)."""
    with MjpegServerProcess(
        exposure_s=EXPOSURE, latency_s=LATENCY, jitter_s=JITTER, seed=4, still=True
    ) as srv:
        yield srv


def _camera(url: str, timeout: float = 1.0) -> OpenCVCamera:
    return OpenCVCamera(url, fps=25.0, latency_s=EXPOSURE / 2 + LATENCY, timeout=timeout)


def test_ten_seconds_at_25_hz_nothing_lost_bytes_exact() -> None:
    """The sim camera in its own process (its renderer holds the GIL), 10 s of frames."""
    with MjpegServerProcess(
        exposure_s=EXPOSURE, latency_s=LATENCY, jitter_s=JITTER, seed=7, still=True
    ) as srv:
        cam = camera_for("opencv", srv.url, fps=25.0, latency_s=EXPOSURE / 2 + LATENCY)
        info = cam.connect()
        cam.start()
        assert info.driver == "opencv" and info.extra["applied"] == "780x582@25 MJPG"
        assert cam.format is not None and (cam.format.width, cam.format.height) == (780, 582)
        frames = []
        t_end = time.monotonic() + 10.0
        while time.monotonic() < t_end:
            frames.append(cam.read_frame())
        cam.close()
        time.sleep(0.1)  # the server logs t_sent once send() has returned
        truth = srv.truth()
    by_digest = {t.digest: t for t in truth if t.status == "sent"}
    matched = [by_digest[jpeg_digest(f.jpeg)] for f in frames]  # KeyError: bytes altered
    seq_true = np.array([t.sequence for t in matched])
    seq_driver = np.array([f.sequence for f in frames])
    # every frame sent between the first and the last received was received, in order
    sent = [t.sequence for t in truth if t.status == "sent"]
    window = [s for s in sent if seq_true[0] <= s <= seq_true[-1]]
    assert list(seq_true) == window
    assert len(frames) >= 245
    # the driver numbers what it receives (MJPEG carries no number) and counts a gap in
    # time as frames lost: on a loaded machine a frame held up more than half a period
    # reads as one (the truth above says none was): at most 1 % of them
    assert np.all(np.diff(seq_driver) >= 1)
    assert int((np.diff(seq_driver) - 1).sum()) <= max(2, len(frames) // 100)
    assert cam.drops <= int((np.diff(seq_driver) - 1).sum())  # late, not lost: taken back
    assert cam.corrupt == 0 and cam.frames == len(frames)
    assert all(f.width == 780 and f.height == 582 and f.time_source == "receipt" for f in frames)

    err = np.array([f.stamp_ns * 1e-9 - t.t_mid for f, t in zip(frames, matched, strict=True)])
    bias = float(err.mean())
    spread = err - bias
    rms = float(np.sqrt(np.mean(spread**2)))
    p99 = float(np.percentile(np.abs(spread), 99))
    # the part the driver adds: from the server's send to the driver's receipt stamp
    transit = np.array([f.recv_ns * 1e-9 - t.t_sent for f, t in zip(frames, matched, strict=True)])
    print(
        f"\nframe time error over {len(frames)} frames: bias {bias * 1e3:+.2f} ms "
        f"(mean random latency of the camera, invisible to the driver), spread about it "
        f"RMS {rms * 1e3:.2f} ms, p99 {p99 * 1e3:.2f} ms; send-to-receipt median "
        f"{np.median(transit) * 1e3:.3f} ms, p99 {np.percentile(transit, 99) * 1e3:.3f} ms"
    )
    # the error is the camera's own random latency (the simulator's jitter, and on a busy
    # machine its late sends), which no driver can see, plus the driver's part, judged here
    assert bias >= 0  # the stamp is never ahead of the exposure on average
    assert float(np.median(transit)) < 0.005
    assert float(np.percentile(transit, 99)) < 0.025


def test_corrupt_jpeg_counted_and_skipped(server: MjpegServerProcess) -> None:
    cam = _camera(server.url)
    cam.connect()
    first = cam.read_frame()
    server.corrupt_next()
    frames = [cam.read_frame() for _ in range(4)]
    cam.close()
    assert cam.corrupt == 1 and cam.drops == 0
    seqs = [first.sequence] + [f.sequence for f in frames]
    assert np.diff(seqs).tolist().count(2) == 1  # the corrupt frame's number is used
    sent = {t.digest for t in server.truth() if t.status == "sent"}
    assert all(jpeg_digest(f.jpeg) in sent for f in frames)


def test_skipped_frame_is_a_drop(server: MjpegServerProcess) -> None:
    cam = _camera(server.url)
    cam.connect()
    # A drop is seen in the receipt times: if this process stalls while the frames after
    # the skip arrive, they come bunched and the driver rightly calls them late, not
    # lost. A busy CI host does that now and then: up to three tries, one must be clean.
    seen = []
    for _ in range(3):
        first, before = cam.read_frame(), cam.drops
        server.skip_next()
        frames = [cam.read_frame() for _ in range(4)]
        gaps = np.diff([first.sequence] + [f.sequence for f in frames]).tolist()
        seen.append((cam.drops - before, sorted(gaps)))
        if seen[-1] == (1, [1, 1, 1, 2]):  # the skipped frame's number is left out
            break
    cam.close()
    assert seen[-1] == (1, [1, 1, 1, 2]), seen
    assert cam.corrupt == 0


def test_stall_times_out_then_recovers(server: MjpegServerProcess) -> None:
    cam = _camera(server.url, timeout=0.2)
    cam.connect()
    cam.read_frame()
    server.stall(0.6)
    with pytest.raises(FrameTimeout):
        for _ in range(5):
            cam.read_frame()
    cam.timeout = 1.0
    before = cam.drops
    frame = cam.read_frame()  # the same connection carries on
    assert frame.jpeg and cam.drops - before >= 10


def test_dropped_connection_is_connection_lost(server: MjpegServerProcess) -> None:
    cam = _camera(server.url)
    cam.connect()
    cam.read_frame()
    server.drop_connection()
    with pytest.raises(ConnectionLost):
        for _ in range(10):
            cam.read_frame()
    cam.close()
    cam.close()  # twice is fine


def test_camera_link_comes_back(server: MjpegServerProcess) -> None:
    cam = _camera(server.url)
    link = CameraLink(cam, backoff=Backoff(first=0.1, cap=0.5))
    stop = threading.Event()
    got = []
    for frame in link.frames(stop):
        got.append(frame)
        if len(got) == 5:
            server.drop_connection()
        if len(got) == 10:
            server.stall(0.5)  # shorter than CAMERA_STALL_S: the connection is kept
        if len(got) == 20:
            stop.set()
    assert link.disconnects == 1
    assert len(got) == 20


def _frames_in_thread(link: CameraLink) -> tuple[list[Frame], threading.Event, threading.Thread]:
    """The link read on a thread until the event is set: (the frames so far, stop, thread)."""
    stop = threading.Event()
    frames: list[Frame] = []

    def run() -> None:
        for frame in link.frames(stop):
            frames.append(frame)

    reader = threading.Thread(target=run, daemon=True)
    reader.start()
    return frames, stop, reader


def _wait_for(frames: list[Frame], n: int, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while len(frames) < n and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(frames) >= n, f"{len(frames)} of {n} frames in {timeout} s"


def test_a_stall_of_a_few_periods_keeps_the_stream_and_every_frame(
    server: MjpegServerProcess,
) -> None:
    """The camera sends nothing for 10 frame periods (a busy camera or host): the stream
    is not closed, and every frame it sent is read, on the same connection."""
    link = CameraLink(_camera(server.url))
    frames, stop, reader = _frames_in_thread(link)
    try:
        _wait_for(frames, 5)
        n = len(frames)
        server.stall(0.4)
        _wait_for(frames, n + 25)
    finally:
        stop.set()
        reader.join(5.0)
    assert link.disconnects == 0
    got = [jpeg_digest(f.jpeg) for f in frames]
    sent = [t.digest for t in server.truth() if t.status == "sent"]
    first = sent.index(got[0])
    assert got == sent[first : first + len(got)]  # none lost on the way


def test_a_dropped_connection_streams_again_within_half_a_second() -> None:
    """The camera closes the connection (twice, 0.6 s apart, as a flaky link would):
    each time the first frame after comes within 0.5 s, the link not held off by a
    connection that streamed."""
    with MjpegServerProcess(exposure_s=EXPOSURE, latency_s=LATENCY, seed=6, still=True) as srv:
        link = CameraLink(_camera(srv.url))
        frames, stop, reader = _frames_in_thread(link)
        backs = []
        try:
            _wait_for(frames, 10)
            for _ in range(2):
                t0 = time.monotonic_ns()
                srv.drop_connection()
                deadline = time.monotonic() + 5.0
                while not frames[-1].recv_ns > t0 + 1 and time.monotonic() < deadline:
                    time.sleep(0.005)
                backs.append((next(f.recv_ns for f in frames if f.recv_ns > t0 + 1) - t0) * 1e-9)
                time.sleep(0.6)
        finally:
            stop.set()
            reader.join(5.0)
    assert link.disconnects == 2
    assert max(backs) < 0.5, backs


def _read_in_thread(link: CameraLink, seconds: float) -> tuple[list[Frame], float]:
    """Frames the link yields in a thread for ``seconds``, and that thread's CPU time (s)."""
    stop = threading.Event()
    frames: list[Frame] = []
    cpu: list[float] = []

    def run() -> None:
        t0 = time.thread_time()
        for frame in link.frames(stop):
            frames.append(frame)
        cpu.append(time.thread_time() - t0)

    reader = threading.Thread(target=run, daemon=True)
    reader.start()
    time.sleep(seconds)
    stop.set()
    reader.join(5.0)
    assert cpu, "the reader did not stop"
    return frames, cpu[0]


def test_frozen_camera_back_within_2s_of_resuming(server: MjpegServerProcess) -> None:
    """The camera's process stopped for 3 s (its port still takes connections, which
    queue in its backlog; nothing is sent), then resumed: the link yields a frame within
    2 s of the resumption, whatever its backoff had reached (here 4 s, as after a few
    failed attempts): an attempt is in flight when the camera resumes."""
    link = CameraLink(_camera(server.url), backoff=Backoff(first=4.0, cap=5.0))
    stop = threading.Event()
    recv: list[int] = []

    def run() -> None:
        for frame in link.frames(stop):
            recv.append(frame.recv_ns)

    reader = threading.Thread(target=run, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 10.0
        while len(recv) < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(recv) >= 5
        server.freeze()
        try:
            time.sleep(3.0)
        finally:
            server.thaw()
        resumed = time.monotonic_ns()
        deadline = time.monotonic() + 5.0
        while recv[-1] < resumed and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        stop.set()
        reader.join(5.0)
    back = [t for t in recv if t > resumed]
    assert back, "no frame within 5 s of the camera resuming"
    assert (back[0] - resumed) * 1e-9 < 2.0
    assert link.disconnects >= 1


def _jpeg_part(boundary: bytes = b"b") -> bytes:
    _, buf = cv2.imencode(".jpg", np.full((48, 64, 3), 128, np.uint8))
    body = buf.tobytes()
    return b"--%s\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n%s\r\n" % (
        boundary,
        len(body),
        body,
    )


class ScriptedCamera:
    """An MJPEG camera on 127.0.0.1 serving one connection at a time: to a request, the
    response head, ``first``, then ``loop`` again and again (every ``pace_s``; 0: back to
    back) until the client hangs up, or once at each of ``at_s`` (s after the head).
    ``requests`` counts the requests served."""

    HEAD = b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=b\r\n\r\n"

    def __init__(
        self, first: bytes, loop: bytes, pace_s: float = 0.0, at_s: list[float] | None = None
    ) -> None:
        self.first, self.loop, self.pace_s, self.at_s = first, loop, pace_s, at_s
        self.requests = 0
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.1)
        self.url = f"http://127.0.0.1:{self._listener.getsockname()[1]}/stream.mjpg"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> ScriptedCamera:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self._listener.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            with conn:
                conn.settimeout(1.0)
                try:
                    if not conn.recv(4096):
                        continue  # a reachability check
                    self.requests += 1
                    conn.sendall(self.HEAD + self.first)
                    if self.at_s is not None:  # ``loop`` once at each time after the head
                        t0 = time.monotonic()
                        for at in self.at_s:
                            time.sleep(max(0.0, t0 + at - time.monotonic()))
                            conn.sendall(self.loop)
                        self._stop.wait()
                        continue
                    while not self._stop.is_set():
                        conn.sendall(self.loop)
                        if self.pace_s:
                            time.sleep(self.pace_s)
                except OSError:
                    pass


def test_bad_content_length_costs_a_part_not_the_link() -> None:
    """A part whose Content-Length holds a superscript digit is a protocol error of that
    part: the link reads on."""
    bad = b"--b\r\nContent-Length: 4\xb2\r\n\r\nabcd\r\n"
    with ScriptedCamera(_jpeg_part() + bad, _jpeg_part(), pace_s=0.04) as cam:
        link = CameraLink(_camera(cam.url))
        stop = threading.Event()
        frames = []
        for frame in link.frames(stop):
            frames.append(frame)
            if len(frames) == 5:
                stop.set()
    assert link.protocol_errors == 1 and all(f.width == 64 for f in frames)


@pytest.mark.parametrize("good_first", [False, True])
def test_flooding_camera_is_dropped_and_held_off(good_first: bool) -> None:
    """A camera that sends empty parts back to back (after one good frame per connection,
    or from the start) has its connections dropped after a few, and is connected again
    only after a backoff: over 2 s the reader's thread spends little CPU on it."""
    empty = b"--b\r\nContent-Length: 0\r\n\r\n\r\n" * 2048
    first = _jpeg_part() if good_first else b""
    with ScriptedCamera(first, empty) as cam:
        link = CameraLink(_camera(cam.url))
        frames, cpu_s = _read_in_thread(link, 2.0)
        print(f"reader CPU {cpu_s:.3f} s, {cam.requests} requests")
        requests = cam.requests
    assert 1 <= requests <= 6
    assert len(frames) == (requests if good_first else 0)
    assert link.camera.corrupt <= requests * 40  # the parts looked at before each drop
    assert cpu_s < 0.25, f"the reader used {cpu_s:.2f} s of CPU in 2 s"


def test_http_errors() -> None:
    cam = SimCamera(Street.generate(seed=1, length_m=100.0))
    with MjpegServer(cam, path="/other.mjpg") as srv:
        with pytest.raises(DeviceError, match="404"):
            _camera(f"http://127.0.0.1:{srv.port}/stream.mjpg").connect()
        port = srv.port
    with pytest.raises(ConnectionLost):
        _camera(f"http://127.0.0.1:{port}/stream.mjpg").connect()


def test_parts_without_content_length(street: Street) -> None:
    cam = SimCamera(street, seed=9)
    with MjpegServer(cam, content_length=False) as srv:
        drv = _camera(srv.url)
        drv.connect()
        frames = [drv.read_frame() for _ in range(3)]
        drv.close()
        sent = {t.digest for t in cam.truth() if t.status == "sent"}
    assert all(jpeg_digest(f.jpeg) in sent for f in frames)


def test_decode_verification(server: MjpegServerProcess) -> None:
    cam = OpenCVCamera(server.url, verify="decode")
    cam.connect()
    assert cam.read_frame().width == 780
    cam.close()


# --- VideoCapture path (no hardware) ----------------------------------------------------


def _images(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 255, (120, 160, 3), dtype=np.uint8) for _ in range(n)]


def test_video_file(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 25.0, (160, 120))
    assert writer.isOpened()
    for image in _images(8):
        writer.write(image)
    writer.release()
    cam = OpenCVCamera(str(path), width=640, height=480, fps=25.0, latency_s=0.01)
    info = cam.connect()
    cam.start()
    assert cam.format is not None and (cam.format.width, cam.format.height) == (160, 120)
    assert info.extra["requested"] == "640x480@25 any"
    assert info.extra["applied"].startswith("160x120@25")
    frames = []
    with pytest.raises(ConnectionLost):
        while True:
            frames.append(cam.read_frame())
    cam.close()
    assert len(frames) == 8 and cam.frames == 8
    for i, f in enumerate(frames):
        assert f.image is not None and f.image.shape == (120, 160, 3) and not f.jpeg
        assert f.time_source == "receipt"
        assert f.stamp_ns == f.recv_ns - 10_000_000
        assert f.sequence == i


def test_image_sequence(tmp_path: Path) -> None:
    for i, image in enumerate(_images(3)):
        cv2.imwrite(str(tmp_path / f"f{i:03d}.png"), image)
    cam = OpenCVCamera(str(tmp_path / "f%03d.png"))
    cam.connect()
    frames = [cam.read_frame() for _ in range(3)]
    assert [f.image.shape for f in frames if f.image is not None] == [(120, 160, 3)] * 3
    cam.close()


def test_unopenable_source(tmp_path: Path) -> None:
    with pytest.raises(DeviceError):
        OpenCVCamera(str(tmp_path / "missing.avi")).connect()


# --- receipt times -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("arrivals_ms", "drops"),
    [
        ([0, 40, 80, 160, 200, 240], 1),  # one frame never came
        ([0, 40, 80, 150, 162, 200, 240], 0),  # one came late, the next right behind it
        ([0, 40, 200, 205, 210, 215, 240], 0),  # three late, bunched
        ([0, 40, 200, 240, 280], 3),  # three lost
    ],
)
def test_a_late_frame_is_not_a_drop(arrivals_ms: list[int], drops: int) -> None:
    # the HTTP stream has no frame numbers: gaps in receipt times are all there is
    cam = OpenCVCamera("http://127.0.0.1:9/stream.mjpg", fps=25.0)
    for t in arrivals_ms:
        cam._advance(t * 1_000_000)
    assert cam.drops == drops


@pytest.mark.parametrize(
    ("sent_ms", "sequence"),
    [
        ([0, 200, 400, 780, 830, 1000, 1200], [0, 1, 2, 3, 4, 5, 6]),  # late, the next behind
        ([0, 200, 400, 800, 1000, 1200], [0, 1, 2, 4, 5, 6]),  # one never sent
        ([0, 200, 1000, 1030, 1060, 1090, 1200], [0, 1, 2, 3, 4, 5, 6]),  # four late
    ],
)
def test_frames_held_up_are_numbered_as_late_not_lost(
    sent_ms: list[int], sequence: list[int]
) -> None:
    """Over a real socket at 5 Hz: a frame that comes after a gap of two periods is held
    (at most half a period) for the next, so frames a busy host or network held up keep
    their numbers and only a frame never sent leaves one out."""
    with ScriptedCamera(b"", _jpeg_part(), at_s=[t / 1e3 for t in sent_ms]) as server:
        cam = OpenCVCamera(server.url, fps=5.0, timeout=3.0)
        cam.connect()
        cam.start()
        frames = [cam.read_frame() for _ in sent_ms]
        cam.close()
    assert [f.sequence - frames[0].sequence for f in frames] == sequence
    assert cam.drops == sequence[-1] + 1 - len(sent_ms)


def test_frames_that_arrived_are_read_when_the_read_comes_late() -> None:
    """A read that runs after its deadline (a host busy elsewhere held the thread: here,
    timeout 0) still takes the frames already in the socket; a timeout only once they
    are taken and nothing more comes."""
    with ScriptedCamera(b"", _jpeg_part(), at_s=[0.0, 0.04, 0.08, 0.12, 0.16]) as server:
        cam = OpenCVCamera(server.url, fps=25.0, timeout=2.0)
        cam.connect()
        cam.start()
        cam.read_frame()
        time.sleep(0.5)  # the other four are in the socket
        cam.timeout = 0.0
        late = []
        with pytest.raises(FrameTimeout):
            for _ in range(10):
                late.append(cam.read_frame())
        cam.close()
    assert len(late) == 4


@pytest.mark.skipif(sys.platform != "linux", reason="kernel receive times: Linux")
def test_a_frame_read_late_keeps_the_time_it_arrived() -> None:
    """The receipt stamp is the kernel's: a frame read 0.3 s after it arrived (the host
    busy elsewhere) is stamped when it arrived."""
    with ScriptedCamera(b"", _jpeg_part(), at_s=[0.0, 0.5]) as server:
        cam = OpenCVCamera(server.url, fps=5.0, timeout=3.0)
        cam.connect()
        cam.start()
        cam.read_frame()
        time.sleep(0.6)  # the second frame arrived about 0.1 s ago
        read_at = time.monotonic_ns()
        second = cam.read_frame()
        cam.close()
    assert 0.05e9 < read_at - second.recv_ns < 0.3e9
