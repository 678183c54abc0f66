"""Copies of recorded logs for the tests, rewritten with acq.log.writer: camera frames
replaced (a camera that sends another size), smaller chunks, one chunk's bytes flipped."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.reader import SeekingReader

from acq.log import schemas
from acq.log.reader import read_messages, read_metadata
from acq.log.writer import LogWriter

IMAGE_TOPIC = "/camera/image/compressed"


def jpeg(width: int, height: int) -> bytes:
    """A grey JPEG of ``width`` x ``height`` px."""
    ok, buf = cv2.imencode(".jpg", np.full((height, width, 3), 128, np.uint8))
    assert ok
    return bytes(buf.tobytes())


def rewrite(
    files: Sequence[Path],
    directory: Path,
    *,
    frames: Mapping[int, bytes] | None = None,
    chunk_size: int = 8 << 20,
) -> tuple[list[Path], dict[int, int]]:
    """The messages of ``files`` written anew into ``directory`` (one file per source
    file), the camera frames numbered in ``frames`` (0: the first) given those JPEG bytes,
    in chunks of ``chunk_size`` bytes. The new files, and the log time (ns) of each
    replaced frame by its number."""
    out: list[Path] = []
    times: dict[int, int] = {}
    k = 0
    for src in files:
        writer = LogWriter(
            directory / src.stem, prefix="copy", metadata=read_metadata(src), chunk_size=chunk_size
        )
        topics: set[str] = set()
        for schema, channel, message in read_messages(src):
            if channel.topic not in topics:
                assert schema is not None
                writer.add_channel(channel.topic, schemas.SCHEMAS[schema.name])
                topics.add(channel.topic)
            data = message.data
            if channel.topic == IMAGE_TOPIC:
                if frames and k in frames:
                    image = CompressedImage.FromString(data)
                    image.data = frames[k]
                    data = image.SerializeToString()
                    times[k] = message.log_time
                k += 1
            writer.write(channel.topic, data, message.log_time, message.publish_time)
        writer.close()
        out += writer.files
    return out, times


def corrupt_chunk(path: Path, which: int) -> tuple[int, int, int]:
    """Flip a byte inside the compressed data of the ``which``-th chunk of a closed log:
    (its first and last log time, ns; the number of chunks)."""
    with path.open("rb") as f:
        summary = SeekingReader(f).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    c = chunks[which]
    data = bytearray(path.read_bytes())
    data[c.chunk_start_offset + c.chunk_length // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    return c.message_start_time, c.message_end_time, len(chunks)
