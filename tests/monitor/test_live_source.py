"""The live colouring's figures in the recorder's ``/acq/status`` and in `acq status`
(from the log and from the live server), and `acq status HOST:PORT` against addresses
where no live server is: nothing listening, an HTTP server, a server that answers
garbage, one that never answers, a WebSocket server of another protocol."""

from __future__ import annotations

import contextlib
import functools
import json
import socket
import socketserver
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.server import ServerConnection, serve

from acq.cli import main as acq_main
from acq.log.schemas import ColouringStatus
from acq.monitor.live_source import LiveSource
from acq.record.listeners import Listener, LogRecord
from acq.record.live import LiveServer
from acq.record.recorder import Recorder
from tests.monitor.test_status import free_port
from tests.sim_rig import Rig, read_log, warm_rig

ROOT = Path(__file__).resolve().parents[2]


def _status(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "acq.cli", "status", *map(str, args)],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def _status_here(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], *args: str
) -> subprocess.CompletedProcess[str]:
    """`acq status` in this process with shorter waits for a live server's handshake
    (2 s, the installed 5 s) and its first status (1 s, the installed 4 s): the same
    path to the same answers, for servers that never give them, without the full wait."""
    from acq.cli import status as status_cli
    from acq.monitor import live_source

    shorter = functools.partial(live_source.LiveSource, timeout_s=2.0)
    monkeypatch.setattr(live_source, "LiveSource", shorter)
    monkeypatch.setattr(status_cli, "FIRST_STATUS_S", 1.0)
    code = acq_main(["status", *args])
    out, err = capsys.readouterr()
    return subprocess.CompletedProcess(["acq", "status", *args], code, out, err)


class StandIn(Listener):
    """Stands in for the live colourer (another part of the recorder): counts the scans
    it is handed and reports fixed shares and skips."""

    def __init__(self) -> None:
        self.scans = 0

    def on_record(self, record: LogRecord) -> None:
        self.scans += record.topic == "/laser/scan"

    def status(self) -> ColouringStatus:
        return ColouringStatus(self.scans, 3, 0.625, {"camera": 0.625})


class Silent(Listener):
    """A listener with no figures (the live server is another): the first with some counts."""

    def on_record(self, record: LogRecord) -> None:
        pass


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    yield from warm_rig()


