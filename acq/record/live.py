"""`acq record --live`: the log's channels served live over the Foxglove WebSocket protocol.

A :class:`LiveServer` is a listener of the recorder's log (:mod:`acq.record.listeners`):
it runs the Foxglove SDK's WebSocket server (``foxglove.sdk.v1``, what the Foxglove app
and Lichtblick connect to) and serves every channel of the log with the log's schemas
(protobuf ``FileDescriptorSet``\\ s) and bytes, each advertised with its first message.
Camera images go to live clients at most ``image_hz`` per topic (the log keeps every
frame). The latched messages (``/tf_static``, camera calibrations) are sent again when
a client subscribes to them, so a client that connects late still has them.

A client's backlog is bounded by the SDK (:data:`BACKLOG`: its oldest messages are
dropped when it does not read; a client whose control queue fills is disconnected), and
the server's threads are its own: a stalled or hostile client never slows the recorder,
which hands records to this listener through its own bounded queue.
"""

from __future__ import annotations

import logging
import threading

import foxglove
from foxglove import _foxglove_py
from foxglove.websocket import ChannelView, Client, ServerListener

from acq.errors import AcqError, InputValueError
from acq.record.listeners import Listener, LogRecord

__all__ = [
    "BACKLOG",
    "IMAGE_SCHEMAS",
    "LiveServer",
    "LiveServerError",
    "parse_address",
]

log = logging.getLogger("acq.record")

# Messages queued per client. The largest messages are camera frames (a 780x582 MJPEG
# frame is ~60 kB, a 1 MB frame the worst we expect): 128 of them bound a stalled client
# to ~8 MB (128 MB at worst), against the SDK's default of 1,024.
BACKLOG = 128
IMAGE_SCHEMAS = frozenset({"foxglove.CompressedImage", "foxglove.RawImage"})


class LiveServerError(AcqError, RuntimeError):
    """The live server cannot start (its port is taken, the address is not this host's)."""


def parse_address(address: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[V6]:PORT`` for IPv6) as (host, port); InputValueError if not."""
    host, sep, port = address.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise InputValueError(f"{address!r}: expected HOST:PORT, e.g. 127.0.0.1:8765")
    return host, int(port)


class _Subscriptions(ServerListener):
    """The SDK's server listener: notes the channels subscribed to (on the SDK's thread),
    so the feed's thread can send the latched messages to the new subscribers."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.new: set[int] = set()  # channel ids subscribed to since last taken

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self.lock:
            self.new.add(channel.id)

    def take(self) -> set[int]:
        with self.lock:
            out, self.new = self.new, set()
        return out


class LiveServer(Listener):
    """The Foxglove WebSocket server on ``host``:``port`` (0: a free port, see
    :attr:`port`), images at most ``image_hz`` per camera topic (0: none)."""

    def __init__(
        self, host: str, port: int, *, image_hz: float = 5.0, backlog: int = BACKLOG
    ) -> None:
        self.image_period_ns = round(1e9 / image_hz) if image_hz > 0 else None
        self.context = foxglove.Context()  # this server's channels only
        self.subscriptions = _Subscriptions()
        try:
            self.server = foxglove.start_server(
                name="acq record",
                host=host,
                port=port,
                context=self.context,
                server_listener=self.subscriptions,
                message_backlog_size=backlog,
            )
        except Exception as e:  # the SDK raises its own error types for a bind failure
            raise LiveServerError(f"--live {host}:{port}: cannot listen: {e}") from None
        # The SDK forwards its log to Python's logging from its own threads, taking the
        # GIL for each line: a client that goes away with a full backlog is one error
        # line per message queued, a burst the device threads would wait on. The
        # clients' troubles are theirs: not forwarded (starting a server turns the
        # forwarding on, hence after it).
        _foxglove_py.disable_logging()
        self.port = self.server.port
        self._running = threading.Event()
        self._running.set()
        self.channels: dict[str, foxglove.Channel] = {}
        self.latched: dict[int, LogRecord] = {}  # channel id -> its latched record
        self.last_image_ns: dict[str, int] = {}
        self.sent = 0  # messages handed to the server
        self.throttled = 0  # images not sent (the rate limit)

    def _channel(self, record: LogRecord) -> foxglove.Channel:
        channel = self.channels.get(record.topic)
        if channel is None:
            s = record.schema
            channel = foxglove.Channel(
                record.topic,
                schema=foxglove.Schema(name=s.name, encoding=s.encoding, data=s.data),
                message_encoding=s.encoding,
                context=self.context,
            )
            self.channels[record.topic] = channel
        return channel

    def _throttled(self, record: LogRecord) -> bool:
        """Whether an image comes sooner than the image rate allows after the last sent."""
        if record.schema.name not in IMAGE_SCHEMAS:
            return False
        if self.image_period_ns is None:
            return True
        last = self.last_image_ns.get(record.topic)
        if last is not None and record.log_time_ns - last < self.image_period_ns:
            return True
        self.last_image_ns[record.topic] = record.log_time_ns
        return False

    def on_record(self, record: LogRecord) -> None:
        channel = self._channel(record)
        if record.latched:
            self.latched[channel.id()] = record
        for cid in self.subscriptions.take():
            again = self.latched.get(cid)
            if again is not None and again is not record:
                self.channels[again.topic].log(again.data, log_time=again.log_time_ns)
        if self._throttled(record):
            self.throttled += 1
            return
        channel.log(record.data, log_time=record.log_time_ns)
        self.sent += 1

    def stop(self) -> None:
        """Stop the server (once; later calls do nothing)."""
        if self._running.is_set():
            self._running.clear()
            self.server.stop()
