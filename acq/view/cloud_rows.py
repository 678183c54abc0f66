"""A cloud file read by rows, as :mod:`acq.view.points_payload` packs it and
:mod:`acq.view.frames` reads a point of it: the protocol of the readers
(:class:`acq.view.ply_rows.PlyRows`, :class:`acq.view.las_rows.LasRows`) and the reader
of a path."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

import numpy as np

__all__ = ["NO_CAMERA", "Rows", "rows_of"]

NO_CAMERA = 255  # a point no camera coloured (its camera index)


class Rows(Protocol):
    """A cloud file's points, read by row: ``count`` rows, ``columns`` the attributes it
    holds (the names of :data:`acq.view.points_payload.COLUMNS`, and "frame": the index
    of the frame that coloured a point in its camera's, -1 none), ``cameras`` the names
    of its cameras (index order), ``world`` whether its points are in the world frame
    (not the laser's, as ``acq colorize --frame laser`` writes them)."""

    count: int
    columns: frozenset[str]
    cameras: list[str]
    world: bool

    def read(self, start: int, stop: int) -> Iterator[dict[str, np.ndarray]]:
        """Rows [start, stop) in consecutive chunks: "xyz" (n,3) float64 m and the
        columns it holds ("rgb" (n,3) uint8, or uint16 for LAS's 16 bits; the others
        (n,)); InputError naming the file when they cannot be read."""
        ...

    def close(self) -> None: ...


def rows_of(path: Path) -> Rows:
    """The reader of the cloud file ``path`` by its suffix (``.ply``, else LAS/LAZ/COPC)."""
    if path.suffix.lower() == ".ply":
        from acq.view.ply_rows import PlyRows

        return PlyRows(path)
    from acq.view.las_rows import LasRows

    return LasRows(path)
