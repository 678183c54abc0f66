"""Listeners on the recorder's log: each gets every record the log gets, off the writer.

python-can's ``Notifier`` / ``Listener`` is the model. The writer's thread hands each
record it writes (:class:`LogRecord`: topic, schema, bytes, log time) to
:meth:`Listeners.publish`, which puts it on every listener's OWN bounded queue and
returns at once: a full queue drops the record for that listener alone (counted in
:attr:`Feed.dropped`), so a slow listener never slows the device threads or the writer
and never costs a logged record. Each listener runs on its own thread, taking records
off its queue and calling :meth:`Listener.on_record`; an exception there is logged once
and counted (:attr:`Feed.failed`), the listener keeps its thread. A listener that has
figures for ``/acq/status`` (the live colourer) returns them from :meth:`Listener.status`.
"""

from __future__ import annotations

import logging
import queue
import threading
from abc import ABC, abstractmethod
from collections.abc import Iterable
from dataclasses import dataclass

from acq.drivers.reconnect import describe
from acq.log.schemas import ColouringStatus, Schema

__all__ = ["FEED_SIZE", "Feed", "Listener", "Listeners", "LogRecord"]

log = logging.getLogger("acq.record")

FEED_SIZE = 256  # records queued per listener; ~10 s of a 25 Hz rig's every record


@dataclass(frozen=True)
class LogRecord:
    """One message as the log gets it: ``log_time_ns`` in the log's time base (UTC ns
    for a recorder's log); ``latched`` for the messages every file starts with
    (``/tf_static``, camera calibrations), published once."""

    topic: str
    schema: Schema
    data: bytes
    log_time_ns: int
    latched: bool = False


class Listener(ABC):
    """Takes the log's records, on its own thread (one :class:`Feed` per listener).
    :meth:`backlog` says how many records wait for it (its feed sets it)."""

    def backlog(self) -> int:
        """Records queued for this listener, not yet taken (0 without a feed)."""
        return 0

    @abstractmethod
    def on_record(self, record: LogRecord) -> None:
        """One record of the log, in the order the writer wrote them (less the dropped)."""

    def dropped(self, record: LogRecord) -> None:  # noqa: B027 (an optional hook)
        """``record`` never reaches :meth:`on_record`: the listener's queue was full
        (called on the writer's thread: count, nothing more)."""

    def stop(self) -> None:  # noqa: B027 (an optional hook: most listeners hold nothing)
        """The log is closed: release what the listener holds (on its feed's thread)."""

    def status(self) -> ColouringStatus | None:
        """Figures for the recorder's ``/acq/status`` (called on the recorder's thread,
        each second): a live colourer's counts; None, most listeners, has none."""
        return None


class Feed:
    """One listener's bounded queue and thread; counts what it had to drop."""

    def __init__(self, listener: Listener, size: int = FEED_SIZE) -> None:
        self.listener = listener
        self.dropped = 0  # records the full queue refused
        self.delivered = 0  # records on_record took (raised or not)
        self.failed = 0  # records on_record raised on
        self._queue: queue.Queue[LogRecord | None] = queue.Queue(maxsize=size)
        self._closing = threading.Event()
        self._thread = threading.Thread(
            target=self._run, name=f"listener {type(listener).__name__}", daemon=True
        )
        listener.backlog = self.qsize  # type: ignore[method-assign]
        self._thread.start()

    def put(self, record: LogRecord) -> bool:
        """Queue ``record``; False (and one more drop) when the queue is full. Never blocks."""
        if self._closing.is_set():
            return False
        try:
            self._queue.put_nowait(record)
        except queue.Full:
            self.dropped += 1
            self.listener.dropped(record)
            return False
        return True

    def qsize(self) -> int:
        """Records queued, not yet taken."""
        return self._queue.qsize()

    def _run(self) -> None:
        while True:
            record = self._queue.get()
            if record is None:
                break
            try:
                self.listener.on_record(record)
            except Exception as e:
                self.failed += 1
                if self.failed == 1:
                    log.warning("%s: %s (later failures at debug level)",
                                self._thread.name, describe(e))  # fmt: skip
                log.debug("%s failed", self._thread.name, exc_info=e)
            self.delivered += 1
        try:
            self.listener.stop()
        except Exception as e:
            log.warning("%s: stopping: %s", self._thread.name, describe(e))

    def close(self, timeout_s: float = 1.0) -> None:
        """Stop taking records; the thread finishes what is queued (up to ``timeout_s``),
        then calls the listener's :meth:`Listener.stop`. One line when it missed records."""
        if self._closing.is_set():
            return
        self._closing.set()
        self._end(timeout_s)
        if self.dropped:
            log.warning("%s fell behind: %d records of the log not passed to it (the log "
                        "has them)", self._thread.name, self.dropped)  # fmt: skip

    def _end(self, timeout_s: float) -> None:
        """The end mark on the queue, then wait for the thread."""
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            pass
        else:
            self._thread.join(timeout_s)
            return
        while True:  # a listener stuck: the end mark goes in at the cost of a record
            try:
                self._queue.put_nowait(None)
                break
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass
        self._thread.join(timeout_s)


class Listeners:
    """The listeners of one log: :meth:`publish` (on the writer's thread) hands each
    record to every listener's :class:`Feed`. Safe to add to while publishing."""

    def __init__(self, listeners: Iterable[Listener] = (), size: int = FEED_SIZE) -> None:
        self.size = size
        self.feeds: list[Feed] = []
        self._lock = threading.Lock()
        for listener in listeners:
            self.add(listener)

    def add(self, listener: Listener) -> Feed:
        """Start feeding ``listener`` (from the next record on)."""
        feed = Feed(listener, self.size)
        with self._lock:
            self.feeds = [*self.feeds, feed]
        return feed

    def publish(self, record: LogRecord) -> None:
        """``record`` to every listener's queue; never blocks."""
        for feed in self.feeds:  # a list replaced, never changed: no lock needed to read it
            feed.put(record)

    def colouring(self) -> ColouringStatus | None:
        """The first listener's colouring figures (None: no listener has any)."""
        for feed in self.feeds:
            try:
                figures = feed.listener.status()
            except Exception as e:  # a listener's fault costs its figures, not the status
                log.debug("%s: status: %s", type(feed.listener).__name__, describe(e))
                continue
            if figures is not None:
                return figures
        return None

    def close(self, timeout_s: float = 1.0) -> None:
        """Close every feed (each finishes its queue within ``timeout_s``)."""
        with self._lock:
            feeds, self.feeds = self.feeds, []
        for feed in feeds:
            feed.close(timeout_s)
