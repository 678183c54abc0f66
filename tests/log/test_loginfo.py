"""acq.log (reader, summary, repair): summaries of closed, cut, zero-filled, corrupt and
killed-writer logs, repair.

The logs here are written with mcap's own Writer and Foxglove's schemas plus test-only
``acq.Timing`` / ``acq.Clock`` / ``acq.Status`` messages built in a private descriptor
pool (so they cannot clash with ``acq.log.schemas``). A chunk ends every second of log
time (``Writer.flush``), as the recorder does; the expected messages of a cut file are
those of the chunks whose record lies wholly before the cut, taken from the closed
file's own chunk index.
"""

from __future__ import annotations

import json
import logging
import math
import os
import random
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from google.protobuf import descriptor_pb2, descriptor_pool, timestamp_pb2
from google.protobuf.message_factory import GetMessageClass
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.exceptions import McapError
from mcap.reader import SeekingReader, make_reader
from mcap.writer import IndexType, Writer
from mcap_protobuf.schema import register_schema

from acq.log import (
    LogError,
    LogInfo,
    format_info,
    info,
    info_many,
    read_messages,
    repair,
    schemas,
)
from acq.log.writer import LogWriter

T0 = 1_000_000_000_000  # host monotonic ns of the first message
REALTIME0 = 1_700_000_000_000_000_000  # UTC ns at T0
MS = 1_000_000
S = 1_000_000_000
SCAN_GAP = (4 * S, 4 * S + 500 * MS)  # laser scans missing strictly between these
STATUS_MISSING = 6  # the status of second 6 (at 6.5 s) is missing
# What mcap's seeking reader raises on a cut file, depending on where it was cut: it reads
# the last 37 bytes as a footer (EndOfFile, RecordLengthLimitExceeded, UnicodeDecodeError,
# struct.error) or seeks before byte 0 in a tiny file (OSError).
SEEKING_READER_FAILS = (McapError, struct.error, UnicodeDecodeError, OSError)

# --- test-only acq.* schemas -------------------------------------------------------------

_F = descriptor_pb2.FieldDescriptorProto
_TIMING = [
    ("recv_ns", _F.TYPE_INT64),
    ("device_ticks", _F.TYPE_UINT64),
    ("unwrapped_tick", _F.TYPE_INT64),
    ("epoch", _F.TYPE_UINT32),
    ("stamp_ns", _F.TYPE_INT64),
    ("offset_ns", _F.TYPE_INT64),
    ("drift_ppm", _F.TYPE_DOUBLE),
    ("uncertainty_s", _F.TYPE_DOUBLE),
    ("sequence", _F.TYPE_UINT64),
    ("received", _F.TYPE_UINT64),
    ("dropped", _F.TYPE_UINT64),
]
_DEVICE = [
    ("name", _F.TYPE_STRING),
    ("kind", _F.TYPE_STRING),
    ("connected", _F.TYPE_BOOL),
    ("rate_hz", _F.TYPE_DOUBLE),
    ("received", _F.TYPE_UINT64),
    ("dropped", _F.TYPE_UINT64),
    ("corrupt", _F.TYPE_UINT64),
    ("disconnects", _F.TYPE_UINT64),
    ("gap_s", _F.TYPE_DOUBLE),
    ("clock_offset_ns", _F.TYPE_INT64),
    ("clock_drift_ppm", _F.TYPE_DOUBLE),
    ("epoch", _F.TYPE_UINT32),
]
_STATUS = [
    ("uptime_s", _F.TYPE_DOUBLE),
    ("file", _F.TYPE_STRING),
    ("disk_free_bytes", _F.TYPE_UINT64),
    ("writer_queue", _F.TYPE_UINT32),
]


