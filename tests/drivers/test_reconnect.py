"""Reconnection through cable pulls, reboots, stalls and garbage, over real TCP.

The scanner here is a minimal driver for the line device of ``tests.line_device`` (one
``tick N`` line per scan, the device clock N * 20 ms), so what is tested is
``acq.drivers.reconnect`` itself; the SCIP and CoLa drivers are run through it in their
own tests.
"""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest

from acq.drivers.reconnect import Backoff, LinkEvent, Reconnecting, url_reachable
from acq.drivers.scanner import (
    ConnectionLost,
    ProtocolError,
    ScanGeometry,
    Scanner,
    ScanTimeout,
)
from acq.records import DeviceInfo, Scan
from acq.sim.transport import TcpDeviceServer
from tests.line_device import LineDevice

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


class LineScanner(Scanner):
    driver = "line"

    def __init__(self, url: str, **kw: object) -> None:
        super().__init__(url, **kw)  # type: ignore[arg-type]
        self.sock: socket.socket | None = None
        self.buf = b""

    def connect(self) -> DeviceInfo:
        host, port = self.url.removeprefix("socket://").split(":")
        self.sock = socket.create_connection((host, int(port)), timeout=1.0)
        self.buf = b""
        self.geometry = ScanGeometry(0.0, 0.1, 1, LineDevice.period, 0.0, 0.1, 10.0)
        self.info = DeviceInfo(name="line", driver="line", vendor="test", model="line")
        return self.info

    def start(self) -> None:
        assert self.sock is not None
        self.sock.sendall(b"start\n")

    def read_scan(self) -> Scan:
        assert self.sock is not None
        deadline = time.monotonic() + self.timeout
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ScanTimeout(f"no telegram within {self.timeout:.2f} s")
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError as e:
                raise ConnectionLost(str(e)) from None
            if not data:
                raise ConnectionLost("end of stream")
            self.buf += data
        line, self.buf = self.buf.split(b"\n", 1)
        parts = line.split(b" ")
        if len(parts) != 2 or parts[0] != b"tick" or not parts[1].isdigit():
            raise ProtocolError(f"bad line {line[:20]!r}")
        n = int(parts[1])
        return Scan(
            ranges=np.ones(1), intensities=[], angle_min=0.0, angle_increment=0.1,
            time_increment=0.0, scan_period=LineDevice.period, recv_ns=time.monotonic_ns(),
            device_ticks=(n * 20,), sequence=n,
        )  # fmt: skip

    def stop(self) -> None:
        pass

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class Run:
    """Consume a Reconnecting stream in a thread, recording scans and events."""

    def __init__(self, url: str) -> None:
        self.events: list[LinkEvent] = []
        self.scans: list[tuple[float, Scan]] = []
        self.link = Reconnecting(LineScanner(url), on_event=self.events.append)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        for scan in self.link.scans(self.stop):
            self.scans.append((time.monotonic(), scan))

    def wait_scans(self, n: int, timeout: float = 5.0) -> None:
        target = len(self.scans) + n
        t0 = time.monotonic()
        while len(self.scans) < target:
            assert time.monotonic() - t0 < timeout, f"only {len(self.scans)} scans"
            time.sleep(0.01)

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events]

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        assert not self.thread.is_alive()


@pytest.fixture
def rig():  # type: ignore[no-untyped-def]
    dev = LineDevice()
    with TcpDeviceServer(dev) as srv:
        run = Run(srv.url)
        yield srv, run
        run.close()


def test_backoff_doubles_from_half_a_second_to_five() -> None:
    b = Backoff()
    assert [b.next() for _ in range(7)] == [0.5, 1.0, 2.0, 4.0, 5.0, 5.0, 5.0]
    b.reset()
    assert b.next() == 0.5


def test_cable_pull_reconnects(rig) -> None:  # type: ignore[no-untyped-def]
    srv, run = rig
    run.wait_scans(5)
    srv.disconnect()
    run.wait_scans(10)
    assert run.kinds().count("connected") == 2
    assert "disconnected" in run.kinds()


