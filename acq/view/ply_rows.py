"""PLY clouds read for the page (:mod:`acq.view.points_payload`): the vertices memory-mapped
(a binary PLY; plyfile reads an ASCII one whole), with the attributes acq writes
(:mod:`acq.cloud.ply`: ``scalar_time``, ``scalar_scan``, ``intensity``,
``scalar_coloured``, ``scalar_camera``, and CloudCompare's names without ``scalar_``) and
the cameras' names (its header comments ``camera <index> <name>``)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from acq.errors import InputError, first_line
from acq.view.camera_names import camera_names

__all__ = ["PlyRows"]

_CHUNK_POINTS = 1 << 18  # rows picked from at a time
# the payload's columns by the vertex properties that may hold them, acq's first
_PROPERTIES = {
    "time": ("scalar_time", "time"),
    "scan": ("scalar_scan", "scan"),
    "intensity": ("intensity", "scalar_intensity"),
    "coloured": ("scalar_coloured", "coloured"),
    "camera": ("scalar_camera", "camera"),
    "frame": ("scalar_frame", "frame"),
}


class PlyRows:
    """The vertices of the PLY cloud ``path`` (a checked layer's:
    :mod:`acq.view.layers`), see :class:`acq.view.cloud_rows.Rows`."""

    def __init__(self, path: Path) -> None:
        from plyfile import PlyData, PlyParseError

        self.path = path
        try:
            data = PlyData.read(str(path))
            self._vertex = data["vertex"].data
        except (
            PlyParseError,
            ValueError,
            KeyError,
            UnicodeDecodeError,
            struct.error,
            OSError,
        ) as e:
            raise InputError(f"{path}: not a readable PLY file ({first_line(e)})") from None
        names = set(self._vertex.dtype.names or ())
        self._found = {
            column: next(p for p in options if p in names)
            for column, options in _PROPERTIES.items()
            if any(p in names for p in options)
        }
        self._rgb = {"red", "green", "blue"} <= names
        self.columns = frozenset([*self._found, *(["rgb"] if self._rgb else [])])
        self.count = len(self._vertex)
        self.cameras = camera_names(
            [c.removeprefix("camera ") for c in data.comments if c.startswith("camera ")]
        )
        self.world = "frame laser" not in data.comments

    def read(self, start: int, stop: int) -> Iterator[dict[str, np.ndarray]]:
        for at in range(start, stop, _CHUNK_POINTS):
            rows = self._vertex[at : min(at + _CHUNK_POINTS, stop)]
            out = {"xyz": np.stack([rows[a] for a in "xyz"], axis=1).astype(np.float64)}
            for column, name in self._found.items():
                out[column] = rows[name]
            if self._rgb:
                out["rgb"] = np.stack([rows[c] for c in ("red", "green", "blue")], axis=1)
            yield out

    def close(self) -> None:
        self._vertex = self._vertex[:0]  # the memory map let go
