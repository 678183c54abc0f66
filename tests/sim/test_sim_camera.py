"""The simulated camera and its MJPEG-over-HTTP server, read by a plain independent reader."""

from __future__ import annotations

import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq.sim.camera_device import SimCamera, jpeg_digest
from acq.sim.mjpeg_process import MjpegServerProcess, _cpu_s
from acq.sim.mjpeg_server import MjpegServer, serve_camera
from acq.sim.world import Street

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


@pytest.fixture(scope="module")
def camera_args() -> dict[str, object]:
    return {"street": Street.generate(seed=3, length_m=200.0)}


@pytest.fixture
def server(camera_args: dict[str, object]) -> Iterator[MjpegServer]:
    cam = SimCamera(**camera_args, latency_s=0.02, jitter_s=0.003, seed=1)  # type: ignore[arg-type]
    with MjpegServer(cam) as srv:
        yield srv


class PlainReader:
    """A deliberately simple multipart reader, independent of acq.drivers.mjpeg."""

    def __init__(self, url_port: int, path: str = "/stream.mjpg", method: str = "GET"):
        self.sock = socket.create_connection(("127.0.0.1", url_port), timeout=3.0)
        self.sock.sendall(f"{method} {path} HTTP/1.0\r\nHost: x\r\n\r\n".encode())
        # a bytearray: taking from its front costs nothing, where slicing bytes copies the
        # rest each time (a flood's thousands of parts a read made this minutes long)
        self.buf = bytearray()

    def _more(self) -> None:
        data = self.sock.recv(65536)
        if not data:
            raise EOFError
        self.buf += data

    def head(self) -> tuple[str, dict[str, str]]:
        while (end := self.buf.find(b"\r\n\r\n")) < 0:
            self._more()
        head = bytes(self.buf[:end])
        del self.buf[: end + 4]
        lines = head.decode("latin-1").split("\r\n")
        headers = dict(line.split(": ", 1) for line in lines[1:])
        return lines[0], {k.lower(): v for k, v in headers.items()}

    def line(self) -> bytes:
        while (end := self.buf.find(b"\r\n")) < 0:
            self._more()
        line = bytes(self.buf[:end])
        del self.buf[: end + 2]
        return line

    def part(self, boundary: bytes = b"acqframe") -> tuple[dict[str, str], bytes, float]:
        """(headers, body, arrival monotonic s) of the next part."""
        line = self.line()
        while line == b"":
            line = self.line()
        assert line == b"--" + boundary, line[:80]
        headers = {}
        while (line := self.line()) != b"":
            name, value = line.decode("ascii").split(": ", 1)
            headers[name.lower()] = value
        if "content-length" in headers:
            n = int(headers["content-length"])
            while len(self.buf) < n + 2:
                self._more()
            body = bytes(self.buf[:n])
            del self.buf[:n]
            assert self.buf.startswith(b"\r\n")
        else:
            delim = b"\r\n--" + boundary
            while (end := self.buf.find(delim)) < 0:
                self._more()
            body = bytes(self.buf[:end])
            del self.buf[: end + 2]  # from the next part's "--" boundary on
        return headers, body, time.monotonic()

    def close(self) -> None:
        self.sock.close()


def test_http_framing_and_truth(server: MjpegServer) -> None:
    reader = PlainReader(server.port)
    status, headers = reader.head()
    assert status == "HTTP/1.0 200 OK"
    assert headers["content-type"] == "multipart/x-mixed-replace; boundary=acqframe"
    parts = [reader.part() for _ in range(6)]
    reader.close()
    # the server notes when a frame was sent once sendall returns, which may be after
    # the client read it: wait for those notes
    deadline = time.monotonic() + 2.0
    while True:
        truth = {t.digest: t for t in server.camera.truth() if t.status == "sent"}
        done = all(truth.get(jpeg_digest(b)) and truth[jpeg_digest(b)].t_sent for _, b, _ in parts)
        if done or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    seqs = []
    for part_headers, body, arrived in parts:
        assert set(part_headers) == {"content-type", "content-length"}  # no truth leaks
        assert part_headers["content-type"] == "image/jpeg"
        assert body[:2] == b"\xff\xd8" and body[-2:] == b"\xff\xd9"
        image = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (582, 780, 3)
        t = truth[jpeg_digest(body)]
        assert t.size == len(body) and t.t_sent is not None
        # sent when available, received just after (generous bounds: the suite shares
        # two cores, and the renderer holds the GIL for ~20 ms a frame)
        # (a loaded host holds the server thread up: a frame later than late_s is dropped)
        assert -0.001 <= t.t_sent - t.t_available < server.late_s + 0.2
        assert arrived >= t.t_available and arrived - t.t_sent < 0.2
        exp = t.exposure_s
        assert exp / 2 + 0.02 <= t.t_available - t.t_mid <= exp / 2 + 0.02 + 4 * 0.003 + 1e-9
        seqs.append(t.sequence)
    # in order; any frame between that did not come was dropped as late
    assert seqs == sorted(seqs)
    statuses = {t.sequence: t.status for t in server.camera.truth()}
    assert all(statuses[k] == "late" for k in set(range(seqs[0], seqs[-1] + 1)) - set(seqs))
    mids = [truth[jpeg_digest(b)].t_mid for _, b, _ in parts]
    assert np.allclose(np.diff(mids), np.diff(seqs) / 25, atol=1e-9)


