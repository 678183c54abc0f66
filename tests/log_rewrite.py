"""Copies of recorded logs for the tests, rewritten with acq.log.writer: camera frames
replaced (a camera that sends another size), smaller chunks, one chunk's bytes flipped;
or copied record by record with mcap's writer (:func:`mcap_copy`): payloads, schemas or
metadata records changed, as other tools write them."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from mcap.reader import SeekingReader, make_reader
from mcap.records import Schema
from mcap.writer import Writer

from acq.log import schemas
from acq.log.reader import LogReader, read_metadata
from acq.log.timebase import MONOTONIC, TimeBase
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
    time_base: TimeBase | None = None,
) -> tuple[list[Path], dict[int, int]]:
    """The messages of ``files`` written anew into ``directory`` (one file per source
    file), the camera frames numbered in ``frames`` (0: the first) given those JPEG bytes,
    in chunks of ``chunk_size`` bytes, on the source's clock or ``time_base`` (its
    Foxglove stamps converted; MONOTONIC: a log as acq wrote them before UTC logs). The
    new files, and the log time (ns, host monotonic) of each replaced frame by its number."""
    out: list[Path] = []
    times: dict[int, int] = {}
    k = 0
    for src in files:
        metadata = read_metadata(src)
        source = TimeBase.of_metadata(metadata)
        target = source if time_base is None else time_base
        if target == MONOTONIC:  # as such logs were: no offset, the old clock line
            metadata["acq"] = {k: v for k, v in metadata["acq"].items() if k != "utc_offset_ns"}
        writer = LogWriter(
            directory / src.stem, prefix="copy", metadata=metadata, chunk_size=chunk_size,
            time_base=target,
        )  # fmt: skip
        topics: set[str] = set()
        reader = LogReader(src)
        for schema, channel, message in reader.messages():
            if channel.topic not in topics:
                assert schema is not None
                writer.add_channel(channel.topic, schemas.SCHEMAS[schema.name])
                topics.add(channel.topic)
            data = message.data
            if target != source and schema is not None and schema.name.startswith("foxglove."):
                msg = reader.decode(schema, channel, message)  # stamps host monotonic
                for stamped in (msg, *getattr(msg, "transforms", ())):
                    ts = stamped.timestamp
                    ts.FromNanoseconds(target.to_log(ts.ToNanoseconds()))
                data = msg.SerializeToString()
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
    (its first and last log time, host monotonic ns as the reader gives them; the number
    of chunks)."""
    with path.open("rb") as f:
        summary = SeekingReader(f).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    c = chunks[which]
    data = bytearray(path.read_bytes())
    data[c.chunk_start_offset + c.chunk_length // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    to_host = TimeBase.of_metadata(read_metadata(path)).to_host
    return to_host(c.message_start_time), to_host(c.message_end_time), len(chunks)


def mcap_copy(
    src: Path,
    dst: Path,
    payload: Callable[[str, bytes], bytes] = lambda _t, d: d,
    schema_data: Callable[[Schema], bytes] = lambda s: s.data,
    metadata: Callable[[str, dict[str, str]], dict[str, str] | None] = lambda _n, m: m,
    extra: Callable[[Writer], None] = lambda _w: None,
    keep: Callable[[str], bool] = lambda _t: True,
) -> dict[str, int]:
    """``src`` copied to ``dst`` with mcap's writer (metadata, schemas, channels, messages),
    payloads, schemas and metadata records through the given functions (``metadata``
    gives None: the record left out, as ``mcap filter`` does without
    ``--include-metadata``), then ``extra`` given the writer to add its own; messages of
    topics ``keep`` refuses left out (their channels stay); the messages per topic."""
    counts: dict[str, int] = {}
    with src.open("rb") as f, dst.open("wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        w = Writer(g)
        w.start()
        for m in reader.iter_metadata():
            kept = metadata(m.name, dict(m.metadata))
            if kept is not None:
                w.add_metadata(m.name, kept)
        schema_ids = {
            s.id: w.register_schema(s.name, s.encoding, schema_data(s))
            for s in summary.schemas.values()
        }
        channel_ids = {
            c.id: w.register_channel(
                c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), c.metadata
            )
            for c in summary.channels.values()
        }
        for _s, channel, m in reader.iter_messages(log_time_order=False):
            if not keep(channel.topic):
                continue
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            data = payload(channel.topic, m.data)
            w.add_message(channel_ids[channel.id], m.log_time, data, m.publish_time, m.sequence)
        extra(w)
        w.finish()
    return counts
