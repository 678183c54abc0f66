"""Whether a file is an MCAP log at all (its magic), and :class:`LogError`, raised for
one that is not: missing, unreadable, a folder, empty, cut inside the magic or not MCAP;
and what lies where a log's records stop (a zero-filled tail or garbage)."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import IO

from acq.errors import InputValueError

__all__ = ["MAGIC", "LogError", "check_magic", "zeros_or_garbage"]

MAGIC = b"\x89MCAP0\r\n"


class LogError(InputValueError):
    """A file that is not an MCAP log at all (missing, unreadable, bad magic); ``offset``:
    the byte where it goes wrong, named in the message when there is one (None: the file
    as a whole)."""

    def __init__(self, path: str | os.PathLike[str], offset: int | None, reason: str) -> None:
        self.path = Path(path)
        self.offset = offset
        self.reason = reason
        where = f" (byte {offset})" if offset is not None else ""
        super().__init__(f"{self.path}: {reason}{where}")


def check_magic(path: Path) -> int:
    """File size in bytes, after checking that ``path`` starts with the MCAP magic."""
    try:
        mode = path.stat().st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):  # never opened: a FIFO would block
            kind = "a named pipe (FIFO)" if stat.S_ISFIFO(mode) else "not a regular file"
            raise LogError(path, None, f"{kind}: a log is read by seeking in it, save it to a file")
        with path.open("rb") as f:
            head = f.read(len(MAGIC))
            size = os.fstat(f.fileno()).st_size
    except FileNotFoundError:
        raise LogError(path, None, "no such file") from None
    except IsADirectoryError:
        raise LogError(path, None, "is a folder, not an MCAP file") from None
    except OSError as e:
        raise LogError(path, None, f"cannot read: {e.strerror or e}") from None
    if not head:
        raise LogError(path, None, "empty file, not an MCAP file")
    if head != MAGIC and MAGIC.startswith(head):
        raise LogError(path, len(head), f"cut inside the MCAP magic, {len(head)} bytes long")
    if head != MAGIC:
        raise LogError(path, None, f"not an MCAP file: bad magic {head!r}")
    return size


def zeros_or_garbage(f: IO[bytes], pos: int, size: int) -> str:
    """Why a log of ``size`` bytes holds no record at byte ``pos`` where one should start
    (a record of opcode 0): a zero-filled tail to its end, as a power loss leaves, or a
    record that is garbage."""
    f.seek(pos)
    while block := f.read(1 << 20):
        if block.count(0) != len(block):
            return f"invalid record (opcode 0x00) at byte {pos}"
    return f"zero-filled tail from byte {pos}, {size - pos} bytes, as after a power loss"