def test_two_clients_get_the_same_frames(server: MjpegServer) -> None:
    a, b = PlainReader(server.port), PlainReader(server.port)
    a.head(), b.head()
    time.sleep(0.1)
    assert server.clients == 2
    got_a = [jpeg_digest(a.part()[1]) for _ in range(4)]
    got_b = [jpeg_digest(b.part()[1]) for _ in range(6)]
    assert set(got_a) & set(got_b)
    a.close(), b.close()


def test_other_paths_and_methods(server: MjpegServer) -> None:
    reader = PlainReader(server.port, path="/nothing")
    assert reader.head()[0] == "HTTP/1.0 404 Not Found"
    reader.close()
    reader = PlainReader(server.port, method="POST")
    assert reader.head()[0].startswith("HTTP/1.0 405")
    reader.close()
    reader = PlainReader(server.port, path="/stream.mjpg?x=1")  # a query is fine
    assert reader.head()[0] == "HTTP/1.0 200 OK"
    reader.close()


def test_parts_without_content_length(camera_args: dict[str, object]) -> None:
    cam = SimCamera(**camera_args, seed=2)  # type: ignore[arg-type]
    with MjpegServer(cam, content_length=False, boundary="b0undary") as srv:
        reader = PlainReader(srv.port)
        assert reader.head()[1]["content-type"].endswith("boundary=b0undary")
        bodies = [reader.part(b"b0undary") for _ in range(3)]
        reader.close()
        sent = {t.digest for t in cam.truth() if t.status == "sent"}
    for headers, body, _ in bodies:
        assert "content-length" not in headers
        assert jpeg_digest(body) in sent


def test_faults(server: MjpegServer) -> None:
    reader = PlainReader(server.port)
    reader.head()
    reader.part()
    server.skip_next()
    server.corrupt_next()
    parts = [reader.part() for _ in range(3)]
    log = {t.sequence: t for t in server.camera.truth()}
    by_digest = {t.digest: t for t in log.values() if t.digest}
    seqs = [by_digest[jpeg_digest(body)].sequence for _, body, _ in parts]
    # skip applies first, then the corrupt frame is the next one sent
    assert log[seqs[0] - 1].status == "skipped"
    assert log[seqs[0]].status == "corrupt"
    assert parts[0][1][-2:] != b"\xff\xd9" and int(parts[0][0]["content-length"]) == len(
        parts[0][1]
    )
    assert seqs[1:] == [seqs[0] + 1, seqs[0] + 2]

    # stall: nothing for the stall's length, the connection stays open
    server.stall(0.4)
    t0 = time.monotonic()
    _, _, arrived = reader.part()
    assert arrived - t0 > 0.3
    # the frames handed over in the stall are held back, none sent: those due in it, and
    # on a loaded host those the server was behind with, up to late_s (a loaded host also
    # renders fewer of them in time: the rest are dropped as late)
    stalled = [t for t in server.camera.truth() if t.status == "stalled"]
    assert 1 <= len(stalled) <= int((0.4 + server.late_s) * 25) + 1

    # drop: the client reads end-of-stream, a new client is served again
    server.drop_connection()
    with pytest.raises((EOFError, ConnectionResetError)):
        for _ in range(10):
            reader.part()
    reader.close()
    again = PlainReader(server.port)
    again.head()
    again.part()
    again.close()
    assert server.connections == 2


