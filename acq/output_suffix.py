"""What format an output file's suffix names (`-o OUT.ply`, `OUT.copc.laz`...)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from acq.errors import InputValueError

__all__ = ["suffix_format"]


def suffix_format(output: Path, suffixes: Sequence[str], what: str, option: str = "-o") -> str:
    """The one of ``suffixes`` (".ply", ".copc.laz"...: the longest that fits, any case)
    ``output``'s name ends with, without its first dot; InputValueError naming ``option``,
    the ``what`` format and the accepted suffixes for any other."""
    name = output.name.lower()
    for suffix in sorted(suffixes, key=len, reverse=True):
        if name.endswith(suffix) and len(name) > len(suffix):
            return suffix[1:]
    found = output.suffix.lower()
    raise InputValueError(
        f"{option} {output}: unknown {what} format {found or '(no suffix)'}; expected a "
        f"{', '.join(suffixes)} file"
    )
