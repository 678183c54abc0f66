"""A folder that a simulated-rig command (`acq demo`, `acq sim rig`) writes into and
marks as its own, so that it replaces its own files there on a new run and nothing else:
the mark lists each file the command wrote (its size and modification time, ns), and a
file of those names that is not as the command left it (changed, or put there by someone
else) is refused, never overwritten."""

from __future__ import annotations

import os
from pathlib import Path

from acq.errors import InputError

__all__ = ["claim_folder", "make_folder", "record_files"]

_WRITTEN = "written"  # a mark's line: written NAME SIZE MTIME_NS
_LISTED = "the files it wrote (name, bytes, modification time in ns):"


def _recorded(mark: Path) -> dict[str, tuple[int, int]] | None:
    """The files a mark lists: name -> (size, mtime ns); none for an unreadable mark;
    None for the mark of an older acq, which listed nothing (its files are taken as its
    own, as they were then)."""
    try:
        lines = mark.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return {}
    if _LISTED not in lines:
        return None
    out: dict[str, tuple[int, int]] = {}
    for line in lines:
        words = line.split(" ")
        if len(words) == 4 and words[0] == _WRITTEN and words[2].isdigit() and words[3].isdigit():
            out[words[1]] = (int(words[2]), int(words[3]))
    return out


def _state(path: Path) -> tuple[int, int] | None:
    """A regular file's (size, mtime ns), None for anything else or nothing."""
    try:
        st = path.lstat()
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns) if os.path.isfile(path) and not path.is_symlink() else None


def _ours(out: Path, mark: str, files: tuple[str, ...]) -> frozenset[str]:
    """Those of ``files`` in ``out`` that are as the command left them (its mark says)."""
    recorded = _recorded(out / mark)
    if recorded is None:
        return frozenset(n for n in files if _state(out / n) is not None)
    return frozenset(n for n in files if n in recorded and _state(out / n) == recorded[n])


def claim_folder(out: Path, mark: str, command: str, files: tuple[str, ...]) -> None:
    """Make folder ``out`` the one of ``command``, marked with the file ``mark``: new,
    empty, or marked by an earlier run whose ``files`` are there as it left them (they
    are replaced, anything else there is left alone); InputError naming ``--out`` for
    any other folder, and for one of ``files`` changed or put there since."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; give a folder")
    if out.is_dir() and not (out / mark).is_file() and any(out.iterdir()):
        raise InputError(
            f"--out {out}: holds files and is not an earlier {command} folder (no {mark}); "
            "give a new or empty folder"
        )
    mine = _ours(out, mark, files)
    others = [n for n in files if (out / n).exists() or (out / n).is_symlink()]
    others = sorted(n for n in others if n not in mine)
    if others:
        raise InputError(
            f"--out {out}: {', '.join(others)} changed or put there since {command} run "
            "wrote it; not overwritten: move it away or give a new folder"
        )
    make_folder(out)
    _write_mark(out, mark, command, files, mine)


def record_files(out: Path, mark: str, command: str, files: tuple[str, ...]) -> None:
    """Note in the mark of ``out`` those of ``files`` there now as the command's own (call
    it after writing them; a file absent is no longer listed)."""
    _write_mark(out, mark, command, files, frozenset(n for n in files if _state(out / n)))


def _write_mark(
    out: Path, mark: str, command: str, files: tuple[str, ...], written: frozenset[str]
) -> None:
    lines = [
        f"{command} writes {', '.join(files)} here, replacing its own files on a new run",
        _LISTED,
    ]
    for name in files:
        state = _state(out / name)
        if name in written and state is not None:
            lines.append(f"{_WRITTEN} {name} {state[0]} {state[1]}")
    (out / mark).write_text("\n".join(lines) + "\n", encoding="utf-8")


def make_folder(out: Path) -> None:
    """Create folder ``out`` (and its parents) if missing; InputError naming ``--out``
    when it or a folder above it is a file."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        above = next(p for p in (out, *out.parents) if p.exists())
        raise InputError(f"--out {out}: {above} is a file, not a folder") from None