def test_flood(server: MjpegServer) -> None:
    """A flood: empty parts back to back instead of frames, to every client, then frames
    again."""
    reader = PlainReader(server.port)
    reader.head()
    reader.part()
    server.flood(0.5)
    frames = 0
    while reader.part()[1]:  # frames sent before the flood began
        frames += 1
        assert frames < 50, "no flood within 2 s of frames"
    parts = [reader.part() for _ in range(1000)]
    assert all(body == b"" and headers["content-length"] == "0" for headers, body, _ in parts)
    end = time.monotonic() + 30
    while not reader.part()[1]:  # frames once the flood is over
        assert time.monotonic() < end, "the flood did not end"
    reader.close()
    assert server.flooded_bytes() >= 1000 * len(b"--acqframe\r\n\r\n\r\n")
    assert any(t.status == "flooded" for t in server.camera.truth())


def test_clients_that_hang_up_in_a_stall_free_their_slot(
    camera_args: dict[str, object],
) -> None:
    """During a stall nothing is sent, which would show that a client is gone: the
    server notices a hang-up itself, so clients that come and go in a stall do not use
    up ``max_clients``."""
    cam = SimCamera(**camera_args, seed=3)  # type: ignore[arg-type]
    with MjpegServer(cam, max_clients=2) as srv:
        srv.stall(5.0)
        for _ in range(4):
            reader = PlainReader(srv.port)
            assert reader.head()[0] == "HTTP/1.0 200 OK"
            reader.close()
            deadline = time.monotonic() + 2.0
            while srv.clients and time.monotonic() < deadline:
                time.sleep(0.01)


def test_in_process_frames_and_clock(camera_args: dict[str, object]) -> None:
    cam = SimCamera(
        **camera_args,  # type: ignore[arg-type]
        fps=10.0,
        clock_offset_s=0.013,
        drift_ppm=100.0,
        t_origin=100.0,
        jitter="uniform",
    )
    frames = [cam.next_frame() for _ in range(3)]
    assert [f.sequence for f in frames] == [0, 1, 2]
    assert frames[0].t_mid == pytest.approx(100.013 + 0.002)
    assert frames[2].t_mid - frames[0].t_mid == pytest.approx(0.2 / (1 + 1e-4))
    truth = cam.truth()
    assert [t.digest for t in truth] == [jpeg_digest(f.jpeg) for f in frames]
    # real time: frames come at their availability times
    cam = SimCamera(**camera_args)  # type: ignore[arg-type]
    it = cam.frames()
    first = next(it)
    second = next(it)
    assert time.monotonic() >= second.t_available
    assert second.sequence == first.sequence + 1


def test_render_and_encode_keep_25_hz(camera_args: dict[str, object]) -> None:
    cam = SimCamera(**camera_args)  # type: ignore[arg-type]
    # this thread's CPU time (the rendering and encoding run on it): what a frame costs
    # whatever else the machine runs; on a loaded machine its wall time only stretches
    durations = []
    for _ in range(12):
        t0 = time.thread_time()
        cam.next_frame()
        durations.append(time.thread_time() - t0)
    median = statistics.median(durations)
    print(f"render+encode 780x582: median {median * 1e3:.1f} ms of CPU per frame")
    assert median < 1 / 25


def test_serve_camera_parses_listen() -> None:
    srv = serve_camera("http://127.0.0.1:0/cam.mjpg", street=Street.generate(1, 100.0))
    try:
        assert srv.url.startswith("http://127.0.0.1:") and srv.url.endswith("/cam.mjpg")
        assert srv.port != 0
    finally:
        srv.close()
    with pytest.raises(ValueError):
        serve_camera("tcp://127.0.0.1:80")


