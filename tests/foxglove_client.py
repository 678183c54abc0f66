"""A Foxglove WebSocket client (``foxglove.sdk.v1``) for the live server's tests and
bench: connects (retrying while the server starts), subscribes to every channel as it is
advertised, and decodes messages with the advertised protobuf schemas."""

from __future__ import annotations

import asyncio
import base64
import functools
import json
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.asyncio.client import ClientConnection, connect

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # the server's binary opcode for a message


@functools.cache  # a class per channel, not per message: a client must keep up at 40 Hz
def _message_class(schema_name: str, schema_b64: str) -> Any:
    """The protobuf class of an advertised channel (its schema: a FileDescriptorSet)."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for file in fds.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


@dataclass
class Seen:
    """What a client received: the server's info, the channels, the messages kept (by
    topic: (receipt, host monotonic s; the message)), how many of each topic came, and
    its subscriptions (id -> channel id), so that :func:`take` can be called again."""

    info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[tuple[float, Any]]] = field(default_factory=dict)  # topic -> ...
    counts: dict[str, int] = field(default_factory=dict)
    subs: dict[int, int] = field(default_factory=dict)


async def connect_client(url: str, **kw: Any) -> ClientConnection:
    """Connect, retrying while the recorder starts its server."""
    end = time.monotonic() + 30.0
    while True:
        try:
            return await connect(url, subprotocols=[SUBPROTOCOL], **kw)  # type: ignore[list-item]
        except OSError:
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.1)


async def take(
    ws: ClientConnection,
    seen: Seen,
    until: float,
    decode: bool,
    keep: Callable[[str], bool] | None = None,
) -> None:
    """Read until the monotonic time ``until``; subscribe to each channel advertised.
    Every message is counted; those of the topics ``keep`` accepts (default all) are kept
    in ``seen.messages``, decoded with ``decode``."""
    subs = seen.subs
    while (left := until - time.monotonic()) > 0:
        try:
            frame = await asyncio.wait_for(ws.recv(), timeout=left)
        except TimeoutError:
            return
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                seen.info = msg
            elif msg["op"] == "advertise":
                new = []
                for ch in msg["channels"]:
                    seen.channels[ch["id"]] = ch
                    subs[len(subs) + 1] = ch["id"]
                    new.append({"id": len(subs), "channelId": ch["id"]})
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            continue
        received = time.monotonic()
        assert frame[0] == MESSAGE_DATA, frame[:1]
        sub_id, _ = struct.unpack_from("<IQ", frame, 1)
        ch = seen.channels[subs[sub_id]]
        topic = ch["topic"]
        seen.counts[topic] = seen.counts.get(topic, 0) + 1
        if keep is not None and not keep(topic):
            continue
        payload = frame[13:]
        if decode:
            cls = _message_class(ch["schemaName"], ch["schema"])
            payload = cls.FromString(payload)
        seen.messages.setdefault(topic, []).append((received, payload))
