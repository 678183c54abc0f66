"""Snapshots of a recorder read from its live server (``acq record --live HOST:PORT``):
a Foxglove WebSocket client (:mod:`acq.monitor.foxglove_client`) on its own thread,
subscribed to ``/acq/status`` and ``/acq/timebase`` only, keeps the newest of each and
when it came. The recorder may be on another host: the ages are this host's (the time
since a status came), and its file and disk are the recorder's own figures."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
import time
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidHandshake

from acq.errors import AcqError
from acq.log.schemas import colouring_of
from acq.monitor.foxglove_client import ProtocolError, Seen, connect_client, take
from acq.monitor.log_source import TOPICS, time_base_line
from acq.monitor.snapshot import Snapshot, device_views

__all__ = ["CONNECT_TIMEOUT_S", "LiveSource", "LiveSourceError"]

CONNECT_TIMEOUT_S = 5.0  # to connect and finish the WebSocket handshake, s
TIME_BASE_WAIT_S = 2.2  # for the first /acq/timebase once a status came, s
NO_DISK_FIGURE = 1e9  # the recorder's disk_minutes_left when nothing limits it, min


class LiveSourceError(AcqError):
    """No live server at the address: nothing listens, or something else answers."""


class _Newest(Seen):
    """Keeps only the newest message of each topic, with its receipt time (thread-safe)."""

    def __init__(self) -> None:
        super().__init__()
        self.lock = threading.Lock()
        self.arrived = threading.Condition(self.lock)

    def add(self, topic: str, received_s: float, message: Any) -> None:
        with self.lock:
            self.messages[topic] = [(received_s, message)]
            self.arrived.notify_all()

    def newest(self, topic: str) -> tuple[float, Any] | None:
        with self.lock:
            got = self.messages.get(topic)
            return got[-1] if got else None


class LiveSource:
    """:class:`acq.monitor.snapshot.Source` over the live server at ``host``:``port``.
    Connects at once: LiveSourceError naming the address when it cannot."""

    def __init__(self, host: str, port: int, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        self.address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        self.url = f"ws://{self.address}"
        self._seen = _Newest()
        self._connected = threading.Event()
        self._done = threading.Event()
        self._error: BaseException | None = None
        self._ended = ""  # why the connection ended, once it has
        self._loop = asyncio.new_event_loop()
        self._task: asyncio.Task[None] | None = None
        self._thread = threading.Thread(
            target=self._run, args=(timeout_s,), name="acq status client", daemon=True
        )
        self._thread.start()
        while not (self._connected.wait(0.05) or self._done.is_set()):
            pass
        if not self._connected.is_set():
            raise self._failure(self._error)

    def _run(self, timeout_s: float) -> None:
        self._task = self._loop.create_task(self._read(timeout_s))
        try:
            self._loop.run_until_complete(self._task)
        except asyncio.CancelledError:
            pass
        finally:
            self._loop.close()
            self._done.set()

    async def _read(self, timeout_s: float) -> None:
        try:
            ws = await connect_client(self.url, retry_s=0.0, open_timeout=timeout_s, max_size=2**22)
        except Exception as e:  # raised to the caller by __init__
            self._error = e
            return
        self._connected.set()
        try:
            await take(ws, self._seen, math.inf, decode=True, topics=TOPICS)
        except ConnectionClosed:
            self._ended = f"the live server at {self.address} closed the connection"
        except ProtocolError as e:
            self._ended = f"the live server at {self.address} left the protocol: {e}"
        except Exception as e:  # the connection's own failures: said in the view
            self._ended = f"connection lost: {self._failure(e)}"
        finally:
            await ws.close()

    def _failure(self, e: BaseException | None) -> LiveSourceError:
        """One line naming the address for why the connection failed."""
        what = self.address
        if isinstance(e, ConnectionRefusedError):
            why = "nothing listens there (is `acq record --live` running?)"
        elif isinstance(e, socket.gaierror):
            why = f"unknown host ({e.strerror})"
        elif isinstance(e, TimeoutError):
            why = "no WebSocket handshake within the time allowed"
        elif isinstance(e, InvalidHandshake | ProtocolError):
            why = f"not an acq live server ({str(e).splitlines()[0] if str(e) else 'no answer'})"
        elif isinstance(e, OSError):
            why = e.strerror or str(e)
        else:
            why = f"{type(e).__name__}: {e}"
        return LiveSourceError(f"{what}: {why}")

    def wait_status(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the first ``/acq/status`` (the recorder sends one
        a second, a subscriber gets the next), then up to a second more for the first
        ``/acq/timebase`` (sent once a second too, when the host clock has a reading);
        whether a status came. LiveSourceError when the connection ended before it."""
        end = time.monotonic() + timeout_s
        if not self._wait("/acq/status", end):
            if self._done.is_set():
                raise LiveSourceError(self._ended or f"{self.address}: connection ended")
            return False
        self._wait("/acq/timebase", min(end, time.monotonic() + TIME_BASE_WAIT_S))
        return True

    def _wait(self, topic: str, end: float) -> bool:
        """Wait until the monotonic time ``end`` for a message of ``topic``; whether one came."""
        with self._seen.arrived:
            while topic not in self._seen.messages and not self._done.is_set():
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._seen.arrived.wait(min(left, 0.1))
            return topic in self._seen.messages

    def snapshot(self) -> Snapshot:
        """The recorder's state as of its newest status."""
        got = self._seen.newest("/acq/status")
        time_base = self._seen.newest("/acq/timebase")
        running = not self._done.is_set()
        status = got[1] if got is not None else None
        age = time.monotonic() - got[0] if got is not None else None
        minutes = math.inf
        if status is not None and running and status.disk_minutes_left < NO_DISK_FIGURE:
            minutes = status.disk_minutes_left
        return Snapshot(
            source=f"live {self.url}",
            file=(status.file or None) if status is not None else None,
            file_bytes=None,
            writing=running,
            closed=False,
            status_age_s=age,
            uptime_s=status.uptime_s if status is not None else None,
            devices=device_views(status, age or 0.0) if status is not None else [],
            time_base=time_base_line(time_base[1] if time_base is not None else None),
            disk_free_bytes=status.disk_free_bytes if status is not None else None,
            disk_minutes_left=minutes,
            colouring=colouring_of(status) if status is not None else None,
            notes=[self._ended] if self._ended else [],
        )

    def close(self) -> None:
        """Close the connection and end the client's thread."""
        if self._task is not None and not self._done.is_set():
            self._loop.call_soon_threadsafe(self._task.cancel)
        self._thread.join(5.0)
