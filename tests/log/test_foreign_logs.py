"""Logs that are not quite acq's, copied from a real log of a simulated drive
(sim/drive_log.py) with mcap's writer: without its metadata records (what `mcap filter`
writes without --include-metadata), with a foreign schema under one of acq's names, or
with an unusable ``utc_offset_ns``. Each is read with what can be known and what is
missing is said once, or refused in one line naming the file and the channel."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from google.protobuf import descriptor_pb2
from mcap.records import Schema
from mcap.writer import Writer
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from acq.cli import main as acq_main
from acq.log.reader import LogReader
from acq.log.schemas import SCHEMAS
from acq.log.summary import info
from acq.sim.drive_log import DriveTruth
from tests.log_rewrite import mcap_copy

_F = descriptor_pb2.FieldDescriptorProto


def _without_metadata(src: Path, dst: Path) -> Path:
    mcap_copy(src, dst, metadata=lambda _n, _m: None)
    return dst


def _offset(value: str):  # type: ignore[no-untyped-def]
    """A metadata function: the ``acq`` record's ``utc_offset_ns`` set to ``value``."""
    return lambda name, m: {**m, "utc_offset_ns": value} if name == "acq" else m


def _read(path: Path) -> list[tuple[str, int, int, int]]:
    """(topic, log time, publish time, a Foxglove message's stamp or -1) of every message."""
    reader = LogReader(path)
    out = []
    for schema, channel, message in reader.messages():
        stamp = -1
        if schema is not None and schema.name.startswith("foxglove."):
            msg = reader.decode(schema, channel, message)
            stamp = msg.timestamp.ToNanoseconds() if msg is not None else -2
        out.append((channel.topic, message.log_time, message.publish_time, stamp))
    return out


def _warnings(caplog: pytest.LogCaptureFixture, path: Path) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno >= logging.WARNING and r.getMessage().startswith(f"{path}: ")
    ]


# --- a log without metadata records ------------------------------------------------------


