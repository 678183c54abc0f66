"""acq.log.writer: standalone rolling files, sync survives a kill, a full disk is reported."""

from __future__ import annotations

import errno
import io
import os
import random
import re
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory

from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import Equidistant
from acq.log import schemas, writer
from acq.log.reader import LogReader
from acq.log.timebase import MONOTONIC, TimeBase, measure_utc_offset_ns
from acq.log.writer import LogWriter

ROOT = Path(__file__).resolve().parents[2]
CLOCK = "/acq/clock"
RAW = "/laser/raw"
TF = "/tf_static"
CALIB = "/camera/calibration"
LATCHED = {TF, CALIB}
CAL = Calibration(cameras={"camera": CameraCalib(Equidistant.from_f(169.3, 390, 291, 780, 582))})
NAME = re.compile(r"^acq_\d{8}T\d{6}Z_(\d{3})\.mcap$")

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


def clock_msg(i: int) -> bytes:
    """Message number ``i``: its realtime_ns carries ``i``."""
    return schemas.clock(realtime_ns=i, monotonic_ns=10**9 + i)


def raw_msg(i: int, size: int = 200) -> bytes:
    """Incompressible, so file sizes follow what was written."""
    return schemas.raw_telegram(device="laser", data=os.urandom(size), recv_ns=i, sequence=i)


def number(channel_topic: str, data: bytes) -> int:
    if channel_topic == CLOCK:
        return int(schemas.decode("acq.Clock", data).realtime_ns)
    return int(schemas.decode("acq.RawTelegram", data).sequence)


META = {"config": {"version": "1"}, "software": {"acq": "test"}}
# what a file's metadata says: the writer adds the time base (here host monotonic, so the
# times the tests give are the times in the file)
WRITTEN_META = {**META, "acq": MONOTONIC.metadata()}


def new_writer(directory: Path, **kw: Any) -> LogWriter:
    kw.setdefault("metadata", META)
    kw.setdefault("time_base", MONOTONIC)
    w = LogWriter(directory, **kw)
    w.add_channel(CLOCK, schemas.SCHEMAS["acq.Clock"])
    w.add_channel(RAW, schemas.SCHEMAS["acq.RawTelegram"], {"device": "laser"})
    w.add_channel(TF, schemas.SCHEMAS["foxglove.FrameTransforms"])
    w.add_channel(CALIB, schemas.SCHEMAS["foxglove.CameraCalibration"])
    w.set_latched(TF, lambda t: schemas.frame_transforms(CAL, t), 5)
    w.set_latched(CALIB, schemas.camera_calibration(CAL.camera(), "camera", 5), 5)
    return w


def linear(data: bytes) -> list[Any]:
    """Records of a possibly cut file, as a linear reader sees them up to the cut.

    mcap's StreamReader ends with EndOfFile at a cut, or struct.error when the cut falls
    inside a record's fixed-size opcode/length header.
    """
    out: list[Any] = []
    try:
        for record in StreamReader(io.BytesIO(data)).records:
            out.append(record)
    except (EndOfFile, struct.error):
        pass
    return out


def linear_numbers(data: bytes) -> list[int]:
    records = linear(data)
    topics = {r.id: r.topic for r in records if isinstance(r, Channel)}
    return [
        number(topics[r.channel_id], r.data)
        for r in records
        if isinstance(r, Message) and topics[r.channel_id] not in LATCHED
    ]


