"""acq.record.sdnotify against real AF_UNIX datagram sockets, as systemd's PID 1 listens."""

from __future__ import annotations

import io
import logging
import os
import socket
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from acq.record.sdnotify import JournalFormatter, Notifier, journal_prefix, use_journal_format


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket bound in tmp_path, and its NOTIFY_SOCKET value."""
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    yield sock, path
    sock.close()


def _recv(sock: socket.socket) -> bytes:
    return sock.recv(4096)


def test_messages_arrive_byte_exact(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    n = Notifier({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready()
    assert _recv(sock) == b"READY=1"
    assert n.ready("recording: laser 40.0 Hz, camera 25.0 fps")
    assert _recv(sock) == b"READY=1\nSTATUS=recording: laser 40.0 Hz, camera 25.0 fps"
    assert n.status("laser 40.0 Hz, 0 drops\ncamera 25 fps")
    assert _recv(sock) == b"STATUS=laser 40.0 Hz, 0 drops camera 25 fps"
    assert n.watchdog()
    assert _recv(sock) == b"WATCHDOG=1"
    assert n.stopping()
    assert _recv(sock) == b"STOPPING=1"
    assert n.errno(28)
    assert _recv(sock) == b"ERRNO=28"
    assert n.extend_timeout(3_000_000)
    assert _recv(sock) == b"EXTEND_TIMEOUT_USEC=3000000"
    n.close()
    assert n.watchdog()  # reopens after close
    assert _recv(sock) == b"WATCHDOG=1"
    n.close()


def test_abstract_namespace() -> None:
    name = f"acq-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        with Notifier({"NOTIFY_SOCKET": "@" + name}) as n:
            assert n.ready("up")
            assert _recv(sock) == b"READY=1\nSTATUS=up"
    finally:
        sock.close()


def test_no_socket_is_a_no_op() -> None:
    n = Notifier({})
    assert not n.enabled
    assert not n.ready("x")
    assert not n.status("x")
    assert not n.watchdog()
    assert not n.stopping()
    assert not n.errno(5)
    assert not n.extend_timeout(1)
    assert n.watchdog_interval_s() is None


@pytest.mark.parametrize("value", ["", "@", "vsock:2:1234", "relative/path"])
def test_unusable_socket_values_disable(value: str) -> None:
    assert not Notifier({"NOTIFY_SOCKET": value}).watchdog()


def test_send_failure_returns_false_and_logs(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    with caplog.at_level(logging.DEBUG, logger="acq.record.sdnotify"):
        assert n.watchdog() is False
    assert any("sd_notify" in r.getMessage() for r in caplog.records)
    assert all(r.levelno == logging.DEBUG for r in caplog.records)


def test_watchdog_interval() -> None:
    me = str(os.getpid())
    assert Notifier({"WATCHDOG_USEC": "10000000"}).watchdog_interval_s() == 10.0
    env = {"WATCHDOG_USEC": "2500000", "WATCHDOG_PID": me}
    assert Notifier(env).watchdog_interval_s() == 2.5
    other = {"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid() + 1)}
    assert Notifier(other).watchdog_interval_s() is None
    for usec in ("", "0", "-5", "ten"):
        assert Notifier({"WATCHDOG_USEC": usec}).watchdog_interval_s() is None
    assert Notifier({"WATCHDOG_USEC": "1", "WATCHDOG_PID": "x"}).watchdog_interval_s() is None


def test_unset_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "s"))
    monkeypatch.setenv("WATCHDOG_USEC", "10000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    n = Notifier(unset_environment=True)
    assert n.enabled and n.watchdog_interval_s() == 10.0
    assert not {"NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"} & set(os.environ)


@pytest.mark.parametrize(
    ("level", "prefix"),
    [
        (logging.DEBUG, "<7>"),
        (logging.INFO, "<6>"),
        (logging.WARNING, "<4>"),
        (logging.ERROR, "<3>"),
        (logging.CRITICAL, "<2>"),
        (logging.INFO + 5, "<6>"),
        (logging.NOTSET, "<7>"),
    ],
)
def test_journal_prefix(level: int, prefix: str) -> None:
    assert journal_prefix(level) == prefix


def test_formatter_prefixes_every_line_without_timestamp() -> None:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JournalFormatter())
    logger = logging.getLogger("acq.test.journal")
    logger.propagate = False
    logger.setLevel(logging.DEBUG)
    logger.addHandler(handler)
    try:
        logger.debug("dbg")
        logger.info("laser: 40.0 Hz")
        logger.warning("camera: 3 frames dropped")
        logger.error("disk below reserve")
        logger.critical("gone")
        try:
            raise RuntimeError("boom")
        except RuntimeError:
            logger.exception("writer failed")
    finally:
        logger.removeHandler(handler)
    lines = stream.getvalue().splitlines()
    assert lines[:5] == [
        "<7>acq.test.journal: dbg",
        "<6>acq.test.journal: laser: 40.0 Hz",
        "<4>acq.test.journal: camera: 3 frames dropped",
        "<3>acq.test.journal: disk below reserve",
        "<2>acq.test.journal: gone",
    ]
    trace = lines[5:]
    assert trace[0] == "<3>acq.test.journal: writer failed"
    assert len(trace) > 2 and all(line.startswith("<3>") for line in trace)
    assert trace[-1] == "<3>RuntimeError: boom"


def test_use_journal_format(tmp_path: Path) -> None:
    with open(tmp_path / "stderr", "w") as f:
        st = os.fstat(f.fileno())
        assert use_journal_format(f, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"})
        assert not use_journal_format(f, {"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino + 1}"})
        assert not use_journal_format(f, {"JOURNAL_STREAM": "garbage"})
        assert not use_journal_format(f, {})
    assert not use_journal_format(io.StringIO(), {"JOURNAL_STREAM": "1:2"})  # no fileno
    assert not use_journal_format(sys.stderr, {})
