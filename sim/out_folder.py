"""A folder that a simulated-rig command (`acq demo`, `acq sim rig`) writes into and
marks as its own, so that it replaces its own files there on a new run and nothing else."""

from __future__ import annotations

from pathlib import Path

from acq.errors import InputError

__all__ = ["claim_folder", "make_folder"]


def claim_folder(out: Path, mark: str, command: str, files: tuple[str, ...]) -> None:
    """Make folder ``out`` the one of ``command``, marked with the file ``mark``: new,
    empty, or marked by an earlier run (whose ``files`` it replaces, leaving anything else
    there alone); InputError naming ``--out`` for any other."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; give a folder")
    if out.is_dir() and not (out / mark).is_file() and any(out.iterdir()):
        raise InputError(
            f"--out {out}: holds files and is not an earlier {command} folder (no {mark}); "
            "give a new or empty folder"
        )
    make_folder(out)
    (out / mark).write_text(
        f"{command} writes {', '.join(files)} here, replacing its own files on a new run\n",
        encoding="utf-8",
    )


def make_folder(out: Path) -> None:
    """Create folder ``out`` (and its parents) if missing; InputError naming ``--out``
    when it or a folder above it is a file."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        above = next(p for p in (out, *out.parents) if p.exists())
        raise InputError(f"--out {out}: {above} is a file, not a folder") from None
