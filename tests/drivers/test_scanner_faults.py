"""The real drivers behind ``Reconnecting`` through a device reboot, and ``acq sim
scanner`` run as its own process for a client to use."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from acq import cli
from acq.drivers.reconnect import LinkEvent, Reconnecting
from acq.drivers.scanner import ScanTimeout, scanner_for
from acq.sim.devices import make_scanner, serve_scanner

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


@pytest.mark.parametrize(("name", "pty"), [("lms111", False), ("utm-30lx", True)])
def test_reboot_is_reported_and_scans_resume_within_2s(name: str, pty: bool) -> None:
    m, device = make_scanner(name)
    server = serve_scanner(device, None, pty=pty)
    driver = "hokuyo" if m.vendor == "hokuyo" else "sick"
    events: list[LinkEvent] = []
    link = Reconnecting(scanner_for(driver, server.url, timeout=2.0), on_event=events.append)
    times: list[float] = []
    stop = threading.Event()

    def consume() -> None:
        for _ in link.scans(stop):
            times.append(time.monotonic())

    thread = threading.Thread(target=consume, daemon=True)
    thread.start()
    try:
        while len(times) < 5:
            time.sleep(0.01)
        down = 2.5  # long enough for the backoff to reach 2 s
        server.reboot(down)
        back = time.monotonic() + down
        n = len(times)
        deadline = back + 4.0
        while len(times) <= n + 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        after = [t for t in times[n:] if t > back]
        assert after, [e.kind for e in events]
        assert after[0] - back < 2.0
        assert "clock_reset" in [e.kind for e in events]
    finally:
        stop.set()
        thread.join(5)
        server.close()


@pytest.mark.parametrize("name", ["utm-30lx", "lms111"])
def test_scans_that_arrived_are_read_when_the_read_comes_late(name: str) -> None:
    """A read that runs after its deadline (a host busy elsewhere held the thread: here,
    timeout 0) still takes the scans already in the socket; a timeout only once they are
    taken and nothing more comes (the device stalled)."""
    m, device = make_scanner(name)
    server = serve_scanner(device, None)
    driver = "hokuyo" if m.vendor == "hokuyo" else "sick"
    scanner = scanner_for(driver, server.url, timeout=2.0)
    try:
        scanner.connect()
        scanner.start()
        scanner.read_scan()
        time.sleep(0.5)  # scans pile up in the socket: 20 at 40 Hz, 25 at 50 Hz
        server.stall(3.0)
        time.sleep(0.1)  # the last telegram under way arrives
        scanner.timeout = 0.0
        late = []
        with pytest.raises(ScanTimeout):
            for _ in range(100):
                late.append(scanner.read_scan())
        assert len(late) >= 5
        assert [s.sequence for s in late] == list(range(late[0].sequence, late[-1].sequence + 1))
    finally:
        scanner.close()
        server.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize(("model", "vendor"), [("utm-30lx", "UTM-30LX"), ("lms111", "LMS1")])
def test_acq_sim_scanner_serves_any_client_until_sigterm(
    model: str, vendor: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """What it prints to try is a command that works (the URL as a config takes it)."""
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "sim", "scanner", "--model", model,
         "--listen", f"tcp://127.0.0.1:{port}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy(),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert f"127.0.0.1:{port}" in first, first + (proc.stderr.read() if proc.stderr else "")
        try_line = proc.stdout.readline().split()
        assert try_line[:3] == ["try:", "acq", "probe"], try_line
        assert cli.main([*try_line[2:], "--count", "2", "--json"]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert vendor in json.loads(lines[0])["device"]["model"]
        assert len(lines) == 3
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0


def test_acq_sim_scanner_refuses_a_bad_listen_address(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["sim", "scanner", "--model", "lms111", "--listen", "udp://127.0.0.1:5"])
    assert code == 2
    assert "expected tcp://HOST:PORT" in capsys.readouterr().err