def _acq_classes(*, old: bool = False) -> dict[str, Any]:
    """Message classes acq.Timing, acq.Clock, acq.DeviceStatus, acq.Status in a private
    pool; ``old``: an older version without uncertainty_s, epoch and disconnects."""
    dropped = {"uncertainty_s", "epoch", "disconnects"} if old else set()
    fdp = descriptor_pb2.FileDescriptorProto(
        name="acq/test_old.proto" if old else "acq/test.proto",
        package="acq",
        syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name],
    )

    def add(name: str, fields: list[tuple[str, int]]) -> descriptor_pb2.DescriptorProto:
        msg = fdp.message_type.add(name=name)
        for number, (fname, ftype) in enumerate(fields, start=1):
            if fname not in dropped:
                msg.field.add(name=fname, number=number, type=ftype, label=_F.LABEL_OPTIONAL)
        return msg

    timing = add("Timing", _TIMING)
    ticks = next(f for f in timing.field if f.name == "device_ticks")
    ticks.label = _F.LABEL_REPEATED  # as acq's always was: a schema that differs is foreign
    add("Clock", [("realtime_ns", _F.TYPE_INT64), ("monotonic_ns", _F.TYPE_INT64)])
    add("DeviceStatus", _DEVICE)
    status = add("Status", _STATUS)
    status.field.add(
        name="timestamp", number=20, type=_F.TYPE_MESSAGE, type_name=".google.protobuf.Timestamp"
    )
    status.field.add(
        name="devices",
        number=21,
        type=_F.TYPE_MESSAGE,
        label=_F.LABEL_REPEATED,
        type_name=".acq.DeviceStatus",
    )
    pool = descriptor_pool.DescriptorPool()
    ts = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(ts)
    pool.Add(ts)
    pool.Add(fdp)
    return {
        n: GetMessageClass(pool.FindMessageTypeByName(f"acq.{n}"))
        for n in ("Timing", "Clock", "DeviceStatus", "Status")
    }


ACQ = _acq_classes()

# --- building logs -------------------------------------------------------------------------


@dataclass
class Built:
    path: Path
    messages: list[tuple[str, int, bytes]]  # (topic, log_time, data), in write order
    chunk_sizes: list[int]  # messages per chunk, in file order
    metadata: dict[str, dict[str, str]]


def _timing(i: int, t: int) -> Any:
    residual = 10 * MS if i % 10 == 0 else 2 * MS
    return ACQ["Timing"](
        recv_ns=t,
        stamp_ns=t - residual,
        unwrapped_tick=7_000 + 25 * i,  # a 1 kHz device clock, at the host's rate
        offset_ns=5_000 + 1_000 * i,
        drift_ppm=12.5 if i else -3.0,
        uncertainty_s={1: math.nan, 7: 5e-4}.get(i, 1e-4),  # NaN: no estimate yet
        epoch=1 if t < T0 + 5 * S else 2,
        sequence=i,
        received=i + 1,
        dropped=i // 100,
    )


def _status(second: int, classes: dict[str, Any]) -> Any:
    dev = classes["DeviceStatus"]
    devices = [
        dev(name="laser", kind="scanner", dropped=second, received=40 * second),
        dev(name="camera", kind="camera", dropped=2 * second, received=25 * second),
    ]
    if "disconnects" in dev.DESCRIPTOR.fields_by_name:
        devices[0].disconnects = 1 if second >= 8 else 0
        devices[1].disconnects = 0
    return classes["Status"](uptime_s=float(second), file="x.mcap", devices=devices)


def _events(seconds: tuple[float, float], classes: dict[str, Any]) -> list[tuple[str, int, Any]]:
    """(topic, log_time, message) of a 40 Hz scanner, a 25 Hz camera, its timing, and the
    1 Hz clock and status between ``seconds`` (s after T0), sorted by time."""
    lo, hi = int(seconds[0] * S), int(seconds[1] * S)
    ev: list[tuple[str, int, Any]] = []
    for i in range(400):
        dt = i * 25 * MS
        if not lo <= dt < hi or SCAN_GAP[0] < dt < SCAN_GAP[1]:
            continue
        scan = LaserScan(frame_id="laser", start_angle=-1.0, end_angle=1.0, ranges=[1.0 + i] * 50)
        ev.append(("/laser/scan", T0 + dt, scan))
        ev.append(("/acq/timing/laser", T0 + dt + 1, _timing(i, T0 + dt)))
    for j in range(250):
        dt = j * 40 * MS + 3 * MS
        if lo <= dt < hi:
            image = CompressedImage(frame_id="camera", format="jpeg", data=b"\xff\xd8" + bytes(300))
            ev.append(("/camera/image/compressed", T0 + dt, image))
    for k in range(10):
        dt = k * S + 2 * MS
        if lo <= dt < hi:
            clock = classes["Clock"](realtime_ns=REALTIME0 + dt, monotonic_ns=T0 + dt)
            ev.append(("/acq/clock", T0 + dt, clock))
        dt = k * S + 500 * MS
        if lo <= dt < hi and k != STATUS_MISSING:
            ev.append(("/acq/status", T0 + dt, _status(k, classes)))
    ev.sort(key=lambda e: e[1])
    start = T0 + lo
    ev[:0] = [
        ("/tf_static", start, FrameTransforms()),
        ("/camera/calibration", start, CameraCalibration(frame_id="camera", width=780)),
    ]
    return ev


