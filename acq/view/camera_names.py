"""The cameras' names of a cloud as acq writes them: lines ``<index> <name>``, in a PLY's
header comments (``camera <index> <name>``) and in a LAS file's VLR ``acq 1``
(:mod:`acq.cloud.ply`, :mod:`acq.cloud.las`)."""

from __future__ import annotations

__all__ = ["camera_names"]


def camera_names(lines: list[str]) -> list[str]:
    """The cameras' names by index from lines ``<index> <name>`` (others ignored; a
    name missing ``camera <index>``), as acq writes them in a PLY's comments and a LAS
    file's VLR."""
    found: dict[int, str] = {}
    for line in lines:
        index, _, name = line.strip().partition(" ")
        if index.isdigit() and int(index) < 255 and name:
            found[int(index)] = name
    return [found.get(k, f"camera {k}") for k in range(max(found, default=-1) + 1)]
