"""`acq record` in a terminal: the recorder's status (the ``STATUS=`` line systemd gets,
each second) kept on the terminal's last line, under the log lines.

:class:`StatusLine` redraws that line in place (carriage return, erase line); a log
record is printed above it (:class:`StatusLineHandler` erases the status, lets the log
handler write its line, then draws the status again), so the two never mix.
:class:`TerminalNotifier` is the recorder's :class:`acq.record.sdnotify.Notifier` that
also shows each status there.
"""

from __future__ import annotations

import logging
import shutil
import threading
from collections.abc import Mapping
from typing import TextIO

from acq.record.sdnotify import Notifier

__all__ = ["StatusLine", "StatusLineHandler", "TerminalNotifier"]

_ERASE = "\r\x1b[2K"  # to the line's start, erase it (ECMA-48 EL 2)


class StatusLine:
    """The last line of the terminal ``stream``, holding the newest status; thread safe.
    ``in_place`` False (not a terminal, the status asked for): each status is a line of
    its own, ``status: TEXT``."""

    def __init__(self, stream: TextIO, *, in_place: bool = True) -> None:
        self.stream = stream
        self.in_place = in_place
        self.text = ""
        self.lock = threading.RLock()

    def show(self, text: str) -> None:
        """Replace the line with ``text``, cut to the terminal's width."""
        with self.lock:
            if not self.in_place:
                self._write(f"status: {text}\n")
                return
            width = shutil.get_terminal_size((100, 24)).columns
            self.text = text if len(text) < width else text[: max(1, width - 2)] + "…"
            self._write(_ERASE + self.text)

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # the terminal went away: the log lines say so
            pass

    def erase(self) -> None:
        """Leave the line empty (before a log line, and at the end)."""
        with self.lock:
            if self.in_place and self.text:
                self._write(_ERASE)

    def redraw(self) -> None:
        """Draw the status again (after a log line)."""
        with self.lock:
            if self.in_place and self.text:
                self._write(_ERASE + self.text)


class StatusLineHandler(logging.Handler):
    """``inner``, the log's handler writing to the status line's terminal, with the status
    erased before each record and drawn again after it."""

    def __init__(self, inner: logging.Handler, line: StatusLine) -> None:
        super().__init__(inner.level)
        self.inner = inner
        self.line = line

    def emit(self, record: logging.LogRecord) -> None:
        with self.line.lock:
            self.line.erase()
            self.inner.handle(record)
            self.line.redraw()


class TerminalNotifier(Notifier):
    """A :class:`Notifier` that also shows each ``STATUS=`` text on ``line``."""

    def __init__(self, line: StatusLine, env: Mapping[str, str] | None = None) -> None:
        super().__init__(env)
        self.line = line

    def status(self, text: str) -> bool:
        self.line.show(text)
        return super().status(text)
