"""A client of the Foxglove WebSocket protocol (``foxglove.sdk.v1``), what ``acq record
--live`` serves: connect, subscribe to the channels as they are advertised (every one, or
the topics asked for) and decode their messages with the advertised protobuf schemas
(``FileDescriptorSet``\\ s). asyncio over `websockets`; :mod:`acq.monitor.live_source`
runs it on a thread. A server that answers otherwise is a :class:`ProtocolError`."""

from __future__ import annotations

import asyncio
import base64
import binascii
import functools
import json
import struct
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError
from websockets.asyncio.client import ClientConnection, connect

from acq.errors import AcqError

__all__ = [
    "MESSAGE_DATA",
    "SUBPROTOCOL",
    "ProtocolError",
    "Seen",
    "connect_client",
    "message_class",
    "take",
]

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # the server's binary opcode for a message
_MESSAGE_HEAD = struct.Struct("<IQ")  # subscription id, log time ns
_CHANNEL_KEYS = frozenset({"id", "topic", "schemaName", "schema"})


class ProtocolError(AcqError):
    """The server does not speak ``foxglove.sdk.v1`` as the protocol says."""


@functools.lru_cache(maxsize=64)
def message_class(schema_name: str, schema_b64: str) -> Any:
    """The protobuf class of an advertised channel (its schema: a base64
    ``FileDescriptorSet``); ProtocolError when the schema does not hold the message."""
    try:
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
        pool = descriptor_pool.DescriptorPool()
        for file in fds.file:
            pool.Add(file)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))
    except (binascii.Error, DecodeError, KeyError, TypeError) as e:
        raise ProtocolError(f"channel schema {schema_name!r} unreadable: {e}") from None


@dataclass
class Seen:
    """What a client received: the server's info, the channels, decoded messages by topic
    (each with the monotonic time of its receipt, s), how many of each topic came, and
    its subscriptions (id -> channel id: :func:`take` may be called again). :meth:`add`
    keeps each message of the topics ``keep`` accepts (default all)."""

    info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    messages: dict[str, list[tuple[float, Any]]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    subs: dict[int, int] = field(default_factory=dict)
    keep: Callable[[str], bool] | None = None

    def add(self, topic: str, received_s: float, message: Any) -> None:
        """One message of ``topic`` received at monotonic ``received_s``."""
        self.counts[topic] = self.counts.get(topic, 0) + 1
        if self.keep is None or self.keep(topic):
            self.messages.setdefault(topic, []).append((received_s, message))


async def connect_client(url: str, *, retry_s: float = 30.0, **kw: Any) -> ClientConnection:
    """Connect to ``url`` offering ``foxglove.sdk.v1``, retrying a refused connection for
    ``retry_s`` (a server still starting; 0: once). ``kw`` go to `websockets`' connect.
    ProtocolError when the server accepts without that subprotocol."""
    end = time.monotonic() + retry_s
    while True:
        try:
            ws = await connect(url, subprotocols=[SUBPROTOCOL], **kw)  # type: ignore[list-item]
            break
        except OSError:
            if time.monotonic() >= end:
                raise
            await asyncio.sleep(0.1)
    if ws.subprotocol != SUBPROTOCOL:
        await ws.close()
        raise ProtocolError(f"a WebSocket server not speaking {SUBPROTOCOL}")
    return ws


async def take(
    ws: ClientConnection,
    seen: Seen,
    until: float,
    decode: bool,
    topics: Collection[str] | None = None,
) -> None:
    """Read until the monotonic time ``until`` (s), subscribing to each channel advertised
    (of ``topics`` only, when given); each message to ``seen.add``, decoded when
    ``decode`` (those ``seen.keep`` refuses only counted). ProtocolError for what the
    protocol does not allow; the connection's closing (`websockets`' ConnectionClosed) is
    raised as is."""
    subs = seen.subs
    while (left := until - time.monotonic()) > 0:
        try:
            frame = await asyncio.wait_for(ws.recv(), timeout=min(left, 3600.0))
        except TimeoutError:
            continue
        if isinstance(frame, str):
            await _control(ws, seen, subs, frame, topics)
            continue
        if len(frame) < 1 + _MESSAGE_HEAD.size or frame[0] != MESSAGE_DATA:
            continue  # another binary opcode (time, a service's answer...), not messages
        sub_id, _ = _MESSAGE_HEAD.unpack_from(frame, 1)
        ch = seen.channels.get(subs.get(sub_id, -1))
        if ch is None:
            raise ProtocolError(f"a message for subscription {sub_id}, never made")
        payload: Any = frame[1 + _MESSAGE_HEAD.size :]
        if seen.keep is not None and not seen.keep(ch["topic"]):
            seen.add(ch["topic"], time.monotonic(), None)  # counted only
            continue
        if decode:
            try:
                payload = message_class(ch["schemaName"], ch["schema"]).FromString(payload)
            except DecodeError as e:
                raise ProtocolError(f"{ch['topic']}: a message not of its schema: {e}") from None
        seen.add(ch["topic"], time.monotonic(), payload)


async def _control(
    ws: ClientConnection,
    seen: Seen,
    subs: dict[int, int],
    text: str,
    topics: Collection[str] | None,
) -> None:
    """One JSON message of the server: its info, or channels advertised (subscribed to)."""
    try:
        msg = json.loads(text)
        op = msg["op"]
        if op == "serverInfo":
            seen.info = msg
        elif op == "advertise":
            new = []
            for ch in msg["channels"]:
                if not _CHANNEL_KEYS <= ch.keys():
                    raise KeyError(f"channel without {sorted(_CHANNEL_KEYS - ch.keys())}")
                seen.channels[ch["id"]] = ch
                if topics is None or ch["topic"] in topics:
                    subs[len(subs) + 1] = ch["id"]
                    new.append({"id": len(subs), "channelId": ch["id"]})
            if new:
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
    except (
        ValueError,
        KeyError,
        TypeError,
        AttributeError,
    ) as e:  # JSONDecodeError is a ValueError
        raise ProtocolError(f"a control message not of the protocol: {e!r}"[:200]) from None
