"""LogTail follows a real MCAP file as the recorder's LogWriter appends to it: each poll
reads only what the writer added, a record not yet whole waits for the next poll, and a
closed file is read from its index."""

from __future__ import annotations

from pathlib import Path

from acq.log import schemas
from acq.log.tail import LogTail
from acq.log.writer import LogWriter


def _status(n: int) -> bytes:
    return schemas.status(
        timestamp_ns=n, uptime_s=float(n), devices=[{"name": "laser", "kind": "scanner"}]
    )


def _writer(tmp_path: Path) -> LogWriter:
    w = LogWriter(tmp_path, metadata={"config": {"yaml": "version: 1\n"}}, profile="acq")
    w.add_channel("/acq/status", schemas.SCHEMAS["acq.Status"])
    w.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    return w


def _seconds(w: LogWriter, start: int, n: int) -> None:
    """``n`` one-second chunks from ``start``: a status and a clock pair each."""
    for s in range(start, start + n):
        t = s * 1_000_000_000
        w.write("/acq/status", _status(s), t, t)
        w.write("/acq/clock", schemas.clock(realtime_ns=t, monotonic_ns=t), t, t)
        w.sync()  # the recorder ends a chunk each second


def test_each_poll_reads_only_what_was_added(tmp_path: Path) -> None:
    w = _writer(tmp_path)
    _seconds(w, 1, 50)
    assert w.path is not None
    tail = LogTail(w.path, ["/acq/status"], back_chunks=2)
    first = tail.poll()
    # of 50 chunks already there, only the newest two are opened (and the first, for
    # the channels): the view wants the newest state
    assert [m.decoded.uptime_s for m in first] == [1.0, 49.0, 50.0]
    assert all(m.topic == "/acq/status" for m in first)
    assert tail.metadata["config"] == {"yaml": "version: 1\n"}
    assert tail.poll() == []
    size = w.path.stat().st_size
    assert tail.offset == size
    _seconds(w, 51, 1)
    again = tail.poll()
    assert [m.decoded.uptime_s for m in again] == [51.0]
    rate = tail.write_rate()
    assert rate is not None and 0 < rate < 10_000  # a few hundred bytes per log second
    assert not tail.finished
    w.close()
    assert tail.poll() == [] and tail.finished


def test_a_record_not_yet_whole_waits_for_the_next_poll(tmp_path: Path) -> None:
    w = _writer(tmp_path)
    _seconds(w, 1, 2)
    assert w.path is not None
    two = len(w.path.read_bytes())
    _seconds(w, 3, 1)
    three = w.path.read_bytes()
    w.close()
    cut = tmp_path / "cut.mcap"
    # the file as a writer leaves it mid-chunk: the third chunk's first 40 bytes there
    cut.write_bytes(three[: two + 40])
    tail = LogTail(cut, ["/acq/status"])
    assert [m.decoded.uptime_s for m in tail.poll()] == [1.0, 2.0]
    assert tail.offset == two
    with cut.open("ab") as f:  # the writer goes on
        f.write(three[two + 40 :])
    assert [m.decoded.uptime_s for m in tail.poll()] == [3.0]


def test_a_closed_file_is_read_from_its_index(tmp_path: Path) -> None:
    w = _writer(tmp_path)
    _seconds(w, 1, 20)
    assert w.path is not None
    path = w.path
    w.close()
    tail = LogTail(path, ["/acq/status", "/acq/clock"], back_chunks=1)
    got = tail.poll()
    assert tail.finished and tail.offset == path.stat().st_size
    assert [m.topic for m in got] == ["/acq/status", "/acq/clock"]
    assert got[0].decoded.uptime_s == 20.0
    assert tail.metadata["config"] == {"yaml": "version: 1\n"}
    assert tail.poll() == []


def test_a_closed_files_last_state_when_its_last_chunks_hold_none(tmp_path: Path) -> None:
    """A metadata record ends the open chunk: a file may end in chunks of other topics
    only (a clock pair after a device's description); the last status is still found."""
    w = _writer(tmp_path)
    _seconds(w, 1, 5)
    assert w.path is not None
    path = w.path
    for s in (6, 7):
        t = s * 1_000_000_000
        w.update_metadata("device.laser", {"model": f"UTM-30LX {s}"})
        w.write("/acq/clock", schemas.clock(realtime_ns=t, monotonic_ns=t), t, t)
    w.close()
    tail = LogTail(path, ["/acq/status"], back_chunks=1)
    got = tail.poll()
    assert [m.decoded.uptime_s for m in got] == [5.0]
    assert tail.metadata["device.laser"] == {"model": "UTM-30LX 7"}