def test_a_log_without_metadata_reads_on_its_clock_and_says_what_is_missing_once(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    truth, _ = short_drive
    src = truth.files[0]
    bare = _without_metadata(src, tmp_path / "bare.mcap")
    reader = LogReader(src)
    for _ in reader.messages():
        pass
    original = reader.time_base
    expected = _read(src)
    assert original.utc and original.utc_offset_ns  # a UTC log
    with caplog.at_level(logging.WARNING):
        got = _read(bare)
        again = _read(bare)  # a second pass in the same process says nothing more
    # the stamps already UTC are mapped back once, as in the log with its metadata
    assert got == expected and again == expected
    (line,) = _warnings(caplog, bare)
    assert "no metadata records" in line and "mcap filter" in line, line
    for missing in ("no acq record (clock", "scanner geometry", "no calibration record"):
        assert missing in line, line
    assert f"host monotonic + {original.utc_offset_ns / 1e9:.6f} s" in line, line
    # cut short (read linearly, no index): the same, up to the cut
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(bare.read_bytes()[: bare.stat().st_size * 2 // 3])
    read = _read(cut)
    assert read and read == expected[: len(read)]
    # acq info: the same span and start in UTC as the log with its metadata
    assert info(bare).start_realtime_ns == info(src).start_realtime_ns is not None
    assert "no metadata records" in (info(bare).problem or "")


def test_commands_read_a_log_without_metadata(
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    truth, calib = short_drive
    src = truth.files[0]
    bare = _without_metadata(src, tmp_path / "bare.mcap")
    with caplog.at_level(logging.WARNING):
        argv = ["colorize", str(bare), "--calib", str(calib), "-o", str(tmp_path / "c.ply")]
        assert acq_main([*argv, "--no-preview"]) == 0, capsys.readouterr().err
        assert (tmp_path / "c.ply").stat().st_size > 10_000
        offset = ["calibrate", "time-offset", str(bare), "--calib", str(calib)]
        assert acq_main([*offset, "-o", str(tmp_path / "t.yaml")]) == 0, capsys.readouterr().err
        for log, out in ((src, "a"), (bare, "b")):
            assert acq_main(["export", "ros2", str(log), "-o", str(tmp_path / out)]) == 0
    err = capsys.readouterr().err
    assert "a bug?" not in err and "laser return strengths" not in err, err
    assert len(_warnings(caplog, bare)) == 1, _warnings(caplog, bare)  # said once, all commands
    # the bag of the bare copy has the very stamps of the log's own bag (not 2084's), less
    # the camera_info of the calibration record it lacks
    with_metadata = _bag_times(tmp_path / "a")
    assert with_metadata.pop("/camera/camera_info")
    assert _bag_times(tmp_path / "b") == with_metadata


def _bag_times(bag: Path) -> dict[str, list[int]]:
    times: dict[str, list[int]] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, timestamp, _raw in reader.messages():
            times.setdefault(conn.topic, []).append(timestamp)
    assert times
    return times


# --- a foreign schema under acq's name ---------------------------------------------------


def _foreign(name: str) -> bytes:
    """A FileDescriptorSet of a message ``name`` whose fields are not acq's."""
    fds = descriptor_pb2.FileDescriptorSet()
    package, _, short = name.rpartition(".")
    f = fds.file.add(name="other.proto", package=package, syntax="proto3")
    m = f.message_type.add(name=short)
    m.field.add(name="x", number=1, type=_F.TYPE_FLOAT, label=_F.LABEL_OPTIONAL)
    m.field.add(name="label", number=2, type=_F.TYPE_STRING, label=_F.LABEL_OPTIONAL)
    return fds.SerializeToString()


def _retyped(name: str, field: str) -> bytes:
    """acq's schema ``name`` with ``field`` made a string."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(SCHEMAS[name].data)
    package, _, short = name.rpartition(".")
    for file in fds.file:
        for m in file.message_type:
            if file.package == package and m.name == short:
                next(f for f in m.field if f.name == field).type = _F.TYPE_STRING
    return fds.SerializeToString()


FOREIGN_SCAN = b"\x0d\x00\x00\x80\x3f\x12\x03abc"  # x = 1.0, label = "abc"


@pytest.fixture
def foreign_scan(short_drive: tuple[DriveTruth, Path], tmp_path: Path) -> tuple[Path, str, int]:
    """A copy whose scan channel has a foreign foxglove.LaserScan: (log, topic, messages)."""
    truth, _ = short_drive
    log = tmp_path / "foreign.mcap"

    def schema(s: Schema) -> bytes:
        return _foreign(s.name) if s.name == "foxglove.LaserScan" else s.data

    counts = mcap_copy(
        truth.files[0], log, lambda t, d: FOREIGN_SCAN if t.endswith("/scan") else d, schema
    )
    (topic,) = [t for t in counts if t.endswith("/scan")]
    return log, topic, counts[topic]


def test_a_foreign_schema_under_acqs_name_is_not_read_as_acqs(
    foreign_scan: tuple[Path, str, int],
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    log, topic, n = foreign_scan
    reader = LogReader(log)
    with caplog.at_level(logging.WARNING):
        scans = [reader.decode(s, c, m) for s, c, m in reader.messages() if c.topic == topic]
    assert scans == [None] * n
    (line,) = _warnings(caplog, log)
    assert line.startswith(f"{log}: {topic} (foxglove.LaserScan) cannot be decoded: ")
    assert "not acq's foxglove.LaserScan" in line and f"{n} messages skipped" in line, line

    # an acq.* name whose fields have other types: the same
    truth, _ = short_drive
    other = tmp_path / "timing.mcap"
    mcap_copy(
        truth.files[0], other,
        schema_data=lambda s: _retyped(s.name, "recv_ns") if s.name == "acq.Timing" else s.data,
    )  # fmt: skip
    reader = LogReader(other)
    timing = [
        reader.decode(s, c, m) for s, c, m in reader.messages() if c.topic.startswith("/acq/timing")
    ]
    assert timing and all(t is None for t in timing)
    assert (
        "its field 'recv_ns' (string) is acq's 'recv_ns' (int64)"
        in reader._why["/acq/timing/laser"][1]
    )
    # acq's own schema with a field fewer (an older acq) is acq's
    fds = descriptor_pb2.FileDescriptorSet.FromString(SCHEMAS["foxglove.LaserScan"].data)
    scan = next(m for f in fds.file for m in f.message_type if m.name == "LaserScan")
    del scan.field[-1]  # intensities
    older = tmp_path / "older.mcap"
    mcap_copy(
        truth.files[0], older,
        schema_data=lambda s: fds.SerializeToString() if s.name == "foxglove.LaserScan" else s.data,
    )  # fmt: skip
    reader = LogReader(older)
    decoded = [reader.decode(s, c, m) for s, c, m in reader.messages() if c.topic == topic]
    assert decoded and all(d is not None and len(d.ranges) > 100 for d in decoded)


def test_a_channel_of_another_encoding_under_acqs_name_is_named(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "json.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("foxglove.LaserScan", "jsonschema", b'{"type": "object"}')
        channel = w.register_channel("/laser/scan", "json", schema)
        for t in range(3):
            w.add_message(channel, log_time=t, data=b'{"ranges": [1.0]}', publish_time=t)
        w.finish()
    reader = LogReader(path)
    with caplog.at_level(logging.WARNING):
        assert [reader.decode(s, c, m) for s, c, m in reader.messages()] == [None] * 3
    (line,) = _warnings(caplog, path)
    assert line == (
        f"{path}: /laser/scan (foxglove.LaserScan) cannot be decoded: its messages are 'json',"
        " not acq's protobuf; 3 messages skipped"
    )


@pytest.mark.parametrize(
    "command",
    [
        ["colorize", "-o", "{tmp}/c.ply", "--no-preview"],
        ["calibrate", "time-offset", "-o", "{tmp}/t.yaml"],
        ["calibrate", "validate"],
        ["analyze", "sensitivity", "-o", "{tmp}/s"],
    ],
    ids=["colorize", "time-offset", "validate", "sensitivity"],
)
def test_commands_name_a_foreign_scan_channel_and_exit_2(
    command: list[str],
    foreign_scan: tuple[Path, str, int],
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    log, topic, _ = foreign_scan
    _, calib = short_drive
    k = 1 if command[0] == "colorize" else 2
    args = [a.format(tmp=tmp_path) for a in command]
    argv = [*args[:k], str(log), "--calib", str(calib), *args[k:]]
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert "a bug?" not in err and "max()" not in err, err
    (line,) = [x for x in err.splitlines() if "no laser scan" in x]
    assert f"{topic} messages cannot be decoded: {log}: its schema is not acq's" in line, err


# --- an unusable utc_offset_ns -----------------------------------------------------------


@pytest.mark.parametrize(
    "value", ["99999999999999999999999", "nan", "1.8e18", str(2**63 - 1)],
    ids=["beyond-int64", "nan", "float", "int64-max"],
)  # fmt: skip
def test_an_unusable_utc_offset_is_said_once_and_the_clock_taken_from_the_messages(
    value: str,
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    truth, _ = short_drive
    src = truth.files[0]
    log = tmp_path / "offset.mcap"
    mcap_copy(src, log, metadata=_offset(value))
    expected = _read(src)
    with caplog.at_level(logging.WARNING):
        assert _read(log) == expected  # no message hidden, none moved
        assert _read(log) == expected
    (line,) = _warnings(caplog, log)
    assert line.startswith(f"{log}: metadata acq.utc_offset_ns: "), line
    assert "ignored" in line and "/acq/timing/" in line, line
    assert info(log).messages == len(expected)
