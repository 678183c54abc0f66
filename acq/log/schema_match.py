"""Whether a log's schema that bears one of acq's names (``foxglove.LaserScan``,
``acq.Timing``, ... :data:`acq.log.schemas.SCHEMAS`) is acq's, or a foreign message
under the same name.

Messages are decoded by the schema in the file and read by field name, so a schema
matches when its message shares at least one field name with acq's and every shared
name has acq's type and label (its number may differ). Fields acq's message has and
the file's lacks (a log from an older acq) or the file's has and acq's lacks (a newer
one) are allowed. A foreign message decodes without error into a message whose fields
acq reads are all unset, so without this check its channel would read as acq's, empty.
"""

from __future__ import annotations

import functools

from google.protobuf import descriptor_pb2
from google.protobuf.message import DecodeError

from acq.log import schemas

__all__ = ["mismatch"]

_Field = descriptor_pb2.FieldDescriptorProto


def mismatch(name: str, encoding: str, data: bytes) -> str | None:
    """Why the schema ``name`` (a protobuf ``FileDescriptorSet`` in ``data``) is not acq's
    message of that name, in a few words; None when it is, or when acq has no schema of
    that name (a foreign name is not ours to judge)."""
    if name not in schemas.SCHEMAS:
        return None
    return _mismatch(name, encoding, data)


@functools.lru_cache(maxsize=64)
def _mismatch(name: str, encoding: str, data: bytes) -> str | None:
    if encoding != "protobuf":
        return f"its encoding is {encoding!r}, acq's is 'protobuf'"
    theirs = _message(name, data)
    if theirs is None:
        return None  # not parseable: left to the decoder, which names the failure
    ours = _message(name, schemas.SCHEMAS[name].data)
    assert ours is not None
    by_name = {f.name: f for f in ours.field}
    shared = 0
    for f in theirs.field:
        mine = by_name.get(f.name)
        if mine is None:
            continue
        if (f.type, f.label, f.type_name) != (mine.type, mine.label, mine.type_name):
            return f"its field {_describe(f)} is acq's {_describe(mine)}"
        shared += 1
    if not shared:
        return "no field in common with acq's"
    return None


def _message(name: str, data: bytes) -> descriptor_pb2.DescriptorProto | None:
    """The message ``name`` (package.Message) in a serialized FileDescriptorSet."""
    try:
        fds = descriptor_pb2.FileDescriptorSet.FromString(data)
    except DecodeError:
        return None
    package, _, short = name.rpartition(".")
    for file in fds.file:
        if file.package == package:
            for message in file.message_type:
                if message.name == short:
                    return message
    return None


def _describe(f: _Field) -> str:
    """``'NAME' (TYPE)``, e.g. ``'ranges' (repeated double)``."""
    kind = f.type_name.lstrip(".") or _Field.Type.Name(f.type).removeprefix("TYPE_").lower()
    repeated = "repeated " if f.label == _Field.LABEL_REPEATED else ""
    return f"{f.name!r} ({repeated}{kind})"
