"""Soak: a driver behind ``Reconnecting`` against a simulated device whose cable is
pulled periodically loses no scan the device sent while connected.

The quick version runs in ``make test``; the ten-minute one (``ACQ_SOAK_S`` seconds,
default 600) in ``make test-slow``. Both devices run at once: a SICK LMS111 over TCP
(keyed by its scan counter) and a Hokuyo UTM-30LX over a pty (keyed by its ms
timestamp).
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import pytest

from acq.drivers.reconnect import LinkEvent, Reconnecting
from acq.drivers.scanner import scanner_for
from acq.sim.devices import make_scanner, serve_scanner

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


@dataclass
class Soak:
    name: str
    pty: bool
    sent: list[int] = field(default_factory=list)
    sent_at: list[float] = field(default_factory=list)  # host monotonic s each was made
    received: list[int] = field(default_factory=list)
    events: list[LinkEvent] = field(default_factory=list)
    pulls: int = 0
    pulled_at: list[float] = field(default_factory=list)  # host monotonic s


def _drain(history: deque, run: Soak, key: str) -> None:  # type: ignore[type-arg]
    while history:
        sent = history.popleft()
        run.sent.append(getattr(sent, key))
        run.sent_at.append(sent.t_sent)


def run_soak(seconds: float, pull_every: float) -> list[Soak]:
    runs = [Soak("lms111", pty=False), Soak("utm-30lx", pty=True)]
    stop = threading.Event()
    setups = []
    for run in runs:
        m, dev = make_scanner(run.name)
        server = serve_scanner(dev, None, pty=run.pty)
        driver = "hokuyo" if m.vendor == "hokuyo" else "sick"
        link = Reconnecting(
            scanner_for(driver, server.url, timeout=2.0), on_event=run.events.append
        )
        history, key, scan_key = (
            (dev.history, "scan_counter", "sequence")  # type: ignore[attr-defined]
            if driver == "sick"
            else (dev.sent, "timestamp", "ticks")  # type: ignore[attr-defined]
        )

        def consume(link: Reconnecting = link, run: Soak = run, scan_key: str = scan_key) -> None:
            for scan in link.scans(stop):
                run.received.append(
                    scan.sequence if scan_key == "sequence" else scan.device_ticks[0]
                )

        thread = threading.Thread(target=consume, daemon=True)
        thread.start()
        setups.append((run, server, history, key, thread))
    t_end = time.monotonic() + seconds
    next_pull = time.monotonic() + pull_every
    while time.monotonic() < t_end:
        time.sleep(0.1)
        for run, _server, history, key, _ in setups:
            _drain(history, run, key)
        if time.monotonic() >= next_pull:
            for run, server, *_ in setups:
                run.pulled_at.append(time.monotonic())
                server.disconnect()
                run.pulls += 1
            next_pull += pull_every
    stop.set()
    for run, server, history, key, thread in setups:
        thread.join(10)
        assert not thread.is_alive()
        _drain(history, run, key)
        server.close()
    return runs


# a scan made this little before a cable pull may still wait in the link's buffer when
# it goes (a pty's unread bytes go with it, as a serial line's do), and one made as
# little after it, before the device's thread saw the pull: lost with the cable
IN_FLIGHT_S = 0.25


def check(runs: list[Soak], min_connects: int) -> None:
    for run in runs:
        assert run.received, run.name
        last = run.received[-1]
        # Every scan sent up to the last one received (later ones were in flight when
        # the consumer stopped) arrived, once, in order; but for any in flight at a pull
        expected = [k for k in run.sent if k <= last]
        in_flight = {
            k for k, t in zip(run.sent, run.sent_at, strict=True)
            if any(abs(pull - t) < IN_FLIGHT_S for pull in run.pulled_at)
        }  # fmt: skip
        got = set(run.received)
        assert run.received == [k for k in expected if k in got], run.name  # once, in order
        lost = [k for k in expected if k not in got]
        assert set(lost) <= in_flight, (run.name, lost, len(expected), len(run.received))
        connects = [e for e in run.events if e.kind == "connected"]
        assert len(connects) >= min_connects, (run.name, [e.kind for e in run.events])


def test_quick_soak_with_cable_pulls() -> None:
    runs = run_soak(seconds=6.0, pull_every=2.0)
    check(runs, min_connects=3)


@pytest.mark.slow
def test_ten_minute_soak_with_periodic_disconnects() -> None:
    seconds = float(os.environ.get("ACQ_SOAK_S", "600"))
    runs = run_soak(seconds=seconds, pull_every=20.0)
    check(runs, min_connects=int(seconds // 20))
    for run in runs:
        print(f"{run.name}: {len(run.received)} scans, {run.pulls} cable pulls, none lost")
