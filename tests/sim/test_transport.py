"""The simulated-device servers on real transports (TCP on 127.0.0.1 and a pty), with
their faults, using a tiny line protocol device so the transport is tested alone."""

from __future__ import annotations

import socket
import time

import pytest
import serial

from acq.sim.transport import DeviceServer, PtyDeviceServer, TcpDeviceServer
from tests.line_device import LineDevice

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


def open_client(server: DeviceServer) -> serial.SerialBase:
    return serial.serial_for_url(server.url, timeout=0.5)


@pytest.fixture(params=["tcp", "pty"])
def server(request: pytest.FixtureRequest):  # type: ignore[no-untyped-def]
    dev = LineDevice()
    srv: DeviceServer = TcpDeviceServer(dev) if request.param == "tcp" else PtyDeviceServer(dev)
    with srv:
        yield srv


def read_lines(port: serial.SerialBase, n: int) -> list[bytes]:
    return [port.readline() for _ in range(n)]


def test_request_reply_and_stream(server: DeviceServer) -> None:
    with open_client(server) as port:
        port.write(b"ping\n")
        assert port.readline() == b"pong\n"
        port.write(b"start\n")
        lines = read_lines(port, 5)
        assert lines == [b"tick %d\n" % i for i in range(1, 6)]


def test_garbage_and_corrupt_telegram(server: DeviceServer) -> None:
    with open_client(server) as port:
        port.write(b"start\n")
        port.readline()
        server.inject_garbage(16)
        server.corrupt_checksum()
        data = port.read(200)
        assert b"!\n" in data  # the corrupted telegram
        assert len(data) == 200


def test_stall_then_stream_again(server: DeviceServer) -> None:
    with open_client(server) as port:
        port.write(b"start\n")
        port.readline()
        server.stall(0.3)
        time.sleep(0.05)
        port.reset_input_buffer()
        port.timeout = 0.15
        assert port.read(100) == b""  # silent
        port.timeout = 1.0
        assert port.readline().startswith(b"tick")  # and back


def test_disconnect_mid_telegram_and_reconnect(server: DeviceServer) -> None:
    port = open_client(server)
    port.write(b"start\n")
    port.readline()
    server.disconnect_mid_telegram()
    got = b""
    with pytest.raises((serial.SerialException, OSError, EOFError)):
        for _ in range(50):
            chunk = port.read(1)
            if isinstance(server, TcpDeviceServer) and chunk == b"":
                raise EOFError  # TCP: the socket handler reads b"" at EOF
            got += chunk
    port.close()
    assert not got.endswith(b"\n")  # the last telegram was cut
    if isinstance(server, TcpDeviceServer):
        assert got  # (a pty hangup may discard what was in flight, as a cable pull does)
    time.sleep(0.1)
    with open_client(server) as again:  # the same URL works again (pty: a new node)
        again.write(b"ping\n")
        assert again.readline() == b"pong\n"


def test_reboot_makes_the_device_unreachable_for_a_while() -> None:
    dev = LineDevice()
    with TcpDeviceServer(dev) as srv:
        with open_client(srv) as port:
            port.write(b"ping\n")
            assert port.readline() == b"pong\n"
            t_reboot = time.monotonic()
            srv.reboot(0.5)
            time.sleep(0.1)
            with pytest.raises(serial.SerialException, match="disconnected"):
                port.read(10)
        t0 = time.monotonic()
        while True:
            try:
                with socket.create_connection((srv.host, srv.port), timeout=0.2) as s:
                    s.sendall(b"ping\n")
                    s.settimeout(0.3)
                    if s.recv(10) == b"pong\n":
                        break
            except OSError:
                pass
            assert time.monotonic() - t0 < 3, "device never came back"
            time.sleep(0.05)
        assert time.monotonic() - t_reboot >= 0.45
        assert dev.reboots == 1
