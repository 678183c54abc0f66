"""The root of every error acq raises, and the one kind the command line reports as bad input.

Libraries raise these (or their own subclasses, defined where they are raised);
``acq.cli`` turns them into a line and an exit status: :class:`InputError` 2,
:class:`DiskFullError` 3, any other 1.
"""

from __future__ import annotations

__all__ = ["AcqError", "DiskFullError", "InputError", "InputValueError", "first_line"]


class AcqError(Exception):
    """Base of every acq error; raised as such for a runtime failure (exit status 1)."""


class InputError(AcqError):
    """A bad file, key, value or usage (exit status 2); the message names the file and
    the key or byte offset, in one line."""


class InputValueError(InputError, ValueError):
    """A bad value given by the user (a flag's, a file's); also a ValueError, for the
    callers that catch that."""


class DiskFullError(AcqError):
    """An output that did not fit on its disk (no space left, a quota or a file size
    limit reached): exit status 3, as `acq record` at its disk reserve; the message names
    the output and the disk (:func:`acq.disk_space.full_disk_error`)."""


def first_line(e: BaseException) -> str:
    """An exception's message's first line (its type's name when it has none): what a
    library's error says inside one of acq's one-line messages."""
    return str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