def test_reboot_scans_flow_within_2s_of_the_device_coming_back(rig) -> None:  # type: ignore[no-untyped-def]
    srv, run = rig
    run.wait_scans(5)
    down = 3.2  # long enough for the backoff to have grown to 2 s and more
    srv.reboot(down)
    back_at = time.monotonic() + down
    n_before = len(run.scans)
    run.wait_scans(3, timeout=down + 4)
    first_after = run.scans[n_before][0]
    assert first_after - back_at < 2.0
    assert "clock_reset" in run.kinds()  # the device's ticks restarted: reported
    assert run.kinds().count("connect_failed") >= 2


def test_stall_is_detected_after_three_periods(rig) -> None:  # type: ignore[no-untyped-def]
    srv, run = rig
    run.wait_scans(5)
    srv.stall(0.5)
    run.wait_scans(10, timeout=5)
    assert "stalled" in run.kinds()
    assert "clock_reset" not in run.kinds()


def test_garbage_costs_telegrams_not_the_connection(rig) -> None:  # type: ignore[no-untyped-def]
    srv, run = rig
    run.wait_scans(5)
    srv.inject_garbage(40)
    run.wait_scans(10)
    assert run.link.protocol_errors >= 1
    assert run.kinds().count("connected") == 1


def test_url_reachable(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with TcpDeviceServer(LineDevice()) as srv:
        assert url_reachable(srv.url)
        assert url_reachable(f"{srv.host}:{srv.port}")
    assert not url_reachable(srv.url)
    assert not url_reachable(str(tmp_path / "ttyACM0"))
    (tmp_path / "ttyACM0").touch()
    assert url_reachable(str(tmp_path / "ttyACM0"))


class BuggyScanner(LineScanner):
    """A driver with a bug: every 5th scan its parser indexes past what it was sent."""

    def read_scan(self) -> Scan:
        scan = super().read_scan()
        if scan.sequence % 5 == 0:
            raise IndexError("list index out of range")
        return scan


def test_a_driver_bug_closes_the_link_and_reconnects_after_a_growing_backoff() -> None:
    events: list[LinkEvent] = []
    scans: list[Scan] = []
    stop = threading.Event()
    with TcpDeviceServer(LineDevice()) as srv:
        link = Reconnecting(BuggyScanner(srv.url), backoff=Backoff(0.1, 1.0),
                            on_event=events.append)  # fmt: skip

        def consume() -> None:
            scans.extend(link.scans(stop))

        thread = threading.Thread(target=consume, daemon=True)
        thread.start()
        t0 = time.monotonic()

        def reconnected_after_third_fault() -> bool:
            faults = [e.mono_ns for e in events if e.kind == "fault"]
            return len(faults) >= 3 and any(
                e.kind == "connected" and e.mono_ns > faults[2] for e in list(events)
            )

        while not reconnected_after_third_fault() and time.monotonic() - t0 < 10:
            time.sleep(0.01)
        n = len(scans)
        while len(scans) < n + 2 and time.monotonic() - t0 < 10:
            time.sleep(0.01)
        assert thread.is_alive() and len(scans) >= n + 2  # scans flow again
        stop.set()
        thread.join(5)
    faults = [e for e in events if e.kind == "fault"]
    assert len(faults) >= 3 and link.faults == len(faults) and link.disconnects >= 3
    assert all(e.detail == "IndexError: list index out of range" for e in faults)
    assert all(isinstance(e.error, IndexError) for e in faults)  # for its traceback
    # after each fault, the next connection waits 0.1, 0.2, 0.4 s: a backoff that grows
    # while the faults go on, although each connection succeeds (a busy host adds to it)
    waits = []
    for fault in faults[:3]:
        after = next(e for e in events if e.kind == "connected" and e.mono_ns > fault.mono_ns)
        waits.append((after.mono_ns - fault.mono_ns) * 1e-9)
    expected = (0.1, 0.2, 0.4)
    assert all(w - 0.01 < got < w + 0.3 for got, w in zip(waits, expected, strict=True)), waits
    assert waits[2] > waits[0] + 0.2, waits
