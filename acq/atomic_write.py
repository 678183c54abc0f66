"""Writing a file whole or not at all: each writer takes a temporary file of its own
beside the file meant (:func:`temporary_beside`), then renames it onto that file.

The temporary is in the same folder (a rename within one file system is atomic) and its
name is unique to the writer, so that two commands writing one output at once never
write into each other's temporary: the output is then one whole file or the other,
never a mix, and each command's "wrote" holds for the file it closed. The temporaries
are hidden and recognisable: ``.STEM.XXXXXXXX.tmpSUFFIX``.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic", "temporary_beside", "write_text"]


def temporary_beside(path: Path, suffix: str | None = None) -> Path:
    """A fresh temporary path beside ``path`` (not created): ``.STEM.XXXXXXXX.tmpSUFFIX``
    with 8 random hex digits; ``suffix``: ``path``'s own unless given (some writers
    choose the format by the suffix)."""
    suffix = path.suffix if suffix is None else suffix
    return path.with_name(f".{path.stem}.{secrets.token_hex(4)}.tmp{suffix}")


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
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (:func:`atomic`)."""
    with atomic(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