def build(
    path: Path,
    seconds: tuple[float, float] = (0.0, 10.0),
    *,
    classes: dict[str, Any] = ACQ,
    indexed: bool = True,
) -> Built:
    """Write a rig log; a chunk ends at every whole second of log time."""
    metadata = {
        "acq": {"version": "0.1.0"},
        "config": {"yaml": "version: 1\n"},
        "calibration": {"yaml": "version: 1\nlaser: laser\n"},
        "clock": {"laser.tick_hz": "1000"},
    }
    with path.open("wb") as f:
        if indexed:
            writer = Writer(f, chunk_size=1 << 30)
        else:  # what the recorder leaves after a full disk: DataEnd + Footer, no summary
            writer = Writer(
                f,
                chunk_size=1 << 30,
                index_types=IndexType.NONE,
                repeat_channels=False,
                repeat_schemas=False,
                use_statistics=False,
                use_summary_offsets=False,
            )
        writer.start(profile="", library="test")
        for name, data in metadata.items():
            writer.add_metadata(name, data)
        writer.add_attachment(T0, T0, "calib.yaml", "application/yaml", b"version: 1\n")
        channels: dict[str, int] = {}
        messages: list[tuple[str, int, bytes]] = []
        chunk_sizes: list[int] = []
        in_chunk = 0
        second: int | None = None
        for topic, t, msg in _events(seconds, classes):
            if second is not None and (t - T0) // S != second and in_chunk:
                writer.flush()
                chunk_sizes.append(in_chunk)
                in_chunk = 0
            second = (t - T0) // S
            if topic not in channels:
                schema_id = register_schema(writer, type(msg))
                channels[topic] = writer.register_channel(topic, "protobuf", schema_id)
            data = msg.SerializeToString()
            writer.add_message(channels[topic], t, data, t)
            messages.append((topic, t, data))
            in_chunk += 1
        if in_chunk:
            chunk_sizes.append(in_chunk)
        writer.finish()
    return Built(path, messages, chunk_sizes, metadata)


def chunk_spans(path: Path) -> list[tuple[int, int]]:
    """(start, end) byte offsets of every chunk record, in file order (from the index)."""
    with path.open("rb") as f:
        summary = SeekingReader(f).get_summary()
        assert summary is not None
        return sorted(
            (c.chunk_start_offset, c.chunk_start_offset + c.chunk_length)
            for c in summary.chunk_indexes
        )


def expected_before(built: Built, cut: int) -> list[tuple[str, int, bytes]]:
    """The messages of the chunks whose record ends at or before byte ``cut``."""
    spans = chunk_spans(built.path)
    assert len(spans) == len(built.chunk_sizes)
    n = sum(size for (_, end), size in zip(spans, built.chunk_sizes, strict=True) if end <= cut)
    return built.messages[:n]


def read_back(path: Path) -> list[tuple[str, int, bytes]]:
    return [(c.topic, m.log_time, m.data) for _, c, m in read_messages(path)]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Built:
    return build(tmp_path_factory.mktemp("rig") / "rig.mcap")


def cut_copy(src: Path, dst: Path, cut: int, zeros: int = 0) -> Path:
    dst.write_bytes(src.read_bytes()[:cut] + bytes(zeros))
    return dst


# --- closed files ---------------------------------------------------------------------------


def test_closed_file_exact_counts_rates_gaps(rig: Built) -> None:
    i = info(rig.path)
    assert i.closed and i.problem is None
    assert i.bytes_read == i.bytes_total == rig.path.stat().st_size
    assert i.messages == len(rig.messages) == sum(rig.chunk_sizes)
    assert len(rig.chunk_sizes) == 10
    ch = {c.topic: c for c in i.channels}
    counts = {t: sum(1 for m in rig.messages if m[0] == t) for t in ch}
    assert {t: c.count for t, c in ch.items()} == counts
    assert counts["/laser/scan"] == 400 - 19 and counts["/camera/image/compressed"] == 250

    scan = ch["/laser/scan"]
    assert scan.schema == "foxglove.LaserScan"
    assert (scan.first_ns, scan.last_ns) == (T0, T0 + 399 * 25 * MS)
    assert scan.rate_hz == pytest.approx(380 / 9.975, rel=1e-12)
    assert scan.gaps == [(T0 + SCAN_GAP[0], T0 + SCAN_GAP[1])]
    assert scan.max_gap_s == pytest.approx(0.5)
    assert scan.bytes == sum(len(m[2]) for m in rig.messages if m[0] == "/laser/scan")

    camera = ch["/camera/image/compressed"]
    assert camera.rate_hz == pytest.approx(25.0, rel=1e-12)
    assert camera.gaps == [] and camera.max_gap_s == pytest.approx(0.04)

    status = ch["/acq/status"]  # 1 Hz: one missed beat is a gap
    t_before = T0 + (STATUS_MISSING - 1) * S + 500 * MS
    assert status.gaps == [(t_before, t_before + 2 * S)]
    assert ch["/acq/clock"].gaps == [] and ch["/acq/clock"].rate_hz == pytest.approx(1.0)
    assert ch["/tf_static"].count == 1 and ch["/tf_static"].rate_hz == 0.0

    assert i.start_ns == T0 and i.end_ns == i.readable_until_ns == T0 + 399 * 25 * MS + 1
    assert i.duration_s == pytest.approx(9.975)
    assert i.start_realtime_ns == REALTIME0
    assert i.metadata == rig.metadata and i.attachments == 1