def test_a_rig_camera_by_name_renders_through_it() -> None:
    """The ``camera`` option (JSON, for a camera's process): that camera of the rig, its
    lens, mounting, photometry and latency; the right camera sees another view than the
    left at the same instant; an unknown name is a ValueError."""
    from acq.sim import sensors
    from acq.sim.mjpeg_server import sim_camera
    from acq.sim.world import default_rig

    street = Street.generate(seed=3, length_m=200.0)
    left = sim_camera(camera="left", street=street, t_origin=0.0)
    right = sim_camera(camera="right", street=street, t_origin=0.0, latency_s=0.05)
    rig = default_rig(cameras=2)
    assert left.rig.camera_names == ("left",) and right.rig.camera_names == ("right",)
    assert left.latency_s == rig.camera("left").latency_s == 0.020
    assert right.latency_s == 0.05  # an option given wins over the rig's
    assert sim_camera(camera="right", street=street).latency_s == rig.camera("right").latency_s
    image = right.render(2.0)
    expected = sensors.render_frame(street, right.trajectory, rig, 2.0, camera="right")
    assert np.array_equal(image, expected)
    assert np.abs(image.astype(int) - left.render(2.0)).mean() > 10
    with pytest.raises(ValueError, match="front"):
        sim_camera(camera="front", street=street)


def test_prerendered_frames_are_the_live_ones(camera_args: dict[str, object]) -> None:
    """Frames rendered before the drive's start (set later) are those a camera renders
    when due: the same bytes, at the same times; frames after them are rendered live."""
    live = SimCamera(**camera_args, clock_offset_s=0.02, t_origin=50.0)  # type: ignore[arg-type]
    early = SimCamera(**camera_args, clock_offset_s=0.02, t_origin=7.0)  # type: ignore[arg-type]
    assert early.prerender(0.1) == 3  # frames 0-2 of the drive's first 0.1 s at 25 Hz
    early.t_origin = 50.0
    assert early.next_frame(render=False).jpeg == b""  # skipped: its bytes are let go
    live.next_frame(render=False)
    # prerendered frames 1, 2; frames 3, 4 rendered when due
    frames = [(early.next_frame(), live.next_frame()) for _ in range(4)]
    for e, v in frames:
        assert e.sequence == v.sequence and e.t_mid == v.t_mid
        assert jpeg_digest(e.jpeg) == jpeg_digest(v.jpeg)
    assert not early._prerendered


class SlowCamera(SimCamera):
    """A camera whose frames take 60 ms to make, longer than its 40 ms period: the
    renderer on a busy machine, emulated by a sleep (the load cannot be had on demand)."""

    def render(self, t: float) -> np.ndarray:
        time.sleep(0.06)
        return super().render(t)


def test_a_camera_rendering_slower_than_real_time_still_sends_in_time(
    camera_args: dict[str, object],
) -> None:
    """It falls behind, and frames too late to send once rendered are not rendered:
    frames keep coming (fewer than 25 a second), where before the server rendered each
    just before its limit, dropped it as late, and sent nothing more."""
    cam = SlowCamera(**camera_args, latency_s=0.02, seed=2)  # type: ignore[arg-type]
    with MjpegServer(cam, late_s=0.3) as srv:
        reader = PlainReader(srv.port)
        reader.head()
        t_end = time.monotonic() + 3.0
        arrived = []
        while time.monotonic() < t_end:
            arrived.append(reader.part()[2])
        reader.close()
        truth = cam.truth()
    # it falls late_s behind within a second or so; the last 1.5 s must still flow (at
    # most 16 frames of 60 ms; a loaded host's rendering took up to 0.4 s a frame, and
    # 7 came: more than a few, where the fault sent none)
    last = [t for t in arrived if t > arrived[-1] - 1.5]
    assert len(last) >= 4, np.diff(arrived)
    assert any(t.status == "late" for t in truth)  # it did fall behind


def test_a_camera_process_that_cannot_serve_says_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its own error, or how it exited, not a bare failure (the demo says it on)."""
    with pytest.raises(RuntimeError, match=r"process failed: .*listen"):
        MjpegServerProcess("ftp://127.0.0.1:0/x")
    # a child that goes without a word: its exit status (a real process, not Python)
    gone = tmp_path / "gone.sh"
    gone.write_text("#!/bin/sh\nexit 3\n")
    gone.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(gone))
    with pytest.raises(RuntimeError, match="it exited with status 3 before serving"):
        MjpegServerProcess()
    # the wait is on the child's CPU, read from /proc, not on the wall clock alone
    spin = subprocess.Popen(["/bin/sh", "-c", "while :; do :; done"])
    try:
        time.sleep(0.5)
        used = _cpu_s(spin.pid)
        assert used is not None and 0.05 < used < 5.0, used
    finally:
        spin.kill()
        spin.wait()
    assert _cpu_s(spin.pid) is None  # gone