def read_file(path: Path) -> list[tuple[str, int, int, Any]]:
    """(topic, log_time, publish_time, decoded) of every message, by the seeking reader."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [
            (channel.topic, message.log_time, message.publish_time, decoded)
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False)
        ]


def assert_file_starts_standalone(path: Path, metadata: dict[str, dict[str, str]]) -> str:
    """Header, the metadata, every channel and the latched messages before any data; the
    session its ``acq`` record names (the writer's start and a random suffix)."""
    records = linear(path.read_bytes())
    assert isinstance(records[0], Header)
    first_data = next(
        i
        for i, r in enumerate(records)
        if isinstance(r, Message)
        and r.channel_id
        in {c.id for c in records if isinstance(c, Channel) and c.topic not in LATCHED}
    )
    head = records[:first_data]
    found = {r.name: dict(r.metadata) for r in head if isinstance(r, Metadata)}
    session = found["acq"].pop("session")
    assert re.fullmatch(r"\d{8}T\d{6}Z-[0-9a-f]{8}", session)
    assert found == metadata
    assert {r.topic for r in head if isinstance(r, Channel)} == {CLOCK, RAW, TF, CALIB}
    assert {r.name for r in head if isinstance(r, Schema)} == {
        "acq.Clock",
        "acq.RawTelegram",
        "foxglove.FrameTransforms",
        "foxglove.CameraCalibration",
    }
    topics = {r.id: r.topic for r in head if isinstance(r, Channel)}
    assert sorted(topics[r.channel_id] for r in head if isinstance(r, Message)) == sorted(LATCHED)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert {c.topic for c in summary.channels.values()} == {CLOCK, RAW, TF, CALIB}
        indexed = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        assert indexed["acq"].pop("session") == session
        assert indexed == metadata
    return session


# --- layout and decoding -------------------------------------------------------------------


def test_a_file_opens_decodes_and_is_named(tmp_path: Path) -> None:
    w = new_writer(tmp_path / "new" / "dir", profile="")
    for i in range(20):
        w.write(CLOCK, clock_msg(i), 1000 + i, 1000 + i)
        w.write(RAW, raw_msg(i), 1000 + i, 990 + i)
    assert w.messages == 40
    path = w.path
    assert path is not None and NAME.match(path.name) and path.name.endswith("_000.mcap")
    assert w.close() is None
    assert w.close() is None and w.path is None  # idempotent
    assert w.files == [path] and w.bytes_written == path.stat().st_size
    assert_file_starts_standalone(path, WRITTEN_META)

    msgs = read_file(path)
    data = [m for m in msgs if m[0] not in LATCHED]
    assert [(t, number(t, d.SerializeToString())) for t, _, _, d in data] == [
        (topic, i) for i in range(20) for topic in (CLOCK, RAW)
    ]
    assert [(lt, pt) for t, lt, pt, _ in data if t == RAW] == [
        (1000 + i, 990 + i) for i in range(20)
    ]
    latched = {t: (lt, pt, d) for t, lt, pt, d in msgs if t in LATCHED}
    assert latched[TF][:2] == (5, 5) and latched[CALIB][:2] == (5, 5)
    assert latched[TF][2].transforms[0].child_frame_id == "camera"
    assert latched[CALIB][2].distortion_model == "kannala_brandt"
    # the same bytes decode with acq.log.schemas
    with open(path, "rb") as f:
        for schema, _, message in make_reader(f).iter_messages():
            assert schema is not None
            msg = schemas.decode(schema.name, message.data)
            assert msg.SerializeToString() == message.data
        f.seek(0)
        header = make_reader(f).get_header()
        assert header.library.startswith("acq/") and header.profile == ""


def test_times_are_utc_from_one_offset_and_read_back_as_host_monotonic(tmp_path: Path) -> None:
    """By default a log's log_time, publish_time and Foxglove timestamps are UTC: host
    monotonic plus one offset measured when the writer starts, named in the ``acq``
    metadata; acq.* messages keep host monotonic. LogReader gives host monotonic back."""
    w = LogWriter(tmp_path, metadata={"acq": {"version": "x"}})
    mono = time.monotonic_ns()
    offset = w.time_base.utc_offset_ns
    assert w.time_base.utc and abs(offset - measure_utc_offset_ns()) < 1_000_000
    w.add_channel(CLOCK, schemas.SCHEMAS["acq.Clock"])
    w.add_channel(TF, schemas.SCHEMAS["foxglove.FrameTransforms"])
    w.add_channel("/laser/scan", schemas.SCHEMAS["foxglove.LaserScan"])
    w.set_latched(TF, lambda t: schemas.frame_transforms(CAL, t), mono)
    clock = schemas.clock(realtime_ns=time.time_ns(), monotonic_ns=mono)
    w.write(CLOCK, clock, mono, mono)
    w.write("/laser/scan", schemas.message_class("foxglove.LaserScan")(
        timestamp={"seconds": 0, "nanos": 0}).SerializeToString(), mono + 2, mono + 1)  # fmt: skip
    w.close()
    (path,) = w.files
    with open(path, "rb") as f:  # as any MCAP reader sees it: today's date
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["acq"]["version"] == "x" and meta["acq"]["utc_offset_ns"] == str(offset)
        assert "UTC" in meta["acq"]["clock"]
        got = {c.topic: (m.log_time, m.publish_time, d) for _, c, m, d in
               reader.iter_decoded_messages(log_time_order=False)}  # fmt: skip
    assert abs(got[CLOCK][0] - time.time_ns()) < 60 * 10**9
    assert got[CLOCK][:2] == (mono + offset, mono + offset)
    assert got[CLOCK][2].monotonic_ns == mono  # acq.*: host monotonic
    tf = got[TF][2].transforms[0].timestamp
    assert got[TF][:2] == (mono + offset,) * 2 and tf.ToNanoseconds() == mono + offset
    reader = LogReader(path)
    back = {}
    for schema, channel, message in reader.messages():
        back[channel.topic] = (message.log_time, message.publish_time,
                               reader.decode(schema, channel, message))  # fmt: skip
    assert reader.time_base == w.time_base
    assert back[CLOCK][:2] == (mono, mono) and back[CLOCK][2].monotonic_ns == mono
    assert back[TF][:2] == (mono, mono)
    assert back[TF][2].transforms[0].timestamp.ToNanoseconds() == mono
    assert back["/laser/scan"][:2] == (mono + 2, mono + 1)
    assert back["/laser/scan"][2].timestamp.ToNanoseconds() == -offset  # 0 was written
    # a window in host monotonic time reads the chunk; one outside it does not
    assert len(list(LogReader(path, (mono, mono + 2)).messages())) == 3
    assert list(LogReader(path, (mono + 10, mono + 20)).messages()) == []


def test_a_bad_time_base_is_an_input_error() -> None:
    """(The reader reads such a log on the clock its messages show:
    tests/log/test_foreign_logs.py.)"""
    from acq.errors import InputValueError

    assert TimeBase.of_metadata({}) == MONOTONIC
    for bad in ("soon", "nan", "1e18", str(2**63)):
        with pytest.raises(InputValueError, match=r"acq\.utc_offset_ns: '.*' is not an integer"):
            TimeBase.of_metadata({"acq": {"utc_offset_ns": bad}})
    assert TimeBase.of_metadata({"acq": {"utc_offset_ns": str(2**63 - 1)}}).utc


def test_writer_errors_are_clear(tmp_path: Path) -> None:
    w = new_writer(tmp_path)
    with pytest.raises(KeyError, match="no channel '/nope'"):
        w.write("/nope", b"", 1, 1)
    with pytest.raises(ValueError, match="already registered"):
        w.add_channel(CLOCK, schemas.SCHEMAS["acq.Clock"])
    with pytest.raises(ValueError, match="compression"):
        LogWriter(tmp_path, compression="gzip")
    w.close()
    with pytest.raises(ValueError, match="closed"):
        w.write(CLOCK, clock_msg(0), 1, 1)


def test_never_overwrites(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(writer.time, "strftime", lambda fmt, t: "20240101T000000Z")
    taken = tmp_path / "acq_20240101T000000Z_000.mcap"
    taken.write_bytes(b"an earlier session")
    w = new_writer(tmp_path)
    w.write(CLOCK, clock_msg(0), 1, 1)
    w.close()
    assert taken.read_bytes() == b"an earlier session"
    assert [p.name for p in w.files] == ["acq_20240101T000000Z_001.mcap"]


# --- sync and crash safety -----------------------------------------------------------------


def test_sync_ends_the_open_chunk(tmp_path: Path) -> None:
    """Pins mcap's Writer.flush(): it writes a chunk well below chunk_size."""
    w = new_writer(tmp_path, chunk_size=8 << 20)
    path = w.path
    assert path is not None
    for i in range(3):
        w.write(CLOCK, clock_msg(i), i, i)
    before = path.stat().st_size
    assert linear_numbers(path.read_bytes()) == []  # still in the open chunk
    w.sync()
    assert path.stat().st_size > before
    assert linear_numbers(path.read_bytes()) == [0, 1, 2]
    w.sync()  # nothing new: no empty chunk
    after = path.stat().st_size
    w.sync()
    assert path.stat().st_size == after
    w.close()


def test_maybe_sync_follows_the_interval(tmp_path: Path) -> None:
    w = new_writer(tmp_path, sync_interval_s=1.0)
    path = w.path
    assert path is not None
    w.write(CLOCK, clock_msg(0), 0, 0)
    w.maybe_sync(10**9)  # first call syncs
    assert linear_numbers(path.read_bytes()) == [0]
    w.write(CLOCK, clock_msg(1), 1, 1)
    w.maybe_sync(10**9 + 999_999_999)
    assert linear_numbers(path.read_bytes()) == [0]
    w.maybe_sync(2 * 10**9)
    assert linear_numbers(path.read_bytes()) == [0, 1]
    w.close()


def test_a_cut_file_keeps_everything_synced(tmp_path: Path) -> None:
    w = new_writer(tmp_path, chunk_size=4096)
    path = w.path
    assert path is not None
    for i in range(150):
        w.write(RAW, raw_msg(i), i, i)
    w.sync()
    synced = path.read_bytes()
    for i in range(150, 400):  # more chunks, written as they fill, then the summary
        w.write(RAW, raw_msg(i), i, i)
    w.close()
    full = path.read_bytes()
    assert full[: len(synced)] == synced
    rng = random.Random(4)
    cuts = [len(synced), len(full), *(rng.randint(len(synced), len(full)) for _ in range(60))]
    for cut in cuts:
        got = linear_numbers(full[:cut])
        assert got == list(range(len(got))), cut  # in order, no duplicates
        assert len(got) >= 150, cut
    assert linear_numbers(full) == list(range(400))


CHILD = """
import sys
from pathlib import Path
from acq.log import schemas
from acq.log.writer import LogWriter

w = LogWriter(Path(sys.argv[1]), chunk_size=1 << 20)
w.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
i = 0
while True:
    w.write("/acq/clock", schemas.clock(realtime_ns=i, monotonic_ns=i), i, i)
    i += 1
    if i % 100 == 0:
        w.sync()
        print(i, flush=True)
"""


def test_sigkill_loses_nothing_before_the_last_sync(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(tmp_path)], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert child.stdout is not None
        synced = 0
        deadline = time.monotonic() + 60
        while synced < 3000 and time.monotonic() < deadline:
            line = child.stdout.readline()
            if not line:
                break
            synced = int(line)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    assert synced >= 3000
    (path,) = tmp_path.glob("*.mcap")
    records = linear(path.read_bytes())
    got = [
        schemas.decode("acq.Clock", r.data).realtime_ns for r in records if isinstance(r, Message)
    ]
    assert got[:synced] == list(range(synced))
    assert got == list(range(len(got)))


# --- rollover ------------------------------------------------------------------------------


def test_rollover_by_size(tmp_path: Path) -> None:
    split = 20_000
    w = new_writer(tmp_path, split_bytes=split, chunk_size=4096)
    for i in range(500):
        w.write(RAW if i % 2 else CLOCK, raw_msg(i) if i % 2 else clock_msg(i), 10**9 + i, i)
        w.maybe_sync(10**9 + i * 10**7)
    assert w.close() is None
    files = w.files
    assert len(files) >= 3
    assert [int(NAME.match(p.name).group(1)) for p in files] == list(range(len(files)))  # type: ignore[union-attr]
    assert sorted(tmp_path.iterdir()) == files
    assert w.bytes_written == sum(p.stat().st_size for p in files)
    seen: list[int] = []
    for k, path in enumerate(files):
        msgs = read_file(path)
        numbers = [number(t, d.SerializeToString()) for t, _, _, d in msgs if t not in LATCHED]
        assert numbers, path
        seen += numbers
        if k < len(files) - 1:
            assert split * 0.9 < path.stat().st_size < split + 4096 + 8000, path
        # every part names the one session
        assert assert_file_starts_standalone(path, WRITTEN_META) == w.session
        # latched messages carry the file's start: its first data message's log time
        first = min(lt for t, lt, _, _ in msgs if t not in LATCHED)
        for t, lt, pt, d in msgs:
            if t in LATCHED:
                assert (lt, pt) == ((5, 5) if k == 0 else (first, first))
                if t == TF:
                    stamp = d.transforms[0].timestamp
                    assert stamp.seconds * 10**9 + stamp.nanos == (5 if k == 0 else first)
    assert seen == list(range(500))
    assert w.messages == 500


def test_rollover_by_duration(tmp_path: Path) -> None:
    w = new_writer(tmp_path, split_s=1.0)
    t0 = 7 * 10**9
    for i in range(55):  # every 0.1 s for 5.5 s
        w.write(CLOCK, clock_msg(i), t0 + i * 100_000_000, t0 + i * 100_000_000)
    w.close()
    assert len(w.files) == 6
    for k, path in enumerate(w.files):
        data = [(lt, d.realtime_ns) for t, lt, _, d in read_file(path) if t == CLOCK]
        assert [n for _, n in data] == list(range(10 * k, min(10 * k + 10, 55)))
        assert data[0][0] == t0 + k * 10**9
        assert data[-1][0] - data[0][0] < 10**9


def test_metadata_updates_reach_the_current_and_later_files(tmp_path: Path) -> None:
    w = new_writer(tmp_path, split_s=1.0, metadata={"config": {"v": "1"}})
    w.write(CLOCK, clock_msg(0), 0, 0)
    w.update_metadata("calibration", {"yaml": "new"})
    w.update_metadata("config", {"v": "2"})
    w.write(CLOCK, clock_msg(1), 2 * 10**9, 0)  # rolls over
    w.close()
    first, second = w.files
    with open(first, "rb") as f:
        records = [(m.name, m.metadata) for m in make_reader(f).iter_metadata()]
    acq = ("acq", {"session": w.session, **MONOTONIC.metadata()})  # first: the time base
    assert records == [
        acq,
        ("config", {"v": "1"}),
        ("calibration", {"yaml": "new"}),
        ("config", {"v": "2"}),
    ]
    with open(second, "rb") as f:
        records = [(m.name, m.metadata) for m in make_reader(f).iter_metadata()]
    assert records == [acq, ("config", {"v": "2"}), ("calibration", {"yaml": "new"})]


# --- a full disk ---------------------------------------------------------------------------


def fill_disk_at(monkeypatch: pytest.MonkeyPatch, limit: int) -> None:
    """Writes past ``limit`` bytes of a file fail with ENOSPC after a partial write, as a
    full filesystem does."""
    real = writer._File.write_pieces

    def write_pieces(self: writer._File, pieces: list[bytes]) -> int:
        data = b"".join(pieces)
        room = limit - self.pos
        if len(data) > room:
            if room > 0:
                self.pos += os.write(self.fd, memoryview(data)[:room])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, pieces)

    monkeypatch.setattr(writer._File, "write_pieces", write_pieces)


def write_until_full(w: LogWriter) -> tuple[int, int]:
    """Write and sync every 10 messages until ENOSPC; (messages synced, messages sent)."""
    synced = 0
    for i in range(10_000):
        try:
            w.write(RAW, raw_msg(i), i, i)
            if i % 10 == 9:
                w.sync()
                synced = i + 1
        except OSError as e:
            assert e.errno == errno.ENOSPC
            return synced, i + 1
    raise AssertionError("the disk never filled")


def test_disk_full_is_raised_then_close_keeps_a_readable_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fill_disk_at(monkeypatch, 30_000)
    w = new_writer(tmp_path, chunk_size=2048)
    path = w.path
    assert path is not None
    synced, sent = write_until_full(w)
    assert synced >= 50
    assert isinstance(w.error, OSError)
    with pytest.raises(OSError, match="earlier error") as e:
        w.write(RAW, raw_msg(sent), 0, 0)
    assert e.value.errno == errno.ENOSPC
    with pytest.raises(OSError):
        w.sync()
    report = w.close()
    assert report is not None and path.name in report and "No space left" in report
    assert "ended without index" in report
    assert w.close() == report
    got = linear_numbers(path.read_bytes())
    assert got == list(range(len(got))) and len(got) >= synced
    # a complete (index-less) MCAP: the seeking reader reads it too
    numbers = [
        number(t, d.SerializeToString()) for t, _, _, d in read_file(path) if t not in LATCHED
    ]
    assert numbers == got
    assert path.read_bytes().endswith(writer.MCAP0_MAGIC)


def test_disk_full_without_room_for_an_end_marker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fill_disk_at(monkeypatch, 30_000)

    def no_room(fd: int, data: bytes, offset: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(writer, "_pwrite_all", no_room)
    w = new_writer(tmp_path, chunk_size=2048)
    path = w.path
    assert path is not None
    synced, _ = write_until_full(w)
    report = w.close()
    assert report is not None and "without end marker" in report
    got = linear_numbers(path.read_bytes())
    assert got == list(range(len(got))) and len(got) >= synced


def test_disk_full_while_closing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    w = new_writer(tmp_path, chunk_size=1 << 20)
    path = w.path
    assert path is not None
    for i in range(50):
        w.write(RAW, raw_msg(i), i, i)
    w.sync()
    for i in range(50, 60):
        w.write(RAW, raw_msg(i), i, i)
    fill_disk_at(monkeypatch, path.stat().st_size + 1000)  # the last chunk does not fit
    with pytest.raises(OSError) as e:
        w.close()
    assert e.value.errno == errno.ENOSPC
    report = w.close()  # does not raise again
    assert report is not None and any(report in note for note in e.value.__notes__)
    got = linear_numbers(path.read_bytes())
    assert got == list(range(50))
    numbers = [
        number(t, d.SerializeToString()) for t, _, _, d in read_file(path) if t not in LATCHED
    ]
    assert numbers == got


def test_disk_full_at_the_first_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fill_disk_at(monkeypatch, 20)  # not even the header fits
    with pytest.raises(OSError) as e:
        LogWriter(tmp_path)
    assert e.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == []  # no empty .mcap left behind
