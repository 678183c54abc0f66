"""Repair a log: copy every readable message of a closed, cut or damaged MCAP file
(with its schemas, channels, metadata and attachments) into a new, indexed file.

The copy carries a :data:`REPAIR_RECORD` metadata record naming its source (file name
and size when copied), so that a command given both reads the session once
(:mod:`acq.log.inputs`)."""

from __future__ import annotations

import os
from pathlib import Path

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from acq.log.reader import LogReader

__all__ = ["REPAIR_RECORD", "repair"]

REPAIR_RECORD = "acq.repair"  # metadata: source (file name), source_bytes (its size)


def repair(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    chunk_size: int = 1 << 20,
    into_empty: bool = False,
) -> int:
    """Write every readable message of ``src`` (with its schemas, channels, metadata and
    attachments) to a new, indexed, zstd-chunked MCAP ``dst``, marked as its repaired
    copy (:data:`REPAIR_RECORD`); returns the message count.

    Raises FileExistsError rather than overwrite ``dst`` (unless ``into_empty``: ``dst``
    is an empty temporary of :func:`acq.atomic_write.temporary_beside`, written in place),
    :class:`acq.log.reader.LogError` when ``src`` is not an MCAP log. ``chunk_size`` is
    the uncompressed chunk size, bytes.
    """
    reader = LogReader(src)
    mark = {"source": reader.path.name, "source_bytes": str(reader.size)}
    dst = Path(dst)
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    schemas: dict[int, Schema] = {}
    pending: dict[int, Channel] = {}
    count = 0
    with dst.open("r+b" if into_empty else "xb") as out:
        writer = Writer(out, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        started = False
        try:
            for record in reader.records():
                if isinstance(record, Header):
                    if not started:
                        writer.start(profile=record.profile, library=record.library)
                        writer.add_metadata(REPAIR_RECORD, mark)
                        started = True
                    continue
                if not started:
                    writer.start()
                    writer.add_metadata(REPAIR_RECORD, mark)
                    started = True
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    pending.setdefault(record.id, record)
                elif isinstance(record, Message):
                    new_id = channel_ids.get(record.channel_id)
                    if new_id is None:
                        channel = pending.get(record.channel_id)
                        if channel is None:
                            continue
                        new_id = _register(writer, channel, schemas, schema_ids)
                        channel_ids[record.channel_id] = new_id
                    writer.add_message(
                        channel_id=new_id,
                        log_time=record.log_time,
                        data=record.data,
                        publish_time=record.publish_time,
                        sequence=record.sequence,
                    )
                    count += 1
                elif isinstance(record, Metadata) and record.name != REPAIR_RECORD:
                    writer.add_metadata(record.name, dict(record.metadata))
                elif isinstance(record, Attachment):
                    writer.add_attachment(
                        record.create_time,
                        record.log_time,
                        record.name,
                        record.media_type,
                        record.data,
                    )
            if not started:
                writer.start()
                writer.add_metadata(REPAIR_RECORD, mark)
            for old_id, channel in pending.items():  # channels without messages, too
                if old_id not in channel_ids:
                    channel_ids[old_id] = _register(writer, channel, schemas, schema_ids)
            writer.finish()
        except BaseException:
            out.close()
            dst.unlink(missing_ok=True)
            raise
    return count


def _register(
    writer: Writer, channel: Channel, schemas: dict[int, Schema], schema_ids: dict[int, int]
) -> int:
    """Register ``channel`` (and its schema, once) with ``writer``; its new id."""
    new_schema = 0
    schema = schemas.get(channel.schema_id)
    if schema is not None:
        if schema.id not in schema_ids:
            schema_ids[schema.id] = writer.register_schema(
                schema.name, schema.encoding, schema.data
            )
        new_schema = schema_ids[schema.id]
    return writer.register_channel(
        channel.topic, channel.message_encoding, new_schema, dict(channel.metadata)
    )