def test_a_time_span_reads_only_the_chunks_that_hold_it(
    rig: Built, monkeypatch: pytest.MonkeyPatch
) -> None:
    import acq.log.mcap_records

    parsed: list[int] = []
    real = acq.log.mcap_records.chunk_messages

    def counted(chunk: Any) -> Any:
        parsed.append(chunk.message_start_time)
        return real(chunk)

    monkeypatch.setattr(acq.log.mcap_records, "chunk_messages", counted)
    span = (T0 + 3 * S + S // 2, T0 + 4 * S + S // 2)  # in chunks 3 and 4 only
    got = [(c.topic, m.log_time, m.data) for _, c, m in read_messages(rig.path, span)]
    first = sum(rig.chunk_sizes[:3])
    assert got == rig.messages[first : first + sum(rig.chunk_sizes[3:5])]
    assert [(t - T0) // S for t in parsed] == [3, 4]


def test_devices_drops_and_clock_quality(rig: Built) -> None:
    i = info(rig.path)
    assert i.drops == {"laser": 9, "camera": 18}  # the last status, second 9
    assert i.disconnects == {"laser": 1, "camera": 0}
    dev = {d.name: d for d in i.devices}
    assert set(dev) == {"laser", "camera"}
    laser = dev["laser"]
    assert laser.records == 381 and laser.epochs == 2
    assert laser.drift_ppm == 12.5
    assert laser.offset_spread_ms == pytest.approx(399 * 1_000 / 1e6)
    assert laser.uncertainty_s_median == pytest.approx(1e-4)
    assert laser.uncertainty_s_max == pytest.approx(5e-4)
    # 39 of 381 residuals are 10 ms, the rest 2 ms
    assert laser.residual_ms_p50 == pytest.approx(2.0)
    assert laser.residual_ms_p95 == pytest.approx(10.0)
    assert laser.residual_ms_max == pytest.approx(10.0)
    # the last epoch's 5 s, fitted: no drift, but a 1 ms clock pins it to 1 tick in 5 s
    assert laser.drift_fit_ppm is not None and laser.drift_ci_ppm is not None
    lo, hi = laser.drift_ci_ppm
    assert lo < laser.drift_fit_ppm < hi and lo < 0.0 < hi and hi - lo > 2 * 1e6 / 5e3
    assert dev["camera"].drift_ci_ppm is None
    assert dev["camera"].records == 0 and dev["camera"].residual_ms_p50 is None


def test_older_schema_versions_are_tolerated(tmp_path: Path) -> None:
    built = build(tmp_path / "old.mcap", classes=_acq_classes(old=True))
    # this log's timing uses the current Timing; status and clock the old file
    i = info(built.path)
    assert i.closed and i.messages == len(built.messages)
    assert i.drops == {"laser": 9, "camera": 18}
    assert i.disconnects == {}


def test_read_messages_closed_matches_writer(rig: Built) -> None:
    assert read_back(rig.path) == rig.messages


# --- cut files: SIGKILL (at any byte) and power loss (zero-filled tail) ---------------------


def _cuts(built: Built, n_random: int = 30, seed: int = 6) -> list[int]:
    size = built.path.stat().st_size
    cuts = set()
    for start, end in chunk_spans(built.path):
        cuts |= {start, start + 1, start + 9, (start + end) // 2, end - 1, end, end + 5}
    rng = random.Random(seed)
    cuts |= {rng.randrange(8, size) for _ in range(n_random)}
    cuts |= {8, 9, size - 1}
    return sorted(c for c in cuts if 8 <= c < size)


def test_cut_at_every_chunk_boundary_and_random_bytes(rig: Built, tmp_path: Path) -> None:
    for cut in _cuts(rig):
        path = cut_copy(rig.path, tmp_path / f"cut{cut}.mcap", cut)
        want = expected_before(rig, cut)
        assert read_back(path) == want, cut
        i = info(path)
        assert not i.closed, cut
        assert i.messages == len(want), cut
        assert i.problem is not None and i.problem.startswith("not closed"), i.problem
        assert i.bytes_total == cut and i.bytes_read <= cut
        if want:
            assert i.readable_until_ns == want[-1][1]
        path.unlink()


@pytest.mark.parametrize("zeros", [1, 100, 4096, 1 << 17])
def test_power_loss_zero_filled_tail(rig: Built, tmp_path: Path, zeros: int) -> None:
    spans = chunk_spans(rig.path)
    for cut in _cuts(rig, n_random=10, seed=zeros):
        path = cut_copy(rig.path, tmp_path / f"z{cut}.mcap", cut, zeros)
        want = expected_before(rig, cut)
        assert read_back(path) == want, cut
        i = info(path)
        assert not i.closed and i.messages == len(want), cut
        assert i.problem is not None and i.problem.startswith("not closed")
        if zeros >= 9 and cut in {end for _, end in spans}:  # at a record boundary
            assert f"zero-filled tail from byte {cut}" in i.problem, i.problem
        path.unlink()


def test_cut_at_last_fsync_reads_everything_before_it(rig: Built, tmp_path: Path) -> None:
    # a flush writes the chunk and then its message indexes: the file ends after those
    data = rig.path.read_bytes()
    spans = chunk_spans(rig.path)
    ends = [s for s, _ in spans[1:]]
    for k, end in enumerate(ends, start=1):
        path = cut_copy(rig.path, tmp_path / "fsync.mcap", end)
        i = info(path)
        assert i.messages == sum(rig.chunk_sizes[:k])
        assert i.bytes_read == end
        assert f"stopped at byte {end} of {end}" in (i.problem or "")
        assert "no footer" in (i.problem or "")
        path.unlink()
    assert len(data) > ends[-1]


def test_truncated_chunk_is_named_in_the_problem(rig: Built, tmp_path: Path) -> None:
    start, end = chunk_spans(rig.path)[3]
    i = info(cut_copy(rig.path, tmp_path / "mid.mcap", (start + end) // 2))
    assert i.problem is not None
    assert f"not closed: the writer stopped at byte {start} of {(start + end) // 2}" in i.problem
    assert f"truncated chunk record at byte {start}" in i.problem
    assert "read everything before it" in i.problem
    assert i.bytes_read == start and i.messages == sum(rig.chunk_sizes[:3])


def _flip_in_chunk(data: bytearray, start: int, end: int) -> None:
    data[(start + 60 + end) // 2] ^= 0xFF  # inside the compressed data


@pytest.mark.parametrize("closed", [True, False])
def test_bad_chunk_is_skipped_and_reported(rig: Built, tmp_path: Path, closed: bool) -> None:
    spans = chunk_spans(rig.path)
    data = bytearray(rig.path.read_bytes())
    _flip_in_chunk(data, *spans[2])
    if not closed:
        data = data[: spans[6][1]]
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    sizes = rig.chunk_sizes
    n = sum(sizes[:7]) if not closed else len(rig.messages)
    want = rig.messages[: sum(sizes[:2])] + rig.messages[sum(sizes[:3]) : n]
    assert read_back(path) == want
    i = info(path)
    assert i.closed is closed and i.messages == len(want)
    assert f"corrupt chunk at byte {spans[2][0]} skipped" in (i.problem or "")


@pytest.mark.parametrize("closed", [True, False])
def test_a_corrupt_chunk_is_one_warning_naming_the_file_its_time_and_the_loss(
    rig: Built, tmp_path: Path, caplog: pytest.LogCaptureFixture, closed: bool
) -> None:
    spans = chunk_spans(rig.path)
    data = bytearray(rig.path.read_bytes())
    _flip_in_chunk(data, *spans[2])
    if not closed:
        data = data[: spans[6][1]]
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING):
        info(path)  # acq info says it in its summary, not in the log
        assert not caplog.records
        read_back(path)
        read_back(path)  # a command reads a file several times: said once
        list(read_messages(path, (T0 + 2 * S, T0 + 3 * S)))
    # chunk 2 holds the messages of log time 2 s to 2.975 s (the last scan's timing)
    cut = [] if closed else [
        ("acq.log.reader", logging.WARNING,
         f"{path}: was not closed (its writer stopped): read up to 7.0 s of it"
         f" (log time {T0 * 1e-9:.3f}..{(T0 + 7 * S) * 1e-9 - 0.025:.3f} s)"),
    ]  # fmt: skip
    assert [(r.name, r.levelno, r.getMessage()) for r in caplog.records] == [
        ("acq.log.reader", logging.WARNING,
         f"{path}: 1 corrupt chunk skipped (2.0..3.0 s into the file, "
         f"{rig.chunk_sizes[2]} messages lost)"),
        *cut,
    ]  # fmt: skip


def test_info_shows_each_cameras_frames_of_an_unexpected_size(rig: Built, tmp_path: Path) -> None:
    """From the last /acq/status (the recorder's counts); an older log's status has no
    such field and reads as before."""
    writer = LogWriter(tmp_path, prefix="odd")
    writer.add_channel("/acq/status", schemas.SCHEMAS["acq.Status"])
    for second, odd in ((1, 1), (2, 3)):
        devices = [
            schemas.DeviceStatus("laser", "scanner", received=40),
            schemas.DeviceStatus("camera", "camera", received=25, odd_size=odd),
        ]
        status = schemas.status(timestamp_ns=second * S, uptime_s=second, devices=devices)
        writer.write("/acq/status", status, second * S, second * S)
    writer.close()
    i = info(writer.files[0])
    assert i.odd_size == {"camera": 3}
    assert (
        "  warning: frames of an unexpected size (recorded, flagged): camera 3"
        in format_info(i).splitlines()
    )
    assert json.loads(format_info(i, json=True))[0]["odd_size"] == {"camera": 3}
    old = info(build(tmp_path / "old.mcap", classes=_acq_classes(old=True)).path)
    assert old.odd_size == {} and info(rig.path).odd_size == {}
    assert "unexpected size" not in format_info(old)


def test_footer_without_summary_is_read_linearly(tmp_path: Path) -> None:
    built = build(tmp_path / "unindexed.mcap", indexed=False)
    assert read_back(built.path) == built.messages
    i = info(built.path)
    assert not i.closed and i.messages == len(built.messages)
    assert i.bytes_read == i.bytes_total
    assert i.problem is not None and i.problem.startswith("not indexed")
    assert "no summary section" in i.problem and i.metadata == built.metadata


# --- repair ---------------------------------------------------------------------------------


def _seeking(path: Path) -> tuple[list[tuple[str, int, bytes]], Any, list[Any], list[Any]]:
    with path.open("rb") as f:
        reader = make_reader(f)
        assert isinstance(reader, SeekingReader)
        summary = reader.get_summary()
        msgs = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
        return msgs, summary, list(reader.iter_metadata()), list(reader.iter_attachments())


@pytest.mark.parametrize("zeros", [0, 5000])
def test_repair_gives_an_indexed_file(rig: Built, tmp_path: Path, zeros: int) -> None:
    spans = chunk_spans(rig.path)
    cut = (spans[7][0] + spans[7][1]) // 2
    src = cut_copy(rig.path, tmp_path / "cut.mcap", cut, zeros)
    with pytest.raises(SEEKING_READER_FAILS):
        with src.open("rb") as f:
            list(make_reader(f).iter_messages())
    dst = tmp_path / "cut.repaired.mcap"
    want = rig.messages[: sum(rig.chunk_sizes[:7])]
    assert repair(src, dst) == len(want)
    msgs, summary, metadata, attachments = _seeking(dst)
    assert msgs == want  # log-time order is also the write order here
    assert summary is not None and summary.chunk_indexes
    assert summary.statistics is not None and summary.statistics.message_count == len(want)
    marks = {"acq.repair": {"source": "cut.mcap", "source_bytes": str(src.stat().st_size)}}
    assert {m.name: m.metadata for m in metadata} == {**marks, **rig.metadata}
    assert [(a.name, a.data) for a in attachments] == [("calib.yaml", b"version: 1\n")]
    repaired = info(dst)
    assert repaired.closed and repaired.problem is None and repaired.messages == len(want)
    with pytest.raises(FileExistsError):
        repair(src, dst)
    assert info(dst).messages == len(want)  # untouched


def test_repair_of_a_closed_file_keeps_everything(rig: Built, tmp_path: Path) -> None:
    dst = tmp_path / "copy.mcap"
    assert repair(rig.path, dst) == len(rig.messages)
    assert _seeking(dst)[0] == rig.messages
    a, b = info(rig.path), info(dst)
    assert [(c.topic, c.count, c.gaps) for c in a.channels] == [
        (c.topic, c.count, c.gaps) for c in b.channels
    ]
    assert (a.drops, a.devices) == (b.drops, b.devices)


# --- a real writer, SIGKILLed ---------------------------------------------------------------

_CHILD = r"""
import os, sys, time
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan
from mcap.writer import Writer
from mcap_protobuf.schema import register_schema

f = open(sys.argv[1], "wb")
w = Writer(f, chunk_size=1 << 30)
w.start(library="killed-writer-test")
w.add_metadata("acq", {"version": "test"})
channel = w.register_channel("/laser/scan", "protobuf", register_schema(w, LaserScan))
i, last_sync = 0, time.monotonic()
while True:
    t = time.monotonic_ns()
    scan = LaserScan(frame_id="laser", ranges=[float(i)] * 200)
    w.add_message(channel, t, scan.SerializeToString(), t, sequence=i)
    i += 1
    if time.monotonic() - last_sync >= 0.2:
        w.flush()
        f.flush()
        os.fsync(f.fileno())
        last_sync = time.monotonic()
        print(i, t, flush=True)
    time.sleep(0.002)
"""


@pytest.mark.realtime  # killed between two syncs: the rest of this module keeps no time
def test_sigkilled_writer(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(path)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    progress: list[tuple[int, int]] = []
    try:
        deadline = time.monotonic() + 60
        while len(progress) < 6 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            n, t = line.split()
            progress.append((int(n), int(t)))
        assert len(progress) >= 6, "the writer made no progress"
        time.sleep(0.1)  # kill it between two syncs, with messages in its open chunk
    finally:
        proc.send_signal(signal.SIGKILL)
        kill_ns = time.monotonic_ns()
        rest = proc.stdout.read()
        proc.wait()
    for line in rest.splitlines():
        n, t = line.split()
        progress.append((int(n), int(t)))
    synced, synced_t = progress[-1]

    msgs = list(read_messages(path))
    assert len(msgs) >= synced  # every message before the last fsync
    assert [m.sequence for _, _, m in msgs] == list(range(len(msgs)))  # nothing garbled
    assert msgs[synced - 1][2].log_time == synced_t
    assert msgs[-1][2].log_time >= kill_ns - 1.2 * S  # all messages older than 1.2 s
    scan = LaserScan()
    scan.ParseFromString(msgs[-1][2].data)
    assert scan.ranges[0] == float(len(msgs) - 1)

    i = info(path)
    assert not i.closed and i.messages == len(msgs)
    assert i.problem is not None and i.problem.startswith("not closed")
    assert i.metadata == {"acq": {"version": "test"}}
    with pytest.raises(SEEKING_READER_FAILS):  # what `acq info --repair` is for
        with path.open("rb") as f:
            list(make_reader(f).iter_messages())
    dst = tmp_path / "killed.repaired.mcap"
    assert repair(path, dst) == len(msgs)
    with dst.open("rb") as f:
        again = [m.sequence for _, _, m in make_reader(f).iter_messages()]
    assert again == list(range(len(msgs)))


# --- sessions, output, errors ---------------------------------------------------------------


def test_info_many_gives_a_session_summary(tmp_path: Path) -> None:
    a = build(tmp_path / "s_000.mcap", (0.0, 5.0))
    b = build(tmp_path / "s_001.mcap", (5.0, 10.0))
    b_cut = cut_copy(b.path, tmp_path / "s_002.mcap", chunk_spans(b.path)[2][0])
    infos = info_many([a.path, b_cut])
    assert len(infos) == 3
    first, second, session = infos
    assert first.closed and not second.closed and not session.closed
    assert session.files == (a.path, b_cut) and session.path == tmp_path.resolve()
    assert session.messages == first.messages + second.messages
    assert second.messages == sum(b.chunk_sizes[:2])
    scan = {c.topic: c for c in session.channels}["/laser/scan"]
    assert scan.gaps == [(T0 + SCAN_GAP[0], T0 + SCAN_GAP[1])]
    assert scan.first_ns == T0 and scan.count == sum(
        1 for m in a.messages + b.messages[: sum(b.chunk_sizes[:2])] if m[0] == "/laser/scan"
    )
    assert session.problem is not None and session.problem.startswith("s_002.mcap: not closed")
    assert len(info_many([a.path])) == 1


def test_format_info_human_and_json(rig: Built, tmp_path: Path) -> None:
    start, end = chunk_spans(rig.path)[5]
    cut = cut_copy(rig.path, tmp_path / "cut.mcap", (start + end) // 2)
    infos = [info(rig.path), info(cut)]
    text = format_info(infos)
    assert f"{rig.path}: closed" in text
    assert f"{cut}: NOT CLOSED" in text
    assert f"warning: not closed: the writer stopped at byte {start}" in text
    laser = next(line for line in text.splitlines() if line.strip().startswith("/laser/scan "))
    assert laser.split()[1:4] == ["foxglove.LaserScan", "381", "38.10"]
    assert "gaps on /laser/scan (s from start): 4.000..4.500 s" in text
    dev = next(line for line in text.splitlines() if line.strip().startswith("laser "))
    assert dev.split()[:5] == ["laser", "9", "1", "381", "2"]
    assert "2023-11-14 22:13:20.000 UTC" in text  # REALTIME0

    data = json.loads(format_info(infos, json=True))
    assert [d["closed"] for d in data] == [True, False]
    assert data[1]["problem"].startswith("not closed")
    chan = {c["topic"]: c for c in data[0]["channels"]}
    assert chan["/laser/scan"]["count"] == 381
    assert chan["/laser/scan"]["gaps"] == [[T0 + SCAN_GAP[0], T0 + SCAN_GAP[1]]]
    assert data[0]["drops"] == {"laser": 9, "camera": 18}
    assert data[0]["metadata"]["acq"] == {"version": "0.1.0"}
    assert isinstance(infos[0], LogInfo) and format_info(infos[0]) == text.split("\n\n")[0]


def test_log_errors(tmp_path: Path) -> None:
    missing = tmp_path / "missing.mcap"
    with pytest.raises(LogError, match=r"missing\.mcap: no such file$"):
        info(missing)
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(random.Random(1).randbytes(5000))
    with pytest.raises(LogError, match=r"garbage\.mcap: not an MCAP file: bad magic [^(]*$"):
        info(garbage)
    with pytest.raises(LogError, match=r"garbage\.mcap"):
        read_messages(garbage)  # at once, not on first iteration
    dst = tmp_path / "out.mcap"
    with pytest.raises(LogError):
        repair(garbage, dst)
    assert not dst.exists()
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(LogError, match="empty file"):
        info(empty)
    assert issubclass(LogError, ValueError)


def test_garbage_after_the_magic_stops_cleanly(tmp_path: Path) -> None:
    path = tmp_path / "g.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + random.Random(2).randbytes(20000))
    i = info(path)
    assert not i.closed and i.messages == 0 and i.problem is not None
    assert os.path.getsize(path) == i.bytes_total


# --- the chunk parser of closed files --------------------------------------------------


def _chunk_of(records: bytes, compression: str = "") -> Any:
    import zlib

    import zstandard
    from mcap.records import Chunk

    data = zstandard.ZstdCompressor().compress(records) if compression == "zstd" else records
    return Chunk(compression=compression, data=data, message_end_time=0, message_start_time=0,
                 uncompressed_crc=zlib.crc32(records), uncompressed_size=len(records))  # fmt: skip


def test_chunk_messages_match_mcaps_own_parser() -> None:
    from mcap.records import Message
    from mcap.stream_reader import breakup_chunk

    from acq.log.mcap_records import chunk_messages

    rng = random.Random(3)
    body = b""
    for i in range(200):
        payload = rng.randbytes(rng.randrange(0, 300))
        msg = struct.pack("<HIQQ", i % 3, i, 10**9 + i, 2 * 10**9 + i) + payload
        body += struct.pack("<BQ", 0x05, len(msg)) + msg
        if i % 50 == 0:  # a record of another kind in between
            body += struct.pack("<BQ", 0x7F, 4) + b"abcd"
    for compression in ("", "zstd"):
        chunk = _chunk_of(body, compression)
        ours = chunk_messages(chunk)
        theirs = [r for r in breakup_chunk(chunk, validate_crc=True) if isinstance(r, Message)]
        assert ours == theirs and len(ours) == 200


@given(st.binary(max_size=400))
@settings(max_examples=300, deadline=None)
def test_chunk_messages_of_any_bytes_are_messages_or_a_typed_error(data: bytes) -> None:
    from acq.log.mcap_records import chunk_messages

    try:
        chunk_messages(_chunk_of(data))
    except McapError:
        pass
