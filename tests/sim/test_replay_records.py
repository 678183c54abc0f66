"""`acq replay` reads the records' bytes from the log files as they are due: memory does
not grow with the drive (the replay of a log holds a bounded number of records' bytes,
measured with tracemalloc), and every record is still served, in time order, from any
record on, across the files of a session, a cut file and records out of order."""

from __future__ import annotations

import hashlib
import logging
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.reader import SeekingReader

from acq.drivers.camera_opencv import OpenCVCamera
from acq.log import schemas
from acq.log.timebase import MONOTONIC
from acq.log.writer import LogWriter
from acq.sim.replay import Replay, load_session

TOPIC = "/cam/image/compressed"
FRAME_NS = 40_000_000  # 25 Hz
T0 = 5_000_000_000


def noise_jpeg(seed: int, width: int = 320, height: int = 240) -> bytes:
    """A JPEG of noise (some 70 KB at 320 x 240, each seed its own: the log's chunks do
    not compress)."""
    pixels = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return bytes(buf.tobytes())


def write_session(
    folder: Path, frames: list[tuple[int, bytes]], *, chunk_size: int, split_bytes: int = 2 << 30
) -> list[Path]:
    """A camera's ``frames`` (log ns, JPEG bytes) in a session of MCAP files, in the order
    given."""
    writer = LogWriter(
        folder, prefix="cam", chunk_size=chunk_size, split_bytes=split_bytes,
        time_base=MONOTONIC,
    )  # fmt: skip
    writer.add_channel(TOPIC, schemas.SCHEMAS["foxglove.CompressedImage"])
    for t, data in frames:
        writer.write(TOPIC, CompressedImage(data=data, format="jpeg").SerializeToString(), t, t)
    writer.close()
    return writer.files


@pytest.mark.realtime
def test_a_replay_holds_a_bounded_number_of_records_in_memory(tmp_path: Path) -> None:
    """300 frames of 70 KB (20 MB) in two files of 256 KB chunks: loaded, the replay holds
    their times only; serving all of them over HTTP to the OpenCV driver, in order, it
    never holds more than a few chunks' worth (tracemalloc: every Python allocation, every
    thread)."""
    n = 300
    frames = [(T0 + k * FRAME_NS, noise_jpeg(k)) for k in range(n)]
    digests = [hashlib.sha1(d).digest() for _, d in frames]
    total = sum(len(d) for _, d in frames)
    files = write_session(tmp_path, frames, chunk_size=256 << 10, split_bytes=total // 2)
    assert len(files) == 2
    del frames
    # bytes: the chunks read ahead and a burst of frames in flight (a server that fell
    # behind on a loaded machine); the log is 20 MB
    bound = 8 << 20
    assert total > 2 * bound

    tracemalloc.start()
    try:
        base_mem = tracemalloc.get_traced_memory()[0]
        replay = Replay(files, speed=8.0)
        held = tracemalloc.get_traced_memory()[0] - base_mem
        assert held < (1 << 20), f"{held} bytes held by a loaded replay of {total}"
        tracemalloc.reset_peak()
        got: list[bytes] = []
        with replay, OpenCVCamera(replay.urls["cam"], timeout=10.0) as camera:
            camera.connect()
            camera.start()
            while len(got) < n:
                got.append(hashlib.sha1(camera.read_frame().jpeg).digest())
        peak = tracemalloc.get_traced_memory()[1] - base_mem
    finally:
        tracemalloc.stop()
    print(f"\nreplay of {total} bytes: {held} held when loaded, peak {peak} while serving")
    assert got == digests  # every frame, in order, byte for byte
    assert peak < bound, f"peak {peak} bytes while serving a log of {total}"


def test_records_come_in_time_order_from_any_record_across_files(tmp_path: Path) -> None:
    """Two files of a session whose times overlap, records out of order within a file,
    ties, and the second file cut short (its writer killed): the source serves what the
    first pass read, as a stable sort of the files in order, from any record on,
    forwards, backwards and after a jump."""
    first = [(T0 + k * FRAME_NS, f"a{k}".encode()) for k in range(400)]
    first[10], first[11] = first[11], first[10]  # overtaken by a later frame
    first[30] = (first[29][0], first[30][1])  # a tie with the one before
    second = [(T0 + 375 * FRAME_NS + k * FRAME_NS + 1, f"b{k}".encode()) for k in range(60)]
    (one,) = write_session(tmp_path / "1", first, chunk_size=200)
    (two,) = write_session(tmp_path / "2", second, chunk_size=200)
    cut = tmp_path / "cut.mcap"
    with two.open("rb") as f:
        summary = SeekingReader(f).get_summary()
    assert summary is not None
    chunks = sorted(c.chunk_start_offset for c in summary.chunk_indexes)
    cut.write_bytes(two.read_bytes()[: chunks[len(chunks) // 2] + 10])  # in a chunk
    session = load_session([one, cut])
    records = session.devices["cam"].records
    n = len(records)
    assert 400 + 20 < n < 460  # the cut file's complete chunks
    kept = second[: n - 400]
    ordered = sorted(first + kept, key=lambda r: r[0])  # stable: file order for ties
    assert list(records.times_ns) == [t for t, _ in ordered]
    want = [d for _, d in ordered]
    cursor = records.cursor()
    try:
        assert [cursor.get(k) for k in range(n)] == want
        assert cursor.get(n) is None
        for k in (31, 30, 5, 400, 390, 391, n - 1, 0):  # back, a jump, on
            assert cursor.get(k) == want[k], k
    finally:
        cursor.close()
    assert records.head(3) == want[:3]


def test_a_file_removed_after_loading_silences_the_device_with_one_error(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The bytes are read when due: a file removed since the replay was loaded ends its
    device's stream with one ERROR line naming the file (no traceback in a server
    thread)."""
    (one,) = write_session(tmp_path, [(T0 + k * FRAME_NS, b"x%d" % k) for k in range(5)],
                           chunk_size=200)  # fmt: skip
    records = load_session([one]).devices["cam"].records
    one.unlink()
    cursor = records.cursor()
    with caplog.at_level(logging.ERROR):
        assert cursor.get(0) is None
        assert cursor.get(1) is None
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and str(one) in errors[0] and "cam" in errors[0], errors
