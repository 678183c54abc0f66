"""Whether a failed write failed for want of disk space, and the line that says so.

The libraries that write clouds report a full disk in their own words, without the
system's error number (lazrs: ``IoError: Failed to call write``; libE57:
``write() failed (ErrorWriteFailed)``; numpy: ``N requested and M written``): the disk
is then asked directly, by writing a few megabytes to an anonymous file beside the
output (:func:`full_disk_error`).
"""

from __future__ import annotations

import errno
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from acq.errors import AcqError, DiskFullError

__all__ = ["FULL_DISK_ERRNOS", "full_disk_error", "naming_full_disk"]

FULL_DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
"""No space left, disk quota exceeded, file too large (a file system's or the process's
size limit, RLIMIT_FSIZE)."""

_PROBE_BYTES = 8 << 20  # more than any one write of the cloud writers (a LAZ chunk)
_WHY = {
    errno.ENOSPC: "no space left on the disk of {folder}",
    errno.EDQUOT: "the disk quota is reached on the disk of {folder}",
    errno.EFBIG: "too large for the disk of {folder} or the process's file size limit",
}


def full_disk_error(output: Path, error: BaseException) -> DiskFullError | None:
    """A :class:`DiskFullError` naming ``output`` and the disk of its folder (its free
    megabytes) when ``error``, raised writing ``output`` (or a temporary beside it), came
    from a full disk, a quota or a file size limit: an OSError of one of
    :data:`FULL_DISK_ERRNOS`, or any other error while a probe write beside ``output``
    fails with one of those; None otherwise."""
    if isinstance(error, AcqError):  # acq's own verdict on the input, not the disk's
        return None
    code = error.errno if isinstance(error, OSError) else None
    if code not in FULL_DISK_ERRNOS:
        code = _probe(output.parent)
    if code is None:
        return None
    folder = output.parent.resolve()
    try:
        free = f"{shutil.disk_usage(folder).free / 1e6:.1f} MB free"
    except OSError:
        free = "free space unknown"
    return DiskFullError(f"{output}: {_WHY[code].format(folder=folder)} ({free})")


def _probe(folder: Path) -> int | None:
    """The error number (one of :data:`FULL_DISK_ERRNOS`) writing a few megabytes to an
    anonymous file in ``folder`` fails with; None when it does not (or fails otherwise)."""
    block = bytes(1 << 20)
    try:
        with tempfile.TemporaryFile(dir=folder, buffering=0) as f:
            written = 0
            while written < _PROBE_BYTES:
                written += f.write(block[: _PROBE_BYTES - written]) or 0
    except OSError as e:
        return e.errno if e.errno in FULL_DISK_ERRNOS else None
    return None


@contextmanager
def naming_full_disk(output: Path) -> Iterator[None]:
    """Within, an error that came from a full disk (:func:`full_disk_error`) is raised
    again as the :class:`DiskFullError` naming ``output``; any other as it is."""
    try:
        yield
    except Exception as e:
        full = full_disk_error(output, e)
        if full is None:
            raise
        raise full from e
