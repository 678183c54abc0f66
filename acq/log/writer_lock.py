"""The lock that says a log is being written: the writer holds an exclusive ``flock`` on
the file it writes for as long as it lives (the kernel drops it when the process ends,
killed or not), and a reader asks for a shared one without waiting.

Advisory: a file system without ``flock`` records all the same, and its logs read as
any whose writer stopped.
"""

from __future__ import annotations

import fcntl
import os
from typing import IO

__all__ = ["being_written", "hold", "locked"]


def hold(fd: int) -> None:
    """Mark the file open on ``fd`` as being written, until the descriptor is closed."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:  # no flock here, or a reader glancing at the new file this instant
        pass


def locked(f: IO[bytes]) -> bool:
    """Whether a writer holds the lock of the file open as ``f`` (another open file: the
    writer of :mod:`acq.log.writer`, alive)."""
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # no flock on this file system: nothing known
        return False
    fcntl.flock(f.fileno(), fcntl.LOCK_UN)
    return False


def being_written(path: str | os.PathLike[str]) -> bool:
    """Whether a live writer (``acq record``) has the log at ``path`` open: it holds the
    file's lock until it finishes the file or dies."""
    try:
        with open(path, "rb") as f:
            return locked(f)
    except OSError:
        return False