@pytest.mark.realtime
def test_colouring_figures_in_the_status_the_log_and_the_live_view(
    rig: Rig, tmp_path: Path
) -> None:
    server = LiveServer("127.0.0.1", 0)
    address = f"127.0.0.1:{server.port}"
    recorder = Recorder(
        rig.config(tmp_path), duration_s=6.0, listeners=[Silent(), StandIn(), server]
    )
    codes: list[int] = []
    thread = threading.Thread(target=lambda: codes.append(recorder.run()))
    thread.start()
    try:
        time.sleep(2.0)  # the recorder's first status
        live = _status(address, "--json")
        source = LiveSource("127.0.0.1", server.port)  # in this process: seen to the end
    finally:
        thread.join(30)
    assert codes == [0]
    try:  # the recorder gone: its last state, and why it is not updated
        deadline = time.monotonic() + 10
        while (snap := source.snapshot()).writing and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        source.close()
    assert not snap.writing and snap.colouring is not None and snap.devices
    assert snap.notes == [f"the live server at {address} closed the connection"]
    assert live.returncode == 0 and live.stderr == "", live.stdout + live.stderr
    colouring = json.loads(live.stdout)["colouring"]
    assert colouring["scans_skipped"] == 3 and colouring["coloured_share"] == 0.625
    assert colouring["camera_shares"] == {"camera": 0.625}
    assert colouring["scans_coloured"] > 0
    # the log: every status carries the figures, the scans counted up to each
    (log,) = (tmp_path / "logs").glob("*.mcap")
    statuses = [m for *_, m in read_log(log)["/acq/status"]]
    assert len(statuses) >= 5
    counts = [s.colouring.scans_coloured for s in statuses]  # type: ignore[attr-defined]
    assert counts == sorted(counts) and counts[-1] > 40 * 4  # a 40 Hz scanner, 6 s
    last = statuses[-1].colouring  # type: ignore[attr-defined]
    assert [(c.camera, c.share) for c in last.cameras] == [("camera", 0.625)]
    assert last.scans_skipped == 3 and last.coloured_share == 0.625
    done = _status(log, "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    assert json.loads(done.stdout)["colouring"]["scans_coloured"] == counts[-1]
    plain = _status(log)  # the view, printed once off a terminal
    assert "colouring: 62% of the last scans' points (camera 62%)" in plain.stdout
    assert f"{counts[-1]} scans coloured, 3 skipped (fell behind)" in plain.stdout


def test_a_status_without_colouring_has_none() -> None:
    from acq.log import schemas

    msg = schemas.decode("acq.Status", schemas.status(timestamp_ns=1, uptime_s=1.0))
    assert schemas.colouring_of(msg) is None
    zero = ColouringStatus(0, 0, 0.0, {})  # a colourer that has coloured nothing yet
    msg = schemas.decode("acq.Status", schemas.status(timestamp_ns=1, uptime_s=1.0, colouring=zero))
    assert schemas.colouring_of(msg) == zero


def _one_line(done: subprocess.CompletedProcess[str], code: int, said: str) -> None:
    assert done.returncode == code, done.stdout + done.stderr
    assert done.stdout == ""
    assert done.stderr.strip().splitlines() == [f"acq status: {said}"], done.stderr


@pytest.mark.parametrize(
    ("address", "said"),
    [("127.0.0.1:70000", "'127.0.0.1:70000': expected HOST:PORT, e.g. 127.0.0.1:8765"),
     ("[::1]:99999", "'[::1]:99999': expected HOST:PORT, e.g. 127.0.0.1:8765")],
)  # fmt: skip
def test_a_bad_address_is_exit_2(address: str, said: str) -> None:
    _one_line(_status(address, "--json"), 2, said)


def test_a_config_with_an_address_is_exit_2(tmp_path: Path) -> None:
    done = _status("-c", tmp_path / "rig.yaml", "127.0.0.1:8765")
    _one_line(done, 2, "-c: only with a log folder, not with a live server's HOST:PORT")


def test_nothing_listening_is_exit_1() -> None:
    port = free_port()
    done = _status(f"127.0.0.1:{port}", "--json")
    _one_line(done, 1, f"127.0.0.1:{port}: nothing listens there (is `acq record --live` running?)")


def _tcp_server(answer: Callable[[socket.socket], None]) -> socketserver.ThreadingTCPServer:
    """A TCP server on a free port of 127.0.0.1 doing ``answer`` to each connection."""

    class Handler(socketserver.BaseRequestHandler):
        def handle(self) -> None:
            answer(self.request)

    server = socketserver.ThreadingTCPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    # polled every 50 ms for the shutdown (socketserver's 0.5 s is waited out at each stop)
    threading.Thread(target=server.serve_forever, args=(0.05,), daemon=True).start()
    return server


def _http(conn: socket.socket) -> None:
    conn.recv(4096)
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 5\r\nConnection: close\r\n\r\nhello")


def _garbage(conn: socket.socket) -> None:
    conn.recv(4096)
    conn.sendall(b"\x00\xff\x16\x03 not a protocol at all\r\n\r\n")


def _never(conn: socket.socket) -> None:
    time.sleep(10.0)


@pytest.mark.parametrize(
    ("answer", "said"),
    [(_http, "not an acq live server (server rejected WebSocket connection: HTTP 200)"),
     (_garbage, "not an acq live server (did not receive a valid HTTP response)"),
     (_never, "no WebSocket handshake within the time allowed")],
)  # fmt: skip
def test_a_server_of_something_else_is_exit_1(
    answer: Callable[[socket.socket], None],
    said: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    server = _tcp_server(answer)
    try:
        port = server.server_address[1]
        done = _status_here(monkeypatch, capsys, f"127.0.0.1:{port}", "--json")
        _one_line(done, 1, f"127.0.0.1:{port}: {said}")
    finally:
        server.shutdown()
        server.server_close()


def _websocket(handler: Callable[[ServerConnection], None], **kw: object) -> Iterator[int]:
    with serve(handler, "127.0.0.1", 0, **kw) as server:  # type: ignore[arg-type]
        threading.Thread(target=server.serve_forever, daemon=True).start()
        try:
            yield server.socket.getsockname()[1]
        finally:
            server.shutdown()


def _garbage_json(ws: ServerConnection) -> None:
    with contextlib.suppress(ConnectionClosed):  # a client that refuses it leaves at once
        ws.send(json.dumps({"op": "serverInfo", "name": "x"}))
        ws.send("not json {")
        for _ in ws:  # held open until the client leaves (then the server stops at once)
            pass


def test_a_websocket_server_of_another_protocol_is_exit_1() -> None:
    for port in _websocket(_garbage_json):  # no subprotocol chosen
        _one_line(
            _status(f"127.0.0.1:{port}", "--json"),
            1,
            f"127.0.0.1:{port}: not an acq live server (a WebSocket server not speaking "
            "foxglove.sdk.v1)",
        )
    for port in _websocket(_garbage_json, subprotocols=["foxglove.sdk.v1"]):  # then garbage
        done = _status(f"127.0.0.1:{port}", "--json")
        assert done.returncode == 1 and done.stdout == "", done.stdout + done.stderr
        (line,) = done.stderr.strip().splitlines()
        assert line.startswith(
            f"acq status: the live server at 127.0.0.1:{port} left the protocol: a control "
            "message not of the protocol: JSONDecodeError"
        ), line


def test_a_live_server_that_sends_no_status_is_exit_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    server = LiveServer("127.0.0.1", 0)  # the protocol spoken, nothing published
    try:
        done = _status_here(monkeypatch, capsys, f"127.0.0.1:{server.port}", "--json")
    finally:
        server.stop()
    assert done.returncode == 1 and done.stderr == "", done.stdout + done.stderr
    snap = json.loads(done.stdout)
    assert snap["writing"] and snap["devices"] == [] and not snap["ok"]
    assert snap["problems"] == ["the recorder's last status: nothing yet (more than 5 s)"]


def test_an_unknown_host_is_exit_1() -> None:
    done = _status("nowhere.invalid:8765", "--json")  # .invalid: never a host (RFC 2606)
    assert done.returncode == 1 and done.stdout == "", done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("acq status: nowhere.invalid:8765: unknown host ("), line
