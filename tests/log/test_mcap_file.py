"""acq.log.mcap_file: the same records as mcap's own Writer, image chunks stored as they are.

The JPEGs are the real fisheye captures of ../shared/data; the reference is mcap's
``Writer`` as the recorder used it before (zstd chunks, every index, CRCs).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as LibraryWriter

from acq.log import info_many, schemas
from acq.log.mcap_file import McapFile
from acq.log.reader import LogReader
from acq.log.writer import INCOMPRESSIBLE, LogWriter, _File
from acq.records import Frame

CHANNELS = [
    ("/camera/image/compressed", "foxglove.CompressedImage"),
    ("/laser/raw", "acq.RawTelegram"),
    ("/acq/clock", "acq.Clock"),
]


def _jpegs(shared_dir: Path) -> list[bytes]:
    paths = sorted((shared_dir / "data" / "fisheye").glob("*.jpg"))
    if not paths:
        pytest.skip("no fisheye JPEGs in ../shared/data/fisheye")
    return [p.read_bytes() for p in paths]


def _messages(jpegs: list[bytes]) -> list[tuple[str, bytes, int]]:
    """(topic, data, log time ns): a second of clock and telegrams alone (a chunk that
    compresses), then frames among telegrams, as a rig records them."""
    out: list[tuple[str, bytes, int]] = []
    t = 1_000_000_000
    for i in range(40):
        out.append(("/acq/clock", schemas.clock(realtime_ns=i, monotonic_ns=t), t))
        raw = schemas.raw_telegram(device="laser", data=bytes(range(200)) * 5, recv_ns=t,
                                   sequence=i)  # fmt: skip
        out.append(("/laser/raw", raw, t))
        t += 25_000_000
    out.append(("sync", b"", t))
    for k in range(15):
        jpeg = jpegs[k % len(jpegs)]
        frame = Frame(recv_ns=t, stamp_ns=t - 5_000_000, sequence=k, width=780, height=582,
                      jpeg=jpeg)  # fmt: skip
        out.append(("/camera/image/compressed", schemas.compressed_image(frame, "camera", t), t))
        for j in range(3):
            raw = schemas.raw_telegram(device="laser", data=os.urandom(300), recv_ns=t,
                                       sequence=100 + 3 * k + j)  # fmt: skip
            out.append(("/laser/raw", raw, t + j))
        t += 40_000_000
    return out


def _write_both(tmp_path: Path, jpegs: list[bytes]) -> tuple[Path, Path]:
    """The same records through mcap's Writer (old) and :class:`McapFile` (new)."""
    old_path, new_path = tmp_path / "old.mcap", tmp_path / "new.mcap"
    fd = os.open(new_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    out = _File(fd)
    with old_path.open("wb") as f:
        old = LibraryWriter(
            f, chunk_size=300_000, compression=CompressionType.ZSTD, index_types=IndexType.ALL
        )
        new = McapFile(out, chunk_size=300_000)
        ids: dict[str, list[int]] = {}
        for w in (old, new):
            w.start(profile="acq", library="test")
            w.add_metadata("acq", {"session": "s"})
        for topic, name in CHANNELS:
            schema = schemas.SCHEMAS[name]
            ids[topic] = []
            for w in (old, new):
                sid = w.register_schema(schema.name, schema.encoding, schema.data)
                if isinstance(w, McapFile):
                    cid = w.register_channel(topic, "protobuf", sid, {},
                                             name not in INCOMPRESSIBLE)  # fmt: skip
                else:
                    cid = w.register_channel(topic, "protobuf", sid, {})
                ids[topic].append(cid)
        for topic, data, t in _messages(jpegs):
            if topic == "sync":
                old.flush()
                new.flush()
                continue
            old.add_message(ids[topic][0], t, data, t - 1)
            new.add_message(ids[topic][1], t, data, t - 1)
        old.add_metadata("clock", {"k": "v"})
        new.add_metadata("clock", {"k": "v"})
        old.finish()
        new.finish()
    os.close(fd)
    return old_path, new_path


def _read(path: Path) -> tuple[list[Any], list[Any], Any]:
    """Every message (topic, times, sequence, bytes) in log-time order, the metadata, and
    the statistics, read through the summary with CRCs checked."""
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None
        messages = [
            (c.topic, m.log_time, m.publish_time, m.sequence, m.data)
            for _s, c, m in reader.iter_messages()
        ]
        metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
    stats = summary.statistics
    assert stats is not None
    return messages, metadata, stats


def test_the_same_messages_byte_for_byte_as_mcaps_writer(tmp_path: Path, shared_dir: Path) -> None:
    old, new = _write_both(tmp_path, _jpegs(shared_dir))
    old_messages, old_meta, old_stats = _read(old)
    new_messages, new_meta, new_stats = _read(new)
    assert len(new_messages) == 40 * 2 + 15 * 4
    assert new_messages == old_messages
    assert new_meta == old_meta
    for key in ("message_count", "schema_count", "channel_count", "metadata_count",
                "message_start_time", "message_end_time", "channel_message_counts"):  # fmt: skip
        assert getattr(new_stats, key) == getattr(old_stats, key), key
    # in file order too, through acq's own linear reader; and `acq info` says the same
    linear = []
    for path in (old, new):
        reader = LogReader(path)
        linear.append([(c.topic, m.log_time, m.data) for _s, c, m in reader.messages()])
    assert linear[1] == linear[0]
    (info_old,), (info_new,) = info_many([old]), info_many([new])
    assert [(c.topic, c.count) for c in info_new.channels] == [
        (c.topic, c.count) for c in info_old.channels
    ]


def test_image_chunks_are_stored_uncompressed_the_rest_zstd(
    tmp_path: Path, shared_dir: Path
) -> None:
    _old, new = _write_both(tmp_path, _jpegs(shared_dir))
    with new.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    kinds = [i.compression for i in summary.chunk_indexes]
    assert kinds[0] == "zstd"  # the clock and telegrams alone
    assert kinds[1:] and set(kinds[1:]) == {""}  # frames among telegrams
    for index in summary.chunk_indexes:
        if index.compression == "":
            assert index.compressed_size == index.uncompressed_size
        else:
            assert index.compressed_size < index.uncompressed_size / 2
    # a linear reader checks every chunk's CRC and gives the messages in file order
    with new.open("rb") as f:
        records = list(StreamReader(f, validate_crcs=True, emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert [c.compression for c in chunks] == kinds
    with new.open("rb") as f:
        linear = [r for r in StreamReader(f, validate_crcs=True).records if isinstance(r, Message)]
    assert len(linear) == 40 * 2 + 15 * 4


def test_log_writer_stores_a_recorded_frame_as_sent(tmp_path: Path, shared_dir: Path) -> None:
    """Through LogWriter, as the recorder writes: the JPEG read back is the file's bytes."""
    jpegs = _jpegs(shared_dir)
    with LogWriter(tmp_path, chunk_size=200_000) as w:
        w.add_channel("/camera/image/compressed", schemas.SCHEMAS["foxglove.CompressedImage"])
        for k, jpeg in enumerate(jpegs * 3):
            frame = Frame(recv_ns=k, stamp_ns=k, sequence=k, width=780, height=582, jpeg=jpeg)
            data = schemas.compressed_image(frame, "camera", w.time_base.to_log(k))
            w.write("/camera/image/compressed", data, 10**9 + k, 10**9 + k)
        path = w.path
    assert path is not None
    reader = LogReader(path)
    got = [reader.decode(s, c, m).data for s, c, m in reader.messages()]
    assert got == jpegs * 3


def test_write_pieces_writes_every_piece_in_order_past_the_iov_limit(tmp_path: Path) -> None:
    pieces: list[bytes | bytearray | memoryview] = []
    for i in range(1500):  # more than one writev takes
        pieces.append(os.urandom(i % 97))
        pieces.append(bytearray(b"x" * (i % 5)))
        pieces.append(memoryview(os.urandom(200))[i % 50 :])
    path = tmp_path / "pieces"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o644)
    out = _File(fd)
    n = out.write_pieces(pieces)
    os.close(fd)
    expected = b"".join(bytes(p) for p in pieces)
    assert n == len(expected) == out.pos == out.good
    assert path.read_bytes() == expected


def test_a_chunk_of_small_frames_among_scans_keeps_zstd(tmp_path: Path, shared_dir: Path) -> None:
    """A chunk about 60 % JPEG (a rig of 780x582 frames beside its scans) is compressed:
    its scans shrink; one 90 % JPEG or more is stored as it is."""
    jpeg = _jpegs(shared_dir)[0]
    path = tmp_path / "mix.mcap"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    f = McapFile(_File(fd), chunk_size=10 << 20)
    f.start(profile="acq", library="test")
    image = f.register_channel("/camera/image/compressed", "protobuf", 0, {}, False)
    raw = f.register_channel("/laser/raw", "protobuf", 0, {})
    scan = bytes(range(256)) * 40  # 10 kB that compresses
    for scans_a_frame in (11, 1):  # 10 kB scans beside each ~160 kB JPEG
        for k in range(4):
            f.add_message(image, k, jpeg, k)
            for _j in range(scans_a_frame):
                f.add_message(raw, k, scan, k)
        f.flush()
    f.finish()
    os.close(fd)
    with path.open("rb") as g:
        summary = make_reader(g).get_summary()
    assert summary is not None
    assert [i.compression for i in summary.chunk_indexes] == ["zstd", ""]
