"""systemd's readiness protocol and journal-friendly logging, without libsystemd.

:class:`Notifier` speaks sd_notify(3): one ``KEY=VALUE`` line per field, sent as a
datagram to the AF_UNIX socket named by ``NOTIFY_SOCKET`` (a path, or ``@name`` for the
abstract namespace). Without ``NOTIFY_SOCKET`` (not under systemd, or not ``Type=notify``)
every call is a no-op returning False; a failed send is logged at debug and returns False,
never raises: the recorder must not stop recording because systemd is unreachable.

The watchdog interval follows sd_watchdog_enabled(3): ``WATCHDOG_USEC`` applies only when
``WATCHDOG_PID`` is unset or names this process; ping at half the interval or more often.

:class:`JournalFormatter` prefixes every line with ``<N>``, the syslog priority of the
record's level, which journald reads from a service's stderr (``SyslogLevelPrefix=``, on
by default); it prints no timestamp since the journal stamps each line itself.
:func:`use_journal_format` tells whether stderr is that journal stream
(``JOURNAL_STREAM``, as sd_journal_stream_fd(3) describes).
"""

from __future__ import annotations

import logging
import os
import socket
import sys
import threading
from collections.abc import Mapping
from typing import IO, Any

__all__ = [
    "JournalFormatter",
    "Notifier",
    "journal_prefix",
    "use_journal_format",
]

log = logging.getLogger(__name__)

SEND_TIMEOUT_S = 0.5  # a ping from the writer's loop must not stall it on a busy PID 1


class Notifier:
    """Sends sd_notify messages to the socket in ``NOTIFY_SOCKET``; thread safe.

    ``env`` defaults to ``os.environ`` (read once, here). With ``unset_environment``
    the notification and watchdog variables are removed from ``os.environ`` so child
    processes do not inherit them (as sd_notify's ``unset_environment``).
    """

    def __init__(
        self, env: Mapping[str, str] | None = None, *, unset_environment: bool = False
    ) -> None:
        env = os.environ if env is None else env
        self.address: str | None = _socket_address(env.get("NOTIFY_SOCKET", ""))
        self._watchdog_usec = env.get("WATCHDOG_USEC", "")
        self._watchdog_pid = env.get("WATCHDOG_PID", "")
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        if unset_environment:
            for key in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"):
                os.environ.pop(key, None)

    @property
    def enabled(self) -> bool:
        """True when there is a socket to notify."""
        return self.address is not None

    def notify(self, **fields: str | int) -> bool:
        """Send ``KEY=VALUE`` lines in one datagram; True when it was sent."""
        return self.send("\n".join(f"{k}={_one_line(v)}" for k, v in fields.items()))

    def send(self, message: str) -> bool:
        """Send a raw message (newline-separated ``KEY=VALUE`` lines); True when sent."""
        if self.address is None or not message:
            return False
        try:
            with self._lock:
                if self._sock is None:
                    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                    sock.settimeout(SEND_TIMEOUT_S)
                    self._sock = sock
                self._sock.sendto(message.encode(), self.address)
        except OSError as e:
            log.debug("sd_notify to %r failed: %s", self.address, e)
            return False
        return True

    def ready(self, status: str = "") -> bool:
        """``READY=1``: start-up finished (with a ``STATUS=`` line when given)."""
        if status:
            return self.notify(READY=1, STATUS=status)
        return self.notify(READY=1)

    def status(self, text: str) -> bool:
        """``STATUS=text``: one line for ``systemctl status``."""
        return self.notify(STATUS=text)

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: the keep-alive ping."""
        return self.notify(WATCHDOG=1)

    def stopping(self) -> bool:
        """``STOPPING=1``: shutting down (finishing the file)."""
        return self.notify(STOPPING=1)

    def errno(self, n: int) -> bool:
        """``ERRNO=n``: the errno-style reason of a failure."""
        return self.notify(ERRNO=int(n))

    def extend_timeout(self, us: int) -> bool:
        """``EXTEND_TIMEOUT_USEC=us``: ask for that much more time to start or stop."""
        return self.notify(EXTEND_TIMEOUT_USEC=int(us))

    def watchdog_interval_s(self) -> float | None:
        """The watchdog timeout in seconds, or None when the watchdog is not for us."""
        return _watchdog_interval_s(self._watchdog_usec, self._watchdog_pid)

    def close(self) -> None:
        """Close the socket (a later send opens a new one)."""
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _socket_address(value: str) -> str | None:
    """The sendto() address for a NOTIFY_SOCKET value, None when unusable."""
    if value.startswith("/"):
        return value
    if value.startswith("@") and len(value) > 1:
        return "\0" + value[1:]  # the abstract namespace
    if value:
        log.debug("NOTIFY_SOCKET=%r is not an AF_UNIX address: notifications disabled", value)
    return None


def _one_line(value: str | int) -> str:
    """A value made safe for the line-based protocol."""
    return str(value).replace("\r", " ").replace("\n", " ")


def _watchdog_interval_s(usec: str, pid: str) -> float | None:
    """sd_watchdog_enabled(): WATCHDOG_USEC in seconds if WATCHDOG_PID allows it."""
    if not usec:
        return None
    if pid:
        try:
            if int(pid) != os.getpid():
                return None
        except ValueError:
            return None
    try:
        value = int(usec)
    except ValueError:
        return None
    return value / 1e6 if value > 0 else None


# logging level -> syslog priority (sd-daemon.h: SD_CRIT 2, SD_ERR 3, SD_WARNING 4,
# SD_INFO 6, SD_DEBUG 7), highest threshold first
_PRIORITIES = (
    (logging.CRITICAL, 2),
    (logging.ERROR, 3),
    (logging.WARNING, 4),
    (logging.INFO, 6),
)


def journal_prefix(level: int) -> str:
    """``<N>``: the syslog priority of a logging level, as journald reads it on stderr."""
    for threshold, priority in _PRIORITIES:
        if level >= threshold:
            return f"<{priority}>"
    return "<7>"


class JournalFormatter(logging.Formatter):
    """Each line prefixed with the record's ``<N>`` priority; no timestamp."""

    def __init__(self, fmt: str = "%(name)s: %(message)s", **kwargs: Any) -> None:
        super().__init__(fmt, **kwargs)

    def format(self, record: logging.LogRecord) -> str:
        prefix = journal_prefix(record.levelno)
        text = super().format(record)
        return "\n".join(prefix + line for line in text.split("\n"))


def use_journal_format(stream: IO[Any] | None = None, env: Mapping[str, str] | None = None) -> bool:
    """True when ``stream`` (default stderr) is the journal stream in ``JOURNAL_STREAM``."""
    env = os.environ if env is None else env
    value = env.get("JOURNAL_STREAM", "")
    stream = sys.stderr if stream is None else stream
    if not value or stream is None:
        return False
    try:
        dev, ino = (int(part) for part in value.split(":"))
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):  # malformed, no fd (pytest capture), closed
        return False
    return (st.st_dev, st.st_ino) == (dev, ino)
