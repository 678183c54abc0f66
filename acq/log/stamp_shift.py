"""Shifting every Timestamp of a decoded protobuf message, nested ones included: a UTC
log's Foxglove messages read in host monotonic time (:mod:`acq.log.timebase`)."""

from __future__ import annotations

from typing import cast

from google.protobuf.descriptor import Descriptor, FieldDescriptor
from google.protobuf.message import Message as Protobuf

__all__ = ["shift_stamps", "stamps_to_host"]

_TIMESTAMP = "google.protobuf.Timestamp"
# by message type (its descriptor: two files may hold two versions of one schema)
_STAMP_FIELDS: dict[Descriptor, tuple[tuple[FieldDescriptor, bool], ...]] = {}


def _stamp_fields(
    descriptor: Descriptor, within: frozenset[Descriptor] = frozenset()
) -> tuple[tuple[FieldDescriptor, bool], ...]:
    """The message fields of a message type that are or may hold a Timestamp, each with
    whether it is one (``within``: the types being looked into, so a type that holds
    itself ends). Cached whole, so threads decoding at once see all or nothing."""
    known = _STAMP_FIELDS.get(descriptor)
    if known is not None:
        return known
    found = []
    for field in descriptor.fields:
        sub = field.message_type
        if sub is None or sub in within:
            continue
        if sub.full_name == _TIMESTAMP or _stamp_fields(sub, within | {descriptor}):
            found.append((field, sub.full_name == _TIMESTAMP))
    _STAMP_FIELDS[descriptor] = result = tuple(found)
    return result


def shift_stamps(msg: Protobuf, delta_ns: int) -> None:
    """Add ``delta_ns`` (ns) to every Timestamp set in ``msg``, nested ones included."""
    for field, is_stamp in _stamp_fields(cast(Descriptor, msg.DESCRIPTOR)):
        if field.is_repeated:
            items = list(getattr(msg, field.name))
        elif msg.HasField(field.name):
            items = [getattr(msg, field.name)]
        else:
            continue
        for item in items:
            if is_stamp:
                item.FromNanoseconds(item.ToNanoseconds() + delta_ns)
            else:
                shift_stamps(item, delta_ns)


def stamps_to_host(msg: Protobuf, schema_name: str, utc_offset_ns: int) -> None:
    """A message of a log whose clock is host monotonic + ``utc_offset_ns``, its stamps
    taken back to host ns: a Foxglove message's (``acq.*`` messages keep host ns)."""
    if utc_offset_ns and schema_name.startswith("foxglove."):
        shift_stamps(msg, -utc_offset_ns)
