"""Listeners on the recorder's log, on plain records: each its own bounded queue and
thread, drops counted, publishing never blocks; and the log writer's tap feeding them
from a real MCAP file's writes."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from acq.log import schemas
from acq.log.writer import LogWriter
from acq.record.listeners import Listener, Listeners, LogRecord

STATUS = schemas.SCHEMAS["acq.Status"]


def _record(k: int, topic: str = "/a") -> LogRecord:
    return LogRecord(topic, STATUS, k.to_bytes(4, "little"), k)


class Collect(Listener):
    """Keeps what it gets; ``gate`` (when given) holds it until set: a stalled listener."""

    def __init__(self, gate: threading.Event | None = None) -> None:
        self.got: list[LogRecord] = []
        self.lost: list[LogRecord] = []
        self.gate = gate
        self.stopped = False

    def on_record(self, record: LogRecord) -> None:
        if self.gate is not None:
            self.gate.wait()
        self.got.append(record)

    def dropped(self, record: LogRecord) -> None:
        self.lost.append(record)

    def stop(self) -> None:
        self.stopped = True


class Fails(Listener):
    def on_record(self, record: LogRecord) -> None:
        raise ValueError("a listener's bug")


def _wait_for(condition: object, timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < end, "timed out"
        time.sleep(0.0005)


def test_every_listener_gets_every_record_in_order() -> None:
    hub = Listeners(size=4096)
    a, b = Collect(), Collect()
    feeds = [hub.add(a), hub.add(b)]
    records = [_record(k) for k in range(2000)]
    for r in records:
        hub.publish(r)
    hub.close()
    assert a.got == records and b.got == records
    assert a.stopped and b.stopped
    assert [f.dropped for f in feeds] == [0, 0]
    assert [f.delivered for f in feeds] == [2000, 2000]


def test_a_stalled_listener_drops_its_own_records_and_never_blocks(
    caplog: pytest.LogCaptureFixture,
) -> None:
    hub = Listeners(size=8)
    gate = threading.Event()
    stalled, other = Collect(gate), Collect()
    stalled_feed, other_feed = hub.add(stalled), hub.add(other)
    records = [_record(k) for k in range(200)]
    started = time.monotonic()
    for r in records:
        hub.publish(r)
        _wait_for(lambda: other_feed.qsize() == 0)  # the other keeps up: loses nothing
    took = time.monotonic() - started
    # the stalled one holds one record in hand and 8 queued; the rest were dropped
    assert stalled_feed.dropped == 200 - 9
    assert stalled.lost == records[9:]  # each told to the listener
    assert other_feed.dropped == 0 and other.got == records and other.lost == []
    assert took < 10.0
    # publishing as fast as it can: no wait, what a queue cannot take is counted
    started = time.perf_counter()
    for r in records * 5:
        hub.publish(r)
    assert time.perf_counter() - started < 0.5
    assert stalled_feed.dropped == 1200 - 9
    gate.set()
    with caplog.at_level(logging.WARNING, "acq.record"):
        hub.close()
    said = [r.getMessage() for r in caplog.records]
    assert f"listener Collect fell behind: {stalled_feed.dropped} records" in said[0], said
    # what it got is the first records, in order: none lost but those counted
    assert [r.log_time_ns for r in stalled.got] == list(range(9))
    assert len(other.got) + other_feed.dropped == 1200
    assert other.got[:200] == records


def test_a_failing_listener_keeps_its_thread_and_the_others_go_on() -> None:
    hub = Listeners()
    failing, good = hub.add(Fails()), Collect()
    hub.add(good)
    for k in range(10):
        hub.publish(_record(k))
    hub.close()
    assert failing.failed == 10 and failing.delivered == 10
    assert len(good.got) == 10


def test_a_listener_added_while_publishing_gets_the_records_after() -> None:
    hub = Listeners()
    first = Collect()
    hub.add(first)
    hub.publish(_record(0))
    late = Collect()
    hub.add(late)
    hub.publish(_record(1))
    hub.close()
    assert [r.log_time_ns for r in first.got] == [0, 1]
    assert [r.log_time_ns for r in late.got] == [1]
    hub.publish(_record(2))  # after close: no listener, no error


def test_the_writer_taps_every_message_it_writes(tmp_path: Path) -> None:
    hub = Listeners()
    got = Collect()
    hub.add(got)
    writer = LogWriter(
        tmp_path, tap=lambda *m: hub.publish(LogRecord(*m)), split_bytes=20_000, sync_interval_s=0
    )
    writer.add_channel("/tf_static", schemas.SCHEMAS["foxglove.FrameTransforms"])
    writer.add_channel("/acq/status", STATUS)
    writer.set_latched("/tf_static", b"latched", 5)
    for k in range(300):  # rolls over a few files: the latched message is tapped once
        writer.write("/acq/status", bytes(100) + k.to_bytes(4, "little"), 10 + k, 10 + k)
    writer.close()
    hub.close()
    assert len(writer.files) > 2
    assert [r.topic for r in got.got] == ["/tf_static"] + ["/acq/status"] * 300
    assert got.got[0].latched and got.got[0].data == b"latched"
    assert got.got[0].schema.name == "foxglove.FrameTransforms"
    # the same bytes and log times (the log's time base) as the files hold
    to_log = writer.time_base.to_log
    assert [r.log_time_ns for r in got.got[1:]] == [to_log(10 + k) for k in range(300)]
    raw = []
    for path in writer.files:
        with path.open("rb") as f:
            raw += [
                m.data for _, c, m in make_reader(f).iter_messages() if c.topic == "/acq/status"
            ]
    assert raw == [r.data for r in got.got[1:]]
