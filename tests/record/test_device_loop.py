"""The recorder's one device loop: a reader never waits for the writer (a full queue drops
records, counted), and a device's description is neither dropped nor waited for."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from acq.drivers.reconnect import LinkEvent
from acq.log.writer import LogWriter
from acq.record.adapters import (
    CameraAdapter,
    CanAdapter,
    GnssAdapter,
    ScannerAdapter,
    adapters_for,
)
from acq.record.config import parse
from acq.record.device_loop import DeviceAdapter, Outbox, run_device


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
