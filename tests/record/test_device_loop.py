"""The recorder's one device loop: a reader never waits for the writer (a full queue drops
records, counted), and a device's description is neither dropped nor waited for."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from acq.drivers.reconnect import Backoff, LinkEvent
from acq.log.writer import LogWriter
from acq.record.adapters import (
    CameraAdapter,
    CanAdapter,
    GnssAdapter,
    ScannerAdapter,
    adapters_for,
)
from acq.record.config import parse
from acq.record.device_loop import DeviceAdapter, DeviceState, Outbox, run_device


@dataclass(frozen=True)
class Info:
    connection: int  # which connection of the device this is


class FakeLink:
    """Records 0..n-1; the device reconnects (a new ``info``) at ``reconnect_at``."""

    def __init__(self, adapter: FakeAdapter, n: int, reconnect_at: int) -> None:
        self.adapter, self.n, self.reconnect_at = adapter, n, reconnect_at

    def records(self, stop: threading.Event) -> Iterator[int]:
        for i in range(self.n):
            if i in (0, self.reconnect_at):
                self.adapter.info = Info(i)
            yield i


class FakeAdapter(DeviceAdapter[int, int]):
    kind = "scanner"

    def __init__(self, n: int, reconnect_at: int) -> None:
        super().__init__("fake", "fakedriver")
        self.n, self.reconnect_at = n, reconnect_at
        self.info: Info | None = None

    def channels(self) -> list[tuple[str, str]]:
        return []

    def open(self, on_event: Callable[[LinkEvent], None]) -> Any:
        self.device = self
        return FakeLink(self, self.n, self.reconnect_at)

    def identity(self) -> object:
        return self.info

    def receive(self, record: int) -> Iterable[int]:
        self.state.count(record)
        return (record,)

    def write(self, writer: LogWriter, payload: int) -> None:
        raise AssertionError("no writer here")


def test_a_full_queue_drops_records_and_never_blocks_the_reader() -> None:
    outbox = Outbox(size=4)
    adapter = FakeAdapter(100, reconnect_at=50)  # reconnects with the queue full
    reader = threading.Thread(target=run_device, args=(adapter, outbox, threading.Event()))
    reader.start()
    reader.join(timeout=10)
    assert not reader.is_alive()  # no writer ever took anything: it did not wait
    assert (adapter.state.received, adapter.state.dropped, outbox.qsize()) == (100, 96, 4)
    assert [outbox.get(0).payload for _ in range(4)] == [0, 1, 2, 3]  # type: ignore[union-attr]
    # the description of the second connection is there, not dropped: the latest one
    described = outbox.descriptions()
    assert described == {"device.fake": {"driver": "fakedriver", "class": "FakeAdapter",
                                         "info": '{"connection": 50}'}}  # fmt: skip
    assert outbox.descriptions() == {}  # handed over once


def test_one_adapter_per_device_in_the_order_of_the_channels() -> None:
    cfg = parse({
        "version": 1,
        "scanners": [{"name": "laser", "driver": "hokuyo", "url": "/dev/ttyACM0"}],
        "cameras": [{"name": "cam", "driver": "opencv", "source": "0"}],
        "can": {"interface": "virtual", "channel": "c", "dbc": "v.dbc"},
        "gnss": {"url": "/dev/ttyUSB0"},
    })  # fmt: skip
    adapters = adapters_for(cfg)
    assert [type(a) for a in adapters] == [ScannerAdapter, CameraAdapter, CanAdapter, GnssAdapter]
    assert [(a.name, a.driver, a.state.kind) for a in adapters] == [
        ("laser", "hokuyo", "scanner"), ("cam", "opencv", "camera"),
        ("vehicle", "python-can", "can"), ("gnss", "nmea", "gnss"),
    ]  # fmt: skip
    assert [t for a in adapters for t, _ in a.channels()] == [
        "/laser/scan", "/laser/raw", "/acq/timing/laser",
        "/cam/image/compressed", "/acq/timing/cam",
        "/vehicle/odometry", "/vehicle/can",
        "/gnss/fix", "/gnss/raw", "/acq/timing/gnss",
    ]  # fmt: skip


class FailingAdapter(FakeAdapter):
    """Its driver fails to open once (a bug in it), then its adapter fails on record 3
    once (bytes it was not written for); each pass of its link is recorded, closed or not."""

    def __init__(self) -> None:
        super().__init__(10, reconnect_at=-1)
        self.opened = 0
        self.passes: list[list[int]] = []
        self.closed: list[bool] = []
        self.failed = False

    def open(self, on_event: Callable[[LinkEvent], None]) -> Any:
        self.opened += 1
        if self.opened == 1:
            raise RuntimeError("the driver's bug")
        self.device = self
        adapter = self

        class Link:
            def records(self, stop: threading.Event) -> Iterator[int]:
                adapter.passes.append([])
                adapter.closed.append(False)
                try:
                    for i in range(adapter.n):
                        adapter.info = Info(len(adapter.passes))
                        adapter.passes[-1].append(i)
                        yield i
                finally:
                    adapter.closed[-1] = True

        return Link()

    def receive(self, record: int) -> Iterable[int]:
        if record == 3 and not self.failed:
            self.failed = True
            raise ValueError("invalid literal for int() with base 10: '4²'")
        return super().receive(record)


def test_a_failure_in_a_device_loop_is_that_devices_and_it_opens_again(
    caplog: pytest.LogCaptureFixture,
) -> None:
    adapter = FailingAdapter()
    outbox = Outbox(size=100)
    with caplog.at_level(logging.DEBUG, logger="acq.record"):
        run_device(adapter, outbox, threading.Event(), Backoff(0.01, 0.05))
    state = adapter.state
    # opened again after its failure, its link closed after the record that failed it
    assert adapter.opened == 2
    assert adapter.passes == [[0, 1, 2, 3], list(range(10))] and adapter.closed == [True, True]
    assert state.received == 3 + 10 and outbox.qsize() == 13
    assert state.faults == 2 and not state.connected
    assert state.last_event == "fault: ValueError: invalid literal for int() with base 10: '4²'"
    errors = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert [r.getMessage().split(":")[0] for r in errors] == [
        "fake failed (1 so far), closed and reopened after a backoff",
        "fake failed (2 so far), closed and reopened after a backoff",
    ]
    assert all(r.exc_info is None for r in errors)  # one line each
    tracebacks = [r for r in caplog.records if r.levelno == logging.DEBUG and r.exc_info]
    assert [type(r.exc_info[1]) for r in tracebacks] == [RuntimeError, ValueError]  # type: ignore[index]


def watch(state: DeviceState, seconds: float, step_s: float = 0.1) -> list[tuple[float, str]]:
    """The warnings of ``state``'s silence watch over ``seconds`` after a start at 0."""
    warned = []
    handler = logging.Handler()
    handler.emit = lambda r: warned.append((t, r.getMessage()))  # type: ignore[method-assign]
    log = logging.getLogger("acq.record")
    log.addHandler(handler)
    try:
        for i in range(round(seconds / step_s) + 1):
            t = i * step_s
            state.watch(round(t * 1e9) + START_NS, START_NS)
    finally:
        log.removeHandler(handler)
    return warned


START_NS = 10**12


def test_a_silent_device_is_a_warning_within_5_s_repeated_with_backoff() -> None:
    state = DeviceState("laser", "scanner")
    state.event("connect_failed", "socket://127.0.0.1:9: [Errno 111] Connection refused")
    warned = watch(state, 700.0)
    assert [t for t, _ in warned] == pytest.approx([4, 9, 19, 39, 79, 159, 319, 619])
    assert warned[0][1] == (
        "laser: no record for 4 s since the start: not connected "
        "(connect_failed: socket://127.0.0.1:9: [Errno 111] Connection refused)"
    )


def test_a_device_connected_but_silent_is_a_warning_and_its_return_a_line(
    caplog: pytest.LogCaptureFixture,
) -> None:
    state = DeviceState("camera", "camera")
    state.event("connected", "MJPEG over HTTP")
    assert [m for _, m in watch(state, 5.0)] == [
        "camera: no record for 4 s since the start: connected, but no record "
        "(connected: MJPEG over HTTP)"
    ]
    state.count(START_NS + 6 * 10**9)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="acq.record"):
        state.watch(START_NS + 6 * 10**9, START_NS)
    assert caplog.messages == ["camera: recording again after 6.0 s without a record"]
