"""Writing a file whole or not at all: each writer takes a temporary file of its own
beside the file meant (:func:`temporary_beside`), then renames it onto that file.

The temporary is in the same folder (a rename within one file system is atomic) and its
name is unique to the writer, so that two commands writing one output at once never
write into each other's temporary: the output is then one whole file or the other,
never a mix, and each command's "wrote" holds for the file it closed. The temporaries
are hidden and recognisable: ``.STEM.XXXXXXXX.tmpSUFFIX``.

A temporary is created empty and locked (``flock``) by :func:`temporary_beside`, and the
lock lasts as long as the process that took it: the kernel drops it when that process
ends, however it ends (SIGKILL too). A temporary whose lock can be taken was therefore
left by a run that was killed, and the next :func:`temporary_beside` for the same
output removes it, saying so in a warning; a temporary of a run still writing is left.
"""

from __future__ import annotations

import fcntl
import logging
import os
import re
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic", "discard", "release", "remove_stale", "temporary_beside", "write_text"]

log = logging.getLogger(__name__)

# the temporaries this process created, each with the descriptor that holds its lock
_held: dict[Path, int] = {}


def temporary_beside(path: Path, suffix: str | None = None, *, folder: bool = False) -> Path:
    """A fresh temporary beside ``path``: ``.STEM.XXXXXXXX.tmpSUFFIX`` with 8 random hex
    digits, created empty (a folder when ``folder``) and locked for this process's life
    (module docstring); ``suffix``: ``path``'s own unless given (some writers choose the
    format by the suffix). Write it by opening it again (``"wb"``, ``"r+b"``; not
    ``"xb"``), never by removing and recreating it: the lock is on the file. The stale
    temporaries of the same output are removed first (:func:`remove_stale`)."""
    suffix = path.suffix if suffix is None else suffix
    _prune()
    remove_stale(path, suffix)
    while True:
        tmp = path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            if folder:
                tmp.mkdir()
                fd = os.open(tmp, os.O_RDONLY | os.O_DIRECTORY)
            else:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:  # one in 4 billion: draw again
            continue
        fcntl.flock(fd, fcntl.LOCK_EX)  # new: nobody else holds it
        _held[tmp] = fd
        return tmp


def release(tmp: Path) -> None:
    """Drop the lock of a temporary of :func:`temporary_beside` once it is renamed or
    removed (else dropped at the next :func:`temporary_beside`, or when the process ends)."""
    fd = _held.pop(tmp, None)
    if fd is not None:
        os.close(fd)


def discard(tmp: Path) -> None:
    """Remove a temporary of :func:`temporary_beside` (a file, or a folder and what it
    holds) if it is still there, and drop its lock."""
    try:
        if tmp.is_dir() and not tmp.is_symlink():
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            tmp.unlink(missing_ok=True)
    finally:
        release(tmp)


def _prune() -> None:
    """Release the locks of this process's temporaries that are gone (renamed into place
    or removed), so that their descriptors do not pile up in a long process."""
    for tmp, fd in list(_held.items()):
        try:
            live = os.stat(tmp).st_ino == os.fstat(fd).st_ino
        except OSError:
            live = False
        if not live:
            release(tmp)


def remove_stale(path: Path, suffix: str | None = None) -> list[Path]:
    """Remove the temporaries of ``path`` (``.STEM.XXXXXXXX.tmpSUFFIX``, ``suffix`` as
    for :func:`temporary_beside`) whose writer is dead (their lock can be taken), each
    named in a warning; the paths removed. A folder that cannot be listed: none."""
    suffix = path.suffix if suffix is None else suffix
    pattern = re.compile(rf"\.{re.escape(path.stem)}\.[0-9a-f]{{8}}\.tmp{re.escape(suffix)}")
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    removed = []
    for name in names:
        tmp = path.with_name(name)
        if pattern.fullmatch(name) is None or tmp in _held:
            continue
        try:
            fd = os.open(tmp, os.O_RDONLY)
        except OSError:  # gone meanwhile, or not ours to read
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # its writer is alive (or the file system cannot tell: kept)
            continue
        else:
            try:
                if tmp.is_dir() and not tmp.is_symlink():
                    shutil.rmtree(tmp)
                else:
                    tmp.unlink()
            except OSError:  # removed by another run meanwhile, or not ours to remove
                continue
            removed.append(tmp)
            log.warning("removed a stale temporary %s left by a run that was killed", tmp)
        finally:
            os.close(fd)
    return removed


@contextmanager
def atomic(path: Path) -> Iterator[Path]:
    """A fresh temporary path beside ``path`` (:func:`temporary_beside`) to write; moved
    onto ``path`` when the block ends, removed when it fails, so that ``path`` is the
    old file or the new one, never half of one. A write error names ``path``."""
    tmp = temporary_beside(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as e:  # named for the file meant, not the temporary one
        if e.strerror and e.filename in (None, str(tmp)):
            raise OSError(e.errno, e.strerror, str(path)) from e
        if not e.strerror and str(tmp) in str(e):
            raise OSError(str(e).replace(str(tmp), str(path))) from e
        raise
    finally:
        discard(tmp)


def write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (:func:`atomic`)."""
    with atomic(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
